#include "geom/plane_bounds.hpp"

#include <algorithm>
#include <bit>
#include <cmath>
#include <limits>

#include <glm/vec3.hpp>

namespace cullpipe::plane_bounds {

namespace {

/// A float >= x, for x >= 2^-126 (no subnormal result) or NaN (stays NaN); past the float
/// range, inf. Rounding x (1 + 2^-23) to nearest loses at most a factor 1 - 2^-24. (No
/// nextafter: a library call per object makes uploads several times slower.)
float float_at_least(double x) {
  const double up = x * (1.0 + 0x1p-23);
  return up > double(std::numeric_limits<float>::max()) ? std::numeric_limits<float>::infinity() : static_cast<float>(up);
}

}  // namespace

/// AabbArrays::bound of `b`, and its centre (min + max) / 2 rounded to a float. With a margin
/// m >= 2^-18 |d| (PlaneSet::max_margin, the largest over the planes) it settles the reference's p/n-vertex test for every plane of
/// normal |n| <= 1 + 2^-20: s < -(bound + m) means d_p < 0 and s >= bound + m means d_n >= 0
/// and d_p >= 0, for s = n.centre + d computed in float in any order, fused or not (or a
/// mirrored plane's difference: CentreArrays in simd_kernels.inl), in any
/// rounding mode. Why, with C and E the exact centre and half extent (E < 0 for an inverted
/// box) and e = 2^-23 (a float rounding in any mode; 2^-24 to nearest, as here at upload):
/// - the exact vertex distances are D_c +- sum |n_i| E_i, D_c = n.C + d, within |n| |E| of D_c;
/// - the reference's four roundings put d_p and d_n within 4e(|n|(|C|_1 + |E|_1) + |d|) of them;
///   s is within 6e(|n| |centre|_1 + |d|) of n.centre + d, which is within |n| 2^-24 |C|_1 of
///   D_c; the sums of the float bound and margin round down by at most e;
/// - so |d_p - s| and |d_n - s| stay below |E| (1 + 2^-16) + 2^-18 (|C|_1 + |E|_1 + |d|): the
///   coefficients needed are at most 11e and 10e, 2^-18 = 32e. 2^-100 covers subnormal
///   roundings, and inputs and results flushed to zero by FTZ / DAZ at cull time (at most a
///   few 2^-126).
/// Non-finite coordinates, or |C|_1 + |E|_1 past 2^120 (where s may overflow), give NaN.
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

/// ObbArrays::bound of `b`: a float bound >= |r| + 2^-18 |c|_1 for the reference's projected
/// radius r = (|a0| h0 + |a1| h1) + |a2| h2, a_i = (n.x u_i.x + n.y u_i.y) + n.z u_i.z, computed
/// in float for every normal n with |n| <= 1 + 2^-20, and the centre c; or NaN where no bound
/// is safe. With a margin m >= 2^-18 |d| (PlaneSet::max_margin) it settles the reference's test
/// from a centre distance s = n.c + d computed in float in any order, fused or not (or from a
/// mirrored plane's difference: CentreArrays in simd_kernels.inl has the room): s < -(bound
/// + m) means s_ref < -|r| (OUTSIDE), s >= bound + m on every plane s_ref >= |r| (INSIDE), s_ref
/// the reference's own centre distance. Why, with e = 2^-23 (a float rounding in any rounding
/// mode) and each rounding also off by at most 2^-149 in the subnormal range (flushing to zero
/// at cull time only shrinks a term):
/// - |a_i| <= (|n.x u.x| + |n.y u.y| + |n.z u.z|)(1 + e)^3 + 6 x 2^-149
///         <= |n| |u_i| (1 + e)^3 + 6 x 2^-149 (Cauchy-Schwarz);
/// - the products with h_i and the two sums add (1 + e)^3 and 5 x 2^-149, so
///   |r| <= [sum_i (|u_i| + 2^-140) |h_i|] (1 + 2^-16) (1 - e) + 2^-140, as
///   (1 + 2^-20)(1 + e)^6 / (1 - e) < 1 + 2^-16;
/// - and, tighter for a box (|h|_2 instead of |h|_1 for orthonormal axes): a_i differs from
///   n.u_i by at most 3.0001e (|n.x u.x| + |n.y u.y| + |n.z u.z|) <= 2^-21 |n| |u_i|, plus
///   less than 2^-122 where DAZ flushes a subnormal axis component (2^-125.2) or FTZ one of
///   a_i's products or partial sums (five, 2^-123.7; flushing here need not shrink a term);
///   sum_i |n.u_i| |h_i| <= |U^T n| |h|_2 <= |n| sqrt(L) |h|_2 (Cauchy-Schwarz), with U the
///   axes as columns and L >= the largest eigenvalue of the Gram matrix U^T U by Gershgorin:
///   L = max_i (|u_i|^2 + sum_j!=i |u_i.u_j|);
///   so |r| <= [sqrt(L) |h|_2 + 2^-21 sum_i |u_i| |h_i| + 2^-120 |h|_1] (1 + 2^-16) (1 - e),
///   the double arithmetic below (L, the square roots) within the factor 1 + 2^-39 it takes;
///   the bound takes the smaller of the two;
/// - s and s_ref are each within 6e (|n| |c|_1 + |d|) of n.c + d (three products and three
///   sums), so within 12e (1 + 2^-20)(|c|_1 + |d|) < 2^-18 (1 - e)(|c|_1 + |d|) of each other;
///   the float sum bound + m is at least (1 - e)(bound + m);
/// - that is computed here in double, with 2^-100 for the absolute terms (subnormal roundings,
///   inputs flushed by DAZ at cull time; the bound stays a normal float: DAZ would read a
///   subnormal one as 0), and rounded up to a float;
/// - NaN inputs give NaN, and so does |c|_1 past 2^120 (s could overflow). An axis component
///   of magnitude 2^125 or more gives NaN: past it a_i may overflow, and r may be inf - inf =
///   NaN while the bound is finite. Below it a_i is finite, so r is NaN only from 0 x inf (an
///   infinite h_i, which makes the bound inf) or inf - inf of two overflowed products (their
///   exact size makes the bound round up to inf). An infinite bound settles nothing (s is
///   finite when the bound and the margin are).
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
  const double tight = std::sqrt(gram_bound) * std::sqrt(h_squares) * (1.0 + 0x1p-39) + 0x1p-21 * sum + 0x1p-120 * h_sum;
  // (A NaN `tight`, from 0 x inf, leaves `sum`; a NaN `sum` stays NaN.)
  const double radius = tight < sum ? tight : sum;
  return float_at_least(radius * (1.0 + 0x1p-16) + 0x1p-18 * size + 0x1p-100);
}

