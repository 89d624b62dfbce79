// The SIMD culling kernels, written once with GCC/Clang vector extensions and compiled once per
// instruction set: the including file defines CULLPIPE_SIMD_NS (a namespace name) and
// CULLPIPE_SIMD_LANES (4, 8 or 16) and is built with the matching -m flags.
//
// Bit-exact with cullpipe::reference: every lane does the reference's float operations in the
// reference's order ((n.x*p.x + n.y*p.y) + n.z*p.z) + d, with contraction off (-ffp-contract=off
// is global), and the same comparisons. The reference's early exit at the first plane that
// rejects does not change its answer (OUTSIDE wins over everything found before or after), so
// the kernels OR the per-plane masks over all planes (early exits per vector, measured on
// AABBs and spheres, cost more in mispredictions than they saved).
// AABBs and OBBs are first settled by a bound (cull_settled): only the objects it leaves open
// get the reference's test, so no answer depends on the bound's own arithmetic.
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

// (Not std::min: this file must not instantiate inline functions the rest of the program shares.)
inline std::size_t smaller(std::size_t x, std::size_t y) { return x < y ? x : y; }

/// Lanes of the set bits of `bits` (0 or -1 per lane).
inline vi lanes_of(std::uint32_t bits) {
  vi lane_bit;
  for (unsigned l = 0; l < W; ++l) lane_bit[l] = static_cast<std::int32_t>(1u << l);
  return (static_cast<std::int32_t>(bits) & lane_bit) != 0;
}

/// Transposes the first `words` floats of the records of up to W objects, objects[0..count),
/// into vectors: col[c] lane l = word c of objects[l] (lanes past count repeat objects[0]).
template <unsigned Words>
void gather_records(const float* records, std::size_t record_floats, const std::uint32_t* objects, unsigned count, vf (&col)[Words]) {
  alignas(64) float lanes[Words][W];
  for (unsigned l = 0; l < W; ++l) {
    const float* rec = records + std::size_t(objects[l < count ? l : 0]) * record_floats;
    for (unsigned c = 0; c < Words; ++c) lanes[c][l] = rec[c];
  }
  for (unsigned c = 0; c < Words; ++c) col[c] = load(lanes[c]);
}

/// a * b + c, fused where the instruction set has it. Only for bounds, never for a distance
/// the reference computes (those are written out in its order).
inline vf mul_add(float a, vf b, vf c) {
#if CULLPIPE_SIMD_LANES == 16 && defined(__AVX512F__)
  return reinterpret_cast<vf>(_mm512_fmadd_ps(_mm512_set1_ps(a), reinterpret_cast<__m512>(b), reinterpret_cast<__m512>(c)));
#elif CULLPIPE_SIMD_LANES == 8 && defined(__FMA__)
  return reinterpret_cast<vf>(_mm256_fmadd_ps(_mm256_set1_ps(a), reinterpret_cast<__m256>(b), reinterpret_cast<__m256>(c)));
#else
  return a * b + c;
#endif
}

// The AABB and OBB kernels first settle what a cheap bound decides: `settle(i, beyond,
// within)` gives the lanes of the vector of objects from i that the reference would find
// OUTSIDE (beyond) or INSIDE (within), from 16 bytes per object read in order. The few
// objects the bound leaves open (those near a plane: about 1% of random scenes) are gathered
// per run of kRunBlocks vectors, their records prefetched as they are found, tested in full by
// `resolve(objects, count, outside_bits, crossing_bits)`, and the run's results emitted in
// object order.
template <class Settle, class Resolve>
ChunkCounts cull_settled(std::size_t begin, std::size_t end, const float* records, std::size_t record_floats, Settle settle,
                         Resolve resolve, ChunkOutput out) {
  constexpr std::size_t kRunBlocks = 256;
  std::uint32_t outside_bits[kRunBlocks], crossing_bits[kRunBlocks];
  std::uint32_t open[kRunBlocks * W];  // objects left open in this run
  ChunkCounts counts;
  for (std::size_t run = begin; run < end; run += kRunBlocks * W) {
    const std::size_t run_end = smaller(end, run + kRunBlocks * W);
    unsigned open_count = 0;
    for (std::size_t i = run, b = 0; i < run_end; i += W, ++b) {
      vi beyond, within;
      settle(i, beyond, within);
      const unsigned valid = static_cast<unsigned>(smaller(W, run_end - i));
      const std::uint32_t lanes = valid >= W ? kAllLanes : (1u << valid) - 1u;
      outside_bits[b] = lane_bits(beyond);
      crossing_bits[b] = 0;
      for (std::uint32_t rest = ~lane_bits(beyond | within) & lanes; rest != 0; rest &= rest - 1) {
        const std::uint32_t object = static_cast<std::uint32_t>(i + static_cast<unsigned>(__builtin_ctz(rest)));
        __builtin_prefetch(records + std::size_t(object) * record_floats);
        open[open_count++] = object;
      }
    }
    for (unsigned o = 0; o < open_count; o += W) {
      const unsigned count = static_cast<unsigned>(smaller(W, open_count - o));
      std::uint32_t outside, crossing;
      resolve(open + o, count, outside, crossing);
      for (unsigned l = 0; l < count; ++l) {
        const std::size_t at = open[o + l] - run;
        const std::uint32_t bit = 1u << (at % W);
        if (outside >> l & 1u) outside_bits[at / W] |= bit;
        if (crossing >> l & 1u) crossing_bits[at / W] |= bit;
      }
    }
    for (std::size_t i = run, b = 0; i < run_end; i += W, ++b)
      emit(i, begin, static_cast<unsigned>(end - i), lanes_of(outside_bits[b]), lanes_of(crossing_bits[b]), out, counts);
  }
  return counts;
}

