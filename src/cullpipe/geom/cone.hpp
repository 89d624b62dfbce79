#pragma once
// Back-face cones: a cluster of triangles that faces away from a viewer as a whole, decided
// from a cone and an apex in the mesh's own space, without visiting its triangles. The test is
// made in float, bit for bit as shaders/shared/cone.glsl makes it, with margins that cover
// every rounding on the way (the eye brought into the mesh's space included). Proof:
// docs/numerics.md, Back-face cones.
#include <glm/vec3.hpp>

#include "cullpipe/geom/instance.hpp"

namespace cullpipe {

/// A cluster's back-face cone in its mesh's space (bounds::backface_cone builds one). It
/// promises, for every triangle (a, b, c) of the cluster that has a normal, with unit normal
/// n = normalize((b - a) x (c - a)):
///  - the angle between n and the direction of `axis` is at most beta, where
///    cutoff >= sin(beta);
///  - the apex lies strictly behind the triangle's plane: dot(n, apex - a) < 0.
/// A viewer at e with dot(apex - e, axis) >= cutoff * |apex - e| then lies strictly behind
/// every triangle's plane: every triangle faces away from it (counter-clockwise front faces).
struct BackfaceCone {
  glm::vec3 apex{0.0f};
  /// sin of the widest angle between the axis and a normal, rounded up; 1 or more (or NaN):
  /// no cone, the cluster is never taken as facing away.
  float cutoff = 1.0f;
  glm::vec3 axis{0.0f};  ///< unit length to within 2^-22
  bool usable() const { return cutoff < 1.0f; }
  bool operator==(const BackfaceCone&) const = default;
};

/// What the back-face test needs of an instance's transform: its inverse, to bring the eye
/// into the mesh's space, as float rows computed in double (`inverse`), and per row the
/// magnitude of the translation's part, sum_j |inverse_ij * t_j| rounded up
/// (`translation_magnitude`), for the error bound. `usable` is false when the transform is
/// singular, not finite, or so ill-conditioned that the double inverse could be off by more
/// than 2^-30 of its magnitudes: such an instance's clusters are never taken as facing away.
struct InverseFrame {
  Transform3x4 inverse;
  glm::vec3 translation_magnitude{0.0f};
  bool usable = false;
  bool operator==(const InverseFrame&) const = default;
};

/// The inverse frame of `t` (host only, in double).
InverseFrame inverse_frame(const Transform3x4& t);

/// Whether every triangle of the cone's cluster, placed by the transform whose inverse frame is
/// `frame`, faces away from a viewer at `eye` (world space) as an exact computation would find
/// it: the eye brought into the mesh's space in float (with a bound on its error), then the cone
/// test with that error, the rounding of the test itself and a relative 2^-16 taken against
/// culling. False for an unusable cone or frame and for anything not finite. (A mirrored
/// instance's triangles face as they do in the mesh's space once their winding is flipped, as
/// glTF asks of a renderer.) The same float operations as cone_facing_away() in
/// shaders/shared/cone.glsl.
bool facing_away(const BackfaceCone& cone, const InverseFrame& frame, const glm::vec3& eye);

}  // namespace cullpipe
