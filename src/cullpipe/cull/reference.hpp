#pragma once
#include <cstddef>
#include <span>

#include "cullpipe/geom/aabb.hpp"
#include "cullpipe/geom/classification.hpp"
#include "cullpipe/geom/frustum.hpp"
#include "cullpipe/geom/obb.hpp"
#include "cullpipe/geom/sphere.hpp"

/// The scalar CPU reference: the oracle every other culling path must match bit for bit.
/// Written for clarity, one object at a time. Compiled with -ffp-contract=off; every sum is
/// evaluated left to right exactly as in shaders/cull_flat.comp.
namespace cullpipe::reference {

/// AABB p-vertex / n-vertex test. Per plane, the p-vertex is the corner farthest along the
/// normal (max.x if n.x >= 0 else min.x, per axis) and the n-vertex the opposite corner.
/// OUTSIDE if the p-vertex is behind any plane (distance < 0); INSIDE if every n-vertex is in
/// front (distance >= 0); otherwise INTERSECTING.
Classification classify_pn(const Aabb& box, const Frustum& frustum);

/// AABB 8-corner test, a second oracle: OUTSIDE if all 8 corners are behind one plane,
/// INSIDE if all corners are in front of all planes, otherwise INTERSECTING. Agrees exactly
/// with classify_pn: rounding is monotone, so the p-vertex is the corner of largest computed
/// distance and the n-vertex the smallest.
Classification classify_corners(const Aabb& box, const Frustum& frustum);

/// OBB test by projected radius: per plane s = n.c + d and
/// r = |n.u0|*h0 + |n.u1|*h1 + |n.u2|*h2 (u = unit axes, h = half extents), which is the
/// p/n-vertex test carried out in the box's own frame. OUTSIDE if s < -r for any plane,
/// INSIDE if s >= r for all planes, otherwise INTERSECTING.
Classification classify(const Obb& box, const Frustum& frustum);

/// Sphere test: per plane s = n.c + d; OUTSIDE if s < -radius for any plane, INSIDE if
/// s >= radius for all, otherwise INTERSECTING.
Classification classify(const Sphere& sphere, const Frustum& frustum);

inline Classification classify(const Aabb& box, const Frustum& frustum) { return classify_pn(box, frustum); }

/// Counts of one culling pass.
struct CullCounts {
  std::size_t visible = 0;  ///< INSIDE + INTERSECTING
  std::size_t inside = 0;
  std::size_t intersecting = 0;
  std::size_t occluded = 0;  ///< kept by the frustum, hidden by a depth pyramid (occlusion culling)
  bool operator==(const CullCounts&) const = default;
};
/// The counts of a list of classes.
CullCounts count_classes(std::span<const Classification> classes);

/// Classifies every volume; `out` must have the same size as `volumes`.
CullCounts classify_all(std::span<const Aabb> volumes, const Frustum& frustum, std::span<Classification> out);
CullCounts classify_all(std::span<const Obb> volumes, const Frustum& frustum, std::span<Classification> out);
CullCounts classify_all(std::span<const Sphere> volumes, const Frustum& frustum, std::span<Classification> out);

}  // namespace cullpipe::reference
