#include "cullpipe/geom/frustum.hpp"

#include <cmath>
#include <stdexcept>
#include <string>

namespace cullpipe {
namespace {

bool all_finite(const glm::vec4& v) {
  return std::isfinite(v.x) && std::isfinite(v.y) && std::isfinite(v.z) && std::isfinite(v.w);
}

const char* plane_name(std::size_t i) {
  static const char* names[] = {"left", "right", "bottom", "top", "near/depth-0", "far/depth-w"};
  return i < 6 ? names[i] : "?";
}

// Normalises a plane; returns false when the normal has zero length. With keep_unit, a plane
// that is already unit length (within 1e-6) is returned unchanged.
bool normalise(const glm::vec4& raw, Plane& out, bool keep_unit = false) {
  const double len = std::sqrt(double(raw.x) * raw.x + double(raw.y) * raw.y + double(raw.z) * raw.z);
  if (!(len > 0.0) || !std::isfinite(len)) return false;
  if (keep_unit && std::abs(len - 1.0) <= 1e-6) {
    out = Plane::from_vec4(raw);
    return true;
  }
  const float inv = float(1.0 / len);
  out.normal = glm::vec3(raw.x * inv, raw.y * inv, raw.z * inv);
  out.d = raw.w * inv;
  return std::isfinite(out.d);
}

}  // namespace

Frustum Frustum::from_view_proj(const glm::mat4& m) {
  auto row = [&](int i) { return glm::vec4(m[0][i], m[1][i], m[2][i], m[3][i]); };
  const glm::vec4 r0 = row(0), r1 = row(1), r2 = row(2), r3 = row(3);
  for (int i = 0; i < 4; ++i)
    if (!all_finite(row(i)))
      throw std::invalid_argument("view-projection matrix has a NaN or infinite entry in row " + std::to_string(i));
  const double det = glm::determinant(glm::dmat4(m));
  if (!(std::abs(det) > 0.0)) throw std::invalid_argument("view-projection matrix is singular (determinant 0)");

  const glm::vec4 raw[6] = {r3 + r0, r3 - r0, r3 + r1, r3 - r1, r2, r3 - r2};
  Frustum f;
  for (std::size_t i = 0; i < 6; ++i) {
    Plane p;
    if (normalise(raw[i], p)) {
      f.planes[f.plane_count++] = p;
      continue;
    }
    // A zero normal with positive d is a plane at infinity (always satisfied): drop it.
    // Only the depth planes may be at infinity; anything else is degenerate.
    if (i >= 4 && raw[i].w > 0.0f) continue;
    throw std::invalid_argument(std::string("view-projection matrix gives a degenerate ") + plane_name(i) +
                                " plane (zero normal)");
  }
  return f;
}

Frustum Frustum::from_planes(std::span<const glm::vec4> planes) {
  if (planes.empty() || planes.size() > 6)
    throw std::invalid_argument("a frustum needs 1 to 6 planes, got " + std::to_string(planes.size()));
  Frustum f;
  for (std::size_t i = 0; i < planes.size(); ++i) {
    if (!all_finite(planes[i]))
      throw std::invalid_argument("plane " + std::to_string(i) + " has a NaN or infinite value");
    Plane p;
    if (!normalise(planes[i], p, /*keep_unit=*/true))
      throw std::invalid_argument("plane " + std::to_string(i) + " has a zero normal");
    f.planes[f.plane_count++] = p;
  }
  return f;
}

}  // namespace cullpipe
