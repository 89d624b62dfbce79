#pragma once
// What every culling pass (flat and hierarchical) needs besides its shaders: storage-range
// checks, growable buffers, one descriptor set, a command buffer with timestamps, and the
// barriers at the start and end of a recorded pass. Internal to src/cullpipe/gpu.
#include <vulkan/vulkan.h>

#include <bit>
#include <cstdint>
#include <cstring>
#include <functional>
#include <memory>
#include <span>
#include <string>
#include <type_traits>
#include <vector>

#include "cullpipe/cull/instances.hpp"
#include "cullpipe/geom/plane_bounds.hpp"
#include "cullpipe/gpu/gpu_culler.hpp"
#include "cullpipe/gpu/layout.hpp"
#include "cullpipe/vulkan/buffer.hpp"
#include "cullpipe/vulkan/compute_pipeline.hpp"
#include "cullpipe/vulkan/context.hpp"

namespace cullpipe::gpu::detail {

/// Format of every uniform texel buffer binding: four 32-bit words per texel, fetched as
/// integers (the shaders reinterpret them with uintBitsToFloat, so every bit pattern arrives
/// unchanged: no float conversion, denormal flush or NaN canonicalisation on the way).
inline constexpr VkFormat kTexelFormat = VK_FORMAT_R32G32B32A32_UINT;
inline constexpr VkDeviceSize kTexelBytes = 16;
/// Format of every storage texel buffer binding (records the shaders write and read back
/// within a pass): two 32-bit words per element.
inline constexpr VkFormat kRecordFormat = VK_FORMAT_R32G32_UINT;
inline constexpr VkDeviceSize kRecordBytes = 8;

/// Throws std::length_error naming `what`, its size and the device limit when `bytes` exceed
/// one storage buffer (maxStorageBufferRange).
/// Throws vulkan::Error naming `who` and the missing operations unless compute shaders on the
/// context's device support every subgroup operation in `needed`.
void check_subgroup_operations(const vulkan::Context& ctx, VkSubgroupFeatureFlags needed, const std::string& who);

void check_storage_range(const vulkan::Context& ctx, VkDeviceSize bytes, const std::string& what);

/// Bytes one texel buffer view covers: maxTexelBufferElements texels of kTexelBytes, at most
/// 2^31 - 1 texels (the shaders index with int).
VkDeviceSize texel_range(const vulkan::Context& ctx);
/// Throws std::length_error naming `what`, its size and the device limit when `bytes` exceed
/// texel_range().
void check_texel_range(const vulkan::Context& ctx, VkDeviceSize bytes, const std::string& what);

/// Throws vulkan::Error naming `who` unless the device reads kTexelFormat from uniform texel
/// buffers (a format the Vulkan spec makes mandatory; checked for a clear error anyway).
void check_texel_format(const vulkan::Context& ctx, const std::string& who);

/// Throws std::length_error naming `what`, its size and the device limit when `bytes` exceed one
/// storage texel buffer view of kRecordFormat (maxTexelBufferElements, at most 2^31 - 1).
void check_record_range(const vulkan::Context& ctx, VkDeviceSize bytes, const std::string& what);
/// Throws vulkan::Error naming `who` unless the device reads and writes kRecordFormat in storage
/// texel buffers (mandatory in Vulkan; checked for a clear error anyway).
void check_record_format(const vulkan::Context& ctx, const std::string& who);

/// Grows `buffer` to at least `bytes` (never shrinks). Sets `dirty` (descriptors must be
/// rewritten) before the old buffer is freed, so a failed allocation cannot leave a descriptor
/// pointing at a destroyed buffer.
void ensure_buffer(const vulkan::Context& ctx, vulkan::Buffer& buffer, VkDeviceSize bytes, VkBufferUsageFlags usage,
                   const char* what, bool& dirty, vulkan::MemoryUse use = vulkan::MemoryUse::Host);

/// Before a recorded pass: earlier work in the same command buffer or queue may still read its
/// outputs (indirect draws, vertex and compute shaders, copies); finish those reads first.
void record_entry_barrier(const vulkan::Context& ctx, VkCommandBuffer cmd);
/// After a pass: its writes become visible to indirect draws, vertex shaders (graphics
/// queues), later compute shaders and the host.
void record_exit_barrier(const vulkan::Context& ctx, VkCommandBuffer cmd);
/// Transfer writes (fills) before compute reads and writes.
void record_transfer_to_compute(VkCommandBuffer cmd);
/// Compute writes before compute reads and writes, and, with `indirect`, before indirect
/// dispatch arguments are read.
void record_compute_to_compute(VkCommandBuffer cmd, bool indirect = false);

/// Occlusion culling's inputs (CullOptions::pyramid): throws std::invalid_argument naming what is
/// wrong unless the pyramid is built and every one of `view_count` views has an occlusion view
/// that matches it (occlusion::check_view), and std::length_error when the occlusion views
/// exceed one texel buffer view. Nothing without a pyramid.
void check_occlusion(const vulkan::Context& ctx, const CullOptions& options, std::size_t view_count);
/// Each view's GpuOcclusionView from options.occlusion_views and the pyramid's levels.
void write_occlusion_views(const CullOptions& options, std::span<GpuOcclusionView> out);

/// The output buffers of a pass, as both culling shaders write them (see cull_types.h).
struct OutputBuffers {
  const vulkan::Buffer& counters;  ///< ViewCounters per view
  const vulkan::Buffer& classes;   ///< uint per view and object
  const vulkan::Buffer& visible;   ///< visible ids, `capacity` per view
  const vulkan::Buffer& draws;     ///< DrawCommand, `capacity` per view
};
/// Reads a completed pass's outputs back as the options ask (counts and test counts always).
/// The classes are stored per segment of `segment_objects` objects (0: one segment of all),
/// each segment as [view][object within the segment].
CullResult read_outputs(const OutputBuffers& buffers, std::size_t object_count, std::size_t view_count,
                        std::size_t capacity, const CullOptions& options, std::size_t segment_objects = 0);

/// Throws std::length_error naming `what` and the device limit when `bytes` exceed one memory
/// allocation (maxMemoryAllocationSize).
void check_allocation_size(const vulkan::Context& ctx, VkDeviceSize bytes, const std::string& what);

// ---- instances: the placing pass both cullers run (shaders/place_instances.comp) ----

/// Texels of one entry of the placing list: an instance the GPU places (boxes, spheres), or an
/// OBB placed on the host with its slot.
template <class Volume>
constexpr std::size_t entry_texels() {
  return std::is_same_v<Volume, Obb> ? OBB_ENTRY_TEXELS : INSTANCE_TEXELS;
}

/// Slot s of `set` as an entry of the placing list, its world volume written at `destination`
/// of the bounds (and centre) buffers: the slot itself for the flat pass, the object's place in
/// the tree order for the hierarchical one.
template <class Volume>
GpuInstance list_entry(const InstanceSet<Volume>& set, std::uint32_t s, std::uint32_t destination) {
  const Transform3x4& t = set.transforms()[s];
  return {{t.rows[0], t.rows[1], t.rows[2]},
          uvec4(set.mesh_indices()[s], std::bit_cast<std::uint32_t>(set.scales()[s]), destination, 0u)};
}

/// Slot s of `set` as the entry_texels<Volume>() texels of a placing list entry at `out`, its
/// world volume written at `destination`: boxes and spheres as list_entry; an OBB placed here
/// (InstanceSet::world_volume, in the GPU's rounding mode) with its settling bound, as
/// GpuCuller::upload(OBBs) sends it. Call under plane_bounds::NearestNoFlush.
template <class Volume>
void write_entry(const InstanceSet<Volume>& set, std::uint32_t s, std::uint32_t destination, uvec4* out) {
  if constexpr (std::is_same_v<Volume, Obb>) {
    const Obb world = set.world_volume(s);
    GpuObb packed = pack(world);
    packed.center.w = plane_bounds::obb_plane_bound(world);
    std::memcpy(out, &packed, sizeof(GpuObb));
    out[OBB_ENTRY_TEXELS - 1] = uvec4(0u, 0u, destination, 0u);
  } else {
    const GpuInstance entry = list_entry(set, s, destination);
    std::memcpy(out, &entry, sizeof(GpuInstance));
  }
}

/// The set's meshes' local volumes, packed as the placing pass reads them (and as update()
/// compares them, to recognise the set uploaded).
template <class Volume>
std::vector<std::uint32_t> mesh_words(const InstanceSet<Volume>& set) {
  std::vector<std::uint32_t> words;
  for (const Volume& v : set.meshes()) {
    const auto packed = pack(v);
    const auto* w = reinterpret_cast<const std::uint32_t*>(&packed);
    words.insert(words.end(), w, w + sizeof(packed) / sizeof(std::uint32_t));
  }
  return words;
}

/// Bindings of the placing pass read as uniform texel buffers (the list and the meshes).
inline constexpr std::uint32_t kPlaceTexelBindings = 1u << PLACE_BINDING_LIST | 1u << PLACE_BINDING_MESHES;
/// The placing pass's pipeline for a volume kind (OBB entries are copied into place).
std::unique_ptr<vulkan::ComputePipeline> make_place_pipeline(const vulkan::Context& ctx, BvKind kind);
/// Records the placing of list entries [0, count) in dispatches of at most `max_groups`
/// workgroups, with `set` bound, then a barrier before the passes that read what it wrote.
void record_placing(VkCommandBuffer cmd, const vulkan::ComputePipeline& pipeline, VkDescriptorSet set,
                    std::size_t count, std::uint32_t max_groups);

class PassResources;

/// One whole culling pass on `resources`' command buffer, as both cullers' cull() run it:
/// `prepare()`, then `record` between timestamps, submit and wait, then `read()`. Fills the
/// result's timings: GPU time between the timestamps, wall time around all of it.
CullResult timed_pass(PassResources& resources, const std::function<void()>& prepare,
                      const std::function<void(VkCommandBuffer, VkQueryPool)>& record,
                      const std::function<CullResult()>& read);

/// Descriptor sets of storage buffers (and uniform texel buffers, whose buffer views it owns),
/// a command buffer and a two-entry timestamp pool.
class PassResources {
 public:
  /// Bindings 0..binding_count-1 of `layout`: storage buffers, except bit i of
  /// `texel_bindings` makes binding i a uniform texel buffer of kTexelFormat, and bit i of
  /// `record_bindings` a storage texel buffer of kRecordFormat.
  PassResources(const vulkan::Context& ctx, VkDescriptorSetLayout layout, std::uint32_t binding_count,
                std::uint32_t texel_bindings = 0, std::uint32_t record_bindings = 0);
  ~PassResources();
  PassResources(const PassResources&) = delete;
  PassResources& operator=(const PassResources&) = delete;

