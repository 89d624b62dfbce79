// The generic top-down builder (axis x position x cost) and the extended tree metrics.
#include <algorithm>
#include <cmath>
#include <numeric>
#include <vector>

#include "cullpipe/bvh/box_ops.hpp"
#include "cullpipe/bvh/builders.hpp"

namespace cullpipe::bvh {

using detail::empty_box;
using detail::grow;
using detail::half_area;

namespace {

bool is_empty(const Aabb& b) { return !(b.min.x <= b.max.x && b.min.y <= b.max.y && b.min.z <= b.max.z); }

double volume(const Aabb& b) {
  if (is_empty(b)) return 0.0;
  const glm::dvec3 e = glm::dvec3(b.max) - glm::dvec3(b.min);
  return e.x * e.y * e.z;
}

// Volume of a intersect b (0 when they are disjoint or touch).
double overlap_volume(const Aabb& a, const Aabb& b) {
  if (is_empty(a) || is_empty(b)) return 0.0;
  const glm::dvec3 e = glm::dvec3(glm::min(a.max, b.max)) - glm::dvec3(glm::max(a.min, b.min));
  if (!(e.x > 0.0 && e.y > 0.0 && e.z > 0.0)) return 0.0;
  return e.x * e.y * e.z;
}

// A direction to split along: a coordinate axis (projections are the exact coordinates) or a
// unit vector in double.
struct Direction {
  int axis = -1;  ///< 0, 1, 2, or -1 for `d`
  glm::dvec3 d{0.0};
};

double project(const glm::vec3& c, const Direction& dir) {
  return dir.axis >= 0 ? double(c[dir.axis]) : glm::dot(glm::dvec3(c), dir.d);
}

// Which objects of a node go left.
struct Predicate {
  enum Kind { Threshold, Bin } kind = Threshold;
  Direction dir;
  // Threshold: projection p < t, or p == t and id < pivot_id (a median's tie-break by id).
  double t = 0.0;
  std::uint32_t pivot_id = 0;
  // Bin: bin(p) <= bin. Axis directions bin the float coordinate exactly as
  // build_binned_sah does; other directions bin the double projection.
  std::uint32_t bin = 0;
  float flo = 0.0f, fscale = 0.0f, flast = 0.0f;
  double dlo = 0.0, dscale = 0.0, dlast = 0.0;

