#include "bvh/bvh.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <numeric>

#include "geom/pn_vertex.hpp"

namespace cullpipe::bvh {
namespace {

Aabb empty_box() { return {glm::vec3(INFINITY), glm::vec3(-INFINITY)}; }

void grow(Aabb& a, const Aabb& b) {
  a.min = glm::min(a.min, b.min);
  a.max = glm::max(a.max, b.max);
}

void grow(Aabb& a, const glm::vec3& p) {
  a.min = glm::min(a.min, p);
  a.max = glm::max(a.max, p);
}

// Half the surface area, in double (only ratios matter).
double half_area(const Aabb& b) {
  if (!(b.min.x <= b.max.x)) return 0.0;
  const glm::dvec3 e = glm::dvec3(b.max) - glm::dvec3(b.min);
  return e.x * e.y + e.y * e.z + e.z * e.x;
}

bool encloses(const Aabb& outer, const Aabb& inner) {
  return glm::all(glm::lessThanEqual(outer.min, inner.min)) && glm::all(glm::lessThanEqual(inner.max, outer.max));
}

// The p/n-vertex test of one box against the planes in `mask` (bit k = plane k); `straddled`
// receives the planes the box crosses (its children must still test those).
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

}  // namespace

Tree build_binned_sah(std::span<const Aabb> boxes, const TopDownOptions& options) {
  Tree tree;
  const std::size_t n = boxes.size();
  if (n == 0) return tree;
  const std::uint32_t max_leaf = std::max<std::uint32_t>(options.max_leaf_size, 1);
  const std::uint32_t bins = std::clamp<std::uint32_t>(options.bins, 2, 256);
  tree.objects.resize(n);
  std::iota(tree.objects.begin(), tree.objects.end(), 0u);
  std::vector<glm::vec3> centroid(n);
  for (std::size_t i = 0; i < n; ++i) centroid[i] = boxes[i].center();

  struct Task {
    std::uint32_t node, first, count;
  };
  tree.nodes.emplace_back();
  std::vector<Task> stack{{0, 0, std::uint32_t(n)}};
  struct Bin {
    Aabb box;
    std::uint32_t count;
  };
  std::vector<Bin> bin(bins);
  std::vector<double> right_area(bins);
  std::vector<std::uint32_t> right_count(bins);
  while (!stack.empty()) {
    const Task task = stack.back();
    stack.pop_back();
    std::uint32_t* objs = tree.objects.data() + task.first;
    Aabb box = empty_box(), cbox = empty_box();
    for (std::uint32_t i = 0; i < task.count; ++i) {
      grow(box, boxes[objs[i]]);
      grow(cbox, centroid[objs[i]]);
    }
    tree.nodes[task.node].box = box;
    if (task.count <= max_leaf) {
      tree.nodes[task.node].first = task.first;
      tree.nodes[task.node].count = task.count;
      continue;
    }
    // Best binned SAH split over the three axes.
    double best_cost = INFINITY;
    int best_axis = -1;
    std::uint32_t best_split = 0;  // bins [0, best_split] go left
    for (int axis = 0; axis < 3; ++axis) {
      const float lo = cbox.min[axis], extent = cbox.max[axis] - cbox.min[axis];
      if (!(extent > 0.0f)) continue;
      const float scale = float(bins) / extent;
      if (!std::isfinite(scale)) continue;  // a subnormal extent: treat the axis as flat
      for (Bin& b : bin) b = {empty_box(), 0};
      for (std::uint32_t i = 0; i < task.count; ++i) {
        const std::uint32_t b = std::min(bins - 1, std::uint32_t((centroid[objs[i]][axis] - lo) * scale));
        grow(bin[b].box, boxes[objs[i]]);
        ++bin[b].count;
      }
      Aabb acc = empty_box();
      std::uint32_t cnt = 0;
      for (std::uint32_t b = bins - 1; b > 0; --b) {
        grow(acc, bin[b].box);
        cnt += bin[b].count;
        right_area[b] = half_area(acc);
        right_count[b] = cnt;
      }
      acc = empty_box();
      cnt = 0;
      for (std::uint32_t b = 0; b + 1 < bins; ++b) {
        grow(acc, bin[b].box);
        cnt += bin[b].count;
        if (cnt == 0 || right_count[b + 1] == 0) continue;
        const double cost = half_area(acc) * cnt + right_area[b + 1] * right_count[b + 1];
        if (cost < best_cost) best_cost = cost, best_axis = axis, best_split = b;
      }
    }
    std::uint32_t mid = 0;
    if (best_axis >= 0) {
      const int axis = best_axis;
      const float lo = cbox.min[axis], scale = float(bins) / (cbox.max[axis] - cbox.min[axis]);
      std::uint32_t* m = std::partition(objs, objs + task.count, [&](std::uint32_t o) {
        return std::min(bins - 1, std::uint32_t((centroid[o][axis] - lo) * scale)) <= best_split;
      });
      mid = std::uint32_t(m - objs);
    }
    if (mid == 0 || mid == task.count) {  // equal centroids: split the range in half (by id, deterministic)
      mid = task.count / 2;
      std::sort(objs, objs + task.count);
    }
    const std::uint32_t left = std::uint32_t(tree.nodes.size());
    tree.nodes.emplace_back();
    tree.nodes.emplace_back();
    tree.nodes[task.node].left = left;
    tree.nodes[task.node].right = left + 1;
    stack.push_back({left + 1, task.first + mid, task.count - mid});
    stack.push_back({left, task.first, mid});
  }
  return tree;
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

std::string check_tree(const Tree& tree, std::span<const Aabb> boxes) {
  if (boxes.empty()) return tree.nodes.empty() && tree.objects.empty() ? "" : "a tree over no objects must be empty";
  if (tree.nodes.empty()) return "no nodes";
  std::vector<std::uint32_t> seen(boxes.size(), 0);
  std::vector<char> visited(tree.nodes.size(), 0);
  std::vector<std::uint32_t> stack{0};
  while (!stack.empty()) {
    const std::uint32_t i = stack.back();
    stack.pop_back();
    const std::string at = "node " + std::to_string(i) + ": ";
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
      out.objects.insert(out.objects.end(), tree.objects.begin() + node.first, tree.objects.begin() + node.first + node.count);
    } else {
      const std::uint32_t left = node.left, right = node.right;  // f is invalidated by the pushes
      stack.push_back({right, 0, false});
      stack.push_back({left, 0, false});
    }
  }
  return out;
}

HierarchicalResult cull_hierarchical(const FlatTree& tree, std::span<const Aabb> boxes, const Frustum& frustum) {
  HierarchicalResult r;
  r.classes.assign(boxes.size(), Classification::Outside);
  if (tree.nodes.empty()) return r;
  const std::uint32_t all = (1u << frustum.active().size()) - 1u;
  std::vector<std::pair<std::uint32_t, std::uint32_t>> stack{{0, all}};  // (node, planes to test)
  while (!stack.empty()) {
    const auto [i, mask] = stack.back();
    stack.pop_back();
    const FlatNode& node = tree.nodes[i];
    ++r.node_tests;
    std::uint32_t straddled = 0;
    const Classification c = classify_masked(node.box, frustum, mask, straddled);
    if (c == Classification::Outside) continue;
    if (c == Classification::Inside) {  // the whole range, no further tests
      for (std::uint32_t k = node.first; k < node.first + node.count; ++k) r.classes[tree.objects[k]] = Classification::Inside;
      continue;
    }
    if (node.leaf) {
      for (std::uint32_t k = node.first; k < node.first + node.count; ++k) {
        std::uint32_t unused = 0;
        r.classes[tree.objects[k]] = classify_masked(boxes[tree.objects[k]], frustum, straddled, unused);
        ++r.object_tests;
      }
      continue;
    }
    const std::uint32_t first_child = i + 1, second_child = tree.nodes[i + 1].skip;
    stack.push_back({second_child, straddled});
    stack.push_back({first_child, straddled});
  }
  for (Classification c : r.classes) {
    r.visible += c != Classification::Outside;
    r.inside += c == Classification::Inside;
  }
  return r;
}

}  // namespace cullpipe::bvh
