// Refitting node boxes after objects move, and collapsing subtrees into leaves by the SAH.
#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <string>
#include <vector>

#include "cullpipe/bvh/binned_sah.hpp"
#include "cullpipe/bvh/box_ops.hpp"
#include "cullpipe/bvh/builders.hpp"

namespace cullpipe::bvh {

using detail::empty_box;
using detail::grow;
using detail::half_area;

namespace {

// The nodes reachable from the root in pre-order (a parent before its children), into `order`,
// so the reverse visits children before parents whatever the index order. Throws on a child
// index out of range or a node reached twice (a cycle or a shared subtree), which would
// otherwise make the callers loop or double-count. `seen` and `stack` are working memory.
void preorder(const Tree& tree, std::vector<std::uint32_t>& order, std::vector<char>& seen,
              std::vector<std::uint32_t>& stack) {
  order.clear();
  if (tree.nodes.empty()) return;
  order.reserve(tree.nodes.size());
  seen.assign(tree.nodes.size(), 0);
  stack.assign(1, 0);
  while (!stack.empty()) {
    const std::uint32_t i = stack.back();
    stack.pop_back();
    if (i >= tree.nodes.size()) throw std::invalid_argument("bvh: child index " + std::to_string(i) + " out of range");
    if (seen[i]++) throw std::invalid_argument("bvh: node " + std::to_string(i) + " reached twice");
    order.push_back(i);
    const Node& n = tree.nodes[i];
    if (!n.leaf()) {
      stack.push_back(n.right);
      stack.push_back(n.left);
    }
  }
}

std::vector<std::uint32_t> preorder(const Tree& tree) {
  std::vector<std::uint32_t> order, stack;
  std::vector<char> seen;
  preorder(tree, order, seen, stack);
  return order;
}

}  // namespace

void refit(Tree& tree, std::span<const Aabb> boxes) {
  const std::vector<std::uint32_t> order = preorder(tree);
  for (std::size_t k = order.size(); k-- > 0;) {
    Node& n = tree.nodes[order[k]];
    Aabb box = empty_box();
    if (n.leaf()) {
      for (std::uint32_t j = n.first; j < n.first + n.count; ++j) grow(box, boxes[tree.objects[j]]);
    } else {
      grow(box, tree.nodes[n.left].box);
      grow(box, tree.nodes[n.right].box);
    }
    n.box = box;
  }
}

void refit(FlatTree& tree, std::span<const Aabb> boxes) {
  // Depth-first order: both children of node i have larger indices (i + 1 and nodes[i + 1].skip).
  for (std::size_t i = tree.nodes.size(); i-- > 0;) {
    FlatNode& n = tree.nodes[i];
    Aabb box = empty_box();
    if (n.leaf) {
      for (std::uint32_t j = n.first; j < n.first + n.count; ++j) grow(box, boxes[tree.objects[j]]);
    } else {
      const FlatNode& first_child = tree.nodes[i + 1];
      grow(box, first_child.box);
      grow(box, tree.nodes[first_child.skip].box);
    }
    n.box = box;
  }
}

Tree collapse_leaves(const Tree& tree, std::uint32_t max_leaf_size, float object_cost) {
  Tree out;
  detail::CollapseScratch scratch;
  detail::collapse_leaves(tree, max_leaf_size, object_cost, out, scratch);
  return out;
}

namespace detail {

void collapse_leaves(const Tree& tree, std::uint32_t max_leaf_size, float object_cost, Tree& out, CollapseScratch& s) {
  if (!(object_cost > 0.0f && std::isfinite(object_cost)))
    throw std::invalid_argument("collapse_leaves: object_cost " + std::to_string(object_cost) +
                                " (a positive finite number)");
  out.nodes.clear();
  out.objects.clear();
  if (tree.nodes.empty()) return;
  const std::uint32_t max_leaf = std::max<std::uint32_t>(max_leaf_size, 1);
  preorder(tree, s.order, s.seen, s.stack);

  // Bottom-up: the cheapest cost of each subtree (in half-area units) and whether it is cheapest
  // as one leaf. A leaf costs area x objects x object_cost, an inner node area + its children's
  // costs.
  s.cost.assign(tree.nodes.size(), 0.0);
  s.count.assign(tree.nodes.size(), 0);
  s.as_leaf.assign(tree.nodes.size(), 0);
  for (std::size_t k = s.order.size(); k-- > 0;) {
    const std::uint32_t i = s.order[k];
    const Node& n = tree.nodes[i];
    const double area = half_area(n.box);
    if (n.leaf()) {
      s.count[i] = n.count;
      s.cost[i] = area * n.count * double(object_cost);
      s.as_leaf[i] = 1;
      continue;
    }
    s.count[i] = s.count[n.left] + s.count[n.right];
    const double inner = area + s.cost[n.left] + s.cost[n.right];
    const double leaf = area * s.count[i] * double(object_cost);
    if (s.count[i] <= max_leaf && leaf <= inner) {
      s.cost[i] = leaf;
      s.as_leaf[i] = 1;
    } else {
      s.cost[i] = inner;
    }
  }

  // Top-down emission in the layout build_binned_sah uses: root at 0, the two children of a
  // node allocated as a pair when it is reached, left subtree first, so leaf object ranges
  // follow the left-to-right leaf order.
  out.nodes.reserve(tree.nodes.size());
  out.objects.reserve(tree.objects.size());
  s.tasks.assign(1, {0, 0});
  out.nodes.emplace_back();
  while (!s.tasks.empty()) {
    const auto [old_node, new_node] = s.tasks.back();
    s.tasks.pop_back();
    const Node& n = tree.nodes[old_node];
    out.nodes[new_node].box = n.box;
    if (s.as_leaf[old_node]) {
      out.nodes[new_node].first = std::uint32_t(out.objects.size());
      out.nodes[new_node].count = s.count[old_node];
      s.stack.assign(1, old_node);  // the subtree's objects, leftmost leaf first
      while (!s.stack.empty()) {
        const Node& g = tree.nodes[s.stack.back()];
        s.stack.pop_back();
        if (g.leaf()) {
          out.objects.insert(out.objects.end(), tree.objects.begin() + g.first,
                             tree.objects.begin() + g.first + g.count);
        } else {
          s.stack.push_back(g.right);
          s.stack.push_back(g.left);
        }
      }
      continue;
    }
    const std::uint32_t left = std::uint32_t(out.nodes.size());
    out.nodes.emplace_back();
    out.nodes.emplace_back();
    out.nodes[new_node].left = left;
    out.nodes[new_node].right = left + 1;
    s.tasks.push_back({n.right, left + 1});
    s.tasks.push_back({n.left, left});
  }
}

}  // namespace detail

}  // namespace cullpipe::bvh
