#pragma once
// Ground truth for the occlusion tests: ray casting in double through pixel centres (the
// nearest depth of an AABB, OBB or sphere along each pixel's ray, as a rasteriser samples it),
// depth images of occluders as a renderer stores them, and random cameras and volumes.
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <glm/geometric.hpp>
#include <glm/mat4x4.hpp>
#include <optional>
#include <vector>

#include "cullpipe/geom/aabb.hpp"
#include "cullpipe/geom/obb.hpp"
#include "cullpipe/geom/sphere.hpp"
#include "cullpipe/scene/camera.hpp"
#include "test_util.hpp"

namespace cullpipe::test {

using dvec3 = glm::dvec3;
using dmat4 = glm::dmat4;

/// The ray through a pixel's centre from the near plane, and the matrix to read depth with.
struct Ray {
  dvec3 origin, direction;
};

struct Caster {
  dmat4 vp, inverse;
  std::uint32_t width, height;
  bool reversed;

  Caster(const glm::mat4& view_proj, std::uint32_t w, std::uint32_t h, bool rev)
      : vp(view_proj), inverse(glm::inverse(dmat4(view_proj))), width(w), height(h), reversed(rev) {}

  dvec3 unproject(double x, double y, double z) const {
    const glm::dvec4 p = inverse * glm::dvec4(x, y, z, 1.0);
    return dvec3(p) / p.w;
  }
  Ray ray(std::uint32_t px, std::uint32_t py) const {
    const double x = (px + 0.5) / width * 2.0 - 1.0, y = (py + 0.5) / height * 2.0 - 1.0;
    const dvec3 a = unproject(x, y, reversed ? 1.0 : 0.0), b = unproject(x, y, 0.5);
    return {a, b - a};
  }
  double depth(const dvec3& p) const {
    const glm::dvec4 c = vp * glm::dvec4(p, 1.0);
    return c.z / c.w;
  }
  /// The nearest depth of a hit interval [t0, t1] along `r` that lies in the depth range, or none.
  std::optional<double> nearest(const Ray& r, double t0, double t1) const {
    t0 = std::max(t0, 0.0);
    if (t0 > t1) return std::nullopt;
    const double d = depth(r.origin + t0 * r.direction);
    if (reversed ? d < 0.0 : d > 1.0) return std::nullopt;  // beyond the far plane
    return d;
  }
};

/// Slab test of a ray against a box given by centre, axes and half extents.
inline bool hit_box(const Ray& r, const dvec3& c, const dvec3 axes[3], const dvec3& h, double& t0, double& t1) {
  t0 = -1e300, t1 = 1e300;
  for (int i = 0; i < 3; ++i) {
    const double o = glm::dot(r.origin - c, axes[i]), d = glm::dot(r.direction, axes[i]);
    if (std::abs(d) < 1e-300) {
      if (std::abs(o) > h[i]) return false;
      continue;
    }
    double a = (-h[i] - o) / d, b = (h[i] - o) / d;
    if (a > b) std::swap(a, b);
    t0 = std::max(t0, a), t1 = std::min(t1, b);
  }
  return t0 <= t1;
}

inline std::optional<double> cast(const Caster& k, const Ray& r, const Aabb& b) {
  const dvec3 axes[3] = {{1, 0, 0}, {0, 1, 0}, {0, 0, 1}};
  double t0, t1;
  const dvec3 c = (dvec3(b.min) + dvec3(b.max)) * 0.5, h = (dvec3(b.max) - dvec3(b.min)) * 0.5;
  if (!hit_box(r, c, axes, h, t0, t1)) return std::nullopt;
  return k.nearest(r, t0, t1);
}

inline std::optional<double> cast(const Caster& k, const Ray& r, const Obb& b) {
  // (Axes normalised; the extents scaled to match, so non-unit axes give the same box.)
  dvec3 axes[3];
  dvec3 h;
  for (int i = 0; i < 3; ++i) {
    const dvec3 u(b.basis[i]);
    axes[i] = glm::normalize(u);
    h[i] = std::abs(double(b.half_extents[i])) * glm::length(u);
  }
  double t0, t1;
  if (!hit_box(r, dvec3(b.center), axes, h, t0, t1)) return std::nullopt;
  return k.nearest(r, t0, t1);
}

inline std::optional<double> cast(const Caster& k, const Ray& r, const Sphere& s) {
  const dvec3 oc = r.origin - dvec3(s.center);
  const double a = glm::dot(r.direction, r.direction), b = glm::dot(oc, r.direction);
  const double c = glm::dot(oc, oc) - double(s.radius) * s.radius, disc = b * b - a * c;
  if (disc < 0) return std::nullopt;
  const double q = std::sqrt(disc);
  return k.nearest(r, (-b - q) / a, (-b + q) / a);
}

/// A depth image of `occluders` as a renderer stores it: per pixel centre the nearest depth,
/// rounded to float; the clear value where nothing is hit.
template <class Volume>
std::vector<float> render_depth(const Caster& k, const std::vector<Volume>& occluders) {
  std::vector<float> depth(std::size_t(k.width) * k.height, k.reversed ? 0.0f : 1.0f);
  for (std::uint32_t y = 0; y < k.height; ++y)
    for (std::uint32_t x = 0; x < k.width; ++x) {
      const Ray r = k.ray(x, y);
      float& d = depth[std::size_t(y) * k.width + x];
      for (const Volume& o : occluders)
        if (const auto hit = cast(k, r, o)) {
          const float f = float(*hit);
          d = k.reversed ? std::max(d, f) : std::min(d, f);
        }
    }
  return depth;
}

inline Camera random_camera(Rng& rng, int variant) {
  Camera c;
  c.eye = rng.vec3(-30.0f, 30.0f) + glm::vec3(0.0f, 0.0f, 40.0f);
  c.target = rng.vec3(-5.0f, 5.0f);
  c.fov_y_degrees = rng.uniform(30.0f, 90.0f);
  c.aspect = rng.uniform(0.6f, 2.0f);
  c.near_plane = rng.uniform(0.05f, 2.0f);
  c.far_plane = rng.uniform(100.0f, 400.0f);
  c.reversed_z = variant & 1;
  c.infinite_far = (variant & 2) && !(variant & 4);
  c.orthographic = variant & 4;
  c.ortho_half_height = rng.uniform(10.0f, 40.0f);
  return c;
}

template <class Volume>
Volume random_volume(Rng& rng, float spread, float size);
template <>
inline Aabb random_volume<Aabb>(Rng& rng, float spread, float size) {
  const glm::vec3 c = rng.vec3(-spread, spread), h = rng.vec3(0.05f * size, size);
  return {c - h, c + h};
}
template <>
inline Obb random_volume<Obb>(Rng& rng, float spread, float size) {
  Obb b;
  b.center = rng.vec3(-spread, spread);
  b.basis = rng.rotation();
  b.half_extents = rng.vec3(0.05f * size, size);
  return b;
}
template <>
inline Sphere random_volume<Sphere>(Rng& rng, float spread, float size) {
  return {rng.vec3(-spread, spread), rng.uniform(0.05f * size, size)};
}

}  // namespace cullpipe::test
