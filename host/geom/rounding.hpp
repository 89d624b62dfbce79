#pragma once
#include <cmath>
#include <limits>

namespace cullpipe {

/// The largest float <= v (v finite or infinite, never NaN).
inline float round_down(double v) {
  float f = static_cast<float>(v);
  if (static_cast<double>(f) > v) f = std::nextafter(f, -std::numeric_limits<float>::infinity());
  return f;
}

/// The smallest float >= v.
inline float round_up(double v) {
  float f = static_cast<float>(v);
  if (static_cast<double>(f) < v) f = std::nextafter(f, std::numeric_limits<float>::infinity());
  return f;
}

}  // namespace cullpipe
