#pragma once
// The CPU occlusion path: a depth buffer the CPU rasterises itself from occluder boxes, for
// engines that cull before they submit anything. Each of its pixels holds a depth at least as
// far as every depth the GPU's full-resolution render of the scene can leave in the pixels it
// covers, so the occlusion test (occlusion.hpp) against its pyramid never hides an object
// owning a pixel. Proof: docs/numerics.md, "Software depth".
#include <cstdint>
#include <glm/mat3x3.hpp>
#include <glm/mat4x4.hpp>
#include <glm/vec3.hpp>
#include <span>
#include <vector>

#include "cullpipe/cull/depth_pyramid.hpp"
#include "cullpipe/cull/occlusion.hpp"
#include "cullpipe/cull/reference.hpp"
#include "cullpipe/geom/aabb.hpp"
#include "cullpipe/geom/frustum.hpp"
#include "cullpipe/geom/obb.hpp"

namespace cullpipe {
class ThreadPool;
}

namespace cullpipe::occlusion {

/// An occluder as the GPU draws it: a parallelepiped, centre +- the three half-axis columns (any
/// independent vectors: a sheared box is drawn sheared).
struct OccluderBox {
  glm::vec3 center{0.0f};
  glm::mat3 half_axes{0.0f};
};
/// The box `local` drawn with the affine transform `world` (a scene's box object): exactly what
/// the GPU draws, shear included, unlike the object's world OBB, which encloses it.
OccluderBox occluder_box(const Aabb& local, const glm::mat4& world);
/// An OBB drawn as itself.
OccluderBox occluder_box(const Obb& box);

/// A depth buffer of width x height pixels over the viewport of `view` (each pixel covering
/// view.width / width by view.height / height of its pixels), cleared to the far depth, in
/// which every occluder box drawn as a box by the GPU (its eight corners its vertices, in the
/// vertex pipeline and rasteriser of numerics.md's model) leaves, in each pixel it covers whole,
/// the farthest depth its front can have there, plus the margins for the GPU's roundings; a pixel
/// keeps the nearest of its occluders' depths. A box with a corner at or behind the eye, or a
/// non-finite value, is skipped (it occludes nothing); so is one with a face seen edge on (to
/// 2^-20 of its edges' lengths, e.g. an orthographic view straight along a box's axis), whose
/// plane's depths this version does not trust. Rows are rasterised in parallel on `pool` (every
/// core) when given.
struct SoftwareDepth {
  std::uint32_t width = 0, height = 0;
  bool reversed_z = false;
  std::vector<float> depth;  ///< row-major, row 0 the top (as the GPU's depth image)
};
SoftwareDepth rasterise_occluders(std::span<const OccluderBox> occluders, const OcclusionView& view,
                                  std::uint32_t width, std::uint32_t height, ThreadPool* pool = nullptr);

/// The view to test objects with against a software depth's pyramid: `view`'s matrix on the
/// buffer's own, smaller viewport.
inline OcclusionView software_view(const OcclusionView& view, const SoftwareDepth& depth) {
  return {view.view_proj, depth.width, depth.height, view.reversed_z};
}

/// The CPU occlusion path end to end: the occluders rasterised (rasterise_occluders), their
/// pyramid, and every volume classified against the frustum and that pyramid (as classify_all
/// does, on the buffer's viewport), in parallel on `pool` when given. `out` gets a class per
/// volume; returns the counts.
template <class Volume>
reference::CullCounts cull_with_software_depth(std::span<const Volume> volumes, std::span<const OccluderBox> occluders,
                                               const Frustum& frustum, const OcclusionView& view, std::uint32_t width,
                                               std::uint32_t height, const OcclusionOptions& options,
                                               std::span<Classification> out, ThreadPool* pool = nullptr);

}  // namespace cullpipe::occlusion
