#include "cull/cpu_bvh_culler.hpp"

#include <algorithm>
#include <deque>
#include <stdexcept>
#include <string>

#include "cull/thread_pool.hpp"

namespace cullpipe::fast {

namespace {

constexpr std::uint32_t kRangeChunk = 16384;  // objects per accepted-range task


}  // namespace

/// What one task found; summed at the end. Kept between passes with its stack's storage.
struct CpuBvhCuller::Tally {
  std::size_t node_tests = 0, object_tests = 0, visible = 0, inside = 0;
  std::vector<std::pair<std::uint32_t, std::uint32_t>> stack;  // (node, planes to test)
};

/// Work for one thread: a subtree to walk (node, planes to test) or part of an accepted range.
struct CpuBvhCuller::Task {
  enum Kind : std::uint8_t { Subtree, Inside } kind;
  std::uint32_t node_or_first;
  std::uint32_t mask_or_count;
};

CpuBvhCuller::CpuBvhCuller(unsigned threads) : pool_(std::make_unique<ThreadPool>(threads)) {}
CpuBvhCuller::~CpuBvhCuller() = default;

unsigned CpuBvhCuller::threads() const { return pool_->size(); }

template <class Volume>
void CpuBvhCuller::upload_impl(const bvh::FlatTree& tree, std::span<const Volume> volumes, std::vector<Volume>& out) {
  if (const std::string why = bvh::check_flat_tree(tree, volumes); !why.empty())
    throw std::invalid_argument("CpuBvhCuller::upload: " + why);
  // Each id exactly once (checked): the threads write classes by id without racing.
  std::vector<Volume> ordered(volumes.size());
  for (std::size_t k = 0; k < tree.objects.size(); ++k) ordered[k] = volumes[tree.objects[k]];
  bvh::FlatTree copy = tree;  // copied before anything changes, so a failure leaves the old upload
  tree_ = std::move(copy);
  boxes_.clear();
  obbs_.clear();
  spheres_.clear();
  out = std::move(ordered);
  kind_ = kind_of<Volume>();
}

void CpuBvhCuller::upload(const bvh::FlatTree& tree, std::span<const Aabb> boxes) { upload_impl(tree, boxes, boxes_); }
void CpuBvhCuller::upload(const bvh::FlatTree& tree, std::span<const Obb> obbs) { upload_impl(tree, obbs, obbs_); }
void CpuBvhCuller::upload(const bvh::FlatTree& tree, std::span<const Sphere> spheres) { upload_impl(tree, spheres, spheres_); }

bvh::HierarchicalResult CpuBvhCuller::cull(const Frustum& frustum) {
  bvh::HierarchicalResult r;
  cull(frustum, r);
  return r;
}

void CpuBvhCuller::cull(const Frustum& frustum, bvh::HierarchicalResult& r) {
  std::vector<std::uint32_t> unused;
  cull(frustum, {}, r, unused);
}

void CpuBvhCuller::cull(const Frustum& frustum, const CpuBvhCullOptions& options, bvh::HierarchicalResult& r,
                        std::vector<std::uint32_t>& visible_ids) {
  if (kind_ == BvKind::Obb)
    cull_impl(frustum, options, r, visible_ids, obbs_);
  else if (kind_ == BvKind::Sphere)
    cull_impl(frustum, options, r, visible_ids, spheres_);
  else
    cull_impl(frustum, options, r, visible_ids, boxes_);
}

template <class Volume>
void CpuBvhCuller::cull_impl(const Frustum& frustum, const CpuBvhCullOptions& options, bvh::HierarchicalResult& r,
                             std::vector<std::uint32_t>& visible_ids, const std::vector<Volume>& volumes) {
  if constexpr (!std::is_same_v<Volume, Aabb>) bvh::require_unit_normals(frustum, "CpuBvhCuller");
  const std::size_t n = volumes.size();
  const std::vector<bvh::FlatNode>& nodes = tree_.nodes;
  const std::vector<std::uint32_t>& objects = tree_.objects;
  const bool classes = options.classes, ids = options.visible_ids;
  r.classes.resize(classes ? n : 0);
  r.node_tests = r.object_tests = r.visible = r.inside = 0;
  visible_ids.clear();

  // Everything starts OUTSIDE, in parallel chunks.
  const std::size_t fill_tasks = classes ? (n + kRangeChunk - 1) / kRangeChunk : 0;
  pool_->parallel_for(fill_tasks, [&](std::size_t t) {
    const std::size_t begin = t * kRangeChunk, end = std::min(n, begin + kRangeChunk);
    std::fill(r.classes.begin() + std::ptrdiff_t(begin), r.classes.begin() + std::ptrdiff_t(end), Classification::Outside);
  });
  if (nodes.empty()) return;

  // The top of the tree, breadth first, until there are subtrees enough for the threads.
  const std::uint32_t all = (1u << frustum.active().size()) - 1u;
  const std::size_t wanted = std::size_t(pool_->size()) * 16;
  std::deque<Task> frontier{{Task::Subtree, 0, all}};
  std::vector<Task>& tasks = tasks_;
  tasks.clear();
  Tally top;
  auto accept = [&](std::uint32_t first, std::uint32_t count) {
    for (std::uint32_t k = 0; k < count; k += kRangeChunk) tasks.push_back({Task::Inside, first + k, std::min(kRangeChunk, count - k)});
  };
  while (!frontier.empty() && frontier.size() + tasks.size() < wanted) {
    const Task t = frontier.front();
    frontier.pop_front();
    const bvh::FlatNode& node = nodes[t.node_or_first];
    if (node.leaf) {  // leaves go to the threads whole
      tasks.push_back(t);
      continue;
    }
    ++top.node_tests;
    std::uint32_t straddled = 0;
    const Classification c = bvh::classify_node<Volume>(node.box, frustum, t.mask_or_count, straddled);
    if (c == Classification::Outside) continue;
    if (c == Classification::Inside) {
      accept(node.first, node.count);
      continue;
    }
    frontier.push_back({Task::Subtree, t.node_or_first + 1, straddled});
    frontier.push_back({Task::Subtree, nodes[t.node_or_first + 1].skip, straddled});
  }
  tasks.insert(tasks.end(), frontier.begin(), frontier.end());
  // Each task covers its own contiguous part of the tree's object order (a subtree's range or
  // part of one): in that order, the tasks' visible lists concatenate into tree order.
  auto first_object = [&](const Task& t) { return t.kind == Task::Inside ? t.node_or_first : nodes[t.node_or_first].first; };
  if (ids) std::sort(tasks.begin(), tasks.end(), [&](const Task& a, const Task& b) { return first_object(a) < first_object(b); });

  std::vector<Tally>& tallies = tallies_;
  if (tallies.size() < tasks.size()) tallies.resize(tasks.size());
  for (std::size_t t = 0; t < tasks.size(); ++t) tallies[t].node_tests = tallies[t].object_tests = tallies[t].visible = tallies[t].inside = 0;
  if (task_ids_.size() < tasks.size()) task_ids_.resize(tasks.size());
  pool_->parallel_for(tasks.size(), [&](std::size_t index) {
    const Task& task = tasks[index];
    Tally& tally = tallies[index];
    std::vector<std::uint32_t>& found = task_ids_[index];
    found.clear();
    auto accept_range = [&](std::uint32_t first, std::uint32_t count) {
      if (classes)
        for (std::uint32_t k = first; k < first + count; ++k) r.classes[objects[k]] = Classification::Inside;
      if (ids) found.insert(found.end(), objects.begin() + first, objects.begin() + first + count);
      tally.visible += count;
      tally.inside += count;
    };
    if (task.kind == Task::Inside) {
      accept_range(task.node_or_first, task.mask_or_count);
      return;
    }
    // Depth first, as bvh::cull_hierarchical.
    std::vector<std::pair<std::uint32_t, std::uint32_t>>& stack = tally.stack;
    stack.assign(1, {task.node_or_first, task.mask_or_count});
    while (!stack.empty()) {
      const auto [i, mask] = stack.back();
      stack.pop_back();
      const bvh::FlatNode& node = nodes[i];
      ++tally.node_tests;
      std::uint32_t straddled = 0;
      const Classification c = bvh::classify_node<Volume>(node.box, frustum, mask, straddled);
      if (c == Classification::Outside) continue;
      if (c == Classification::Inside) {
        accept_range(node.first, node.count);
        continue;
      }
      if (node.leaf) {
        for (std::uint32_t k = node.first; k < node.first + node.count; ++k) {
          const Classification oc = bvh::classify_object(volumes[k], frustum, straddled);
          if (classes) r.classes[objects[k]] = oc;
          if (ids && oc != Classification::Outside) found.push_back(objects[k]);
          ++tally.object_tests;
          tally.visible += oc != Classification::Outside;
          tally.inside += oc == Classification::Inside;
        }
        continue;
      }
      stack.push_back({nodes[i + 1].skip, straddled});
      stack.push_back({i + 1, straddled});
    }
  });
  r.node_tests = top.node_tests;
  for (std::size_t index = 0; index < tasks.size(); ++index) {
    const Tally& t = tallies[index];
    r.node_tests += t.node_tests;
    r.object_tests += t.object_tests;
    r.visible += t.visible;
    r.inside += t.inside;
  }
  if (!ids) return;
  visible_ids.resize(r.visible);
  offsets_.assign(tasks.size() + 1, 0);
  for (std::size_t t = 0; t < tasks.size(); ++t) offsets_[t + 1] = offsets_[t] + task_ids_[t].size();
  pool_->parallel_for(tasks.size(), [&](std::size_t t) {
    std::vector<std::uint32_t>& found = task_ids_[t];
    std::copy(found.begin(), found.end(), visible_ids.begin() + std::ptrdiff_t(offsets_[t]));
    // Tasks cover other subtrees from view to view: do not let each keep its largest list.
    if (found.capacity() > 2 * found.size() + 4096) std::vector<std::uint32_t>().swap(found);
  });
}

}  // namespace cullpipe::fast
