#include "bvh/bvh.hpp"

#if defined(__linux__)
#include <sys/mman.h>
#endif

#include <algorithm>
#include <array>
#include <bit>
#include <cmath>
#include <limits>
#include <memory>
#include <stdexcept>
#include <string>
#if defined(__SSE2__)
#include <emmintrin.h>
#endif

#include "bvh/box_ops.hpp"
#include "geom/bv_kind.hpp"
#include "geom/pn_vertex.hpp"
#include "geom/rounding.hpp"
#include "geom/validate.hpp"
#include "geom/volume_tests.hpp"

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

Classification classify_masked_margin(const Aabb& box, const Frustum& frustum, std::uint32_t mask, std::uint32_t& straddled) {
  straddled = 0;
  // Evaluated in this order, as in shaders/cull_bvh.comp (the margin is part of the contract).
  const float reach = std::max(std::abs(box.min.x), std::abs(box.max.x)) + std::max(std::abs(box.min.y), std::abs(box.max.y)) +
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
      throw std::invalid_argument(std::string(who) + ": plane " + std::to_string(k) + " has a normal of length " + std::to_string(length) +
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

namespace {

// The binned builder's working types. Four floats, the fourth unused by the box maths: a box
// corner in one SIMD register where there is SSE2 (every x86-64), plain loops elsewhere;
// both give the same results.
struct alignas(16) Lanes {
  float v[4];
};

// One object as the binned builder works on it: its box, with +infinity in the fourth lane of
// `lo` and its id in the fourth lane of `hi` (never used as a number). Kept
// in tree order, so each pass over a node reads memory sequentially instead of gathering by
// id. 32 bytes.
struct BinRef {
  Lanes lo, hi;
  std::uint32_t id() const { return std::bit_cast<std::uint32_t>(hi.v[3]); }
};

#if defined(__SSE2__)
inline void lanes_min(Lanes& a, const Lanes& b) { _mm_store_ps(a.v, _mm_min_ps(_mm_load_ps(b.v), _mm_load_ps(a.v))); }
inline void lanes_max(Lanes& a, const Lanes& b) { _mm_store_ps(a.v, _mm_max_ps(_mm_load_ps(b.v), _mm_load_ps(a.v))); }
// (lo + hi) * 0.5 per axis, as Aabb::center(); fourth lane 0.
inline Lanes centroid(const BinRef& r) {
  const __m128 xyz = _mm_castsi128_ps(_mm_set_epi32(0, -1, -1, -1));
  Lanes c;
  _mm_store_ps(c.v, _mm_mul_ps(_mm_add_ps(_mm_and_ps(_mm_load_ps(r.lo.v), xyz), _mm_and_ps(_mm_load_ps(r.hi.v), xyz)),
                               _mm_set1_ps(0.5f)));
  return c;
}
// Per axis k < 3: bin index uint32(min((c - lo) * scale, last)); NaN goes to `last`.
inline void bin_indices(const Lanes& c, const Lanes& lo, const Lanes& scale, const Lanes& last, std::uint32_t out[4]) {
  const __m128 x = _mm_mul_ps(_mm_sub_ps(_mm_load_ps(c.v), _mm_load_ps(lo.v)), _mm_load_ps(scale.v));
  _mm_storeu_si128(reinterpret_cast<__m128i*>(out), _mm_cvttps_epi32(_mm_min_ps(x, _mm_load_ps(last.v))));
}
#else
inline void lanes_min(Lanes& a, const Lanes& b) {
  for (int k = 0; k < 4; ++k) a.v[k] = b.v[k] < a.v[k] ? b.v[k] : a.v[k];
}
inline void lanes_max(Lanes& a, const Lanes& b) {
  for (int k = 0; k < 4; ++k) a.v[k] = a.v[k] < b.v[k] ? b.v[k] : a.v[k];
}
inline Lanes centroid(const BinRef& r) {
  return {{(r.lo.v[0] + r.hi.v[0]) * 0.5f, (r.lo.v[1] + r.hi.v[1]) * 0.5f, (r.lo.v[2] + r.hi.v[2]) * 0.5f, 0.0f}};
}
inline void bin_indices(const Lanes& c, const Lanes& lo, const Lanes& scale, const Lanes& last, std::uint32_t out[4]) {
  for (int k = 0; k < 3; ++k) {
    const float x = (c.v[k] - lo.v[k]) * scale.v[k];
    out[k] = std::uint32_t(x < last.v[k] ? x : last.v[k]);
  }
}
#endif

// A box as two corners of Lanes; starts empty.
struct LaneBox {
  Lanes lo{{INFINITY, INFINITY, INFINITY, 0.0f}}, hi{{-INFINITY, -INFINITY, -INFINITY, 0.0f}};
  void grow(const Lanes& min, const Lanes& max) {
    lanes_min(lo, min);
    lanes_max(hi, max);
  }
  void grow(const LaneBox& b) { grow(b.lo, b.hi); }
  Aabb box() const { return {{lo.v[0], lo.v[1], lo.v[2]}, {hi.v[0], hi.v[1], hi.v[2]}}; }
  // half_area(box()) for a non-empty box: the same operations in the same order.
  double half_area() const {
#if defined(__SSE2__)
    const __m128 l = _mm_load_ps(lo.v), h = _mm_load_ps(hi.v);
    const __m128d exy = _mm_sub_pd(_mm_cvtps_pd(h), _mm_cvtps_pd(l));
    // Only the z lanes are converted (the fourth lanes hold ids and counts, not numbers).
    const __m128d ezw = _mm_sub_pd(_mm_cvtss_sd(_mm_setzero_pd(), _mm_movehl_ps(h, h)),
                                   _mm_cvtss_sd(_mm_setzero_pd(), _mm_movehl_ps(l, l)));
    const __m128d p = _mm_mul_pd(exy, _mm_shuffle_pd(exy, ezw, 1));  // (ex * ey, ey * ez)
    return _mm_cvtsd_f64(_mm_add_sd(_mm_add_sd(p, _mm_unpackhi_pd(p, p)), _mm_mul_sd(ezw, exy)));
#else
    const double ex = double(hi.v[0]) - double(lo.v[0]), ey = double(hi.v[1]) - double(lo.v[1]),
                 ez = double(hi.v[2]) - double(lo.v[2]);
    return ex * ey + ey * ez + ez * ex;
#endif
  }
};

// Asks the kernel to back the 2 MiB-aligned part of [p, p + bytes) with transparent huge
// pages: a million-object build touches ~100 MB of fresh memory, and with 4 KiB pages the page
// faults alone cost several percent. A hint only (no effect where THP is off or elsewhere).
void advise_huge_pages(void* p, std::size_t bytes) {
#if defined(__linux__) && defined(MADV_HUGEPAGE)
  constexpr std::uintptr_t kHuge = std::uintptr_t(2) << 20;
  const std::uintptr_t begin = (reinterpret_cast<std::uintptr_t>(p) + kHuge - 1) & ~(kHuge - 1);
  const std::uintptr_t end = (reinterpret_cast<std::uintptr_t>(p) + bytes) & ~(kHuge - 1);
  if (end > begin) madvise(reinterpret_cast<void*>(begin), end - begin, MADV_HUGEPAGE);
#else
  (void)p;
  (void)bytes;
#endif
}

// The box and the centroid box of objects [0, count).
void bounds_of(const BinRef* refs, std::uint32_t count, LaneBox& box, LaneBox& centroids) {
  for (std::uint32_t i = 0; i < count; ++i) {
    box.grow(refs[i].lo, refs[i].hi);
    const Lanes c = centroid(refs[i]);
    centroids.grow(c, c);
  }
}

}  // namespace

// Implementation notes (the tree is fixed by the description in bvh.hpp; these only make it
// fast): objects are copied once into 32-byte BinRef records, and a split moves its node's
// records into the other of two buffers (stable, branch-free), so every pass reads memory in
// order; one pass per node bins all three axes at once; the children's boxes are unions of
// the chosen bins and their centroid boxes are gathered while the records move, so no node
// is scanned again to find its bounds; the SAH sweep visits only non-empty bins (an empty bin
// repeats the cost of the split before it, which is tried first and kept on ties); the
// binning pass saves each record's three bin indices, so the partition reads a byte instead of
// recomputing a centroid (206 -> 178 ms at 10^6 objects); bin counts are integers beside the
// bin boxes; the large buffers ask for transparent huge pages (220 -> 206 ms, page faults).
Tree build_binned_sah(std::span<const Aabb> boxes, const TopDownOptions& options) {
  Tree tree;
  const std::size_t n = boxes.size();
  if (n == 0) return tree;
  const std::uint32_t max_leaf = std::max<std::uint32_t>(options.max_leaf_size, 1);
  const std::uint32_t bins = std::clamp<std::uint32_t>(options.bins, 2, 256);
  // Two buffers of records, left uninitialised (they are written before they are read).
  std::unique_ptr<BinRef[]> buffer[2] = {std::unique_ptr<BinRef[]>(new BinRef[n]),
                                         std::unique_ptr<BinRef[]>(n > max_leaf ? new BinRef[n] : nullptr)};
  advise_huge_pages(buffer[0].get(), n * sizeof(BinRef));
  if (buffer[1]) advise_huge_pages(buffer[1].get(), n * sizeof(BinRef));
  LaneBox root_box, root_centroids;
  for (std::size_t i = 0; i < n; ++i) {
    const Aabb& b = boxes[i];
    BinRef& r = buffer[0][i];
    r = {{{b.min.x, b.min.y, b.min.z, INFINITY}},
         {{b.max.x, b.max.y, b.max.z, std::bit_cast<float>(std::uint32_t(i))}}};
    root_box.grow(r.lo, r.hi);
    const Lanes c = centroid(r);
    root_centroids.grow(c, c);
  }
  tree.objects.resize(n);

  struct Task {
    std::uint32_t node, first, count;
    std::uint32_t buffer;  // which buffer holds the node's records
    LaneBox centroids;     // the box of the node's centroids (its box is in tree.nodes)
  };
  tree.nodes.reserve(2 * n);  // at most 2n - 1; pages never touched cost nothing
  advise_huge_pages(tree.nodes.data(), tree.nodes.capacity() * sizeof(Node));
  tree.nodes.emplace_back();
  tree.nodes[0].box = root_box.box();
  std::vector<Task> stack;
  // A node of at most max_leaf objects becomes a leaf at once; others wait on the stack.
  const auto add = [&](std::uint32_t node, std::uint32_t first, std::uint32_t count, std::uint32_t in,
                       const LaneBox& centroids) {
    if (count > max_leaf) {
      stack.push_back({node, first, count, in, centroids});
      return;
    }
    tree.nodes[node].first = first;
    tree.nodes[node].count = count;
    const BinRef* objs = buffer[in].get() + first;
    for (std::uint32_t i = 0; i < count; ++i) tree.objects[first + i] = objs[i].id();
  };
  add(0, 0, std::uint32_t(n), 0, root_centroids);
  // Bins of axis a are bin[a * bins, (a + 1) * bins), each a box, and their object counts
  // bin_count[a * bins + b] (integers beside the boxes: packing them into a spare float lane
  // cost masking on every add); all empty between nodes.
  std::vector<LaneBox> bin(3 * std::size_t(bins));
  std::vector<std::uint32_t> bin_count(3 * std::size_t(bins), 0);
  std::vector<std::uint32_t> used(3 * std::size_t(bins));  // non-empty bins per axis, ascending
  std::uint32_t used_count[3];
  std::vector<double> right_area(bins);
  // The three bin indices of each record of the node being split (a byte each, bins <= 256),
  // saved by the binning pass so the partition does not recompute them.
  std::unique_ptr<std::uint32_t[]> bin_of(new std::uint32_t[n]);
  std::vector<std::uint32_t> right_count(bins);
  const float last_bin = float(bins - 1);
  while (!stack.empty()) {
    const Task task = stack.back();
    stack.pop_back();
    BinRef* objs = buffer[task.buffer].get() + task.first;
    // Bin the centroids along all three axes in one pass; a flat axis (zero or subnormal
    // extent) is binned with scale 0 (everything in bin 0) and not considered.
    Lanes lo{{0, 0, 0, 0}}, scale{{0, 0, 0, 0}}, last{{last_bin, last_bin, last_bin, 0}};
    bool usable[3];
    for (int axis = 0; axis < 3; ++axis) {
      lo.v[axis] = task.centroids.lo.v[axis];
      const float extent = task.centroids.hi.v[axis] - lo.v[axis];
      scale.v[axis] = float(bins) / extent;
      usable[axis] = extent > 0.0f && std::isfinite(extent) && std::isfinite(scale.v[axis]);
      if (!usable[axis]) scale.v[axis] = 0.0f;
    }
    for (std::uint32_t i = 0; i < task.count; ++i) {
      const BinRef& r = objs[i];
      std::uint32_t index[4];
      bin_indices(centroid(r), lo, scale, last, index);
      bin_of[i] = index[0] | index[1] << 8 | index[2] << 16;
      for (int axis = 0; axis < 3; ++axis) {
        const std::size_t b = std::size_t(axis) * bins + index[axis];
        lanes_min(bin[b].lo, r.lo);
        lanes_max(bin[b].hi, r.hi);
        ++bin_count[b];
      }
    }
    for (int axis = 0; axis < 3; ++axis) {
      std::uint32_t* list = used.data() + std::size_t(axis) * bins;
      std::uint32_t k = 0;
      for (std::uint32_t b = 0; b < bins; ++b) {  // branch-free: which bins are used is random
        list[k] = b;
        k += bin_count[std::size_t(axis) * bins + b] != 0;
      }
      used_count[axis] = k;
    }
    // Best binned SAH split over the three axes: bins [0, best_split] go left.
    double best_cost = INFINITY;
    int best_axis = -1;
    std::uint32_t best_split = 0;
    for (int axis = 0; axis < 3; ++axis) {
      if (!usable[axis]) continue;
      const LaneBox* axis_bin = bin.data() + std::size_t(axis) * bins;
      const std::uint32_t* axis_count = bin_count.data() + std::size_t(axis) * bins;
      const std::uint32_t* list = used.data() + std::size_t(axis) * bins;
      const std::uint32_t k = used_count[axis];
      // right_area[j] / right_count[j]: the union of used bins list[j..k-1].
      LaneBox acc;
      std::uint32_t cnt = 0;
      for (std::uint32_t j = k; j-- > 1;) {
        acc.grow(axis_bin[list[j]]);
        cnt += axis_count[list[j]];
        right_area[j] = acc.half_area();
        right_count[j] = cnt;
      }
      acc = LaneBox{};
      cnt = 0;
      for (std::uint32_t j = 0; j + 1 < k; ++j) {
        acc.grow(axis_bin[list[j]]);
        cnt += axis_count[list[j]];
        const double cost = acc.half_area() * cnt + right_area[j + 1] * right_count[j + 1];
        if (cost < best_cost) best_cost = cost, best_axis = axis, best_split = list[j];
      }
    }
    std::uint32_t mid = 0, child_buffer = task.buffer;
    LaneBox left_box, right_box, left_centroids, right_centroids;
    if (best_axis >= 0) {
      const int axis = best_axis;
      const LaneBox* axis_bin = bin.data() + std::size_t(axis) * bins;
      const std::uint32_t* list = used.data() + std::size_t(axis) * bins;
      for (std::uint32_t j = 0; j < used_count[axis]; ++j) {
        const std::uint32_t b = list[j];
        if (b <= best_split) mid += bin_count[std::size_t(axis) * bins + b];
        (b <= best_split ? left_box : right_box).grow(axis_bin[b]);
      }
      // Stable partition into the other buffer, bins [0, best_split] to the front, gathering
      // each side's centroid box on the way.
      child_buffer = 1 - task.buffer;
      BinRef* out = buffer[child_buffer].get() + task.first;
      LaneBox left_side, right_side;
      std::uint32_t l = 0, r = mid;
      for (std::uint32_t i = 0; i < task.count; ++i) {
        const BinRef& ref = objs[i];
        const std::uint32_t go_left = (bin_of[i] >> (8 * axis) & 0xffu) <= best_split;
        const std::uint32_t at = r + (l - r) * go_left;  // l or r, without a branch to mispredict
        out[at] = ref;
        const Lanes c = centroid(ref);
        (go_left ? left_side : right_side).grow(c, c);
        l += go_left;
        r += go_left ^ 1u;
      }
      left_centroids = left_side;
      right_centroids = right_side;
      if (l != mid || r != task.count) throw std::logic_error("build_binned_sah: bin counts disagree with the partition");
    }
    // Empty the bins for the next node.
    for (int axis = 0; axis < 3; ++axis)
      for (std::uint32_t j = 0; j < used_count[axis]; ++j) {
        const std::size_t b = std::size_t(axis) * bins + used[std::size_t(axis) * bins + j];
        bin[b] = LaneBox{};
        bin_count[b] = 0;
      }
    if (mid == 0 || mid == task.count) {  // equal centroids: split the range in half (by id, deterministic)
      mid = task.count / 2;
      child_buffer = task.buffer;
      std::sort(objs, objs + task.count, [](const BinRef& x, const BinRef& y) { return x.id() < y.id(); });
      left_box = right_box = left_centroids = right_centroids = LaneBox{};
      bounds_of(objs, mid, left_box, left_centroids);
      bounds_of(objs + mid, task.count - mid, right_box, right_centroids);
    }
    const std::uint32_t left = std::uint32_t(tree.nodes.size());
    tree.nodes.emplace_back();
    tree.nodes.emplace_back();
    tree.nodes[task.node].left = left;
    tree.nodes[task.node].right = left + 1;
    tree.nodes[left].box = left_box.box();
    tree.nodes[left + 1].box = right_box.box();
    add(left + 1, task.first + mid, task.count - mid, child_buffer, right_centroids);
    add(left, task.first, mid, child_buffer, left_centroids);
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
      out.objects.insert(out.objects.end(), tree.objects.begin() + node.first, tree.objects.begin() + node.first + node.count);
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
    return "the tree orders " + std::to_string(tree.objects.size()) + " objects, but " + std::to_string(n) + " " + kind + " were given";
  if ((nodes == 0) != (n == 0)) return nodes ? "a tree over no objects must have no nodes" : "no nodes for " + std::to_string(n) + " objects";
  std::vector<char> seen(n, 0);
  for (std::uint32_t o : tree.objects) {
    if (o >= n) return "object id " + std::to_string(o) + " out of range (" + std::to_string(n) + " objects)";
    if (seen[o]++) return "object id " + std::to_string(o) + " appears twice";
  }
  if (volumes)  // (before the leaves' checks, which assume valid volumes for their message)
    for (std::size_t i = 0; i < n; ++i)
      if (!is_valid(volumes[i])) return std::string(to_string(kind_of<Volume>())) + " " + std::to_string(i) + ": " + invalid_reason(volumes[i]);
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
      if (volumes && !visit_leaf_volumes<true>(tree, std::span<const Volume>(volumes, n), i, i + 1, [&](std::size_t k, const Volume&) { failed = k + 1; }))
        return at + "box does not enclose " + std::string(to_string(kind_of<Volume>())) + " " + std::to_string(tree.objects[failed]) +
               (std::is_same_v<Volume, Aabb> ? "" : " (build the tree over bvh::enclosing_boxes)");
    } else {
      if (i + 1 >= node.skip) return at + "inner node without children";
      const std::uint32_t second = tree.nodes[i + 1].skip;
      if (second <= i + 1 || second >= node.skip) return at + "second child " + std::to_string(second) + " out of range";
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
      for (std::uint32_t k = node.first; k < node.first + node.count; ++k) r.classes[tree.objects[k]] = Classification::Inside;
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
    r.visible += c != Classification::Outside;
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
