// Refitting node boxes after objects move, and collapsing subtrees into leaves by the SAH.
#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <string>
#include <vector>

#include "cullpipe/bvh/box_ops.hpp"
#include "cullpipe/bvh/builders.hpp"

namespace cullpipe::bvh {

using detail::empty_box;
using detail::grow;
using detail::half_area;

namespace {

// The nodes reachable from the root in pre-order (a parent before its children), so the
// reverse visits children before parents whatever the index order. Throws on a child index
// out of range or a node reached twice (a cycle or a shared subtree), which would otherwise
// make the callers loop or double-count.
std::vector<std::uint32_t> preorder(const Tree& tree) {
  std::vector<std::uint32_t> order;
  if (tree.nodes.empty()) return order;
  order.reserve(tree.nodes.size());
  std::vector<char> seen(tree.nodes.size(), 0);
  std::vector<std::uint32_t> stack{0};
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

Tree collapse_leaves(const Tree& tree, std::uint32_t max_leaf_size) {
  Tree out;
  if (tree.nodes.empty()) return out;
  const std::uint32_t max_leaf = std::max<std::uint32_t>(max_leaf_size, 1);
  const std::vector<std::uint32_t> order = preorder(tree);

  // Bottom-up: the cheapest cost of each subtree (in half-area units) and whether it is cheapest
  // as one leaf. A leaf costs area x objects, an inner node area + its children's costs.
  std::vector<double> cost(tree.nodes.size(), 0.0);
  std::vector<std::uint32_t> count(tree.nodes.size(), 0);
  std::vector<char> as_leaf(tree.nodes.size(), 0);
  for (std::size_t k = order.size(); k-- > 0;) {
    const std::uint32_t i = order[k];
    const Node& n = tree.nodes[i];
    const double area = half_area(n.box);
    if (n.leaf()) {
      count[i] = n.count;
      cost[i] = area * n.count;
      as_leaf[i] = 1;
      continue;
    }
    count[i] = count[n.left] + count[n.right];
    const double inner = area + cost[n.left] + cost[n.right];
    const double leaf = area * count[i];
    if (count[i] <= max_leaf && leaf <= inner) {
      cost[i] = leaf;
      as_leaf[i] = 1;
    } else {
      cost[i] = inner;
    }
  }

  // Top-down emission in the layout build_binned_sah uses: root at 0, the two children of a
  // node allocated as a pair when it is reached, left subtree first, so leaf object ranges
  // follow the left-to-right leaf order.
  out.nodes.reserve(tree.nodes.size());
  out.objects.reserve(tree.objects.size());
  struct Task {
    std::uint32_t old_node, new_node;
  };
  std::vector<Task> stack{{0, 0}};
  std::vector<std::uint32_t> gather;
  out.nodes.emplace_back();
  while (!stack.empty()) {
    const Task task = stack.back();
    stack.pop_back();
    const Node& n = tree.nodes[task.old_node];
    out.nodes[task.new_node].box = n.box;
    if (as_leaf[task.old_node]) {
      out.nodes[task.new_node].first = std::uint32_t(out.objects.size());
      out.nodes[task.new_node].count = count[task.old_node];
      gather.assign(1, task.old_node);  // the subtree's objects, leftmost leaf first
      while (!gather.empty()) {
        const Node& g = tree.nodes[gather.back()];
        gather.pop_back();
        if (g.leaf()) {
          out.objects.insert(out.objects.end(), tree.objects.begin() + g.first,
                             tree.objects.begin() + g.first + g.count);
        } else {
          gather.push_back(g.right);
          gather.push_back(g.left);
        }
      }
      continue;
    }
    const std::uint32_t left = std::uint32_t(out.nodes.size());
    out.nodes.emplace_back();
    out.nodes.emplace_back();
    out.nodes[task.new_node].left = left;
    out.nodes[task.new_node].right = left + 1;
    stack.push_back({n.right, left + 1});
    stack.push_back({n.left, left});
  }
  return out;
}

}  // namespace cullpipe::bvh
