#include <algorithm>
#include <cmath>
#include <string>
#include <glm/geometric.hpp>

#include "geom/aabb.hpp"
#include "geom/obb.hpp"
#include "geom/validate.hpp"

namespace cullpipe {

Aabb Aabb::transformed(const glm::mat4& m) const {
  const glm::vec3 c = center();
  const glm::vec3 h = half_extent();
  const glm::vec3 new_c = glm::vec3(m * glm::vec4(c, 1.0f));
  glm::vec3 new_h(0.0f);
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) new_h[i] += std::abs(m[j][i]) * h[j];
  return {new_c - new_h, new_c + new_h};
}

namespace {

// A unit vector orthogonal to both a and b (assumed unit or zero), completing a basis.
glm::vec3 any_orthogonal(const glm::vec3& a) {
  const glm::vec3 helper = std::abs(a.x) < 0.9f ? glm::vec3(1, 0, 0) : glm::vec3(0, 1, 0);
  return glm::normalize(glm::cross(a, helper));
}

// Gram-Schmidt on three vectors; zero or dependent vectors are replaced so the result is
// always a right-handed orthonormal basis.
glm::mat3 orthonormalise(glm::vec3 u, glm::vec3 v, glm::vec3 w) {
  const float eps = 1e-20f;
  u = glm::dot(u, u) > eps ? glm::normalize(u) : glm::vec3(1, 0, 0);
  v = v - glm::dot(v, u) * u;
  v = glm::dot(v, v) > eps ? glm::normalize(v) : any_orthogonal(u);
  glm::vec3 n = glm::cross(u, v);
  // Keep w's orientation when it is usable, so mirrored transforms keep their axis order.
  if (glm::dot(w, n) < 0.0f) n = -n;
  return glm::mat3(u, v, n);
}

}  // namespace

Obb Obb::from_transformed_aabb(const Aabb& local, const glm::mat4& m) {
  Obb b;
  b.center = glm::vec3(m * glm::vec4(local.center(), 1.0f));
  b.basis = orthonormalise(glm::vec3(m[0]), glm::vec3(m[1]), glm::vec3(m[2]));
  for (const glm::vec3& corner : local.corners()) {
    const glm::vec3 p = glm::vec3(m * glm::vec4(corner, 1.0f)) - b.center;
    for (int k = 0; k < 3; ++k) b.half_extents[k] = std::max(b.half_extents[k], std::abs(glm::dot(p, b.basis[k])));
  }
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
  out.basis = orthonormalise(b.edges[0], b.edges[1], b.edges[2]);
  out.half_extents = len * 0.5f;
  out.center = b.base + (b.edges[0] + b.edges[1] + b.edges[2]) * 0.5f;
  return out;
}

namespace {

const char* axis_name(int i) { return i == 0 ? "x" : i == 1 ? "y" : "z"; }

std::string non_finite(const char* what, const glm::vec3& v) {
  for (int i = 0; i < 3; ++i)
    if (!std::isfinite(v[i]))
      return std::string(what) + "." + axis_name(i) + (std::isnan(v[i]) ? " is NaN" : " is infinite");
  return {};
}

}  // namespace

std::string invalid_reason(const Aabb& b) {
  if (auto e = non_finite("min", b.min); !e.empty()) return e;
  if (auto e = non_finite("max", b.max); !e.empty()) return e;
  for (int i = 0; i < 3; ++i)
    if (b.min[i] > b.max[i]) return std::string("min.") + axis_name(i) + " > max." + axis_name(i);
  return {};
}

std::string invalid_reason(const Obb& b) {
  if (auto e = non_finite("center", b.center); !e.empty()) return e;
  if (auto e = non_finite("half_extents", b.half_extents); !e.empty()) return e;
  for (int k = 0; k < 3; ++k) {
    const std::string name = std::string("axes[") + std::to_string(k) + "]";
    if (auto e = non_finite(name.c_str(), b.basis[k]); !e.empty()) return e;
    if (b.half_extents[k] < 0.0f) return std::string("half_extents.") + axis_name(k) + " is negative";
    if (std::abs(glm::length(b.basis[k]) - 1.0f) > 1e-3f) return name + " is not unit length";
    for (int j = 0; j < k; ++j)
      if (std::abs(glm::dot(b.basis[k], b.basis[j])) > 1e-3f)
        return "axes[" + std::to_string(j) + "] and " + name + " are not orthogonal";
  }
  return {};
}

std::string invalid_reason(const Sphere& s) {
  if (auto e = non_finite("center", s.center); !e.empty()) return e;
  if (std::isnan(s.radius)) return "radius is NaN";
  if (!std::isfinite(s.radius)) return "radius is infinite";
  if (s.radius < 0.0f) return "radius is negative";
  return {};
}

}  // namespace cullpipe
