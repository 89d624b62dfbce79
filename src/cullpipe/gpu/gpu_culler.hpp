#pragma once
#include <cstddef>
#include <cstdint>
#include <memory>
#include <span>
#include <vector>

#include "cullpipe/cull/instances.hpp"
#include "cullpipe/cull/occlusion.hpp"
#include "cullpipe/cull/reference.hpp"
#include "cullpipe/geom/aabb.hpp"
#include "cullpipe/geom/bv_kind.hpp"
#include "cullpipe/geom/classification.hpp"
#include "cullpipe/geom/frustum.hpp"
#include "cullpipe/geom/obb.hpp"
#include "cullpipe/geom/sphere.hpp"
#include "cullpipe/gpu/depth_pyramid_pass.hpp"
#include "cullpipe/gpu/layout.hpp"
#include "cullpipe/gpu/pipeline_cache.hpp"
#include "cullpipe/vulkan/buffer.hpp"
#include "cullpipe/vulkan/compute_pipeline.hpp"
#include "cullpipe/vulkan/context.hpp"

namespace cullpipe {
class ThreadPool;
}

namespace cullpipe::gpu {

namespace detail {
class PassResources;

/// A scene on the device: what every culler that culls it reads (GpuCuller::share_scene).
struct SceneBuffers {
  BvKind kind = BvKind::Aabb;
  std::size_t object_count = 0;
  std::size_t bytes_per_object = sizeof(GpuAabb);
  vulkan::Buffer bounds;     // the volumes, world space (BINDING_BOUNDS)
  vulkan::Buffer centres;    // AABBs: centre and bound per object (BINDING_CENTRES)
  vulkan::Buffer templates;  // draw templates (BINDING_DRAW_TEMPLATES)
  std::size_t template_count = 0;
  // Instances: the meshes' local volumes, their words (to recognise their set in update()), and
  // the objects the bounds and centre buffers hold.
  vulkan::Buffer meshes;
  std::vector<std::uint32_t> mesh_words;
  std::size_t instance_capacity = 0;
  bool instanced = false;
  /// Placements sent (upload, update) and not yet recorded by any sharer: ascending slots and
  /// their list entries, entry_texels texels each (instances; OBBs placed on the host). The next
  /// pass of whichever culler records first places them.
  std::vector<std::uint32_t> pending_slots;
  std::vector<uvec4> pending_entries;
  std::size_t entry_texels = INSTANCE_TEXELS;
  /// Changes whenever a buffer above is replaced or the object count changes, so every culler
  /// sharing the scene writes its descriptors again.
  std::uint64_t generation = 1;
};
}  // namespace detail

/// One view's result of a GPU culling pass.
struct ViewResult {
  std::vector<Classification> classes;  ///< per object, in object order
  /// Ids of INSIDE/INTERSECTING objects: in object order with CullOptions::ordered, else in
  /// GPU arrival order.
  std::vector<std::uint32_t> visible_ids;
  /// With CullOptions::draws: one draw per visible id, in the same order: the object's
  /// template (upload_draws) with object_id set.
  std::vector<DrawCommand> draws;
  reference::CullCounts counts;  ///< as counted by the GPU
  bool overflow = false;         ///< more visible objects than the list could hold
  /// Work done: hierarchical passes count node boxes tested and objects tested in
  /// INTERSECTING leaves; a flat pass tests no nodes and every object.
  std::size_t node_tests = 0;
  std::size_t object_tests = 0;
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
  /// Deterministic output: visible ids and draws in object order, by prefix-sum compaction
  /// (two more passes), instead of atomic arrival order. With a capacity, the list holds the
  /// first visible objects in object order.
  bool ordered = false;
  /// Also write a DrawCommand per visible object (needs upload_draws) and read them back.
  bool draws = false;
  /// Occlusion culling: with a pyramid, the objects the frustum keeps are tested against it as
  /// each view's entry of occlusion_views says its depth was rendered (one per view), exactly as
  /// occlusion::classify tests them; the hidden ones are Classification::Occluded, counted in
  /// counts.occluded, neither listed nor drawn. The pyramid must have been built (its record()
  /// earlier in the same command buffer, or its build()) and must outlive the pass.
  const DepthPyramidPass* pyramid = nullptr;
  std::vector<occlusion::OcclusionView> occlusion_views;
  occlusion::OcclusionOptions occlusion_options;
};

namespace detail {
/// The texels per axis the occlusion test of a pass with `options` reads, in the low byte, and
/// its refine_texels_per_axis above it where that refines (0 otherwise): a pipeline key, turned
/// into the cull shaders' specialization constants 7 and 10 by set_occlusion_constants; 0
/// without a pyramid.
inline std::uint32_t occlusion_texels(const CullOptions& options) {
  const occlusion::OcclusionOptions& o = options.occlusion_options;
  const std::uint32_t refine = o.refine_texels_per_axis > o.texels_per_axis ? o.refine_texels_per_axis : 0u;
  return options.pyramid ? o.texels_per_axis | refine << 8 : 0u;
}
/// Specialization constants 6 (occlusion on), 7 (texels per axis) and 10 (refining texels) of
/// a cull shader's constants `spec` (8 and 9 left as they are), for an occlusion_texels key.
inline void set_occlusion_constants(std::span<std::uint32_t, 11> spec, std::uint32_t key) {
  spec[6] = key ? 1u : 0u;
  spec[7] = key ? key & 0xffu : 4u;
  spec[10] = key >> 8;
}
}  // namespace detail

/// Buffers an engine owns for a pass's outputs (GpuCuller::use_engine_outputs): the pass writes
/// into them instead of its own, from their first byte, in the layout draw_buffer(),
/// counter_buffer() and the visible lists have. A null handle keeps cullpipe's own buffer for
/// that output. The `*_host` pointers, where the engine's memory is mapped, let read_results()
/// and cull() read them back; without one they cannot, and say so.
struct EngineOutputs {
  VkBuffer draws = VK_NULL_HANDLE;  ///< usage STORAGE_BUFFER | INDIRECT_BUFFER
  VkDeviceSize draws_size = 0;
  const void* draws_host = nullptr;
  VkBuffer counters = VK_NULL_HANDLE;  ///< usage STORAGE_BUFFER | TRANSFER_DST | INDIRECT_BUFFER
  VkDeviceSize counters_size = 0;
  const void* counters_host = nullptr;
  VkBuffer visible = VK_NULL_HANDLE;  ///< usage STORAGE_BUFFER
  VkDeviceSize visible_size = 0;
  const void* visible_host = nullptr;
};

/// How a GpuCuller is set up.
struct GpuCullerConfig {
  /// Invocations per workgroup; lowered to the device's limits when larger.
  std::uint32_t group_size = FLAT_CULL_GROUP_SIZE;
  /// Workgroups per dispatch before the pass is split into chunks; 0 means the device limit
  /// (maxComputeWorkGroupCount[0]). Tests set it low to exercise the chunked path.
  std::uint32_t max_groups_per_dispatch = 0;
  /// Objects each invocation classifies in the arrival-order pass (1..32): planes loaded once
  /// for all of them, and one visible-list atomic per subgroup for all of the subgroup's.
  /// The ordered passes use the same number.
  std::uint32_t objects_per_invocation = FLAT_OBJECTS_PER_INVOCATION;
  /// Most objects per segment; 0 means as many as the device's limits allow (one texel buffer
  /// view of volumes, one storage buffer of classes). Larger scenes are culled in segments of
  /// this many objects (a multiple of 256), each bound as its own range. Tests set it low to
  /// exercise that path.
  std::size_t max_segment_objects = 0;
  /// Threads that write an upload (packing the volumes and computing the boxes' bounds):
  /// 0 means every core (std::thread::hardware_concurrency()), 1 the calling thread only.
  /// The threads start with the first upload of more than 16384 objects and sleep between
  /// uploads (each GpuCuller has its own; where none can start, uploads run on the caller).
  unsigned upload_threads = 0;
};

/// Flat frustum culling on a Vulkan device: uploads one set of volumes, then classifies them
/// against any number of views per pass, a few objects per compute invocation and view, with
/// results identical bit for bit to cullpipe::reference. Not thread-safe; one pass at a time.
class GpuCuller {
 public:
  explicit GpuCuller(const vulkan::Context& ctx, const GpuCullerConfig& config = {});
  ~GpuCuller();
  GpuCuller(const GpuCuller&) = delete;
  GpuCuller& operator=(const GpuCuller&) = delete;

