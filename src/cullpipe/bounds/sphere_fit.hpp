#pragma once
#include <cstdint>
#include <glm/ext/vector_double3.hpp>
#include <glm/vec3.hpp>
#include <span>

#include "cullpipe/geom/aabb.hpp"
#include "cullpipe/geom/sphere.hpp"

/// Bounding spheres and boxes from point sets. Every builder throws BadPoints on an empty set
/// or a non-finite coordinate, and returns a volume that encloses every input point: the
/// final radius (or box) is widened to the largest distance evaluated in double, rounded up
/// to the next float, so `glm::length(p - center) <= radius` holds for every point p when
/// evaluated in double (and in float up to float rounding of that expression, ~1e-7 relative).
namespace cullpipe::bounds {

/// The AABB of the points, in one pass.
Aabb aabb_of_points(std::span<const glm::vec3> points);

/// The sphere about `center` (rounded to float) that encloses every point: the radius is the
/// largest distance from the float centre, evaluated in double and rounded up to a float. What
/// every builder here ends with; for a centre found elsewhere.
Sphere enclosing_sphere(const glm::dvec3& center, std::span<const glm::vec3> points);

/// Ritter (1990) as usually given (Ericson, Real-Time Collision Detection 4.3.2): seed with the
/// most separated pair among the six axis-extreme points, then one pass growing the sphere
/// just enough to take in each point outside it. Fast and loose (typically 5-20% larger).
Sphere ritter_sphere(std::span<const glm::vec3> points);

/// Iterative refinement (Ericson 4.3.4): start from the sphere about the AABB centre, then
/// `iterations` times shrink the best sphere by 5% and regrow it with a Ritter pass over the
/// points in a random order, keeping the smallest valid sphere. Deterministic per `seed`.
Sphere refined_sphere(std::span<const glm::vec3> points, int iterations = 16, std::uint64_t seed = 1);

/// The exact minimum enclosing sphere, in double. Welzl's algorithm (1991) runs on a small core
/// set of the points; linear scans add the points farthest outside its ball to the core until
/// none is outside (the core-set scheme of Gärtner's pivoting Miniball). On 10^6 points that is
/// about three scans, 1.1-1.3x Ritter's time. Degenerate support sets (collinear or coplanar
/// boundary points, duplicates) fall back to the smallest ball of their subsets, so cospherical
/// and duplicate points are handled.
Sphere exact_sphere(std::span<const glm::vec3> points);

/// Welzl's algorithm over every point at once: the same sphere as exact_sphere by the direct
/// route, several times slower on large sets. Kept as a test oracle.
Sphere welzl_sphere(std::span<const glm::vec3> points);

/// Brute force over every 1- to 4-point support set: O(n^5), for small n only (test oracle).
/// Throws std::invalid_argument for more than 64 points.
Sphere brute_force_sphere(std::span<const glm::vec3> points);

}  // namespace cullpipe::bounds
