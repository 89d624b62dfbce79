// Part of the SIMD kernels (simd_kernels.inl includes it once per instruction set). Listing ids from
// bits and marks, and the read-floor loops (touch) the benchmark measures against.
#include <cstddef>
#include <cstdint>

namespace cullpipe::fast::detail {
namespace CULLPIPE_SIMD_NS {
namespace {

std::uint32_t* expand_ids(const std::uint32_t* bits, std::size_t vectors, std::uint32_t first, std::uint32_t* out,
                          const std::uint32_t* out_end) {
  for (std::size_t v = 0; v < vectors; ++v, first += W) {
    if (out_end - out >= static_cast<std::ptrdiff_t>(W)) {  // room for the vector store
      out = append_ids(out, first, bits[v]);
      continue;
    }
    for (std::uint32_t rest = bits[v]; rest != 0; rest &= rest - 1)
      *out++ = first + static_cast<std::uint32_t>(__builtin_ctz(rest));
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
      // vector of words at a time.
      while (w + 1 + kVectorWords <= words &&
             all_zero(load_ints(reinterpret_cast<const std::uint32_t*>(marks + w + 1)))) {
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
    // check per group.
    if (w + 1 < words && out_end - out >= 64) {
      for (unsigned q = 0; q < 64 / W; ++q) {
        const std::uint32_t lanes = static_cast<std::uint32_t>(word >> (q * W)) & kAllLanes;
        compress_store(out, load_ints(from + q * W), lanes);
        out += __builtin_popcount(lanes);
      }
      continue;
    }
    // Every group of W marks, those with none too, without a branch on them (it would
    // mispredict at half visible).
    for (unsigned q = 0; q < 64 / W; ++q) {
      const std::uint32_t lanes = static_cast<std::uint32_t>(word >> (q * W)) & kAllLanes;
      if (out_end - out >= static_cast<std::ptrdiff_t>(W)) {  // room for the vector store
        compress_store(out, load_ints_where(from + q * W, lanes), lanes);
        out += __builtin_popcount(lanes);
        continue;
      }
      for (std::uint32_t rest = lanes; rest != 0 && out != out_end; rest &= rest - 1)
        *out++ = from[q * W + static_cast<unsigned>(__builtin_ctz(rest))];
    }
  }
  return out;
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

}  // namespace
}  // namespace CULLPIPE_SIMD_NS
}  // namespace cullpipe::fast::detail
