#pragma once
#include <cmath>
#include <cstdint>

#include "cullpipe/geom/classification.hpp"
#include "cullpipe/geom/exact_fp.hpp"
#include "cullpipe/geom/frustum.hpp"
#include "cullpipe/geom/obb.hpp"
#include "cullpipe/geom/sphere.hpp"

CULLPIPE_EXACT_FP_BEGIN
namespace cullpipe {

/// Every plane of a frustum, as a plane mask (bit k = plane k).
inline constexpr std::uint32_t kAllPlanes = ~0u;

/// The OBB and sphere tests on the planes of `frustum` in `mask`: the one definition behind
/// the scalar reference (every plane, cull/reference.hpp) and hierarchical culling's object
/// tests (the planes a leaf straddles, bvh::classify_object). The shaders' copy is
/// shaders/shared/classify.glsl. Written for clarity, one object at a time; every sum is
/// evaluated left to right as the shaders do (built with -ffp-contract=off).
///
/// OBB, by projected radius: per plane s = n.c + d and r = |n.u0|*h0 + |n.u1|*h1 + |n.u2|*h2
/// (the p/n-vertex test carried out in the box's own frame). OUTSIDE if s < -r for any plane,
/// INSIDE if s >= r for all, otherwise INTERSECTING.
inline Classification classify_planes(const Obb& box, const Frustum& frustum, std::uint32_t mask) {
  bool intersecting = false;
  const auto planes = frustum.active();
  for (std::uint32_t k = 0; k < planes.size(); ++k) {
    if (!(mask & (1u << k))) continue;
    const Plane& plane = planes[k];
    const glm::vec3& n = plane.normal;
    const float s = plane.distance(box.center);
    const glm::vec3 &u0 = box.basis[0], &u1 = box.basis[1], &u2 = box.basis[2];
    const float n_dot_u0 = n.x * u0.x + n.y * u0.y + n.z * u0.z;
    const float n_dot_u1 = n.x * u1.x + n.y * u1.y + n.z * u1.z;
    const float n_dot_u2 = n.x * u2.x + n.y * u2.y + n.z * u2.z;
    const float r = std::abs(n_dot_u0) * box.half_extents.x + std::abs(n_dot_u1) * box.half_extents.y +
                    std::abs(n_dot_u2) * box.half_extents.z;
    if (s < -r) return Classification::Outside;
    if (s < r) intersecting = true;
  }
  return intersecting ? Classification::Intersecting : Classification::Inside;
}

/// Sphere, by signed distance: per plane s = n.c + d; OUTSIDE if s < -radius for any plane,
/// INSIDE if s >= radius for all, otherwise INTERSECTING.
inline Classification classify_planes(const Sphere& sphere, const Frustum& frustum, std::uint32_t mask) {
  bool intersecting = false;
  const auto planes = frustum.active();
  for (std::uint32_t k = 0; k < planes.size(); ++k) {
    if (!(mask & (1u << k))) continue;
    const float s = planes[k].distance(sphere.center);
    if (s < -sphere.radius) return Classification::Outside;
    if (s < sphere.radius) intersecting = true;
  }
  return intersecting ? Classification::Intersecting : Classification::Inside;
}

}  // namespace cullpipe
CULLPIPE_EXACT_FP_END
