#pragma once
// Shared helpers for the tests: a deterministic RNG, random volumes near a frustum, and an
// exact (double precision, separating-axis) intersection test used to check conservativeness.
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <glm/ext/matrix_clip_space.hpp>
#include <glm/ext/matrix_transform.hpp>
#include <glm/geometric.hpp>
#include <glm/mat3x3.hpp>
#include <vector>

#include "cullpipe/core/splitmix.hpp"
#include "cullpipe/geom/aabb.hpp"
#include "cullpipe/geom/frustum.hpp"
#include "cullpipe/geom/obb.hpp"
#include "cullpipe/geom/sphere.hpp"

namespace cullpipe::test {

struct Rng : SplitMix64 {
  explicit Rng(std::uint64_t seed) : SplitMix64{seed} {}
  using SplitMix64::uniform;
  glm::vec3 vec3(float lo, float hi) { return {uniform(lo, hi), uniform(lo, hi), uniform(lo, hi)}; }
  glm::mat3 rotation() {
    glm::mat4 m(1.0f);
    m = glm::rotate(m, uniform(0.0f, 6.2831853f), glm::vec3(0, 1, 0));
    m = glm::rotate(m, uniform(0.0f, 6.2831853f), glm::vec3(1, 0, 0));
    m = glm::rotate(m, uniform(0.0f, 6.2831853f), glm::vec3(0, 0, 1));
    return glm::mat3(m);
  }
};

/// A typical camera frustum: looking from (0,0,10) at the origin, 60 degrees, near 0.5, far 50.
inline glm::mat4 test_view_proj(float fov_degrees = 60.0f, float aspect = 1.5f) {
  glm::mat4 proj = glm::perspectiveRH_ZO(glm::radians(fov_degrees), aspect, 0.5f, 50.0f);
  proj[1][1] *= -1.0f;
  return proj * glm::lookAtRH(glm::vec3(0, 0, 10), glm::vec3(0), glm::vec3(0, 1, 0));
}

inline Aabb random_aabb(Rng& rng, float spread, float max_half) {
  const glm::vec3 c = rng.vec3(-spread, spread) + glm::vec3(0, 0, -spread * 0.5f);
  const glm::vec3 h = rng.vec3(0.0f, max_half);
  return {c - h, c + h};
}

inline Obb random_obb(Rng& rng, float spread, float max_half) {
  Obb b;
  b.center = rng.vec3(-spread, spread) + glm::vec3(0, 0, -spread * 0.5f);
  b.basis = rng.rotation();
  b.half_extents = rng.vec3(0.0f, max_half);
  return b;
}

inline Sphere random_sphere(Rng& rng, float spread, float max_radius) {
  return {rng.vec3(-spread, spread) + glm::vec3(0, 0, -spread * 0.5f), rng.uniform(0.0f, max_radius)};
}

/// n random AABBs, OBBs and spheres, drawn interleaved (box i, OBB i, sphere i, ...).
struct RandomVolumes {
  std::vector<Aabb> aabbs;
  std::vector<Obb> obbs;
  std::vector<Sphere> spheres;
};
inline RandomVolumes random_volumes(Rng& rng, std::size_t n, float spread, float max_half) {
  RandomVolumes v{std::vector<Aabb>(n), std::vector<Obb>(n), std::vector<Sphere>(n)};
  for (std::size_t i = 0; i < n; ++i) {
    v.aabbs[i] = random_aabb(rng, spread, max_half);
    v.obbs[i] = random_obb(rng, spread, max_half);
    v.spheres[i] = random_sphere(rng, spread, max_half);
  }
  return v;
}

// ---- exact geometry in double -------------------------------------------------------------

using dvec3 = glm::dvec3;

/// The 8 vertices of a frustum of 6 planes (left, right, bottom, top, near, far), each the
/// intersection of one plane from each pair, computed in double from the float planes.
inline std::array<dvec3, 8> frustum_vertices(const Frustum& f) {
  std::array<dvec3, 8> out;
  for (int i = 0; i < 8; ++i) {
    const Plane& a = f.planes[(i & 1) ? 1 : 0];
    const Plane& b = f.planes[(i & 2) ? 3 : 2];
    const Plane& c = f.planes[(i & 4) ? 5 : 4];
    const dvec3 na(a.normal), nb(b.normal), nc(c.normal);
    const double det = glm::dot(na, glm::cross(nb, nc));
    out[std::size_t(i)] =
        (-double(a.d) * glm::cross(nb, nc) - double(b.d) * glm::cross(nc, na) - double(c.d) * glm::cross(na, nb)) / det;
  }
  return out;
}

inline void project(const dvec3* pts, std::size_t n, const dvec3& axis, double& lo, double& hi) {
  lo = hi = glm::dot(pts[0], axis);
  for (std::size_t i = 1; i < n; ++i) {
    const double p = glm::dot(pts[i], axis);
    lo = std::min(lo, p);
    hi = std::max(hi, p);
  }
}

/// Exact separating-axis test between a 6-plane frustum and a box given by its 8 corners
/// and 3 edge directions. True when the two closed convex sets intersect.
inline bool frustum_box_intersect(const Frustum& f, const std::array<dvec3, 8>& box,
                                  const std::array<dvec3, 3>& box_dirs) {
  const auto fv = frustum_vertices(f);
  std::vector<dvec3> axes;
  for (const Plane& p : f.active()) axes.push_back(dvec3(p.normal));
  for (const dvec3& d : box_dirs) axes.push_back(d);
  // Frustum edges: between vertices differing in one index bit.
  for (int i = 0; i < 8; ++i)
    for (int bit = 1; bit < 8; bit <<= 1)
      if (!(i & bit))
        for (const dvec3& d : box_dirs) axes.push_back(glm::cross(fv[std::size_t(i | bit)] - fv[std::size_t(i)], d));
  for (const dvec3& axis : axes) {
    if (glm::dot(axis, axis) < 1e-24) continue;
    double flo, fhi, blo, bhi;
    project(fv.data(), 8, axis, flo, fhi);
    project(box.data(), 8, axis, blo, bhi);
    if (fhi < blo || bhi < flo) return false;
  }
  return true;
}

inline std::array<dvec3, 8> corners_d(const Aabb& b) {
  std::array<dvec3, 8> c;
  for (int i = 0; i < 8; ++i) c[std::size_t(i)] = dvec3(b.corner(i));
  return c;
}

/// Box corners computed in double (not rounded to float), optionally shrunk by `shrink`.
inline std::array<dvec3, 8> corners_d(const Obb& b, double shrink = 0.0) {
  std::array<dvec3, 8> c;
  for (int i = 0; i < 8; ++i) {
    dvec3 p(b.center);
    for (int k = 0; k < 3; ++k) {
      const double h = std::max(0.0, double(b.half_extents[k]) - shrink);
      p += dvec3(b.basis[k]) * ((i >> k) & 1 ? h : -h);
    }
    c[std::size_t(i)] = p;
  }
  return c;
}

inline double point_segment_distance(const dvec3& p, const dvec3& a, const dvec3& b) {
  const dvec3 ab = b - a;
  const double t = std::clamp(glm::dot(p - a, ab) / std::max(glm::dot(ab, ab), 1e-300), 0.0, 1.0);
  return glm::length(p - (a + t * ab));
}

/// Exact distance from a point to a 6-plane frustum (0 inside), in double.
inline double frustum_point_distance(const Frustum& f, const dvec3& p) {
  bool inside = true;
  for (const Plane& pl : f.active())
    if (glm::dot(dvec3(pl.normal), p) + double(pl.d) < 0.0) inside = false;
  if (inside) return 0.0;
  const auto v = frustum_vertices(f);
  // Faces as quads: fixed bit b of the vertex index at value s; the 4 vertices in cyclic order.
  double best = 1e300;
  for (int bit = 1; bit < 8; bit <<= 1)
    for (int s = 0; s < 2; ++s) {
      const int o1 = bit == 1 ? 2 : 1, o2 = bit == 4 ? 2 : 4;
      const int base = s ? bit : 0;
      const dvec3 q[4] = {v[std::size_t(base)], v[std::size_t(base | o1)], v[std::size_t(base | o1 | o2)],
                          v[std::size_t(base | o2)]};
      dvec3 n = glm::normalize(glm::cross(q[1] - q[0], q[3] - q[0]));
      const double plane_dist = glm::dot(p - q[0], n);
      const dvec3 proj = p - plane_dist * n;
      bool in_quad = true;
      double sign = 0.0;
      for (int e = 0; e < 4; ++e) {
        const double side = glm::dot(glm::cross(q[(e + 1) % 4] - q[e], proj - q[e]), n);
        if (sign == 0.0) sign = side;
        if (side * sign < 0.0) in_quad = false;
      }
      if (in_quad) best = std::min(best, std::abs(plane_dist));
      for (int e = 0; e < 4; ++e) best = std::min(best, point_segment_distance(p, q[e], q[(e + 1) % 4]));
    }
  return best;
}

/// Minimum over planes of the double-precision signed distance of p.
inline double min_plane_distance(const Frustum& f, const dvec3& p) {
  double m = 1e300;
  for (const Plane& pl : f.active()) m = std::min(m, glm::dot(dvec3(pl.normal), p) + double(pl.d));
  return m;
}

}  // namespace cullpipe::test
