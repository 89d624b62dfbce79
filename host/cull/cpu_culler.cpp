#include "cull/cpu_culler.hpp"

#include <algorithm>
#include <bit>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <limits>
#include <new>
#include <stdexcept>
#include <string>
#if defined(__SSE__)
#include <xmmintrin.h>
#endif

#include "cull/aligned_vector.hpp"
#include "cull/kernel_select.hpp"
#include "cull/plane_bounds.hpp"
#include "cull/simd_kernels.hpp"
#include "cull/thread_pool.hpp"

namespace cullpipe::fast {

namespace {

constexpr std::size_t kPad = 16;  // widest vector, in floats

bool cpu_runs(Isa isa) {
#if defined(CULLPIPE_HAVE_X86_KERNELS)
  switch (isa) {
    case Isa::Portable: return true;
    case Isa::Avx2: return __builtin_cpu_supports("avx2") && __builtin_cpu_supports("fma");
    case Isa::Avx512: return __builtin_cpu_supports("avx512f");
  }
  return false;
#else
  return isa == Isa::Portable;
#endif
}

constexpr double kUnitNormalLimit = 1.0 + 0x1p-20;  // PlaneSet::unit_normals

/// A float >= x, for x >= 2^-126 (no subnormal result) or NaN (stays NaN); past the float
/// range, inf. Rounding x (1 + 2^-23) to nearest loses at most a factor 1 - 2^-24. (No
/// nextafter: a library call per object made uploads 7x slower.)
float round_up(double x) {
  const double up = x * (1.0 + 0x1p-23);
  return up > double(std::numeric_limits<float>::max()) ? std::numeric_limits<float>::infinity() : static_cast<float>(up);
}

/// Round to nearest without flushing subnormals, for the scope: the bounds are computed in
/// that mode whatever the caller's (under DAZ a subnormal extent would read as 0 and the
/// bound would leave out what it adds to the radius; the proofs assume round to nearest).
/// The pool runs tasks in the caller's mode, so each upload task sets its own.
struct NearestNoFlush {
#if defined(__SSE__)
  unsigned saved = _mm_getcsr();
  NearestNoFlush() { _mm_setcsr(0x1F80); }  // all exceptions masked, nearest, no FTZ / DAZ
  ~NearestNoFlush() { _mm_setcsr(saved); }
#endif
  NearestNoFlush(const NearestNoFlush&) = delete;
  NearestNoFlush& operator=(const NearestNoFlush&) = delete;
};

}  // namespace

namespace detail {

KernelTable kernels(Isa isa) {
#if defined(CULLPIPE_HAVE_X86_KERNELS)
  if (isa == Isa::Avx512) return avx512_kernels();
  if (isa == Isa::Avx2) return avx2_kernels();
#endif
  (void)isa;
  return portable_kernels();
}

PlaneSet plane_set(const Frustum& f) {
  PlaneSet s;
  s.count = static_cast<std::uint32_t>(std::min<std::size_t>(f.plane_count, 6));
  s.unit_normals = true;
  for (std::uint32_t k = 0; k < s.count; ++k) {
    const glm::vec3 n = f.planes[k].normal;
    s.nx[k] = n.x;
    s.ny[k] = n.y;
    s.nz[k] = n.z;
    s.d[k] = f.planes[k].d;
    const double length = std::sqrt(double(n.x) * n.x + double(n.y) * n.y + double(n.z) * n.z);
    s.unit_normals = s.unit_normals && length <= kUnitNormalLimit;  // false for NaN too
    const double d = std::fabs(double(f.planes[k].d));
    const float margin = d <= 0x1p120 ? round_up(0x1p-18 * d + 0x1p-100) : std::numeric_limits<float>::quiet_NaN();
    s.max_margin = std::isnan(s.max_margin) || std::isnan(margin) ? std::numeric_limits<float>::quiet_NaN() : std::max(s.max_margin, margin);
  }
  // The lower bounds' factors: the smallest |n|_1 and |n|_2, rounded down, times 2^-8 (q's
  // step) and 1 - 2^-12, which covers the packing's 2^-15 and the kernel's three roundings.
  double l1 = std::numeric_limits<double>::infinity(), l2 = l1;
  for (std::uint32_t k = 0; k < s.count; ++k) {
    const double x = s.nx[k], y = s.ny[k], z = s.nz[k];
    l1 = std::min(l1, std::fabs(x) + std::fabs(y) + std::fabs(z));
    l2 = std::min(l2, std::sqrt(x * x + y * y + z * z));
  }
  auto scale = [](double c) { return c >= 0.5 && c <= 2.0 ? static_cast<float>(c * (1.0 - 0x1p-30) * 0x1p-8 * (1.0 - 0x1p-12)) : 0.0f; };
  s.lower_scale_l1 = scale(l1);
  s.lower_scale_l2 = scale(l2);
  // The first pair of planes whose normals are opposite within kMirrorSlack (float sums are
  // exact in double).
  auto mirrors = [&](std::uint32_t i, std::uint32_t j) {
    return std::fabs(double(s.nx[i]) + s.nx[j]) <= kMirrorSlack && std::fabs(double(s.ny[i]) + s.ny[j]) <= kMirrorSlack &&
           std::fabs(double(s.nz[i]) + s.nz[j]) <= kMirrorSlack;
  };
  for (std::uint32_t i = 0; i < s.count && !s.mirrored; ++i)
    for (std::uint32_t j = i + 1; j < s.count && !s.mirrored; ++j)
      if (mirrors(i, j)) s.mirrored = true, s.mirror_base = i, s.mirror_plane = j;
  return s;
}

}  // namespace detail

namespace {

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
  return round_up(radius * (1.0 + 0x1p-16) + 0x1p-18 * size + 0x1p-100);
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
  return round_up(radius * (1.0 + 0x1p-20) + 0x1p-18 * size + 0x1p-100);
}

}  // namespace