  /// Uploads the volumes to cull, replacing any earlier upload. Volumes must be valid
  /// (see invalid_reason). More than one storage buffer (maxStorageBufferRange) of them is
  /// culled in segments; throws std::length_error, naming the sizes, when they do not fit one
  /// memory allocation (maxMemoryAllocationSize) or exceed 2^32 - 1 objects.
  void upload(std::span<const Aabb> volumes);
  void upload(std::span<const Obb> volumes);
  void upload(std::span<const Sphere> volumes);

  /// Uploads a scene of instances, replacing any earlier upload: the meshes' local volumes once,
  /// and per object its transform and mesh index. The next pass first places every object in
  /// the world on the GPU (shaders/shared/instance.glsl: the floats instance_volume computes on
  /// the CPU, bit for bit), then culls the placed volumes as upload(world volumes) would, so its
  /// answers are the reference's on instances.world_volumes(), object by object; objects are
  /// reported by slot. Throws as upload(volumes) does when the buffers cannot hold them.
  /// OBBs are placed on the host (instance_volume: their axes orthonormalised in double, which
  /// GPUs do not round alike) on the upload threads, and the placed boxes sent: still only the
  /// objects that changed, 80 bytes each.
  void upload(const InstanceSet<Aabb>& instances);
  void upload(const InstanceSet<Obb>& instances);
  void upload(const InstanceSet<Sphere>& instances);
  /// Sends what changed in the set uploaded last: the transforms and mesh indices of `slots`
  /// (InstanceSet::changed_slots(), ascending), and its new size after adds and removes. Only
  /// those objects are placed again, by the next pass; the others keep their placed volumes.
  /// Buffers grow here, by half again, when the set outgrew them (then every object is sent and
  /// placed), never inside record(). Throws std::invalid_argument when the set's meshes are not
  /// the ones uploaded, a slot is out of range or the slots are not ascending, and nothing
  /// changes.
  void update(const InstanceSet<Aabb>& instances, std::span<const std::uint32_t> slots);
  void update(const InstanceSet<Obb>& instances, std::span<const std::uint32_t> slots);
  void update(const InstanceSet<Sphere>& instances, std::span<const std::uint32_t> slots);
  /// Objects the next pass places before culling (0 after a pass, or for world volumes).
  std::size_t pending_placements() const { return scene_->pending_slots.size(); }
  /// Objects the scene's buffers hold before an update() must grow them (instances).
  std::size_t instance_capacity() const { return scene_->instance_capacity; }
  /// Grows the scene's buffers to hold `objects` instances now (every object is sent and placed
  /// again), so that no later update() grows them: an engine calls it when no pass using the
  /// scene is in flight. Throws std::invalid_argument without instances uploaded.
  void reserve_instances(const InstanceSet<Aabb>& instances, std::size_t objects);
  void reserve_instances(const InstanceSet<Obb>& instances, std::size_t objects);
  void reserve_instances(const InstanceSet<Sphere>& instances, std::size_t objects);

