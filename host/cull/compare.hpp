#pragma once
#include <cstddef>
#include <span>
#include <string>

#include "geom/aabb.hpp"
#include "geom/classification.hpp"
#include "geom/frustum.hpp"
#include "geom/obb.hpp"
#include "geom/sphere.hpp"

namespace cullpipe {

/// Human-readable forms with every float printed to round-trip precision (%.9g), so a
/// reported case can be reproduced exactly.
std::string describe(const Aabb& b);
std::string describe(const Obb& b);
std::string describe(const Sphere& s);
std::string describe(const Frustum& f);

/// Index of the first position where `expected` and `actual` differ, or `npos` when equal
/// (sizes differing counts as a difference at the shorter size).
std::size_t first_mismatch(std::span<const Classification> expected, std::span<const Classification> actual);
inline constexpr std::size_t npos = static_cast<std::size_t>(-1);

/// Counts positions where the two differ (positions beyond the shorter span count too).
std::size_t count_mismatches(std::span<const Classification> expected, std::span<const Classification> actual);

/// "object 17: aabb min (..) max (..); planes [...]; cpu says inside, gpu says intersecting".
template <class Volume>
std::string describe_mismatch(std::size_t object, const Volume& v, const Frustum& f, Classification cpu,
                              Classification gpu) {
  return "object " + std::to_string(object) + ": " + describe(v) + "; frustum " + describe(f) + "; cpu says " +
         std::string(to_string(cpu)) + ", gpu says " + std::string(to_string(gpu));
}

}  // namespace cullpipe
