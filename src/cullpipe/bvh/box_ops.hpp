#pragma once
// Small box operations the BVH builders, metrics, refit and upload checks share (internal to
// src/cullpipe/bvh and src/cullpipe/gpu). Areas in double: only ratios matter, and every builder's SAH cost is
// computed by the same operations, so costs compare exactly across builders.
#include <cmath>
#include <compare>
#include <glm/common.hpp>
#include <glm/ext/vector_double3.hpp>
#include <glm/vec3.hpp>
#include <glm/vector_relational.hpp>

#include "cullpipe/geom/aabb.hpp"

namespace cullpipe::bvh::detail {

/// The empty box: growing it by anything gives that thing.
inline Aabb empty_box() { return {glm::vec3(INFINITY), glm::vec3(-INFINITY)}; }

inline void grow(Aabb& a, const Aabb& b) {
  a.min = glm::min(a.min, b.min);
  a.max = glm::max(a.max, b.max);
}

inline void grow(Aabb& a, const glm::vec3& p) {
  a.min = glm::min(a.min, p);
  a.max = glm::max(a.max, p);
}

inline Aabb merged(const Aabb& a, const Aabb& b) { return {glm::min(a.min, b.min), glm::max(a.max, b.max)}; }

/// Half the surface area, in double; 0 for an empty box.
inline double half_area(const Aabb& b) {
  if (!(b.min.x <= b.max.x)) return 0.0;
  const glm::dvec3 e = glm::dvec3(b.max) - glm::dvec3(b.min);
  return e.x * e.y + e.y * e.z + e.z * e.x;
}

/// A cost in surface area for the bottom-up and insertion builders: half the area of a box, in
/// double, with the half perimeter (sum of extents) as a tie-breaker compared only when areas
/// are equal (flat and collinear boxes all have area 0). Both grow with the box, so a cluster
/// never pairs better than its parts. Costs add and subtract componentwise and compare
/// lexicographically, so induced costs stay lower bounds (insertion's branch and bound).
struct Measure {
  double area = 0.0, perimeter = 0.0;
  auto operator<=>(const Measure&) const = default;
  Measure operator+(const Measure& o) const { return {area + o.area, perimeter + o.perimeter}; }
  Measure operator-(const Measure& o) const { return {area - o.area, perimeter - o.perimeter}; }
};
inline Measure measure(const Aabb& b) {
  const glm::dvec3 e = glm::dvec3(b.max) - glm::dvec3(b.min);
  return {e.x * e.y + e.y * e.z + e.z * e.x, e.x + e.y + e.z};
}

inline bool encloses(const Aabb& outer, const Aabb& inner) {
  return glm::all(glm::lessThanEqual(outer.min, inner.min)) && glm::all(glm::lessThanEqual(inner.max, outer.max));
}

}  // namespace cullpipe::bvh::detail
