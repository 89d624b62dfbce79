#pragma once
#include <array>
#include <glm/ext/matrix_double4x4.hpp>
#include <glm/mat3x3.hpp>
#include <glm/mat4x4.hpp>
#include <glm/vec3.hpp>

#include "cullpipe/geom/aabb.hpp"
#include "cullpipe/geom/exact_fp.hpp"

CULLPIPE_EXACT_FP_BEGIN
namespace cullpipe {

/// Oriented box, basis matrix + radius form (the form culling uses): `center`, an orthonormal
/// `basis` whose columns are the box axes, and `half_extents` (radius) along each axis.
/// Points of the box: center + basis * t with |t_i| <= half_extents_i.
struct Obb {
  glm::vec3 center{0.0f};
  glm::mat3 basis{1.0f};
  glm::vec3 half_extents{0.0f};

  glm::vec3 axis(int i) const { return basis[i]; }
  /// Corner i: bit k set means +half_extents along axis k, else minus.
  glm::vec3 corner(int i) const {
    glm::vec3 p = center;
    for (int k = 0; k < 3; ++k) p += basis[k] * ((i >> k) & 1 ? half_extents[k] : -half_extents[k]);
    return p;
  }
  std::array<glm::vec3, 8> corners() const {
    std::array<glm::vec3, 8> c;
    for (int i = 0; i < 8; ++i) c[static_cast<std::size_t>(i)] = corner(i);
    return c;
  }

  /// The box `local` carried by the affine transform `m`, as an OBB: axes are the matrix
  /// columns orthonormalised in double (Gram-Schmidt), extents the 8 corners transformed in
  /// double and projected on the stored float axes, rounded up. Tight for rotation, scale and
  /// translation; with shear still enclosing. Overflow shows as infinite extents.
  static Obb from_transformed_aabb(const Aabb& local, const glm::mat4& m);
  static Obb from_transformed_aabb(const Aabb& local, const glm::dmat4& m);

  bool operator==(const Obb&) const = default;
};

/// Oriented box, base point + axes form: a corner `base` and three edge vectors; the box is
/// base + a*u + b*v + c*w for a, b, c in [0, 1]. Edges must be mutually orthogonal.
struct ObbBaseAxes {
  glm::vec3 base{0.0f};
  std::array<glm::vec3, 3> edges{glm::vec3(1, 0, 0), glm::vec3(0, 1, 0), glm::vec3(0, 0, 1)};
  bool operator==(const ObbBaseAxes&) const = default;
};

/// Conversions. A zero-length edge gets an axis completing a right-handed orthonormal basis.
ObbBaseAxes to_base_axes(const Obb& b);
Obb to_basis_radius(const ObbBaseAxes& b);

}  // namespace cullpipe
CULLPIPE_EXACT_FP_END
