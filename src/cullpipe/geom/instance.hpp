#pragma once
// Instances: an object as a mesh's local volume and a transform, placed in the world by float
// arithmetic the GPU repeats bit for bit (shaders/shared/instance.glsl), widened so the world
// volume encloses the local one as transformed exactly. Proof: docs/numerics.md, Instance
// volumes.
#include <array>
#include <glm/mat4x4.hpp>
#include <glm/vec4.hpp>
#include <string>

#include "cullpipe/geom/aabb.hpp"
#include "cullpipe/geom/obb.hpp"
#include "cullpipe/geom/sphere.hpp"

namespace cullpipe {

/// An affine transform as the three rows of a 3x4 matrix: row i = (m_i0, m_i1, m_i2, t_i), and
/// a point p goes to (row_i.xyz . p + t_i) per world axis i. The layout of the GPU's instance
/// records (48 bytes, the rows as vec4).
struct Transform3x4 {
  std::array<glm::vec4, 3> rows{glm::vec4(1, 0, 0, 0), glm::vec4(0, 1, 0, 0), glm::vec4(0, 0, 1, 0)};
  /// The affine part of a column-major glm matrix. Throws std::invalid_argument when a value is
  /// not finite or the last row is not (0, 0, 0, 1) (a projective matrix).
  static Transform3x4 from_mat4(const glm::mat4& m);
  glm::mat4 to_mat4() const;
  bool operator==(const Transform3x4&) const = default;
};

/// "" when every value is finite, else which one is not ("row 1 column 3 is NaN").
std::string invalid_reason(const Transform3x4& t);

/// An upper bound on how far the transform's linear part M stretches a vector, its largest
/// singular value: the smaller of the Frobenius norm and the square root of M^T M's largest
/// absolute row sum, in double, rounded up to a float. Equal to the largest scale (up to that
/// rounding) when the columns are orthogonal, as for rotation then scale. Infinite on overflow.
float max_scale(const Transform3x4& t);

/// A local box placed by `t`: per world axis Arvo's least and greatest values, each a float
/// sum of rounded products, then widened by 2^-20 of the axis's sum of magnitudes plus 2^-120,
/// so the box encloses the local box transformed exactly. An axis whose magnitudes overflow
/// spans (-inf, +inf). The GPU's transform pass computes the same floats.
Aabb instance_volume(const Aabb& local, const Transform3x4& t);
/// A local sphere placed by `t`, with scale = max_scale(t) (computed once per transform): the
/// centre transformed in float, the radius r * scale widened by 2^-20 of itself and of the
/// centre's magnitudes, plus 2^-120. A sphere whose values overflow becomes the one centred
/// at the origin with an infinite radius. The GPU's transform pass computes the same floats.
Sphere instance_volume(const Sphere& local, const Transform3x4& t, float scale);
/// A local OBB placed by `t`, on the host only: the box's frame composed with the transform in
/// double, then Obb::from_transformed_aabb (axes orthonormalised in double, extents from the
/// eight corners projected on the float axes, rounded up), so the box encloses the local box
/// transformed exactly: tight for rotation, uniform scale and translation, still enclosing with
/// non-uniform scale or shear. The orthonormalisation takes square roots and divisions, which
/// GPUs do not round as the CPU does: placed OBBs are computed here and sent, not placed by the
/// GPU.
Obb instance_volume(const Obb& local, const Transform3x4& t);

}  // namespace cullpipe
