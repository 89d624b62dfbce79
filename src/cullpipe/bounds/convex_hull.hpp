#pragma once
#include <array>
#include <cstdint>
#include <glm/vec3.hpp>
#include <span>
#include <vector>

namespace cullpipe::bounds {

/// A convex hull of a point set, with adjacency.
struct ConvexHull {
  /// What the points span. A degenerate set gives the lower-dimensional hull: one point
  /// (all points coincide within the tolerance), a segment (collinear), or a convex polygon
  /// (coplanar).
  enum class Dimension { Point = 0, Segment = 1, Polygon = 2, Polyhedron = 3 };
  Dimension dimension = Dimension::Point;

  /// Hull vertices (a subset of the input points). For a Polygon they are in counter-clockwise
  /// order about `normal`; for a Segment they are its two ends.
  std::vector<glm::vec3> vertices;
  /// For each hull vertex, its index in the input.
  std::vector<std::uint32_t> input_index;
  /// Polyhedron only: triangles as vertex indices, counter-clockwise seen from outside.
  std::vector<std::array<std::uint32_t, 3>> faces;
  /// Polyhedron only: face_neighbours[f][i] is the face across edge (faces[f][i], faces[f][(i+1)%3]),
  /// always an index into `faces`; f itself where the build lost that adjacency (then `valid`
  /// is false).
  std::vector<std::array<std::uint32_t, 3>> face_neighbours;
  /// For each vertex, the vertices joined to it by a hull edge (sorted).
  std::vector<std::vector<std::uint32_t>> vertex_neighbours;
  /// Polygon only: the unit normal of the plane of the points (plane_u x plane_v, to rounding).
  glm::vec3 normal{0.0f};
  /// Polygon only: the in-plane axes the ring was built on. Its vertices' coordinates along
  /// them, dot(dvec3(vertex), axis) in double, make a ring convex exactly (every turn larger
  /// than its rounding), which walks over the ring (hill climbing) can rely on.
  glm::dvec3 plane_u{0.0}, plane_v{0.0};
  /// How far an input point may lie outside the result: for a Point, Segment or Polygon, the
  /// measured distance (from vertices[0], from the line through vertices[0] and [1], or from
  /// the plane through vertices[0] with normal plane_u x plane_v, which `normal` rounds to
  /// float) plus a rounding margin of 16 x Lloyd's
  /// tolerance (for points the in-line or in-plane hull dropped by rounding); for a
  /// Polyhedron, that margin alone, a bound on Quickhull's rounding, which holds when `valid`
  /// and the coordinates' magnitudes are not too far apart (docs/numerics.md, World-space
  /// volumes).
  double tolerance = 0.0;
  /// Polyhedron only: false when the built surface failed validation (a lost or
  /// non-reciprocal adjacency, a zero-area face, or an edge not convex to within `tolerance`), which
  /// near-degenerate inputs can cause. Users that rely on convexity must not trust it then.
  bool valid = true;
};

/// Quickhull (Barber, Dobkin, Huhdanpaa 1996) in double precision. With M = max|x| + max|y| +
/// max|z| of the input: a set whose points all lie within 3 * FLT_EPSILON * M of one point, one
/// line or one plane (degenerate to float precision) gets the lower-dimensional hull; otherwise
/// Quickhull runs with Lloyd's visibility tolerance 3 * DBL_EPSILON * M. `tolerance` reports how
/// far an input point may lie outside the result; `valid` says whether a polyhedron passed
/// validation. Exact duplicates are dropped first. Faces are triangles (coplanar neighbours
/// are not merged). Throws BadPoints on an empty input or a non-finite coordinate.
ConvexHull convex_hull(std::span<const glm::vec3> points);

}  // namespace cullpipe::bounds