// AABBs: the bound b (aabb_plane_bound) covers the half diagonal and every rounding of both
// the reference's p/n-vertex distances and the centre distance s computed here (in any order,
// fused where possible); with the plane's share m_k <= m = PlaneSet::max_margin, s < -(b + m)
// makes the p-vertex distance negative (OUTSIDE) and s >= b + m on every plane makes both
// vertex distances non-negative (INSIDE). The open boxes get the reference's p/n-vertex test.
ChunkCounts cull_aabb(const AabbArrays& a, std::size_t begin, std::size_t end, const PlaneSet& planes, ChunkOutput out) {
  const vi none = {}, all = ~none;
  auto settle = [&](std::size_t i, vi& beyond, vi& within) {
    beyond = within = none;
    if (!planes.unit_normals) return;  // the bound assumes unit normals: test every box in full
    const vf cx = load(a.c_x + i), cy = load(a.c_y + i), cz = load(a.c_z + i);
    // Every plane's margin share is at most max_margin: a reach that covers them all (rounding
    // is monotonic), added once per vector instead of once per plane.
    const vf reach = load(a.bound + i) + planes.max_margin, neg_reach = -reach;
    within = all;
    for (std::uint32_t k = 0; k < planes.count; ++k) {
      const vf s = mul_add(planes.nz[k], cz, mul_add(planes.ny[k], cy, mul_add(planes.nx[k], cx, vf{} + planes.d[k])));
      beyond |= s < neg_reach;
      within &= s >= reach;  // a NaN bound or margin settles neither
    }
  };
  auto resolve = [&](const std::uint32_t* objects, unsigned count, std::uint32_t& outside_bits, std::uint32_t& crossing_bits) {
    vf box[6];  // min x y z, max x y z
    gather_records(a.records, kAabbRecordFloats, objects, count, box);
    const vf zero = {};
    vi outside = {}, crossing = {};
    for (std::uint32_t k = 0; k < planes.count; ++k) {
      const float nx = planes.nx[k], ny = planes.ny[k], nz = planes.nz[k], d = planes.d[k];
      // The p-vertex (farthest along the normal) and n-vertex, as pn_vertices (-0 as positive).
      const bool sx = nx >= 0.0f, sy = ny >= 0.0f, sz = nz >= 0.0f;
      const vf dp = ((nx * box[sx ? 3 : 0] + ny * box[sy ? 4 : 1]) + nz * box[sz ? 5 : 2]) + d;
      const vf dn = ((nx * box[sx ? 0 : 3] + ny * box[sy ? 1 : 4]) + nz * box[sz ? 2 : 5]) + d;
      outside |= dp < zero;
      crossing |= dn < zero;
    }
    outside_bits = lane_bits(outside);
    crossing_bits = lane_bits(crossing);
  };
  return cull_settled(begin, end, a.records, kAabbRecordFloats, settle, resolve, out);
}

// OBBs: the bound b >= |r| (obb_plane_bound) on the projected radius; s is the reference's own
// centre distance, so s < -b on some plane is OUTSIDE and s >= b on all is INSIDE.
ChunkCounts cull_obb(const ObbArrays& a, std::size_t begin, std::size_t end, const PlaneSet& planes, ChunkOutput out) {
  const vi none = {}, all = ~none;
  auto settle = [&](std::size_t i, vi& beyond, vi& within) {
    beyond = within = none;
    if (!planes.unit_normals) return;  // the bound assumes unit normals: test every box in full
    const vf cx = load(a.c_x + i), cy = load(a.c_y + i), cz = load(a.c_z + i), bound = load(a.bound + i);
    within = all;
    for (std::uint32_t k = 0; k < planes.count; ++k) {
      const vf s = ((planes.nx[k] * cx + planes.ny[k] * cy) + planes.nz[k] * cz) + planes.d[k];
      beyond |= s < -bound;
      within &= s >= bound;  // a NaN bound settles neither
    }
  };
  auto resolve = [&](const std::uint32_t* objects, unsigned count, std::uint32_t& outside_bits, std::uint32_t& crossing_bits) {
    vf col[15];  // centre, axes u0 u1 u2, half extents
    gather_records(a.records, kObbRecordFloats, objects, count, col);
    vi outside = {}, crossing = {};
    for (std::uint32_t k = 0; k < planes.count; ++k) {
      const float nx = planes.nx[k], ny = planes.ny[k], nz = planes.nz[k];
      const vf s = ((nx * col[0] + ny * col[1]) + nz * col[2]) + planes.d[k];
      const vf a0 = (nx * col[3] + ny * col[4]) + nz * col[5];
      const vf a1 = (nx * col[6] + ny * col[7]) + nz * col[8];
      const vf a2 = (nx * col[9] + ny * col[10]) + nz * col[11];
      const vf r = (abs(a0) * col[12] + abs(a1) * col[13]) + abs(a2) * col[14];
      outside |= s < -r;
      crossing |= s < r;
    }
    outside_bits = lane_bits(outside);
    crossing_bits = lane_bits(crossing);
  };
  return cull_settled(begin, end, a.records, kObbRecordFloats, settle, resolve, out);
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
