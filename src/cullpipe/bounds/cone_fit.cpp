#include "cullpipe/bounds/cone_fit.hpp"

#include <algorithm>
#include <cmath>
#include <glm/ext/vector_double3.hpp>
#include <glm/geometric.hpp>
#include <vector>

#include "cullpipe/geom/rounding.hpp"

namespace cullpipe::bounds {

namespace {

struct Face {
  glm::dvec3 normal;  // unit
  glm::dvec3 corner;
  double altitude;  // the smallest: twice the area over the longest edge
};

// The smallest cosine between meshoptimizer's cone and its normals before it gives up on a
// cone (its meshopt_computeMeshletBounds takes 0.1): at 84 degrees the apex runs off far behind
// the cluster and the cone culls little.
constexpr double kMinCosine = 0.1;
constexpr double kThinTriangle = 0x1p-30;  // |n| against |e1| |e2|: the normal's direction is sure
constexpr double kAngleSlack = 0x1p-20;    // added to the sine of the widest angle
// The viewer's margin: the cone is narrowed by an angle whose sine is 2^-5, so a viewer it passes
// is behind every triangle's plane by 2^-5 of its distance to the apex, not merely behind it:
// the renderer decides facing on float positions snapped to its sub-pixel grid, and a triangle
// seen nearly edge-on could come out front-facing there (docs/numerics.md, Back-face cones).
const double kViewMargin = std::asin(0x1p-5);
// Triangles whose smallest altitude is below 2^-8 of the cluster's radius are slivers that even
// that margin does not keep facing away after rounding: a cluster with one has no cone.
constexpr double kSliver = 0x1p-8;
// How far behind every plane the apex is put, of the cluster's radius, and how far behind it must
// be found: a normal from double cross products of a triangle that is not thin points within
// 2^-22 radians of the exact one, which moves a plane by 2^-22 of the apex's distance to it.
constexpr double kApexSlack = 0x1p-12;
constexpr double kApexCheck = 0x1p-21;

}  // namespace

BackfaceCone backface_cone(std::span<const glm::vec3> positions, std::span<const std::uint32_t> indices,
                           const glm::vec3& axis_hint) {
  const BackfaceCone none;
  std::vector<Face> faces;
  faces.reserve(indices.size() / 3);
  glm::dvec3 lo(INFINITY), hi(-INFINITY), mean(0.0);
  for (std::size_t k = 0; k + 2 < indices.size(); k += 3) {
    const std::uint32_t i0 = indices[k], i1 = indices[k + 1], i2 = indices[k + 2];
    const glm::dvec3 a(positions[i0]), b(positions[i1]), c(positions[i2]);
    for (const glm::dvec3& p : {a, b, c}) {
      if (!std::isfinite(p.x) || !std::isfinite(p.y) || !std::isfinite(p.z)) return none;
      lo = glm::min(lo, p);
      hi = glm::max(hi, p);
    }
    if (i0 == i1 || i1 == i2 || i0 == i2 || a == b || b == c || a == c) continue;  // no area anywhere
    const glm::dvec3 e1 = b - a, e2 = c - a, n = glm::cross(e1, e2);
    const double length = glm::length(n);
    if (!(length > kThinTriangle * glm::length(e1) * glm::length(e2))) return none;
    const double longest = std::max({glm::length(e1), glm::length(e2), glm::length(c - b)});
    faces.push_back({n / length, a, length / longest});
    mean += n / length;
  }
  if (faces.empty()) return none;  // nothing that can face anywhere: leave it to the other tests

  glm::dvec3 hint(axis_hint);
  if (!(glm::length(hint) > 0.0) || !std::isfinite(glm::length(hint))) hint = mean;
  if (!(glm::length(hint) > 0.0)) return none;
  BackfaceCone cone;
  cone.axis = glm::vec3(hint / glm::length(hint));
  // The test uses the float axis: measure the angles from its own direction.
  const glm::dvec3 axis = glm::normalize(glm::dvec3(cone.axis));
  double min_cos = 1.0;
  for (const Face& f : faces) min_cos = std::min(min_cos, glm::dot(axis, f.normal));
  if (!(min_cos >= kMinCosine)) return none;
  const double beta = std::acos(std::min(1.0, min_cos)) + kViewMargin;
  if (!(beta < 1.5)) return none;
  const double sine = std::sin(beta) + kAngleSlack;
  if (!(sine < 1.0)) return none;
  cone.cutoff = round_up(sine);
  if (!(cone.cutoff < 1.0f)) return none;

  // The apex on the axis through the box's centre, just behind every triangle's plane: plane i
  // is behind p = centre - axis * t when dot(n_i, centre - corner_i) <= t * dot(n_i, axis)
  // (dot(n_i, axis) >= 0.1 > 0).
  const glm::dvec3 centre = (lo + hi) * 0.5;
  const double radius = glm::length(hi - lo) * 0.5;
  for (const Face& f : faces)
    if (!(f.altitude >= kSliver * radius)) return none;
  double t = -INFINITY;
  for (const Face& f : faces) t = std::max(t, glm::dot(f.normal, centre - f.corner) / glm::dot(f.normal, axis));
  double slack = kApexSlack * radius + 0x1p-100;
  for (int attempt = 0; attempt < 8; ++attempt, slack *= 16.0) {
    // (Each plane is then at least slack * 0.1 in front of the double apex; rounding the apex to
    // float moves it by 2^-24 of its coordinates, which the check catches where it matters.)
    cone.apex = glm::vec3(centre - axis * (t + slack));
    const glm::dvec3 apex(cone.apex);
    bool behind = std::isfinite(apex.x) && std::isfinite(apex.y) && std::isfinite(apex.z);
    for (std::size_t i = 0; behind && i < faces.size(); ++i) {
      const glm::dvec3 to_apex = apex - faces[i].corner;
      behind = glm::dot(faces[i].normal, to_apex) < -kApexCheck * glm::length(to_apex);
    }
    if (behind) return cone;
  }
  return none;
}

}  // namespace cullpipe::bounds
