#pragma once
// The scalar cluster tests, the oracle for the GPU's cluster pass (gpu::ClusterCuller): a
// cluster of an instance is culled when its object was culled, when its box placed by the
// instance's transform is outside the frustum, when all of its triangles face away from the eye
// (its back-face cone), or when that box is hidden behind the depth pyramid; tested in that
// order, the first test that culls naming its class.
#include <cstddef>
#include <cstdint>
#include <string_view>

#include "cullpipe/cull/depth_pyramid.hpp"
#include "cullpipe/cull/occlusion.hpp"
#include "cullpipe/geom/aabb.hpp"
#include "cullpipe/geom/cone.hpp"
#include "cullpipe/geom/frustum.hpp"
#include "cullpipe/geom/instance.hpp"
#include "cullpipe/geom/obb.hpp"

namespace cullpipe::clusters {

/// What became of a cluster of an instance. Numbered as the GPU writes them (cull_types.h,
/// CLUSTER_*): Outside and Drawn as the object classes OUTSIDE and INTERSECTING, so the object
/// passes' compaction lists the drawn ones.
enum class ClusterClass : std::uint8_t { Outside = 0, Drawn = 1, Occluded = 3, BackFacing = 4, ObjectCulled = 5 };
/// Entries of an array indexed by a ClusterClass's value (2 is unused: the object classes'
/// INSIDE, which clusters do not tell apart from INTERSECTING).
inline constexpr std::size_t kClusterClassCount = 6;

constexpr std::string_view to_string(ClusterClass c) {
  switch (c) {
    case ClusterClass::Drawn:
      return "drawn";
    case ClusterClass::ObjectCulled:
      return "object culled";
    case ClusterClass::Outside:
      return "outside";
    case ClusterClass::BackFacing:
      return "back-facing";
    case ClusterClass::Occluded:
      return "occluded";
  }
  return "invalid";
}

/// One view as the cluster tests see it.
struct ClusterView {
  Frustum frustum;
  /// The eye, world space: the centre of the perspective projection that draws the image.
  glm::vec3 eye{0.0f};
  /// False: no back-face test (an orthographic view has no eye point; or the caller's choice).
  bool backface = true;
  /// With both set, the occlusion test against this pyramid.
  const occlusion::OcclusionView* occlusion = nullptr;
  const occlusion::DepthPyramid* pyramid = nullptr;
  occlusion::OcclusionOptions occlusion_options;
};

/// The class of one cluster (local box `box`, cone `cone`) of an instance placed by `transform`
/// (whose inverse frame is `frame`), whose object the object pass kept (`object_kept`) or not.
/// The box is placed as instance_volume places it; the frustum test is reference::classify's;
/// the back-face test is facing_away's (for a cone and frame that are usable); the occlusion
/// test is occlusion::occluded on the placed box's footprint. With `obb`, the cluster's OBB
/// placed by the transform (instance_volume(Obb, transform)), the frustum and occlusion tests
/// cull what either volume's test culls (the box's first).
ClusterClass classify(const Aabb& box, const BackfaceCone& cone, const Transform3x4& transform,
                      const InverseFrame& frame, bool object_kept, const ClusterView& view, const Obb* obb = nullptr);

}  // namespace cullpipe::clusters
