#include "cullpipe/bvh/dynamic.hpp"

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <exception>
#include <optional>
#include <stdexcept>
#include <system_error>
#include <utility>

#include "cullpipe/bvh/box_ops.hpp"
#include "cullpipe/bvh/bvh.hpp"
#include "cullpipe/bvh/sibling_search.inl"
#include "cullpipe/geom/validate.hpp"

namespace cullpipe::bvh {

using detail::merged;

struct DynamicTree::Scratch {
  detail::SiblingHeap heap;
  std::vector<std::uint32_t> objects;  // compaction's new list
};

namespace {

// SAH cost with a floor: a tree of one point box has cost 0, and quality divides by it.
double sah_cost(const Tree& tree) {
  const double cost = metrics(tree).sah_cost;
  return cost > 0.0 ? cost : 1.0;
}

std::string describe(const Aabb& box) {
  char text[160];
  std::snprintf(text, sizeof text, "{min (%g, %g, %g), max (%g, %g, %g)}", double(box.min.x), double(box.min.y),
                double(box.min.z), double(box.max.x), double(box.max.y), double(box.max.z));
  return text;
}

void check_box(const Aabb& box, std::size_t index, bool batch) {
  const std::string why = invalid_reason(box);
  if (!why.empty())
    throw std::invalid_argument("DynamicTree::insert: " + (batch ? "box " + std::to_string(index) + " " : "box ") +
                                describe(box) + " is invalid (" + why + ")");
}

void check_id(std::uint32_t id, std::size_t count, std::size_t index, bool batch) {
  if (id >= count)
    throw std::invalid_argument("DynamicTree::remove: id " + std::to_string(id) +
                                (batch ? " (ids[" + std::to_string(index) + "])" : std::string()) +
                                " is not below the object count " + std::to_string(count));
}

// The tree's nodes as detail::best_sibling reads them.
struct View {
  const Tree& tree;
  const std::vector<std::uint32_t>& below;
  const Aabb& box(std::uint32_t i) const { return tree.nodes[i].box; }
  bool leaf(std::uint32_t i) const { return tree.nodes[i].leaf(); }
  std::uint32_t left(std::uint32_t i) const { return tree.nodes[i].left; }
  std::uint32_t right(std::uint32_t i) const { return tree.nodes[i].right; }
  std::uint32_t count(std::uint32_t i) const { return below[i]; }
};

void replace_child(Node& parent, std::uint32_t old_child, std::uint32_t new_child) {
  (parent.left == old_child ? parent.left : parent.right) = new_child;
}

}  // namespace

DynamicTree::Built DynamicTree::make(const std::vector<Aabb>& boxes, const DynamicTreeOptions& options) {
  Built b;
  b.tree = build(options.builder, boxes, options.build);
  b.cost = sah_cost(b.tree);
  b.objects = boxes.size();
  // The links, here rather than at the swap, so that the thread that built pays for them.
  Links& l = b.links;
  const std::size_t nodes = b.tree.nodes.size();
  l.parent.assign(nodes, kNone);
  l.below.assign(nodes, 0);
  l.leaf_of.assign(boxes.size(), kNone);
  l.position.assign(boxes.size(), kNone);
  std::vector<std::uint32_t> order;  // parents before children
  order.reserve(nodes);
  if (nodes) order.push_back(0);
  for (std::size_t k = 0; k < order.size(); ++k) {
    const Node& n = b.tree.nodes[order[k]];
    if (n.leaf()) continue;
    for (const std::uint32_t c : {n.left, n.right}) {
      l.parent[c] = order[k];
      order.push_back(c);
    }
  }
  for (std::size_t k = order.size(); k-- > 0;) {
    const std::uint32_t i = order[k];
    const Node& n = b.tree.nodes[i];
    if (n.leaf()) {
      l.below[i] = n.count;
      for (std::uint32_t p = n.first; p < n.first + n.count; ++p) {
        l.leaf_of[b.tree.objects[p]] = i;
        l.position[b.tree.objects[p]] = p;
      }
    } else {
      l.below[i] = l.below[n.left] + l.below[n.right];
    }
  }
  return b;
}

void DynamicTree::take(Built&& built) {
  tree_ = std::move(built.tree);
  links_ = std::move(built.links);
  free_positions_.clear();
  built_cost_ = built.cost;
  built_objects_ = built.objects;
  quality_ = 1.0;
}

DynamicTree::DynamicTree(std::span<const Aabb> boxes, DynamicTreeOptions options)
    : options_(std::move(options)), scratch_(std::make_unique<Scratch>()) {
  take(make(std::vector<Aabb>(boxes.begin(), boxes.end()), options_));
}

DynamicTree::~DynamicTree() {
  if (pending_.valid()) pending_.wait();
}

TreeStep DynamicTree::update(std::span<const Aabb> boxes) {
  if (boxes.size() != object_count()) {
    if (pending_.valid()) {
      pending_.wait();
      pending_ = {};
    }
    edits_.clear();
    take(make(std::vector<Aabb>(boxes.begin(), boxes.end()), options_));
    ++rebuilds_;
    return TreeStep::Rebuilt;
  }
  TreeStep step = TreeStep::Refitted;
  if (pending_.valid() && pending_.wait_for(std::chrono::seconds(0)) == std::future_status::ready) {
    std::optional<Built> done;
    try {
      done = pending_.get();
    } catch (const std::exception& e) {  // the old tree stays; the next update may try again
      last_error_ = e.what();
    }
    pending_ = {};
    if (done) {
      take(std::move(*done));
      for (const Edit& e : edits_) {
        if (e.removed == kNone)
          insert_one(e.box);
        else
          remove_one(e.removed);
      }
      ++rebuilds_;
      step = TreeStep::Swapped;
    }
    edits_.clear();
  }
  compact_objects();
  // The objects moved since the copy the rebuild started from (or since the last frame), and
  // inserted objects since their insertion: the tree's topology stays, its boxes follow them.
  refit(tree_, boxes);
  // A fresh tree over fewer objects costs less, by less than their ratio in the scenes measured
  // (the cost grows as n^0.45 to n^1): scaled by it, the built cost errs low, so that removals
  // do not hide a degraded tree.
  const double scale = built_objects_ ? std::min(1.0, double(boxes.size()) / double(built_objects_)) : 1.0;
  quality_ = boxes.empty() ? 1.0 : sah_cost(tree_) / (built_cost_ * scale);
  if (step == TreeStep::Refitted && !pending_.valid() && quality_ > options_.rebuild_ratio) {
    try {
      // Not on the caller's pool: its parallel_for takes one caller at a time, and the engine
      // may use it during the frame while this build runs.
      DynamicTreeOptions background = options_;
      background.build.pool = nullptr;
      pending_ = std::async(std::launch::async, &DynamicTree::make, std::vector<Aabb>(boxes.begin(), boxes.end()),
                            std::move(background));
      step = TreeStep::RebuildStarted;
    } catch (const std::system_error& e) {  // no thread to be had: refitting goes on
      last_error_ = e.what();
    }
  }
  return step;
}

void DynamicTree::insert(const Aabb& box) {
  check_box(box, 0, false);
  insert_one(box);
  if (pending_.valid()) edits_.push_back({box, kNone});
}

void DynamicTree::insert(std::span<const Aabb> boxes) {
  for (std::size_t k = 0; k < boxes.size(); ++k) check_box(boxes[k], k, true);
  for (const Aabb& box : boxes) {
    insert_one(box);
    if (pending_.valid()) edits_.push_back({box, kNone});
  }
}

void DynamicTree::remove(std::uint32_t id) {
  check_id(id, object_count(), 0, false);
  remove_one(id);
  if (pending_.valid()) edits_.push_back({{}, id});
}

void DynamicTree::remove(std::span<const std::uint32_t> ids) {
  for (std::size_t k = 0; k < ids.size(); ++k) check_id(ids[k], object_count() - std::min(k, object_count()), k, true);
  for (const std::uint32_t id : ids) {
    remove_one(id);
    if (pending_.valid()) edits_.push_back({{}, id});
  }
}

void DynamicTree::insert_one(const Aabb& box) {
  Links& l = links_;
  const auto id = std::uint32_t(l.leaf_of.size());
  std::uint32_t k = 0;
  if (!free_positions_.empty()) {
    k = free_positions_.back();
    free_positions_.pop_back();
    tree_.objects[k] = id;
  } else {
    k = std::uint32_t(tree_.objects.size());
    tree_.objects.push_back(id);
  }
  l.position.push_back(k);
  if (tree_.nodes.empty()) {
    l.leaf_of.push_back(add_node({box, kNone, kNone, k, 1}, kNone, 1));
    return;
  }
  const std::uint32_t sibling = detail::best_sibling(View{tree_, l.below}, 0, box, scratch_->heap);
  const std::uint32_t leaf = add_node({box, kNone, kNone, k, 1}, kNone, 1);
  l.leaf_of.push_back(leaf);
  if (sibling == 0) {  // the new inner node becomes the root, which stays at node 0
    const std::uint32_t old_root = add_node({}, kNone, 0);
    place_node(0, old_root);
    l.parent[old_root] = l.parent[leaf] = 0;
    tree_.nodes[0] = {merged(tree_.nodes[old_root].box, box), old_root, leaf, 0, 0};
    l.below[0] = l.below[old_root] + 1;
    return;
  }
  const std::uint32_t up = l.parent[sibling];
  const std::uint32_t parent =
      add_node({merged(tree_.nodes[sibling].box, box), sibling, leaf, 0, 0}, up, l.below[sibling] + 1);
  replace_child(tree_.nodes[up], sibling, parent);
  l.parent[sibling] = l.parent[leaf] = parent;
  for (std::uint32_t i = up; i != kNone; i = l.parent[i]) {
    Node& n = tree_.nodes[i];
    n.box = merged(tree_.nodes[n.left].box, tree_.nodes[n.right].box);
    ++l.below[i];
  }
}

void DynamicTree::remove_one(std::uint32_t id) {
  Links& l = links_;
  const std::uint32_t leaf = l.leaf_of[id];
  Node& n = tree_.nodes[leaf];
  if (n.count > 1) {
    // The leaf's last entry fills the removed one's, so that its range stays contiguous.
    const std::uint32_t last = n.first + n.count - 1, k = l.position[id];
    const std::uint32_t moved = tree_.objects[last];
    tree_.objects[k] = moved;
    l.position[moved] = k;
    --n.count;
    free_position(last);
    for (std::uint32_t i = leaf; i != kNone; i = l.parent[i]) --l.below[i];
  } else if (leaf == 0) {  // the last object
    tree_ = {};
    l.parent.clear();
    l.below.clear();
    free_positions_.clear();
  } else {
    free_position(l.position[id]);
    const std::uint32_t parent = l.parent[leaf];
    const Node& p = tree_.nodes[parent];
    const std::uint32_t sibling = p.left == leaf ? p.right : p.left;
    const std::uint32_t up = l.parent[parent];
    if (up == kNone) {  // the sibling becomes the root, at node 0
      place_node(sibling, 0);
      l.parent[0] = kNone;
      free_node(std::max(leaf, sibling));
      free_node(std::min(leaf, sibling));
    } else {
      replace_child(tree_.nodes[up], parent, sibling);
      l.parent[sibling] = up;
      for (std::uint32_t i = up; i != kNone; i = l.parent[i]) {
        Node& a = tree_.nodes[i];
        a.box = merged(tree_.nodes[a.left].box, tree_.nodes[a.right].box);
        --l.below[i];
      }
      free_node(std::max(leaf, parent));
      free_node(std::min(leaf, parent));
    }
  }
  // The last id takes the removed one's.
  const auto last_id = std::uint32_t(l.leaf_of.size() - 1);
  if (id != last_id) {
    l.leaf_of[id] = l.leaf_of[last_id];
    l.position[id] = l.position[last_id];
    tree_.objects[l.position[id]] = id;
  }
  l.leaf_of.pop_back();
  l.position.pop_back();
  // Compacting once the unowned entries outnumber a quarter of the objects costs O(1) per
  // removal, amortised, and bounds the list at 1.25 x the objects (plus a little).
  if (free_positions_.size() > l.leaf_of.size() / 4 + 64) compact_objects();
}

std::uint32_t DynamicTree::add_node(const Node& node, std::uint32_t parent, std::uint32_t below) {
  tree_.nodes.push_back(node);
  links_.parent.push_back(parent);
  links_.below.push_back(below);
  return std::uint32_t(tree_.nodes.size() - 1);
}

// Node `from` is copied to `to`, and its children or objects point to `to`; its parent's link
// is the caller's to set.
void DynamicTree::place_node(std::uint32_t from, std::uint32_t to) {
  Links& l = links_;
  const Node& n = tree_.nodes[to] = tree_.nodes[from];
  l.parent[to] = l.parent[from];
  l.below[to] = l.below[from];
  if (n.leaf()) {
    for (std::uint32_t k = n.first; k < n.first + n.count; ++k) l.leaf_of[tree_.objects[k]] = to;
  } else {
    l.parent[n.left] = l.parent[n.right] = to;
  }
}

// The last node takes the place of node `i`, which nothing links to any more, so that the
// nodes stay a packed array of reachable ones.
void DynamicTree::free_node(std::uint32_t i) {
  const auto last = std::uint32_t(tree_.nodes.size() - 1);
  if (i != last) {
    place_node(last, i);
    replace_child(tree_.nodes[links_.parent[i]], last, i);
  }
  tree_.nodes.pop_back();
  links_.parent.pop_back();
  links_.below.pop_back();
}

void DynamicTree::free_position(std::uint32_t k) {
  tree_.objects[k] = kNone;
  if (k + 1 == tree_.objects.size())
    tree_.objects.pop_back();
  else
    free_positions_.push_back(k);
}

void DynamicTree::compact_objects() {
  if (free_positions_.empty()) return;
  std::vector<std::uint32_t>& out = scratch_->objects;
  out.clear();
  out.reserve(links_.leaf_of.size());
  for (Node& n : tree_.nodes) {
    if (!n.leaf()) continue;
    const auto first = std::uint32_t(out.size());
    for (std::uint32_t k = n.first; k < n.first + n.count; ++k) {
      links_.position[tree_.objects[k]] = std::uint32_t(out.size());
      out.push_back(tree_.objects[k]);
    }
    n.first = first;
  }
  std::swap(tree_.objects, out);
  free_positions_.clear();
}

}  // namespace cullpipe::bvh