namespace detail {

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

}  // namespace detail

namespace {

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
  return round_up(std::sqrt(diagonal) * (1.0 + 0x1p-16) + 0x1p-18 * size + 0x1p-100);
}

}  // namespace

namespace detail {

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

float settle_margin(const Frustum& frustum) {
  const PlaneSet s = plane_set(frustum);
  return s.unit_normals ? s.max_margin : std::numeric_limits<float>::quiet_NaN();
}

}  // namespace detail

namespace {

/// Frees the columns, which come from CacheLineAllocator: on a cache line, and from 4 MiB on
/// a 2 MiB boundary with transparent huge pages asked for.
struct ColumnsFree {
  std::size_t floats = 0;
  void operator()(float* p) const { detail::CacheLineAllocator<float>().deallocate(p, floats); }
};

}  // namespace

std::string_view to_string(Isa isa) {
  switch (isa) {
    case Isa::Portable: return "portable";
    case Isa::Avx2: return "avx2";
    case Isa::Avx512: return "avx512";
  }
  return "invalid";
}

std::optional<Isa> parse_isa(std::string_view name) {
  for (Isa isa : {Isa::Portable, Isa::Avx2, Isa::Avx512})
    if (name == to_string(isa)) return isa;
  return std::nullopt;
}

bool isa_supported(Isa isa) { return cpu_runs(isa); }

std::vector<Isa> supported_isas() {
  std::vector<Isa> isas;
  for (Isa isa : {Isa::Portable, Isa::Avx2, Isa::Avx512})
    if (cpu_runs(isa)) isas.push_back(isa);
  return isas;
}

Isa best_isa() {
  Isa best = Isa::Portable;
  for (Isa isa : {Isa::Avx2, Isa::Avx512})
    if (cpu_runs(isa)) best = isa;
  if (const char* env = std::getenv("CULLPIPE_ISA")) {
    const std::optional<Isa> wanted = parse_isa(env);
    if (wanted && static_cast<int>(*wanted) < static_cast<int>(best)) best = *wanted;
  }
  return best;
}