/// SphereArrays::bound of `s`: with a margin m >= 2^-18 |d| (PlaneSet::max_margin) it settles
/// the reference's test (s_ref < -r: OUTSIDE, else s_ref < r: INTERSECTING, else INSIDE) for
/// every plane of normal |n| <= 1 + 2^-20 from a centre distance s computed in float in any
/// order, fused or not: s < -(bound + m) means s_ref < -|r| <= -r, and s >= bound + m on every
/// plane s_ref >= |r| >= r. Why, with e = 2^-23 as above: s and s_ref are within
/// 12e (1 + 2^-20)(|c|_1 + |d|) of each other (see obb_plane_bound), less than the
/// 2^-18 (1 - e)(|c|_1 + |d|) the bound and margin add; |r| (1 + 2^-20)(1 - e) >= |r| covers
/// the float sum bound + m rounding down; 2^-100 covers subnormal roundings and inputs (or a
/// radius) flushed to zero at cull time. Non-finite values or |c|_1 past 2^120 give NaN.
float sphere_plane_bound(const Sphere& s) {
  const double size = std::fabs(double(s.center.x)) + std::fabs(double(s.center.y)) + std::fabs(double(s.center.z));
  const double radius = std::fabs(double(s.radius));
  if (!(size <= 0x1p120) || !std::isfinite(radius)) return std::numeric_limits<float>::quiet_NaN();
  return float_at_least(radius * (1.0 + 0x1p-20) + 0x1p-18 * size + 0x1p-100);
}

// The lower bounds packed into the bounds' low bits (CentreArrays in simd_kernels.inl): per
// object a value X such that, for every plane k of a unit-normal PlaneSet, the reference's
// straddling threshold less every rounding of both centre distances is at least c_k X - m,
// with m the plane's margin (PlaneSet::max_margin) and c_k the factor the kind names (|n_k|_1
// for boxes, |n_k|_2 for OBBs, 1 for spheres). Then a fused smallest centre distance with
// |s| < c X - m, c the smallest c_k, means the reference's INTERSECTING: every plane's
// reference distance is above -(threshold) (not OUTSIDE) and the nearest one's below it. 0
// where none holds (negative extents or radius, non-orthogonal axes). (A mirrored plane's
// distance rounds more: CentreArrays in simd_kernels.inl shows the shares below cover it.)
//
// Spheres: the reference says OUTSIDE on a plane when s_ref < -r and straddles it when
// s_ref < r; s and s_ref are within 12e (1 + 2^-20)(|c|_1 + |d|) of each other (see
// obb_plane_bound), under 2^-18 |c|_1 + m. X = r (1 - 2^-20) - 2^-18 |c|_1; c_k = 1.
double sphere_lower(const Sphere& s) {
  const double size = std::fabs(double(s.center.x)) + std::fabs(double(s.center.y)) + std::fabs(double(s.center.z));
  return double(s.radius) * (1.0 - 0x1p-20) - 0x1p-18 * size;
}

