#include "cullpipe/bounds/mesh_bounds.hpp"

#include <algorithm>
#include <cmath>
#include <glm/geometric.hpp>
#include <glm/mat3x3.hpp>

#include "cullpipe/bounds/obb_fit.hpp"
#include "cullpipe/bounds/sphere_fit.hpp"
#include "cullpipe/geom/rounding.hpp"

namespace cullpipe::bounds {
namespace {

// The largest eigenvalue of a symmetric positive semidefinite 3x3 matrix (Smith 1961, the
// trigonometric closed form), in double. Where the two largest eigenvalues nearly coincide
// the acos is ill-conditioned: a rounding error e in det(b) moves the result by about
// sqrt(e), i.e. up to about 1e-8 relative. Callers add a margin well above that
// (docs/numerics.md, World-space volumes).
double largest_eigenvalue(const glm::dmat3& a) {
  const double p1 = a[0][1] * a[0][1] + a[0][2] * a[0][2] + a[1][2] * a[1][2];
  const double q = (a[0][0] + a[1][1] + a[2][2]) / 3.0;
  if (p1 == 0.0) return std::max({a[0][0], a[1][1], a[2][2]});
  const double p2 =
      (a[0][0] - q) * (a[0][0] - q) + (a[1][1] - q) * (a[1][1] - q) + (a[2][2] - q) * (a[2][2] - q) + 2.0 * p1;
  const double p = std::sqrt(p2 / 6.0);
  if (p == 0.0) return q;
  const glm::dmat3 b = (a - q * glm::dmat3(1.0)) * (1.0 / p);
  const double r = std::clamp(glm::determinant(b) / 2.0, -1.0, 1.0);
  const double phi = std::acos(r) / 3.0;
  return q + 2.0 * p * std::cos(phi);
}

}  // namespace

std::string_view to_string(ObbMethod method) {
  switch (method) {
    case ObbMethod::Pca:
      return "pca";
    case ObbMethod::Dito:
      return "dito";
    case ObbMethod::HullFace:
      return "hull-face";
    case ObbMethod::Exact:
      return "exact";
  }
  return "?";
}

std::optional<ObbMethod> parse_obb_method(std::string_view name) {
  for (ObbMethod m : {ObbMethod::Pca, ObbMethod::Dito, ObbMethod::HullFace, ObbMethod::Exact})
    if (to_string(m) == name) return m;
  return std::nullopt;
}

std::string_view to_string(SphereMethod method) {
  switch (method) {
    case SphereMethod::Ritter:
      return "ritter";
    case SphereMethod::Refined:
      return "refined";
    case SphereMethod::Exact:
      return "exact";
  }
  return "?";
}

std::optional<SphereMethod> parse_sphere_method(std::string_view name) {
  for (SphereMethod m : {SphereMethod::Ritter, SphereMethod::Refined, SphereMethod::Exact})
    if (to_string(m) == name) return m;
  return std::nullopt;
}

Sphere transform_sphere(const Sphere& s, const glm::mat4& m) {
  const glm::dmat4 dm(m);
  const glm::dvec3 center = glm::dvec3(dm * glm::dvec4(glm::dvec3(s.center), 1.0));
  const glm::dmat3 linear(dm);
  // Largest singular value of the linear part, with a margin of 1e-6 relative: 100x above the
  // eigenvalue formula's worst error near repeated eigenvalues (see largest_eigenvalue).
  const double sigma = std::sqrt(std::max(largest_eigenvalue(glm::transpose(linear) * linear), 0.0)) * (1.0 + 1e-6);
  // Rounding of the centre's double evaluation: a few ulps of the terms' magnitudes.
  double magnitude = 0.0;
  for (int r = 0; r < 3; ++r) {
    double row = std::abs(dm[3][r]);
    for (int c = 0; c < 3; ++c) row += std::abs(dm[c][r]) * std::abs(double(s.center[c]));
    magnitude = std::max(magnitude, row);
  }
  Sphere out;
  out.center = glm::vec3(center);
  // The float centre moved by rounding: widen by that distance so nothing is lost.
  out.radius =
      round_up(double(s.radius) * sigma + glm::length(glm::dvec3(out.center) - center) + 8.0 * 2.2e-16 * magnitude);
  return out;
}

MeshBounds::MeshBounds(std::span<const glm::vec3> local_points, const MeshBoundsOptions& options)
    : tracker_(local_points) {
  switch (options.obb) {
    case ObbMethod::Pca:
      obb_ = pca_obb(local_points);
      break;
    case ObbMethod::Dito:
      obb_ = dito_obb(local_points);
      break;
    case ObbMethod::HullFace:
      obb_ = hull_face_obb(local_points, tracker_.hull());
      break;
    case ObbMethod::Exact:
      obb_ = exact_obb(local_points);
      break;
  }
  switch (options.sphere) {
    case SphereMethod::Ritter:
      sphere_ = ritter_sphere(local_points);
      break;
    case SphereMethod::Refined:
      sphere_ = refined_sphere(local_points);
      break;
    case SphereMethod::Exact:
      sphere_ = exact_sphere(local_points);
      break;
  }
}

Obb MeshBounds::world_obb(const glm::mat4& world) const { return transform_obb(obb_, world); }

}  // namespace cullpipe::bounds
