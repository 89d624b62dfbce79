#pragma once
#include <glm/mat4x4.hpp>
#include <glm/vec3.hpp>
#include <optional>
#include <span>
#include <string_view>

#include "cullpipe/bounds/aabb_update.hpp"
#include "cullpipe/geom/aabb.hpp"
#include "cullpipe/geom/obb.hpp"
#include "cullpipe/geom/sphere.hpp"

/// The bounding volumes of one rigid piece of geometry (a mesh primitive), built once from its
/// vertices and placed anywhere in the world by a transform. This is how scenes built from
/// meshes get their per-object volumes: instances of one mesh share one MeshBounds.
namespace cullpipe::bounds {

/// Which OBB builder a MeshBounds uses (see obb_fit.hpp).
enum class ObbMethod { Pca, Dito, HullFace, Exact };
std::string_view to_string(ObbMethod method);
std::optional<ObbMethod> parse_obb_method(std::string_view name);  ///< pca, dito, hull-face, exact

/// Which sphere builder a MeshBounds uses (see sphere_fit.hpp).
enum class SphereMethod { Ritter, Refined, Exact };
std::string_view to_string(SphereMethod method);
std::optional<SphereMethod> parse_sphere_method(std::string_view name);  ///< ritter, refined, exact

struct MeshBoundsOptions {
  ObbMethod obb = ObbMethod::Dito;            ///< fast by default; Exact on request
  SphereMethod sphere = SphereMethod::Exact;  ///< Welzl: expected O(n), the tightest
};

/// The sphere `s` carried by an affine transform: centre transformed, radius scaled by the
/// largest singular value of the linear part (the ellipsoid's longest semi-axis, so the result
/// is the smallest sphere about the new centre enclosing the transformed sphere, here widened
/// by 1e-6 relative as a margin for the eigenvalue computation). Computed in double and
/// rounded outward, including the rounding of the centre to float (docs/numerics.md,
/// World-space volumes).
Sphere transform_sphere(const Sphere& s, const glm::mat4& m);

class MeshBounds {
 public:
  /// Builds the hull, the local AABB, OBB and sphere. Throws BadPoints on an empty set or a
  /// non-finite coordinate.
  MeshBounds(std::span<const glm::vec3> local_points, const MeshBoundsOptions& options = {});

  const Aabb& local_aabb() const { return tracker_.local_bounds(); }
  const Obb& local_obb() const { return obb_; }
  const Sphere& local_sphere() const { return sphere_; }
  const ConvexHull& hull() const { return tracker_.hull(); }
  const AabbTracker& tracker() const { return tracker_; }

  /// The world AABB under `world` by the chosen update method; `extremes` is the object's own
  /// hill-climbing state (start from tracker().initial_extremes()).
  Aabb world_aabb(const glm::mat4& world, AabbUpdate method, AabbTracker::Extremes& extremes) const {
    return tracker_.update(world, method, extremes);
  }
  Obb world_obb(const glm::mat4& world) const;
  Sphere world_sphere(const glm::mat4& world) const { return transform_sphere(sphere_, world); }

 private:
  AabbTracker tracker_;
  Obb obb_;
  Sphere sphere_;
};

}  // namespace cullpipe::bounds