  /// Culls the scene `other` culls, stored once: the volumes, instances and draw templates, and
  /// every upload and update made through either culler (both on one context). Each culler
  /// keeps its own outputs, so an engine keeps one culler per frame in flight over one scene.
  /// Uploads and updates through any of them queue their placements on the scene; the next
  /// pass recorded by any of them places them in the shared buffers (through its own list), in
  /// queue order before any later pass reads them. Uploads, and updates that
  /// grow the buffers, replace buffers that passes in flight may still read: make them when no
  /// pass using the scene is in flight (or reserve_instances first). Throws
  /// std::invalid_argument when the cullers are on different contexts.
  void share_scene(const GpuCuller& other);

  /// One draw template per object, in object order (object_id is ignored): the indirect draw
  /// each visible object gets. Needed before a pass with CullOptions::draws; must match the
  /// object count of the volumes culled then.
  void upload_draws(std::span<const DrawCommand> templates);

  /// The output buffers of the last pass, for drawing from them without a readback:
  /// draw_buffer() holds DrawCommand records for view v at byte offset
  /// v * visible_capacity * sizeof(DrawCommand) (stride 24, usable with
  /// vkCmdDrawIndexedIndirectCount); counter_buffer() holds ViewCounters per view, and the
  /// draw count of view v is its visible_count at byte offset v * sizeof(ViewCounters) (it
  /// may exceed visible_capacity: pass that as maxDrawCount). Both have
  /// VK_BUFFER_USAGE_INDIRECT_BUFFER_BIT.
  const vulkan::Buffer& draw_buffer() const { return draws_; }
  const vulkan::Buffer& counter_buffer() const { return counters_; }
  std::size_t last_visible_capacity() const { return last_capacity_; }
  /// The classes the last pass wrote (ordered passes always write them; arrival order with
  /// CullOptions::classes): object i of view v at uint [v * object count + i] when it culled
  /// one segment (last_segment_count() == 1, as every ordered pass does). What the cluster pass
  /// reads (ClusterFrame::object_classes).
  const vulkan::Buffer& class_buffer() const { return classes_; }

