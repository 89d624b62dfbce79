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
#include <type_traits>

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
typedef std::uint32_t vu __attribute__((vector_size(W * 4)));
typedef std::uint8_t vb __attribute__((vector_size(W)));

constexpr std::uint8_t kOutside = 0, kIntersecting = 1, kInside = 2;  // = Classification values

inline vf load(const float* p) {
  vf v;
  __builtin_memcpy(&v, p, sizeof v);
  return v;
}
inline vi load_ints(const std::uint32_t* p) {
  vi v;
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

/// True when every bit of `v` is 0.
inline bool all_zero(vi v) {
#if CULLPIPE_SIMD_LANES == 16 && defined(__AVX512F__)
  return _mm512_test_epi32_mask(reinterpret_cast<__m512i>(v), reinterpret_cast<__m512i>(v)) == 0;
#elif CULLPIPE_SIMD_LANES == 8 && defined(__AVX2__)
  return _mm256_testz_si256(reinterpret_cast<__m256i>(v), reinterpret_cast<__m256i>(v)) != 0;
#else
  return lane_bits(v != 0) == 0;
#endif
}

/// lane_bits(a < b) and lane_bits(a >= b) (both false where either is NaN), straight into a
/// mask where the instruction set has mask registers.
inline std::uint32_t less_bits(vf a, vf b) {
#if CULLPIPE_SIMD_LANES == 16 && defined(__AVX512F__)
  return _mm512_cmp_ps_mask(reinterpret_cast<__m512>(a), reinterpret_cast<__m512>(b), _CMP_LT_OQ);
#else
  return lane_bits(a < b);
#endif
}
inline std::uint32_t at_least_bits(vf a, vf b) {
#if CULLPIPE_SIMD_LANES == 16 && defined(__AVX512F__)
  return _mm512_cmp_ps_mask(reinterpret_cast<__m512>(a), reinterpret_cast<__m512>(b), _CMP_GE_OQ);
#else
  return lane_bits(a >= b);
#endif
}

/// A vector of x in every lane.
inline vf splat(float x) {
  vf v;
  for (unsigned l = 0; l < W; ++l) v[l] = x;
  return v;
}

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
/// (AVX-512: the compress merges into its own source, not into zeros. The zeroing form waits
/// for the last write of its destination register on this Zen 5, so back-to-back compresses
/// ran one after another: listing ids from bits, 0.078 ->
/// 0.040 ns/object on one thread in cache; a pass's listing at 10^6 objects, half visible,
/// 0.044 -> 0.034. The lanes past the compressed ones are garbage either way.)
inline std::uint32_t* append_ids(std::uint32_t* ids, std::uint32_t base, std::uint32_t lanes) {
#if CULLPIPE_SIMD_LANES == 16 && defined(__AVX512F__)
  const __m512i index = _mm512_add_epi32(_mm512_set1_epi32(static_cast<int>(base)),
                                         _mm512_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15));
  _mm512_storeu_si512(ids, _mm512_mask_compress_epi32(index, static_cast<__mmask16>(lanes), index));
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

/// Writes the lanes of `values` whose bit is set in `lanes` to out[0..], in lane order; may
/// write up to W values (the caller has that room). (The zeroing compress here: the merging
/// one, as in append_ids, measured the same in the hierarchy's listing, which waits on its
/// loads of the ids instead.)
inline void compress_store(std::uint32_t* out, vi values, std::uint32_t lanes) {
#if CULLPIPE_SIMD_LANES == 16 && defined(__AVX512F__)
  _mm512_storeu_si512(out, _mm512_maskz_compress_epi32(static_cast<__mmask16>(lanes), reinterpret_cast<__m512i>(values)));
#elif CULLPIPE_SIMD_LANES == 8 && defined(__AVX2__)
  const __m256i order = _mm256_cvtepu8_epi32(_mm_cvtsi64_si128(static_cast<long long>(kCompress.entry[lanes])));
  _mm256_storeu_si256(reinterpret_cast<__m256i*>(out), _mm256_permutevar8x32_epi32(reinterpret_cast<__m256i>(values), order));
#else
  for (unsigned l = 0; l < W; ++l) {
    *out = static_cast<std::uint32_t>(values[l]);
    out += (lanes >> l) & 1u;
  }
#endif
}

// (Not std::min: this file must not instantiate inline functions the rest of the program shares.)
inline std::size_t smaller(std::size_t x, std::size_t y) { return x < y ? x : y; }

/// Lanes of the set bits of `bits` (0 or -1 per lane).
inline vi lanes_of(std::uint32_t bits) {
  vi lane_bit;
  for (unsigned l = 0; l < W; ++l) lane_bit[l] = static_cast<std::int32_t>(1u << l);
  return (static_cast<std::int32_t>(bits) & lane_bit) != 0;
}

/// Writes the classes and visible ids of the W objects at `i` (of which `valid` are real) and
/// counts them, from their lane bits: `outside` behind a plane, `crossing` straddling one
/// (counts only where not outside).
inline void emit(std::size_t i, std::size_t begin, unsigned valid, std::uint32_t outside, std::uint32_t crossing, ChunkOutput& out,
                 ChunkCounts& counts) {
  const std::uint32_t lanes = valid >= W ? kAllLanes : (1u << valid) - 1u;
  const std::uint32_t visible = ~outside & lanes;
  if (out.classes) {
    const vi cls = (kInside + lanes_of(crossing)) & ~lanes_of(outside);  // crossing is -1: Inside - 1 = Intersecting
    const vb bytes = __builtin_convertvector(cls, vb);
    __builtin_memcpy(out.classes + (i - begin), &bytes, valid >= W ? W : valid);
  }
  counts.visible += static_cast<std::uint32_t>(__builtin_popcount(visible));
  counts.inside += static_cast<std::uint32_t>(__builtin_popcount(visible & ~crossing));
  if (out.ids) out.ids = append_ids(out.ids, static_cast<std::uint32_t>(i), visible);
}

/// Transposes W records of `Floats` floats (4, 8 or 16), the records at records + at[l] *
/// Floats (lanes past `count` repeat the first): col[c] lane l = word c of record l. With
/// AVX2 or SSE by register shuffles; otherwise through memory (narrow stores read back wide
/// stall store forwarding: a cost the shuffles avoid).
template <unsigned Floats>
inline void gather_columns(const float* records, const std::uint32_t* at, unsigned count, vf (&col)[Floats]) {
  static_assert(Floats == 4 || Floats == 8 || Floats == 16);
  const float* row[W];
  for (unsigned l = 0; l < W; ++l) row[l] = records + std::size_t(at[l < count ? l : 0]) * Floats;
#if CULLPIPE_SIMD_LANES == 16 && defined(__AVX512F__)
  // Four records per register, one per 128-bit lane, transposed within the lanes as SSE does;
  // with 8-float records, two per register (256-bit halves), transposed as AVX2 does, and the
  // 128-bit blocks put in record order at the end. (Vector-extension shuffles: GCC 12's
  // AVX-512 shuffle intrinsics trip -Wmaybe-uninitialized in its own header.)
  typedef float v4f __attribute__((vector_size(16)));
  typedef float v8f __attribute__((vector_size(32)));
  auto unpack_lo = [](vf x, vf y) { return __builtin_shufflevector(x, y, 0, 16, 1, 17, 4, 20, 5, 21, 8, 24, 9, 25, 12, 28, 13, 29); };
  auto unpack_hi = [](vf x, vf y) { return __builtin_shufflevector(x, y, 2, 18, 3, 19, 6, 22, 7, 23, 10, 26, 11, 27, 14, 30, 15, 31); };
  auto pick_low_pairs = [](vf x, vf y) { return __builtin_shufflevector(x, y, 0, 1, 16, 17, 4, 5, 20, 21, 8, 9, 24, 25, 12, 13, 28, 29); };
  auto pick_high_pairs = [](vf x, vf y) { return __builtin_shufflevector(x, y, 2, 3, 18, 19, 6, 7, 22, 23, 10, 11, 26, 27, 14, 15, 30, 31); };
  if constexpr (Floats == 4) {
    vf a[4];
    for (unsigned i = 0; i < 4; ++i) {  // lane k of a[i]: record 4k + i
      v4f r[4];
      for (unsigned k = 0; k < 4; ++k) __builtin_memcpy(&r[k], row[i + 4 * k], sizeof r[k]);
      const v8f lo = __builtin_shufflevector(r[0], r[1], 0, 1, 2, 3, 4, 5, 6, 7), hi = __builtin_shufflevector(r[2], r[3], 0, 1, 2, 3, 4, 5, 6, 7);
      a[i] = __builtin_shufflevector(lo, hi, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15);
    }
    const vf t0 = unpack_lo(a[0], a[1]), t1 = unpack_hi(a[0], a[1]), t2 = unpack_lo(a[2], a[3]), t3 = unpack_hi(a[2], a[3]);
    col[0] = pick_low_pairs(t0, t2);
    col[1] = pick_high_pairs(t0, t2);
    col[2] = pick_low_pairs(t1, t3);
    col[3] = pick_high_pairs(t1, t3);
  } else {
    for (unsigned base = 0; base < Floats; base += 8) {
      vf a[8];
      for (unsigned i = 0; i < 8; ++i) {  // records i (low half) and i + 8 (high half)
        v8f lo, hi;
        __builtin_memcpy(&lo, row[i] + base, sizeof lo);
        __builtin_memcpy(&hi, row[i + 8] + base, sizeof hi);
        a[i] = __builtin_shufflevector(lo, hi, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15);
      }
      vf u[8];
      for (unsigned h = 0; h < 8; h += 4) {  // per 128-bit lane: records h..h+3 (or + 8), columns c or c + 4
        const vf t0 = unpack_lo(a[h], a[h + 1]), t1 = unpack_hi(a[h], a[h + 1]);
        const vf t2 = unpack_lo(a[h + 2], a[h + 3]), t3 = unpack_hi(a[h + 2], a[h + 3]);
        u[h] = pick_low_pairs(t0, t2);
        u[h + 1] = pick_high_pairs(t0, t2);
        u[h + 2] = pick_low_pairs(t1, t3);
        u[h + 3] = pick_high_pairs(t1, t3);
      }
      // u[c] blocks: records 0-3 column c, 0-3 column c + 4, 8-11 column c, 8-11 column c + 4;
      // u[c + 4] the same for records 4-7 and 12-15.
      for (unsigned c = 0; c < 4; ++c) {
        col[base + c] = __builtin_shufflevector(u[c], u[c + 4], 0, 1, 2, 3, 16, 17, 18, 19, 8, 9, 10, 11, 24, 25, 26, 27);
        col[base + c + 4] = __builtin_shufflevector(u[c], u[c + 4], 4, 5, 6, 7, 20, 21, 22, 23, 12, 13, 14, 15, 28, 29, 30, 31);
      }
    }
  }
#elif CULLPIPE_SIMD_LANES == 8 && defined(__AVX2__)
  if constexpr (Floats == 4) {
    __m256 a[4];
    for (unsigned i = 0; i < 4; ++i) a[i] = _mm256_insertf128_ps(_mm256_castps128_ps256(_mm_loadu_ps(row[i])), _mm_loadu_ps(row[i + 4]), 1);
    const __m256 t0 = _mm256_unpacklo_ps(a[0], a[1]), t1 = _mm256_unpackhi_ps(a[0], a[1]);
    const __m256 t2 = _mm256_unpacklo_ps(a[2], a[3]), t3 = _mm256_unpackhi_ps(a[2], a[3]);
    col[0] = reinterpret_cast<vf>(_mm256_shuffle_ps(t0, t2, 0x44));
    col[1] = reinterpret_cast<vf>(_mm256_shuffle_ps(t0, t2, 0xEE));
    col[2] = reinterpret_cast<vf>(_mm256_shuffle_ps(t1, t3, 0x44));
    col[3] = reinterpret_cast<vf>(_mm256_shuffle_ps(t1, t3, 0xEE));
  } else {
    for (unsigned base = 0; base < Floats; base += 8) {
      __m256 a[8];
      for (unsigned i = 0; i < 8; ++i) a[i] = _mm256_loadu_ps(row[i] + base);
      __m256 u[8];
      for (unsigned h = 0; h < 8; h += 4) {  // records h..h+3: columns c (low half) and c + 4 (high half)
        const __m256 t0 = _mm256_unpacklo_ps(a[h], a[h + 1]), t1 = _mm256_unpackhi_ps(a[h], a[h + 1]);
        const __m256 t2 = _mm256_unpacklo_ps(a[h + 2], a[h + 3]), t3 = _mm256_unpackhi_ps(a[h + 2], a[h + 3]);
        u[h] = _mm256_shuffle_ps(t0, t2, 0x44);
        u[h + 1] = _mm256_shuffle_ps(t0, t2, 0xEE);
        u[h + 2] = _mm256_shuffle_ps(t1, t3, 0x44);
        u[h + 3] = _mm256_shuffle_ps(t1, t3, 0xEE);
      }
      for (unsigned c = 0; c < 4; ++c) {
        col[base + c] = reinterpret_cast<vf>(_mm256_permute2f128_ps(u[c], u[c + 4], 0x20));
        col[base + c + 4] = reinterpret_cast<vf>(_mm256_permute2f128_ps(u[c], u[c + 4], 0x31));
      }
    }
  }
#elif CULLPIPE_SIMD_LANES == 4 && defined(__SSE2__)
  for (unsigned base = 0; base < Floats; base += 4) {
    __m128 r0 = _mm_loadu_ps(row[0] + base), r1 = _mm_loadu_ps(row[1] + base), r2 = _mm_loadu_ps(row[2] + base),
           r3 = _mm_loadu_ps(row[3] + base);
    _MM_TRANSPOSE4_PS(r0, r1, r2, r3);
    col[base] = reinterpret_cast<vf>(r0);
    col[base + 1] = reinterpret_cast<vf>(r1);
    col[base + 2] = reinterpret_cast<vf>(r2);
    col[base + 3] = reinterpret_cast<vf>(r3);
  }
#else
  alignas(64) float lanes[Floats][W];
  for (unsigned l = 0; l < W; ++l)
    for (unsigned c = 0; c < Floats; ++c) lanes[c][l] = row[l][c];
  for (unsigned c = 0; c < Floats; ++c) col[c] = load(lanes[c]);
#endif
}

/// The lanes of p[0..W) whose bit is set in `lanes` (the others 0, and not read: p may end
/// before them).
inline vi load_ints_where(const std::uint32_t* p, std::uint32_t lanes) {
#if CULLPIPE_SIMD_LANES == 16 && defined(__AVX512F__)
  return reinterpret_cast<vi>(_mm512_maskz_loadu_epi32(static_cast<__mmask16>(lanes), p));
#elif CULLPIPE_SIMD_LANES == 8 && defined(__AVX2__)
  return reinterpret_cast<vi>(_mm256_maskload_epi32(reinterpret_cast<const int*>(p), reinterpret_cast<__m256i>(lanes_of(lanes))));
#else
  vi v = {};
  for (unsigned l = 0; l < W; ++l)
    if (lanes & (1u << l)) v[l] = static_cast<std::int32_t>(p[l]);
  return v;
#endif
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

/// a * b - c, fused where the instruction set has it (bounds only).
inline vf mul_sub(vf a, vf b, vf c) {
#if CULLPIPE_SIMD_LANES == 16 && defined(__AVX512F__)
  return reinterpret_cast<vf>(_mm512_fmsub_ps(reinterpret_cast<__m512>(a), reinterpret_cast<__m512>(b), reinterpret_cast<__m512>(c)));
#elif CULLPIPE_SIMD_LANES == 8 && defined(__FMA__)
  return reinterpret_cast<vf>(_mm256_fmsub_ps(reinterpret_cast<__m256>(a), reinterpret_cast<__m256>(b), reinterpret_cast<__m256>(c)));
#else
  return a * b - c;
#endif
}

// Every kind is first settled by a bound: per object a centre c and a bound b (AabbArrays,
// ObbArrays, SphereArrays) such that, with reach = b + PlaneSet::max_margin and s = n.c + d
// computed in float in any order, fused or not, s < -reach on some plane is the reference's
// OUTSIDE and s >= reach on every plane its INSIDE (the proofs: aabb_plane_bound,
// obb_plane_bound and sphere_plane_bound in cpu_culler.cpp). Both conditions are decided by the
// smallest s over the planes, so a vector of objects costs three fused multiply-adds and a min
// per plane, and two comparisons. The few objects the bound leaves open (those near a plane:
// under 1% of random scenes) are gathered per run of kRunBlocks vectors, their records
// prefetched as they are found (`prefetch(object)`), tested in full by `resolve(objects,
// count, outside_bits, crossing_bits)` (the reference's own operations), and the run's results emitted in object
// order. Without unit normals (PlaneSet::unit_normals) no bound holds and every object is
// resolved. A NaN bound or margin settles nothing (both comparisons are false); a finite bound
// and margin mean finite centres and planes (|c|_1, |d| <= 2^120), so every s is finite.
//
// The bound's lowest 8 bits also hold q, 0 to 255 (pack_lower in cpu_culler.cpp), so that
// L = (q b) lower_scale - PlaneSet::max_margin, computed in float in any order, is a lower
// bound on the reference's straddling threshold less every rounding, on every plane
// (lower_scale: the kind's factor, PlaneSet::lower_scale_l1 for boxes and _l2 for OBBs, 2^-8
// (1 - 2^-12) for spheres): |s| < L for the smallest s means every plane's reference distance
// is above -threshold (not OUTSIDE) and the nearest plane's below +threshold: INTERSECTING,
// settled without the full test. The bits cost no bytes (the bound grew by less than 2^-14 of
// itself to hold them) and six vector operations; they settle the straddling objects whose
// centre is nearer the plane than their smallest extent (spheres: than their radius), which
// left the open objects of the benchmark's scenes at 4*10^6 and half visible 0.61 -> 0.26%
// (boxes), 0.72 -> 0.56% (OBBs), 0.43 -> 0.012% (spheres): at 4*10^6 objects 3-9% faster for
// boxes and spheres, 1-2.5% for OBBs; at 10^6 (in cache) 7-18% faster at half visible, 2-6%
// slower at 1% (NOTES). A NaN bound (q b NaN), an infinite one (q = 0: 0 x inf is NaN), a
// scale of 0 (NaN or -m) or L <= 0 settles nothing; q is 0 past 2^119, so q b stays finite.
//
// A mirrored plane j (PlaneSet::mirrored: n_j = -n_i + delta, |delta| <= kMirrorSlack = 2^-21
// per component; a frustum's far plane against its near one, which from a perspective matrix
// takes a modest depth range: see the README; an orthographic frustum's first pair, its left
// and right planes: taking its other two pairs so too was 5-13% slower at 1% and 10% visible
// on a Zen 5, NOTES) gets s_j = (d_i + d_j) - s_i, from its base plane's fused distance s_i:
// one subtraction for three fused multiply-adds (10^6 boxes in cache: 1-4% faster than the
// same loop without the pair; NOTES). With e = 2^-23 and |n_i| <=
// 1 + 2^-20, s_i is within 6e (1 + 2^-20)(|c|_1 + |d_i|) of n_i.c + d_i, the float d_i + d_j
// within 2e max|d| of the
// sum, the subtraction within e (|c|_1 + 3 max|d|)(1 + 2^-20), and n_j.c + d_j differs from
// (d_i + d_j) - (n_i.c + d_i) by delta.c, at most 4e |c|_1: s_j is within 11.01e (|c|_1 +
// max|d|) of n_j.c + d_j, plus a few 2^-126 under FTZ / DAZ (inside the bounds' 2^-100). The
// proofs in cpu_culler.cpp take 6e (|n| |c|_1 + |d|) for a kernel's distance and have room for
// this: with the reference's share, spheres and OBBs need 17.01e of the 2^-18 = 32e their bound
// and margin add; boxes 4.5e |n| + 11.01e against 32e; the lower bounds' centre shares hold
// 17.01e |c|_1 (spheres: 2^-18 |c|_1; boxes: 2^-18 |n|_1 (|C|_1 + |E|_1) with |n|_1 >= 1/2 where
// one settles, against 4.5e |n|_1 + 11.01e <= 26.6e |n|_1; OBBs: 2^-17 |n|_2 |c|_1 with |n|_2 >=
// 1/2, against 6.01e |n|_2 + 11.01e <= 28.1e |n|_2); every |d| term, at most 17.01e max|d|,
// is inside m >= 2^-18 max|d| (PlaneSet::max_margin is the largest over the planes).
struct CentreArrays {
  const float *c_x, *c_y, *c_z, *bound;
};

/// Removes from ids[0..count) (ascending) the k values gone[0..k) (ascending, each one in ids).
inline void remove_ids(std::uint32_t* ids, std::uint32_t count, const std::uint32_t* gone, unsigned k) {
  auto find = [&](std::uint32_t from, std::uint32_t value) {  // its index, at or after `from`
    std::uint32_t hi = count;
    while (from < hi) {
      const std::uint32_t mid = from + (hi - from) / 2;
      if (ids[mid] < value) from = mid + 1;
      else hi = mid;
    }
    return from;
  };
  std::uint32_t at = find(0, gone[0]);
  for (unsigned j = 0; j < k; ++j) {  // the ids between gone[j] and gone[j + 1] move down j + 1
    const std::uint32_t next = j + 1 < k ? find(at + 1, gone[j + 1]) : count;
    __builtin_memmove(ids + at - j, ids + at + 1, (next - at - 1) * sizeof *ids);
    at = next;
  }
}

template <class Prefetch, class Resolve>
ChunkCounts cull_settled(const CentreArrays& a, std::size_t begin, std::size_t end, const PlaneSet& planes, float lower_scale, Prefetch prefetch,
                         Resolve resolve, ChunkOutput out) {
  constexpr std::size_t kRunBlocks = kRunObjects / W;
  constexpr unsigned kRemovedAtMost = 64;  // appended ids removed one by one, at most
  static_assert(kRunObjects % W == 0);
  std::uint32_t run_bits[kRunBlocks], crossing_bits[kRunBlocks];
  std::uint32_t open[kRunBlocks * W];  // objects left open in this run
  // The planes in the order the loop reads them, padded to six with copies of the first (a
  // repeated plane leaves the smallest distance as it is), so it has a fixed trip count. With
  // a mirrored pair (PlaneSet::mirrored), its base plane first and the mirrored plane left
  // out: five planes, the sixth distance (d_base + d_mirrored) less the first's.
  const bool mirrored = planes.mirrored;
  std::uint32_t order[6] = {};
  unsigned listed = 0;
  if (mirrored) order[listed++] = planes.mirror_base;
  for (std::uint32_t k = 0; k < planes.count; ++k)
    if (!mirrored || (k != planes.mirror_base && k != planes.mirror_plane)) order[listed++] = k;
  for (unsigned k = listed; k < 6; ++k) order[k] = order[0];
  const bool settles = planes.unit_normals, no_planes = planes.count == 0;
  const bool bound_settles = settles && !__builtin_isnan(planes.max_margin);  // a NaN margin settles nothing
  const bool listed_by_runs = out.ids && out.runs && out.bits;
  ChunkCounts counts;
  for (std::size_t run = begin; run < end; run += kRunBlocks * W) {
    const std::size_t run_end = smaller(end, run + kRunBlocks * W);
    // Each vector's visible lanes, counted as they are found (open objects as visible until
    // resolved), written where a dense run leaves them: the counts and the bits need no second
    // pass over the run. The settled visible objects are INSIDE or (`across`) INTERSECTING,
    // so the INSIDE count is the visible count less the open objects and the settled
    // INTERSECTING ones, plus those resolved INSIDE.
    std::uint32_t* const run_visible_bits = listed_by_runs ? out.bits + (run - begin) / W : run_bits;
    // A run guessed sparse appends its visible lanes' ids as it finds them, its open objects
    // among them until resolved (removed after if OUTSIDE): the appends overlap the loads
    // instead of taking a loop of their own after the run (at 1% and 10% visible, 10^6
    // objects: 9-14% faster, 4*10^6: 0-15%; NOTES).
    const std::size_t run_index = (run - begin) / kRunObjects;
    // (Not where no bound can settle an object: every object would be appended, most of them
    // to be removed.)
    const bool appending = out.ids && bound_settles && (!listed_by_runs || !(out.runs[run_index] & (kDenseRun | kListedDense)));
    unsigned open_count = 0;
    std::uint32_t run_visible = 0, run_across = 0;
    // The run's vectors, by a loop made once for each of appending or not, classes or not and
    // a mirrored plane or not (no test of any per vector), reading local copies of the planes
    // and pointers and counting in locals written back after: no store in the loop can change
    // them, so none is reloaded per vector. Each loop is a function of its own: inlined into
    // this one, GCC 12 compiled the loop without a mirrored plane, the one most views take
    // (a perspective frustum from a game's depth range has no pair), 1.5-1.6x slower than
    // the loop with one (10^6 objects in cache, AVX-512; AVX2 1.1x; NOTES).
    // crossing_bits is read only for classes: each vector's settled INTERSECTING lanes, and
    // the open objects found crossing set their bits.
    auto scan = [&](auto append_c, auto classes_c, auto mirror_c) __attribute__((noinline)) {
      constexpr bool kAppend = decltype(append_c)::value, kClasses = decltype(classes_c)::value;
      constexpr bool kMirror = decltype(mirror_c)::value;
      std::uint32_t visible_count = 0, across_count = 0;
      unsigned opened_count = 0;
      const float *const c_x = a.c_x, *const c_y = a.c_y, *const c_z = a.c_z, *const bound = a.bound;
      float nx[6], ny[6], nz[6];
      vf d[6];
      for (unsigned k = 0; k < 6; ++k)
        nx[k] = planes.nx[order[k]], ny[k] = planes.ny[order[k]], nz[k] = planes.nz[order[k]], d[k] = splat(planes.d[order[k]]);
      const vf margin = splat(planes.max_margin), lower = splat(lower_scale);
      const vf mirror_d = splat(planes.d[planes.mirror_base] + planes.d[planes.mirror_plane]);
      std::uint32_t* const visible_bits = run_visible_bits;
      std::uint32_t* const run_ids = out.ids;
      // Vector b (objects i..i+W-1, `lanes` of them in range) found OUTSIDE (`beyond`), INSIDE
      // (`within`) and INTERSECTING (`across`); the rest are open.
      auto record = [&](std::size_t i, std::size_t b, std::uint32_t lanes, std::uint32_t beyond, std::uint32_t within, std::uint32_t across) __attribute__((always_inline)) {
        const std::uint32_t visible = ~beyond & lanes;
        visible_bits[b] = visible;
        if constexpr (kAppend) append_ids(run_ids + visible_count, static_cast<std::uint32_t>(i), visible);
        visible_count += static_cast<std::uint32_t>(__builtin_popcount(visible));
        across &= lanes;
        across_count += static_cast<std::uint32_t>(__builtin_popcount(across));
        if constexpr (kClasses) crossing_bits[b] = across;
        for (std::uint32_t rest = visible & ~(within | across); rest != 0; rest &= rest - 1) {  // the open lanes
          const std::uint32_t object = static_cast<std::uint32_t>(i + static_cast<unsigned>(__builtin_ctz(rest)));
          prefetch(object);
          open[opened_count++] = object;
        }
      };
      auto settle = [&](std::size_t i, std::size_t b, std::uint32_t lanes) __attribute__((always_inline)) {
        const vf cx = load(c_x + i), cy = load(c_y + i), cz = load(c_z + i);
        const vf stored = load(bound + i);
        const vf reach = stored + margin;
        const vf first_s = mul_add(nz[0], cz, mul_add(ny[0], cy, mul_add(nx[0], cx, d[0])));
        vf m = first_s;
        for (unsigned k = 1; k < (kMirror ? 5 : 6); ++k) {
          const vf s = mul_add(nz[k], cz, mul_add(ny[k], cy, mul_add(nx[k], cx, d[k])));
          m = s < m ? s : m;
        }
        if constexpr (kMirror) {
          const vf s = mirror_d - first_s;
          m = s < m ? s : m;
        }
        const vf q = __builtin_convertvector(reinterpret_cast<vi>(stored) & 255, vf);
        const vf reach_in = mul_sub(q * stored, lower, margin);
        record(i, b, lanes, less_bits(m, -reach), at_least_bits(m, reach), less_bits(abs(m), reach_in));
      };
      std::size_t first = run, block = 0;  // the next vector's first object and index
      if (settles && !no_planes) {
        // A cache line of each stream per step (kLine / W vectors, no lane checks), its line
        // kAhead floats on prefetched: without the prefetch, 4*10^6 boxes took 0.34-0.37
        // ns/object counting (the loads alone, 0.21), with it 0.25. The lines whose prefetch
        // stays in the chunk come first, in a loop of their own: no test per line (10^6
        // objects: up to 6% faster than a test per line; NOTES).
        constexpr std::size_t kLine = 16, kAhead = 1024;  // floats
        static_assert(kLine % W == 0);
        const std::size_t lines_end = run_end - (run_end - run) % kLine;
        const std::size_t prefetched_end = end > kAhead ? smaller(lines_end, end - kAhead > run ? end - kAhead : run) : run;
        auto line = [&](std::size_t at) __attribute__((always_inline)) {
#pragma GCC unroll 4
          for (unsigned v = 0; v < kLine / W; ++v, ++block) settle(at + v * W, block, kAllLanes);
        };
        for (; first + kLine <= prefetched_end; first += kLine) {
          __builtin_prefetch(c_x + first + kAhead);
          __builtin_prefetch(c_y + first + kAhead);
          __builtin_prefetch(c_z + first + kAhead);
          __builtin_prefetch(bound + first + kAhead);
          line(first);
        }
        for (; first < lines_end; first += kLine) line(first);
        for (; first < run_end; first += W, ++block)  // the last vectors (loads past the end stay in the columns' spare vector)
          settle(first, block, run_end - first >= W ? kAllLanes : (1u << (run_end - first)) - 1u);
      } else {
        for (; first < run_end; first += W, ++block)  // no bound holds (every object open), or no planes (every object INSIDE)
          record(first, block, run_end - first >= W ? kAllLanes : (1u << (run_end - first)) - 1u, 0, no_planes ? kAllLanes : 0, 0);
      }
      run_visible = visible_count;
      run_across = across_count;
      open_count = opened_count;
    };
    const std::true_type yes;
    const std::false_type no;
    if (mirrored) {
      if (appending) out.classes ? scan(yes, yes, yes) : scan(yes, no, yes);
      else out.classes ? scan(no, yes, yes) : scan(no, no, yes);
    } else {
      if (appending) out.classes ? scan(yes, yes, no) : scan(yes, no, no);
      else out.classes ? scan(no, yes, no) : scan(no, no, no);
    }
    std::uint32_t run_inside = run_visible - open_count - run_across;
    const std::uint32_t appended = run_visible;
    unsigned gone = 0;  // the open objects found OUTSIDE, gathered at the front of `open`
    for (unsigned o = 0; o < open_count; o += W) {
      const unsigned count = static_cast<unsigned>(smaller(W, open_count - o));
      std::uint32_t outside, crossing;
      resolve(open + o, count, outside, crossing);
      for (unsigned l = 0; l < count; ++l) {
        const std::size_t at = open[o + l] - run;
        const std::uint32_t bit = 1u << (at % W);
        if (outside >> l & 1u) {
          run_visible_bits[at / W] &= ~bit;
          --run_visible;
          open[gone++] = open[o + l];  // (read above: gone <= o + l)
        } else if (crossing >> l & 1u) {
          if (out.classes) crossing_bits[at / W] |= bit;
        } else {
          ++run_inside;
        }
      }
    }
    counts.visible += run_visible;
    counts.inside += run_inside;
    if (out.classes) {
      ChunkOutput classes_only;
      classes_only.classes = out.classes;
      ChunkCounts unused;
      for (std::size_t i = run, b = 0; i < run_end; i += W, ++b)
        emit(i, begin, static_cast<unsigned>(smaller(W, end - i)), ~run_visible_bits[b], crossing_bits[b], classes_only, unused);
    }
    if (!out.ids) continue;
    const bool dense = run_visible * kDenseShare > run_end - run;
    // Every vector's visible lanes appended from `bits`, none skipped. Skipping the vectors
    // with no visible lane cost a mispredicted branch about every 70 objects (4*10^6 boxes at
    // 10% visible, one thread: 1.085 -> 0.93 ns/object; NOTES).
    auto list_run = [&] {
      std::uint32_t* ids = out.ids;
      for (std::size_t i = run, b = 0; i < run_end; i += W, ++b) ids = append_ids(ids, static_cast<std::uint32_t>(i), run_visible_bits[b]);
    };
    if (appending) {
      if (gone > kRemovedAtMost) list_run();  // many gone: listed again from the bits
      else if (gone) remove_ids(out.ids, appended, open, gone);
      if (out.runs) out.runs[run_index] = run_visible | (dense ? kListedDense : 0u);
    } else if (dense && listed_by_runs) {  // no ids: its vectors' visible lanes are in `bits`
      out.runs[run_index] = kDenseRun | run_visible;
      continue;
    } else {
      list_run();
      if (out.runs) out.runs[run_index] = run_visible;
    }
    out.ids += run_visible;
  }
  return counts;
}

std::uint32_t* expand_ids(const std::uint32_t* bits, std::size_t vectors, std::uint32_t first, std::uint32_t* out, const std::uint32_t* out_end) {
  for (std::size_t v = 0; v < vectors; ++v, first += W) {
    if (out_end - out >= static_cast<std::ptrdiff_t>(W)) {  // room for the vector store
      out = append_ids(out, first, bits[v]);
      continue;
    }
    for (std::uint32_t rest = bits[v]; rest != 0; rest &= rest - 1) *out++ = first + static_cast<std::uint32_t>(__builtin_ctz(rest));
  }
  return out;
}

/// Writes from[64 w + l] for every set bit l of marks[w], w = 0..words-1, in that order from
/// `out`, and returns the new end; never writes at or past out_end. Clears each word it finds
/// set, so the marks are zero again after it.
std::uint32_t* list_marked(std::uint64_t* marks, std::size_t words, const std::uint32_t* from, std::uint32_t* out,
                           const std::uint32_t* out_end) {
  constexpr std::size_t kVectorWords = W / 2;  // the words one vector load reads
  for (std::size_t w = 0; w < words; ++w, from += 64) {
    const std::uint64_t word = marks[w];
    if (word == 0) {
      // Most words are 0 (the objects out of view): the zero words after one are skipped a
      // vector of words at a time (10^6 boxes at 10% visible, 2 threads: the pass 3% faster,
      // 42.4 -> 41.0 microseconds; NOTES).
      while (w + 1 + kVectorWords <= words && all_zero(load_ints(reinterpret_cast<const std::uint32_t*>(marks + w + 1)))) {
        w += kVectorWords;
        from += 64 * kVectorWords;
      }
      continue;
    }
    marks[w] = 0;
    if (word == ~std::uint64_t{0} && out_end - out >= 64) {
      __builtin_memcpy(out, from, 64 * sizeof *out);
      out += 64;
      continue;
    }
    // A word with room for all its stores (at most 64 ids past `out`) and ids readable past its
    // last mark (not the last word: that one may end the array) takes plain loads and no room
    // check per group (10^6 boxes at 10% visible, one thread: 0.200 -> 0.192 ms; NOTES).
    if (w + 1 < words && out_end - out >= 64) {
      for (unsigned q = 0; q < 64 / W; ++q) {
        const std::uint32_t lanes = static_cast<std::uint32_t>(word >> (q * W)) & kAllLanes;
        compress_store(out, load_ints(from + q * W), lanes);
        out += __builtin_popcount(lanes);
      }
      continue;
    }
    // Every group of W marks, those with none too, without a branch on them (10^6 boxes, one
    // thread: 0.41 -> 0.39 ms at 50% visible; NOTES).
    for (unsigned q = 0; q < 64 / W; ++q) {
      const std::uint32_t lanes = static_cast<std::uint32_t>(word >> (q * W)) & kAllLanes;
      if (out_end - out >= static_cast<std::ptrdiff_t>(W)) {  // room for the vector store
        compress_store(out, load_ints_where(from + q * W, lanes), lanes);
        out += __builtin_popcount(lanes);
        continue;
      }
      for (std::uint32_t rest = lanes; rest != 0 && out != out_end; rest &= rest - 1) *out++ = from[q * W + static_cast<unsigned>(__builtin_ctz(rest))];
    }
  }
  return out;
}

// AABBs: the open boxes get the reference's p/n-vertex test.
ChunkCounts cull_aabb(const AabbArrays& a, std::size_t begin, std::size_t end, const PlaneSet& planes, ChunkOutput out) {
  auto resolve = [&](const std::uint32_t* objects, unsigned count, std::uint32_t& outside_bits, std::uint32_t& crossing_bits) {
    vf box[kAabbRecordFloats];  // min x y z, max x y z, two spare
    gather_columns(a.records, objects, count, box);
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
  auto prefetch = [&](std::uint32_t o) { __builtin_prefetch(a.records + std::size_t(o) * kAabbRecordFloats); };
  return cull_settled({a.c_x, a.c_y, a.c_z, a.bound}, begin, end, planes, planes.lower_scale_l1, prefetch, resolve, out);
}

// OBBs: the open ones get the reference's projected-radius test.
ChunkCounts cull_obb(const ObbArrays& a, std::size_t begin, std::size_t end, const PlaneSet& planes, ChunkOutput out) {
  auto resolve = [&](const std::uint32_t* objects, unsigned count, std::uint32_t& outside_bits, std::uint32_t& crossing_bits) {
    vf col[kObbRecordFloats];  // centre, axes u0 u1 u2, half extents, a spare
    gather_columns(a.records, objects, count, col);
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
  auto prefetch = [&](std::uint32_t o) { __builtin_prefetch(a.records + std::size_t(o) * kObbRecordFloats); };
  return cull_settled({a.c_x, a.c_y, a.c_z, a.bound}, begin, end, planes, planes.lower_scale_l2, prefetch, resolve, out);
}

/// The reference's sphere test of W spheres (centre, radius) on every plane.
inline void test_spheres_all(vf cx, vf cy, vf cz, vf radius, const PlaneSet& planes, vi& outside, vi& crossing) {
  outside = crossing = vi{};
  for (std::uint32_t k = 0; k < planes.count; ++k) {
    const vf s = ((planes.nx[k] * cx + planes.ny[k] * cy) + planes.nz[k] * cz) + planes.d[k];
    outside |= s < -radius;
    crossing |= s < radius;
  }
}

// Spheres: the open ones get the reference's signed-distance test, their centres and radii
// read from the columns (16 bytes of records per sphere would double what an upload writes).
// Without unit normals every sphere is tested that way, a vector at a time.
ChunkCounts cull_sphere(const SphereArrays& a, std::size_t begin, std::size_t end, const PlaneSet& planes, ChunkOutput out) {
  if (!planes.unit_normals) {
    ChunkCounts counts;
    for (std::size_t run = begin, r = 0; run < end; run += kRunObjects, ++r) {
      const std::uint32_t* const ids_before = out.ids;
      for (std::size_t i = run; i < smaller(end, run + kRunObjects); i += W) {
        vi outside, crossing;
        test_spheres_all(load(a.c_x + i), load(a.c_y + i), load(a.c_z + i), load(a.radius + i), planes, outside, crossing);
        emit(i, begin, static_cast<unsigned>(smaller(W, end - i)), lane_bits(outside), lane_bits(crossing), out, counts);
      }
      if (out.runs) out.runs[r] = static_cast<std::uint32_t>(out.ids - ids_before);  // (every run's ids listed)
    }
    return counts;
  }
  auto resolve = [&](const std::uint32_t* objects, unsigned count, std::uint32_t& outside_bits, std::uint32_t& crossing_bits) {
    alignas(64) float col[4][W];
    for (unsigned l = 0; l < W; ++l) {
      const std::uint32_t o = objects[l < count ? l : 0];
      col[0][l] = a.c_x[o], col[1][l] = a.c_y[o], col[2][l] = a.c_z[o], col[3][l] = a.radius[o];
    }
    vi outside, crossing;
    test_spheres_all(load(col[0]), load(col[1]), load(col[2]), load(col[3]), planes, outside, crossing);
    outside_bits = lane_bits(outside);
    crossing_bits = lane_bits(crossing);
  };
  auto prefetch = [&](std::uint32_t o) {
    __builtin_prefetch(a.c_x + o);
    __builtin_prefetch(a.c_y + o);
    __builtin_prefetch(a.c_z + o);
    __builtin_prefetch(a.radius + o);
  };
  return cull_settled({a.c_x, a.c_y, a.c_z, a.bound}, begin, end, planes, 0x1p-8f * (1.0f - 0x1p-12f), prefetch, resolve, out);
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

std::uint32_t touch_columns(const float* const* columns, std::size_t begin, std::size_t end) {
  const float *const c0 = columns[0], *const c1 = columns[1], *const c2 = columns[2], *const c3 = columns[3];
  vi acc0 = {}, acc1 = {}, acc2 = {}, acc3 = {};
  for (std::size_t i = begin; i < end; i += W) {
    acc0 |= reinterpret_cast<vi>(load(c0 + i));
    acc1 |= reinterpret_cast<vi>(load(c1 + i));
    acc2 |= reinterpret_cast<vi>(load(c2 + i));
    acc3 |= reinterpret_cast<vi>(load(c3 + i));
  }
  const vi all = (acc0 | acc1) | (acc2 | acc3);
  std::uint32_t bits = 0;
  for (unsigned l = 0; l < W; ++l) bits |= static_cast<std::uint32_t>(all[l]);
  return bits;
}

// ---- Hierarchy walks (fast::CpuBvhCuller) ----
// bvh::cull_hierarchical's tests of one subtree, W at a time: a work list of sibling pairs
// (the two children of a straddling node, with the planes it straddles) is taken W / 2 pairs
// per step, their records transposed into vectors (one node per lane) and tested against the
// planes one by one. The object ranges of straddling leaves (and, with range_objects, of
// straddling nodes of at most that many objects) go to a second list, tested at the end in
// groups of up to 64 objects, W at a time, loaded straight from the volumes' blocks in tree
// order (WalkTree::blocks) against the planes their node straddles. Every lane does the scalar test's float operations in its
// order (bvh::classify_masked for boxes, classify_masked_margin for the nodes of OBB and
// sphere trees, classify_planes for OBBs and spheres) and the planes outside its mask count
// for nothing. The scalar tests stop at the first plane that rejects, which does not change
// their answer (OUTSIDE wins over anything found before or after), so testing every plane
// gives the same class, and the same straddled planes whenever the class is not OUTSIDE.
// Every node and object the depth-first traversal tests is tested here once, so the counts
// are its counts. The order of the tests is not its order, so the visible objects are marked
// in a bitmap (by position in the subtree's range), from which the caller lists them in tree
// order.

inline std::uint32_t bits_of(float word) {
  std::uint32_t bits;
  __builtin_memcpy(&bits, &word, sizeof bits);
  return bits;
}

inline vf larger(vf a, vf b) { return a < b ? b : a; }  // std::max's choice, per lane

/// For the box tests: each plane's p-vertex columns (4 + axis where the normal component is
/// >= 0, -0 too, as pn_vertices; else the axis), chosen once per walk. The n-vertex column is
/// the other one (p ^ 4).
struct BoxPlanes {
  std::uint32_t p[6][3];
  explicit BoxPlanes(const PlaneSet& planes) : p{} {
    for (std::uint32_t k = 0; k < planes.count; ++k) {
      p[k][0] = planes.nx[k] >= 0.0f ? 4 : 0;
      p[k][1] = planes.ny[k] >= 0.0f ? 5 : 1;
      p[k][2] = planes.nz[k] >= 0.0f ? 6 : 2;
    }
  }
};

/// bvh::classify_masked of W boxes (min x y z in box[0..2], max in box[4..6]) against the
/// planes in each lane's `mask`: `outside` nonzero where a p-vertex is behind, `straddled` the
/// planes whose n-vertex is behind. With `margin` (OBB and sphere trees),
/// classify_masked_margin.
inline void test_boxes(const vf* box, vi mask, std::uint32_t any, const PlaneSet& planes, const BoxPlanes& columns, const WalkTree* margin,
                       vi& outside, vi& straddled) {
  outside = straddled = vi{};
  const vf zero = {};
  vf reach = {};
  if (margin) {
    reach = (larger(abs(box[0]), abs(box[4])) + larger(abs(box[1]), abs(box[5]))) + larger(abs(box[2]), abs(box[6]));
  }
  for (; any != 0; any &= any - 1) {
    const std::uint32_t k = static_cast<std::uint32_t>(__builtin_ctz(any));
    const float nx = planes.nx[k], ny = planes.ny[k], nz = planes.nz[k], d = planes.d[k];
    const std::uint32_t* p = columns.p[k];
    const vf dp = ((nx * box[p[0]] + ny * box[p[1]]) + nz * box[p[2]]) + d;
    const vf dn = ((nx * box[p[0] ^ 4] + ny * box[p[1] ^ 4]) + nz * box[p[2] ^ 4]) + d;
    const vi bit = mask & static_cast<std::int32_t>(1u << k);
    if (margin) {
      const vf size = reach + __builtin_fabsf(d);
      const vi certain = size <= margin->margin_limit;  // false for NaN
      const vf m = margin->margin_scale * size + margin->margin_floor;
      outside |= (certain & (dp < -m)) & bit;
      straddled |= (~certain | (dn < m)) & bit;
    } else {
      outside |= (dp < zero) & bit;
      straddled |= (dn < zero) & bit;
    }
  }
}

/// classify_planes of W OBBs (centre, u0, u1, u2, half extents in col[0..14]).
inline void test_obbs(const vf* col, vi mask, std::uint32_t any, const PlaneSet& planes, vi& outside, vi& crossing) {
  outside = crossing = vi{};
  for (; any != 0; any &= any - 1) {
    const std::uint32_t k = static_cast<std::uint32_t>(__builtin_ctz(any));
    const float nx = planes.nx[k], ny = planes.ny[k], nz = planes.nz[k];
    const vf s = ((nx * col[0] + ny * col[1]) + nz * col[2]) + planes.d[k];
    const vf a0 = (nx * col[3] + ny * col[4]) + nz * col[5];
    const vf a1 = (nx * col[6] + ny * col[7]) + nz * col[8];
    const vf a2 = (nx * col[9] + ny * col[10]) + nz * col[11];
    const vf r = (abs(a0) * col[12] + abs(a1) * col[13]) + abs(a2) * col[14];
    const vi bit = mask & static_cast<std::int32_t>(1u << k);
    outside |= (s < -r) & bit;
    crossing |= (s < r) & bit;
  }
}

/// classify_planes of W spheres (centre, radius in col[0..3]).
inline void test_spheres(const vf* col, vi mask, std::uint32_t any, const PlaneSet& planes, vi& outside, vi& crossing) {
  outside = crossing = vi{};
  for (; any != 0; any &= any - 1) {
    const std::uint32_t k = static_cast<std::uint32_t>(__builtin_ctz(any));
    const vf s = ((planes.nx[k] * col[0] + planes.ny[k] * col[1]) + planes.nz[k] * col[2]) + planes.d[k];
    const vi bit = mask & static_cast<std::int32_t>(1u << k);
    outside |= (s < -col[3]) & bit;
    crossing |= (s < col[3]) & bit;
  }
}

enum class WalkKind { Aabb, Obb, Sphere };

/// Lane l = p[l / 2]: W / 2 items, each in two adjacent lanes.
inline vi load_doubled(const std::uint32_t* p) {
  typedef std::int32_t vh __attribute__((vector_size(W * 2)));
  vh h;
  __builtin_memcpy(&h, p, sizeof h);
#if CULLPIPE_SIMD_LANES == 16
  return __builtin_shufflevector(h, h, 0, 0, 1, 1, 2, 2, 3, 3, 4, 4, 5, 5, 6, 6, 7, 7);
#elif CULLPIPE_SIMD_LANES == 8
  return __builtin_shufflevector(h, h, 0, 0, 1, 1, 2, 2, 3, 3);
#else
  return __builtin_shufflevector(h, h, 0, 0, 1, 1);
#endif
}

/// Lanes 2k and 2k + 1 = lane 2k of v.
inline vi even_lanes_doubled(vi v) {
#if CULLPIPE_SIMD_LANES == 16
  return __builtin_shufflevector(v, v, 0, 0, 2, 2, 4, 4, 6, 6, 8, 8, 10, 10, 12, 12, 14, 14);
#elif CULLPIPE_SIMD_LANES == 8
  return __builtin_shufflevector(v, v, 0, 0, 2, 2, 4, 4, 6, 6);
#else
  return __builtin_shufflevector(v, v, 0, 0, 2, 2);
#endif
}

template <WalkKind Kind>
WalkCounts walk(const WalkTree& t, WalkRoot root, const PlaneSet& planes, WalkOutput out) {
  constexpr unsigned object_columns = Kind == WalkKind::Obb      ? kWalkObbColumns
                                      : Kind == WalkKind::Sphere ? kWalkSphereColumns
                                                                 : kWalkAabbColumns;
  static_assert(W % 2 == 0, "a step takes whole sibling pairs");
  const WalkTree* margin = Kind == WalkKind::Aabb ? nullptr : &t;
  const BoxPlanes columns(planes);
  constexpr std::size_t block_floats = kWalkBlock * object_columns;  // a block of the volumes (WalkTree::blocks)
  auto block_at = [&](std::uint32_t pos) { return t.blocks + walk_block_offset(pos, object_columns); };
  static_assert(kWalkBlock % W == 0, "a vector aligned to W lies within one block's column");
  WalkCounts counts;
  const std::uint32_t range_first = root.first;
  // Visible objects, one bit per position in the subtree's range.
  std::uint64_t* const marks = out.marks;
  auto mark_range = [&](std::uint32_t first, std::uint32_t count) {
    const std::uint32_t a = first - range_first, b = a + count - 1;  // count > 0
    const std::uint64_t low = ~std::uint64_t{0} << (a & 63), high = ~std::uint64_t{0} >> (63 - (b & 63));
    if (a / 64 == b / 64) {
      marks[a / 64] |= low & high;
      return;
    }
    marks[a / 64] |= low;
    for (std::uint32_t w = a / 64 + 1; w < b / 64; ++w) marks[w] = ~std::uint64_t{0};
    marks[b / 64] |= high;
  };

  // The work list: sibling pairs to test (pair, planes their parent straddles, first object of
  // the pair's range), taken W / 2 pairs (W slots, a lane each) per step. Breadth first: a
  // pair is tested a level after it was listed and its record prefetched (each pair is listed
  // once: work_capacity suffices). The subtree's root is listed as a pair with one slot
  // skipped (kSkipLow / kSkipHigh in its planes word).
  constexpr std::uint32_t kSkipLow = 1u << 30, kSkipHigh = 1u << 31, kPlaneBits = kSkipLow - 1u;
  const std::size_t span = out.work_capacity + 16;  // a list and the room a vector store may write past it
  std::uint32_t* const work_pair = out.work;
  std::uint32_t* const work_mask = work_pair + span;
  std::uint32_t* const work_first = work_mask + span;
  // The object ranges to test (first, count, planes): straddling leaves, and straddling nodes
  // of at most t.range_objects objects. Listed as they are found (their first lines
  // prefetched) and tested at the end, up to 64 objects at a time, straight from the blocks.
  std::uint32_t* const range_at = work_first + span;
  std::uint32_t* const range_count = range_at + span;
  std::uint32_t* const range_mask = range_count + span;
  std::size_t ranges = 0;
  const vu small_limit = vu{} + t.range_objects;

  const bool root_high = root.slot & 1u;  // the root's sibling (low slot) comes first in the pair's range
  work_pair[0] = root.slot / 2;
  work_mask[0] = root.mask | (root_high ? kSkipLow : kSkipHigh);
  work_first[0] = root_high ? root.first - bits_of(t.nodes[std::size_t(root.slot - 1) * kWalkNodeFloats + 3]) : root.first;
  std::size_t head = 0, tail = 1;
  vi lane_index;
  for (unsigned l = 0; l < W; ++l) lane_index[l] = static_cast<std::int32_t>(l);
  const vi odd = -(lane_index & 1);  // -1 in the high slots' lanes
  const vi skip_bit = (~odd & static_cast<std::int32_t>(kSkipLow)) | (odd & static_cast<std::int32_t>(kSkipHigh));  // the slot's skip flag
  while (head != tail) {
    // W / 2 pairs from the list (reads past its end stay in its room), their slots a lane each.
    const unsigned pairs = static_cast<unsigned>(smaller(tail - head, W / 2));
    const vi in_use = lane_index < static_cast<std::int32_t>(2 * pairs);
    const vi listed_mask = load_doubled(work_mask + head);
    // Lanes past the pairs repeat the first pair (their reads stay in the tree).
    const vi pair = in_use ? load_doubled(work_pair + head) : vi{} + static_cast<std::int32_t>(work_pair[head]);
    alignas(64) std::uint32_t slot[W], first_of[W];
    const vi slots = reinterpret_cast<vi>(reinterpret_cast<vu>(pair) * 2u - reinterpret_cast<vu>(odd));
    __builtin_memcpy(slot, &slots, sizeof slot);
    const vi lane_mask = listed_mask & static_cast<std::int32_t>(kPlaneBits);
    const std::uint32_t valid = lane_bits((listed_mask & skip_bit) == 0) & lane_bits(in_use);  // the lanes in use
    std::uint32_t any = 0;  // the planes some lane tests (deep nodes straddle few)
    for (unsigned k = 0; k < pairs; ++k) any |= work_mask[head + k];
    any &= kPlaneBits;
    const vi low_first = load_doubled(work_first + head);
    head += pairs;
    vf col[8];  // min x y z, count, max x y z, link
    gather_columns<kWalkNodeFloats>(t.nodes, slot, W, col);
    alignas(64) std::uint32_t count_of[W], link_of[W];
    __builtin_memcpy(count_of, &col[3], sizeof count_of);
    __builtin_memcpy(link_of, &col[7], sizeof link_of);
    // The low slot's range comes first: the high slot's starts past it.
    const vi lane_first =
        reinterpret_cast<vi>(reinterpret_cast<vu>(low_first) + reinterpret_cast<vu>(odd & even_lanes_doubled(reinterpret_cast<vi>(col[3]))));
    __builtin_memcpy(first_of, &lane_first, sizeof first_of);
    vi outside, straddled;
    test_boxes(col, lane_mask, any, planes, columns, margin, outside, straddled);
    counts.node_tests += static_cast<unsigned>(__builtin_popcount(valid));
    const vi link = reinterpret_cast<vi>(col[7]), count = reinterpret_cast<vi>(col[3]);
    const std::uint32_t live = ~lane_bits(outside != 0) & valid;
    // Leaves (kWalkLeaf: the sign bit), and with range_objects the nodes of at most that many objects.
    const std::uint32_t ends = lane_bits(link < 0) | (t.range_objects ? lane_bits(reinterpret_cast<vu>(count) <= small_limit) : 0u);
    const std::uint32_t inner = live & ~ends & ~lane_bits(straddled == 0);
    // Straddling inner nodes: their children's pair listed, with the planes still to test.
    if (inner) {
      compress_store(work_pair + tail, link, inner);
      compress_store(work_mask + tail, straddled, inner);
      compress_store(work_first + tail, lane_first, inner);
      for (std::uint32_t rest = inner; rest != 0; rest &= rest - 1)
        __builtin_prefetch(t.nodes + std::size_t(link_of[__builtin_ctz(rest)]) * (2 * kWalkNodeFloats));
      tail += static_cast<unsigned>(__builtin_popcount(inner));
    }
    alignas(64) std::int32_t straddled_lanes[W];
    __builtin_memcpy(straddled_lanes, &straddled, sizeof straddled);
    for (std::uint32_t rest = live & ~inner; rest != 0; rest &= rest - 1) {
      const unsigned l = static_cast<unsigned>(__builtin_ctz(rest));
      const std::uint32_t planes_left = static_cast<std::uint32_t>(straddled_lanes[l]);
      const std::uint32_t first = first_of[l], n = count_of[l];
      if (planes_left == 0) {  // INSIDE: the whole range, no further tests
        if (out.classes)
          for (std::uint32_t k = first; k < first + n; ++k) out.classes[t.ids[k]] = kInside;
        if (marks && n) mark_range(first, n);
        counts.visible += n;
        counts.inside += n;
        continue;
      }
      // An empty straddling leaf (a tree may have them) has nothing to test; listed, its
      // range's first vector (aligned below `first`) would mark a word the subtree does not own.
      if (n == 0) continue;
      // A straddling leaf or small node: its objects, against the planes it straddles. Its
      // blocks are one run of lines: the first line of its first block and of the next
      // prefetched, the hardware prefetcher takes the rest (the first line of every block of
      // the range measured slower, none about the same; NOTES).
      const float* const range_block = block_at(first);
      __builtin_prefetch(range_block);
      __builtin_prefetch(range_block + block_floats);
      range_at[ranges] = first;
      range_count[ranges] = n;
      range_mask[ranges++] = planes_left;
    }
  }

  // Boxes: each plane's p- and n-vertex columns (BoxPlanes) as offsets in a block, so a
  // range's vectors are loaded straight from the columns the plane needs.
  unsigned vertex_offset[6][6] = {};  // [plane][p x y z, n x y z]
  if constexpr (Kind == WalkKind::Aabb)
    for (std::uint32_t k = 0; k < planes.count; ++k)
      for (unsigned a = 0; a < 3; ++a) {
        const unsigned p = columns.p[k][a] & 4 ? 3 + a : a;  // max or min column
        vertex_offset[k][a] = static_cast<unsigned>(p * kWalkBlock);
        vertex_offset[k][3 + a] = static_cast<unsigned>((p >= 3 ? p - 3 : p + 3) * kWalkBlock);
      }
  for (std::size_t r = 0; r < ranges; ++r) {
    const std::uint32_t first = range_at[r], n = range_count[r], m = range_mask[r], end = first + n;
    counts.object_tests += n;
    // Up to 64 of the range's objects at a time, tested plane by plane (a plane's coefficients
    // and columns set up once), in vectors aligned to W (so within a block) from the one
    // holding `first`; the lanes before `first` and from `end` count for nothing. Their outside
    // and crossing lanes are gathered a bit per object in two words, then counted, marked and
    // classed once per 64, not per vector (10^6 boxes at 10% visible, one thread: 0.192 ->
    // 0.167 ms; NOTES). Blocks instead of a column each: 41.4 -> 38.4 microseconds per pass,
    // 2 threads (NOTES).
    for (std::uint32_t at = first & ~(W - 1); at < end; at += 64) {
      const std::uint32_t size = end - at < 64 ? end - at : 64, low = at < first ? first - at : 0;
      std::uint64_t outside_bits = 0, crossing_bits = 0;
      if constexpr (Kind == WalkKind::Aabb) {  // test_boxes's operations, plane by plane
        const vf zero = {};
        for (std::uint32_t any = m; any != 0; any &= any - 1) {
          const std::uint32_t k = static_cast<std::uint32_t>(__builtin_ctz(any));
          const float nx = planes.nx[k], ny = planes.ny[k], nz = planes.nz[k], d = planes.d[k];
          const unsigned* const o = vertex_offset[k];
          for (std::uint32_t j = 0; j < size; j += W) {
            const float* const b = block_at(at + j);
            const vf dp = ((nx * load(b + o[0]) + ny * load(b + o[1])) + nz * load(b + o[2])) + d;
            const vf dn = ((nx * load(b + o[3]) + ny * load(b + o[4])) + nz * load(b + o[5])) + d;
            outside_bits |= std::uint64_t(less_bits(dp, zero)) << j;
            crossing_bits |= std::uint64_t(less_bits(dn, zero)) << j;
          }
        }
      } else {
        const vi mask = vi{} + static_cast<std::int32_t>(m);
        for (std::uint32_t j = 0; j < size; j += W) {
          const float* const b = block_at(at + j);
          vf col[object_columns];
          for (unsigned c = 0; c < object_columns; ++c) col[c] = load(b + c * kWalkBlock);
          vi outside, crossing;
          if constexpr (Kind == WalkKind::Obb)
            test_obbs(col, mask, m, planes, outside, crossing);
          else
            test_spheres(col, mask, m, planes, outside, crossing);
          outside_bits |= std::uint64_t(lane_bits(outside != 0)) << j;
          crossing_bits |= std::uint64_t(lane_bits(crossing != 0)) << j;
        }
      }
      const std::uint64_t valid = (size == 64 ? ~std::uint64_t{0} : (std::uint64_t{1} << size) - 1u) & (~std::uint64_t{0} << low);
      const std::uint64_t visible = ~outside_bits & valid;
      counts.visible += static_cast<std::uint32_t>(__builtin_popcountll(visible));
      counts.inside += static_cast<std::uint32_t>(__builtin_popcountll(visible & ~crossing_bits));
      if (out.classes)
        for (std::uint32_t l = low; l < size; ++l)
          out.classes[t.ids[at + l]] = visible >> l & 1u ? (crossing_bits >> l & 1u ? kIntersecting : kInside) : kOutside;
      if (marks) {
        if (at < range_first) {  // the subtree's range starts inside this vector (no lane below it is valid)
          marks[0] |= visible >> (range_first - at);
        } else {
          const std::uint32_t p = at - range_first, shift = p % 64;
          marks[p / 64] |= visible << shift;
          if (shift + size > 64) marks[p / 64 + 1] |= visible >> (64 - shift);
        }
      }
    }
  }

  return counts;
}

WalkCounts walk_aabb(const WalkTree& t, WalkRoot root, const PlaneSet& planes, WalkOutput out) { return walk<WalkKind::Aabb>(t, root, planes, out); }
WalkCounts walk_obb(const WalkTree& t, WalkRoot root, const PlaneSet& planes, WalkOutput out) { return walk<WalkKind::Obb>(t, root, planes, out); }
WalkCounts walk_sphere(const WalkTree& t, WalkRoot root, const PlaneSet& planes, WalkOutput out) {
  return walk<WalkKind::Sphere>(t, root, planes, out);
}

}  // namespace
}  // namespace CULLPIPE_SIMD_NS
}  // namespace cullpipe::fast::detail
