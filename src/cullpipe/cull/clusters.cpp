#include "cullpipe/cull/clusters.hpp"

#include "cullpipe/cull/reference.hpp"

namespace cullpipe::clusters {

ClusterClass classify(const Aabb& box, const BackfaceCone& cone, const Transform3x4& transform,
                      const InverseFrame& frame, bool object_kept, const ClusterView& view, const Obb* obb) {
  if (!object_kept) return ClusterClass::ObjectCulled;
  const Aabb world = instance_volume(box, transform);
  if (reference::classify(world, view.frustum) == Classification::Outside) return ClusterClass::Outside;
  if (obb && reference::classify(*obb, view.frustum) == Classification::Outside) return ClusterClass::Outside;
  if (view.backface && facing_away(cone, frame, view.eye)) return ClusterClass::BackFacing;
  if (view.occlusion && view.pyramid) {
    if (occlusion::occluded(occlusion::footprint(world, *view.occlusion), *view.pyramid, view.occlusion_options))
      return ClusterClass::Occluded;
    if (obb && occlusion::occluded(occlusion::footprint(*obb, *view.occlusion), *view.pyramid, view.occlusion_options))
      return ClusterClass::Occluded;
  }
  return ClusterClass::Drawn;
}

}  // namespace cullpipe::clusters
