#pragma once
#include <string>

#include "cullpipe/geom/aabb.hpp"
#include "cullpipe/geom/obb.hpp"
#include "cullpipe/geom/sphere.hpp"

namespace cullpipe {

/// Checks that a volume can be culled: every value finite, min <= max, radius and half
/// extents >= 0, OBB basis orthonormal within 1e-3. Returns an empty string when valid,
/// otherwise what is wrong (e.g. "min.y > max.y", "radius is NaN").
std::string invalid_reason(const Aabb& b);
std::string invalid_reason(const Obb& b);
std::string invalid_reason(const Sphere& s);

/// invalid_reason(v).empty(), without building strings: for checks of every volume of a scene
/// on each upload.
bool is_valid(const Aabb& b);
bool is_valid(const Obb& b);
bool is_valid(const Sphere& s);

}  // namespace cullpipe
