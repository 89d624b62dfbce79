#include "cullpipe/bvh/bvh.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <stdexcept>
#include <string>

#include "cullpipe/bvh/box_ops.hpp"
#include "cullpipe/geom/bv_kind.hpp"
#include "cullpipe/geom/pn_vertex.hpp"
#include "cullpipe/geom/rounding.hpp"
#include "cullpipe/geom/validate.hpp"
#include "cullpipe/geom/volume_tests.hpp"

namespace cullpipe::bvh {

using detail::encloses;
using detail::half_area;

Classification classify_masked(const Aabb& box, const Frustum& frustum, std::uint32_t mask, std::uint32_t& straddled) {
  straddled = 0;
  const auto planes = frustum.active();
  for (std::uint32_t k = 0; k < planes.size(); ++k) {
    if (!(mask & (1u << k))) continue;
    const Plane& plane = planes[k];
    const PnVertices v = pn_vertices(plane.normal, box);
    if (plane.distance(v.p) < 0.0f) return Classification::Outside;
    if (plane.distance(v.n) < 0.0f) straddled |= 1u << k;
  }
  return straddled ? Classification::Intersecting : Classification::Inside;
}

Classification classify_masked_margin(const Aabb& box, const Frustum& frustum, std::uint32_t mask,
                                      std::uint32_t& straddled) {
  straddled = 0;
  // Evaluated in this order, as in shaders/cull_bvh.comp (the margin is part of the contract:
  // docs/numerics.md, BVH node margins).
  const float reach = std::max(std::abs(box.min.x), std::abs(box.max.x)) +
                      std::max(std::abs(box.min.y), std::abs(box.max.y)) +
                      std::max(std::abs(box.min.z), std::abs(box.max.z));
  const auto planes = frustum.active();
  for (std::uint32_t k = 0; k < planes.size(); ++k) {
    if (!(mask & (1u << k))) continue;
    const Plane& plane = planes[k];
    const float size = reach + std::abs(plane.d);
    // Beyond 2^120 a distance could overflow, and the error bound with it: decide nothing
    // (also when `size` is NaN).
    const bool certain = size <= kBvhMarginLimit;
    const float margin = kBvhMarginScale * size + kBvhMarginFloor;
    const PnVertices v = pn_vertices(plane.normal, box);
    if (certain && plane.distance(v.p) < -margin) return Classification::Outside;
    if (!certain || plane.distance(v.n) < margin) straddled |= 1u << k;
  }
  return straddled ? Classification::Intersecting : Classification::Inside;
}

void require_unit_normals(const Frustum& frustum, const char* who) {
  for (std::size_t k = 0; k < frustum.active().size(); ++k) {
    const glm::vec3& n = frustum.planes[k].normal;
    const double length = std::sqrt(double(n.x) * n.x + double(n.y) * n.y + double(n.z) * n.z);
    if (!(std::abs(length - 1.0) <= kBvhUnitNormalTolerance))
      throw std::invalid_argument(
          std::string(who) + ": plane " + std::to_string(k) + " has a normal of length " + std::to_string(length) +
          "; hierarchies over OBBs and spheres need unit normals (Frustum::from_planes normalises)");
  }
}

Classification classify_object(const Aabb& box, const Frustum& frustum, std::uint32_t mask) {
  std::uint32_t unused = 0;
  return classify_masked(box, frustum, mask, unused);
}

Classification classify_object(const Obb& box, const Frustum& frustum, std::uint32_t mask) {
  return classify_planes(box, frustum, mask);
}

Classification classify_object(const Sphere& sphere, const Frustum& frustum, std::uint32_t mask) {
  return classify_planes(sphere, frustum, mask);
}

namespace {

// One float step below round_down(v) / above round_up(v): the double arithmetic before the
// rounding may itself have rounded, by far less than a float step.
float below(double v) { return float_below(round_down(v)); }
float above(double v) { return float_above(round_up(v)); }

}  // namespace

Aabb enclosing_box(const Obb& box) {
  Aabb out;
  for (int j = 0; j < 3; ++j) {
    double extent = 0.0;
    for (int i = 0; i < 3; ++i) extent += std::abs(double(box.basis[i][j])) * double(box.half_extents[i]);
    // The sum may have rounded down by a double step of `extent`, which the float step after
    // the subtraction below need not cover (when the centre nearly cancels it): round it up.
    extent *= 1.0 + 0x1p-50;
    out.min[j] = below(double(box.center[j]) - extent);
    out.max[j] = above(double(box.center[j]) + extent);
  }
  return out;
}

Aabb enclosing_box(const Sphere& sphere) {
  Aabb out;
  for (int j = 0; j < 3; ++j) {
    out.min[j] = below(double(sphere.center[j]) - double(sphere.radius));
    out.max[j] = above(double(sphere.center[j]) + double(sphere.radius));
  }
  return out;
}

Metrics metrics(const Tree& tree) {
  Metrics m;
  if (tree.nodes.empty()) return m;
  const double root = std::max(half_area(tree.nodes[0].box), 1e-300);
  std::vector<std::pair<std::uint32_t, std::size_t>> stack{{0, 1}};
  while (!stack.empty()) {
    const auto [i, depth] = stack.back();
    stack.pop_back();
    const Node& node = tree.nodes[i];
    ++m.nodes;
    m.depth = std::max(m.depth, depth);
    const double ratio = half_area(node.box) / root;
    if (node.leaf()) {
      ++m.leaves;
      m.max_leaf_size = std::max<std::size_t>(m.max_leaf_size, node.count);
      m.sah_cost += ratio * node.count;
    } else {
      m.sah_cost += ratio;
      stack.push_back({node.left, depth + 1});
      stack.push_back({node.right, depth + 1});
    }
  }
  return m;
}

namespace {

// "node i: " + what, formatted only when there is a message (the checks run per upload).
struct NodePrefix {
  std::size_t i;
  std::string operator+(const std::string& what) const { return "node " + std::to_string(i) + ": " + what; }
};

}  // namespace

std::string check_tree(const Tree& tree, std::span<const Aabb> boxes) {
  if (boxes.empty()) return tree.nodes.empty() && tree.objects.empty() ? "" : "a tree over no objects must be empty";
  if (tree.nodes.empty()) return "no nodes";
  std::vector<std::uint32_t> seen(boxes.size(), 0);
  std::vector<char> visited(tree.nodes.size(), 0);
  std::vector<std::uint32_t> stack{0};
  while (!stack.empty()) {
    const std::uint32_t i = stack.back();
    stack.pop_back();
    const NodePrefix at{i};
    if (i >= tree.nodes.size()) return at + "does not exist";
    if (visited[i]++) return at + "reached twice";
    const Node& node = tree.nodes[i];
    if (node.leaf()) {
      if (node.right != kNone) return at + "leaf with a right child";
      if (std::size_t(node.first) + node.count > tree.objects.size()) return at + "object range past the object list";
      for (std::uint32_t k = node.first; k < node.first + node.count; ++k) {
        const std::uint32_t o = tree.objects[k];
        if (o >= boxes.size()) return at + "object id " + std::to_string(o) + " out of range";
        if (seen[o]++) return at + "object " + std::to_string(o) + " is in two leaves";
        if (!encloses(node.box, boxes[o])) return at + "box does not enclose object " + std::to_string(o);
      }
    } else {
      if (node.right == kNone) return at + "inner node without a right child";
      for (std::uint32_t c : {node.left, node.right}) {
        if (c >= tree.nodes.size()) return at + "child " + std::to_string(c) + " does not exist";
        if (!encloses(node.box, tree.nodes[c].box)) return at + "box does not enclose child " + std::to_string(c);
        stack.push_back(c);
      }
    }
  }
  for (std::size_t o = 0; o < boxes.size(); ++o)
    if (!seen[o]) return "object " + std::to_string(o) + " is in no leaf";
  return "";
}

FlatTree flatten(const Tree& tree) {
  FlatTree out;
  if (tree.nodes.empty()) return out;
  out.nodes.reserve(tree.nodes.size());
  out.objects.reserve(tree.objects.size());
  struct Frame {
    std::uint32_t node, flat;
    bool entered;
  };
  std::vector<Frame> stack{{0, 0, false}};
  while (!stack.empty()) {
    Frame& f = stack.back();
    if (f.entered) {  // leaving: the subtree is complete
      FlatNode& flat = out.nodes[f.flat];
      flat.count = std::uint32_t(out.objects.size()) - flat.first;
      flat.skip = std::uint32_t(out.nodes.size());
      stack.pop_back();
      continue;
    }
    f.entered = true;
    f.flat = std::uint32_t(out.nodes.size());
    const Node& node = tree.nodes[f.node];
    FlatNode flat;
    flat.box = node.box;
    flat.first = std::uint32_t(out.objects.size());
    flat.leaf = node.leaf();
    out.nodes.push_back(flat);
    if (node.leaf()) {
      out.objects.insert(out.objects.end(), tree.objects.begin() + node.first,
                         tree.objects.begin() + node.first + node.count);
    } else {
      const std::uint32_t left = node.left, right = node.right;  // f is invalidated by the pushes
      stack.push_back({right, 0, false});
      stack.push_back({left, 0, false});
    }
  }
  return out;
}

namespace {

// check_flat_tree over `n` objects; without volumes (check_flat_structure: with_volumes false,
// `volumes` unread), without the volumes' validity and the leaves' enclosure of them.
template <class Volume>
std::string check_flat_tree_impl(const FlatTree& tree, std::size_t n, const Volume* all_volumes, bool with_volumes,
                                 std::vector<std::uint32_t>* depth_out) {
  const Volume* const volumes = with_volumes && n ? all_volumes : nullptr;  // (nothing to check without objects)
  const std::size_t nodes = tree.nodes.size();
  const std::string kind = with_volumes ? std::string(to_string(kind_of<Volume>())) + " volumes" : "objects";
  if (tree.objects.size() != n)
    return "the tree orders " + std::to_string(tree.objects.size()) + " objects, but " + std::to_string(n) + " " +
           kind + " were given";
  if ((nodes == 0) != (n == 0))
    return nodes ? "a tree over no objects must have no nodes" : "no nodes for " + std::to_string(n) + " objects";
  std::vector<char> seen(n, 0);
  for (std::uint32_t o : tree.objects) {
    if (o >= n) return "object id " + std::to_string(o) + " out of range (" + std::to_string(n) + " objects)";
    if (seen[o]++) return "object id " + std::to_string(o) + " appears twice";
  }
  if (volumes)  // (before the leaves' checks, which assume valid volumes for their message)
    for (std::size_t i = 0; i < n; ++i)
      if (!is_valid(volumes[i]))
        return std::string(to_string(kind_of<Volume>())) + " " + std::to_string(i) + ": " + invalid_reason(volumes[i]);
  // Depth of every node: children follow their parent in depth-first order.
  std::vector<std::uint32_t> depth(nodes, 0);
  if (nodes) {
    depth[0] = 1;
    if (tree.nodes[0].first != 0 || tree.nodes[0].count != n || tree.nodes[0].skip != nodes)
      return "the root must cover every object and every node";
  }
  for (std::size_t i = 0; i < nodes; ++i) {
    const FlatNode& node = tree.nodes[i];
    const NodePrefix at{i};
    if (depth[i] == 0) return at + "not reachable from the root in depth-first order";
    if (node.skip <= i || node.skip > nodes) return at + "skip index " + std::to_string(node.skip) + " out of range";
    if (std::size_t(node.first) + node.count > n) return at + "object range past the object list";
    if (!is_valid(node.box)) return at + "invalid box: " + invalid_reason(node.box);
    if (node.leaf) {
      if (node.skip != i + 1) return at + "leaf whose skip is not the next node";
      std::size_t failed = node.first;  // past the last volume that passed
      // (every volume passed is_valid above)
      if (volumes && !visit_leaf_volumes<true>(tree, std::span<const Volume>(volumes, n), i, i + 1,
                                               [&](std::size_t k, const Volume&) { failed = k + 1; }))
        return at + "box does not enclose " + std::string(to_string(kind_of<Volume>())) + " " +
               std::to_string(tree.objects[failed]) +
               (std::is_same_v<Volume, Aabb> ? "" : " (build the tree over bvh::enclosing_boxes)");
    } else {
      if (i + 1 >= node.skip) return at + "inner node without children";
      const std::uint32_t second = tree.nodes[i + 1].skip;
      if (second <= i + 1 || second >= node.skip)
        return at + "second child " + std::to_string(second) + " out of range";
      const FlatNode &a = tree.nodes[i + 1], &b = tree.nodes[second];
      if (b.skip != node.skip) return at + "more than two children";
      if (a.first != node.first || b.first != a.first + a.count || std::size_t(a.count) + b.count != node.count)
        return at + "children's object ranges do not split the node's";
      if (!encloses(node.box, a.box) || !encloses(node.box, b.box)) return at + "box does not enclose its children";
      depth[i + 1] = depth[second] = depth[i] + 1;
    }
  }
  if (depth_out) *depth_out = std::move(depth);
  return {};
}

}  // namespace

std::string check_flat_tree(const FlatTree& tree, std::span<const Aabb> volumes, std::vector<std::uint32_t>* depth) {
  return check_flat_tree_impl(tree, volumes.size(), volumes.data(), true, depth);
}
std::string check_flat_tree(const FlatTree& tree, std::span<const Obb> volumes, std::vector<std::uint32_t>* depth) {
  return check_flat_tree_impl(tree, volumes.size(), volumes.data(), true, depth);
}
std::string check_flat_tree(const FlatTree& tree, std::span<const Sphere> volumes, std::vector<std::uint32_t>* depth) {
  return check_flat_tree_impl(tree, volumes.size(), volumes.data(), true, depth);
}
bool leaf_encloses(const Aabb& leaf, const Aabb& volume) { return encloses(leaf, volume); }
bool leaf_encloses(const Aabb& leaf, const Obb& volume) { return encloses(leaf, enclosing_box(volume)); }
bool leaf_encloses(const Aabb& leaf, const Sphere& volume) { return encloses(leaf, enclosing_box(volume)); }
bool volume_in_leaf(const Aabb& leaf, const Aabb& volume) { return is_valid(volume) && leaf_encloses(leaf, volume); }
bool volume_in_leaf(const Aabb& leaf, const Obb& volume) { return is_valid(volume) && leaf_encloses(leaf, volume); }
bool volume_in_leaf(const Aabb& leaf, const Sphere& volume) { return is_valid(volume) && leaf_encloses(leaf, volume); }
std::string check_flat_structure(const FlatTree& tree, std::size_t object_count, std::vector<std::uint32_t>* depth) {
  return check_flat_tree_impl(tree, object_count, static_cast<const Aabb*>(nullptr), false, depth);
}

namespace {

template <class Volume>
HierarchicalResult cull_hierarchical_impl(const FlatTree& tree, std::span<const Volume> volumes, const Frustum& frustum,
                                          const TraversalOptions& options) {
  if constexpr (!std::is_same_v<Volume, Aabb>) require_unit_normals(frustum, "bvh::cull_hierarchical");
  HierarchicalResult r;
  r.classes.assign(volumes.size(), Classification::Outside);
  if (tree.nodes.empty()) return r;
  const std::uint32_t all = (1u << frustum.active().size()) - 1u;
  std::vector<std::pair<std::uint32_t, std::uint32_t>> stack{{0, all}};  // (node, planes to test)
  while (!stack.empty()) {
    const auto [i, mask] = stack.back();
    stack.pop_back();
    const FlatNode& node = tree.nodes[i];
    ++r.node_tests;
    std::uint32_t straddled = 0;
    const Classification c = classify_node<Volume>(node.box, frustum, mask, straddled);
    if (c == Classification::Outside) continue;
    if (c == Classification::Inside) {  // the whole range, no further tests
      for (std::uint32_t k = node.first; k < node.first + node.count; ++k)
        r.classes[tree.objects[k]] = Classification::Inside;
      continue;
    }
    if (options.tests_objects_of(node)) {
      for (std::uint32_t k = node.first; k < node.first + node.count; ++k) {
        r.classes[tree.objects[k]] = classify_object(volumes[tree.objects[k]], frustum, straddled);
        ++r.object_tests;
      }
      continue;
    }
    const std::uint32_t first_child = i + 1, second_child = tree.nodes[i + 1].skip;
    stack.push_back({second_child, straddled});
    stack.push_back({first_child, straddled});
  }
  for (Classification c : r.classes) {
    r.visible += is_visible(c);
    r.inside += c == Classification::Inside;
  }
  return r;
}

}  // namespace

HierarchicalResult cull_hierarchical(const FlatTree& tree, std::span<const Aabb> boxes, const Frustum& frustum,
                                     const TraversalOptions& options) {
  return cull_hierarchical_impl(tree, boxes, frustum, options);
}
HierarchicalResult cull_hierarchical(const FlatTree& tree, std::span<const Obb> volumes, const Frustum& frustum,
                                     const TraversalOptions& options) {
  return cull_hierarchical_impl(tree, volumes, frustum, options);
}
HierarchicalResult cull_hierarchical(const FlatTree& tree, std::span<const Sphere> volumes, const Frustum& frustum,
                                     const TraversalOptions& options) {
  return cull_hierarchical_impl(tree, volumes, frustum, options);
}

}  // namespace cullpipe::bvh
