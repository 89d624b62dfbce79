#include "cullpipe/bounds/sphere_fit.hpp"

#include <algorithm>
#include <cmath>
#include <glm/geometric.hpp>
#include <limits>
#include <numeric>
#include <string>
#include <vector>

#include "cullpipe/bounds/points.hpp"
#include "cullpipe/core/splitmix.hpp"
#include "cullpipe/geom/rounding.hpp"

namespace cullpipe::bounds {

void check_points(std::span<const glm::vec3> points) {
  if (points.empty()) throw BadPoints("no points: a bounding volume needs at least one point");
  for (std::size_t i = 0; i < points.size(); ++i)
    for (int k = 0; k < 3; ++k)
      if (!std::isfinite(points[i][k]))
        throw BadPoints("point " + std::to_string(i) + " has a" + (std::isnan(points[i][k]) ? " NaN" : "n infinite") +
                        " coordinate");
}

std::pair<std::size_t, std::size_t> most_separated_axis_extremes(std::span<const glm::vec3> points) {
  std::size_t lo[3] = {0, 0, 0}, hi[3] = {0, 0, 0};
  for (std::size_t i = 1; i < points.size(); ++i)
    for (int k = 0; k < 3; ++k) {
      if (points[i][k] < points[lo[k]][k]) lo[k] = i;
      if (points[i][k] > points[hi[k]][k]) hi[k] = i;
    }
  int axis = 0;
  double best = -1.0;
  for (int k = 0; k < 3; ++k) {
    const glm::dvec3 d = glm::dvec3(points[hi[k]]) - glm::dvec3(points[lo[k]]);
    if (glm::dot(d, d) > best) {
      best = glm::dot(d, d);
      axis = k;
    }
  }
  return {lo[axis], hi[axis]};
}

namespace {

using dvec3 = glm::dvec3;

struct Ball {
  dvec3 c{0.0};
  double r2 = -1.0;  // squared radius; negative: empty
};

void shuffle(std::vector<dvec3>& v, std::uint64_t seed) {
  SplitMix64 rng{seed};
  for (std::size_t i = v.size(); i > 1; --i) std::swap(v[i - 1], v[rng.next() % i]);
}

std::vector<dvec3> to_double(std::span<const glm::vec3> points) { return {points.begin(), points.end()}; }

// Membership with a relative tolerance for rounding in the ball constructions.
struct Tolerance {
  double abs2;  // absolute slack (squared), from the coordinate scale
  bool contains(const Ball& b, const dvec3& p) const {
    if (b.r2 < 0.0) return false;
    const dvec3 d = p - b.c;
    return glm::dot(d, d) <= b.r2 * (1.0 + 1e-12) + abs2;
  }
};

Ball ball1(const dvec3& a) { return {a, 0.0}; }

Ball ball2(const dvec3& a, const dvec3& b) {
  const dvec3 c = (a + b) * 0.5;
  const dvec3 d = a - c;
  return {c, glm::dot(d, d)};
}

// Smallest ball with a, b, c on its boundary (their circumcircle); for collinear points,
// the smallest ball enclosing them.
Ball ball3(const dvec3& a, const dvec3& b, const dvec3& c, const Tolerance& tol) {
  const dvec3 ab = b - a, ac = c - a;
  const dvec3 n = glm::cross(ab, ac);
  const double n2 = glm::dot(n, n);
  if (n2 <= 1e-24 * glm::dot(ab, ab) * glm::dot(ac, ac) || n2 == 0.0) {
    Ball best;
    for (const Ball& cand : {ball2(a, b), ball2(a, c), ball2(b, c)})
      if (tol.contains(cand, a) && tol.contains(cand, b) && tol.contains(cand, c) && (best.r2 < 0 || cand.r2 < best.r2))
        best = cand;
    return best;
  }
  const dvec3 offset = (glm::dot(ac, ac) * glm::cross(n, ab) + glm::dot(ab, ab) * glm::cross(ac, n)) / (2.0 * n2);
  return {a + offset, glm::dot(offset, offset)};
}

// Smallest ball with a, b, c, d on its boundary (circumsphere); for coplanar points, the
// smallest ball enclosing the four.
Ball ball4(const dvec3& a, const dvec3& b, const dvec3& c, const dvec3& d, const Tolerance& tol) {
  const dvec3 v1 = b - a, v2 = c - a, v3 = d - a;
  const double det = glm::dot(v1, glm::cross(v2, v3));
  const double scale = glm::length(v1) * glm::length(v2) * glm::length(v3);
  if (std::abs(det) <= 1e-12 * scale || det == 0.0) {
    const dvec3 pts[4] = {a, b, c, d};
    Ball best;
    auto consider = [&](const Ball& cand) {
      if (cand.r2 < 0) return;
      for (const dvec3& p : pts)
        if (!tol.contains(cand, p)) return;
      if (best.r2 < 0 || cand.r2 < best.r2) best = cand;
    };
    for (int i = 0; i < 4; ++i)
      for (int j = i + 1; j < 4; ++j) {
        consider(ball2(pts[i], pts[j]));
        for (int k = j + 1; k < 4; ++k) consider(ball3(pts[i], pts[j], pts[k], tol));
      }
    return best;
  }
  const dvec3 offset = (glm::dot(v1, v1) * glm::cross(v2, v3) + glm::dot(v2, v2) * glm::cross(v3, v1) +
                        glm::dot(v3, v3) * glm::cross(v1, v2)) /
                       (2.0 * det);
  return {a + offset, glm::dot(offset, offset)};
}

Tolerance tolerance_for(std::span<const glm::vec3> pts) {
  float scale = 0.0f;
  for (const glm::vec3& p : pts) scale = std::max({scale, std::abs(p.x), std::abs(p.y), std::abs(p.z)});
  const double abs = double(scale) * 1e-14;
  return {abs * abs};
}

// Welzl's algorithm, loop form, over `p` in a fixed pseudo-random order (it shuffles `p`):
// expected O(n) ball-in-ball tests.
Ball welzl(std::vector<dvec3>& p, const Tolerance& tol) {
  shuffle(p, 0x5EED);
  Ball b = ball1(p[0]);
  for (std::size_t i = 1; i < p.size(); ++i) {
    if (tol.contains(b, p[i])) continue;
    b = ball1(p[i]);
    for (std::size_t j = 0; j < i; ++j) {
      if (tol.contains(b, p[j])) continue;
      b = ball2(p[i], p[j]);
      for (std::size_t k = 0; k < j; ++k) {
        if (tol.contains(b, p[k])) continue;
        b = ball3(p[i], p[j], p[k], tol);
        for (std::size_t l = 0; l < k; ++l) {
          if (tol.contains(b, p[l])) continue;
          b = ball4(p[i], p[j], p[k], p[l], tol);
        }
      }
    }
  }
  return b;
}

// The points farthest outside a ball, found in one pass: a buffer of candidates above an
// admission distance that rises to the k-th largest seen whenever the buffer fills, so the
// pass stays linear however many points lie outside.
class FarthestOutside {
 public:
  explicit FarthestOutside(std::size_t k) : k_(k) { buffer_.reserve(4 * k); }

