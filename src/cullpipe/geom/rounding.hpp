#pragma once
#include <bit>
#include <cmath>
#include <cstdint>
#include <limits>

namespace cullpipe {

/// std::nextafter(f, -inf) and std::nextafter(f, +inf), inline: on the bit pattern instead of
/// a library call (the bounds of every object of an upload take several), and decided on the
/// bits alone, so a subnormal steps as it should whatever the floating-point mode (a float
/// comparison under DAZ would read it as zero). NaN stays NaN; both zeros step to the
/// smallest subnormal of the step's sign; -inf / +inf stay where they are.
inline float float_below(float f) {
  const std::uint32_t u = std::bit_cast<std::uint32_t>(f), magnitude = u & 0x7fffffffu;
  if (magnitude > 0x7f800000u || u == 0xff800000u) return f;     // NaN, -inf
  if (magnitude == 0) return std::bit_cast<float>(0x80000001u);  // -denorm_min
  return std::bit_cast<float>(u >> 31 ? u + 1 : u - 1);          // away from zero if negative
}
inline float float_above(float f) {
  const std::uint32_t u = std::bit_cast<std::uint32_t>(f), magnitude = u & 0x7fffffffu;
  if (magnitude > 0x7f800000u || u == 0x7f800000u) return f;     // NaN, +inf
  if (magnitude == 0) return std::bit_cast<float>(0x00000001u);  // denorm_min
  return std::bit_cast<float>(u >> 31 ? u - 1 : u + 1);
}

namespace detail {
/// |v| < 2^-126 (the smallest normal float), decided on the bits.
inline bool below_normal_float(double v) {
  return (std::bit_cast<std::uint64_t>(v) & 0x7fffffffffffffffu) < std::bit_cast<std::uint64_t>(0x1p-126);
}

/// round_down / round_up for |v| below the smallest normal float, on the bits: a conversion
/// to float would flush such a result to zero under FTZ, and under DAZ a comparison reads a
/// subnormal as zero. Proof: docs/numerics.md, Rounding model.
inline float tiny_to_float(double v, bool up) {
  const std::uint64_t bits = std::bit_cast<std::uint64_t>(v), magnitude = bits & 0x7fffffffffffffffu;
  const bool negative = bits >> 63;
  const std::uint32_t sign = negative ? 0x80000000u : 0u;
  if (magnitude == 0) return std::bit_cast<float>(sign);             // +-0 as it is
  if (magnitude < std::bit_cast<std::uint64_t>(0x1p-1000))           // (a double subnormal too: DAZ reads it as 0)
    return std::bit_cast<float>(up != negative ? sign | 1u : sign);  // the smallest subnormal away from zero, or zero
  const double scaled = std::fabs(v) * 0x1p149;
  // Away from zero for round_up of a positive v and round_down of a negative one.
  const double significand = up != negative ? std::ceil(scaled) : std::floor(scaled);
  return std::bit_cast<float>(sign | static_cast<std::uint32_t>(significand));
}
}  // namespace detail

/// The largest float <= v (v finite or infinite, never NaN), whatever the floating-point mode
/// (rounding direction, FTZ, DAZ) it runs in (docs/numerics.md, Rounding model). A caller's own
/// arithmetic before it is another matter: under DAZ a subnormal float input converts to a double 0.
inline float round_down(double v) {
  if (detail::below_normal_float(v)) return detail::tiny_to_float(v, false);
  float f = static_cast<float>(v);
  if (static_cast<double>(f) > v) f = float_below(f);
  return f;
}

/// The smallest float >= v, whatever the floating-point mode.
inline float round_up(double v) {
  if (detail::below_normal_float(v)) return detail::tiny_to_float(v, true);
  float f = static_cast<float>(v);
  if (static_cast<double>(f) < v) f = float_above(f);
  return f;
}

}  // namespace cullpipe
