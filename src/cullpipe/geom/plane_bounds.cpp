#include "cullpipe/geom/plane_bounds.hpp"

#include <algorithm>
#include <bit>
#include <cmath>
#include <glm/vec3.hpp>
#include <limits>

namespace cullpipe::plane_bounds {

namespace {

/// A float >= x, for x >= 2^-126 (no subnormal result) or NaN (stays NaN); past the float
/// range, inf. Needs round to nearest. Proof: docs/numerics.md, Rounding model.
/// (No nextafter: a library call per object would dominate an upload.)
float float_at_least(double x) {
  const double up = x * (1.0 + 0x1p-23);
  return up > double(std::numeric_limits<float>::max()) ? std::numeric_limits<float>::infinity()
                                                        : static_cast<float>(up);
}

}  // namespace

/// |E| (1 + 2^-16) + 2^-18 (|C|_1 + |E|_1) + 2^-100 rounded up (C, E: exact centre, half extent): settles the
/// p/n-vertex test with the view's margin; NaN for non-finite boxes or |C|_1 + |E|_1 past 2^120 (s may overflow).
/// Proof: docs/numerics.md, Settling bounds.
float aabb_plane_bound(const Aabb& b, glm::vec3& centre) {
  double size = 0.0, diagonal = 0.0;
  centre = glm::vec3(0.0f);
  for (int a = 0; a < 3; ++a) {
    const double lo = b.min[a], hi = b.max[a];
    if (!std::isfinite(lo) || !std::isfinite(hi)) return std::numeric_limits<float>::quiet_NaN();
    const double c = (lo + hi) / 2, e = (hi - lo) / 2;
    centre[a] = static_cast<float>(c);
    size += std::fabs(c) + std::fabs(e);
    diagonal += e * e;
  }
  if (!(size <= 0x1p120)) return std::numeric_limits<float>::quiet_NaN();
  return float_at_least(std::sqrt(diagonal) * (1.0 + 0x1p-16) + 0x1p-18 * size + 0x1p-100);
}

/// At least |r| + 2^-18 |c|_1 for the reference's projected radius r on any plane with |n| <= 1 + 2^-20, from
/// the smaller of a loose radius (sum (|u_i| + 2^-140) |h_i|) and a tight one (Gershgorin on the axes' Gram
/// matrix); NaN for NaN inputs, |c|_1 past 2^120 or an axis component of 2^125 or more. Proof: docs/numerics.md,
/// Settling bounds.
float obb_plane_bound(const Obb& b) {
  double sum = 0.0, size = 0.0, h_squares = 0.0, h_sum = 0.0;
  for (int i = 0; i < 3; ++i) {
    const glm::vec3 u = b.basis[i];
    const double x = u.x, y = u.y, z = u.z;
    if (!(std::fabs(x) < 0x1p125 && std::fabs(y) < 0x1p125 && std::fabs(z) < 0x1p125))  // NaN too
      return std::numeric_limits<float>::quiet_NaN();
    const double h = std::fabs(double(b.half_extents[i]));
    sum += (std::sqrt(x * x + y * y + z * z) + 0x1p-140) * h;
    size += std::fabs(double(b.center[i]));
    h_squares += h * h;
    h_sum += h;
  }
  if (!(size <= 0x1p120)) return std::numeric_limits<float>::quiet_NaN();  // NaN and inf too
  // Gershgorin on the Gram matrix (products of floats are exact in double).
  auto dot = [&](int i, int j) {
    const glm::dvec3 u(b.basis[i]), v(b.basis[j]);
    return u.x * v.x + u.y * v.y + u.z * v.z;
  };
  double gram_bound = 0.0;
  for (int i = 0; i < 3; ++i)
    gram_bound = std::max(gram_bound, dot(i, i) + std::fabs(dot(i, (i + 1) % 3)) + std::fabs(dot(i, (i + 2) % 3)));
  const double tight =
      std::sqrt(gram_bound) * std::sqrt(h_squares) * (1.0 + 0x1p-39) + 0x1p-21 * sum + 0x1p-120 * h_sum;
  // (A NaN `tight`, from 0 x inf, leaves `sum`; a NaN `sum` stays NaN.)
  const double radius = tight < sum ? tight : sum;
  return float_at_least(radius * (1.0 + 0x1p-16) + 0x1p-18 * size + 0x1p-100);
}

/// |r| (1 + 2^-20) + 2^-18 |c|_1 + 2^-100 rounded up: settles the sphere test with the view's margin; NaN for
/// non-finite values or |c|_1 past 2^120. Proof: docs/numerics.md, Settling bounds.
float sphere_plane_bound(const Sphere& s) {
  const double size = std::fabs(double(s.center.x)) + std::fabs(double(s.center.y)) + std::fabs(double(s.center.z));
  const double radius = std::fabs(double(s.radius));
  if (!(size <= 0x1p120) || !std::isfinite(radius)) return std::numeric_limits<float>::quiet_NaN();
  return float_at_least(radius * (1.0 + 0x1p-20) + 0x1p-18 * size + 0x1p-100);
}

// The lower bounds packed into the bounds' low bits: X such that every plane's straddling threshold, less every
// rounding of both centre distances, is at least c_k X - m (c_k: |n_k|_1 for boxes, |n_k|_2 for OBBs, 1 for
// spheres); 0 or negative where none is known. Proof: docs/numerics.md, Packed lower bounds.
//
// Spheres: X = r (1 - 2^-20) - 2^-18 |c|_1.
double sphere_lower(const Sphere& s) {
  const double size = std::fabs(double(s.center.x)) + std::fabs(double(s.center.y)) + std::fabs(double(s.center.z));
  return double(s.radius) * (1.0 - 0x1p-20) - 0x1p-18 * size;
}

// Boxes: X = min E_i (1 - 2^-50) - 2^-18 (|C|_1 + |E|_1), negative for an inverted box.
double aabb_lower(const Aabb& b) {
  double size = 0.0, smallest = std::numeric_limits<double>::infinity();
  for (int a = 0; a < 3; ++a) {
    const double lo = b.min[a], hi = b.max[a], c = (lo + hi) / 2, e = (hi - lo) / 2;
    size += std::fabs(c) + std::fabs(e);
    smallest = std::min(smallest, e);
  }
  return smallest * (1.0 - 0x1p-50) - 0x1p-18 * size;  // (NaN for non-finite boxes: packs 0)
}

// OBBs: X = (min h sqrt(g) (1 - 2^-40) - 2^-21 sum |u_i| h_i)(1 - 2^-20) - 2^-17 |c|_1 - 2^-118 sum h_i, g a
// Gershgorin bound on the smallest eigenvalue of the axes' Gram matrix; 0 where g <= 0 or an h_i is not normal.
double obb_lower(const Obb& b) {
  double smallest = std::numeric_limits<double>::infinity(), sum = 0.0, spread = 0.0, size = 0.0;
  double gram[3][3];
  for (int i = 0; i < 3; ++i) {
    const double h = b.half_extents[i];
    if (!(h >= 0x1p-126) || !std::isfinite(h)) return 0.0;  // (DAZ reads a subnormal h as 0)
    smallest = std::min(smallest, h);
    sum += h;
    for (int j = 0; j < 3; ++j)
      gram[i][j] = double(b.basis[i].x) * b.basis[j].x + double(b.basis[i].y) * b.basis[j].y +
                   double(b.basis[i].z) * b.basis[j].z;
    spread += std::sqrt(gram[i][i]) * h;
    size += std::fabs(double(b.center[i]));
  }
  double g = std::numeric_limits<double>::infinity();
  for (int i = 0; i < 3; ++i)
    g = std::min(g, gram[i][i] - std::fabs(gram[i][(i + 1) % 3]) - std::fabs(gram[i][(i + 2) % 3]));
  g -= 0x1p-48 * std::max({gram[0][0], gram[1][1], gram[2][2]});
  if (!(g > 0.0) || !std::isfinite(g)) return 0.0;
  return (smallest * std::sqrt(g) * (1.0 - 0x1p-40) - 0x1p-21 * spread) * (1.0 - 0x1p-20) - 0x1p-17 * size -
         0x1p-118 * sum;
}

/// Still a bound (it grew by less than 2^-14 of itself), and the kernels read q bound / 256 <= lower (1 + 2^-15)
/// back; q = 0 past 2^119 keeps q bound finite. Proof: docs/numerics.md, Packed lower bounds.
float pack_lower(float bound, double lower) {
  if (!(bound > 0.0f) || !std::isfinite(bound)) return bound;
  std::uint32_t bits =
      (std::bit_cast<std::uint32_t>(bound) + 255u) & ~255u;  // (a carry into the exponent is still larger)
  const float rounded = std::bit_cast<float>(bits);
  if (!std::isfinite(rounded)) return rounded;
  const bool small = rounded <= 0x1p119f;
  const double q =
      small && lower > 0.0 ? std::floor(std::min(255.0, 256.0 * (lower / double(rounded)) * (1.0 - 0x1p-40))) : 0.0;
  return std::bit_cast<float>(bits | static_cast<std::uint32_t>(q));
}

float plane_margin(float d) {
  const double magnitude = std::fabs(double(d));
  return magnitude <= 0x1p120 ? float_at_least(0x1p-18 * magnitude + 0x1p-100)
                              : std::numeric_limits<float>::quiet_NaN();
}

bool unit_normal(const glm::vec3& n) {
  const double length = std::sqrt(double(n.x) * n.x + double(n.y) * n.y + double(n.z) * n.z);
  return length <= kUnitNormalLimit;  // false for NaN too
}

float settle_margin(const Frustum& frustum) {
  float margin = 0.0f;
  for (std::size_t k = 0; k < std::min<std::size_t>(frustum.plane_count, 6); ++k) {
    const Plane& plane = frustum.planes[k];
    const float m = plane_margin(plane.d);
    if (!unit_normal(plane.normal) || std::isnan(m)) return std::numeric_limits<float>::quiet_NaN();
    margin = std::max(margin, m);
  }
  return margin;
}

void aabb_centre_bounds(std::span<const Aabb> boxes, std::span<glm::vec4> out) {
  const NearestNoFlush mode;
  glm::vec3 centre;
  for (std::size_t i = 0; i < boxes.size(); ++i) {
    const float bound = aabb_plane_bound(boxes[i], centre);
    out[i] = glm::vec4(centre, bound);
  }
}

void obb_plane_bounds(std::span<const Obb> boxes, std::span<float> out) {
  const NearestNoFlush mode;
  for (std::size_t i = 0; i < boxes.size(); ++i) out[i] = obb_plane_bound(boxes[i]);
}

}  // namespace cullpipe::plane_bounds
