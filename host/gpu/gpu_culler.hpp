#pragma once
#include <cstddef>
#include <cstdint>
#include <memory>
#include <span>
#include <vector>

#include "cull/reference.hpp"
#include "geom/aabb.hpp"
#include "geom/bv_kind.hpp"
#include "geom/classification.hpp"
#include "geom/frustum.hpp"
#include "geom/obb.hpp"
#include "geom/sphere.hpp"
#include "gpu/layout.hpp"
#include "vk/buffer.hpp"
#include "vk/compute_pipeline.hpp"
#include "vk/context.hpp"

namespace cullpipe::gpu {

/// One view's result of a GPU culling pass.
struct ViewResult {
  std::vector<Classification> classes;     ///< per object, in object order
  std::vector<std::uint32_t> visible_ids;  ///< ids of INSIDE/INTERSECTING objects, in GPU arrival order
  reference::CullCounts counts;            ///< as counted by the GPU
  bool overflow = false;                   ///< more visible objects than the list could hold
};

/// Times of one pass. gpu_ns: between timestamps around the dispatches (0 when the queue has
/// no timestamps). wall_ns: recording, submission, waiting and reading results back.
struct CullTimings {
  double gpu_ns = 0.0;
  double wall_ns = 0.0;
};

struct CullResult {
  std::vector<ViewResult> views;
  CullTimings timings;
};

/// Options of one culling pass.
struct CullOptions {
  bool classes = true;      ///< read back per-object classifications
  bool visible_ids = true;  ///< read back the compacted visible list
  /// Room for visible ids per view; 0 means the object count (cannot overflow). With less,
  /// the list holds the first ids that fit, the counters still count every visible object and
  /// ViewResult::overflow is set.
  std::size_t visible_capacity = 0;
};

/// How a GpuCuller is set up.
struct GpuCullerConfig {
  /// Invocations per workgroup; lowered to the device's limits when larger.
  std::uint32_t group_size = FLAT_CULL_GROUP_SIZE;
  /// Workgroups per dispatch before the pass is split into chunks; 0 means the device limit
  /// (maxComputeWorkGroupCount[0]). Tests set it low to exercise the chunked path.
  std::uint32_t max_groups_per_dispatch = 0;
};

/// Flat frustum culling on a Vulkan device: uploads one set of volumes, then classifies them
/// against any number of views per pass, one compute invocation per object and view, with
/// results identical bit for bit to cullpipe::reference. Not thread-safe; one pass at a time.
class GpuCuller {
 public:
  explicit GpuCuller(const vk::Context& ctx, const GpuCullerConfig& config = {});
  ~GpuCuller();
  GpuCuller(const GpuCuller&) = delete;
  GpuCuller& operator=(const GpuCuller&) = delete;

  /// Uploads the volumes to cull, replacing any earlier upload. Volumes must be valid
  /// (see invalid_reason); throws std::length_error when they do not fit one storage buffer
  /// (maxStorageBufferRange), naming the sizes.
  void upload(std::span<const Aabb> volumes);
  void upload(std::span<const Obb> volumes);
  void upload(std::span<const Sphere> volumes);

  /// Classifies the uploaded volumes against every view in one submission.
  /// Throws std::length_error when views x objects outputs exceed a storage buffer.
  CullResult cull(std::span<const Frustum> views, const CullOptions& options = {});

  BvKind kind() const { return kind_; }
  std::uint32_t group_size() const { return group_size_; }
  std::size_t object_count() const { return object_count_; }
  const vk::Context& context() const { return ctx_; }

 private:
  void upload_words(BvKind kind, const void* data, std::size_t count, std::size_t bytes_per_object);
  void ensure_outputs(std::size_t view_count, std::size_t visible_capacity);
  void update_descriptors();
  void setup(const GpuCullerConfig& config);
  void release();

  const vk::Context& ctx_;
  std::uint32_t group_size_ = FLAT_CULL_GROUP_SIZE;
  std::uint32_t max_groups_ = 0;
  BvKind kind_ = BvKind::Aabb;
  std::size_t object_count_ = 0;
  std::unique_ptr<vk::ComputePipeline> pipelines_[3];
  vk::Buffer bounds_, classes_, visible_, counters_, views_;
  VkDescriptorPool descriptor_pool_ = VK_NULL_HANDLE;
  VkDescriptorSet descriptor_set_ = VK_NULL_HANDLE;
  VkCommandBuffer cmd_ = VK_NULL_HANDLE;
  VkQueryPool query_pool_ = VK_NULL_HANDLE;
  bool descriptors_dirty_ = true;
};

}  // namespace cullpipe::gpu
