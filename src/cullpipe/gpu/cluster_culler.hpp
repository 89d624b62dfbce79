#pragma once
// The GPU cluster pass (shaders/cull_clusters.comp): every cluster of every instance tested in
// parallel, by its object's class from the object pass, the frustum, its back-face cone and
// the depth pyramid, and the drawn ones listed as indexed indirect draws of their index
// ranges, in pair order, with a count; drawn clusters whose ranges follow on from each other
// share a draw. Its classes equal clusters::classify's, pair by pair.
#include <vulkan/vulkan.h>

#include <array>
#include <cstdint>
#include <map>
#include <memory>
#include <optional>
#include <span>
#include <vector>

#include "cullpipe/cull/clusters.hpp"
#include "cullpipe/geom/obb.hpp"
#include "cullpipe/gpu/cull_types.h"
#include "cullpipe/gpu/depth_pyramid_pass.hpp"
#include "cullpipe/vulkan/buffer.hpp"
#include "cullpipe/vulkan/compute_pipeline.hpp"
#include "cullpipe/vulkan/context.hpp"

namespace cullpipe::gpu {

namespace detail {
class PassResources;
}

/// An instance of a mesh split into clusters: its transform and its mesh's clusters, the range
/// [first_cluster, first_cluster + cluster_count) of the boxes and cones uploaded with it.
struct ClusterInstance {
  Transform3x4 transform;
  std::uint32_t first_cluster = 0;
  std::uint32_t cluster_count = 0;
  /// False: its clusters are never taken as facing away (double-sided materials).
  bool backface = true;
};

/// One frame of the cluster pass.
struct ClusterFrame {
  Frustum frustum;
  /// The back-face test from `eye` (world space, the perspective projection's centre); off for
  /// orthographic views.
  bool backface = true;
  glm::vec3 eye{0.0f};
  /// The object pass's classes (CLASS_*, a uint per instance from `object_classes_offset` bytes,
  /// a multiple of minStorageBufferOffsetAlignment), written earlier in the same command buffer
  /// by a pass whose writes were made visible to compute shaders (GpuCuller::record's are:
  /// GpuCuller::class_buffer()); null: every instance kept.
  const vulkan::Buffer* object_classes = nullptr;
  VkDeviceSize object_classes_offset = 0;
  /// Occlusion: the pyramid (built earlier in the same command buffer) and the view its depth was
  /// rendered from.
  const DepthPyramidPass* pyramid = nullptr;
  occlusion::OcclusionView occlusion_view;
  occlusion::OcclusionOptions occlusion_options;
};

/// What one pass found.
struct ClusterResult {
  std::vector<clusters::ClusterClass> classes;                     ///< per pair, in pair order
  std::array<std::size_t, clusters::kClusterClassCount> counts{};  ///< pairs per class, indexed by the class's value
  std::size_t drawn = 0;                                           ///< clusters drawn
  /// Draws written (the draw count): a run of drawn clusters whose index ranges follow on from
  /// each other is one draw.
  std::size_t draws = 0;
  /// cull(): GPU time of the passes (timestamps; 0 without) and wall time of all of it.
  double gpu_ns = 0.0, wall_ns = 0.0;
};

class ClusterCuller {
 public:
  explicit ClusterCuller(const vulkan::Context& ctx);
  ~ClusterCuller();
  ClusterCuller(const ClusterCuller&) = delete;
  ClusterCuller& operator=(const ClusterCuller&) = delete;

  /// The clusters (local boxes and back-face cones, one each per cluster of every mesh, and
  /// optionally an OBB per cluster, Cluster::obb) and the instances. The pairs are every
  /// instance's clusters in order, instances in order. A pair whose cluster has an OBB gets it
  /// placed by the instance's transform on the host (instance_volume(Obb, transform), 64 bytes
  /// a pair), and its frustum and occlusion tests cull what either volume's test culls. Throws
  /// std::invalid_argument naming the instance for a cluster range past the clusters or a
  /// transform that is not finite, and for boxes, cones and OBBs (when given) of different
  /// counts; std::length_error past 2^32 pairs or the device's limits. On a throw the culler
  /// keeps what it had. Call when no pass of this culler is in flight (its buffers are replaced).
  void upload(std::span<const Aabb> boxes, std::span<const BackfaceCone> cones,
              std::span<const ClusterInstance> instances, std::span<const std::optional<Obb>> obbs = {});
  /// A draw per pair, in pair order (first_instance says which object a draw is of). Where a
  /// pair's draw continues the one before (same instance, instance count, vertex offset and
  /// first instance, its index range starting where that one's ends), a run of them that is
  /// drawn becomes one draw, unless `merge` is false (every drawn pair its own draw, as given).
  /// Throws std::invalid_argument for a count other than pair_count(). Call when no pass of this
  /// culler is in flight.
  void upload_draws(std::span<const DrawCommand> draws, bool merge = true);
  std::size_t pair_count() const { return pair_count_; }
  std::size_t instance_count() const { return instance_count_; }

  /// Records the pass into `cmd`: a barrier first (earlier reads of its outputs complete, and
  /// earlier compute and transfer writes visible to its shaders), then the draws of the drawn pairs in
  /// draw_buffer() and their count in counter_buffer() (ViewCounters::visible_count), ready for
  /// vkCmdDrawIndexedIndirectCount with maxDrawCount = pair_count(). Throws
  /// std::invalid_argument for an occlusion view that does not match the pyramid, or a frame
  /// that is not finite, before recording anything. A frame naming another object class buffer
  /// or pyramid buffer than the last one rewrites the descriptor set: the last pass must have
  /// completed by then (one frame in flight per culler).
  void record(VkCommandBuffer cmd, const ClusterFrame& frame);
  /// The classes and counts of the last recorded pass, once it has completed.
  ClusterResult read_results() const;
  /// record() on its own command buffer, submitted and waited for, then read_results().
  ClusterResult cull(const ClusterFrame& frame);

  const vulkan::Buffer& draw_buffer() const { return draws_; }
  const vulkan::Buffer& counter_buffer() const { return counters_; }

 private:
  void prepare(const ClusterFrame& frame);
  void record_passes(VkCommandBuffer cmd);
  const vulkan::ComputePipeline& pipeline(int which, bool occlusion = false, bool object_classes = false,
                                          std::uint32_t texels = 4, std::uint32_t refine = 0);

  const vulkan::Context& ctx_;
  std::uint32_t group_size_ = FLAT_CULL_GROUP_SIZE;
  std::uint32_t max_groups_ = 0;
  std::map<std::uint32_t, std::unique_ptr<vulkan::ComputePipeline>> pipelines_;  // by key (pipeline())
  std::unique_ptr<detail::PassResources> resources_;
  std::size_t pair_count_ = 0;
  vulkan::Buffer clusters_, instances_, pairs_, pair_obbs_, templates_;
  vulkan::Buffer classes_, visible_, counters_, views_, draws_, group_counts_, occlusion_views_, no_pyramid_,
      no_classes_;
  vulkan::Buffer expand_counts_, active_;  // the listing of the kept instances' pairs
  std::size_t instance_count_ = 0;
  ClusterCullParams params_{};
  // What the descriptor set names now (rewritten when a frame names other buffers).
  VkBuffer bound_classes_ = VK_NULL_HANDLE;
  VkDeviceSize bound_classes_offset_ = 0;
  VkBuffer bound_pyramid_ = VK_NULL_HANDLE;
  VkDeviceSize bound_pyramid_size_ = 0;
  bool occlusion_ = false, object_classes_ = false;
  std::uint32_t texels_ = 4, refine_ = 0;
};

}  // namespace cullpipe::gpu
