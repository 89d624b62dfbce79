#pragma once
// Settling bounds: per-object bounds that decide most plane tests from one centre distance,
// with the same answer as the reference's full test. The fast CPU kernels and the GPU flat
// pass both store them. Proofs: docs/numerics.md, Settling bounds and Packed lower bounds. Internal.
#include <glm/vec3.hpp>
#include <glm/vec4.hpp>
#include <span>
#if defined(__SSE__)
#include <xmmintrin.h>
#endif

#include "cullpipe/geom/aabb.hpp"
#include "cullpipe/geom/frustum.hpp"
#include "cullpipe/geom/obb.hpp"
#include "cullpipe/geom/sphere.hpp"

namespace cullpipe::plane_bounds {

/// The bounds hold for plane normals up to this length (Frustum's normalised planes are).
inline constexpr double kUnitNormalLimit = 1.0 + 0x1p-20;

/// Round to nearest without flushing subnormals, for the scope: the bounds are computed in that
/// mode whatever the caller's, as the proofs assume it (docs/numerics.md, Rounding model). Thread
/// pools run tasks in the caller's mode, so each upload task sets its own.
struct NearestNoFlush {
#if defined(__SSE__)
  unsigned saved = _mm_getcsr();
  NearestNoFlush() { _mm_setcsr(0x1F80); }  // all exceptions masked, nearest, no FTZ / DAZ
  ~NearestNoFlush() { _mm_setcsr(saved); }
#else
  NearestNoFlush() = default;
#endif
  NearestNoFlush(const NearestNoFlush&) = delete;
  NearestNoFlush& operator=(const NearestNoFlush&) = delete;
};

/// A box's bound and its centre (min + max) / 2 rounded to a float: with a view's margin
/// (settle_margin), a centre distance s < -(bound + m) means OUTSIDE and s >= bound + m on
/// every plane INSIDE, as the reference's p/n-vertex test says. NaN where no bound is safe.
float aabb_plane_bound(const Aabb& b, glm::vec3& centre);
/// An OBB's bound on the reference's projected radius, settling like aabb_plane_bound.
float obb_plane_bound(const Obb& b);
/// A sphere's bound on its radius, settling like aabb_plane_bound.
float sphere_plane_bound(const Sphere& s);

/// Per box: xyz = its centre, w = aabb_plane_bound, computed under NearestNoFlush.
/// out.size() == boxes.size().
void aabb_centre_bounds(std::span<const Aabb> boxes, std::span<glm::vec4> out);
/// Per OBB: obb_plane_bound, computed under NearestNoFlush. out.size() == boxes.size().
void obb_plane_bounds(std::span<const Obb> boxes, std::span<float> out);

/// Lower bounds on the straddling threshold less every rounding, per object: X such that a
/// smallest centre distance |s| < c X - m means the reference's INTERSECTING (c: |n|_1 for
/// boxes, |n|_2 for OBBs, 1 for spheres). 0 or negative where none is known.
double aabb_lower(const Aabb& b);
double obb_lower(const Obb& b);
double sphere_lower(const Sphere& s);
/// `bound` rounded up to a multiple of 2^8 float steps, its lowest 8 bits q = floor(256 lower /
/// bound), 0 to 255 (0 for lower <= 0 and bounds past 2^119); NaN, infinite and zero bounds
/// unchanged, one that rounds up past the float range infinite. The fast CPU path stores
/// pack_lower(bound, aabb_lower(box)) and so on.
float pack_lower(float bound, double lower);

/// A plane's share of the settling margin: 2^-18 |d| + 2^-100 rounded up; NaN past |d| = 2^120.
float plane_margin(float d);
/// Whether the bounds hold for normal n: |n| <= kUnitNormalLimit (false for NaN).
bool unit_normal(const glm::vec3& n);
/// The margin m a view adds to every bound: the largest plane_margin over its planes, or NaN
/// (settles nothing) unless every normal passes unit_normal and every |d| <= 2^120.
float settle_margin(const Frustum& frustum);

}  // namespace cullpipe::plane_bounds
