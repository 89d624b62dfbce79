// build_binned_sah's implementation, included twice by binned_sah.cpp: the baseline (SSE2 on
// x86-64, plain C++ elsewhere) and, under `#pragma GCC target("avx2")`, the AVX2 variant chosen at
// run time. Every variant computes the same values in the same order (min/max are exact and the
// areas are the same double operations), so all of them build the same tree, bit for bit.
//
// Include with CULLPIPE_BINNED_NS set to the namespace (inside cullpipe::bvh::detail) to define
// that variant's build() (declared in binned_sah.hpp) in, and CULLPIPE_BINNED_AVX2 to 0 or 1.
// Every header is included on the first (baseline) pass, so no inline function shared with
// other translation units is ever compiled for AVX2.
#include <algorithm>
#include <bit>
#include <cmath>
#include <cstddef>
#include <memory>
#include <stdexcept>
#include <string>
#include <vector>
#if defined(__SSE2__)
#include <immintrin.h>
#endif

#include "cullpipe/bvh/binned_sah.hpp"
#include "cullpipe/core/huge_pages.hpp"
#include "cullpipe/core/thread_pool.hpp"

namespace cullpipe::bvh::detail::CULLPIPE_BINNED_NS {
namespace {

constexpr std::size_t kCacheLine = 64;
constexpr Box8 kEmpty{{INFINITY, INFINITY, INFINITY, INFINITY, INFINITY, INFINITY, INFINITY, INFINITY}};

// Centroids and bin coordinates: x, y, z and an unused fourth lane.
struct alignas(16) Lanes {
  float v[4];
};

#if defined(__SSE2__)
// acc = min(b, acc) lane by lane (a NaN in b keeps acc).
inline void grow(Box8& acc, const Box8& b) {
#if CULLPIPE_BINNED_AVX2
  _mm256_store_ps(acc.v, _mm256_min_ps(_mm256_load_ps(b.v), _mm256_load_ps(acc.v)));
#else
  _mm_store_ps(acc.v, _mm_min_ps(_mm_load_ps(b.v), _mm_load_ps(acc.v)));
  _mm_store_ps(acc.v + 4, _mm_min_ps(_mm_load_ps(b.v + 4), _mm_load_ps(acc.v + 4)));
#endif
}
inline void copy(Box8& to, const Box8& from) {
#if CULLPIPE_BINNED_AVX2
  _mm256_store_ps(to.v, _mm256_load_ps(from.v));
#else
  _mm_store_ps(to.v, _mm_load_ps(from.v));
  _mm_store_ps(to.v + 4, _mm_load_ps(from.v + 4));
#endif
}
// (lo + hi) * 0.5 per axis, as Aabb::center() (lo - (-hi) is lo + hi exactly); fourth lane 0.
inline __m128 centroid(const Box8& r) {
  const __m128 xyz = _mm_castsi128_ps(_mm_set_epi32(0, -1, -1, -1));
  return _mm_mul_ps(_mm_sub_ps(_mm_and_ps(_mm_load_ps(r.v), xyz), _mm_and_ps(_mm_load_ps(r.v + 4), xyz)),
                    _mm_set1_ps(0.5f));
}
inline void grow_point(Lanes& lo, Lanes& hi, __m128 c) {
  _mm_store_ps(lo.v, _mm_min_ps(c, _mm_load_ps(lo.v)));
  _mm_store_ps(hi.v, _mm_max_ps(c, _mm_load_ps(hi.v)));
}
// Per axis k < 3: the bin uint32(min((c - lo) * scale, last)); NaN goes to `last`.
inline __m128i bin_indices(__m128 c, const Lanes& lo, const Lanes& scale, const Lanes& last) {
  const __m128 x = _mm_mul_ps(_mm_sub_ps(c, _mm_load_ps(lo.v)), _mm_load_ps(scale.v));
  return _mm_cvttps_epi32(_mm_min_ps(x, _mm_load_ps(last.v)));
}
// A record held in registers (loaded once for its three bins: the compiler cannot tell that
// the bins' stores leave the record alone).
#if CULLPIPE_BINNED_AVX2
using Rec = __m256;
inline Rec load(const Box8& b) { return _mm256_load_ps(b.v); }
inline void grow(Box8& acc, Rec r) { _mm256_store_ps(acc.v, _mm256_min_ps(r, _mm256_load_ps(acc.v))); }
#else
struct Rec {
  __m128 lo, hi;
};
inline Rec load(const Box8& b) { return {_mm_load_ps(b.v), _mm_load_ps(b.v + 4)}; }
inline void grow(Box8& acc, Rec r) {
  _mm_store_ps(acc.v, _mm_min_ps(r.lo, _mm_load_ps(acc.v)));
  _mm_store_ps(acc.v + 4, _mm_min_ps(r.hi, _mm_load_ps(acc.v + 4)));
}
#endif
// Bin indices below 256 (x, y, z, 0) as the bytes of one word: x | y << 8 | z << 16.
inline std::uint32_t packed(__m128i idx) {
  const __m128i words = _mm_packs_epi32(idx, idx);
  return std::uint32_t(_mm_cvtsi128_si32(_mm_packus_epi16(words, words)));
}
// Half the surface area of a non-empty box, in double, as detail::half_area (e = hi - lo;
// ex*ey + ey*ez + ez*ex): u = lo + (-hi) is -e exactly, and the products of two negated extents
// are the same numbers.
inline double half_area(const Box8& b) {
  const __m128 l = _mm_load_ps(b.v), h = _mm_load_ps(b.v + 4);
  const __m128d uxy = _mm_add_pd(_mm_cvtps_pd(h), _mm_cvtps_pd(l));
  // Only the z lanes are converted (the fourth lanes hold an id's bits, not numbers).
  const __m128d uz = _mm_add_sd(_mm_cvtss_sd(_mm_setzero_pd(), _mm_movehl_ps(h, h)),
                                _mm_cvtss_sd(_mm_setzero_pd(), _mm_movehl_ps(l, l)));
  const __m128d p = _mm_mul_pd(uxy, _mm_shuffle_pd(uxy, uz, 1));  // (ux uy, uy uz)
  return _mm_cvtsd_f64(_mm_add_sd(_mm_add_sd(p, _mm_unpackhi_pd(p, p)), _mm_mul_sd(uz, uxy)));
}
// Bit b set when counts[b] != 0, for counts[0, 8).
#if CULLPIPE_BINNED_AVX2
inline std::uint32_t nonzero_mask(const std::uint32_t* counts) {
  const __m256i c = _mm256_loadu_si256(reinterpret_cast<const __m256i*>(counts));
  return ~std::uint32_t(_mm256_movemask_ps(_mm256_castsi256_ps(_mm256_cmpeq_epi32(c, _mm256_setzero_si256())))) & 0xffu;
}
// (lo | -hi) of four boxes along one axis to double(-hi) + double(lo), four lanes.
inline __m256d negated_extents(__m256 v) {
  return _mm256_add_pd(_mm256_cvtps_pd(_mm256_extractf128_ps(v, 1)), _mm256_cvtps_pd(_mm256_castps256_ps128(v)));
}
// half_area of four boxes at once (the same operations per lane): their x, y and z lanes
// transposed into vectors, so the fourth lanes (ids) are never converted.
inline __m256d half_areas4(const Box8* b) {
  const __m256 r0 = _mm256_load_ps(b[0].v), r1 = _mm256_load_ps(b[1].v), r2 = _mm256_load_ps(b[2].v),
               r3 = _mm256_load_ps(b[3].v);
  const __m256 t0 = _mm256_unpacklo_ps(r0, r1), t1 = _mm256_unpacklo_ps(r2, r3);  // (x0 x1 y0 y1) per half
  const __m256 t2 = _mm256_unpackhi_ps(r0, r1), t3 = _mm256_unpackhi_ps(r2, r3);  // (z0 z1 w0 w1) per half
  const __m256 x = _mm256_shuffle_ps(t0, t1, _MM_SHUFFLE(1, 0, 1, 0));  // lo x of the four | -hi x of the four
  const __m256 y = _mm256_shuffle_ps(t0, t1, _MM_SHUFFLE(3, 2, 3, 2));
  const __m256 z = _mm256_shuffle_ps(t2, t3, _MM_SHUFFLE(1, 0, 1, 0));
  const __m256d ux = negated_extents(x), uy = negated_extents(y), uz = negated_extents(z);
  return _mm256_add_pd(_mm256_add_pd(_mm256_mul_pd(ux, uy), _mm256_mul_pd(uy, uz)), _mm256_mul_pd(uz, ux));
}
#else
inline std::uint32_t nonzero_mask(const std::uint32_t* counts) {
  const __m128i zero = _mm_setzero_si128();
  const __m128i a = _mm_loadu_si128(reinterpret_cast<const __m128i*>(counts)),
                b = _mm_loadu_si128(reinterpret_cast<const __m128i*>(counts + 4));
  const std::uint32_t empty = std::uint32_t(_mm_movemask_ps(_mm_castsi128_ps(_mm_cmpeq_epi32(a, zero)))) |
                              std::uint32_t(_mm_movemask_ps(_mm_castsi128_ps(_mm_cmpeq_epi32(b, zero)))) << 4;
  return ~empty & 0xffu;
}
#endif
#else  // no SSE2: plain loops, the same results
inline void grow(Box8& acc, const Box8& b) {
  for (int k = 0; k < 8; ++k) acc.v[k] = b.v[k] < acc.v[k] ? b.v[k] : acc.v[k];
}
inline void copy(Box8& to, const Box8& from) { to = from; }
inline Lanes centroid(const Box8& r) {
  return {{(r.v[0] - r.v[4]) * 0.5f, (r.v[1] - r.v[5]) * 0.5f, (r.v[2] - r.v[6]) * 0.5f, 0.0f}};
}
inline void grow_point(Lanes& lo, Lanes& hi, const Lanes& c) {
  for (int k = 0; k < 4; ++k) {
    lo.v[k] = c.v[k] < lo.v[k] ? c.v[k] : lo.v[k];
    hi.v[k] = hi.v[k] < c.v[k] ? c.v[k] : hi.v[k];
  }
}
struct Indices {
  std::uint32_t v[4];
};
inline Indices bin_indices(const Lanes& c, const Lanes& lo, const Lanes& scale, const Lanes& last) {
  Indices out{};
  for (int k = 0; k < 3; ++k) {
    const float x = (c.v[k] - lo.v[k]) * scale.v[k];
    out.v[k] = std::uint32_t(x < last.v[k] ? x : last.v[k]);
  }
  return out;
}
using Rec = Box8;
inline Rec load(const Box8& b) { return b; }
inline double half_area(const Box8& b) {
  const double ux = double(b.v[4]) + double(b.v[0]), uy = double(b.v[5]) + double(b.v[1]),
               uz = double(b.v[6]) + double(b.v[2]);
  return ux * uy + uy * uz + uz * ux;
}
inline std::uint32_t nonzero_mask(const std::uint32_t* counts) {
  std::uint32_t m = 0;
  for (std::uint32_t k = 0; k < 8; ++k) m |= std::uint32_t(counts[k] != 0) << k;
  return m;
}
#endif

#if defined(__SSE2__)
inline void index3(__m128i idx, std::uint32_t& a, std::uint32_t& b, std::uint32_t& c) {
  a = std::uint32_t(_mm_cvtsi128_si32(idx));
  b = std::uint32_t(_mm_cvtsi128_si32(_mm_shuffle_epi32(idx, 1)));
  c = std::uint32_t(_mm_cvtsi128_si32(_mm_shuffle_epi32(idx, 2)));
}
#else
inline void index3(const Indices& idx, std::uint32_t& a, std::uint32_t& b, std::uint32_t& c) {
  a = idx.v[0];
  b = idx.v[1];
  c = idx.v[2];
}
inline std::uint32_t packed(const Indices& idx) { return idx.v[0] | idx.v[1] << 8 | idx.v[2] << 16; }
#endif

#if defined(__SSE2__)
inline __m128i times4(__m128i idx) { return _mm_slli_epi32(idx, 2); }
#else
inline Indices times4(Indices idx) {
  for (int k = 0; k < 4; ++k) idx.v[k] *= 4;
  return idx;
}
#endif
// The bin whose count sits `offset` bytes into counts (bins are 8 times as large as counts, so
// one offset addresses both without a shift).
inline Box8& box_at(Box8* bins, std::uint32_t offset) {
  return *reinterpret_cast<Box8*>(reinterpret_cast<char*>(bins) + std::size_t(offset) * 8);
}
inline std::uint32_t& count_at(std::uint32_t* counts, std::uint32_t offset) {
  return *reinterpret_cast<std::uint32_t*>(reinterpret_cast<char*>(counts) + offset);
}
static_assert(sizeof(Box8) == 8 * sizeof(std::uint32_t));
// The byte of a packed word (x | y << 8 | z << 16) that holds axis a's bin, in memory order.
static_assert(std::endian::native == std::endian::little || std::endian::native == std::endian::big);
constexpr bool kLittle = std::endian::native == std::endian::little;
constexpr std::size_t kByteOf[3] = {kLittle ? 0u : 3u, kLittle ? 1u : 2u, kLittle ? 2u : 1u};

// The SAH sweep over one axis's non-empty bins. Candidate j puts used bins list[0..j] left and
// list[j+1..k-1] right; its cost is half_area(left) * |left| + half_area(right) * |right|.
class Sweep {
 public:
  // (Each array ends in a cache line's worth of slots never used: see Workspace.)
  explicit Sweep(std::uint32_t bins)
      : left_(round4(bins) + kCacheLine / sizeof(Box8)),
        right_(round4(bins) + kCacheLine / sizeof(Box8)),
        nl_(round4(bins) + kCacheLine / sizeof(std::uint32_t)),
        nr_(CULLPIPE_BINNED_AVX2 ? 0 : round4(bins) + kCacheLine / sizeof(double)),
        cost_(round4(bins) + kCacheLine / sizeof(double)) {}