struct CpuCuller::Impl {
  explicit Impl(unsigned threads) : pool(threads) {}
  ThreadPool pool;
  detail::KernelTable table{};
  std::size_t chunk = 16384;
  std::size_t padded = 0;     // floats per component array
  std::unique_ptr<float[], ColumnsFree> data;
  std::size_t capacity = 0;   // floats allocated
  std::vector<const float*> arrays;  // component array starts
  float* records = nullptr;          // per-object records after the arrays (OBB), or null
  std::size_t record_size = 0;       // floats per record
  // Per view: visible ids, written per chunk into slots of chunk + kPad, then gathered; and
  // per chunk the visible lanes of every run's vectors and a word per run (ChunkOutput).
  std::vector<std::unique_ptr<std::uint32_t[]>> scratch, bits, runs;
  std::size_t scratch_size = 0, bits_size = 0, runs_size = 0;
  std::vector<detail::ChunkCounts> chunk_counts;  // [view * chunks + chunk]
  std::vector<std::size_t> offsets;               // [view * chunks + chunk]: first id's index in the view's list
  std::vector<detail::PlaneSet> planes;           // per view of the current pass

  /// Room for `components` arrays of `count` objects, each padded with zeros to kPad, then
  /// `record_floats` floats per object (records, also padded with zeros).
  float* reserve(std::size_t components, std::size_t count, std::size_t record_floats = 0) {
    padded = (count + kPad - 1) / kPad * kPad + kPad;  // one spare vector: loads past the end stay in bounds
    const std::size_t floats = (components + record_floats) * padded;
    if (floats > capacity) {
      data = std::unique_ptr<float[], ColumnsFree>(detail::CacheLineAllocator<float>().allocate(floats), ColumnsFree{floats});
      capacity = floats;
    }
    arrays.resize(components);
    for (std::size_t c = 0; c < components; ++c) {
      arrays[c] = data.get() + c * padded;
      std::memset(data.get() + c * padded + count, 0, (padded - count) * sizeof(float));  // the padding
    }
    record_size = record_floats;
    records = record_floats ? data.get() + components * padded : nullptr;  // 64-byte aligned: padded % 16 == 0
    if (records) std::memset(records + count * record_floats, 0, (padded - count) * record_floats * sizeof(float));
    return data.get();
  }
  float* column(std::size_t c) { return data.get() + c * padded; }
};

CpuCuller::CpuCuller(const CpuCullerConfig& config) {
  isa_ = config.isa.value_or(best_isa());
  if (!isa_supported(isa_))
    throw std::invalid_argument("CpuCuller: this CPU (or build) cannot run the " + std::string(to_string(isa_)) + " kernels");
  impl_ = std::make_unique<Impl>(config.threads);
  impl_->table = detail::kernels(isa_);
  impl_->chunk = std::max<std::size_t>(kPad, (config.chunk_objects + kPad - 1) / kPad * kPad);
}

CpuCuller::~CpuCuller() = default;

unsigned CpuCuller::threads() const { return impl_->pool.size(); }

namespace {
void check_count(std::size_t n) {
  if (n > std::numeric_limits<std::uint32_t>::max())
    throw std::length_error("CpuCuller: " + std::to_string(n) + " objects; object ids are 32-bit (at most 4294967295)");
}
}  // namespace

template <std::size_t Columns, std::size_t RecordFloats, class Volume, class Store>
void CpuCuller::upload_columns(std::span<const Volume> volumes, Store store) {
  check_count(volumes.size());
  count_ = 0;  // stays 0 if the allocation fails
  impl_->reserve(Columns, volumes.size(), RecordFloats);
  float* c[Columns + 1];
  for (std::size_t k = 0; k < Columns; ++k) c[k] = impl_->column(k);
  c[Columns] = impl_->records;
  // In tasks of `chunk` objects on the pool: the bounds take a few square roots per object.
  const std::size_t n = volumes.size(), per_task = impl_->chunk;
  impl_->pool.parallel_for((n + per_task - 1) / per_task, [&](std::size_t t) {
    const NearestNoFlush mode;
    const std::size_t end = std::min(n, (t + 1) * per_task);
    for (std::size_t i = t * per_task; i < end; ++i) store(volumes[i], c, i);
  });
  kind_ = kind_of<Volume>();
  count_ = volumes.size();
}

