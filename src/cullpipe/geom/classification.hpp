#pragma once
#include <cstdint>
#include <string_view>

namespace cullpipe {

/// Result of testing a volume against a frustum.
/// OUTSIDE: the volume is entirely behind at least one plane (it cannot be visible).
/// INSIDE: the volume is in front of every plane (entirely inside the frustum).
/// INTERSECTING: neither; the volume may be visible (conservative: it may still be outside).
/// OCCLUDED: inside or intersecting the frustum, but hidden behind a depth pyramid's depths
/// (occlusion culling only): none of its fragments can pass the depth test.
enum class Classification : std::uint8_t { Outside = 0, Intersecting = 1, Inside = 2, Occluded = 3 };

constexpr std::string_view to_string(Classification c) {
  switch (c) {
    case Classification::Outside:
      return "outside";
    case Classification::Intersecting:
      return "intersecting";
    case Classification::Inside:
      return "inside";
    case Classification::Occluded:
      return "occluded";
  }
  return "invalid";
}

/// True when the volume may be visible (INSIDE or INTERSECTING).
constexpr bool is_visible(Classification c) { return c == Classification::Intersecting || c == Classification::Inside; }

}  // namespace cullpipe