  // The first candidate with the axis's least cost, when that cost is below best_cost (which
  // it then becomes); else kNone. Costs that are NaN never win; neither does +infinity.
  // `total`: the node's object count (the sum of count over the list).
  std::uint32_t best(const Box8* bin, const std::uint32_t* count, const std::uint32_t* list, std::uint32_t k,
                     std::uint32_t total, double& best_cost) {
    if (k < 2) return kNone;
    const std::uint32_t candidates = k - 1;
#if CULLPIPE_BINNED_AVX2
    // The children's boxes of every candidate first (two chains of minimums, left to right and
    // right to left, in one loop), then their areas and costs four candidates at a time, then
    // the least cost: no branch per candidate.
    Box8 acc_left = kEmpty, acc_right = kEmpty;
    std::uint32_t cnt = 0;
    for (std::uint32_t j = 0; j < candidates; ++j) {
      grow(acc_left, bin[list[j]]);
      copy(left_[j], acc_left);
      cnt += count[list[j]];
      nl_[j] = cnt;
      grow(acc_right, bin[list[candidates - j]]);
      copy(right_[candidates - 1 - j], acc_right);
    }
    const __m256d inf = _mm256_set1_pd(INFINITY);
    __m256d least = inf;
    for (std::uint32_t q = 0; q < candidates; q += 4) {
      // The counts as doubles, exactly: an unsigned count is its signed conversion, plus 2^32
      // where that came out negative; the right side's is total minus the left's (integers
      // below 2^53: exact).
      const __m128i counts = _mm_loadu_si128(reinterpret_cast<const __m128i*>(nl_.data() + q));
      const __m256d signed_nl = _mm256_cvtepi32_pd(counts);
      const __m256d nl = _mm256_add_pd(
          signed_nl,
          _mm256_and_pd(_mm256_cmp_pd(signed_nl, _mm256_setzero_pd(), _CMP_LT_OQ), _mm256_set1_pd(4294967296.0)));
      const __m256d nr = _mm256_sub_pd(_mm256_set1_pd(double(total)), nl);
      const __m256d cost = _mm256_add_pd(_mm256_mul_pd(half_areas4(left_.data() + q), nl),
                                         _mm256_mul_pd(half_areas4(right_.data() + q), nr));
      // Lanes past the last candidate hold stale boxes: +infinity, never chosen.
      const __m256d live = _mm256_castsi256_pd(
          _mm256_cmpgt_epi64(_mm256_set1_epi64x(std::int64_t(candidates - q)), _mm256_set_epi64x(3, 2, 1, 0)));
      const __m256d c = _mm256_blendv_pd(inf, cost, live);
      _mm256_storeu_pd(cost_.data() + q, c);
      least = _mm256_min_pd(c, least);  // a NaN cost keeps `least`
    }
    __m128d m = _mm_min_pd(_mm256_castpd256_pd128(least), _mm256_extractf128_pd(least, 1));
    m = _mm_min_sd(m, _mm_unpackhi_pd(m, m));
    const double axis_least = _mm_cvtsd_f64(m);
    if (!(axis_least < best_cost)) return kNone;
    best_cost = axis_least;
    const __m256d target = _mm256_set1_pd(axis_least);
    for (std::uint32_t q = 0;; q += 4) {
      const int hit = _mm256_movemask_pd(_mm256_cmp_pd(_mm256_loadu_pd(cost_.data() + q), target, _CMP_EQ_OQ));
      if (hit != 0) return q + std::uint32_t(std::countr_zero(std::uint32_t(hit)));
    }
#else
    // right areas first, then the costs in order (the first strictly better one wins).
    Box8 acc = kEmpty;
    std::uint32_t cnt = 0;
    for (std::uint32_t j = candidates; j > 0; --j) {
      grow(acc, bin[list[j]]);
      cnt += count[list[j]];
      cost_[j - 1] = half_area(acc);
      nr_[j - 1] = double(cnt);
    }
    acc = kEmpty;
    cnt = 0;
    std::uint32_t chosen = kNone;
    for (std::uint32_t j = 0; j < candidates; ++j) {
      grow(acc, bin[list[j]]);
      cnt += count[list[j]];
      const double cost = half_area(acc) * double(cnt) + cost_[j] * nr_[j];
      if (cost < best_cost) best_cost = cost, chosen = j;
    }
    (void)total;
    return chosen;
#endif
  }

