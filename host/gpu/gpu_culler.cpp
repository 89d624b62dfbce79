#include "gpu/gpu_culler.hpp"

#include <algorithm>
#include <chrono>
#include <cstring>
#include <stdexcept>
#include <string>

#include "gpu/layout.hpp"
#include "vk/check.hpp"

// SPIR-V compiled from shaders/*.comp at build time (glslangValidator --vn).
#include "compact_scan.spv.h"
#include "compact_scatter.spv.h"
#include "cull_flat.spv.h"

namespace cullpipe::gpu {
namespace {

constexpr std::uint32_t kBindingCount = CULL_BINDING_COUNT;  // one descriptor set for every shader
constexpr VkDeviceSize kMinBufferSize = 16;

std::uint32_t kind_index(BvKind k) { return static_cast<std::uint32_t>(k); }

std::string mib(VkDeviceSize bytes) { return std::to_string(bytes / (1024 * 1024)) + " MiB"; }

void check_storage_range(const vk::Context& ctx, VkDeviceSize bytes, const std::string& what) {
  const VkDeviceSize limit = ctx.properties().limits.maxStorageBufferRange;
  if (bytes > limit)
    throw std::length_error(what + " needs " + std::to_string(bytes) + " bytes (" + mib(bytes) +
                            "), more than one storage buffer can hold on " + ctx.info().name + " (maxStorageBufferRange " +
                            std::to_string(limit) + " bytes, " + mib(limit) + ")");
}

// Grows `buffer` to at least `bytes` (never shrinks). Sets `dirty` (descriptors must be
// rewritten) before the old buffer is freed, so a failed allocation cannot leave a descriptor
// pointing at a destroyed buffer.
void ensure_buffer(const vk::Context& ctx, vk::Buffer& buffer, VkDeviceSize bytes, VkBufferUsageFlags usage,
                   const char* what, bool& dirty) {
  bytes = std::max(bytes, kMinBufferSize);
  if (buffer && buffer.size() >= bytes) return;
  dirty = true;
  buffer = vk::Buffer();  // free first, so peak memory is not old + new
  buffer = vk::Buffer(ctx, bytes, usage, what);
}

}  // namespace

GpuCuller::GpuCuller(const vk::Context& ctx, const GpuCullerConfig& config) : ctx_(ctx) {
  try {
    setup(config);
  } catch (...) {
    release();
    throw;
  }
}

void GpuCuller::setup(const GpuCullerConfig& config) {
  const VkPhysicalDeviceLimits& limits = ctx_.properties().limits;
  group_size_ = std::max<std::uint32_t>(
      1, std::min({config.group_size, limits.maxComputeWorkGroupSize[0], limits.maxComputeWorkGroupInvocations}));
  max_groups_ = config.max_groups_per_dispatch ? std::min(config.max_groups_per_dispatch, limits.maxComputeWorkGroupCount[0])
                                               : limits.maxComputeWorkGroupCount[0];
  group_size_ = std::min(group_size_, MAX_CULL_GROUP_SIZE);
  // Every pipeline has the same set layout; the flat AABB one is built now, for the descriptor
  // set, the others on first use.
  static_assert(BV_KIND_AABB == 0 && BV_KIND_OBB == 1 && BV_KIND_SPHERE == 2, "BvKind order must match the shader");
  pipeline(0, 0, false, false);

  VkDevice dev = ctx_.device();
  VkDescriptorPoolSize pool_size{VK_DESCRIPTOR_TYPE_STORAGE_BUFFER, kBindingCount};
  VkDescriptorPoolCreateInfo pool_info{VK_STRUCTURE_TYPE_DESCRIPTOR_POOL_CREATE_INFO};
  pool_info.maxSets = 1;
  pool_info.poolSizeCount = 1;
  pool_info.pPoolSizes = &pool_size;
  CULLPIPE_VK_CHECK(vkCreateDescriptorPool(dev, &pool_info, nullptr, &descriptor_pool_));
  VkDescriptorSetLayout set_layout = pipelines_[0][0][0][0]->set_layout();  // identical in all
  VkDescriptorSetAllocateInfo set_info{VK_STRUCTURE_TYPE_DESCRIPTOR_SET_ALLOCATE_INFO};
  set_info.descriptorPool = descriptor_pool_;
  set_info.descriptorSetCount = 1;
  set_info.pSetLayouts = &set_layout;
  CULLPIPE_VK_CHECK(vkAllocateDescriptorSets(dev, &set_info, &descriptor_set_));

  VkCommandBufferAllocateInfo cmd_info{VK_STRUCTURE_TYPE_COMMAND_BUFFER_ALLOCATE_INFO};
  cmd_info.commandPool = ctx_.command_pool();
  cmd_info.level = VK_COMMAND_BUFFER_LEVEL_PRIMARY;
  cmd_info.commandBufferCount = 1;
  CULLPIPE_VK_CHECK(vkAllocateCommandBuffers(dev, &cmd_info, &cmd_));

  if (ctx_.timestamp_period_ns() > 0.0) {
    VkQueryPoolCreateInfo query_info{VK_STRUCTURE_TYPE_QUERY_POOL_CREATE_INFO};
    query_info.queryType = VK_QUERY_TYPE_TIMESTAMP;
    query_info.queryCount = 2;
    CULLPIPE_VK_CHECK(vkCreateQueryPool(dev, &query_info, nullptr, &query_pool_));
  }
}

const vk::ComputePipeline& GpuCuller::pipeline(int shader, std::uint32_t kind, bool ordered, bool draws) {
  if (shader != 0) kind = 0, ordered = false;
  std::unique_ptr<vk::ComputePipeline>& slot = pipelines_[shader][kind][ordered][draws];
  if (slot) return *slot;
  std::span<const std::uint32_t> spirv;
  std::string name;
  static const char* kinds[3] = {"aabb", "obb", "sphere"};
  if (shader == 0) {
    spirv = {cullpipe_cull_flat_spv, sizeof(cullpipe_cull_flat_spv) / sizeof(std::uint32_t)};
    name = std::string("flat cull (") + kinds[kind] + (ordered ? ", ordered" : "") + (draws ? ", draws" : "") + ")";
  } else if (shader == 1) {
    spirv = {cullpipe_compact_scan_spv, sizeof(cullpipe_compact_scan_spv) / sizeof(std::uint32_t)};
    name = "ordered compaction scan";
  } else {
    spirv = {cullpipe_compact_scatter_spv, sizeof(cullpipe_compact_scatter_spv) / sizeof(std::uint32_t)};
    name = std::string("ordered compaction scatter") + (draws ? " (draws)" : "");
  }
  // Specialization constants: 0 kind, 1 group size, 2 ordered, 3 draws.
  const std::uint32_t spec[4] = {kind, group_size_, ordered ? 1u : 0u, draws ? 1u : 0u};
  slot = std::make_unique<vk::ComputePipeline>(
      ctx_, vk::ComputePipelineDesc{spirv, kBindingCount, sizeof(FlatCullParams), spec, name.c_str()});
  return *slot;
}

GpuCuller::~GpuCuller() { release(); }

void GpuCuller::release() {
  VkDevice dev = ctx_.device();
  // Our own passes are waited for in cull(); on a borrowed device, the caller must not destroy
  // the culler while a command buffer it recorded into is pending (and we do not stall the
  // caller's queues).
  if (ctx_.owns_device()) vkDeviceWaitIdle(dev);
  if (query_pool_) vkDestroyQueryPool(dev, query_pool_, nullptr);
  if (cmd_) vkFreeCommandBuffers(dev, ctx_.command_pool(), 1, &cmd_);
  if (descriptor_pool_) vkDestroyDescriptorPool(dev, descriptor_pool_, nullptr);
  query_pool_ = VK_NULL_HANDLE;
  cmd_ = VK_NULL_HANDLE;
  descriptor_pool_ = VK_NULL_HANDLE;
}

void GpuCuller::upload(std::span<const Aabb> volumes) {
  std::vector<GpuAabb> packed(volumes.size());
  for (std::size_t i = 0; i < volumes.size(); ++i) packed[i] = pack(volumes[i]);
  upload_words(BvKind::Aabb, packed.data(), packed.size(), sizeof(GpuAabb));
}

void GpuCuller::upload(std::span<const Obb> volumes) {
  std::vector<GpuObb> packed(volumes.size());
  for (std::size_t i = 0; i < volumes.size(); ++i) packed[i] = pack(volumes[i]);
  upload_words(BvKind::Obb, packed.data(), packed.size(), sizeof(GpuObb));
}

void GpuCuller::upload(std::span<const Sphere> volumes) {
  std::vector<GpuSphere> packed(volumes.size());
  for (std::size_t i = 0; i < volumes.size(); ++i) packed[i] = pack(volumes[i]);
  upload_words(BvKind::Sphere, packed.data(), packed.size(), sizeof(GpuSphere));
}

void GpuCuller::upload_words(BvKind kind, const void* data, std::size_t count, std::size_t bytes_per_object) {
  // The storage-range limit also keeps object ids and output indices within 32 bits.
  const VkDeviceSize bytes = VkDeviceSize(count) * bytes_per_object;
  check_storage_range(ctx_, bytes, std::to_string(count) + " " + std::string(to_string(kind)) + " volumes");
  object_count_ = 0;  // stays 0 if the allocation below fails
  ensure_buffer(ctx_, bounds_, bytes, VK_BUFFER_USAGE_STORAGE_BUFFER_BIT, "bounds buffer", descriptors_dirty_);
  if (bytes) std::memcpy(bounds_.data(), data, bytes);
  kind_ = kind;
  object_count_ = count;
}

void GpuCuller::upload_draws(std::span<const DrawCommand> templates) {
  const VkDeviceSize bytes = VkDeviceSize(templates.size()) * sizeof(DrawCommand);
  check_storage_range(ctx_, bytes, std::to_string(templates.size()) + " draw templates");
  template_count_ = 0;
  ensure_buffer(ctx_, templates_, bytes, VK_BUFFER_USAGE_STORAGE_BUFFER_BIT, "draw template buffer", descriptors_dirty_);
  if (bytes) std::memcpy(templates_.data(), templates.data(), bytes);
  template_count_ = templates.size();
}

void GpuCuller::ensure_outputs(std::size_t view_count, std::size_t visible_capacity, bool draws) {
  const VkDeviceSize outputs = VkDeviceSize(object_count_) * view_count * sizeof(std::uint32_t);
  const VkDeviceSize visible = VkDeviceSize(visible_capacity) * view_count * sizeof(std::uint32_t);
  const VkDeviceSize draw_bytes = draws ? VkDeviceSize(visible_capacity) * view_count * sizeof(DrawCommand) : 0;
  const VkDeviceSize groups = VkDeviceSize(vk::group_count(object_count_, group_size_)) * view_count * sizeof(std::uint32_t);
  check_storage_range(ctx_, outputs, std::to_string(view_count) + " views x " + std::to_string(object_count_) + " objects of output");
  check_storage_range(ctx_, visible, std::to_string(view_count) + " views x " + std::to_string(visible_capacity) + " visible ids");
  check_storage_range(ctx_, draw_bytes, std::to_string(view_count) + " views x " + std::to_string(visible_capacity) + " draw commands");
  constexpr VkBufferUsageFlags storage = VK_BUFFER_USAGE_STORAGE_BUFFER_BIT;
  bool& dirty = descriptors_dirty_;
  ensure_buffer(ctx_, classes_, outputs, storage, "classification buffer", dirty);
  ensure_buffer(ctx_, visible_, visible, storage, "visible-id buffer", dirty);
  ensure_buffer(ctx_, counters_, view_count * sizeof(ViewCounters),
                storage | VK_BUFFER_USAGE_TRANSFER_DST_BIT | VK_BUFFER_USAGE_INDIRECT_BUFFER_BIT, "counter buffer", dirty);
  ensure_buffer(ctx_, views_, view_count * sizeof(GpuFrustum), storage, "view buffer", dirty);
  ensure_buffer(ctx_, draws_, draw_bytes, storage | VK_BUFFER_USAGE_INDIRECT_BUFFER_BIT, "draw buffer", dirty);
  ensure_buffer(ctx_, templates_, 0, storage, "draw template buffer", dirty);
  ensure_buffer(ctx_, group_counts_, groups, storage, "group count buffer", dirty);
}

void GpuCuller::update_descriptors() {
  if (!descriptors_dirty_) return;
  const vk::Buffer* buffers[kBindingCount] = {&bounds_, &classes_, &visible_, &counters_, &views_, &templates_, &draws_, &group_counts_};
  static_assert(BINDING_BOUNDS == 0 && BINDING_CLASSES == 1 && BINDING_VISIBLE == 2 && BINDING_COUNTERS == 3 &&
                BINDING_VIEWS == 4 && BINDING_DRAW_TEMPLATES == 5 && BINDING_DRAWS == 6 && BINDING_GROUP_COUNTS == 7);
  VkDescriptorBufferInfo infos[kBindingCount];
  VkWriteDescriptorSet writes[kBindingCount];
  for (std::uint32_t b = 0; b < kBindingCount; ++b) {
    infos[b] = {buffers[b]->handle(), 0, VK_WHOLE_SIZE};
    writes[b] = {VK_STRUCTURE_TYPE_WRITE_DESCRIPTOR_SET};
    writes[b].dstSet = descriptor_set_;
    writes[b].dstBinding = b;
    writes[b].descriptorCount = 1;
    writes[b].descriptorType = VK_DESCRIPTOR_TYPE_STORAGE_BUFFER;
    writes[b].pBufferInfo = &infos[b];
  }
  vkUpdateDescriptorSets(ctx_.device(), kBindingCount, writes, 0, nullptr);
  descriptors_dirty_ = false;
}

void GpuCuller::prepare(std::span<const Frustum> views, const CullOptions& options) {
  const std::size_t capacity = options.visible_capacity ? options.visible_capacity : object_count_;
  if (options.draws && template_count_ != object_count_)
    throw std::invalid_argument("draw commands requested, but " + std::to_string(template_count_) + " draw templates were uploaded for " +
                                std::to_string(object_count_) + " objects (call upload_draws)");
  if (views.size() > ctx_.properties().limits.maxComputeWorkGroupCount[1])
    throw std::length_error(std::to_string(views.size()) + " views exceed the device's dispatch limit of " +
                            std::to_string(ctx_.properties().limits.maxComputeWorkGroupCount[1]));
  ensure_buffer(ctx_, bounds_, 0, VK_BUFFER_USAGE_STORAGE_BUFFER_BIT, "bounds buffer", descriptors_dirty_);
  ensure_outputs(views.size(), capacity, options.draws);
  update_descriptors();
  auto gpu_views = views_.as<GpuFrustum>();
  for (std::size_t v = 0; v < views.size(); ++v) gpu_views[v] = pack(views[v]);
  last_capacity_ = capacity;
  last_view_count_ = views.size();
  last_options_ = options;
  // Build every pipeline the pass needs now, not while recording.
  const std::uint32_t kind = kind_index(kind_);
  if (!options.ordered) {
    pipeline(0, kind, false, options.draws);
  } else {
    pipeline(0, kind, true, false);
    pipeline(1, 0, false, false);
    pipeline(2, 0, false, options.draws);
  }
}

void GpuCuller::record_passes(VkCommandBuffer cmd, bool timestamps) {
  const std::size_t view_count = last_view_count_;
  const CullOptions& options = last_options_;
  const std::uint64_t objects_per_dispatch = std::uint64_t(max_groups_) * group_size_;

  // Earlier work in the same command buffer or queue may still read the outputs (indirect
  // draws, shaders, copies): finish those reads before they are overwritten.
  const VkPipelineStageFlags graphics_stages =
      (ctx_.queue_flags() & VK_QUEUE_GRAPHICS_BIT) ? VkPipelineStageFlags(VK_PIPELINE_STAGE_VERTEX_SHADER_BIT) : 0;
  const VkMemoryBarrier in_barrier{VK_STRUCTURE_TYPE_MEMORY_BARRIER, nullptr, 0, 0};  // execution dependency (WAR)
  vkCmdPipelineBarrier(cmd,
                       VK_PIPELINE_STAGE_DRAW_INDIRECT_BIT | VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT | VK_PIPELINE_STAGE_TRANSFER_BIT |
                           graphics_stages,
                       VK_PIPELINE_STAGE_TRANSFER_BIT | VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT, 0, 1, &in_barrier, 0, nullptr, 0,
                       nullptr);
  vkCmdFillBuffer(cmd, counters_.handle(), 0, view_count * sizeof(ViewCounters), 0);
  const VkMemoryBarrier clear_barrier{VK_STRUCTURE_TYPE_MEMORY_BARRIER, nullptr, VK_ACCESS_TRANSFER_WRITE_BIT,
                                      VK_ACCESS_SHADER_READ_BIT | VK_ACCESS_SHADER_WRITE_BIT};
  vkCmdPipelineBarrier(cmd, VK_PIPELINE_STAGE_TRANSFER_BIT, VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT, 0, 1, &clear_barrier, 0,
                       nullptr, 0, nullptr);
  if (timestamps) vkCmdWriteTimestamp(cmd, VK_PIPELINE_STAGE_TOP_OF_PIPE_BIT, query_pool_, 0);

  const VkMemoryBarrier compute_barrier{VK_STRUCTURE_TYPE_MEMORY_BARRIER, nullptr,
                                        VK_ACCESS_SHADER_READ_BIT | VK_ACCESS_SHADER_WRITE_BIT,
                                        VK_ACCESS_SHADER_READ_BIT | VK_ACCESS_SHADER_WRITE_BIT};
  auto compute_to_compute = [&] {
    vkCmdPipelineBarrier(cmd, VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT, VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT, 0, 1, &compute_barrier,
                         0, nullptr, 0, nullptr);
  };
  const FlatCullParams base_params{std::uint32_t(object_count_), 0, std::uint32_t(view_count), std::uint32_t(last_capacity_)};
  // One pass over every object in chunks of at most max_groups_ workgroups.
  auto object_pass = [&](const vk::ComputePipeline& pipe) {
    vkCmdBindPipeline(cmd, VK_PIPELINE_BIND_POINT_COMPUTE, pipe.pipeline());
    vkCmdBindDescriptorSets(cmd, VK_PIPELINE_BIND_POINT_COMPUTE, pipe.layout(), 0, 1, &descriptor_set_, 0, nullptr);
    for (std::uint64_t first = 0; first < object_count_; first += objects_per_dispatch) {
      if (first > 0) compute_to_compute();  // successive chunks update the same counters
      const std::uint64_t count = std::min<std::uint64_t>(objects_per_dispatch, object_count_ - first);
      FlatCullParams params = base_params;
      params.first_object = std::uint32_t(first);
      vkCmdPushConstants(cmd, pipe.layout(), VK_SHADER_STAGE_COMPUTE_BIT, 0, sizeof(params), &params);
      vkCmdDispatch(cmd, vk::group_count(count, group_size_), std::uint32_t(view_count), 1);
    }
  };
  const std::uint32_t kind = kind_index(kind_);
  if (!options.ordered) {
    object_pass(pipeline(0, kind, false, options.draws));
  } else if (object_count_ > 0) {
    // Count per workgroup, scan the counts per view, scatter in object order.
    object_pass(pipeline(0, kind, true, false));
    compute_to_compute();
    const vk::ComputePipeline& scan = pipeline(1, 0, false, false);
    vkCmdBindPipeline(cmd, VK_PIPELINE_BIND_POINT_COMPUTE, scan.pipeline());
    vkCmdBindDescriptorSets(cmd, VK_PIPELINE_BIND_POINT_COMPUTE, scan.layout(), 0, 1, &descriptor_set_, 0, nullptr);
    vkCmdPushConstants(cmd, scan.layout(), VK_SHADER_STAGE_COMPUTE_BIT, 0, sizeof(base_params), &base_params);
    vkCmdDispatch(cmd, 1, std::uint32_t(view_count), 1);
    compute_to_compute();
    object_pass(pipeline(2, 0, false, options.draws));
  }
  if (timestamps) vkCmdWriteTimestamp(cmd, VK_PIPELINE_STAGE_BOTTOM_OF_PIPE_BIT, query_pool_, 1);
  // Make the outputs visible to indirect draws (the count and the commands), to later shaders
  // and to the host.
  const VkMemoryBarrier out_barrier{VK_STRUCTURE_TYPE_MEMORY_BARRIER, nullptr, VK_ACCESS_SHADER_WRITE_BIT,
                                    VK_ACCESS_INDIRECT_COMMAND_READ_BIT | VK_ACCESS_SHADER_READ_BIT | VK_ACCESS_HOST_READ_BIT};
  vkCmdPipelineBarrier(cmd, VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT,
                       VK_PIPELINE_STAGE_DRAW_INDIRECT_BIT | VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT | VK_PIPELINE_STAGE_HOST_BIT |
                           graphics_stages,
                       0, 1, &out_barrier, 0, nullptr, 0, nullptr);
}

void GpuCuller::record(VkCommandBuffer cmd, std::span<const Frustum> views, const CullOptions& options) {
  if (views.empty()) throw std::invalid_argument("GpuCuller::record: no views");
  prepare(views, options);
  record_passes(cmd, false);
}

CullResult GpuCuller::read_results() const {
  CullResult result;
  const CullOptions& options = last_options_;
  const std::size_t capacity = last_capacity_;
  result.views.resize(last_view_count_);
  if (last_view_count_ == 0) return result;
  const auto counters = counters_.as<const ViewCounters>();
  const auto classes = classes_.as<const std::uint32_t>();
  const auto visible = visible_.as<const std::uint32_t>();
  for (std::size_t v = 0; v < last_view_count_; ++v) {
    ViewResult& out = result.views[v];
    const ViewCounters& c = counters[v];
    out.counts = {c.visible_count, c.inside_count, c.visible_count - c.inside_count};
    out.overflow = c.visible_count > capacity;
    if (options.classes) {
      out.classes.resize(object_count_);
      const std::uint32_t* src = classes.data() + v * object_count_;
      for (std::size_t i = 0; i < object_count_; ++i) out.classes[i] = static_cast<Classification>(src[i]);
    }
    if (options.visible_ids) {
      const std::uint32_t* src = visible.data() + v * capacity;
      out.visible_ids.assign(src, src + std::min<std::size_t>(c.visible_count, capacity));
    }
    if (options.draws) {
      const DrawCommand* src = draws_.as<const DrawCommand>().data() + v * capacity;
      out.draws.assign(src, src + std::min<std::size_t>(c.visible_count, capacity));
    }
  }
  return result;
}

CullResult GpuCuller::cull(std::span<const Frustum> views, const CullOptions& options) {
  const auto start = std::chrono::steady_clock::now();
  if (views.empty()) return {};
  prepare(views, options);
  CULLPIPE_VK_CHECK(vkResetCommandBuffer(cmd_, 0));
  VkCommandBufferBeginInfo begin{VK_STRUCTURE_TYPE_COMMAND_BUFFER_BEGIN_INFO};
  begin.flags = VK_COMMAND_BUFFER_USAGE_ONE_TIME_SUBMIT_BIT;
  CULLPIPE_VK_CHECK(vkBeginCommandBuffer(cmd_, &begin));
  if (query_pool_) vkCmdResetQueryPool(cmd_, query_pool_, 0, 2);
  record_passes(cmd_, query_pool_ != VK_NULL_HANDLE);
  CULLPIPE_VK_CHECK(vkEndCommandBuffer(cmd_));
  ctx_.submit_and_wait(cmd_);

  CullResult result = read_results();
  if (query_pool_) {
    std::uint64_t stamps[2] = {0, 0};
    CULLPIPE_VK_CHECK(vkGetQueryPoolResults(ctx_.device(), query_pool_, 0, 2, sizeof(stamps), stamps, sizeof(std::uint64_t),
                                            VK_QUERY_RESULT_64_BIT | VK_QUERY_RESULT_WAIT_BIT));
    const std::uint32_t bits = ctx_.timestamp_valid_bits();
    const std::uint64_t mask = bits >= 64 ? ~0ull : (1ull << bits) - 1;
    result.timings.gpu_ns = double((stamps[1] - stamps[0]) & mask) * ctx_.timestamp_period_ns();
  }
  result.timings.wall_ns = double(std::chrono::duration_cast<std::chrono::nanoseconds>(std::chrono::steady_clock::now() - start).count());
  return result;
}

}  // namespace cullpipe::gpu
