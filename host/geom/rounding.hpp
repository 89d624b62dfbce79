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
  if (magnitude > 0x7f800000u || u == 0xff800000u) return f;  // NaN, -inf
  if (magnitude == 0) return std::bit_cast<float>(0x80000001u);  // -denorm_min
  return std::bit_cast<float>(u >> 31 ? u + 1 : u - 1);          // away from zero if negative
}
inline float float_above(float f) {
  const std::uint32_t u = std::bit_cast<std::uint32_t>(f), magnitude = u & 0x7fffffffu;
  if (magnitude > 0x7f800000u || u == 0x7f800000u) return f;  // NaN, +inf
  if (magnitude == 0) return std::bit_cast<float>(0x00000001u);  // denorm_min
  return std::bit_cast<float>(u >> 31 ? u - 1 : u + 1);
}

/// The largest float <= v (v finite or infinite, never NaN).
inline float round_down(double v) {
  float f = static_cast<float>(v);
  if (static_cast<double>(f) > v) f = float_below(f);
  return f;
}

/// The smallest float >= v.
inline float round_up(double v) {
  float f = static_cast<float>(v);
  if (static_cast<double>(f) < v) f = float_above(f);
  return f;
}

}  // namespace cullpipe
