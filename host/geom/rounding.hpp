#pragma once
#include <bit>
#include <cmath>
#include <cstdint>
#include <limits>

namespace cullpipe {

/// std::nextafter(f, -inf) and std::nextafter(f, +inf), inline: on the bit pattern instead of
/// a library call (the bounds of every object of an upload take several). NaN stays NaN; both
/// zeros step to the smallest subnormal of the step's sign; -inf / +inf stay where they are.
inline float float_below(float f) {
  if (!(f > -std::numeric_limits<float>::infinity())) return f;  // -inf, NaN
  if (f == 0.0f) return -std::numeric_limits<float>::denorm_min();
  const std::uint32_t u = std::bit_cast<std::uint32_t>(f);
  return std::bit_cast<float>(f > 0.0f ? u - 1 : u + 1);
}
inline float float_above(float f) {
  if (!(f < std::numeric_limits<float>::infinity())) return f;  // +inf, NaN
  if (f == 0.0f) return std::numeric_limits<float>::denorm_min();
  const std::uint32_t u = std::bit_cast<std::uint32_t>(f);
  return std::bit_cast<float>(f > 0.0f ? u + 1 : u - 1);
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