void CpuCuller::upload(std::span<const Aabb> volumes) {
  static_assert(detail::kAabbRecordFloats == 8);
  upload_columns<4, detail::kAabbRecordFloats>(volumes, [](const Aabb& b, float* const* c, std::size_t i) {
    glm::vec3 centre;
    c[3][i] = detail::pack_lower(aabb_plane_bound(b, centre), detail::aabb_lower(b));
    c[0][i] = centre.x, c[1][i] = centre.y, c[2][i] = centre.z;
    float* record = c[4] + i * detail::kAabbRecordFloats;  // as cull_aabb's resolve reads it
    for (int a = 0; a < 3; ++a) {
      record[a] = b.min[a];
      record[3 + a] = b.max[a];
    }
    record[6] = record[7] = 0.0f;
  });
}

void CpuCuller::upload(std::span<const Obb> volumes) {
  static_assert(detail::kObbRecordFloats == 16);
  upload_columns<4, detail::kObbRecordFloats>(volumes, [](const Obb& b, float* const* c, std::size_t i) {
    c[0][i] = b.center.x, c[1][i] = b.center.y, c[2][i] = b.center.z;
    c[3][i] = detail::pack_lower(obb_plane_bound(b), detail::obb_lower(b));
    float* record = c[4] + i * detail::kObbRecordFloats;  // as classify_obb_records reads it
    for (int a = 0; a < 3; ++a) {
      record[a] = b.center[a];
      record[3 + a] = b.basis[0][a];
      record[6 + a] = b.basis[1][a];
      record[9 + a] = b.basis[2][a];
      record[12 + a] = b.half_extents[a];
    }
    record[15] = 0.0f;
  });
}

void CpuCuller::upload(std::span<const Sphere> volumes) {
  upload_columns<5, 0>(volumes, [](const Sphere& s, float* const* c, std::size_t i) {
    c[0][i] = s.center.x, c[1][i] = s.center.y, c[2][i] = s.center.z;
    c[3][i] = detail::pack_lower(sphere_plane_bound(s), detail::sphere_lower(s));
    c[4][i] = s.radius;
  });
}

std::size_t CpuCuller::bytes_per_object() const { return (impl_->arrays.size() + impl_->record_size) * sizeof(float); }

namespace {
/// Reads each of `spans`, split into tasks of at most `per_task` floats, and ORs what it read.
std::uint32_t touch_spans(ThreadPool& pool, const detail::KernelTable& table, std::span<const std::span<const float>> spans,
                          std::size_t per_task) {
  std::vector<std::size_t> first_task(spans.size() + 1, 0);  // tasks of span s: first_task[s] ..
  for (std::size_t s = 0; s < spans.size(); ++s)
    first_task[s + 1] = first_task[s] + std::max<std::size_t>(1, (spans[s].size() + per_task - 1) / per_task);
  std::vector<std::uint32_t> bits(first_task.back(), 0);
  pool.parallel_for(bits.size(), [&](std::size_t t) {
    const std::size_t s = static_cast<std::size_t>(std::upper_bound(first_task.begin(), first_task.end(), t) - first_task.begin()) - 1;
    const float* data = spans[s].data();
    const std::size_t begin = (t - first_task[s]) * per_task, end = std::min(spans[s].size(), begin + per_task);
    if (begin >= end) return;
    const std::size_t whole = begin + (end - begin) / kPad * kPad;
    std::uint32_t b = table.touch(data, begin, whole);
    for (std::size_t i = whole; i < end; ++i) {
      std::uint32_t word;
      std::memcpy(&word, data + i, sizeof word);
      b |= word;
    }
    bits[t] = b;
  });
  std::uint32_t all = 0;
  for (std::uint32_t b : bits) all |= b;
  return all;
}
}  // namespace

std::uint32_t CpuCuller::touch(std::span<const float> data) {
  return touch_spans(impl_->pool, impl_->table, {&data, 1}, impl_->chunk * 8);
}