  /// Writes the draws, counters and visible ids of every later pass into the engine's buffers
  /// (the engine keeps its indirect arguments where it wants them); draw_buffer() and
  /// counter_buffer() then name them. A pass they are too small for throws std::length_error
  /// naming the size it needs; they are never replaced. The barriers around a pass cover them
  /// as they cover cullpipe's own. Call when no pass of this culler is in flight.
  void use_engine_outputs(const EngineOutputs& outputs);
  /// Back to cullpipe's own output buffers.
  void use_own_outputs();

  /// Makes the outputs (classes, visible ids, counters, draws) large enough for passes of
  /// `view_count` views with `options` (its capacity, draws, order) over `objects` objects (0 or
  /// fewer than uploaded: the objects uploaded now; more: room for a scene of instances that will
  /// grow to that), replacing buffers that are too small. record() never replaces them, so the handles of
  /// draw_buffer() and counter_buffer() an engine binds stay the same from frame to frame until
  /// it calls this again (when no pass of this culler is in flight). Throws as cull() does for
  /// passes that cannot run.
  void reserve_outputs(std::size_t view_count, const CullOptions& options = {}, std::size_t objects = 0);

  /// Classifies the uploaded volumes against every view in one submission and waits, growing
  /// the outputs as the pass needs. Throws std::length_error when the visible lists or draws
  /// (views x capacity) exceed a storage buffer, or when `ordered` output is asked of more than
  /// one segment of objects.
  CullResult cull(std::span<const Frustum> views, const CullOptions& options = {});

  /// The engine path: records the whole pass (counter reset, dispatches, barriers) into the
  /// caller's command buffer, which must be recording, outside a render pass, for a queue of
  /// the context's queue family. Nothing is submitted. The outputs are never replaced here: when
  /// they are too small for the pass (more objects, views or capacity than reserve_outputs or an
  /// earlier pass made room for) it throws std::logic_error saying what to reserve. The views
  /// are written to a host-visible buffer now and descriptors may be written, so one GpuCuller
  /// serves one recorded pass at a time: record again (or cull, or upload) only after the
  /// submission of the previous recording has completed; use one GpuCuller per frame in flight
  /// (over one scene: share_scene). The
  /// recording starts with a barrier after earlier readers of the outputs (indirect draws,
  /// shaders, transfers) and ends with one that makes draw_buffer() and counter_buffer() ready
  /// for vkCmdDrawIndexedIndirectCount (DRAW_INDIRECT stage), vertex shaders (on graphics
  /// queues, e.g. reading DrawCommand::object_id), later compute shaders and the host.
  /// Pipelines are built here (not during recording's hot path later). After the caller's
  /// submission has completed, read_results() returns what cull() would have (no timings).
  void record(VkCommandBuffer cmd, std::span<const Frustum> views, const CullOptions& options = {});
  CullResult read_results() const;

  BvKind kind() const { return scene_->kind; }
  std::uint32_t group_size() const { return group_size_; }
  std::uint32_t objects_per_invocation() const { return objects_per_invocation_; }
  /// Segments of the last pass (1 unless the scene exceeds one storage buffer).
  std::size_t last_segment_count() const { return segment_count_; }
  std::size_t object_count() const { return scene_->object_count; }
  const vulkan::Context& context() const { return ctx_; }

