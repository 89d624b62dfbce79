#include <algorithm>
#include <cmath>
#include <glm/geometric.hpp>
#include <string>

#include "cullpipe/geom/aabb.hpp"
#include "cullpipe/geom/obb.hpp"
#include "cullpipe/geom/rounding.hpp"
#include "cullpipe/geom/validate.hpp"

namespace cullpipe {

Aabb Aabb::transformed(const glm::mat4& m) const {
  // Arvo in its direct form, per world axis t_i + sum_j min (max) of M_ij * min_j and M_ij * max_j,
  // added in double as glm adds M * (p, 1) and rounded outward: it encloses every point of the box
  // transformed in double. Proof, and why not c' +- |M| h: docs/numerics.md, World-space volumes.
  const glm::dmat4 dm(m);
  glm::dvec3 lo, hi;
  for (int i = 0; i < 3; ++i) {
    double a[3], b[3];
    for (int j = 0; j < 3; ++j) {
      const double p = dm[j][i] * double(min[j]), q = dm[j][i] * double(max[j]);
      a[j] = std::min(p, q);
      b[j] = std::max(p, q);
    }
    lo[i] = (a[0] + a[1]) + (a[2] + dm[3][i]);
    hi[i] = (b[0] + b[1]) + (b[2] + dm[3][i]);
  }
  return {{round_down(lo.x), round_down(lo.y), round_down(lo.z)}, {round_up(hi.x), round_up(hi.y), round_up(hi.z)}};
}

namespace {

// A unit vector orthogonal to unit a.
glm::dvec3 any_orthogonal(const glm::dvec3& a) {
  const glm::dvec3 helper = std::abs(a.x) < 0.9 ? glm::dvec3(1, 0, 0) : glm::dvec3(0, 1, 0);
  return glm::normalize(glm::cross(a, helper));
}

// Gram-Schmidt in double on three vectors; zero or dependent vectors are replaced, so the
// result is always an orthonormal basis. The third axis points to the side of w, so a
// mirrored transform gives a left-handed basis (its axes still span the same box).
glm::dmat3 orthonormalise(glm::dvec3 u, glm::dvec3 v, const glm::dvec3& w) {
  u = glm::dot(u, u) > 0.0 ? glm::normalize(u) : glm::dvec3(1, 0, 0);
  v = v - glm::dot(v, u) * u;
  v = glm::dot(v, v) > 1e-24 * glm::dot(u, u) ? glm::normalize(v) : any_orthogonal(u);
  glm::dvec3 n = glm::cross(u, v);
  if (glm::dot(w, n) < 0.0) n = -n;
  return glm::dmat3(u, v, n);
}

}  // namespace

Obb Obb::from_transformed_aabb(const Aabb& local, const glm::mat4& m) {
  return from_transformed_aabb(local, glm::dmat4(m));
}

Obb Obb::from_transformed_aabb(const Aabb& local, const glm::dmat4& m) {
  Obb b;
  b.center = glm::vec3(m * glm::dvec4((glm::dvec3(local.min) + glm::dvec3(local.max)) * 0.5, 1.0));
  const glm::dmat3 axes = orthonormalise(glm::dvec3(m[0]), glm::dvec3(m[1]), glm::dvec3(m[2]));
  b.basis = glm::mat3(axes);
  // Extents about the stored float centre along the stored float axes, from the corners
  // transformed in double, rounded up: the box encloses the transformed box.
  const glm::dvec3 c(b.center);
  glm::dvec3 ext(0.0);
  for (const glm::vec3& corner : local.corners()) {
    const glm::dvec3 p = glm::dvec3(m * glm::dvec4(glm::dvec3(corner), 1.0)) - c;
    for (int k = 0; k < 3; ++k) ext[k] = std::max(ext[k], std::abs(glm::dot(p, glm::dvec3(b.basis[k]))));
  }
  for (int k = 0; k < 3; ++k) b.half_extents[k] = round_up(ext[k]);
  return b;
}

ObbBaseAxes to_base_axes(const Obb& b) {
  ObbBaseAxes out;
  glm::vec3 base = b.center;
  for (int k = 0; k < 3; ++k) {
    base -= b.basis[k] * b.half_extents[k];
    out.edges[static_cast<std::size_t>(k)] = b.basis[k] * (2.0f * b.half_extents[k]);
  }
  out.base = base;
  return out;
}

Obb to_basis_radius(const ObbBaseAxes& b) {
  Obb out;
  glm::vec3 len;
  for (int k = 0; k < 3; ++k) len[k] = glm::length(b.edges[static_cast<std::size_t>(k)]);
  out.basis = glm::mat3(orthonormalise(glm::dvec3(b.edges[0]), glm::dvec3(b.edges[1]), glm::dvec3(b.edges[2])));
  out.half_extents = len * 0.5f;
  out.center = b.base + (b.edges[0] + b.edges[1] + b.edges[2]) * 0.5f;
  return out;
}

namespace {

const char* axis_name(int i) { return i == 0 ? "x" : i == 1 ? "y" : "z"; }

// The checks of is_valid and invalid_reason, written once. At the first that fails, `fail` is
// called with a callable that formats what is wrong (only invalid_reason calls it: a valid
// volume, or one merely tested by is_valid, builds no string); the check returns false.
template <class Fail>
bool check_finite(const char* what, const glm::vec3& v, Fail& fail) {
  for (int i = 0; i < 3; ++i)
    if (!std::isfinite(v[i]))
      return fail(
          [&] { return std::string(what) + "." + axis_name(i) + (std::isnan(v[i]) ? " is NaN" : " is infinite"); });
  return true;
}

template <class Fail>
bool check(const Aabb& b, Fail& fail) {
  if (!check_finite("min", b.min, fail) || !check_finite("max", b.max, fail)) return false;
  for (int i = 0; i < 3; ++i)
    if (b.min[i] > b.max[i]) return fail([&] { return std::string("min.") + axis_name(i) + " > max." + axis_name(i); });
  return true;
}

template <class Fail>
bool check(const Obb& b, Fail& fail) {
  if (!check_finite("center", b.center, fail) || !check_finite("half_extents", b.half_extents, fail)) return false;
  const char* const names[3] = {"axes[0]", "axes[1]", "axes[2]"};
  for (int k = 0; k < 3; ++k) {
    if (!check_finite(names[k], b.basis[k], fail)) return false;
    if (b.half_extents[k] < 0.0f)
      return fail([&] { return std::string("half_extents.") + axis_name(k) + " is negative"; });
    if (std::abs(glm::length(b.basis[k]) - 1.0f) > 1e-3f)
      return fail([&] { return std::string(names[k]) + " is not unit length"; });
    for (int j = 0; j < k; ++j)
      if (std::abs(glm::dot(b.basis[k], b.basis[j])) > 1e-3f)
        return fail([&] { return std::string(names[j]) + " and " + names[k] + " are not orthogonal"; });
  }
  return true;
}

template <class Fail>
bool check(const Sphere& s, Fail& fail) {
  if (!check_finite("center", s.center, fail)) return false;
  if (std::isnan(s.radius)) return fail([] { return std::string("radius is NaN"); });
  if (!std::isfinite(s.radius)) return fail([] { return std::string("radius is infinite"); });
  if (s.radius < 0.0f) return fail([] { return std::string("radius is negative"); });
  return true;
}

template <class Volume>
bool valid(const Volume& v) {
  auto fail = [](auto&&) { return false; };
  return check(v, fail);
}

template <class Volume>
std::string reason(const Volume& v) {
  std::string why;
  auto fail = [&](auto&& message) {
    why = message();
    return false;
  };
  check(v, fail);
  return why;
}

}  // namespace

bool is_valid(const Aabb& b) { return valid(b); }
bool is_valid(const Obb& b) { return valid(b); }
bool is_valid(const Sphere& s) { return valid(s); }

std::string invalid_reason(const Aabb& b) { return reason(b); }
std::string invalid_reason(const Obb& b) { return reason(b); }
std::string invalid_reason(const Sphere& s) { return reason(s); }

}  // namespace cullpipe