// Boxes: with E_i >= 0 the exact vertex distances are D_c +- R, R = sum |n_i| E_i >=
// |n|_1 min E_i, and the reference's d_p, d_n and the kernel's s are within
// 11e (|n|_2 (|C|_1 + |E|_1) + |d|) of them and D_c (see aabb_plane_bound), which is at most
// |n|_1 2^-18 (|C|_1 + |E|_1) + m. X = min E_i (1 - 2^-50) - 2^-18 (|C|_1 + |E|_1) (the
// double sums round by 2^-52); c_k = |n_k|_1. Subnormal roundings and DAZ / FTZ change the
// distances by a few 2^-126, inside the 2^-100 of m.
double aabb_lower(const Aabb& b) {
  double size = 0.0, smallest = std::numeric_limits<double>::infinity();
  for (int a = 0; a < 3; ++a) {
    const double lo = b.min[a], hi = b.max[a], c = (lo + hi) / 2, e = (hi - lo) / 2;
    size += std::fabs(c) + std::fabs(e);
    smallest = std::min(smallest, e);
  }
  return smallest * (1.0 - 0x1p-50) - 0x1p-18 * size;  // (NaN for non-finite boxes: packs 0)
}

// OBBs: with h_i >= 0, r_ref = (|a0| h0 + |a1| h1) + |a2| h2 rounds each of its three
// products and sums down by at most a factor 1 - e, and |a_i| >= |n.u_i| - 3.01 e |n|_2 |u_i|
// (Cauchy-Schwarz on the dot product's rounding); sum |n.u_i| h_i >= min h |U^T n|_2 >=
// min h sqrt(g) |n|_2, g a Gershgorin bound on the smallest eigenvalue of U^T U (the axes'
// Gram matrix, in double: less 2^-48 of its largest diagonal for the sums' roundings; none
// for axes far from orthogonal). With every h_i normal (none for a subnormal one, which DAZ
// reads as 0), DAZ / FTZ and subnormal roundings take at most 2^-122 h_i more from each
// a_i h_i, and a few 2^-126 from the products and sums (inside m's 2^-100);
// the centre distances are within 12e |n|_2 |c|_1 + 12e |d| of each other. With
// |n|_2 >= 1/2 (PlaneSet::lower_scale_l2 is 0 otherwise),
// X = (min h sqrt(g) (1 - 2^-40) - 2^-21 sum |u_i| h_i)(1 - 2^-20) - 2^-17 |c|_1
// - 2^-118 sum h_i; c_k = |n_k|_2.
double obb_lower(const Obb& b) {
  double smallest = std::numeric_limits<double>::infinity(), sum = 0.0, spread = 0.0, size = 0.0;
  double gram[3][3];
  for (int i = 0; i < 3; ++i) {
    const double h = b.half_extents[i];
    if (!(h >= 0x1p-126) || !std::isfinite(h)) return 0.0;  // (DAZ would read a subnormal h as 0, losing all of |a_i| h)
    smallest = std::min(smallest, h);
    sum += h;
    for (int j = 0; j < 3; ++j)
      gram[i][j] = double(b.basis[i].x) * b.basis[j].x + double(b.basis[i].y) * b.basis[j].y + double(b.basis[i].z) * b.basis[j].z;
    spread += std::sqrt(gram[i][i]) * h;
    size += std::fabs(double(b.center[i]));
  }
  double g = std::numeric_limits<double>::infinity();
  for (int i = 0; i < 3; ++i) g = std::min(g, gram[i][i] - std::fabs(gram[i][(i + 1) % 3]) - std::fabs(gram[i][(i + 2) % 3]));
  g -= 0x1p-48 * std::max({gram[0][0], gram[1][1], gram[2][2]});
  if (!(g > 0.0) || !std::isfinite(g)) return 0.0;
  return (smallest * std::sqrt(g) * (1.0 - 0x1p-40) - 0x1p-21 * spread) * (1.0 - 0x1p-20) - 0x1p-17 * size - 0x1p-118 * sum;
}

/// `bound` (a float bound from the functions here) with its lowest 8 bits replaced by
/// q = floor(256 lower / bound') (0 to 255), bound' the bound rounded up to a multiple of 2^8
/// float steps: still a bound (it only grew, by less than 2^-14 of itself), and the kernels read
/// q bound / 256 <= lower (1 + 2^-15) back. NaN, infinite and zero bounds are kept as they are
/// and one that rounds up past the float range becomes infinite (each settles nothing either
/// way); past 2^119, q = 0, so that the kernels' q bound stays
/// finite (below 2^127: an infinite L would settle every lane).
float pack_lower(float bound, double lower) {
  if (!(bound > 0.0f) || !std::isfinite(bound)) return bound;
  std::uint32_t bits = (std::bit_cast<std::uint32_t>(bound) + 255u) & ~255u;  // (a carry into the exponent is still larger)
  const float rounded = std::bit_cast<float>(bits);
  if (!std::isfinite(rounded)) return rounded;
  const bool small = rounded <= 0x1p119f;
  const double q = small && lower > 0.0 ? std::floor(std::min(255.0, 256.0 * (lower / double(rounded)) * (1.0 - 0x1p-40))) : 0.0;
  return std::bit_cast<float>(bits | static_cast<std::uint32_t>(q));
}

float plane_margin(float d) {
  const double magnitude = std::fabs(double(d));
  return magnitude <= 0x1p120 ? float_at_least(0x1p-18 * magnitude + 0x1p-100) : std::numeric_limits<float>::quiet_NaN();
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
