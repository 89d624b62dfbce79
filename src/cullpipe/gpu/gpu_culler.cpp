#include "cullpipe/gpu/gpu_culler.hpp"

#include <algorithm>
#include <bit>
#include <cstring>
#include <limits>
#include <stdexcept>
#include <string>
#include <system_error>

#include "cullpipe/core/thread_pool.hpp"
#include "cullpipe/geom/plane_bounds.hpp"
#include "cullpipe/gpu/layout.hpp"
#include "cullpipe/gpu/pass_support.hpp"
#include "cullpipe/vulkan/check.hpp"

// SPIR-V compiled from shaders/*.comp at build time (glslangValidator --vn).
#include "compact_scan.spv.h"
#include "compact_scatter.spv.h"
#include "cull_flat.spv.h"

namespace cullpipe::gpu {
namespace {

constexpr std::uint32_t kBindingCount = CULL_BINDING_COUNT;  // one descriptor set for every shader
// The volumes are read through a uniform texel buffer: on lavapipe a texel fetch loads a whole
// 16-byte texel per lane, where a storage-buffer load is a bounds-checked branch per lane and
// per component; on GPUs both are ordinary typed loads.
// The views and the AABBs' centre bounds too (see GpuFrustum, BINDING_CENTRES).
constexpr std::uint32_t kTexelBindings =
    1u << BINDING_BOUNDS | 1u << BINDING_VIEWS | 1u << BINDING_CENTRES | 1u << BINDING_OCCLUSION_VIEWS;
// Storage too: the placing pass writes instances' world volumes and centres into them.
constexpr VkBufferUsageFlags kBoundsUsage =
    VK_BUFFER_USAGE_UNIFORM_TEXEL_BUFFER_BIT | VK_BUFFER_USAGE_STORAGE_BUFFER_BIT;
// Scene buffers (volumes, centre bounds, meshes, draw templates): device-local, written by
// uploads straight where the host can map that memory, else through a staging copy.
constexpr VkBufferUsageFlags kSceneUsage = kBoundsUsage | VK_BUFFER_USAGE_TRANSFER_DST_BIT;
constexpr VkBufferUsageFlags kTemplateUsage = VK_BUFFER_USAGE_STORAGE_BUFFER_BIT | VK_BUFFER_USAGE_TRANSFER_DST_BIT;
constexpr vulkan::MemoryUse kScene = vulkan::MemoryUse::Device;
using detail::kPlaceTexelBindings;
constexpr std::size_t kUploadChunk = 16384;  // objects per upload task

std::uint32_t kind_index(BvKind k) { return static_cast<std::uint32_t>(k); }

}  // namespace

GpuCuller::GpuCuller(const vulkan::Context& ctx, const GpuCullerConfig& config) : ctx_(ctx) {
  const VkPhysicalDeviceLimits& limits = ctx_.properties().limits;
  group_size_ = std::max<std::uint32_t>(
      1, std::min({config.group_size, limits.maxComputeWorkGroupSize[0], limits.maxComputeWorkGroupInvocations}));
  detail::check_subgroup_operations(ctx_,
                                    VK_SUBGROUP_FEATURE_BASIC_BIT | VK_SUBGROUP_FEATURE_ARITHMETIC_BIT |
                                        VK_SUBGROUP_FEATURE_BALLOT_BIT | VK_SUBGROUP_FEATURE_SHUFFLE_BIT,
                                    "flat culling");
  detail::check_texel_format(ctx_, "flat culling");
  objects_per_invocation_ = std::clamp<std::uint32_t>(config.objects_per_invocation, 1, 32);
  max_segment_objects_ = config.max_segment_objects;
  upload_threads_ = config.upload_threads;
  max_groups_ = config.max_groups_per_dispatch
                    ? std::min(config.max_groups_per_dispatch, limits.maxComputeWorkGroupCount[0])
                    : limits.maxComputeWorkGroupCount[0];
  group_size_ = std::min(group_size_, MAX_CULL_GROUP_SIZE);
  // Every pipeline has the same set layout; the flat AABB one of default options (arrival
  // order, classes) is built now, for the descriptor set, the others on first use.
  static_assert(BV_KIND_AABB == 0 && BV_KIND_OBB == 1 && BV_KIND_SPHERE == 2, "BvKind order must match the shader");
  const vulkan::ComputePipeline& first = pipeline({.kind = BvKind::Aabb, .classes = true});
  resources_ = std::make_unique<detail::PassResources>(ctx_, first.set_layout(), kBindingCount, kTexelBindings);
}

const vulkan::ComputePipeline& GpuCuller::pipeline(PipelineKey key) {
  using Shader = PipelineKey::Shader;
  if (key.shader != Shader::Cull)
    key.kind = BvKind::Aabb, key.ordered = false, key.classes = false, key.occlusion_texels = 0;
  if (key.ordered) key.classes = true;  // the scatter pass reads them
  return pipelines_.get(key, [&] {
    std::span<const std::uint32_t> spirv;
    std::string name;
    if (key.shader == Shader::Cull) {
      spirv = cullpipe_cull_flat_spv;
      name = "flat cull (" + std::string(to_string(key.kind)) + (key.ordered ? ", ordered" : "") +
             (key.draws ? ", draws" : "") + (key.classes ? ", classes" : "") +
             (key.occlusion_texels ? ", occlusion" : "") + ")";
    } else if (key.shader == Shader::CompactScan) {
      spirv = cullpipe_compact_scan_spv;
      name = "ordered compaction scan";
    } else {
      spirv = cullpipe_compact_scatter_spv;
      name = std::string("ordered compaction scatter") + (key.draws ? " (draws)" : "");
    }
    // Specialization constants: 0 kind, 1 group size, 2 ordered, 3 draws, 4 objects per
    // invocation (every pass: the ordered passes' unit is a workgroup's run of objects), 5 classes,
    // 6 occlusion, 7 texels per axis of the occlusion test, 10 its refining texels (8, 9 unused).
    std::uint32_t spec[11] = {kind_index(key.kind),    group_size_,          key.ordered ? 1u : 0u, key.draws ? 1u : 0u,
                              objects_per_invocation_, key.classes ? 1u : 0u};
    detail::set_occlusion_constants(spec, key.occlusion_texels);
    return std::make_unique<vulkan::ComputePipeline>(
        ctx_,
        vulkan::ComputePipelineDesc{spirv, kBindingCount, sizeof(FlatCullParams), spec, name.c_str(), kTexelBindings});
  });
}

GpuCuller::~GpuCuller() = default;

// Every upload writes straight into the scene buffers where the host maps them (unified memory),
// in chunks on the upload pool, else into staging buffers copied into them; buffers are kept
// and reused, with no fresh allocation whose pages fault in on every upload (faulting in a
// large buffer costs more than culling it). `fill(first, end)` writes objects [first, end);
// with `centres` (AABBs) the centre-bound buffer is sized for them too.
template <class Fill>
void GpuCuller::upload_volumes(BvKind kind, std::size_t count, std::size_t bytes_per_object, bool centres,
                               Fill&& fill) {
  const std::string what = std::to_string(count) + " " + std::string(to_string(kind)) + " volumes";
  if (count > std::numeric_limits<std::uint32_t>::max())
    throw std::length_error(what + ": object ids are 32-bit (at most 4294967295 objects)");
  const VkDeviceSize bytes = VkDeviceSize(count) * bytes_per_object,
                     centre_bytes = VkDeviceSize(count) * sizeof(glm::vec4);
  // Both sizes are checked before anything changes: a scene that cannot fit keeps the old one.
  detail::check_allocation_size(ctx_, bytes, what);
  if (centres) detail::check_allocation_size(ctx_, centre_bytes, what + " (centre bounds)");
  scene_->object_count = 0;  // stays 0 if an allocation below fails: no pass on half-written buffers
  scene_->instanced = false;
  scene_->instance_capacity = 0;
  scene_->pending_slots.clear();  // placements queued for an earlier scene do not apply
  scene_->pending_entries.clear();
  scene_->bytes_per_object = bytes_per_object;
  descriptors_dirty_ = true;  // segment ranges depend on the object size and count
  ++scene_->generation;
  if (centres)
    detail::ensure_buffer(ctx_, scene_->centres, centre_bytes, kSceneUsage, "centre bound buffer", descriptors_dirty_,
                          kScene);
  detail::ensure_buffer(ctx_, scene_->bounds, bytes, kSceneUsage, "bounds buffer", descriptors_dirty_, kScene);
  // The fill writes at upload_bounds_ and upload_centres_: the scene buffers themselves where
  // mapped, else staging buffers copied into them afterwards.
  const bool direct = scene_->bounds.mapped() && (!centres || scene_->centres.mapped());
  vulkan::Buffer bounds_staging, centres_staging;
  if (!direct) {
    bounds_staging = vulkan::Buffer(ctx_, std::max<VkDeviceSize>(bytes, 16), VK_BUFFER_USAGE_TRANSFER_SRC_BIT,
                                    "bounds staging buffer");
    if (centres)
      centres_staging = vulkan::Buffer(ctx_, std::max<VkDeviceSize>(centre_bytes, 16), VK_BUFFER_USAGE_TRANSFER_SRC_BIT,
                                       "centre bound staging buffer");
  }
  upload_bounds_ = direct ? scene_->bounds.data() : bounds_staging.data();
  upload_centres_ = centres ? (direct ? scene_->centres.data() : centres_staging.data()) : nullptr;
  run_upload_tasks(count, fill);
  if (!direct && bytes) {
    vulkan::copy_buffer(ctx_, bounds_staging, scene_->bounds, bytes);
    if (centres) vulkan::copy_buffer(ctx_, centres_staging, scene_->centres, centre_bytes);
  }
  scene_->kind = kind;
  scene_->object_count = count;
}

template <class Fill>
void GpuCuller::run_upload_tasks(std::size_t count, Fill&& fill) {
  const std::size_t tasks = (count + kUploadChunk - 1) / kUploadChunk;
  auto task = [&](std::size_t t) { fill(t * kUploadChunk, std::min(count, (t + 1) * kUploadChunk)); };
  if (tasks > 1 && upload_threads_ != 1 && !upload_pool_) {
    try {
      upload_pool_ = std::make_unique<ThreadPool>(upload_threads_);
    } catch (const std::system_error&) {  // no threads to be had: this upload runs on the caller
    }
  }
  if (tasks > 1 && upload_pool_) {
    upload_pool_->parallel_for(tasks, task);
  } else {
    for (std::size_t t = 0; t < tasks; ++t) task(t);
  }
}

void GpuCuller::upload(std::span<const Aabb> volumes) {
  // The culling passes first test each box's centre against its bound (one texel; the bounds
  // of geom/plane_bounds.hpp, as the CPU kernels use them; proof: docs/numerics.md, Settling
  // bounds); only the boxes it leaves open are read in full.
  upload_volumes(BvKind::Aabb, volumes.size(), sizeof(GpuAabb), true, [&](std::size_t first, std::size_t end) {
    GpuAabb* out = static_cast<GpuAabb*>(upload_bounds_);
    for (std::size_t i = first; i < end; ++i) out[i] = pack(volumes[i]);
    plane_bounds::aabb_centre_bounds(
        volumes.subspan(first, end - first),
        std::span<glm::vec4>(static_cast<glm::vec4*>(upload_centres_) + first, end - first));
  });
}

void GpuCuller::upload(std::span<const Obb> volumes) {
  upload_volumes(BvKind::Obb, volumes.size(), sizeof(GpuObb), false, [&](std::size_t first, std::size_t end) {
    GpuObb* out = static_cast<GpuObb*>(upload_bounds_);
    constexpr std::size_t kBatch = 256;  // bounds on the stack (upload threads may be small-stack job threads)
    float bounds[kBatch];
    for (std::size_t b = first; b < end; b += kBatch) {
      const std::size_t count = std::min(kBatch, end - b);
      plane_bounds::obb_plane_bounds(volumes.subspan(b, count), std::span<float>(bounds, count));
      for (std::size_t i = b; i < b + count; ++i) {
        GpuObb o = pack(volumes[i]);
        o.center.w = bounds[i - b];  // settles most boxes on the centre texel alone
        out[i] = o;                  // one whole store to mapped (perhaps write-combined) memory
      }
    }
  });
}

void GpuCuller::upload(std::span<const Sphere> volumes) {
  upload_volumes(BvKind::Sphere, volumes.size(), sizeof(GpuSphere), false, [&](std::size_t first, std::size_t end) {
    GpuSphere* out = static_cast<GpuSphere*>(upload_bounds_);
    for (std::size_t i = first; i < end; ++i) out[i] = pack(volumes[i]);
  });
}

using detail::mesh_words;

template <class Volume>
void GpuCuller::upload_instances(const InstanceSet<Volume>& set) {
  constexpr BvKind kind = kind_of<Volume>();
  const std::size_t count = set.size();
  // Room for growth by later updates: half again, so a scene that grows a little at a time
  // reallocates (and sends every object again) a logarithmic number of times.
  const std::size_t capacity =
      std::max<std::size_t>({count, scene_->instance_capacity > count ? scene_->instance_capacity : 0, 256});
  const std::string what = std::to_string(capacity) + " " + std::string(to_string(kind)) + " instances";
  if (capacity > std::numeric_limits<std::uint32_t>::max())
    throw std::length_error(what + ": object ids are 32-bit (at most 4294967295 objects)");
  const std::size_t bytes_per_object = kind == BvKind::Aabb  ? sizeof(GpuAabb)
                                       : kind == BvKind::Obb ? sizeof(GpuObb)
                                                             : sizeof(GpuSphere);
  constexpr std::size_t texels = detail::entry_texels<Volume>();
  const std::vector<std::uint32_t> words = mesh_words(set);
  const VkDeviceSize bound_bytes = VkDeviceSize(capacity) * bytes_per_object,
                     centre_bytes = kind == BvKind::Aabb ? VkDeviceSize(capacity) * sizeof(glm::vec4) : 0,
                     list_bytes = VkDeviceSize(capacity) * texels * detail::kTexelBytes,
                     mesh_bytes = VkDeviceSize(words.size()) * sizeof(std::uint32_t);
  // Every check before anything changes. The placing pass binds whole buffers: the outputs as one
  // storage buffer range each, the inputs as one texel buffer view each.
  detail::check_allocation_size(ctx_, list_bytes, what);
  detail::check_storage_range(ctx_, bound_bytes, what + " (world volumes written by the placing pass)");
  detail::check_storage_range(ctx_, centre_bytes, what + " (centre bounds written by the placing pass)");
  detail::check_texel_range(ctx_, list_bytes, what + " (placing list)");
  detail::check_texel_range(ctx_, mesh_bytes, std::to_string(set.meshes().size()) + " meshes");
  ensure_place_resources(kind);  // the pipeline built now, not while recording

  scene_->object_count = 0;  // stays 0 if an allocation below fails: no pass on half-written buffers
  scene_->instanced = false;
  scene_->pending_slots.clear();
  scene_->pending_entries.clear();
  scene_->bytes_per_object = bytes_per_object;
  descriptors_dirty_ = place_descriptors_dirty_ = true;
  ++scene_->generation;
  if (kind == BvKind::Aabb)
    detail::ensure_buffer(ctx_, scene_->centres, centre_bytes, kSceneUsage, "centre bound buffer", descriptors_dirty_,
                          kScene);
  detail::ensure_buffer(ctx_, scene_->bounds, bound_bytes, kSceneUsage, "bounds buffer", descriptors_dirty_, kScene);
  bool unused = false;
  detail::ensure_buffer(ctx_, scene_->meshes, mesh_bytes, kSceneUsage, "mesh volume buffer", unused, kScene);
  vulkan::write_through_staging(ctx_, scene_->meshes, mesh_bytes,
                                [&](void* host) { std::memcpy(host, words.data(), mesh_bytes); });
  scene_->mesh_words = words;
  // Every object, placed by whichever sharer records next.
  scene_->pending_slots.resize(count);
  scene_->pending_entries.resize(count * texels);
  scene_->entry_texels = texels;
  run_upload_tasks(count, [&](std::size_t first, std::size_t end) {
    const plane_bounds::NearestNoFlush mode;  // (OBBs are placed here)
    for (std::size_t i = first; i < end; ++i) {
      const auto s = static_cast<std::uint32_t>(i);
      scene_->pending_slots[i] = s;
      detail::write_entry(set, s, s, &scene_->pending_entries[i * texels]);
    }
  });
  scene_->instance_capacity = capacity;
  scene_->kind = kind;
  scene_->object_count = count;
  scene_->instanced = true;
}

template <class Volume>
void GpuCuller::update_instances(const InstanceSet<Volume>& set, std::span<const std::uint32_t> slots) {
  if (!scene_->instanced || scene_->kind != kind_of<Volume>())
    throw std::invalid_argument("GpuCuller::update: no " + std::string(to_string(kind_of<Volume>())) +
                                " instances were uploaded (call upload(instances) first)");
  if (mesh_words(set) != scene_->mesh_words)
    throw std::invalid_argument("GpuCuller::update: the set's " + std::to_string(set.meshes().size()) +
                                " meshes are not the ones uploaded (upload the set instead)");
  set.check_slots(slots, "GpuCuller::update");
  if (set.size() > scene_->instance_capacity) {
    // Grown past the buffers: larger ones by half again, every object sent and placed.
    const std::size_t old = scene_->instance_capacity;
    scene_->instance_capacity = std::max(set.size(), old + old / 2);
    try {
      upload_instances(set);
    } catch (...) {
      scene_->instance_capacity = old;
      throw;
    }
    return;
  }
  // The scene's queue: what earlier updates (through any culler sharing the scene) sent and no
  // pass has placed yet, with these slots, each once (two entries for one slot would race), as
  // the set has it now, without slots past its end. Entries are built in order (on the upload
  // threads); the next pass, whichever sharer records it, copies them into its placing list.
  std::vector<std::uint32_t> pending;
  const std::vector<std::uint32_t>& queued = scene_->pending_slots;
  if (queued.empty()) {
    pending.assign(slots.begin(), slots.end());
  } else {
    pending.reserve(queued.size() + slots.size());
    std::set_union(queued.begin(), queued.end(), slots.begin(), slots.end(), std::back_inserter(pending));
    pending.erase(std::lower_bound(pending.begin(), pending.end(), static_cast<std::uint32_t>(set.size())),
                  pending.end());
  }
  // Entries rebuilt for the whole queue, into the scene's own storage (kept from frame to frame:
  // a fresh vector per update would fault its pages in each time). Only the resize can throw,
  // and it leaves the entries as they were.
  constexpr std::size_t texels = detail::entry_texels<Volume>();
  std::vector<uvec4>& entries = scene_->pending_entries;
  entries.resize(pending.size() * texels);
  run_upload_tasks(pending.size(), [&](std::size_t first, std::size_t end) {
    const plane_bounds::NearestNoFlush mode;  // (OBBs are placed here)
    for (std::size_t k = first; k < end; ++k) detail::write_entry(set, pending[k], pending[k], &entries[k * texels]);
  });
  if (set.size() != scene_->object_count) ++scene_->generation;  // segment ranges follow the object count
  scene_->object_count = set.size();
  scene_->pending_slots = std::move(pending);
}

void GpuCuller::ensure_place_resources(BvKind kind) {
  const vulkan::ComputePipeline& place = place_pipeline(kind);
  if (!place_resources_)
    place_resources_ =
        std::make_unique<detail::PassResources>(ctx_, place.set_layout(), PLACE_BINDING_COUNT, kPlaceTexelBindings);
}

template <class Volume>
void GpuCuller::reserve(const InstanceSet<Volume>& set, std::size_t objects) {
  if (!scene_->instanced || scene_->kind != kind_of<Volume>())
    throw std::invalid_argument("GpuCuller::reserve_instances: no " + std::string(to_string(kind_of<Volume>())) +
                                " instances were uploaded (call upload(instances) first)");
  if (objects <= scene_->instance_capacity) return;
  const std::size_t old = scene_->instance_capacity;
  scene_->instance_capacity = objects;
  try {
    upload_instances(set);
  } catch (...) {
    scene_->instance_capacity = old;
    throw;
  }
}

void GpuCuller::reserve_instances(const InstanceSet<Aabb>& instances, std::size_t objects) {
  reserve(instances, objects);
}
void GpuCuller::reserve_instances(const InstanceSet<Obb>& instances, std::size_t objects) {
  reserve(instances, objects);
}
void GpuCuller::reserve_instances(const InstanceSet<Sphere>& instances, std::size_t objects) {
  reserve(instances, objects);
}

void GpuCuller::share_scene(const GpuCuller& other) {
  if (&other.ctx_ != &ctx_)
    throw std::invalid_argument("GpuCuller::share_scene: the cullers are on different contexts");
  if (other.scene_ == scene_) return;
  scene_ = other.scene_;
  descriptors_dirty_ = place_descriptors_dirty_ = true;
}

void GpuCuller::upload(const InstanceSet<Aabb>& instances) { upload_instances(instances); }
void GpuCuller::upload(const InstanceSet<Obb>& instances) { upload_instances(instances); }
void GpuCuller::upload(const InstanceSet<Sphere>& instances) { upload_instances(instances); }
void GpuCuller::update(const InstanceSet<Aabb>& instances, std::span<const std::uint32_t> slots) {
  update_instances(instances, slots);
}
void GpuCuller::update(const InstanceSet<Obb>& instances, std::span<const std::uint32_t> slots) {
  update_instances(instances, slots);
}
void GpuCuller::update(const InstanceSet<Sphere>& instances, std::span<const std::uint32_t> slots) {
  update_instances(instances, slots);
}

const vulkan::ComputePipeline& GpuCuller::place_pipeline(BvKind kind) {
  auto& slot = place_pipelines_[kind_index(kind)];
  if (!slot) slot = detail::make_place_pipeline(ctx_, kind);
  return *slot;
}

void GpuCuller::prepare_placement() {
  // The scene's queued placements go into this culler's own list (a sharer's list may still be
  // read by its pass in flight), before anything is recorded.
  placing_ = 0;
  if (!scene_->instanced || scene_->pending_slots.empty()) return;
  const std::size_t n = scene_->pending_slots.size(), entry_bytes = scene_->entry_texels * detail::kTexelBytes;
  ensure_place_resources(scene_->kind);
  const VkDeviceSize bytes = VkDeviceSize(std::max(n, scene_->instance_capacity)) * entry_bytes;
  detail::check_texel_range(ctx_, bytes, std::to_string(n) + " objects to place");
  detail::ensure_buffer(ctx_, place_list_, bytes, kBoundsUsage, "placing list buffer", place_descriptors_dirty_);
  std::memcpy(place_list_.data(), scene_->pending_entries.data(), n * entry_bytes);
  if (place_descriptors_dirty_ || written_place_generation_ != scene_->generation) {
    // Within one texel buffer view and one storage buffer range (buffers kept from a larger
    // scene may be bigger).
    using Range = detail::PassResources::Range;
    const VkDeviceSize storage = ctx_.properties().limits.maxStorageBufferRange;
    auto texels = [&](const vulkan::Buffer& b) {
      return Range{&b, 0, std::min(b.size(), detail::texel_range(ctx_)) / detail::kTexelBytes * detail::kTexelBytes};
    };
    auto whole = [&](const vulkan::Buffer& b) { return Range{&b, 0, std::min(b.size(), storage)}; };
    const Range ranges[PLACE_BINDING_COUNT] = {texels(place_list_), texels(scene_->meshes), whole(scene_->bounds),
                                               whole(scene_->centres)};
    place_resources_->write(0, ranges);
    place_descriptors_dirty_ = false;
    written_place_generation_ = scene_->generation;
  }
  placing_ = n;
}

void GpuCuller::record_placement(VkCommandBuffer cmd) {
  if (placing_ == 0) return;
  const vulkan::ComputePipeline& place = place_pipeline(scene_->kind);
  detail::record_placing(cmd, place, place_resources_->set(), placing_, max_groups_);
  // Recorded: no later pass of any sharer places them again.
  placing_ = 0;
  scene_->pending_slots.clear();
  scene_->pending_entries.clear();  // its storage is kept for the next frame's
}

void GpuCuller::upload_draws(std::span<const DrawCommand> templates) {
  const VkDeviceSize bytes = VkDeviceSize(templates.size()) * sizeof(DrawCommand);
  detail::check_allocation_size(ctx_, bytes, std::to_string(templates.size()) + " draw templates");
  scene_->template_count = 0;
  descriptors_dirty_ = true;  // segment ranges of the templates
  ++scene_->generation;
  detail::ensure_buffer(ctx_, scene_->templates, bytes, kTemplateUsage, "draw template buffer", descriptors_dirty_,
                        kScene);
  vulkan::write_through_staging(ctx_, scene_->templates, bytes,
                                [&](void* host) { std::memcpy(host, templates.data(), bytes); });
  scene_->template_count = templates.size();
}

void GpuCuller::ensure_outputs(std::size_t view_count, std::size_t visible_capacity, bool draws, bool ordered,
                               bool may_grow) {
  const VkDeviceSize outputs = VkDeviceSize(scene_->object_count) * view_count * sizeof(std::uint32_t);
  const VkDeviceSize visible = VkDeviceSize(visible_capacity) * view_count * sizeof(std::uint32_t);
  const VkDeviceSize draw_bytes = draws ? VkDeviceSize(visible_capacity) * view_count * sizeof(DrawCommand) : 0;
  const VkDeviceSize groups = ordered ? group_count_bytes(view_count) : 0;
  // Classes are bound per segment (plan_segments keeps each within range); all of them must
  // still fit one allocation.
  detail::check_allocation_size(
      ctx_, outputs,
      std::to_string(view_count) + " views x " + std::to_string(scene_->object_count) + " objects of output");
  detail::check_storage_range(
      ctx_, visible, std::to_string(view_count) + " views x " + std::to_string(visible_capacity) + " visible ids");
  detail::check_storage_range(
      ctx_, draw_bytes, std::to_string(view_count) + " views x " + std::to_string(visible_capacity) + " draw commands");
  detail::check_texel_range(ctx_, VkDeviceSize(view_count) * sizeof(GpuFrustum), std::to_string(view_count) + " views");
  detail::check_storage_range(
      ctx_, groups,
      std::to_string(view_count) + " views x " + std::to_string(scene_->object_count) + " objects of workgroup counts");
  // What an engine binds or reads (draws, counts, the visible list, the classes) is never
  // replaced by record(): it must have been made large enough first (reserve_outputs, or an
  // earlier pass as large), so its handles stay the ones the engine recorded.
  if (!may_grow) {
    auto fits = [&](const vulkan::Buffer& b, VkDeviceSize bytes, const char* what, const std::string& holds) {
      if (b && b.size() >= std::max<VkDeviceSize>(bytes, 1)) return;
      throw std::logic_error("GpuCuller::record: the " + std::string(what) + " (" + std::to_string(b ? b.size() : 0) +
                             " bytes) cannot hold " + holds + " (" + std::to_string(bytes) +
                             " bytes); record never replaces the outputs an engine binds: call reserve_outputs(" +
                             std::to_string(view_count) + ", options) first");
    };
    const std::string per_view = std::to_string(view_count) + " views x " + std::to_string(visible_capacity);
    fits(classes_, outputs, "classification buffer",
         std::to_string(view_count) + " views x " + std::to_string(scene_->object_count) + " objects of classes");
    if (!engine_visible_) fits(visible_, visible, "visible-id buffer", per_view + " visible ids");
    if (!engine_counters_)
      fits(counters_, view_count * sizeof(ViewCounters), "counter buffer",
           std::to_string(view_count) + " views' counters");
    if (draws && !engine_draws_) fits(draws_, draw_bytes, "draw buffer", per_view + " draw commands");
  }
  constexpr VkBufferUsageFlags storage = VK_BUFFER_USAGE_STORAGE_BUFFER_BIT;
  bool& dirty = descriptors_dirty_;
  // The engine's buffers are used as they are: too small is an error, never a new buffer.
  auto engine_fits = [&](const vulkan::Buffer& b, VkDeviceSize bytes, const char* what, const std::string& holds) {
    if (b.size() >= bytes) return;
    throw std::length_error("the engine's " + std::string(what) + " (" + std::to_string(b.size()) +
                            " bytes) cannot hold " + holds + " (" + std::to_string(bytes) + " bytes)");
  };
  const std::string per_view = std::to_string(view_count) + " views x " + std::to_string(visible_capacity);
  if (engine_visible_) engine_fits(visible_, visible, "visible-id buffer", per_view + " visible ids");
  if (engine_counters_)
    engine_fits(counters_, view_count * sizeof(ViewCounters), "counter buffer",
                std::to_string(view_count) + " views' counters");
  if (engine_draws_ && draws) engine_fits(draws_, draw_bytes, "draw buffer", per_view + " draw commands");
  detail::ensure_buffer(ctx_, classes_, outputs, storage, "classification buffer", dirty);
  if (!engine_visible_) detail::ensure_buffer(ctx_, visible_, visible, storage, "visible-id buffer", dirty);
  if (!engine_counters_)
    detail::ensure_buffer(ctx_, counters_, view_count * sizeof(ViewCounters),
                          storage | VK_BUFFER_USAGE_TRANSFER_DST_BIT | VK_BUFFER_USAGE_INDIRECT_BUFFER_BIT,
                          "counter buffer", dirty);
  detail::ensure_buffer(ctx_, views_, view_count * sizeof(GpuFrustum), kBoundsUsage, "view buffer", dirty);
  if (!engine_draws_)
    detail::ensure_buffer(ctx_, draws_, draw_bytes, storage | VK_BUFFER_USAGE_INDIRECT_BUFFER_BIT, "draw buffer",
                          dirty);
  detail::ensure_buffer(ctx_, scene_->templates, 0, kTemplateUsage, "draw template buffer", dirty, kScene);
  detail::ensure_buffer(ctx_, group_counts_, groups, storage | VK_BUFFER_USAGE_TRANSFER_DST_BIT, "group count buffer",
                        dirty);
}

VkDeviceSize GpuCuller::group_count_bytes(std::size_t view_count) const {
  // Ordered passes: a visible and an INSIDE count per workgroup and view.
  return 2 * VkDeviceSize(vulkan::group_count(scene_->object_count, group_size_ * objects_per_invocation_)) *
         view_count * sizeof(std::uint32_t);
}

GpuCuller::SegmentPlan GpuCuller::plan_segments(std::size_t view_count, bool ordered) const {
  // Objects per segment: as many as every per-object binding allows within one storage buffer
  // range (the bounds: one texel buffer view), rounded down to a multiple of 256 so every segment's offset in every
  // buffer is a multiple of 256 x (bytes per object) >= 1 KiB, and so of any minStorageBufferOffsetAlignment (at most
  // 256 bytes by the Vulkan spec).
  const VkDeviceSize range = ctx_.properties().limits.maxStorageBufferRange;
  std::size_t s = scene_->object_count;
  s = std::min<std::size_t>(s, detail::texel_range(ctx_) / scene_->bytes_per_object);
  s = std::min<std::size_t>(s, range / (sizeof(std::uint32_t) * std::max<std::size_t>(view_count, 1)));
  if (scene_->template_count) s = std::min<std::size_t>(s, range / sizeof(DrawCommand));
  if (max_segment_objects_) s = std::min(s, max_segment_objects_);
  if (s < scene_->object_count) s = std::max<std::size_t>(256, s / 256 * 256);
  const SegmentPlan plan{s, scene_->object_count && s ? (scene_->object_count + s - 1) / s : 1};
  if (plan.count > 1 && ordered)
    throw std::length_error("object-order output (CullOptions::ordered) is limited to one storage buffer of objects; " +
                            std::to_string(scene_->object_count) + " objects need " + std::to_string(plan.count) +
                            " segments of " + std::to_string(s) + " on " + ctx_.info().name + " (use arrival order)");
  return plan;
}

void GpuCuller::update_descriptors() {
  if (!descriptors_dirty_ && written_generation_ == scene_->generation &&
      written_segment_objects_ == segment_objects_ && written_view_count_ == last_view_count_ &&
      resources_->set_count() >= segment_count_ && written_pyramid_ == pyramid_generation_)
    return;
  static_assert(BINDING_BOUNDS == 0 && BINDING_CLASSES == 1 && BINDING_VISIBLE == 2 && BINDING_COUNTERS == 3 &&
                BINDING_VIEWS == 4 && BINDING_DRAW_TEMPLATES == 5 && BINDING_DRAWS == 6 && BINDING_GROUP_COUNTS == 7 &&
                BINDING_CENTRES == 8 && BINDING_PYRAMID == 9 && BINDING_OCCLUSION_VIEWS == 10);
  resources_->ensure_sets(segment_count_);
  const std::size_t views = last_view_count_;
  for (std::size_t seg = 0; seg < segment_count_; ++seg) {
    using Range = detail::PassResources::Range;
    // Whole buffers, but never more than one storage buffer range (a buffer grown for an
    // earlier, larger scene may be bigger).
    const VkDeviceSize range = ctx_.properties().limits.maxStorageBufferRange;
    auto whole = [&](const vulkan::Buffer& b) { return Range{&b, 0, std::min<VkDeviceSize>(b.size(), range)}; };
    // Texel views: whole texels within one texel buffer view.
    auto texels = [&](const vulkan::Buffer& b) {
      return Range{
          &b, 0,
          std::min<VkDeviceSize>(b.size(), detail::texel_range(ctx_)) / detail::kTexelBytes * detail::kTexelBytes};
    };
    Range ranges[kBindingCount] = {texels(scene_->bounds), whole(classes_),         whole(visible_),
                                   whole(counters_),       texels(views_),          whole(scene_->templates),
                                   whole(draws_),          whole(group_counts_),    texels(scene_->centres),
                                   whole(*pyramid_),       texels(occlusion_views_)};
    if (segment_count_ > 1) {  // one segment binds whole buffers
      const VkDeviceSize first = VkDeviceSize(seg) * segment_objects_;
      const VkDeviceSize n = std::min<VkDeviceSize>(segment_objects_, scene_->object_count - first);
      ranges[BINDING_BOUNDS] = {&scene_->bounds, first * scene_->bytes_per_object, n * scene_->bytes_per_object};
      ranges[BINDING_CLASSES] = {&classes_, first * views * sizeof(std::uint32_t), n * views * sizeof(std::uint32_t)};
      if (scene_->kind == BvKind::Aabb)
        ranges[BINDING_CENTRES] = {&scene_->centres, first * sizeof(glm::vec4), n * sizeof(glm::vec4)};
      if (scene_->template_count == scene_->object_count)
        ranges[BINDING_DRAW_TEMPLATES] = {&scene_->templates, first * sizeof(DrawCommand), n * sizeof(DrawCommand)};
    }
    resources_->write(seg, ranges);
  }
  written_segment_objects_ = segment_objects_;
  written_view_count_ = views;
  written_pyramid_ = pyramid_generation_;
  written_generation_ = scene_->generation;
  descriptors_dirty_ = false;
}

void GpuCuller::use_engine_outputs(const EngineOutputs& o) {
  use_own_outputs();
  if (o.draws) draws_ = vulkan::Buffer::borrow(o.draws, o.draws_size, const_cast<void*>(o.draws_host));
  if (o.counters) counters_ = vulkan::Buffer::borrow(o.counters, o.counters_size, const_cast<void*>(o.counters_host));
  if (o.visible) visible_ = vulkan::Buffer::borrow(o.visible, o.visible_size, const_cast<void*>(o.visible_host));
  engine_draws_ = o.draws != VK_NULL_HANDLE;
  engine_counters_ = o.counters != VK_NULL_HANDLE;
  engine_visible_ = o.visible != VK_NULL_HANDLE;
  descriptors_dirty_ = true;
}

void GpuCuller::use_own_outputs() {
  // A borrowed buffer is forgotten, not destroyed; cullpipe's own are made again as passes need.
  if (engine_draws_) draws_ = vulkan::Buffer();
  if (engine_counters_) counters_ = vulkan::Buffer();
  if (engine_visible_) visible_ = vulkan::Buffer();
  engine_draws_ = engine_counters_ = engine_visible_ = false;
  descriptors_dirty_ = true;
}

void GpuCuller::reserve_outputs(std::size_t view_count, const CullOptions& options, std::size_t objects) {
  if (view_count == 0) throw std::invalid_argument("GpuCuller::reserve_outputs: no views");
  // For `objects` objects (a scene that will grow to it), or the scene as it is.
  const std::size_t current = scene_->object_count;
  scene_->object_count = std::max(current, objects);
  try {
    const std::size_t capacity = options.visible_capacity ? options.visible_capacity : scene_->object_count;
    plan_segments(view_count, options.ordered);  // throws where a pass could not run
    ensure_outputs(view_count, capacity, options.draws, options.ordered, true);
  } catch (...) {
    scene_->object_count = current;
    throw;
  }
  scene_->object_count = current;
}

void GpuCuller::prepare(std::span<const Frustum> views, const CullOptions& options, bool may_grow) {
  const std::size_t capacity = options.visible_capacity ? options.visible_capacity : scene_->object_count;
  if (options.draws && scene_->template_count != scene_->object_count)
    throw std::invalid_argument("draw commands requested, but " + std::to_string(scene_->template_count) +
                                " draw templates were uploaded for " + std::to_string(scene_->object_count) +
                                " objects (call upload_draws)");
  if (views.size() > ctx_.properties().limits.maxComputeWorkGroupCount[1])
    throw std::length_error(std::to_string(views.size()) + " views exceed the device's dispatch limit of " +
                            std::to_string(ctx_.properties().limits.maxComputeWorkGroupCount[1]));
  detail::check_occlusion(ctx_, options, views.size());
  bool created = false;  // a scene's first pass, before any upload
  detail::ensure_buffer(ctx_, scene_->bounds, 0, kSceneUsage, "bounds buffer", created, kScene);
  detail::ensure_buffer(ctx_, scene_->centres, 0, kSceneUsage, "centre bound buffer", created, kScene);
  detail::ensure_buffer(ctx_, scene_->templates, 0, kTemplateUsage, "draw template buffer", created, kScene);
  if (created) ++scene_->generation;
  detail::ensure_buffer(ctx_, no_pyramid_, 16, VK_BUFFER_USAGE_STORAGE_BUFFER_BIT, "empty pyramid buffer",
                        descriptors_dirty_);
  detail::ensure_buffer(ctx_, occlusion_views_, (options.pyramid ? views.size() : 1) * sizeof(GpuOcclusionView),
                        kBoundsUsage, "occlusion view buffer", descriptors_dirty_);
  // Nothing of the pass's state changes until every check and allocation has passed.
  const SegmentPlan plan = plan_segments(views.size(), options.ordered);
  ensure_outputs(views.size(), capacity, options.draws, options.ordered, may_grow);
  segment_objects_ = plan.objects;
  segment_count_ = plan.count;
  last_view_count_ = views.size();
  last_object_count_ = scene_->object_count;  // a culler sharing the scene may change it before the readback
  pyramid_ = options.pyramid ? &options.pyramid->texels() : &no_pyramid_;
  pyramid_generation_ = options.pyramid ? options.pyramid->generation() : 0;
  update_descriptors();
  prepare_placement();
  if (options.pyramid) detail::write_occlusion_views(options, occlusion_views_.as<GpuOcclusionView>());
  auto gpu_views = views_.as<GpuFrustum>();
  for (std::size_t v = 0; v < views.size(); ++v) {
    gpu_views[v] = pack(views[v]);
    gpu_views[v].settle_margin = plane_bounds::settle_margin(views[v]);
  }
  last_capacity_ = capacity;
  last_options_ = options;
  // Build every pipeline the pass needs now, not while recording.
  if (!options.ordered) {
    pipeline(arrival_key(options));
  } else {
    pipeline(ordered_key(options));
    pipeline({.shader = PipelineKey::Shader::CompactScan});
    pipeline(scatter_key(options));
  }
}

void GpuCuller::record_passes(VkCommandBuffer cmd, VkQueryPool timestamps) {
  const std::size_t view_count = last_view_count_;
  const CullOptions& options = last_options_;

  detail::record_entry_barrier(ctx_, cmd);
  vkCmdFillBuffer(cmd, counters_.handle(), 0, view_count * sizeof(ViewCounters), 0);
  if (options.ordered && scene_->object_count > 0)  // the per-workgroup counts the first pass adds to
    vkCmdFillBuffer(cmd, group_counts_.handle(), 0, group_count_bytes(view_count), 0);
  detail::record_transfer_to_compute(cmd);
  if (timestamps) vkCmdWriteTimestamp(cmd, VK_PIPELINE_STAGE_TOP_OF_PIPE_BIT, timestamps, 0);
  record_placement(cmd);  // instances that changed, placed before anything reads them

  auto compute_to_compute = [&] { detail::record_compute_to_compute(cmd); };
  const VkDescriptorSet set = resources_->set();
  // The ordered passes always write classes (the scatter pass reads them); the arrival-order
  // pass only when they are read back (a pipeline of its own, see WRITE_CLASSES in cull_flat.comp).
  const FlatCullParams base_params{std::uint32_t(scene_->object_count), 0, std::uint32_t(view_count),
                                   std::uint32_t(last_capacity_), 0};
  // One pass over every object: per segment (its own descriptor set), in chunks of at most
  // max_groups_ workgroups.
  auto object_pass = [&](const vulkan::ComputePipeline& pipe, std::uint32_t objects_per_invocation) {
    const std::uint64_t objects_per_group = std::uint64_t(group_size_) * objects_per_invocation;
    const std::uint64_t objects_per_dispatch = std::uint64_t(max_groups_) * objects_per_group;
    vkCmdBindPipeline(cmd, VK_PIPELINE_BIND_POINT_COMPUTE, pipe.pipeline());
    for (std::size_t seg = 0; seg < segment_count_; ++seg) {
      const VkDescriptorSet segment_set = resources_->set(seg);
      vkCmdBindDescriptorSets(cmd, VK_PIPELINE_BIND_POINT_COMPUTE, pipe.layout(), 0, 1, &segment_set, 0, nullptr);
      const std::uint64_t segment_first = std::uint64_t(seg) * segment_objects_;
      const std::uint64_t segment_count =
          segment_count_ > 1 ? std::min<std::uint64_t>(segment_objects_, scene_->object_count - segment_first)
                             : scene_->object_count;
      for (std::uint64_t first = 0; first < segment_count; first += objects_per_dispatch) {
        if (first > 0 || seg > 0) compute_to_compute();  // successive dispatches update the same counters
        const std::uint64_t count = std::min<std::uint64_t>(objects_per_dispatch, segment_count - first);
        FlatCullParams params = base_params;
        params.object_count = std::uint32_t(segment_count);
        params.first_object = std::uint32_t(first);
        params.id_base = std::uint32_t(segment_first);
        vkCmdPushConstants(cmd, pipe.layout(), VK_SHADER_STAGE_COMPUTE_BIT, 0, sizeof(params), &params);
        vkCmdDispatch(cmd, std::uint32_t((count + objects_per_group - 1) / objects_per_group),
                      std::uint32_t(view_count), 1);
      }
    }
  };
  if (!options.ordered) {
    object_pass(pipeline(arrival_key(options)), objects_per_invocation_);
  } else if (scene_->object_count > 0) {
    // Count per workgroup, scan the counts per view, scatter in object order.
    object_pass(pipeline(ordered_key(options)), objects_per_invocation_);
    compute_to_compute();
    const vulkan::ComputePipeline& scan = pipeline({.shader = PipelineKey::Shader::CompactScan});
    vkCmdBindPipeline(cmd, VK_PIPELINE_BIND_POINT_COMPUTE, scan.pipeline());
    vkCmdBindDescriptorSets(cmd, VK_PIPELINE_BIND_POINT_COMPUTE, scan.layout(), 0, 1, &set, 0, nullptr);
    vkCmdPushConstants(cmd, scan.layout(), VK_SHADER_STAGE_COMPUTE_BIT, 0, sizeof(base_params), &base_params);
    vkCmdDispatch(cmd, 1, std::uint32_t(view_count), 1);
    compute_to_compute();
    object_pass(pipeline(scatter_key(options)), objects_per_invocation_);
  }
  if (timestamps) vkCmdWriteTimestamp(cmd, VK_PIPELINE_STAGE_BOTTOM_OF_PIPE_BIT, timestamps, 1);
  detail::record_exit_barrier(ctx_, cmd);
}

void GpuCuller::record(VkCommandBuffer cmd, std::span<const Frustum> views, const CullOptions& options) {
  if (views.empty()) throw std::invalid_argument("GpuCuller::record: no views");
  prepare(views, options, false);
  record_passes(cmd, VK_NULL_HANDLE);
}

CullResult GpuCuller::read_results() const {
  if ((engine_counters_ && !counters_.data()) || (engine_visible_ && last_options_.visible_ids && !visible_.data()) ||
      (engine_draws_ && last_options_.draws && !draws_.data()))
    throw std::logic_error(
        "GpuCuller::read_results: the pass wrote into the engine's buffers, and no host address of "
        "them was given (EngineOutputs::*_host): read them from the engine's side");
  CullResult result =
      detail::read_outputs({counters_, classes_, visible_, draws_}, last_object_count_, last_view_count_,
                           last_capacity_, last_options_, segment_count_ > 1 ? segment_objects_ : 0);
  for (ViewResult& view : result.views) view.object_tests = last_object_count_;  // flat: every object, no nodes
  return result;
}

CullResult GpuCuller::cull(std::span<const Frustum> views, const CullOptions& options) {
  if (views.empty()) return {};
  return detail::timed_pass(
      *resources_, [&] { prepare(views, options, true); },
      [&](VkCommandBuffer cmd, VkQueryPool timestamps) { record_passes(cmd, timestamps); },
      [&] { return read_results(); });
}

}  // namespace cullpipe::gpu
