#pragma once
#include <glm/mat3x3.hpp>
#include <glm/mat4x4.hpp>
#include <glm/vec3.hpp>
#include <span>

#include "cullpipe/bounds/convex_hull.hpp"
#include "cullpipe/geom/obb.hpp"

/// Oriented bounding boxes from point sets. Every builder throws BadPoints on an empty set or
/// a non-finite coordinate, and returns a box that encloses every input point: after choosing
/// the axes, the box is fitted by projecting every point in double and rounding the extents
/// outward to float (enclosure holds to ~1e-7 relative, the orthogonality of float axes).
/// Degenerate sets give flat boxes (zero extent along an axis), never NaN.
namespace cullpipe::bounds {

/// The enclosing box of the points with the given axes (columns of `basis`, orthonormal).
Obb fit_box(std::span<const glm::vec3> points, const glm::mat3& basis);

/// Principal component analysis: axes are the eigenvectors of the covariance of the convex
/// hull's surface (area-weighted triangles, Gottschalk 1996), which does not depend on how
/// densely the surface is sampled; point covariance for flat or degenerate sets. O(n log n)
/// for the hull, then O(h).
Obb pca_obb(std::span<const glm::vec3> points);

/// DiTO-14 (Larsson & Kallberg 2011): extremal points along 7 fixed directions, a base
/// triangle and two apex points from them, then the best of the candidate frames the
/// resulting ditetrahedron's edges and normals give; compared against the AABB. O(n).
Obb dito_obb(std::span<const glm::vec3> points);

/// Hull-face method: for each face of the convex hull, the smallest rectangle around the
/// hull's projection onto the face plane (rotating calipers over the 2D hull, Toussaint
/// 1983), extended by the hull's depth below the face; the box of least volume. O(F h log h).
Obb hull_face_obb(std::span<const glm::vec3> points);
/// The same, with the convex hull of `points` already computed.
Obb hull_face_obb(std::span<const glm::vec3> points, const ConvexHull& hull);

/// The minimum-volume box: the hull-face candidates plus a sweep over every one-parameter
/// family of boxes with two adjacent faces flush with hull edges (O'Rourke 1985), with the
/// support vertices tracked through exact event times and the volume minimised between
/// events (see obb_exact.cpp). Beats the hull-face method where the best box has no face flush
/// with a hull face (e.g. a long thin tetrahedron whose best box is rotated 45 degrees).
/// Cost grows with the square of the hull's edge count; on hulls of more than 24 vertices,
/// proved lower bounds skip edge arcs, pair families and pieces that cannot beat the best
/// box found (2.6x faster over the shared meshes; bench/NOTES.md, "Bounding volumes").
Obb exact_obb(std::span<const glm::vec3> points);

/// The box `b` carried by an affine transform (`update` for a moving object): exact for
/// rotations, translations and uniform scale; with non-uniform scale or shear the transformed
/// box is re-fitted as an OBB that still encloses it.
Obb transform_obb(const Obb& b, const glm::mat4& m);

/// Volume of a box (8 h.x h.y h.z) in double.
double volume(const Obb& b);

}  // namespace cullpipe::bounds
