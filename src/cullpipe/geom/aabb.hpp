#pragma once
#include <array>
#include <glm/mat4x4.hpp>
#include <glm/vec3.hpp>

namespace cullpipe {

/// Axis-aligned box, min/max form (the form culling uses). Valid when min <= max per axis;
/// a zero extent (a flat or point box) is allowed.
struct Aabb {
  glm::vec3 min{0.0f};
  glm::vec3 max{0.0f};

  glm::vec3 center() const { return (min + max) * 0.5f; }
  glm::vec3 extent() const { return max - min; }  ///< full size per axis (diameter)
  glm::vec3 half_extent() const { return (max - min) * 0.5f; }

  /// Corner i: bit 0 selects max.x, bit 1 max.y, bit 2 max.z.
  glm::vec3 corner(int i) const { return {(i & 1) ? max.x : min.x, (i & 2) ? max.y : min.y, (i & 4) ? max.z : min.z}; }
  std::array<glm::vec3, 8> corners() const {
    std::array<glm::vec3, 8> c;
    for (int i = 0; i < 8; ++i) c[static_cast<std::size_t>(i)] = corner(i);
    return c;
  }

  /// The AABB of this box after an affine transform (Arvo 1990: along axis i, the least value
  /// is t_i + sum_j min(M[j][i] * min_j, M[j][i] * max_j), the greatest likewise), evaluated in
  /// double in the order glm transforms a point and rounded outward to float: it encloses every
  /// point of the box transformed in double (as AabbUpdate::Recompute transforms them), and is
  /// the tightest float box doing so.
  Aabb transformed(const glm::mat4& m) const;

  bool operator==(const Aabb&) const = default;
};

/// Axis-aligned box, min/diameter form: `min` corner and full size `diameter` per axis.
struct AabbMinDiameter {
  glm::vec3 min{0.0f};
  glm::vec3 diameter{0.0f};
  bool operator==(const AabbMinDiameter&) const = default;
};

/// Axis-aligned box, center/radius form: `center` and half size `radius` per axis.
struct AabbCenterRadius {
  glm::vec3 center{0.0f};
  glm::vec3 radius{0.0f};
  bool operator==(const AabbCenterRadius&) const = default;
};

// Conversions between the three forms. Exact for values whose sums and halves are exact in
// float (e.g. small integers and dyadic fractions); otherwise within one rounding per step.
inline AabbMinDiameter to_min_diameter(const Aabb& b) { return {b.min, b.max - b.min}; }
inline AabbCenterRadius to_center_radius(const Aabb& b) { return {b.center(), b.half_extent()}; }
inline Aabb to_min_max(const AabbMinDiameter& b) { return {b.min, b.min + b.diameter}; }
inline Aabb to_min_max(const AabbCenterRadius& b) { return {b.center - b.radius, b.center + b.radius}; }

}  // namespace cullpipe
