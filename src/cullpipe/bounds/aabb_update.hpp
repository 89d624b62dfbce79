#pragma once
#include <array>
#include <glm/ext/vector_double2.hpp>
#include <glm/ext/vector_double3.hpp>
#include <glm/mat4x4.hpp>
#include <glm/vec3.hpp>
#include <optional>
#include <span>
#include <string_view>
#include <vector>

#include "cullpipe/bounds/convex_hull.hpp"
#include "cullpipe/geom/aabb.hpp"

namespace cullpipe::bounds {

/// Ways to find the world AABB of an object's points after a new transform.
enum class AabbUpdate {
  Recompute,      ///< transform every point: exact, O(n)
  HullRecompute,  ///< transform the convex-hull vertices only: O(h), padded by the hull tolerance
  TransformBox,   ///< the AABB of the transformed local AABB (Arvo): O(1), loose
  HillClimb,      ///< walk hull edges from the last extreme vertex per axis: ~O(1) for small motions, padded
                  ///< (see AabbTracker for where a walk can fall short)
};

std::string_view to_string(AabbUpdate method);
std::optional<AabbUpdate> parse_aabb_update(std::string_view name);

/// Keeps an object's world AABB as its transform changes. Built once from the object's local
/// points (hull and local AABB computed up front); then `update` returns the world AABB for
/// any affine transform by the chosen method. Results are computed in double and rounded
/// outward to float. Recompute and TransformBox enclose every transformed point. HullRecompute
/// is widened by the hull tolerance (points within it of a hull face may lie outside it;
/// twice that for a flat or linear hull, whose vertices also lie within it of its plane or
/// line), and encloses every point as far as the hull contains them within that tolerance:
/// Quickhull's rounding bound, which holds for the test scenes' meshes and random sets but
/// not for sets whose coordinates span about ten orders of magnitude. When the hull failed
/// validation (ConvexHull::valid), the hull-based methods recompute from every point instead;
/// when an edge of the hull is certainly folded inward, HillClimb transforms the hull vertices
/// instead of walking. HillClimb's walk also relies on the hull being convex: Quickhull's
/// surface may still fold inward at edges by the rounding of its orientation tests, and where
/// such a fold meets a direction almost tangent to a long face a walk can stop short of the
/// maximum by far more than the padding, again only among coordinates of very different
/// magnitudes. On the real meshes of the test scenes the walk's boxes match HullRecompute's to
/// 1e-6 of their size (tested over many rotations), and no hull there has an edge certainly
/// folded inward. Examples of both limits: docs/numerics.md, World-space volumes.
class AabbTracker {
 public:
  /// Throws BadPoints on an empty set or a non-finite coordinate.
  explicit AabbTracker(std::span<const glm::vec3> local_points);

  Aabb update(const glm::mat4& world, AabbUpdate method);

  /// Hull vertex indices maximising -x, +x, -y, +y, -z, +z: where hill climbing starts.
  using Extremes = std::array<std::uint32_t, 6>;
  /// The local-space extremes (the start for an object seen for the first time).
  const Extremes& initial_extremes() const { return initial_extreme_; }
  /// Stateless form, for one tracker shared by many objects (instances of one mesh): hill
  /// climbing starts from `extremes` and leaves the new extreme vertices there; `steps`, when
  /// given, receives the number of vertices visited. Same results as `update` above.
  Aabb update(const glm::mat4& world, AabbUpdate method, Extremes& extremes, std::size_t* steps = nullptr) const;

  const ConvexHull& hull() const { return hull_; }
  const Aabb& local_bounds() const { return local_; }
  /// Hull vertices visited by the last HillClimb update (its cost; 0 when the tracker does not
  /// walk and transformed the hull vertices instead).
  std::size_t last_climb_steps() const { return climb_steps_; }

 private:
  std::vector<glm::vec3> points_;
  ConvexHull hull_;
  Aabb local_;
  Extremes initial_extreme_{};
  Extremes extreme_{};  // where the last HillClimb update ended
  std::size_t climb_steps_ = 0;
  std::vector<glm::dvec3> climb_points_;  // hull vertices (projected onto a flat hull's plane)
  std::vector<glm::dvec2> ring_uv_;       // a flat hull's ring in its plane axes (walked on these)
  glm::dvec3 plane_n_{0.0};               // a flat hull's plane: normal plane_u x plane_v, offset
  double plane_c_ = 0.0;                  // n . vertices[0]
  bool climb_safe_ = true;                // no hull edge certainly concave: hill climbing may walk
};

}  // namespace cullpipe::bounds