  VkDescriptorSet set(std::size_t index = 0) const { return sets_.at(index); }
  std::size_t set_count() const { return sets_.size(); }
  /// Makes room for `count` descriptor sets (same layout); earlier sets are freed and must be
  /// written again when the count grows.
  void ensure_sets(std::size_t count);
  /// Binding i of set 0 = the whole of buffers[i].
  void write(std::span<const vulkan::Buffer* const> buffers);
  /// A part of a buffer bound to one binding (for a texel binding: a multiple of kTexelBytes, for
  /// a record binding of kRecordBytes; VK_WHOLE_SIZE for the rest of the buffer).
  struct Range {
    const vulkan::Buffer* buffer;
    VkDeviceSize offset = 0;
    VkDeviceSize size = VK_WHOLE_SIZE;
  };
  /// Binding i of set `index` = ranges[i].
  void write(std::size_t index, std::span<const Range> ranges);

  /// Records with `record(cmd, query_pool)` (query_pool is VK_NULL_HANDLE without timestamps;
  /// else the recorder writes timestamps 0 and 1 around its work), submits, waits, and
  /// returns the nanoseconds between the timestamps (0 without).
  double run(const std::function<void(VkCommandBuffer, VkQueryPool)>& record);

 private:
  void release();

  const vulkan::Context& ctx_;
  bool texel(std::uint32_t binding) const { return binding < 32 && (texel_bindings_ >> binding & 1u); }
  bool record(std::uint32_t binding) const { return binding < 32 && (record_bindings_ >> binding & 1u); }
  void destroy_views(std::size_t set);

  std::uint32_t binding_count_;
  std::uint32_t texel_bindings_;
  std::uint32_t record_bindings_;
  VkDescriptorSetLayout layout_;
  VkDescriptorPool pool_ = VK_NULL_HANDLE;
  std::vector<VkDescriptorSet> sets_;
  std::vector<std::vector<VkBufferView>> views_;  // per set, the texel and record bindings' views
  VkCommandBuffer cmd_ = VK_NULL_HANDLE;
  VkQueryPool query_pool_ = VK_NULL_HANDLE;
};

}  // namespace cullpipe::gpu::detail