std::uint32_t CpuCuller::touch_bounds(bool streamed_only) {
  // Only the objects' floats (rounded up to a vector), not the spare padding.
  if (!count_) return 0;
  const std::size_t used = (count_ + kPad - 1) / kPad * kPad;
  std::vector<std::span<const float>> spans;
  constexpr std::size_t kStreamed = kStreamedBytesPerObject / sizeof(float);  // the first columns: centre x y z, bound
  for (std::size_t c = 0; c < impl_->arrays.size() && (!streamed_only || c < kStreamed); ++c) spans.emplace_back(impl_->arrays[c], used);
  if (impl_->records && !streamed_only) spans.emplace_back(impl_->records, used * impl_->record_size);
  return touch_spans(impl_->pool, impl_->table, spans, impl_->chunk);
}

std::uint32_t CpuCuller::touch_streamed_side_by_side() {
  if (!count_) return 0;
  const std::size_t used = (count_ + kPad - 1) / kPad * kPad, chunks = (used + impl_->chunk - 1) / impl_->chunk;
  static_assert(kStreamedBytesPerObject == 4 * sizeof(float));  // the first four arrays
  const float* const columns[4] = {impl_->arrays[0], impl_->arrays[1], impl_->arrays[2], impl_->arrays[3]};
  std::vector<std::uint32_t> bits(chunks, 0);
  impl_->pool.parallel_for(chunks, [&](std::size_t t) {
    const std::size_t begin = t * impl_->chunk;
    bits[t] = impl_->table.touch_columns(columns, begin, std::min(used, begin + impl_->chunk));
  });
  std::uint32_t all = 0;
  for (std::uint32_t b : bits) all |= b;
  return all;
}

std::vector<CpuViewResult> CpuCuller::cull(std::span<const Frustum> views, const CpuCullOptions& options) {
  std::vector<CpuViewResult> results;
  cull(views, options, results);
  return results;
}

