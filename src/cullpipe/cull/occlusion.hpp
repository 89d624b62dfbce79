#pragma once
// The scalar occlusion test, the oracle for the GPU's: a volume's conservative screen footprint
// (a pixel rectangle and a bound on its nearest depth) against a depth pyramid. Written for
// clarity, one object at a time, in float with every operation in the order the shader takes.
#include <cstdint>
#include <glm/mat4x4.hpp>
#include <span>

#include "cullpipe/bvh/bvh.hpp"
#include "cullpipe/cull/depth_pyramid.hpp"
#include "cullpipe/cull/reference.hpp"
#include "cullpipe/geom/aabb.hpp"
#include "cullpipe/geom/classification.hpp"
#include "cullpipe/geom/frustum.hpp"
#include "cullpipe/geom/obb.hpp"
#include "cullpipe/geom/sphere.hpp"

namespace cullpipe::occlusion {

/// The view a depth image was rendered from: its view-projection matrix (Vulkan clip space, as
/// Frustum::from_view_proj takes it), the viewport (the depth image's size; viewport depth
/// range 0..1) and the depth direction (reversed_z: 1 nearest, GREATER test).
struct OcclusionView {
  glm::mat4 view_proj{1.0f};
  std::uint32_t width = 0, height = 0;
  bool reversed_z = false;
};

/// The largest viewport side the footprint's pixel margin is proved for.
inline constexpr std::uint32_t kMaxViewportSide = 16384;

/// How an occlusion test reads the pyramid.
struct OcclusionOptions {
  /// The test reads the finest level at which the footprint spans at most this many texels per
  /// axis (2, 4, 8 or 16): 2 is the classic 2x2 test; more texels read, tighter answers.
  std::uint32_t texels_per_axis = 4;
  /// 0, 2, 4, 8 or 16; when above texels_per_axis, a volume that test keeps is tested again at
  /// the finest level where its footprint spans at most this many texels per axis, so only the
  /// volumes the cheap test keeps pay for the fine one (at or below it: no second test). Each level's test is
  /// conservative on its own, so hidden by either is hidden. Volumes only: hierarchy nodes keep their one test
  /// (node_occluded).
  std::uint32_t refine_texels_per_axis = 0;
};

/// A volume's screen footprint: every pixel any of its fragments can cover lies in
/// [x0, x1] x [y0, y1] (inclusive, clamped to the viewport), and no fragment depth is nearer
/// than `nearest`. Not `projected` when some point of the volume may be at or behind the eye
/// (clip w <= 0), or a value overflowed: such a volume is never occluded.
struct Footprint {
  bool projected = false;
  std::uint32_t x0 = 0, y0 = 0, x1 = 0, y1 = 0;
  float nearest = 0.0f;
  bool operator==(const Footprint&) const = default;
};

/// The footprints of boxes from their eight corners, of spheres from their bounding boxes'.
/// Proof that they hold for the rasteriser's fragments: docs/numerics.md, "Occlusion footprints".
Footprint footprint(const Aabb& box, const OcclusionView& view);
Footprint footprint(const Obb& box, const OcclusionView& view);
Footprint footprint(const Sphere& sphere, const OcclusionView& view);

/// A hierarchy node's footprint: its box's, with every margin kNodeMarginScale times an object's.
/// It holds the computed footprint of every volume inside the box (AABBs, and OBBs and spheres
/// whose enclosing boxes it contains), so a node found occluded hides every one of them as their
/// own test finds it (docs/numerics.md, "Hierarchical occlusion").
inline constexpr float kNodeMarginScale = 4.0f;
Footprint node_footprint(const Aabb& node, const OcclusionView& view);
/// A node is tested reading at most min(texels_per_axis, kNodeTexelsPerAxis) texels per axis: a
/// cheap filter (the objects of a node it keeps get their own, finer test). Any level at least as
/// coarse as its objects' keeps the node's answer conservative for them.
inline constexpr std::uint32_t kNodeTexelsPerAxis = 4;
/// Whether a hierarchy node is hidden: node_footprint read at min(texels_per_axis,
/// kNodeTexelsPerAxis) texels per axis.
bool node_occluded(const Aabb& node, const OcclusionView& view, const DepthPyramid& pyramid,
                   const OcclusionOptions& options);

/// The pyramid level the test reads for `f`: the finest at which [x0, x1] and [y0, y1] span at
/// most `texels_per_axis` texels.
unsigned test_level(const Footprint& f, const DepthPyramid& pyramid, std::uint32_t texels_per_axis);

/// True when every pixel of the footprint holds a depth strictly nearer than any fragment of
/// the volume can have: then none of its fragments passes the depth test and it owns no pixel.
/// Read at texels_per_axis, then, where that keeps the volume, at refine_texels_per_axis.
bool occluded(const Footprint& f, const DepthPyramid& pyramid, const OcclusionOptions& options = {});

/// Throws std::invalid_argument naming what is wrong when `view` cannot be tested against
/// `pyramid`: a viewport of another size or side past kMaxViewportSide, another depth
/// direction, a non-finite matrix, texels_per_axis not 2, 4, 8 or 16, or
/// refine_texels_per_axis not 0, 2, 4, 8 or 16.
void check_view(const OcclusionView& view, const DepthPyramid& pyramid, const OcclusionOptions& options = {});
/// The same checks against a pyramid of a width x height image and that depth direction.
void check_view(const OcclusionView& view, std::uint32_t width, std::uint32_t height, bool reversed_z,
                const OcclusionOptions& options = {});

/// The frustum test's class (reference::classify), or Classification::Occluded for a volume
/// the frustum keeps and the pyramid hides. Checks the view first (check_view).
Classification classify(const Aabb& box, const Frustum& frustum, const OcclusionView& view, const DepthPyramid& pyramid,
                        const OcclusionOptions& options = {});
Classification classify(const Obb& box, const Frustum& frustum, const OcclusionView& view, const DepthPyramid& pyramid,
                        const OcclusionOptions& options = {});
Classification classify(const Sphere& sphere, const Frustum& frustum, const OcclusionView& view,
                        const DepthPyramid& pyramid, const OcclusionOptions& options = {});

/// Classifies every volume as classify does; `out` must have the same size as `volumes`. The
/// counts: visible (INSIDE + INTERSECTING), inside, intersecting and occluded.
reference::CullCounts classify_all(std::span<const Aabb> volumes, const Frustum& frustum, const OcclusionView& view,
                                   const DepthPyramid& pyramid, const OcclusionOptions& options,
                                   std::span<Classification> out);
reference::CullCounts classify_all(std::span<const Obb> volumes, const Frustum& frustum, const OcclusionView& view,
                                   const DepthPyramid& pyramid, const OcclusionOptions& options,
                                   std::span<Classification> out);
reference::CullCounts classify_all(std::span<const Sphere> volumes, const Frustum& frustum, const OcclusionView& view,
                                   const DepthPyramid& pyramid, const OcclusionOptions& options,
                                   std::span<Classification> out);

/// Hierarchical occlusion culling, the reference for the GPU's (gpu::BvhCuller with a pyramid):
/// bvh::cull_hierarchical's walk, where every node the frustum keeps is also tested against the
/// pyramid by its node_footprint. Below an occluded node nothing more is tested for occlusion:
/// what the frustum keeps there is OCCLUDED (an INSIDE node's whole range at once), and OUTSIDE
/// stays OUTSIDE. Below an INSIDE node that is not occluded the walk goes on (with no planes
/// left) so that its objects get their own occlusion test. Every object's class equals
/// classify_all's. node_tests and object_tests count frustum tests as cull_hierarchical does;
/// `occluded` counts the OCCLUDED objects. Checks the view first (check_view); over OBBs or
/// spheres the frustum needs unit normals (bvh::require_unit_normals).
bvh::HierarchicalResult cull_hierarchical(const bvh::FlatTree& tree, std::span<const Aabb> volumes,
                                          const Frustum& frustum, const OcclusionView& view,
                                          const DepthPyramid& pyramid, const OcclusionOptions& options = {},
                                          const bvh::TraversalOptions& traversal = {});
bvh::HierarchicalResult cull_hierarchical(const bvh::FlatTree& tree, std::span<const Obb> volumes,
                                          const Frustum& frustum, const OcclusionView& view,
                                          const DepthPyramid& pyramid, const OcclusionOptions& options = {},
                                          const bvh::TraversalOptions& traversal = {});
bvh::HierarchicalResult cull_hierarchical(const bvh::FlatTree& tree, std::span<const Sphere> volumes,
                                          const Frustum& frustum, const OcclusionView& view,
                                          const DepthPyramid& pyramid, const OcclusionOptions& options = {},
                                          const bvh::TraversalOptions& traversal = {});

}  // namespace cullpipe::occlusion