 private:
  static std::size_t round4(std::uint32_t n) { return (std::size_t(n) + 3) / 4 * 4; }
  // AVX2: each candidate's children's boxes, left object count (nl_) and cost (nr_ unused,
  // empty). Baseline: nr_ the right side's counts and cost_ its areas.
  std::vector<Box8> left_, right_;
  std::vector<std::uint32_t> nl_;
  std::vector<double> nr_;
  std::vector<double> cost_;
};

// For each 8-bit mask, its set bits' positions in ascending order (then zeros): a group of
// eight bins' non-empty ones listed without a branch per bin.
constexpr std::uint32_t kMaskStep = 8;
struct BitLists {
  std::uint8_t at[256][8];
};
constexpr BitLists make_bit_lists() {
  BitLists t{};
  for (std::uint32_t m = 0; m < 256; ++m) {
    std::uint32_t k = 0;
    for (std::uint8_t b = 0; b < 8; ++b)
      if (m >> b & 1u) t.at[m][k++] = b;
  }
  return t;
}
constexpr BitLists kBitLists = make_bit_lists();

// The non-empty bins of one axis, ascending, into list (room for `stride`); returns how many.
inline std::uint32_t list_used(const std::uint32_t* counts, std::uint32_t stride, std::uint32_t* list) {
  std::uint32_t k = 0;
  for (std::uint32_t b0 = 0; b0 < stride; b0 += kMaskStep) {
    const std::uint32_t m = nonzero_mask(counts + b0);
    for (std::uint32_t i = 0; i < 8; ++i) list[k + i] = b0 + kBitLists.at[m][i];  // k <= b0: stays in [0, stride)
    k += std::uint32_t(std::popcount(m));
  }
  return k;
}

// r = object `id`'s record: (min, +inf, -max, id's bits), stored whole (a record written as
// eight floats and read back as one vector waits for the stores to drain instead of taking
// the value from them).
static_assert(sizeof(Aabb) == 6 * sizeof(float) && offsetof(Aabb, max) == 3 * sizeof(float));
inline void store_record(Box8& r, const Aabb& b, std::uint32_t id) {
#if defined(__SSE2__)
  const float* const p = &b.min.x;
  const __m128 xyz = _mm_castsi128_ps(_mm_set_epi32(0, -1, -1, -1));
  const __m128 a = _mm_loadu_ps(p);      // min.x min.y min.z max.x
  const __m128 c = _mm_loadu_ps(p + 2);  // min.z max.x max.y max.z: both loads within the box
  const __m128 lo = _mm_or_ps(_mm_and_ps(a, xyz), _mm_andnot_ps(xyz, _mm_set1_ps(INFINITY)));
  const __m128 neg = _mm_xor_ps(_mm_shuffle_ps(c, c, _MM_SHUFFLE(0, 3, 2, 1)), _mm_set1_ps(-0.0f));  // -max, -min.z
  const __m128 nh =
      _mm_or_ps(_mm_and_ps(neg, xyz), _mm_castsi128_ps(_mm_slli_si128(_mm_cvtsi32_si128(std::int32_t(id)), 12)));
#if CULLPIPE_BINNED_AVX2
  _mm256_store_ps(r.v, _mm256_set_m128(nh, lo));
#else
  _mm_store_ps(r.v, lo);
  _mm_store_ps(r.v + 4, nh);
#endif
#else
  r = {{b.min.x, b.min.y, b.min.z, INFINITY, -b.max.x, -b.max.y, -b.max.z, std::bit_cast<float>(id)}};
#endif
}

// The centroid box of objects: lo and hi corners (x, y, z, unused).
struct PointBox {
  Lanes lo{{INFINITY, INFINITY, INFINITY, INFINITY}}, hi{{-INFINITY, -INFINITY, -INFINITY, -INFINITY}};
};

// The two children's centroid boxes, gathered while a split moves its records: each side's box
// is its centroids' minimum and their negated maximum, held in registers, and a record that goes
// to the other side offers NaN (all bits set), which a minimum ignores. The minimums take the
// same operands in the same order as grow_point's min(c, lo) and max(c, hi) (-max(c, hi) is
// min(-c, -hi), ties keeping the accumulated value, and -c is c with its sign bit flipped), so
// the boxes are the same, bit for bit (checked against grow_point with zeros of both signs,
// NaN, infinities and subnormals). Registers, not a box in memory behind a pointer chosen per
// record, which would make each record wait for the last one's store.
#if defined(__SSE2__)
class SideCentroids {
 public:
  // Written out (not member initialisers): an implicit constructor would not get the AVX2
  // target pragma.
  SideCentroids() {
#if CULLPIPE_BINNED_AVX2
    left_ = right_ = _mm256_set1_ps(INFINITY);
#else
    left_lo_ = left_nh_ = right_lo_ = right_nh_ = _mm_set1_ps(INFINITY);
#endif
  }
  // go_left: 1 when the record goes left, 0 when it goes right.
  inline void add(const Box8& r, std::uint32_t go_left) {
#if CULLPIPE_BINNED_AVX2
    const __m256 xyz = _mm256_castsi256_ps(_mm256_set_epi32(0, -1, -1, -1, 0, -1, -1, -1));
    const __m256 a = _mm256_and_ps(_mm256_load_ps(r.v), xyz);            // (lo, 0, -hi, 0)
    const __m256 d = _mm256_sub_ps(a, _mm256_permute2f128_ps(a, a, 1));  // lo - (-hi) in the low half
    // (c, 0, -c, 0): -c by flipping c's sign bit ((-hi - lo) * 0.5 would be +0 where c is).
    const __m256 v = _mm256_xor_ps(_mm256_mul_ps(_mm256_permute2f128_ps(d, d, 0), _mm256_set1_ps(0.5f)),
                                   _mm256_setr_ps(0.0f, 0.0f, 0.0f, 0.0f, -0.0f, -0.0f, -0.0f, 0.0f));
    const __m256 to_right = _mm256_castsi256_ps(_mm256_set1_epi32(std::int32_t(go_left) - 1));
    left_ = _mm256_min_ps(_mm256_or_ps(v, to_right), left_);
    right_ =
        _mm256_min_ps(_mm256_or_ps(v, _mm256_xor_ps(to_right, _mm256_castsi256_ps(_mm256_set1_epi32(-1)))), right_);
#else
    const __m128 xyz = _mm_castsi128_ps(_mm_set_epi32(0, -1, -1, -1));
    const __m128 lo = _mm_and_ps(_mm_load_ps(r.v), xyz), nh = _mm_and_ps(_mm_load_ps(r.v + 4), xyz);
    const __m128 half = _mm_set1_ps(0.5f);
    const __m128 c = _mm_mul_ps(_mm_sub_ps(lo, nh), half);
    const __m128 nc = _mm_xor_ps(c, _mm_set1_ps(-0.0f));  // -c exactly ((-hi - lo) * 0.5 would be +0 where c is)
    const __m128 to_right = _mm_castsi128_ps(_mm_set1_epi32(std::int32_t(go_left) - 1));
    const __m128 to_left = _mm_castsi128_ps(_mm_set1_epi32(-std::int32_t(go_left)));
    left_lo_ = _mm_min_ps(_mm_or_ps(c, to_right), left_lo_);
    left_nh_ = _mm_min_ps(_mm_or_ps(nc, to_right), left_nh_);
    right_lo_ = _mm_min_ps(_mm_or_ps(c, to_left), right_lo_);
    right_nh_ = _mm_min_ps(_mm_or_ps(nc, to_left), right_nh_);
#endif
  }
  PointBox left() const {
#if CULLPIPE_BINNED_AVX2
    return point_box(_mm256_castps256_ps128(left_), _mm256_extractf128_ps(left_, 1));
#else
    return point_box(left_lo_, left_nh_);
#endif
  }
  PointBox right() const {
#if CULLPIPE_BINNED_AVX2
    return point_box(_mm256_castps256_ps128(right_), _mm256_extractf128_ps(right_, 1));
#else
    return point_box(right_lo_, right_nh_);
#endif
  }

