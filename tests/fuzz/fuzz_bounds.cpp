// Fuzzes the bounding-volume builders (src/cullpipe/bounds) with arbitrary point sets: the bytes after
// the first are read as float triples (x, y, z), any values at all. Every builder must either
// reject the set as documented (BadPoints: empty, or a NaN or infinite coordinate) or return a
// volume that encloses every point; the convex hull's indices must stay inside its arrays, and
// the transform-box AABB update must enclose the exact recompute. The hull-based updates
// (hull, hill-climb) run too, but only for crashes and sanitizer reports: their bounds rest on
// Quickhull containing every point within its tolerance, which fails for sets whose
// coordinates span about ten orders of magnitude (points at 3*10^10 and at 1 missed by 0.05,
// a hill-climbing walk stopped 0.6 short among points at 7*10^9 and 1: docs/numerics.md,
// World-space volumes). The first byte's low bit also runs the exact OBB
// (slow on large hulls, so only for sets of at most 64 points).
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <glm/ext/matrix_transform.hpp>
#include <glm/geometric.hpp>
#include <vector>

#include "cullpipe/bounds/aabb_update.hpp"
#include "cullpipe/bounds/convex_hull.hpp"
#include "cullpipe/bounds/obb_fit.hpp"
#include "cullpipe/bounds/points.hpp"
#include "cullpipe/bounds/sphere_fit.hpp"
#include "fuzz_util.hpp"

namespace {

using namespace cullpipe;
using Points = std::vector<glm::vec3>;

[[noreturn]] void fail(const char* what, std::size_t i) {
  std::fprintf(stderr, "fuzz_bounds: %s (point %zu)\n", what, i);
  std::abort();
}

void check_hull(const bounds::ConvexHull& h, const Points& p) {
  for (std::uint32_t i : h.input_index)
    if (i >= p.size()) fail("hull input_index past the input", i);
  for (std::size_t f = 0; f < h.faces.size(); ++f)
    for (std::uint32_t v : h.faces[f])
      if (v >= h.vertices.size()) fail("hull face names a vertex past the hull", f);
  if (h.dimension == bounds::ConvexHull::Dimension::Polyhedron && h.face_neighbours.size() != h.faces.size())
    fail("hull face_neighbours and faces differ in size", h.faces.size());
  for (std::size_t f = 0; f < h.face_neighbours.size(); ++f)
    for (std::uint32_t g : h.face_neighbours[f])
      if (g >= h.faces.size()) fail("hull face neighbour past the faces", f);
  if (h.vertex_neighbours.size() != h.vertices.size()) fail("hull vertex_neighbours and vertices differ in size", 0);
  for (std::size_t v = 0; v < h.vertex_neighbours.size(); ++v)
    for (std::uint32_t w : h.vertex_neighbours[v])
      if (w >= h.vertices.size()) fail("hull vertex neighbour past the vertices", v);
}

void check_box(const Aabb& b, const Points& p, const char* what) {
  for (std::size_t i = 0; i < p.size(); ++i)
    for (int k = 0; k < 3; ++k)
      if (!(b.min[k] <= p[i][k] && p[i][k] <= b.max[k])) fail(what, i);
}

// Slack as the unit tests allow (tests/test_bounds.cpp): float axes are orthonormal to about
// 1e-7, and the points carry rounding of their magnitude.
void check_obb(const Obb& b, const Points& p, const char* what) {
  double scale = 0;
  for (const glm::vec3& q : p) scale = std::max(scale, double(glm::length(glm::dvec3(q))));
  for (std::size_t i = 0; i < p.size(); ++i) {
    const glm::dvec3 d = glm::dvec3(p[i]) - glm::dvec3(b.center);
    const double slack = 1e-6 * (glm::length(d) + glm::length(glm::dvec3(p[i])) + scale * 1e-3) + 1e-300;
    for (int k = 0; k < 3; ++k)
      if (!(std::abs(glm::dot(d, glm::dvec3(b.basis[k]))) <= double(b.half_extents[k]) + slack)) fail(what, i);
  }
}

// sphere_fit.hpp: the radius is the largest double distance, rounded up.
void check_sphere(const Sphere& s, const Points& p, const char* what) {
  for (std::size_t i = 0; i < p.size(); ++i)
    if (!(glm::length(glm::dvec3(p[i]) - glm::dvec3(s.center)) <= double(s.radius) * (1 + 1e-12) + 1e-300))
      fail(what, i);
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  if (size == 0) return 0;
  const bool exact_obb_too = (data[0] & 1) != 0;
  Points p((size - 1) / 12);
  if (!p.empty()) std::memcpy(p.data(), data + 1, p.size() * 12);
  fuzz::expect_clean([&] {
    try {
      check_hull(bounds::convex_hull(p), p);
      check_box(bounds::aabb_of_points(p), p, "aabb_of_points");
      check_obb(bounds::pca_obb(p), p, "pca_obb");
      check_obb(bounds::dito_obb(p), p, "dito_obb");
      check_obb(bounds::hull_face_obb(p), p, "hull_face_obb");
      if (exact_obb_too && p.size() <= 64) check_obb(bounds::exact_obb(p), p, "exact_obb");
      check_sphere(bounds::ritter_sphere(p), p, "ritter_sphere");
      check_sphere(bounds::refined_sphere(p), p, "refined_sphere");
      check_sphere(bounds::exact_sphere(p), p, "exact_sphere");
      bounds::AabbTracker tracker(p);
      check_hull(tracker.hull(), p);
      const glm::mat4 turn = glm::rotate(glm::mat4(1.0f), 0.7f, glm::normalize(glm::vec3(1, 2, 3)));
      for (const glm::mat4& m :
           {glm::mat4(1.0f), turn, glm::translate(glm::mat4(1.0f), glm::vec3(3.0f, -2.0f, 0.5f)) * turn}) {
        const Aabb full = tracker.update(m, bounds::AabbUpdate::Recompute);
        tracker.update(m, bounds::AabbUpdate::HillClimb);
        tracker.update(m, bounds::AabbUpdate::HullRecompute);
        const Aabb b = tracker.update(m, bounds::AabbUpdate::TransformBox);
        for (int k = 0; k < 3; ++k)
          if (!(b.min[k] <= full.min[k] && full.max[k] <= b.max[k]))
            fail("the transform-box update misses the recomputed box", std::size_t(k));
      }
    } catch (const bounds::BadPoints&) {
      // Documented: an empty set or a non-finite coordinate.
    }
  });
  return 0;
}
