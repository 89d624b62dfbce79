#include "cullpipe/cull/compare.hpp"

#include <algorithm>
#include <cstdio>

namespace cullpipe {
namespace {

std::string num(float v) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%.9g", double(v));
  return buf;
}

std::string vec(const glm::vec3& v) {
  char buf[96];
  std::snprintf(buf, sizeof buf, "(%.9g, %.9g, %.9g)", double(v.x), double(v.y), double(v.z));
  return buf;
}

}  // namespace

std::string describe(const Aabb& b) { return "aabb min " + vec(b.min) + " max " + vec(b.max); }

std::string describe(const Obb& b) {
  return "obb center " + vec(b.center) + " half_extents " + vec(b.half_extents) + " axes " + vec(b.basis[0]) + " " +
         vec(b.basis[1]) + " " + vec(b.basis[2]);
}

std::string describe(const Sphere& s) { return "sphere center " + vec(s.center) + " radius " + num(s.radius); }

std::string describe(const Frustum& f) {
  std::string out = "[";
  for (std::size_t i = 0; i < f.plane_count; ++i) {
    const Plane& p = f.planes[i];
    if (i) out.append(", ");
    out.append("[").append(num(p.normal.x)).append(", ").append(num(p.normal.y)).append(", ");
    out.append(num(p.normal.z)).append(", ").append(num(p.d)).append("]");
  }
  return out + "]";
}

std::size_t first_mismatch(std::span<const Classification> expected, std::span<const Classification> actual) {
  const std::size_t n = std::min(expected.size(), actual.size());
  for (std::size_t i = 0; i < n; ++i)
    if (expected[i] != actual[i]) return i;
  return expected.size() == actual.size() ? npos : n;
}

std::size_t count_mismatches(std::span<const Classification> expected, std::span<const Classification> actual) {
  const std::size_t n = std::min(expected.size(), actual.size());
  std::size_t count = std::max(expected.size(), actual.size()) - n;
  for (std::size_t i = 0; i < n; ++i) count += expected[i] != actual[i];
  return count;
}

}  // namespace cullpipe
