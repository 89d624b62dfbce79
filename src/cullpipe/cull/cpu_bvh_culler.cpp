#include "cullpipe/cull/cpu_bvh_culler.hpp"

#include <algorithm>
#include <array>
#include <atomic>
#include <bit>
#include <functional>
#include <iterator>
#include <stdexcept>
#include <string>

#include "cullpipe/core/thread_pool.hpp"
#include "cullpipe/cull/kernel_select.hpp"

namespace cullpipe::fast {

namespace {

constexpr std::uint32_t kRangeChunk = 16384;       // objects per accepted-range task
constexpr std::size_t kTaskObjects = 8192;         // at most one subtree task per this many objects
constexpr std::size_t kLargeTaskObjects = 131072;  // subtree tasks of about this many objects where there are enough

}  // namespace

/// What one task found; summed at the end.
struct CpuBvhCuller::Tally {
  std::uint64_t node_tests = 0, object_tests = 0;
  std::size_t visible = 0, inside = 0;
  std::size_t marks = 0;  // a subtree task's first word in marks_
};

/// Work for one thread: a subtree to walk (node, planes to test) or part of an accepted range.
struct CpuBvhCuller::Task {
  enum Kind : std::uint8_t { Subtree, Inside } kind;
  std::uint32_t node_or_first;
  std::uint32_t mask_or_count;
  std::uint32_t view;
};

CpuBvhCuller::CpuBvhCuller(unsigned threads, std::optional<Isa> isa) : isa_(isa.value_or(best_isa())) {
  if (!isa_supported(isa_))
    throw std::invalid_argument("CpuBvhCuller: this CPU (or build) cannot run the " + std::string(to_string(isa_)) +
                                " kernels");
  kernels_ = std::make_unique<detail::KernelTable>(detail::kernels(isa_));
  pool_ = std::make_unique<ThreadPool>(threads);
}
CpuBvhCuller::~CpuBvhCuller() = default;

unsigned CpuBvhCuller::threads() const { return pool_->size(); }

namespace {

/// A volume's columns as the walk kernels read them (detail::kWalk*Columns).
template <std::size_t Columns>
using WalkColumns = std::array<float, Columns>;
WalkColumns<detail::kWalkAabbColumns> walk_columns(const Aabb& b) {
  return {b.min.x, b.min.y, b.min.z, b.max.x, b.max.y, b.max.z};
}
WalkColumns<detail::kWalkObbColumns> walk_columns(const Obb& b) {
  return {b.center.x,   b.center.y,   b.center.z,       b.basis[0].x,     b.basis[0].y,
          b.basis[0].z, b.basis[1].x, b.basis[1].y,     b.basis[1].z,     b.basis[2].x,
          b.basis[2].y, b.basis[2].z, b.half_extents.x, b.half_extents.y, b.half_extents.z};
}
WalkColumns<detail::kWalkSphereColumns> walk_columns(const Sphere& s) {
  return {s.center.x, s.center.y, s.center.z, s.radius};
}

float float_bits(std::uint32_t u) { return std::bit_cast<float>(u); }

}  // namespace

template <class Volume>
void CpuBvhCuller::upload_impl(const bvh::FlatTree& tree, std::span<const Volume> volumes) {
  // The whole of bvh::check_flat_tree, in two parts: the tree's own checks here, and each
  // volume's (valid, inside its leaf's box: bvh::volume_in_leaf) as the threads gather the
  // volumes into blocks below, so they are gathered once, on every core. A failure in either
  // is reported as check_flat_tree reports it.
  auto refuse = [&] {
    const std::string why = bvh::check_flat_tree(tree, volumes);
    throw std::invalid_argument("CpuBvhCuller::upload: " + (why.empty() ? "a volume outside its leaf" : why));
  };
  if (!bvh::check_flat_structure(tree, volumes.size()).empty()) refuse();
  // Each id exactly once (checked): the threads write classes by id without racing.
  // Everything that can fail is checked, and the arrays' room reserved, before anything
  // changes, so a failure leaves the old upload: the volumes are gathered into a second set of
  // blocks, which replaces the first only when every volume has passed (the two sets take
  // turns, so the memory is twice the blocks'). The arrays are rewritten in place: an
  // engine that refits and uploads every frame reuses their memory instead of faulting in
  // fresh pages on every upload. The node pairs and the volumes' blocks start on a cache line
  // (CacheLineVector): with malloc's 16-byte alignment a node record could straddle two
  // lines, and a pass's speed would depend on where an allocation happened to land.
  const std::size_t nodes = tree.nodes.size(), n = tree.objects.size();
  if (nodes >= detail::kWalkLeaf)  // (a pair index at or past the leaf bit would read as a leaf)
    throw std::length_error("CpuBvhCuller::upload: " + std::to_string(nodes) + " nodes (at most 2^31 - 1)");
  constexpr std::size_t columns = std::tuple_size_v<decltype(walk_columns(std::declval<const Volume&>()))>;
  constexpr std::size_t block = detail::kWalkBlock, block_floats = block * columns;
  // Whole blocks, and one more of zeros (detail::WalkTree::blocks).
  const std::size_t block_count = (n + block - 1) / block + 1;
  // Slots: the root alone in pair 0, then a pair per inner node for its two children, in
  // depth-first order (a subtree's pairs are adjacent). A binary tree of `nodes` nodes has
  // (nodes - 1) / 2 inner nodes: nodes + 1 slots.
  const std::size_t slots = std::max<std::size_t>(nodes + 1, 2);  // (pair 0 whole even without nodes)
  tree_.nodes.reserve(nodes);  // (each has the strong guarantee; growing capacity changes nothing seen)
  tree_.objects.reserve(n);
  walk_nodes_.reserve(slots * detail::kWalkNodeFloats);
  slot_of_.reserve(nodes);
  spare_blocks_.reserve(block_count * block_floats);

  // The volumes, gathered in tree order into the spare blocks by runs of leaves (a run of
  // nodes holds a contiguous run of the object order), each checked on the way.
  spare_blocks_.resize(block_count * block_floats);  // (within the reserved capacity)
  float* const blocks = spare_blocks_.data();
  const std::size_t parts = n < kTaskObjects ? 1 : std::min<std::size_t>(nodes, std::size_t(pool_->size()) * 8);
  std::atomic<bool> all_in_leaves{true};
  pool_->parallel_for(parts, [&](std::size_t part) {
    auto to_blocks = [&](std::size_t slot, const Volume& v) {
      const auto record = walk_columns(v);
      float* const out = blocks + detail::walk_block_offset(slot, columns);
      for (std::size_t c = 0; c < columns; ++c) out[c * block] = record[c];
    };
    if (!bvh::visit_leaf_volumes(tree, volumes, nodes * part / parts, nodes * (part + 1) / parts, to_blocks))
      all_in_leaves.store(false, std::memory_order_relaxed);
  });
  if (!all_in_leaves.load()) refuse();
  // Zeros past the last object: in its block's columns, and the block after.
  for (std::size_t c = 0; c < columns; ++c)
    std::fill(blocks + detail::walk_block_offset(n, columns) + c * block,
              blocks + n / block * block_floats + (c + 1) * block, 0.0f);
  std::fill(blocks + (block_count - 1) * block_floats, blocks + block_count * block_floats, 0.0f);

  // Nothing below throws: every resize is within the reserved capacity.
  tree_.nodes.assign(tree.nodes.begin(), tree.nodes.end());
  tree_.objects.assign(tree.objects.begin(), tree.objects.end());
  walk_nodes_.resize(slots * detail::kWalkNodeFloats);  // every slot is written below but pair 0's second
  std::fill_n(walk_nodes_.data() + detail::kWalkNodeFloats, detail::kWalkNodeFloats, 0.0f);
  slot_of_.resize(nodes);
  if (nodes != 0) slot_of_[0] = 0;
  std::uint32_t next_pair = 1;
  for (std::size_t i = 0; i < nodes; ++i) {  // depth first: a node's slot is set before it is reached
    const bvh::FlatNode& node = tree.nodes[i];
    std::uint32_t link = detail::kWalkLeaf;
    if (!node.leaf) {  // checked: two children, the next node and the one at that one's skip
      link = next_pair++;
      slot_of_[i + 1] = 2 * link;
      slot_of_[tree.nodes[i + 1].skip] = 2 * link + 1;
    }
    float* out = walk_nodes_.data() + std::size_t(slot_of_[i]) * detail::kWalkNodeFloats;
    const float r[detail::kWalkNodeFloats] = {node.box.min.x, node.box.min.y, node.box.min.z, float_bits(node.count),
                                              node.box.max.x, node.box.max.y, node.box.max.z, float_bits(link)};
    std::copy(std::begin(r), std::end(r), out);
  }
  walk_blocks_.swap(spare_blocks_);
  kind_ = kind_of<Volume>();
}

void CpuBvhCuller::upload(const bvh::FlatTree& tree, std::span<const Aabb> boxes) { upload_impl(tree, boxes); }
void CpuBvhCuller::upload(const bvh::FlatTree& tree, std::span<const Obb> obbs) { upload_impl(tree, obbs); }
void CpuBvhCuller::upload(const bvh::FlatTree& tree, std::span<const Sphere> spheres) { upload_impl(tree, spheres); }

bvh::HierarchicalResult CpuBvhCuller::cull(const Frustum& frustum) {
  bvh::HierarchicalResult r;
  cull(frustum, r);
  return r;
}

void CpuBvhCuller::cull(const Frustum& frustum, bvh::HierarchicalResult& r) {
  std::vector<std::uint32_t> unused;  // (never grown: no list is asked for)
  cull(frustum, {}, r, unused);
}

void CpuBvhCuller::cull(const Frustum& frustum, const CpuBvhCullOptions& options, bvh::HierarchicalResult& r,
                        std::vector<std::uint32_t>& visible_ids) {
  const Output out{&r, &visible_ids};
  cull_views(std::span<const Frustum>(&frustum, 1), options, std::span<const Output>(&out, 1));
}

void CpuBvhCuller::cull(std::span<const Frustum> views, const CpuBvhCullOptions& options,
                        std::vector<CpuBvhViewResult>& results) {
  results.resize(views.size());
  outputs_.clear();
  for (CpuBvhViewResult& v : results) outputs_.push_back({&v.result, &v.visible_ids});
  cull_views(views, options, outputs_);
}

void CpuBvhCuller::cull_views(std::span<const Frustum> views, const CpuBvhCullOptions& options,
                              std::span<const Output> outs) {
  if (kind_ != BvKind::Aabb)
    for (const Frustum& f : views) bvh::require_unit_normals(f, "CpuBvhCuller");
  const std::size_t n = tree_.objects.size(), view_count = views.size();
  const std::vector<bvh::FlatNode>& nodes = tree_.nodes;
  const std::vector<std::uint32_t>& objects = tree_.objects;
  const bool classes = options.classes, ids = options.visible_ids;
  const std::uint32_t range_objects = options.range_objects_for(kind_);
  for (const Output& o : outs) {
    o.result->classes.resize(classes ? n : 0);
    o.result->node_tests = o.result->object_tests = o.result->visible = o.result->inside = 0;
  }

  // Everything starts OUTSIDE, in parallel chunks.
  const std::size_t chunks = classes ? (n + kRangeChunk - 1) / kRangeChunk : 0;
  pool_->parallel_for(chunks * view_count, [&](std::size_t t) {
    std::vector<Classification>& c = outs[t / chunks].result->classes;
    const std::size_t begin = t % chunks * kRangeChunk, end = std::min(n, begin + kRangeChunk);
    std::fill(c.begin() + std::ptrdiff_t(begin), c.begin() + std::ptrdiff_t(end), Classification::Outside);
  });
  if (nodes.empty()) {
    for (const Output& o : outs) o.visible_ids->clear();
    return;
  }

  // The top of each view's tree, breadth first, until there are subtrees enough for the
  // threads: one per kLargeTaskObjects objects, but at least 4 per thread (for balance; the
  // threads take the largest first) and at most 16, and never more than one per kTaskObjects
  // objects (a small tree is one task on the calling thread: a task costs more than walking a
  // few hundred nodes). Fewer, larger subtrees start fewer walks, whose first steps test a node
  // or two each; much larger ones list more object ranges than the caches keep until they are
  // tested.
  const std::size_t threads = pool_->size();
  const std::size_t wanted = std::clamp<std::size_t>(
      std::max(n / kLargeTaskObjects, std::min(n / kTaskObjects, threads * 4)), 1, threads * 16);
  std::vector<Task>& tasks = tasks_;
  tasks.clear();
  for (std::uint32_t v = 0; v < view_count; ++v) {
    const Frustum& frustum = views[v];
    const std::size_t first_task = tasks.size();
    // A queue in a kept vector (front at `head`), so a steady pass allocates nothing.
    std::vector<Task>& frontier = frontier_;
    frontier.assign(1, {Task::Subtree, 0, (1u << frustum.active().size()) - 1u, v});
    std::size_t head = 0;
    auto accept = [&](std::uint32_t first, std::uint32_t count) {
      for (std::uint32_t k = 0; k < count; k += kRangeChunk)
        tasks.push_back({Task::Inside, first + k, std::min(kRangeChunk, count - k), v});
    };
    while (head != frontier.size() && frontier.size() - head + tasks.size() - first_task < wanted) {
      const Task t = frontier[head++];
      const bvh::FlatNode& node = nodes[t.node_or_first];
      if (bvh::TraversalOptions{range_objects}.tests_objects_of(
              node)) {  // leaves (and small nodes) go to the threads whole
        tasks.push_back(t);
        continue;
      }
      ++outs[v].result->node_tests;
      std::uint32_t straddled = 0;
      const Classification c = kind_ == BvKind::Aabb
                                   ? bvh::classify_node<Aabb>(node.box, frustum, t.mask_or_count, straddled)
                                   : bvh::classify_masked_margin(node.box, frustum, t.mask_or_count, straddled);
      if (c == Classification::Outside) continue;
      if (c == Classification::Inside) {
        accept(node.first, node.count);
        continue;
      }
      frontier.push_back({Task::Subtree, t.node_or_first + 1, straddled, v});
      frontier.push_back({Task::Subtree, nodes[t.node_or_first + 1].skip, straddled, v});
    }
    tasks.insert(tasks.end(), frontier.begin() + std::ptrdiff_t(head), frontier.end());
  }
  // Each task covers its own contiguous part of its view's tree object order (a subtree's
  // range or part of one): in that order, a view's task lists concatenate into tree order.
  // The sorts below (of the tasks' indices, by key_of(index)) compare keys computed once per
  // task, not the nodes (scattered over the tree's memory) at every comparison.
  std::vector<std::uint64_t>& keys = sort_keys_;
  std::vector<std::uint32_t>& order = order_;
  auto sort_order = [&](auto key_of, auto before) {
    keys.resize(tasks.size());
    order.resize(tasks.size());
    for (std::size_t t = 0; t < tasks.size(); ++t) {
      keys[t] = key_of(t);
      order[t] = static_cast<std::uint32_t>(t);
    }
    std::sort(order.begin(), order.end(), [&](std::uint32_t a, std::uint32_t b) { return before(keys[a], keys[b]); });
  };
  if (ids) {
    sort_order(
        [&](std::size_t i) {
          const Task& t = tasks[i];
          return std::uint64_t(t.view) << 32 |
                 (t.kind == Task::Inside ? t.node_or_first : nodes[t.node_or_first].first);
        },
        std::less<std::uint64_t>());
    frontier_.clear();  // (the walk's queue, done with: the tasks in their new order, copied back
                        // so each vector keeps its role and a steady pass allocates nothing)
    for (std::uint32_t t : order) frontier_.push_back(tasks[t]);
    tasks.assign(frontier_.begin(), frontier_.end());
  }

  std::vector<Tally>& tallies = tallies_;
  tallies.assign(tasks.size(), Tally{});
  // Every thread's work lists sized here for the largest subtree, whichever thread takes it,
  // so a steady pass allocates nothing.
  work_.resize(pool_->size());
  std::size_t most_work = 0;
  for (const Task& t : tasks)
    if (t.kind == Task::Subtree)
      most_work = std::max(most_work, detail::walk_work_words(nodes[t.node_or_first].skip - t.node_or_first));
  for (std::vector<std::uint32_t>& w : work_)
    if (w.size() < most_work) w.resize(most_work);
  // Each subtree task marks its visible objects in its own words of marks_ (a bit per object
  // of its range), from which the last step lists them.
  std::size_t mark_words = 0;
  for (std::size_t t = 0; t < tasks.size(); ++t) {
    if (tasks[t].kind != Task::Subtree) continue;
    tallies[t].marks = mark_words;
    mark_words += (std::size_t(nodes[tasks[t].node_or_first].count) + 63) / 64;
  }
  if (ids) {
    // The marks are all zero between passes: the listing clears every word it finds set, so
    // a walk starts on clear words without clearing its subtree's. A pass stopped between
    // its walk and its listing (by an exception from a list's resize) leaves marks set;
    // marks_clean_ says so, and the next pass clears them all first.
    if (!marks_clean_) std::fill(marks_.begin(), marks_.end(), std::uint64_t{0});
    if (marks_.size() < mark_words) marks_.resize(mark_words);  // (new words are zero)
    marks_clean_ = false;
  }
  planes_.clear();
  for (const Frustum& f : views) planes_.push_back(detail::plane_set(f));
  const detail::WalkTree walk_tree{walk_nodes_.data(),   walk_blocks_.data(),  objects.data(),      range_objects,
                                   bvh::kBvhMarginScale, bvh::kBvhMarginFloor, bvh::kBvhMarginLimit};
  const detail::WalkKernel walk = kind_ == BvKind::Obb      ? kernels_->walk_obb
                                  : kind_ == BvKind::Sphere ? kernels_->walk_sphere
                                                            : kernels_->walk_aabb;
  // The threads take the largest subtrees first and the accepted ranges (short, even) last,
  // so the pass does not end waiting on one thread's large subtree.
  sort_order(
      [&](std::size_t i) -> std::uint64_t {
        const Task& t = tasks[i];
        return t.kind == Task::Inside ? 0 : nodes[t.node_or_first].skip - t.node_or_first;
      },
      std::greater<std::uint64_t>());
  pool_->parallel_for(tasks.size(), [&](std::size_t claimed) {
    const std::size_t index = order_[claimed];
    const Task& task = tasks[index];
    Tally& tally = tallies[index];
    std::vector<Classification>& view_classes = outs[task.view].result->classes;
    if (task.kind == Task::Inside) {
      const std::uint32_t first = task.node_or_first, count = task.mask_or_count;
      if (classes)
        for (std::uint32_t k = first; k < first + count; ++k) view_classes[objects[k]] = Classification::Inside;
      tally.visible = tally.inside = count;
      return;
    }
    std::vector<std::uint32_t>& work = work_[pool_->thread_index()];  // kept between passes, sized above
    const bvh::FlatNode& root = nodes[task.node_or_first];
    const std::size_t subtree_nodes = root.skip - task.node_or_first;
    detail::WalkOutput out;
    out.classes = classes ? reinterpret_cast<std::uint8_t*>(view_classes.data()) : nullptr;
    if (ids) out.marks = marks_.data() + tally.marks;  // (clear: see marks_clean_)
    out.work = work.data();
    out.work_capacity = subtree_nodes;
    const detail::WalkRoot walk_root{slot_of_[task.node_or_first], root.first, root.count, task.mask_or_count};
    const detail::WalkCounts c = walk(walk_tree, walk_root, planes_[task.view], out);
    tally.node_tests = c.node_tests;
    tally.object_tests = c.object_tests;
    tally.visible = c.visible;
    tally.inside = c.inside;
  });
  for (std::size_t t = 0; t < tasks.size(); ++t) {
    bvh::HierarchicalResult& r = *outs[tasks[t].view].result;
    r.node_tests += tallies[t].node_tests;
    r.object_tests += tallies[t].object_tests;
    r.visible += tallies[t].visible;
    r.inside += tallies[t].inside;
  }
  if (!ids) return;
  // Each view's list, its tasks' lists in task order (tree order), straight from the ranges
  // and the marks.
  for (const Output& o : outs) o.visible_ids->resize(o.result->visible);
  offsets_.assign(tasks.size(), 0);
  for (std::size_t t = 1; t < tasks.size(); ++t)
    offsets_[t] = tasks[t].view == tasks[t - 1].view ? offsets_[t - 1] + tallies[t - 1].visible : 0;
  // The threads take the longest lists first, as they took the largest walks: claimed in
  // tree order, a subtree's list of thousands of ids could start last and leave the other
  // thread waiting.
  sort_order([&](std::size_t i) -> std::uint64_t { return tallies[i].visible; }, std::greater<std::uint64_t>());
  pool_->parallel_for(tasks.size(), [&](std::size_t claimed) {
    const std::size_t index = order_[claimed];
    const Task& task = tasks[index];
    std::uint32_t* out = outs[task.view].visible_ids->data() + offsets_[index];
    if (task.kind == Task::Inside) {
      std::copy_n(objects.data() + task.node_or_first, task.mask_or_count, out);
      return;
    }
    const bvh::FlatNode& root = nodes[task.node_or_first];
    const std::uint32_t* from = objects.data() + root.first;
    std::uint64_t* marks = marks_.data() + tallies[index].marks;
    kernels_->list(marks, (std::size_t(root.count) + 63) / 64, from, out, out + tallies[index].visible);
  });
  marks_clean_ = true;  // every subtree task's words listed, and so cleared
}

}  // namespace cullpipe::fast
