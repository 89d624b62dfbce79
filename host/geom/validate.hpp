#pragma once
#include <string>

#include "geom/aabb.hpp"
#include "geom/obb.hpp"
#include "geom/sphere.hpp"

namespace cullpipe {

/// Checks that a volume can be culled: every value finite, min <= max, radius and half
/// extents >= 0, OBB basis orthonormal within 1e-3. Returns an empty string when valid,
/// otherwise what is wrong (e.g. "min.y > max.y", "radius is NaN").
std::string invalid_reason(const Aabb& b);
std::string invalid_reason(const Obb& b);
std::string invalid_reason(const Sphere& s);

}  // namespace cullpipe
