// The SIMD culling kernels, written once with GCC/Clang vector extensions and compiled once per
// instruction set: the including file defines CULLPIPE_SIMD_NS (a namespace name) and
// CULLPIPE_SIMD_LANES (4, 8 or 16) and is built with the matching -m flags.
//
// Bit-exact with cullpipe::reference: every lane does the reference's float operations in the
// reference's order ((n.x*p.x + n.y*p.y) + n.z*p.z) + d, with contraction off (-ffp-contract=off
// is global), and the same comparisons. The reference's early exit at the first plane that
// rejects does not change its answer (OUTSIDE wins over everything found before or after), so
// the kernels OR the per-plane masks over all planes. Only the OBB kernel, whose per-plane work
// is large, stops early when every lane of a vector is OUTSIDE; for AABBs and spheres the
// mispredicted exits cost more than they save (measured: AABB, 1% visible, 0.69 -> 0.52 ns
// per object without them).
// The p/n-vertex choice depends only on the plane (the sign of each normal component, -0 as
// positive, as pn_vertices), so it is made once per plane by picking the min or max array.
#include <cstddef>
#include <cstdint>

#include "cull/simd_kernels.hpp"

#if defined(__x86_64__) || defined(__i386__)
#include <immintrin.h>
#endif

namespace cullpipe::fast::detail {
namespace CULLPIPE_SIMD_NS {
namespace {

constexpr unsigned W = CULLPIPE_SIMD_LANES;
static_assert(W == 4 || W == 8 || W == 16);
typedef float vf __attribute__((vector_size(W * 4)));
typedef std::int32_t vi __attribute__((vector_size(W * 4)));
typedef std::uint8_t vb __attribute__((vector_size(W)));

constexpr std::uint8_t kOutside = 0, kIntersecting = 1, kInside = 2;  // = Classification values

inline vf load(const float* p) {
  vf v;
  __builtin_memcpy(&v, p, sizeof v);
  return v;
}

/// Bit l set when lane l of `mask` (0 or -1 per lane) is set.
inline std::uint32_t lane_bits(vi mask) {
#if CULLPIPE_SIMD_LANES == 16 && defined(__AVX512F__)
  return _mm512_cmplt_epi32_mask(reinterpret_cast<__m512i>(mask), _mm512_setzero_si512());
#elif CULLPIPE_SIMD_LANES == 8 && defined(__AVX2__)
  return static_cast<std::uint32_t>(_mm256_movemask_ps(reinterpret_cast<__m256>(mask)));
#elif CULLPIPE_SIMD_LANES == 4 && defined(__SSE2__)
  return static_cast<std::uint32_t>(_mm_movemask_ps(reinterpret_cast<__m128>(mask)));
#else
  std::uint32_t bits = 0;
  for (unsigned l = 0; l < W; ++l) bits |= std::uint32_t(mask[l] != 0) << l;
  return bits;
#endif
}

constexpr std::uint32_t kAllLanes = (1u << W) - 1u;

inline vf abs(vf v) { return reinterpret_cast<vf>(reinterpret_cast<vi>(v) & 0x7fffffff); }

#if CULLPIPE_SIMD_LANES == 8 && defined(__AVX2__)
/// For each 8-bit lane mask, the indices of its set bits, packed to the front (one byte each).
struct CompressTable {
  std::uint64_t entry[256];
  constexpr CompressTable() : entry{} {
    for (unsigned m = 0; m < 256; ++m) {
      unsigned k = 0;
      for (unsigned l = 0; l < 8; ++l)
        if (m & (1u << l)) entry[m] |= std::uint64_t(l) << (8 * k++);
    }
  }
};
constexpr CompressTable kCompress;
#endif

/// Appends base + l for every set bit l of `lanes` at `ids`, in lane order; returns the new
/// end. May write up to W values past the new end (ChunkOutput::ids has that slack).
inline std::uint32_t* append_ids(std::uint32_t* ids, std::uint32_t base, std::uint32_t lanes) {
#if CULLPIPE_SIMD_LANES == 16 && defined(__AVX512F__)
  const __m512i index = _mm512_add_epi32(_mm512_set1_epi32(static_cast<int>(base)),
                                         _mm512_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15));
  _mm512_storeu_si512(ids, _mm512_maskz_compress_epi32(static_cast<__mmask16>(lanes), index));
#elif CULLPIPE_SIMD_LANES == 8 && defined(__AVX2__)
  const __m256i order = _mm256_cvtepu8_epi32(_mm_cvtsi64_si128(static_cast<long long>(kCompress.entry[lanes])));
  const __m256i index = _mm256_add_epi32(_mm256_set1_epi32(static_cast<int>(base)), order);
  _mm256_storeu_si256(reinterpret_cast<__m256i*>(ids), index);
#else
  std::uint32_t* out = ids;
  for (unsigned l = 0; l < W; ++l) {
    *out = base + l;
    out += (lanes >> l) & 1u;
  }
  return out;
#endif
  return ids + __builtin_popcount(lanes);
}

/// Writes the classes and visible ids of the W objects at `i` (of which `valid` are real) and
/// counts them. outside / crossing: lanes behind a plane / straddling one.
inline void emit(std::size_t i, std::size_t begin, unsigned valid, vi outside, vi crossing, ChunkOutput& out,
                 ChunkCounts& counts) {
  const std::uint32_t lanes = valid >= W ? kAllLanes : (1u << valid) - 1u;
  if (out.classes) {
    const vi cls = (kInside + crossing) & ~outside;  // crossing is -1: Inside - 1 = Intersecting
    const vb bytes = __builtin_convertvector(cls, vb);
    __builtin_memcpy(out.classes + (i - begin), &bytes, valid >= W ? W : valid);
  }
  std::uint32_t visible = lane_bits(~outside) & lanes;
  counts.visible += static_cast<std::uint32_t>(__builtin_popcount(visible));
  counts.inside += static_cast<std::uint32_t>(__builtin_popcount(lane_bits(~outside & ~crossing) & lanes));
  if (out.ids) out.ids = append_ids(out.ids, static_cast<std::uint32_t>(i), visible);
}

ChunkCounts cull_aabb(const AabbArrays& a, std::size_t begin, std::size_t end, const PlaneSet& planes, ChunkOutput out) {
  // Per plane, the arrays that hold the p-vertex (farthest along the normal) and n-vertex.
  const float *p_x[6], *p_y[6], *p_z[6], *n_x[6], *n_y[6], *n_z[6];
  for (std::uint32_t k = 0; k < planes.count; ++k) {
    const bool sx = planes.nx[k] >= 0.0f, sy = planes.ny[k] >= 0.0f, sz = planes.nz[k] >= 0.0f;
    p_x[k] = sx ? a.max_x : a.min_x, n_x[k] = sx ? a.min_x : a.max_x;
    p_y[k] = sy ? a.max_y : a.min_y, n_y[k] = sy ? a.min_y : a.max_y;
    p_z[k] = sz ? a.max_z : a.min_z, n_z[k] = sz ? a.min_z : a.max_z;
  }
  ChunkCounts counts;
  const vf zero = {};
  for (std::size_t i = begin; i < end; i += W) {
    vi outside = {}, crossing = {};
    for (std::uint32_t k = 0; k < planes.count; ++k) {
      const float nx = planes.nx[k], ny = planes.ny[k], nz = planes.nz[k], d = planes.d[k];
      const vf dp = ((nx * load(p_x[k] + i) + ny * load(p_y[k] + i)) + nz * load(p_z[k] + i)) + d;
      const vf dn = ((nx * load(n_x[k] + i) + ny * load(n_y[k] + i)) + nz * load(n_z[k] + i)) + d;
      outside |= dp < zero;
      crossing |= dn < zero;
    }
    emit(i, begin, static_cast<unsigned>(end - i), outside, crossing, out, counts);
  }
  return counts;
}

ChunkCounts cull_obb(const ObbArrays& a, std::size_t begin, std::size_t end, const PlaneSet& planes, ChunkOutput out) {
  ChunkCounts counts;
  for (std::size_t i = begin; i < end; i += W) {
    const vf cx = load(a.c_x + i), cy = load(a.c_y + i), cz = load(a.c_z + i);
    vi outside = {}, crossing = {};
    for (std::uint32_t k = 0; k < planes.count; ++k) {
      const float nx = planes.nx[k], ny = planes.ny[k], nz = planes.nz[k], d = planes.d[k];
      const vf s = ((nx * cx + ny * cy) + nz * cz) + d;
      const vf a0 = (nx * load(a.u0_x + i) + ny * load(a.u0_y + i)) + nz * load(a.u0_z + i);
      const vf a1 = (nx * load(a.u1_x + i) + ny * load(a.u1_y + i)) + nz * load(a.u1_z + i);
      const vf a2 = (nx * load(a.u2_x + i) + ny * load(a.u2_y + i)) + nz * load(a.u2_z + i);
      const vf r = (abs(a0) * load(a.h_x + i) + abs(a1) * load(a.h_y + i)) + abs(a2) * load(a.h_z + i);
      outside |= s < -r;
      crossing |= s < r;
      if (lane_bits(outside) == kAllLanes) break;
    }
    emit(i, begin, static_cast<unsigned>(end - i), outside, crossing, out, counts);
  }
  return counts;
}

ChunkCounts cull_sphere(const SphereArrays& a, std::size_t begin, std::size_t end, const PlaneSet& planes, ChunkOutput out) {
  ChunkCounts counts;
  for (std::size_t i = begin; i < end; i += W) {
    const vf cx = load(a.c_x + i), cy = load(a.c_y + i), cz = load(a.c_z + i), radius = load(a.radius + i);
    vi outside = {}, crossing = {};
    for (std::uint32_t k = 0; k < planes.count; ++k) {
      const vf s = ((planes.nx[k] * cx + planes.ny[k] * cy) + planes.nz[k] * cz) + planes.d[k];
      outside |= s < -radius;
      crossing |= s < radius;
    }
    emit(i, begin, static_cast<unsigned>(end - i), outside, crossing, out, counts);
  }
  return counts;
}

std::uint32_t touch(const float* data, std::size_t begin, std::size_t end) {
  vi acc0 = {}, acc1 = {}, acc2 = {}, acc3 = {};
  std::size_t i = begin;
  for (; i + 4 * W <= end; i += 4 * W) {  // four independent chains keep several loads in flight
    acc0 |= reinterpret_cast<vi>(load(data + i));
    acc1 |= reinterpret_cast<vi>(load(data + i + W));
    acc2 |= reinterpret_cast<vi>(load(data + i + 2 * W));
    acc3 |= reinterpret_cast<vi>(load(data + i + 3 * W));
  }
  for (; i < end; i += W) acc0 |= reinterpret_cast<vi>(load(data + i));
  const vi all = (acc0 | acc1) | (acc2 | acc3);
  std::uint32_t bits = 0;
  for (unsigned l = 0; l < W; ++l) bits |= static_cast<std::uint32_t>(all[l]);
  return bits;
}

}  // namespace
}  // namespace CULLPIPE_SIMD_NS
}  // namespace cullpipe::fast::detail