void CpuCuller::cull(std::span<const Frustum> views, const CpuCullOptions& options, std::vector<CpuViewResult>& results) {
  Impl& m = *impl_;
  const std::size_t n = count_;
  const std::size_t chunks = std::max<std::size_t>(1, (n + m.chunk - 1) / m.chunk);
  results.resize(views.size());
  std::vector<detail::PlaneSet>& planes = m.planes;  // kept between calls: no allocation per pass
  planes.clear();
  for (const Frustum& f : views) planes.push_back(detail::plane_set(f));
  // Each chunk writes its visible ids at its own slot of the view's scratch (chunk size plus
  // the kernels' slack), then they are gathered in chunk order.
  // Dense runs (more than a quarter visible) leave their ids out of the scratch: they are
  // listed from the runs' bits straight into the result, each id written once instead of
  // twice (4*10^6 boxes, half of them visible, medians of 5 interleaved runs: 0.407 -> 0.364
  // ns/object against 0.22 to read; unchanged at 1% and 10%, whose runs are sparse).
  const std::size_t slot = m.chunk + kPad;
  const std::size_t bits_slot = m.chunk / m.table.lanes, runs_slot = (m.chunk + detail::kRunObjects - 1) / detail::kRunObjects;
  if (options.visible_ids) {
    auto room = [&](std::vector<std::unique_ptr<std::uint32_t[]>>& buffers, std::size_t& size, std::size_t need) {
      if (size < need) {  // too small: reallocate every view's
        buffers.clear();
        size = need;
      }
      if (buffers.size() < views.size()) buffers.resize(views.size());
      for (std::size_t v = 0; v < views.size(); ++v)
        if (!buffers[v]) buffers[v].reset(new std::uint32_t[size]());  // zeros: the kernels read `runs` as a guess
    };
    room(m.scratch, m.scratch_size, chunks * slot);
    room(m.bits, m.bits_size, chunks * bits_slot);
    room(m.runs, m.runs_size, chunks * runs_slot);
  }
  for (CpuViewResult& r : results) {
    if (options.classes) r.classes.resize(n);
    else r.classes.clear();
  }
  m.chunk_counts.assign(views.size() * chunks, {});

  const std::vector<const float*>& a = m.arrays;
  auto chunk_end = [&](std::size_t begin) { return std::min(n, begin + m.chunk); };
  // View v's chunk `chunk`, task v * chunks + chunk of the counts and offsets.
  auto cull_chunk = [&](std::size_t v, std::size_t chunk) {
    const std::size_t task = v * chunks + chunk;
    const std::size_t begin = chunk * m.chunk, end = chunk_end(begin);
    if (begin >= end) return;
    detail::ChunkOutput out;
    if (options.classes) out.classes = reinterpret_cast<std::uint8_t*>(results[v].classes.data()) + begin;
    if (options.visible_ids) {
      out.ids = m.scratch[v].get() + chunk * slot;
      out.bits = m.bits[v].get() + chunk * bits_slot;
      out.runs = m.runs[v].get() + chunk * runs_slot;
    }
    detail::ChunkCounts& counts = m.chunk_counts[task];
    switch (kind_) {
      case BvKind::Aabb:
        counts = m.table.aabb(detail::AabbArrays{a[0], a[1], a[2], a[3], m.records}, begin, end, planes[v], out);
        break;
      case BvKind::Obb:
        counts = m.table.obb(detail::ObbArrays{a[0], a[1], a[2], a[3], m.records}, begin, end, planes[v], out);
        break;
      case BvKind::Sphere:
        counts = m.table.sphere(detail::SphereArrays{a[0], a[1], a[2], a[3], a[4]}, begin, end, planes[v], out);
        break;
    }
  };
  // Several views: each chunk read from memory once for all of them. With enough chunks to
  // keep every thread busy, a task is one chunk and every view in turn, its centres and bounds
  // (256 KiB) in the thread's L2 after the first; with fewer, a task is one chunk and one view,
  // tasks of one chunk next to each other, so that every thread works. (4*10^6 boxes, 4 views:
  // a chunk per task 0.76-0.83x the time of four single-view passes, a chunk and view per task
  // 0.79-0.84x, and 8% slower than a chunk per task; NOTES.)
  const std::size_t view_count = views.size();
  if (view_count > 1 && chunks >= 4 * std::size_t(m.pool.size())) {
    m.pool.parallel_for(chunks, [&](std::size_t chunk) {
      for (std::size_t v = 0; v < view_count; ++v) cull_chunk(v, chunk);
    });
  } else {
    m.pool.parallel_for(view_count * chunks, [&](std::size_t t) { cull_chunk(t % view_count, t / view_count); });
  }

  m.offsets.assign(views.size() * chunks, 0);
  for (std::size_t v = 0; v < views.size(); ++v) {
    CpuViewResult& r = results[v];
    r.counts = {};
    for (std::size_t c = 0; c < chunks; ++c) {
      m.offsets[v * chunks + c] = r.counts.visible;
      r.counts.visible += m.chunk_counts[v * chunks + c].visible;
      r.counts.inside += m.chunk_counts[v * chunks + c].inside;
    }
    r.counts.intersecting = r.counts.visible - r.counts.inside;
    // resize, not clear + resize: a reused result only initialises what it grows by.
    r.visible_ids.resize(options.visible_ids ? r.counts.visible : 0);
  }
  if (!options.visible_ids) return;
  m.pool.parallel_for(views.size() * chunks, [&](std::size_t task) {
    const std::size_t v = task / chunks, chunk = task % chunks;
    const std::size_t begin = chunk * m.chunk, end = chunk_end(begin);
    if (begin >= end) return;
    const std::uint32_t* ids = m.scratch[v].get() + chunk * slot;
    const std::uint32_t* bits = m.bits[v].get() + chunk * bits_slot;
    const std::uint32_t* runs = m.runs[v].get() + chunk * runs_slot;
    std::uint32_t* out = results[v].visible_ids.data() + m.offsets[task];
    const std::uint32_t* const out_end = out + m.chunk_counts[task].visible;
    for (std::size_t run = begin, r = 0; run < end; run += detail::kRunObjects, ++r) {
      if (runs[r] & detail::kDenseRun) {
        const std::size_t vectors = (std::min(end, run + detail::kRunObjects) - run + m.table.lanes - 1) / m.table.lanes;
        out = m.table.expand(bits + (run - begin) / m.table.lanes, vectors, static_cast<std::uint32_t>(run), out, out_end);
      } else {
        const std::uint32_t count = runs[r] & detail::kRunCount;
        out = std::copy(ids, ids + count, out);
        ids += count;
      }
    }
  });
}

}  // namespace cullpipe::fast