 private:
  template <class Fill>
  void upload_volumes(BvKind kind, std::size_t count, std::size_t bytes_per_object, bool centres, Fill&& fill);
  // fill(first, end) for objects [0, count), in chunks on the upload threads.
  template <class Fill>
  void run_upload_tasks(std::size_t count, Fill&& fill);
  template <class Volume>
  void upload_instances(const InstanceSet<Volume>& instances);
  template <class Volume>
  void update_instances(const InstanceSet<Volume>& instances, std::span<const std::uint32_t> slots);
  template <class Volume>
  void reserve(const InstanceSet<Volume>& instances, std::size_t objects);
  void ensure_place_resources(BvKind kind);
  void prepare_placement();
  void record_placement(VkCommandBuffer cmd);
  const vulkan::ComputePipeline& place_pipeline(BvKind kind);
  void ensure_outputs(std::size_t view_count, std::size_t visible_capacity, bool draws, bool ordered, bool may_grow);
  VkDeviceSize group_count_bytes(std::size_t view_count) const;  // the ordered passes' workgroup counts
  struct SegmentPlan {
    std::size_t objects = 0;  // per segment
    std::size_t count = 1;
  };
  SegmentPlan plan_segments(std::size_t view_count, bool ordered) const;
  void prepare(std::span<const Frustum> views, const CullOptions& options, bool may_grow);
  void record_passes(VkCommandBuffer cmd, VkQueryPool timestamps);
  /// One variant of the flat pass's shaders; fields a shader does not read stay at their defaults.
  struct PipelineKey {
    enum class Shader { Cull, CompactScan, CompactScatter };
    Shader shader = Shader::Cull;
    BvKind kind = BvKind::Aabb;  // Cull
    bool ordered = false;        // Cull: count per workgroup for the ordered passes
    bool draws = false;          // Cull, CompactScatter: write indirect draws
    bool classes = false;        // Cull: write the per-object classes
    // Cull: test the kept objects against the depth pyramid: detail::occlusion_texels's packed
    // texels and refining texels (0: no occlusion test).
    std::uint32_t occlusion_texels = 0;
    auto operator<=>(const PipelineKey&) const = default;
  };
  const vulkan::ComputePipeline& pipeline(PipelineKey key);
  /// The cull pass in arrival order; the ordered passes' counting cull and their scatter.
  PipelineKey arrival_key(const CullOptions& o) const {
    return {
        .kind = scene_->kind, .draws = o.draws, .classes = o.classes, .occlusion_texels = detail::occlusion_texels(o)};
  }
  PipelineKey ordered_key(const CullOptions& o) const {
    return {.kind = scene_->kind, .ordered = true, .classes = true, .occlusion_texels = detail::occlusion_texels(o)};
  }
  static PipelineKey scatter_key(const CullOptions& o) {
    return {.shader = PipelineKey::Shader::CompactScatter, .draws = o.draws};
  }
  void update_descriptors();

  const vulkan::Context& ctx_;
  std::uint32_t group_size_ = FLAT_CULL_GROUP_SIZE;
  std::uint32_t max_groups_ = 0;
  std::uint32_t objects_per_invocation_ = 1;
  std::size_t max_segment_objects_ = 0;
  unsigned upload_threads_ = 0;
  std::unique_ptr<ThreadPool> upload_pool_;  // started by the first upload of several chunks
  // Segments of the current pass: objects per segment and their count (1 when all fit).
  std::size_t segment_objects_ = 0;
  std::size_t segment_count_ = 1;
  // What the descriptor sets were last written for.
  std::size_t written_segment_objects_ = 0, written_view_count_ = 0;
  // The pyramid buffer the descriptors hold, by DepthPyramidPass::generation() (0: none; a
  // handle could be reused by a later buffer, a generation is not).
  std::uint64_t written_pyramid_ = ~std::uint64_t{0}, pyramid_generation_ = 0;
  detail::PipelineCache<PipelineKey> pipelines_;
  vulkan::Buffer classes_, visible_, counters_, views_, draws_, group_counts_;
  bool engine_draws_ = false, engine_counters_ = false, engine_visible_ = false;  // borrowed
  vulkan::Buffer occlusion_views_;           // GpuOcclusionView per view (BINDING_OCCLUSION_VIEWS)
  vulkan::Buffer no_pyramid_;                // bound to BINDING_PYRAMID in passes without occlusion
  const vulkan::Buffer* pyramid_ = nullptr;  // the buffer bound to BINDING_PYRAMID
  std::size_t last_capacity_ = 0;
  std::size_t last_view_count_ = 0;
  std::size_t last_object_count_ = 0;
  CullOptions last_options_;
  std::unique_ptr<detail::PassResources> resources_;  // descriptor set, command buffer, timestamps
  bool descriptors_dirty_ = true;
  void* upload_bounds_ = nullptr;   // where an upload's fill writes the volumes
  void* upload_centres_ = nullptr;  // and the boxes' centre bounds
  std::shared_ptr<detail::SceneBuffers> scene_ = std::make_shared<detail::SceneBuffers>();
  std::uint64_t written_generation_ = 0, written_place_generation_ = 0;  // the scene's, in the descriptors
  // Instances (upload(InstanceSet)): the objects the next pass places (GpuInstance each: its
  // transform, mesh and slot), the meshes' local volumes, and the placing pass's pipeline and set.
  vulkan::Buffer place_list_;
  std::size_t placing_ = 0;  // entries of place_list_ the pass being recorded places
  std::unique_ptr<vulkan::ComputePipeline> place_pipelines_[3];  // by BvKind
  std::unique_ptr<detail::PassResources> place_resources_;
  bool place_descriptors_dirty_ = true;
};

}  // namespace cullpipe::gpu