  void start(double limit) {
    buffer_.clear();
    admit_ = limit;
  }
  void offer(double d2, std::uint32_t index) {
    if (d2 <= admit_) return;
    buffer_.push_back({d2, index});
    if (buffer_.size() == buffer_.capacity()) keep_largest();
  }
  // The indices of the (at most k) farthest points offered, in no order.
  std::span<const std::pair<double, std::uint32_t>> finish() {
    if (buffer_.size() > k_) keep_largest();
    return buffer_;
  }
  double admit() const { return admit_; }

 private:
  void keep_largest() {
    std::nth_element(buffer_.begin(), buffer_.begin() + std::ptrdiff_t(k_ - 1), buffer_.end(),
                     [](const auto& a, const auto& b) { return a.first > b.first; });
    buffer_.resize(k_);
    admit_ = std::max(admit_, buffer_[k_ - 1].first);
  }

  std::size_t k_;
  double admit_ = 0.0;
  std::vector<std::pair<double, std::uint32_t>> buffer_;
};

// Offers every point outside `b` (by the tolerance of Tolerance::contains) to `far`. The
// distances of a block are computed first, in a loop the compiler vectorises, and the block
// is searched only when its largest distance is outside.
void scan_outside(std::span<const glm::vec3> points, const Ball& b, const Tolerance& tol, FarthestOutside& far) {
  far.start(b.r2 * (1.0 + 1e-12) + tol.abs2);
  constexpr std::size_t kBlock = 256;
  double d2[kBlock];
  for (std::size_t base = 0; base < points.size(); base += kBlock) {
    const std::size_t m = std::min(kBlock, points.size() - base);
    const glm::vec3* p = points.data() + base;
    double largest = 0.0;
    for (std::size_t i = 0; i < m; ++i) {
      const double dx = double(p[i].x) - b.c.x, dy = double(p[i].y) - b.c.y, dz = double(p[i].z) - b.c.z;
      d2[i] = dx * dx + dy * dy + dz * dz;
      largest = std::max(largest, d2[i]);
    }
    if (largest <= far.admit()) continue;
    for (std::size_t i = 0; i < m; ++i) far.offer(d2[i], std::uint32_t(base + i));
  }
}

// Ritter's grow step: the smallest sphere containing the sphere and p.
void grow(dvec3& c, double& r, const dvec3& p) {
  const dvec3 d = p - c;
  const double d2 = glm::dot(d, d);
  if (d2 <= r * r) return;
  const double dist = std::sqrt(d2);
  const double new_r = (r + dist) * 0.5;
  c += d * ((new_r - r) / dist);
  r = new_r;
}

}  // namespace

Sphere enclosing_sphere(const dvec3& center, std::span<const glm::vec3> points) {
  Sphere s;
  s.center = glm::vec3(center);
  const dvec3 c(s.center);
  double r2 = 0.0;
  for (const glm::vec3& p : points) {
    const dvec3 d = dvec3(p) - c;
    r2 = std::max(r2, glm::dot(d, d));
  }
  s.radius = round_up(std::sqrt(r2));
  return s;
}

Aabb aabb_of_points(std::span<const glm::vec3> points) {
  check_points(points);
  Aabb b{points[0], points[0]};
  for (const glm::vec3& p : points) {
    b.min = glm::min(b.min, p);
    b.max = glm::max(b.max, p);
  }
  return b;
}

Sphere ritter_sphere(std::span<const glm::vec3> points) {
  check_points(points);
  // Seed: the diameter sphere of the most separated pair of axis-extreme points.
  const auto [a, b] = most_separated_axis_extremes(points);
  dvec3 c = (dvec3(points[a]) + dvec3(points[b])) * 0.5;
  double r = glm::length(dvec3(points[b]) - dvec3(points[a])) * 0.5;
  for (const glm::vec3& p : points) grow(c, r, dvec3(p));
  return enclosing_sphere(c, points);
}

Sphere refined_sphere(std::span<const glm::vec3> points, int iterations, std::uint64_t seed) {
  const Aabb box = aabb_of_points(points);
  std::vector<dvec3> pts = to_double(points);
  dvec3 best_c = dvec3(box.min) * 0.5 + dvec3(box.max) * 0.5;
  double best_r = 0.0;
  for (const dvec3& p : pts) best_r = std::max(best_r, glm::length(p - best_c));
  for (int it = 0; it < iterations; ++it) {
    dvec3 c = best_c;
    double r = best_r * 0.95;
    shuffle(pts, seed + std::uint64_t(it));
    for (const dvec3& p : pts) grow(c, r, p);
    if (r < best_r) {
      best_r = r;
      best_c = c;
    }
  }
  return enclosing_sphere(best_c, points);
}

Sphere exact_sphere(std::span<const glm::vec3> points) {
  check_points(points);
  const Tolerance tol = tolerance_for(points);
  // The minimum ball of a subset that encloses every point is the minimum ball of them all
  // (no ball smaller than the subset's encloses the subset). So: take the exact ball of a
  // small core set, scan for the points outside it, add the farthest of them to the core,
  // and repeat until none is outside. Each round grows the core's ball, and the core stays
  // small (the support of the answer is at most 4 points), so a few linear scans, done in
  // the cheapest form, cost about what Ritter's single pass does.
  constexpr std::size_t kSample = 32, kAddPerScan = 32;
  if (points.size() <= 4 * kSample) return welzl_sphere(points);
  std::vector<dvec3> core, shuffled;
  const std::size_t stride = points.size() / kSample;
  for (std::size_t i = 0; i < kSample; ++i) core.push_back(dvec3(points[i * stride]));
  shuffled = core;
  Ball b = welzl(shuffled, tol);
  FarthestOutside far(kAddPerScan);
  // A core past n/4 points (a set where every scan finds many points barely outside) means
  // the scans no longer pay for themselves; Welzl over everything ends it.
  while (core.size() < points.size() / 4) {
    scan_outside(points, b, tol, far);
    const auto outside = far.finish();
    if (outside.empty()) return enclosing_sphere(b.c, points);
    for (const auto& [d2, index] : outside) core.push_back(dvec3(points[index]));
    shuffled = core;
    b = welzl(shuffled, tol);
  }
  return welzl_sphere(points);
}

Sphere welzl_sphere(std::span<const glm::vec3> points) {
  check_points(points);
  std::vector<dvec3> all = to_double(points);
  return enclosing_sphere(welzl(all, tolerance_for(points)).c, points);
}

Sphere brute_force_sphere(std::span<const glm::vec3> points) {
  check_points(points);
  if (points.size() > 64) throw std::invalid_argument("brute_force_sphere: at most 64 points");
  const std::vector<dvec3> p = to_double(points);
  const Tolerance tol = tolerance_for(points);
  const std::size_t n = p.size();
  Ball best;
  auto consider = [&](const Ball& b) {
    if (b.r2 < 0 || (best.r2 >= 0 && b.r2 >= best.r2)) return;
    for (const dvec3& q : p)
      if (!tol.contains(b, q)) return;
    best = b;
  };
  for (std::size_t i = 0; i < n; ++i) {
    consider(ball1(p[i]));
    for (std::size_t j = i + 1; j < n; ++j) {
      consider(ball2(p[i], p[j]));
      for (std::size_t k = j + 1; k < n; ++k) {
        consider(ball3(p[i], p[j], p[k], tol));
        for (std::size_t l = k + 1; l < n; ++l) consider(ball4(p[i], p[j], p[k], p[l], tol));
      }
    }
  }
  return enclosing_sphere(best.c, points);
}

}  // namespace cullpipe::bounds
