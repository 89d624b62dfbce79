// Compile-time checks that the C++ view of src/cullpipe/gpu/cull_types.h matches std430, so the
// structs written once there mean the same bytes to the host and to the shaders.
#include <vulkan/vulkan.h>

#include <bit>
#include <cstddef>

#include "cullpipe/bvh/bvh.hpp"
#include "cullpipe/gpu/layout.hpp"

namespace cullpipe::gpu {

static_assert(sizeof(vec4) == 16 && alignof(vec4) <= 16);

// The hierarchical node-test margin is one constant on both sides.
static_assert(std::bit_cast<std::uint32_t>(bvh::kBvhMarginScale) == BVH_MARGIN_SCALE_BITS);
static_assert(std::bit_cast<std::uint32_t>(bvh::kBvhMarginFloor) == BVH_MARGIN_FLOOR_BITS);
static_assert(std::bit_cast<std::uint32_t>(bvh::kBvhMarginLimit) == BVH_MARGIN_LIMIT_BITS);

static_assert(sizeof(GpuAabb) == AABB_VEC4S * 16);
static_assert(offsetof(GpuAabb, min_corner) == 0);
static_assert(offsetof(GpuAabb, max_corner) == 16);

static_assert(sizeof(GpuObb) == OBB_VEC4S * 16);
static_assert(offsetof(GpuObb, center) == 0);
static_assert(offsetof(GpuObb, axis_x) == 16);
static_assert(offsetof(GpuObb, axis_y) == 32);
static_assert(offsetof(GpuObb, axis_z) == 48);

static_assert(sizeof(GpuSphere) == SPHERE_VEC4S * 16);
static_assert(offsetof(GpuSphere, center_radius) == 0);

static_assert(sizeof(GpuFrustum) == 112 && sizeof(GpuFrustum) == FRUSTUM_TEXELS * 16 &&
              offsetof(GpuFrustum, plane_count) == MAX_FRUSTUM_PLANES * 16);
static_assert(offsetof(GpuFrustum, planes) == 0);
static_assert(offsetof(GpuFrustum, plane_count) == 96);
static_assert(offsetof(GpuFrustum, settle_margin) == 100);
static_assert(offsetof(GpuFrustum, reserved2) == 108);

static_assert(sizeof(FlatCullParams) == 20);
static_assert(offsetof(FlatCullParams, object_count) == 0);
static_assert(offsetof(FlatCullParams, first_object) == 4);
static_assert(offsetof(FlatCullParams, view_count) == 8);
static_assert(offsetof(FlatCullParams, visible_capacity) == 12);
static_assert(offsetof(FlatCullParams, id_base) == 16);

static_assert(sizeof(ViewCounters) == 32);
static_assert(offsetof(ViewCounters, occluded_count) == 16);
static_assert(sizeof(GpuOcclusionView) == OCCLUSION_VIEW_TEXELS * 16);
static_assert(offsetof(GpuOcclusionView, width) == 64);
static_assert(offsetof(GpuOcclusionView, level_count) == 80);
static_assert(offsetof(GpuOcclusionView, levels) == 96);
static_assert(offsetof(ViewCounters, visible_count) == 0);
static_assert(offsetof(ViewCounters, inside_count) == 4);
static_assert(offsetof(ViewCounters, node_tests) == 8);
static_assert(offsetof(ViewCounters, object_tests) == 12);

static_assert(sizeof(GpuBvhNode) == 48);
static_assert(offsetof(GpuBvhNode, box_min) == 0);
static_assert(offsetof(GpuBvhNode, first) == 12);
static_assert(offsetof(GpuBvhNode, box_max) == 16);
static_assert(offsetof(GpuBvhNode, count) == 28);
static_assert(offsetof(GpuBvhNode, skip) == 32);
static_assert(offsetof(GpuBvhNode, second_child) == 36);
static_assert(offsetof(GpuBvhNode, leaf) == 40);
static_assert(sizeof(BvhCullParams) == 24);
static_assert(offsetof(BvhCullParams, cut_count) == 12 && offsetof(BvhCullParams, groups_per_view) == 16 &&
              offsetof(BvhCullParams, cut_offset) == 20);
static_assert(BVH_STACK_PER_INVOCATION >= 1 + 2 * BVH_CUT_MAX_HEIGHT,
              "the walk stack holds a cut node and two nodes per level below it, per lane");

// DrawCommand starts with exactly VkDrawIndexedIndirectCommand.
static_assert(sizeof(DrawCommand) == 24);
static_assert(offsetof(DrawCommand, index_count) == offsetof(VkDrawIndexedIndirectCommand, indexCount));
static_assert(offsetof(DrawCommand, instance_count) == offsetof(VkDrawIndexedIndirectCommand, instanceCount));
static_assert(offsetof(DrawCommand, first_index) == offsetof(VkDrawIndexedIndirectCommand, firstIndex));
static_assert(offsetof(DrawCommand, vertex_offset) == offsetof(VkDrawIndexedIndirectCommand, vertexOffset));
static_assert(offsetof(DrawCommand, first_instance) == offsetof(VkDrawIndexedIndirectCommand, firstInstance));
static_assert(sizeof(VkDrawIndexedIndirectCommand) == 20);
static_assert(offsetof(DrawCommand, object_id) == 20);

static_assert(sizeof(RenderObject) == 80);
static_assert(offsetof(RenderObject, model) == 0);
static_assert(offsetof(RenderObject, color) == 64);
static_assert(sizeof(RenderParams) == 64);

static_assert(CLASS_OUTSIDE == 0 && CLASS_INTERSECTING == 1 && CLASS_INSIDE == 2 && CLASS_OCCLUDED == 3,
              "must match cullpipe::Classification");

static_assert(sizeof(PyramidReduceParams) == 32);
static_assert(offsetof(PyramidReduceParams, source_offset) == 0);
static_assert(offsetof(PyramidReduceParams, reversed_z) == 12);
static_assert(offsetof(PyramidReduceParams, offset) == 16);
static_assert(offsetof(PyramidReduceParams, height) == 24);

}  // namespace cullpipe::gpu
