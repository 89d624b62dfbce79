// Part of the SIMD kernels (simd_kernels.inl includes it once per instruction set). Vectors of W lanes:
// loads, lane masks, id compression, record transposes and the output of a vector's classes.
#include <cstddef>
#include <cstdint>

#include "cullpipe/cull/simd_kernels.hpp"

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
/// (AVX-512: the compress merges into its own source, not into zeros: the zeroing form waits
/// for the last write of its destination, which serialises back-to-back compresses on Zen 5.
/// The lanes past the compressed ones are garbage either way.)
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
  _mm512_storeu_si512(out,
                      _mm512_maskz_compress_epi32(static_cast<__mmask16>(lanes), reinterpret_cast<__m512i>(values)));
#elif CULLPIPE_SIMD_LANES == 8 && defined(__AVX2__)
  const __m256i order = _mm256_cvtepu8_epi32(_mm_cvtsi64_si128(static_cast<long long>(kCompress.entry[lanes])));
  _mm256_storeu_si256(reinterpret_cast<__m256i*>(out),
                      _mm256_permutevar8x32_epi32(reinterpret_cast<__m256i>(values), order));
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
inline void emit(std::size_t i, std::size_t begin, unsigned valid, std::uint32_t outside, std::uint32_t crossing,
                 ChunkOutput& out, ChunkCounts& counts) {
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
  auto unpack_lo = [](vf x, vf y) {
    return __builtin_shufflevector(x, y, 0, 16, 1, 17, 4, 20, 5, 21, 8, 24, 9, 25, 12, 28, 13, 29);
  };
  auto unpack_hi = [](vf x, vf y) {
    return __builtin_shufflevector(x, y, 2, 18, 3, 19, 6, 22, 7, 23, 10, 26, 11, 27, 14, 30, 15, 31);
  };
  auto pick_low_pairs = [](vf x, vf y) {
    return __builtin_shufflevector(x, y, 0, 1, 16, 17, 4, 5, 20, 21, 8, 9, 24, 25, 12, 13, 28, 29);
  };
  auto pick_high_pairs = [](vf x, vf y) {
    return __builtin_shufflevector(x, y, 2, 3, 18, 19, 6, 7, 22, 23, 10, 11, 26, 27, 14, 15, 30, 31);
  };
  if constexpr (Floats == 4) {
    vf a[4];
    for (unsigned i = 0; i < 4; ++i) {  // lane k of a[i]: record 4k + i
      v4f r[4];
      for (unsigned k = 0; k < 4; ++k) __builtin_memcpy(&r[k], row[i + 4 * k], sizeof r[k]);
      const v8f lo = __builtin_shufflevector(r[0], r[1], 0, 1, 2, 3, 4, 5, 6, 7),
                hi = __builtin_shufflevector(r[2], r[3], 0, 1, 2, 3, 4, 5, 6, 7);
      a[i] = __builtin_shufflevector(lo, hi, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15);
    }
    const vf t0 = unpack_lo(a[0], a[1]), t1 = unpack_hi(a[0], a[1]), t2 = unpack_lo(a[2], a[3]),
             t3 = unpack_hi(a[2], a[3]);
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
        col[base + c] =
            __builtin_shufflevector(u[c], u[c + 4], 0, 1, 2, 3, 16, 17, 18, 19, 8, 9, 10, 11, 24, 25, 26, 27);
        col[base + c + 4] =
            __builtin_shufflevector(u[c], u[c + 4], 4, 5, 6, 7, 20, 21, 22, 23, 12, 13, 14, 15, 28, 29, 30, 31);
      }
    }
  }
#elif CULLPIPE_SIMD_LANES == 8 && defined(__AVX2__)
  if constexpr (Floats == 4) {
    __m256 a[4];
    for (unsigned i = 0; i < 4; ++i)
      a[i] = _mm256_insertf128_ps(_mm256_castps128_ps256(_mm_loadu_ps(row[i])), _mm_loadu_ps(row[i + 4]), 1);
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
  return reinterpret_cast<vi>(
      _mm256_maskload_epi32(reinterpret_cast<const int*>(p), reinterpret_cast<__m256i>(lanes_of(lanes))));
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
  return reinterpret_cast<vf>(
      _mm512_fmadd_ps(_mm512_set1_ps(a), reinterpret_cast<__m512>(b), reinterpret_cast<__m512>(c)));
#elif CULLPIPE_SIMD_LANES == 8 && defined(__FMA__)
  return reinterpret_cast<vf>(
      _mm256_fmadd_ps(_mm256_set1_ps(a), reinterpret_cast<__m256>(b), reinterpret_cast<__m256>(c)));
#else
  return a * b + c;
#endif
}

/// a * b - c, fused where the instruction set has it (bounds only).
inline vf mul_sub(vf a, vf b, vf c) {
#if CULLPIPE_SIMD_LANES == 16 && defined(__AVX512F__)
  return reinterpret_cast<vf>(
      _mm512_fmsub_ps(reinterpret_cast<__m512>(a), reinterpret_cast<__m512>(b), reinterpret_cast<__m512>(c)));
#elif CULLPIPE_SIMD_LANES == 8 && defined(__FMA__)
  return reinterpret_cast<vf>(
      _mm256_fmsub_ps(reinterpret_cast<__m256>(a), reinterpret_cast<__m256>(b), reinterpret_cast<__m256>(c)));
#else
  return a * b - c;
#endif
}

}  // namespace
}  // namespace CULLPIPE_SIMD_NS
}  // namespace cullpipe::fast::detail