  std::uint32_t bin_of(const glm::vec3& c) const {
    if (dir.axis >= 0) {
      const float x = (c[dir.axis] - flo) * fscale;
      return std::uint32_t(x < flast ? x : flast);  // NaN goes to the last bin
    }
    const double x = (project(c, dir) - dlo) * dscale;
    return std::uint32_t(x < dlast ? x : dlast);
  }
  bool left(const glm::vec3& c, std::uint32_t id) const {
    if (kind == Bin) return bin_of(c) <= bin;
    const double p = project(c, dir);
    return p < t || (p == t && id < pivot_id);
  }
};

// One candidate split of a node: which objects go left, and the two children it makes.
struct Candidate {
  Predicate pred;
  Aabb left = empty_box(), right = empty_box();
  std::uint32_t nl = 0, nr = 0;
};

double sah_cost(const Candidate& c) { return half_area(c.left) * c.nl + half_area(c.right) * c.nr; }

// The projected interval of a box on a direction.
void box_interval(const Aabb& b, const Direction& dir, double& lo, double& hi) {
  if (dir.axis >= 0) {
    lo = b.min[dir.axis];
    hi = b.max[dir.axis];
    return;
  }
  const glm::dvec3 c = (glm::dvec3(b.min) + glm::dvec3(b.max)) * 0.5, h = (glm::dvec3(b.max) - glm::dvec3(b.min)) * 0.5;
  const double r = glm::dot(h, glm::abs(dir.d));
  lo = glm::dot(c, dir.d) - r;
  hi = glm::dot(c, dir.d) + r;
}

double cost_of(SplitCost cost, const Candidate& c) {
  switch (cost) {
    case SplitCost::Sah:
    case SplitCost::SahOverlapGuarded:
      return sah_cost(c);
    case SplitCost::VolumeSum:
      return volume(c.left) + volume(c.right);
    case SplitCost::LargestVolume:
      return std::max(volume(c.left), volume(c.right));
    case SplitCost::Overlap:
      return overlap_volume(c.left, c.right);
    case SplitCost::Separation: {
      // Signed gap between the children's projected intervals: max(lo) - min(hi), which is
      // the distance between them when disjoint and minus the overlap length otherwise.
      double l0, l1, r0, r1;
      box_interval(c.left, c.pred.dir, l0, l1);
      box_interval(c.right, c.pred.dir, r0, r1);
      return -(std::max(l0, r0) - std::min(l1, r1));
    }
  }
  return 0.0;
}

// The chosen candidate's index, or -1 when there is none. Ties go to the earlier candidate.
int choose(const std::vector<Candidate>& candidates, SplitCost cost, const Aabb& node_box) {
  int best = -1;
  double best_cost = INFINITY;
  for (std::size_t i = 0; i < candidates.size(); ++i) {
    const double c = cost_of(cost, candidates[i]);
    if (best < 0 || c < best_cost) best = int(i), best_cost = c;
  }
  if (cost != SplitCost::SahOverlapGuarded || best < 0) return best;
  // Guarded SAH: when the SAH choice's children overlap in more than a quarter of the node's
  // volume, take the best SAH among the candidates whose overlap is at most that, if any.
  const double limit = volume(node_box) * 0.25;
  if (!(overlap_volume(candidates[std::size_t(best)].left, candidates[std::size_t(best)].right) > limit)) return best;
  int guarded = -1;
  double guarded_cost = INFINITY;
  for (std::size_t i = 0; i < candidates.size(); ++i) {
    if (overlap_volume(candidates[i].left, candidates[i].right) > limit) continue;
    const double c = sah_cost(candidates[i]);
    if (guarded < 0 || c < guarded_cost) guarded = int(i), guarded_cost = c;
  }
  return guarded >= 0 ? guarded : best;
}

int longest_axis(const Aabb& cbox) {
  const glm::vec3 e = cbox.max - cbox.min;
  return e.x >= e.y && e.x >= e.z ? 0 : (e.y >= e.z ? 1 : 2);
}

// Principal axis of the centroids: power iteration on the covariance (double), from each
// coordinate axis, keeping the result with the largest Rayleigh quotient (a start orthogonal
// to the principal axis converges elsewhere, but not all three can be). False when the
// centroids all coincide (or the covariance is not finite).
bool principal_axis(const std::uint32_t* objs, std::uint32_t count, const std::vector<glm::vec3>& centroid,
                    glm::dvec3& axis) {
  glm::dvec3 mean(0.0);
  for (std::uint32_t i = 0; i < count; ++i) mean += glm::dvec3(centroid[objs[i]]);
  mean /= double(count);
  glm::dmat3 cov(0.0);
  for (std::uint32_t i = 0; i < count; ++i) {
    const glm::dvec3 v = glm::dvec3(centroid[objs[i]]) - mean;
    for (int r = 0; r < 3; ++r)
      for (int c = 0; c < 3; ++c) cov[c][r] += v[r] * v[c];
  }
  double best = 0.0;
  for (int start = 0; start < 3; ++start) {
    glm::dvec3 v(0.0);
    v[start] = 1.0;
    bool ok = true;
    for (int iteration = 0; iteration < 64 && ok; ++iteration) {
      const glm::dvec3 w = cov * v;
      const double len = glm::length(w);
      ok = len > 0.0 && std::isfinite(len);
      if (ok) v = w / len;
    }
    if (!ok) continue;
    const double rayleigh = glm::dot(v, cov * v);
    if (rayleigh > best) best = rayleigh, axis = v;
  }
  return best > 0.0 && std::isfinite(best);
}

// Approximately the most distant pair of centroids (two farthest-point sweeps from the
// node's first object); false when all centroids coincide.
bool distant_axis(const std::uint32_t* objs, std::uint32_t count, const std::vector<glm::vec3>& centroid,
                  glm::dvec3& axis) {
  const auto farthest = [&](const glm::dvec3& from) {
    glm::dvec3 far = from;
    double best = -1.0;
    for (std::uint32_t i = 0; i < count; ++i) {
      const glm::dvec3 c(centroid[objs[i]]);
      const double d = glm::dot(c - from, c - from);
      if (d > best) best = d, far = c;
    }
    return far;
  };
  const glm::dvec3 a = farthest(glm::dvec3(centroid[objs[0]]));
  const glm::dvec3 b = farthest(a);
  const double len = glm::length(b - a);
  if (!(len > 0.0 && std::isfinite(len))) return false;
  axis = (b - a) / len;
  return true;
}

Tree build_generic(std::span<const Aabb> boxes, const BuildOptions& options) {
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
  std::vector<Candidate> candidates;
  std::vector<std::pair<double, std::uint32_t>> keyed;  // (projection, id) for the median
  std::vector<Aabb> bin_box(bins), prefix(bins);
  std::vector<std::uint32_t> bin_count(bins);
  std::vector<std::uint32_t> scratch(n);
  std::vector<Direction> directions;
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

    // The directions to try.
    directions.clear();
    const auto add_longest = [&] { directions.push_back({longest_axis(cbox), glm::dvec3(0.0)}); };
    switch (options.axis) {
      case SplitAxis::Best:
        for (int axis = 0; axis < 3; ++axis) directions.push_back({axis, glm::dvec3(0.0)});
        break;
      case SplitAxis::Longest:
        add_longest();
        break;
      case SplitAxis::DistantCentroids:
      case SplitAxis::Pca: {
        glm::dvec3 d(0.0);
        const bool found = options.axis == SplitAxis::Pca ? principal_axis(objs, task.count, centroid, d)
                                                          : distant_axis(objs, task.count, centroid, d);
        if (found) {
          directions.push_back({-1, d});
        } else {
          add_longest();
        }
        break;
      }
    }

    candidates.clear();
    for (std::size_t k = 0; k < directions.size(); ++k) {
      const Direction dir = directions[k];
      double plo = INFINITY, phi = -INFINITY, sum = 0.0;
      for (std::uint32_t i = 0; i < task.count; ++i) {
        const double p = project(centroid[objs[i]], dir);
        plo = std::min(plo, p);
        phi = std::max(phi, p);
        sum += p;
      }
      if (!(phi > plo) || !std::isfinite(phi - plo)) {
        // Flat along this direction. A general direction that projects flat (rounding on
        // nearly coincident centroids) is replaced by the longest axis.
        if (dir.axis < 0) directions.push_back({longest_axis(cbox), glm::dvec3(0.0)});
        continue;
      }
      Predicate pred;
      pred.dir = dir;
      if (options.position == SplitPosition::Binned) {
        pred.kind = Predicate::Bin;
        if (dir.axis >= 0) {  // as build_binned_sah
          pred.flo = cbox.min[dir.axis];
          const float extent = cbox.max[dir.axis] - cbox.min[dir.axis];
          pred.fscale = float(bins) / extent;
          pred.flast = float(bins - 1);
          if (!std::isfinite(pred.fscale)) continue;  // a subnormal extent: treat the axis as flat
        } else {
          pred.dlo = plo;
          pred.dscale = double(bins) / (phi - plo);
          pred.dlast = double(bins - 1);
        }
        std::fill(bin_box.begin(), bin_box.end(), empty_box());
        std::fill(bin_count.begin(), bin_count.end(), 0u);
        for (std::uint32_t i = 0; i < task.count; ++i) {
          const std::uint32_t b = pred.bin_of(centroid[objs[i]]);
          grow(bin_box[b], boxes[objs[i]]);
          ++bin_count[b];
        }
        Aabb acc = empty_box();
        std::uint32_t cnt = 0;
        for (std::uint32_t b = 0; b < bins; ++b) {
          grow(acc, bin_box[b]);
          cnt += bin_count[b];
          prefix[b] = acc;
        }
        acc = empty_box();
        std::uint32_t right = 0;
        const std::size_t first_candidate = candidates.size();
        for (std::uint32_t b = bins - 1; b > 0; --b) {  // candidate b - 1: bins [0, b - 1] left
          grow(acc, bin_box[b]);
          right += bin_count[b];
          const std::uint32_t left = cnt - right;
          if (left == 0 || right == 0) continue;
          Candidate c;
          c.pred = pred;
          c.pred.bin = b - 1;
          c.left = prefix[b - 1];
          c.right = acc;
          c.nl = left;
          c.nr = right;
          candidates.push_back(c);
        }
        std::reverse(candidates.begin() + std::ptrdiff_t(first_candidate), candidates.end());  // ascending bins
        continue;
      }
      pred.kind = Predicate::Threshold;
      switch (options.position) {
        case SplitPosition::Median: {
          keyed.resize(task.count);
          for (std::uint32_t i = 0; i < task.count; ++i) keyed[i] = {project(centroid[objs[i]], dir), objs[i]};
          std::nth_element(keyed.begin(), keyed.begin() + task.count / 2, keyed.end());
          pred.t = keyed[task.count / 2].first;
          pred.pivot_id = keyed[task.count / 2].second;
          break;
        }
        case SplitPosition::Mean:
          pred.t = sum / double(task.count);
          break;
        case SplitPosition::ExtentMedian:
        case SplitPosition::Binned:
          pred.t = plo + (phi - plo) * 0.5;
          break;
      }
      Candidate c;
      c.pred = pred;
      for (std::uint32_t i = 0; i < task.count; ++i) {
        const bool l = pred.left(centroid[objs[i]], objs[i]);
        grow(l ? c.left : c.right, boxes[objs[i]]);
        ++(l ? c.nl : c.nr);
      }
      if (c.nl > 0 && c.nr > 0) candidates.push_back(c);
    }

    std::uint32_t mid = 0;
    const int chosen = choose(candidates, options.cost, box);
    if (chosen >= 0) {  // stable partition by the chosen predicate
      const Predicate& pred = candidates[std::size_t(chosen)].pred;
      std::uint32_t r = 0;
      for (std::uint32_t i = 0; i < task.count; ++i) {
        if (pred.left(centroid[objs[i]], objs[i])) {
          objs[mid++] = objs[i];
        } else {
          scratch[r++] = objs[i];
        }
      }
      std::copy(scratch.begin(), scratch.begin() + r, objs + mid);
    }
    if (mid == 0 || mid == task.count) {  // no split: halve the range by id (deterministic)
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

}  // namespace

Tree build_top_down(std::span<const Aabb> boxes, const BuildOptions& options) {
  if (options.sah_leaves && !(options.object_cost > 0.0f && std::isfinite(options.object_cost)))
    throw std::invalid_argument("build_top_down: object_cost " + std::to_string(options.object_cost) +
                                " (a positive finite number)");
  if (options.axis == SplitAxis::Best && options.position == SplitPosition::Binned && options.cost == SplitCost::Sah)
    return build_binned_sah(boxes, {options.max_leaf_size, options.bins, options.sah_leaves, options.object_cost},
                            options.pool);
  if (options.sah_leaves && options.max_leaf_size > 1) {
    BuildOptions ones = options;
    ones.max_leaf_size = 1;
    return collapse_leaves(build_generic(boxes, ones), options.max_leaf_size, options.object_cost);
  }
  return build_generic(boxes, options);
}

DetailedMetrics detailed_metrics(const Tree& tree) {
  DetailedMetrics m;
  m.basic = metrics(tree);
  if (tree.nodes.empty()) return m;
  const double root_volume = volume(tree.nodes[0].box);
  double volume_sum = 0.0, overlap_sum = 0.0, depth_sum = 0.0;
  std::vector<std::pair<std::uint32_t, std::size_t>> stack{{0, 1}};
  while (!stack.empty()) {
    const auto [i, depth] = stack.back();
    stack.pop_back();
    const Node& node = tree.nodes[i];
    volume_sum += volume(node.box);
    if (node.leaf()) {
      if (m.leaf_sizes.size() <= node.count) m.leaf_sizes.resize(std::size_t(node.count) + 1, 0);
      ++m.leaf_sizes[node.count];
      depth_sum += double(depth);
    } else {
      overlap_sum += overlap_volume(tree.nodes[node.left].box, tree.nodes[node.right].box);
      stack.push_back({node.left, depth + 1});
      stack.push_back({node.right, depth + 1});
    }
  }
  if (root_volume > 0.0) {
    m.total_volume = volume_sum / root_volume;
    m.overlap_volume = overlap_sum / root_volume;
  }
  m.mean_leaf_depth = depth_sum / double(m.basic.leaves);
  std::size_t log2_leaves = 0;  // ceil(log2(leaves))
  while ((std::size_t(1) << log2_leaves) < m.basic.leaves) ++log2_leaves;
  m.balance = double(m.basic.depth) / double(log2_leaves + 1);
  return m;
}

}  // namespace cullpipe::bvh