 private:
  // lo and -hi to a PointBox (-(-hi) by flipping the sign bit: exact, zeros too). The fourth
  // lanes are never read.
  static PointBox point_box(__m128 lo, __m128 nh) {
    PointBox b;
    _mm_store_ps(b.lo.v, lo);
    _mm_store_ps(b.hi.v, _mm_xor_ps(nh, _mm_set1_ps(-0.0f)));
    return b;
  }
#if CULLPIPE_BINNED_AVX2
  __m256 left_, right_;
#else
  __m128 left_lo_, left_nh_, right_lo_, right_nh_;
#endif
};
#else  // no SSE2: the chosen side's box grown in place
class SideCentroids {
 public:
  void add(const Box8& r, std::uint32_t go_left) {
    PointBox& side = go_left ? left_ : right_;
    grow_point(side.lo, side.hi, centroid(r));
  }
  PointBox left() const { return left_; }
  PointBox right() const { return right_; }

 private:
  PointBox left_, right_;
};
#endif

// The box and the centroid box of objects [0, count).
void bounds_of(const Box8* refs, std::uint32_t count, Box8& box, PointBox& centroids) {
  for (std::uint32_t i = 0; i < count; ++i) {
    grow(box, refs[i]);
    grow_point(centroids.lo, centroids.hi, centroid(refs[i]));
  }
}

// `into` grown by the centroid box `later` of records that come after its own, lane by lane as
// grow_point grows it by their centroids one by one: minimums and maximums are exact, and ties
// keep the value `into` holds (the earlier record's), so a box gathered in pieces is the box
// gathered in one pass, bit for bit (-0 against +0 included).
inline void merge_later(PointBox& into, const PointBox& later) {
#if defined(__SSE2__)
  _mm_store_ps(into.lo.v, _mm_min_ps(_mm_load_ps(later.lo.v), _mm_load_ps(into.lo.v)));
  _mm_store_ps(into.hi.v, _mm_max_ps(_mm_load_ps(later.hi.v), _mm_load_ps(into.hi.v)));
#else
  for (int k = 0; k < 4; ++k) {
    into.lo.v[k] = later.lo.v[k] < into.lo.v[k] ? later.lo.v[k] : into.lo.v[k];
    into.hi.v[k] = into.hi.v[k] < later.hi.v[k] ? later.hi.v[k] : into.hi.v[k];
  }
#endif
}

// A build's constants.
struct Params {
  std::uint32_t max_leaf, bins, stride;
  float last_bin;
};

// A node waiting to be split.
struct Task {
  std::uint32_t node, first, count;
  std::uint32_t buffer;  // which buffer holds the node's records
  PointBox centroids;    // the box of the node's centroids (its box is in the node)
};

// One thread's bins. Bins of axis a are bin[a * stride, a * stride + bins), each a box, and
// their object counts count[a * stride + b] (integers beside the boxes); all empty between
// nodes. The stride rounds up to whole groups of the non-zero mask (the padding counts stay 0).
// Threads write their own workspaces for every node (every record, for the bins), so no
// cache line may hold two threads' data: a workspace is aligned to a line, and its arrays
// (and the sweep's) end in a line's worth of slots never used, so the next allocation's data
// starts on a line of its own. Without that, building the subtrees took 1.8x as long on 2
// threads as on one.
struct alignas(kCacheLine) Workspace {
  explicit Workspace(const Params& p)
      : bin(3 * std::size_t(p.stride) + kCacheLine / sizeof(Box8), kEmpty),
        count(3 * std::size_t(p.stride) + kCacheLine / sizeof(std::uint32_t), 0),
        used(3 * std::size_t(p.stride) + kCacheLine / sizeof(std::uint32_t)),
        sweep(p.bins) {}
  std::vector<Box8> bin;
  std::vector<std::uint32_t> count;
  std::vector<std::uint32_t> used;  // non-empty bins per axis, ascending
  std::uint32_t used_count[3] = {0, 0, 0};
  Sweep sweep;
};

// How a node's centroids map to bins: a flat axis (zero or subnormal extent) is binned with
// scale 0 (everything in bin 0) and not considered.
struct Binning {
  Lanes lo{{0, 0, 0, 0}}, scale{{0, 0, 0, 0}}, last{{0, 0, 0, 0}};
  bool usable[3] = {false, false, false};
};
inline Binning binning_of(const PointBox& centroids, const Params& p) {
  Binning b;
  b.last = Lanes{{p.last_bin, p.last_bin, p.last_bin, 0}};
  for (int axis = 0; axis < 3; ++axis) {
    b.lo.v[axis] = centroids.lo.v[axis];
    const float extent = centroids.hi.v[axis] - b.lo.v[axis];
    b.scale.v[axis] = float(p.bins) / extent;
    b.usable[axis] = extent > 0.0f && std::isfinite(extent) && std::isfinite(b.scale.v[axis]);
    if (!b.usable[axis]) b.scale.v[axis] = 0.0f;
  }
  return b;
}

// Bins records [0, count) of objs along all three axes in one pass, saving each record's
// packed bin indices in bin_of[0, count).
inline void bin_records(const Box8* objs, std::uint32_t count, std::uint32_t* bin_of, const Binning& binning,
                        Workspace& ws, std::uint32_t stride) {
  Box8* const bin0 = ws.bin.data();
  Box8* const bin1 = bin0 + stride;
  Box8* const bin2 = bin1 + stride;
  std::uint32_t* const count0 = ws.count.data();
  std::uint32_t* const count1 = count0 + stride;
  std::uint32_t* const count2 = count1 + stride;
  // Each record's bin indices are computed three records ahead of its bin updates: their
  // long chain of dependent operations then never holds up the updates, and more records
  // are in flight at once (fewer ahead hide less of the chain; more gain nothing). Past the
  // last record, the last one is computed again.
  const std::uint32_t final_i = count - 1;
  const auto indices_of = [&](std::uint32_t i) {
    return bin_indices(centroid(objs[std::min(i, final_i)]), binning.lo, binning.scale, binning.last);
  };
  auto ahead1 = indices_of(0), ahead2 = indices_of(1), ahead3 = indices_of(2);
  for (std::uint32_t i = 0; i < count; ++i) {
    const Rec r = load(objs[i]);
    const auto idx = ahead1;
    ahead1 = ahead2;
    ahead2 = ahead3;
    ahead3 = indices_of(i + 3);
    bin_of[i] = packed(idx);
    // Byte offsets of the bins' counts (4 bytes each); their boxes are at 8 times those.
    std::uint32_t o0, o1, o2;
    index3(times4(idx), o0, o1, o2);
    grow(box_at(bin0, o0), r);
    ++count_at(count0, o0);
    grow(box_at(bin1, o1), r);
    ++count_at(count1, o1);
    grow(box_at(bin2, o2), r);
    ++count_at(count2, o2);
  }
}

// The best binned SAH split over the three axes of a node of `count` objects whose records
// are in ws's bins: bins [0, split] of `axis` go left; axis -1 when no candidate wins.
struct Choice {
  int axis = -1;
  std::uint32_t split = 0;
};
inline Choice choose_split(Workspace& ws, const Binning& binning, std::uint32_t count, std::uint32_t stride) {
  for (int axis = 0; axis < 3; ++axis)
    ws.used_count[axis] =
        list_used(ws.count.data() + std::size_t(axis) * stride, stride, ws.used.data() + std::size_t(axis) * stride);
  double best_cost = INFINITY;
  Choice c;
  for (int axis = 0; axis < 3; ++axis) {
    if (!binning.usable[axis]) continue;
    const std::uint32_t* list = ws.used.data() + std::size_t(axis) * stride;
    const std::uint32_t j =
        ws.sweep.best(ws.bin.data() + std::size_t(axis) * stride, ws.count.data() + std::size_t(axis) * stride, list,
                      ws.used_count[axis], count, best_cost);
    if (j != kNone) c.axis = axis, c.split = list[j];
  }
  return c;
}

// Empties ws's bins (the non-empty ones choose_split listed) for the next node.
inline void clear_bins(Workspace& ws, std::uint32_t stride) {
  for (int axis = 0; axis < 3; ++axis)
    for (std::uint32_t j = 0; j < ws.used_count[axis]; ++j) {
      const std::size_t b = std::size_t(axis) * stride + ws.used[std::size_t(axis) * stride + j];
      ws.bin[b] = kEmpty;
      ws.count[b] = 0;
    }
}

// A node's split: [0, mid) of its range goes left, in buffer child_buffer.
struct Split {
  std::uint32_t mid = 0, child_buffer = 0;
  Box8 left_box = kEmpty, right_box = kEmpty;
  PointBox left_centroids, right_centroids;
};

// The left side's object count and both children's boxes: unions of the chosen bins.
inline void children_from_bins(const Workspace& ws, const Choice& c, std::uint32_t stride, Split& s) {
  const Box8* axis_bin = ws.bin.data() + std::size_t(c.axis) * stride;
  const std::uint32_t* list = ws.used.data() + std::size_t(c.axis) * stride;
  for (std::uint32_t j = 0; j < ws.used_count[c.axis]; ++j) {
    const std::uint32_t b = list[j];
    if (b <= c.split) s.mid += ws.count[std::size_t(c.axis) * stride + b];
    grow(b <= c.split ? s.left_box : s.right_box, axis_bin[b]);
  }
}

// Moves records [0, count) of objs, stably, to out: bins [0, split] of `axis` to out[l, ...),
// the others to out[r, ...), gathering each side's centroid box on the way; l and r end past
// the last record each side received.
inline void partition_records(const Box8* objs, std::uint32_t count, const std::uint32_t* bin_of, int axis,
                              std::uint32_t split, Box8* out, std::uint32_t& l, std::uint32_t& r,
                              SideCentroids& sides) {
  // Each record's bin along the split axis: byte `axis` of its packed indices.
  const std::uint8_t* const split_bin = reinterpret_cast<const std::uint8_t*>(bin_of) + kByteOf[axis];
  for (std::uint32_t i = 0; i < count; ++i) {
    const Box8& ref = objs[i];
    const std::uint32_t go_left =
        split_bin[sizeof(std::uint32_t) * std::size_t(i)] <= split;  // size_t: nodes past 2^30 objects
    // l or r, as a select: GCC makes it a conditional move in both variants (a branch on
    // go_left would mispredict wherever the sides follow no pattern). `r + (l - r) * go_left` and
    // `r ^ ((l ^ r) & -go_left)` are branch-free whatever the compiler does, but cost more.
    const std::uint32_t at = go_left ? l : r;
    copy(out[at], ref);
    sides.add(ref, go_left);
    l += go_left;
    r += go_left ^ 1u;
  }
}

// A split that moved nothing (all centroids equal, or no candidate won) splits the range in
// half by id: every node's records are already in id order (the root's are, and the partition
// and this split keep the order), so the halves are the lower and the upper ids.
inline void split_in_half_if_one_sided(const Task& task, const Box8* objs, Split& s) {
  if (s.mid != 0 && s.mid != task.count) return;
  s.mid = task.count / 2;
  s.child_buffer = task.buffer;
  s.left_box = s.right_box = kEmpty;
  s.left_centroids = s.right_centroids = PointBox{};
  bounds_of(objs, s.mid, s.left_box, s.left_centroids);
  bounds_of(objs + s.mid, task.count - s.mid, s.right_box, s.right_centroids);
}

// A node's split on the calling thread.
inline Split split_node(const Task& task, Box8* const buffer[2], std::uint32_t* bin_of_all, Workspace& ws,
                        const Params& p) {
  const Box8* objs = buffer[task.buffer] + task.first;
  std::uint32_t* const bin_of = bin_of_all + task.first;
  const Binning binning = binning_of(task.centroids, p);
  bin_records(objs, task.count, bin_of, binning, ws, p.stride);
  const Choice c = choose_split(ws, binning, task.count, p.stride);
  Split s;
  s.child_buffer = task.buffer;
  if (c.axis >= 0) {
    children_from_bins(ws, c, p.stride, s);
    s.child_buffer = 1 - task.buffer;
    std::uint32_t l = 0, r = s.mid;
    SideCentroids sides;
    partition_records(objs, task.count, bin_of, c.axis, c.split, buffer[s.child_buffer] + task.first, l, r, sides);
    if (l != s.mid || r != task.count)
      throw std::logic_error("build_binned_sah: bin counts disagree with the partition");
    s.left_centroids = sides.left();
    s.right_centroids = sides.right();
  }
  clear_bins(ws, p.stride);
  split_in_half_if_one_sided(task, objs, s);
  return s;
}

// Chunk c of `chunks` equal parts of [0, count).
inline std::uint32_t chunk_begin(std::uint32_t count, std::size_t c, std::size_t chunks) {
  return std::uint32_t(std::uint64_t(count) * c / chunks);
}

// The same split as split_node, with each pass over the records cut into one chunk per thread
// of `pool`. Bins and centroid boxes are gathered per chunk and merged in chunk order, where
// ties keep the earlier chunk's value, as one pass keeps the earlier record's; counts are
// integers; the partition writes each chunk's records where the one-pass partition would (its
// start on each side is the earlier chunks' counts). So the split is split_node's, bit for bit.
Split split_node_parallel(const Task& task, Box8* const buffer[2], std::uint32_t* bin_of_all,
                          std::vector<Workspace>& ws, const Params& p, ThreadPool& pool) {
  const Box8* objs = buffer[task.buffer] + task.first;
  std::uint32_t* const bin_of = bin_of_all + task.first;
  const std::size_t chunks = ws.size();
  const Binning binning = binning_of(task.centroids, p);
  auto bin_chunk = [&](std::size_t c) {
    const std::uint32_t b = chunk_begin(task.count, c, chunks), e = chunk_begin(task.count, c + 1, chunks);
    if (e > b) bin_records(objs + b, e - b, bin_of + b, binning, ws[c], p.stride);
  };
  pool.parallel_for(chunks, bin_chunk);
  const std::size_t slots = 3 * std::size_t(p.stride);
  for (std::size_t c = 1; c < chunks; ++c)
    for (std::size_t b = 0; b < slots; ++b)
      if (ws[c].count[b] != 0) {
        grow(ws[0].bin[b], ws[c].bin[b]);
        ws[0].count[b] += ws[c].count[b];
      }
  const Choice choice = choose_split(ws[0], binning, task.count, p.stride);
  Split s;
  s.child_buffer = task.buffer;
  if (choice.axis >= 0) {
    children_from_bins(ws[0], choice, p.stride, s);
    // Each chunk's start on either side: the earlier chunks' left and right counts (from their
    // own bins; chunk 0's are the rest).
    std::vector<std::uint32_t> left_start(chunks + 1, 0), right_start(chunks + 1, s.mid);
    std::uint32_t left_of_others = 0;
    for (std::size_t c = 1; c < chunks; ++c) {
      std::uint32_t left = 0;
      for (std::uint32_t b = 0; b <= choice.split; ++b) left += ws[c].count[std::size_t(choice.axis) * p.stride + b];
      left_start[c + 1] = left;  // (made a running sum below)
      left_of_others += left;
    }
    left_start[1] = s.mid - left_of_others;
    for (std::size_t c = 1; c <= chunks; ++c) {
      const std::uint32_t size = chunk_begin(task.count, c, chunks) - chunk_begin(task.count, c - 1, chunks);
      right_start[c] = right_start[c - 1] + (size - left_start[c]);
      left_start[c] += left_start[c - 1];
    }
    s.child_buffer = 1 - task.buffer;
    Box8* const out = buffer[s.child_buffer] + task.first;
    std::vector<PointBox> lefts(chunks), rights(chunks);
    std::vector<std::uint8_t> agree(chunks, 0);
    auto move_chunk = [&](std::size_t c) {
      const std::uint32_t b = chunk_begin(task.count, c, chunks), e = chunk_begin(task.count, c + 1, chunks);
      std::uint32_t l = left_start[c], r = right_start[c];
      SideCentroids sides;
      partition_records(objs + b, e - b, bin_of + b, choice.axis, choice.split, out, l, r, sides);
      agree[c] = l == left_start[c + 1] && r == right_start[c + 1];
      lefts[c] = sides.left();
      rights[c] = sides.right();
    };
    pool.parallel_for(chunks, move_chunk);
    for (std::size_t c = 0; c < chunks; ++c)
      if (!agree[c]) throw std::logic_error("build_binned_sah: bin counts disagree with the partition");
    s.left_centroids = lefts[0];
    s.right_centroids = rights[0];
    for (std::size_t c = 1; c < chunks; ++c) {
      merge_later(s.left_centroids, lefts[c]);
      merge_later(s.right_centroids, rights[c]);
    }
  }
  for (Workspace& w : ws) {
    std::fill(w.bin.begin(), w.bin.end(), kEmpty);
    std::fill(w.count.begin(), w.count.end(), 0u);
  }
  split_in_half_if_one_sided(task, objs, s);
  return s;
}

// A node of at most max_leaf objects becomes a leaf: its range and its objects' ids. Up to
// kFixedLeafWrite ids go as a fixed run of that many slots (no branch on the count), the slots
// past the leaf's range rewritten with what they hold, when the run stays inside `limit` (the
// range of objects only this thread writes).
constexpr std::uint32_t kFixedLeafWrite = 4;
inline void make_leaf(Node& node, std::uint32_t first, std::uint32_t count, const Box8* records, std::uint32_t* objects,
                      std::uint32_t limit, bool fixed_leaf_write) {
  node.first = first;
  node.count = count;
  const Box8* objs = records + first;
  std::uint32_t* ids = objects + first;
  if (fixed_leaf_write && first + kFixedLeafWrite <= limit) {
    for (std::uint32_t i = 0; i < kFixedLeafWrite; ++i) ids[i] = i < count ? objs[i].id() : ids[i];
  } else {
    for (std::uint32_t i = 0; i < count; ++i) ids[i] = objs[i].id();
  }
}

// Nodes appended to a vector (the whole tree on one thread) or to raw memory (a subtree).
struct VectorNodes {
  std::vector<Node>& v;
  std::uint32_t size() const { return std::uint32_t(v.size()); }
  void add_two() {
    v.emplace_back();
    v.emplace_back();
  }
  Node& operator[](std::uint32_t i) { return v[i]; }
};
struct RawNodes {
  Node* data;
  std::uint32_t count;
  std::uint32_t size() const { return count; }
  void add_two() {
    data[count] = Node{};
    data[count + 1] = Node{};
    count += 2;
  }
  Node& operator[](std::uint32_t i) { return data[i]; }
};

// A split node's two children, at left and left + 1: their boxes, a leaf at once for a child of
// at most max_leaf objects (its ids written as make_leaf writes them, within `limit`), the
// others pushed onto `stack`, the left one on top.
template <class Nodes>
void add_children(Nodes& nodes, const Task& task, const Split& s, std::uint32_t left, Box8* const buffer[2],
                  const Params& p, std::uint32_t* objects, std::uint32_t limit, bool fixed_leaf_write,
                  std::vector<Task>& stack) {
  nodes[task.node].left = left;
  nodes[task.node].right = left + 1;
  nodes[left].box = s.left_box.box();
  nodes[left + 1].box = s.right_box.box();
  const std::uint32_t right_count = task.count - s.mid;
  if (s.mid <= p.max_leaf)
    make_leaf(nodes[left], task.first, s.mid, buffer[s.child_buffer], objects, limit, fixed_leaf_write);
  if (right_count <= p.max_leaf) {
    make_leaf(nodes[left + 1], task.first + s.mid, right_count, buffer[s.child_buffer], objects, limit,
              fixed_leaf_write);
  } else {
    stack.push_back({left + 1, task.first + s.mid, right_count, s.child_buffer, s.right_centroids});
  }
  if (s.mid > p.max_leaf) stack.push_back({left, task.first, s.mid, s.child_buffer, s.left_centroids});
}

// Splits `root` and everything below it on the calling thread, depth first, the left child
// first: a node's two children are appended when it is split, so a subtree's nodes follow its
// children in one block. Objects [root.first, root.first + root.count) are this call's alone.
template <class Nodes>
void build_subtree(const Task& root, Nodes& nodes, Box8* const buffer[2], std::uint32_t* bin_of, Workspace& ws,
                   const Params& p, std::uint32_t* objects, std::vector<Task>& stack) {
  const bool fixed_leaf_write = p.max_leaf <= kFixedLeafWrite;
  const std::uint32_t limit = root.first + root.count;
  stack.clear();
  stack.push_back(root);
  while (!stack.empty()) {
    const Task task = stack.back();
    stack.pop_back();
    const Split s = split_node(task, buffer, bin_of, ws, p);
    const std::uint32_t left = nodes.size();
    nodes.add_two();
    add_children(nodes, task, s, left, buffer, p, objects, limit, fixed_leaf_write, stack);
  }
}

// Below this many objects (and at least n / kTasksPerBuild), a node's subtree is built by one
// thread; above it, each pass over a node's records is shared by every thread. Fixed by n
// alone, so the cut, and with it the tree, is the same for any number of threads. The passes
// above the cut run at the speed of memory, not of the threads (4 levels of 10^6 objects take
// ~21 ms on 2 threads, ~26 on one), so few levels go there: 16 tasks and more balanced 2
// threads as well as 128 did, and built 10^6 objects 10% faster.
constexpr std::uint32_t kMinTaskObjects = 4096, kTasksPerBuild = 16;

// The tree on the threads of `pool`, in the order one thread would have appended its nodes.
// The nodes above the cut are split in depth-first order with every thread in each pass; the
// subtrees below it are built as tasks, each one's nodes a block that follows its root's
// split. With leaves of one object, a subtree of c objects has exactly 2c - 1 nodes, so every
// node's place is known as the splits above the cut happen, and the tasks build straight into
// the tree. Otherwise each task builds into memory of its own (a subtree of c objects has at
// most 2c - 1 nodes: its region of 2c slots at 2 * first never meets another's), and the tree
// is put together afterwards: each block where its root was split.
void build_threaded(std::uint32_t n, const Task& root, Box8* const buffer[2], BinnedScratch& scratch, const Params& p,
                    ThreadPool& pool, Tree& tree) {
  const std::uint32_t cut = std::max(kMinTaskObjects, n / kTasksPerBuild);
  const bool direct = p.max_leaf == 1;
  std::vector<Workspace> ws;
  ws.reserve(pool.size());
  for (unsigned t = 0; t < pool.size(); ++t) ws.emplace_back(p);
  std::uint32_t* const bin_of = scratch.bin_of.get();
  // Above the cut, directly: the tree itself, at final places. Otherwise a tree of its own
  // ("top"), and the order things happen in: a split (children appended) or a task started.
  std::vector<Node> top;
  if (direct) {
    tree.nodes.resize(2 * std::size_t(n) - 1);
  } else {
    top.resize(1);
    top[0].box = tree.nodes[0].box;
  }
  std::vector<Node>& upper = direct ? tree.nodes : top;
  std::vector<Task> tasks, stack{root};
  std::vector<std::uint32_t> block;  // direct: each task's first descendant's place
  std::uint32_t next = 1;            // direct: the next place
  std::vector<std::int64_t> events;  // otherwise: >= 0 top node split; < 0 task -1 - event started
  while (!stack.empty()) {
    const Task task = stack.back();
    stack.pop_back();
    if (task.count <= cut) {
      if (direct) {
        block.push_back(next);
        next += 2 * task.count - 2;
      } else {
        events.push_back(-1 - std::int64_t(tasks.size()));
      }
      tasks.push_back(task);
      continue;
    }
    const Split s = split_node_parallel(task, buffer, bin_of, ws, p, pool);
    std::uint32_t left = next;
    if (direct) {
      next += 2;
    } else {
      events.push_back(task.node);
      left = std::uint32_t(top.size());
      top.emplace_back();
      top.emplace_back();
    }
    VectorNodes nodes{upper};
    add_children(nodes, task, s, left, buffer, p, tree.objects.data(), n, false, stack);
  }
  if (direct && next != tree.nodes.size()) throw std::logic_error("build_binned_sah: subtree sizes disagree");
  // The subtrees, largest first (they balance better).
  if (!direct) scratch.reserve_nodes(n);
  std::vector<std::uint32_t> by_size(tasks.size()), task_nodes(tasks.size());
  for (std::uint32_t t = 0; t < tasks.size(); ++t) by_size[t] = t;
  std::sort(by_size.begin(), by_size.end(), [&](std::uint32_t a, std::uint32_t b) {
    return tasks[a].count != tasks[b].count ? tasks[a].count > tasks[b].count : a < b;
  });
  struct alignas(kCacheLine) Stack {  // (a line each: see Workspace)
    std::vector<Task> v;
  };
  std::vector<Stack> stacks(pool.size());
  auto build_task = [&](std::size_t i) {
    const std::uint32_t t = by_size[i];
    const unsigned thread = pool.thread_index();
    Task local = tasks[t];
    // Direct: appended at the task's place in the tree, under its root's place. Otherwise:
    // the root at slot 0 of the task's region, the rest after it.
    RawNodes nodes{tree.nodes.data(), direct ? block[t] : 0};
    if (!direct) {
      nodes = {scratch.nodes.get() + 2 * std::size_t(tasks[t].first), 1};
      nodes.data[0] = Node{};
      local.node = 0;
    }
    build_subtree(local, nodes, buffer, bin_of, ws[thread], p, tree.objects.data(), stacks[thread].v);
    task_nodes[t] = nodes.count;
  };
  pool.parallel_for(tasks.size(), build_task);
  if (direct) {
    for (std::size_t t = 0; t < tasks.size(); ++t)
      if (task_nodes[t] != block[t] + 2 * tasks[t].count - 2)
        throw std::logic_error("build_binned_sah: subtree sizes disagree");
    return;
  }
  // Where every node goes: walk the events in order, as one thread appends.
  std::vector<std::uint32_t> top_final(top.size(), 0);
  block.assign(tasks.size(), 0);
  for (const std::int64_t e : events) {
    if (e >= 0) {
      top_final[top[std::size_t(e)].left] = next;
      top_final[top[std::size_t(e)].right] = next + 1;
      next += 2;
    } else {
      const std::size_t t = std::size_t(-1 - e);
      block[t] = next;
      next += task_nodes[t] - 1;
    }
  }
  tree.nodes.resize(next);
  for (std::size_t i = 0; i < top.size(); ++i) {
    Node node = top[i];
    if (!node.leaf()) node.left = top_final[node.left], node.right = top_final[node.right];
    tree.nodes[top_final[i]] = node;
  }
  // A subtree's slot i > 0 goes to block + i - 1; its root's children are set in place.
  auto place_task = [&](std::size_t t) {
    const Node* local = scratch.nodes.get() + 2 * std::size_t(tasks[t].first);
    const auto place = [&](std::uint32_t i) { return i == kNone ? kNone : block[t] + i - 1; };
    Node& root_node = tree.nodes[top_final[tasks[t].node]];
    root_node.left = place(local[0].left);
    root_node.right = place(local[0].right);
    Node* out = tree.nodes.data() + block[t];
    for (std::uint32_t i = 1; i < task_nodes[t]; ++i) {
      Node node = local[i];
      node.left = place(node.left);
      node.right = place(node.right);
      out[i - 1] = node;
    }
  };
  pool.parallel_for(tasks.size(), place_task);
}

}  // namespace

// Implementation notes (the tree is fixed by the description in bvh.hpp; these only make it
// fast): objects are copied once into 32-byte records (Box8 with the id), and a split moves
// its node's records into the other of two buffers (stable, branch-free), so every pass reads
// memory in order; one pass per node bins all three axes at once; the children's boxes are
// unions of the chosen bins and their centroid boxes are gathered while the records move, so
// no node is scanned again to find its bounds; the SAH sweep visits only non-empty bins (an
// empty bin repeats the cost of the split before it, which is tried first and kept on ties),
// listed from a mask of the non-zero counts; the binning pass saves each record's three bin
// indices, so the partition reads a byte instead of recomputing a centroid; bin counts are
// integers beside the bin boxes; the large buffers ask for transparent huge pages. On several
// threads (build_threaded), the same tree.
void build(std::span<const Aabb> boxes, const TopDownOptions& options, BinnedScratch& scratch, Tree& tree,
           ThreadPool* pool) {
  tree.nodes.clear();
  tree.objects.clear();
  const std::size_t n = boxes.size();
  if (n == 0) return;
  // Node indices are 32-bit, and a tree of n objects may have 2n - 1 nodes.
  if (n > std::size_t(kNone - 1) / 2)
    throw std::length_error("build_binned_sah: " + std::to_string(n) + " objects; at most " +
                            std::to_string((kNone - 1) / 2) + " fit 32-bit node indices");
  const std::uint32_t bins = std::clamp<std::uint32_t>(options.bins, 2, 256);
  const Params p{std::max<std::uint32_t>(options.max_leaf_size, 1), bins,
                 (bins + kMaskStep - 1) / kMaskStep * kMaskStep, float(bins - 1)};
  const bool threaded = pool != nullptr && pool->size() > 1 && n > kMinTaskObjects;
  // Two buffers of records, left uninitialised (they are written before they are read).
  scratch.reserve(n);
  Box8* const buffer[2] = {scratch.buffer[0].get(), scratch.buffer[1].get()};
  Box8 root_box = kEmpty;
  PointBox root_centroids;
  const auto store_range = [&](std::size_t b, std::size_t e, Box8& box, PointBox& centroids) {
    for (std::size_t i = b; i < e; ++i) {
      Box8& r = buffer[0][i];
      store_record(r, boxes[i], std::uint32_t(i));
      grow(box, r);
      grow_point(centroids.lo, centroids.hi, centroid(r));
    }
  };
  if (threaded) {
    // Per chunk, merged in chunk order (merge_later): the one-pass boxes. Each chunk grows
    // boxes of its own and stores them once (the chunks' entries share cache lines).
    const std::size_t chunks = pool->size();
    std::vector<Box8> chunk_box(chunks, kEmpty);
    std::vector<PointBox> chunk_centroids(chunks);
    auto store_chunk = [&](std::size_t c) {
      Box8 box = kEmpty;
      PointBox centroids;
      store_range(chunk_begin(std::uint32_t(n), c, chunks), chunk_begin(std::uint32_t(n), c + 1, chunks), box,
                  centroids);
      chunk_box[c] = box;
      chunk_centroids[c] = centroids;
    };
    pool->parallel_for(chunks, store_chunk);
    for (std::size_t c = 0; c < chunks; ++c) {
      grow(root_box, chunk_box[c]);
      merge_later(root_centroids, chunk_centroids[c]);
    }
  } else {
    store_range(0, n, root_box, root_centroids);
  }
  tree.objects.resize(n);
  if (tree.nodes.capacity() < 2 * n) {
    tree.nodes.reserve(2 * n);  // at most 2n - 1; pages never touched cost nothing
    cullpipe::detail::advise_huge_pages(tree.nodes.data(), tree.nodes.capacity() * sizeof(Node));
  }
  tree.nodes.emplace_back();
  tree.nodes[0].box = root_box.box();
  if (n <= p.max_leaf) {
    make_leaf(tree.nodes[0], 0, std::uint32_t(n), buffer[0], tree.objects.data(), std::uint32_t(n),
              p.max_leaf <= kFixedLeafWrite);
    return;
  }
  const Task root{0, 0, std::uint32_t(n), 0, root_centroids};
  if (threaded) {
    build_threaded(std::uint32_t(n), root, buffer, scratch, p, *pool, tree);
    return;
  }
  Workspace ws(p);
  std::vector<Task> stack;
  VectorNodes nodes{tree.nodes};
  build_subtree(root, nodes, buffer, scratch.bin_of.get(), ws, p, tree.objects.data(), stack);
}

}  // namespace cullpipe::bvh::detail::CULLPIPE_BINNED_NS
