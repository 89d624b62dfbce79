// cull_types.h: the one definition of every struct and constant shared by the GLSL compute
// shaders and the C++ host. Included by both; std430 layout, vec4-packed, no implicit padding.
// Offsets and sizes are checked by static_assert in src/cullpipe/gpu/layout_checks.cpp.
#ifndef CULLPIPE_SHADERS_SHARED_CULL_TYPES_H
#define CULLPIPE_SHADERS_SHARED_CULL_TYPES_H

#ifdef __cplusplus
#include <cstdint>
#include <glm/ext/vector_uint4.hpp>
#include <glm/mat4x4.hpp>
#include <glm/vec3.hpp>
#include <glm/vec4.hpp>
namespace cullpipe::gpu {
using vec3 = glm::vec3;
using vec4 = glm::vec4;
using uvec4 = glm::uvec4;
using mat4 = glm::mat4;
using uint = std::uint32_t;
#define CP_CONST inline constexpr uint
#else
#define CP_CONST const uint
#endif

// Bounding-volume kinds; selected in the shader by specialization constant 0.
CP_CONST BV_KIND_AABB = 0u;
CP_CONST BV_KIND_OBB = 1u;
CP_CONST BV_KIND_SPHERE = 2u;

// Classification values written per object (same numbering as cullpipe::Classification).
CP_CONST CLASS_OUTSIDE = 0u;
CP_CONST CLASS_INTERSECTING = 1u;
CP_CONST CLASS_INSIDE = 2u;
CP_CONST CLASS_OCCLUDED = 3u;

// Invocations per workgroup of the flat culling shader.
CP_CONST FLAT_CULL_GROUP_SIZE = 256u;
// Objects per invocation of the flat arrival-order pass (GpuCullerConfig::objects_per_invocation).
CP_CONST FLAT_OBJECTS_PER_INVOCATION = 8u;
// Planes in a frustum: left, right, bottom, top, near, far (far may be absent: infinite).
CP_CONST MAX_FRUSTUM_PLANES = 6u;

// Number of vec4 words each volume kind occupies in the bounds buffer.
CP_CONST AABB_VEC4S = 2u;    // GpuAabb
CP_CONST OBB_VEC4S = 4u;     // GpuObb
CP_CONST SPHERE_VEC4S = 1u;  // GpuSphere

// Axis-aligned box, min/max form. w components are unused (kept 0).
struct GpuAabb {
  vec4 min_corner;  // xyz = minimum corner
  vec4 max_corner;  // xyz = maximum corner
};

// Oriented box, basis matrix + radius form: centre, three unit axes, half extent per axis.
struct GpuObb {
  vec4 center;  // xyz = centre; w = flat pass: a bound on the projected radius (src/cullpipe/geom/plane_bounds.hpp)
  vec4 axis_x;  // xyz = unit axis, w = half extent along it
  vec4 axis_y;
  vec4 axis_z;
};

// Sphere: xyz = centre, w = radius.
struct GpuSphere {
  vec4 center_radius;
};

// An object to place: the rows of its 3x4 transform (Transform3x4: row i = (m_i0, m_i1, m_i2,
// t_i)), then info.x = its mesh's index, info.y = the bits of max_scale (spheres' radius
// factor), info.z = its slot (where its world volume goes).
struct GpuInstance {
  vec4 rows[3];
  uvec4 info;
};
CP_CONST INSTANCE_TEXELS = 4u;
// OBBs are placed on the host (their axes are orthonormalised, with square roots and divisions
// GPUs do not round as the CPU does) and their list entries carry the placed box: a GpuObb
// (four texels), then a texel whose z is the slot.
CP_CONST OBB_ENTRY_TEXELS = 5u;

// The placing pass (place_instances.comp): world volumes of the listed instances, written where
// the culling passes read them. Uniform texel buffers, except the two outputs.
CP_CONST PLACE_BINDING_LIST = 0u;     // per object to place: a GpuInstance, or an OBB's OBB_ENTRY_TEXELS
CP_CONST PLACE_BINDING_MESHES = 1u;   // the meshes' local volumes (GpuAabb or GpuSphere; OBB entries need none)
CP_CONST PLACE_BINDING_BOUNDS = 2u;   // out: vec4 words of the world volumes (BINDING_BOUNDS' buffer)
CP_CONST PLACE_BINDING_CENTRES = 3u;  // out: AABBs' centre and bound (BINDING_CENTRES' buffer)
CP_CONST PLACE_BINDING_COUNT = 4u;
CP_CONST PLACE_GROUP_SIZE = 64u;

// Push constants of the placing pass: entries [first, count) of the list.
struct PlaceParams {
  uint count;
  uint first;
};

// The refitting pass (refit_bvh.comp): the node boxes of a flattened tree recomputed from its
// objects' placed boxes, one dispatch per height (leaves first), each node's box the union of
// its objects' or its children's (the float minima and maxima bvh::refit takes, so the boxes
// are its bit for bit). Uniform texel buffers, except the nodes' words it writes.
CP_CONST REFIT_BINDING_NODES = 0u;       // GpuBvhNode per node (BVH_BINDING_NODES' buffer), read
CP_CONST REFIT_BINDING_NODE_WORDS = 1u;  // the same buffer, storage: the boxes written
CP_CONST REFIT_BINDING_BOUNDS = 2u;      // the objects' boxes in tree order (BINDING_BOUNDS' buffer, GpuAabb)
CP_CONST REFIT_BINDING_ORDER = 3u;       // GpuRefitEntry per node to refit, by height, leaves first
CP_CONST REFIT_BINDING_COUNT = 4u;
CP_CONST REFIT_GROUP_SIZE = 64u;

// A node to refit: its index, then a leaf's first object (in tree order) and count, or an inner
// node's first and second child.
struct GpuRefitEntry {
  uint node;
  uint a;
  uint b;
  uint unused;
};

// Push constants of one refitting dispatch: the nodes at order[first + i] for i < count.
struct RefitParams {
  uint first;
  uint count;
};

// One view's frustum, as stored in the views buffer (one entry per view).
// The culling shaders read the views as integer texels of a uniform texel buffer, FRUSTUM_TEXELS
// per view: on lavapipe a storage-buffer load at an index it cannot prove uniform (the view
// index comes from the workgroup id) is a loop over the lanes, each inserting one component
// through the stack, and the 25 such loads per invocation would dominate the flat pass.
struct GpuFrustum {
  vec4 planes[MAX_FRUSTUM_PLANES];  // xyz = unit inward normal, w = d; inside when dot(n,p)+d >= 0
  uint plane_count;                 // planes actually used (5 when the far plane is at infinity)
  float settle_margin;              // the margin added to each box's centre bound (NaN or inf: none settles)
  uint reserved1;
  uint reserved2;
};
CP_CONST FRUSTUM_TEXELS = 7u;

// Push constants of the flat culling pass. One dispatch covers every view (y = view index)
// and up to maxComputeWorkGroupCount[0] groups of objects, starting at first_object. Scenes
// larger than one storage buffer are culled in segments, each bound as its own range of the
// bounds, classes and draw-template buffers; indices here are within the segment.
struct FlatCullParams {
  uint object_count;      // objects in the bound segment of the bounds buffer
  uint first_object;      // index of the first object of this dispatch, within the segment
  uint view_count;        // views in the views buffer
  uint visible_capacity;  // capacity of each view's visible-id list
  uint id_base;           // object id of the segment's first object (added to listed ids)
};

// Largest workgroup and objects per invocation the compaction shaders support (their shared
// arrays).
CP_CONST MAX_CULL_GROUP_SIZE = 1024u;
CP_CONST MAX_OBJECTS_PER_INVOCATION = 32u;

// Bindings of set 0, shared by every culling shader (one descriptor set): storage buffers,
// except the bounds, views and centres, which are uniform texel buffers.
CP_CONST BINDING_BOUNDS = 0u;          // vec4 words of the volumes
CP_CONST BINDING_CLASSES = 1u;         // uint per object and view: [view * object_count + i]
CP_CONST BINDING_VISIBLE = 2u;         // visible ids: [view * visible_capacity + k]
CP_CONST BINDING_COUNTERS = 3u;        // ViewCounters per view
CP_CONST BINDING_VIEWS = 4u;           // GpuFrustum per view
CP_CONST BINDING_DRAW_TEMPLATES = 5u;  // DrawCommand per object (object_id ignored)
CP_CONST BINDING_DRAWS = 6u;           // DrawCommand out: [view * visible_capacity + k]
CP_CONST BINDING_GROUP_COUNTS =
    7u;  // ordered mode: [view][group] visible counts (then offsets), then [view][group] INSIDE counts
CP_CONST BINDING_PYRAMID = 9u;           // occlusion: the depth pyramid's floats (DepthPyramidPass)
CP_CONST BINDING_OCCLUSION_VIEWS = 10u;  // occlusion: GpuOcclusionView per view, OCCLUSION_VIEW_TEXELS texels each
CP_CONST BINDING_CENTRES = 8u;  // AABBs: vec4 per object, xyz = centre, w = bound (src/cullpipe/geom/plane_bounds.hpp)
CP_CONST CULL_BINDING_COUNT = 11u;

// One indirect draw of a visible object: the first five fields are exactly
// VkDrawIndexedIndirectCommand (so the array can be passed to vkCmdDrawIndexedIndirectCount
// with stride sizeof(DrawCommand) = 24), followed by the id of the object it draws.
struct DrawCommand {
  uint index_count;
  uint instance_count;
  uint first_index;
  int vertex_offset;
  uint first_instance;
  uint object_id;
};

// Per-view counters, written by the shader (cleared with vkCmdFillBuffer before each pass).
// INTERSECTING = visible - inside, derived on the host (one atomic fewer per subgroup).
// visible_count (offset 0 of each view's entry) is also the draw count for
// vkCmdDrawIndexedIndirectCount; pass maxDrawCount = visible_capacity, since it may exceed it.
struct ViewCounters {
  uint visible_count;   // visible objects found; may exceed visible_capacity (overflow)
  uint inside_count;    // of which INSIDE
  uint node_tests;      // hierarchical pass: BVH node boxes tested (flat pass: 0)
  uint object_tests;    // hierarchical pass: objects tested in INTERSECTING leaves (flat pass: 0)
  uint occluded_count;  // occlusion culling: objects the frustum keeps and the depth pyramid hides
  uint reserved1;
  uint reserved2;
  uint reserved3;
};

// ---- hierarchical culling (shaders/cull_bvh.comp) ----
// The BVH is stored depth first (src/cullpipe/bvh flatten): a node's first child follows it, `skip`
// is the index of the node after its subtree, and every subtree's objects are the range
// [first, first + count) of the object-order buffer.

// Invocations per workgroup of the hierarchical pass, at most: a workgroup is one subgroup
// (the device's subgroup size, up to this).
CP_CONST BVH_CULL_GROUP_SIZE = 64u;
// Entries per invocation of the hierarchical pass's walk stack (shared memory, 4 bytes each):
// at most one cut node per lane and two nodes per lane for each of BVH_CUT_MAX_HEIGHT levels
// below (see cull_bvh.comp).
CP_CONST BVH_STACK_PER_INVOCATION = 40u;
// A stack entry holds a node's offset from its workgroup's first cut node in the bits above the
// 6 plane bits and the occluded-ancestor bit: a workgroup's cut subtrees must span fewer nodes
// than this (checked on upload).
CP_CONST BVH_WORKGROUP_NODE_SPAN = 1u << 25u;

// The host cuts the tree into the highest subtrees of at most so many objects (a BvhCuller
// setting) and at most BVH_CUT_MAX_HEIGHT levels below their root (20 levels in all), or
// leaves; one invocation walks one. The height bound keeps a walk's plane masks (6 bits per
// level) in four words.
CP_CONST BVH_CUT_MAX_HEIGHT = 19u;

// The node-test margin of hierarchies over OBBs and spheres, as float bits: 2^-16 and 2^-120
// (bvh::kBvhMarginScale, kBvhMarginFloor, kBvhMarginLimit; checked in src/cullpipe/gpu/layout_checks.cpp).
// Why they suffice: docs/numerics.md, BVH node margins.
CP_CONST BVH_MARGIN_SCALE_BITS = 0x37800000u;
CP_CONST BVH_MARGIN_FLOOR_BITS = 0x03800000u;
CP_CONST BVH_MARGIN_LIMIT_BITS = 0x7b800000u;  // 2^120 (bvh::kBvhMarginLimit)

struct GpuBvhNode {
  vec3 box_min;
  uint first;  // first object (index into the object-order buffer) of the subtree
  vec3 box_max;
  uint count;         // objects in the subtree
  uint skip;          // node after this subtree
  uint second_child;  // inner node: index of its second child (its first is this index + 1)
  uint leaf;          // 1 for a leaf
  uint depth;         // the root is 1
};

// Push constants of the hierarchical pass.
struct BvhCullParams {
  uint object_count;
  uint view_count;
  uint visible_capacity;  // per view
  uint cut_count;         // cut subtrees (one invocation each, per view)
  uint groups_per_view;   // workgroups per view: cut_count / BVH_CULL_GROUP_SIZE rounded up
  uint cut_offset;        // the pass's cut starts at cuts[cut_offset] (occlusion passes take their own)
};

// Bindings of the hierarchical pass (set 0). 0..6 mean what they mean for the flat pass,
// except that BINDING_BOUNDS holds each object's volume (GpuAabb, GpuObb or GpuSphere) in tree
// order (the order of BVH_BINDING_OBJECTS), so a leaf's volumes are read together. Bounds,
// views, nodes, the object order and the centre bounds are uniform texel buffers; the rest
// storage buffers.
CP_CONST BVH_BINDING_NODES = 7u;     // GpuBvhNode, depth first, three texels each
CP_CONST BVH_BINDING_OBJECTS = 8u;   // object ids in tree order, four per texel
CP_CONST BVH_BINDING_CUTS = 9u;      // uint: the cut nodes, depth first
CP_CONST BVH_BINDING_RECORDS = 10u;  // uvec2 scratch: a record per object and view (each cut subtree's slice)
CP_CONST BVH_BINDING_CENTRES =
    11u;  // AABBs: vec4 per object in tree order, xyz = centre, w = bound (as BINDING_CENTRES)
CP_CONST BVH_BINDING_PYRAMID = 12u;          // occlusion: the depth pyramid's floats (as BINDING_PYRAMID)
CP_CONST BVH_BINDING_OCCLUSION_VIEWS = 13u;  // occlusion: GpuOcclusionView per view (as BINDING_OCCLUSION_VIEWS)
CP_CONST BVH_BINDING_COUNT = 14u;

// ---- clusters (shaders/cull_clusters.comp) ----
// First the pairs of the instances the object pass kept are listed (cluster_expand.comp, with
// compact_scan.comp between its two stages); then one invocation per listed pair, in pair order
// (an instance's clusters together, instances in order), writes the pair's class and its
// workgroup's count of draws in the layout the ordered flat pass writes them; compact_scan.comp
// turns the counts into offsets and cluster_scatter.comp writes the draws in pair order, one per
// run of drawn pairs whose index ranges follow on from each other. The pairs of culled instances
// cost nothing but a fill of their classes. Bindings 0..10 mean what they mean for the flat pass,
// with these inputs: BINDING_BOUNDS holds CLUSTER_TEXELS per cluster, BINDING_CENTRES
// CLUSTER_INSTANCE_TEXELS per instance.
// Per pair x = instance, y = cluster, z = 1 + its placed OBB's index in CLUSTER_BINDING_OBBS
// (0: none), w = 1 when its draw continues the pair before's (ClusterCuller::upload_draws).
CP_CONST CLUSTER_BINDING_PAIRS = 11u;           // uniform texel buffer
CP_CONST CLUSTER_BINDING_OBJECT_CLASSES = 12u;  // uint per instance: the object pass's class (CLASS_*)
// The pairs of the instances the object pass kept, in pair order (cluster_expand.comp): a
// ViewCounters first (its visible_count the number of them; the workgroups of the passes over
// them from CLUSTER_ACTIVE_DISPATCH), then their pair indices from uint CLUSTER_ACTIVE_HEADER on.
// The cluster pass and its draws run over this list only, dispatched indirectly.
CP_CONST CLUSTER_BINDING_ACTIVE = 13u;
// The pairs' OBBs placed by their instances' transforms (GpuObb, OBB_VEC4S texels each; the
// centre's w unused), for the pairs whose cluster has one: a uniform texel buffer.
CP_CONST CLUSTER_BINDING_OBBS = 14u;
CP_CONST CLUSTER_BINDING_COUNT = 15u;
CP_CONST CLUSTER_ACTIVE_HEADER = 8u;
// In the header, from this uint: the VkDispatchIndirectCommand of the passes over the list.
CP_CONST CLUSTER_ACTIVE_DISPATCH = 4u;

// Per cluster: (box min, cone cutoff), (box max, 0), (cone apex, 0), (cone axis, 0).
CP_CONST CLUSTER_TEXELS = 4u;
// Per instance: the rows of its transform, the rows of its inverse (InverseFrame::inverse),
// (translation magnitudes, flags: bit 0 = the inverse frame is usable), then (its first pair,
// its cluster count, 0, 0).
CP_CONST CLUSTER_INSTANCE_TEXELS = 8u;

// A pair's class. Drawn and culled-by-the-frustum take the object classes' values that mean
// the same, so the compaction passes list exactly the drawn pairs (CLASS_INTERSECTING).
CP_CONST CLUSTER_OUTSIDE = 0u;        // its placed box is outside the frustum
CP_CONST CLUSTER_DRAWN = 1u;          // = CLASS_INTERSECTING
CP_CONST CLUSTER_OCCLUDED = 3u;       // its placed box is hidden behind the depth pyramid
CP_CONST CLUSTER_BACK_FACING = 4u;    // every one of its triangles faces away from the eye
CP_CONST CLUSTER_OBJECT_CULLED = 5u;  // the object pass culled its instance

// Push constants of the cluster pass; the compaction passes read the first five words as their
// FlatCullParams (object_count = pairs, one view).
struct ClusterCullParams {
  uint pair_count;
  uint first_pair;  // the first pair of this dispatch
  uint view_count;  // 1
  uint visible_capacity;
  uint id_base;   // 0
  uint backface;  // 1: the back-face test
  uint reserved1;
  uint reserved2;
  vec4 eye;  // xyz: the eye, world space
};

// ---- occlusion: the depth pyramid (src/cullpipe/gpu/depth_pyramid_pass.hpp) ----

// Invocations per workgroup side of depth_pyramid.comp (8 x 8 texels a workgroup).
CP_CONST PYRAMID_GROUP_SIDE = 8u;

// The most levels a pyramid has (a side of occlusion::kMaxViewportSide = 16384 pixels: 15).
CP_CONST PYRAMID_MAX_LEVELS = 15u;

// One view as the flat pass's occlusion test sees it (occlusion::OcclusionView and the
// pyramid's levels), read as integer texels like GpuFrustum.
struct GpuOcclusionView {
  mat4 view_proj;  // the matrix the depth was rendered with
  uint width;      // viewport = depth image size
  uint height;
  uint reversed_z;       // 1: depth 1 is nearest (GREATER test)
  uint texels_per_axis;  // OcclusionOptions::texels_per_axis (the shaders take it as specialization constant 7)
  uint level_count;
  uint reserved1;
  uint reserved2;
  uint reserved3;
  uvec4 levels[PYRAMID_MAX_LEVELS];  // x = offset in floats, y = width, z = height
};
CP_CONST OCCLUSION_VIEW_TEXELS = 21u;

// Push constants of the pass that fills level 0 from unorm depth (depth_unorm.comp).
struct PyramidUnormParams {
  uint count;       // texels
  uint bits;        // 16 or 24
  uint reversed_z;  // 1: the farthest depth is the smallest
  uint step_bits;   // the bits of fl(1 / (2^bits - 1))
};

// Push constants of depth_pyramid.comp: one level from the level below it, both in one float
// array (occlusion::pyramid_levels gives the offsets, in floats).
struct PyramidReduceParams {
  uint source_offset;
  uint source_width;
  uint source_height;
  uint reversed_z;  // 1: the farthest depth is the smallest
  uint offset;
  uint width;
  uint height;
  uint pad;
};

// ---- src/cullpipe/render: the headless rasteriser that draws the culled objects ----

// One drawable object, indexed by gl_InstanceIndex (= the draw's first_instance = object id).
struct RenderObject {
  mat4 model;  // object-to-world (for box objects: world * box placement of a unit cube)
  vec4 color;  // rgb in 0..1, a = 1
};

// Push constants of the mesh pipeline.
struct RenderParams {
  mat4 view_proj;  // world to Vulkan clip space
};

#ifdef __cplusplus
}  // namespace cullpipe::gpu
#undef CP_CONST
#endif

#endif
