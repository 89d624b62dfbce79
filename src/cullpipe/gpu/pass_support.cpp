#include "cullpipe/gpu/pass_support.hpp"

#include <algorithm>
#include <chrono>
#include <stdexcept>
#include <vector>

#include "cullpipe/vulkan/check.hpp"

// SPIR-V compiled from shaders/place_instances.comp at build time (glslangValidator --vn).
#include "place_instances.spv.h"

namespace cullpipe::gpu::detail {
namespace {

constexpr VkDeviceSize kMinBufferSize = 16;

std::string mib(VkDeviceSize bytes) { return std::to_string(bytes / (1024 * 1024)) + " MiB"; }

VkPipelineStageFlags graphics_stages(const vulkan::Context& ctx) {
  return (ctx.queue_flags() & VK_QUEUE_GRAPHICS_BIT) ? VkPipelineStageFlags(VK_PIPELINE_STAGE_VERTEX_SHADER_BIT) : 0;
}

}  // namespace

void check_subgroup_operations(const vulkan::Context& ctx, VkSubgroupFeatureFlags needed, const std::string& who) {
  VkPhysicalDeviceSubgroupProperties subgroup{VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_SUBGROUP_PROPERTIES};
  VkPhysicalDeviceProperties2 properties{VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_PROPERTIES_2, &subgroup, {}};
  vkGetPhysicalDeviceProperties2(ctx.physical_device(), &properties);
  const bool compute = (subgroup.supportedStages & VK_SHADER_STAGE_COMPUTE_BIT) != 0;
  const VkSubgroupFeatureFlags missing = compute ? needed & ~subgroup.supportedOperations : needed;
  if (!missing) return;
  static const std::pair<VkSubgroupFeatureFlagBits, const char*> names[] = {
      {VK_SUBGROUP_FEATURE_BASIC_BIT, "basic"},
      {VK_SUBGROUP_FEATURE_VOTE_BIT, "vote"},
      {VK_SUBGROUP_FEATURE_ARITHMETIC_BIT, "arithmetic"},
      {VK_SUBGROUP_FEATURE_BALLOT_BIT, "ballot"},
      {VK_SUBGROUP_FEATURE_SHUFFLE_BIT, "shuffle"},
      {VK_SUBGROUP_FEATURE_SHUFFLE_RELATIVE_BIT, "shuffle relative"},
      {VK_SUBGROUP_FEATURE_CLUSTERED_BIT, "clustered"},
      {VK_SUBGROUP_FEATURE_QUAD_BIT, "quad"}};
  std::string list;
  for (const auto& [bit, name] : names)
    if (missing & bit) list += (list.empty() ? "" : ", ") + std::string(name);
  throw vulkan::Error(who + " needs subgroup operations in compute shaders that " + ctx.info().name +
                      " lacks: " + list);
}

void check_storage_range(const vulkan::Context& ctx, VkDeviceSize bytes, const std::string& what) {
  const VkDeviceSize limit = ctx.properties().limits.maxStorageBufferRange;
  if (bytes > limit)
    throw std::length_error(what + " needs " + std::to_string(bytes) + " bytes (" + mib(bytes) +
                            "), more than one storage buffer can hold on " + ctx.info().name +
                            " (maxStorageBufferRange " + std::to_string(limit) + " bytes, " + mib(limit) + ")");
}

VkDeviceSize texel_range(const vulkan::Context& ctx) {
  // The shaders index texels with a signed int.
  return std::min<VkDeviceSize>(ctx.properties().limits.maxTexelBufferElements, 0x7fffffffu) * kTexelBytes;
}

void check_texel_range(const vulkan::Context& ctx, VkDeviceSize bytes, const std::string& what) {
  const VkDeviceSize limit = texel_range(ctx);
  if (bytes > limit)
    throw std::length_error(
        what + " needs " + std::to_string(bytes) + " bytes (" + mib(bytes) +
        "), more than one texel buffer view covers on " + ctx.info().name + " (maxTexelBufferElements " +
        std::to_string(ctx.properties().limits.maxTexelBufferElements) + " of 16 bytes, " + mib(limit) + " usable)");
}

void check_record_range(const vulkan::Context& ctx, VkDeviceSize bytes, const std::string& what) {
  const VkDeviceSize limit =
      std::min<VkDeviceSize>(ctx.properties().limits.maxTexelBufferElements, 0x7fffffffu) * kRecordBytes;
  if (bytes > limit)
    throw std::length_error(
        what + " needs " + std::to_string(bytes) + " bytes (" + mib(bytes) +
        "), more than one texel buffer view covers on " + ctx.info().name + " (maxTexelBufferElements " +
        std::to_string(ctx.properties().limits.maxTexelBufferElements) + " of 8 bytes, " + mib(limit) + " usable)");
}

void check_record_format(const vulkan::Context& ctx, const std::string& who) {
  VkFormatProperties props{};
  vkGetPhysicalDeviceFormatProperties(ctx.physical_device(), kRecordFormat, &props);
  if (!(props.bufferFeatures & VK_FORMAT_FEATURE_STORAGE_TEXEL_BUFFER_BIT))
    throw vulkan::Error(who + ": " + ctx.info().name + " cannot read and write R32G32_UINT storage texel buffers");
}

void check_texel_format(const vulkan::Context& ctx, const std::string& who) {
  VkFormatProperties props{};
  vkGetPhysicalDeviceFormatProperties(ctx.physical_device(), kTexelFormat, &props);
  if (!(props.bufferFeatures & VK_FORMAT_FEATURE_UNIFORM_TEXEL_BUFFER_BIT))
    throw vulkan::Error(who + ": " + ctx.info().name + " cannot read R32G32B32A32_UINT uniform texel buffers");
}

void ensure_buffer(const vulkan::Context& ctx, vulkan::Buffer& buffer, VkDeviceSize bytes, VkBufferUsageFlags usage,
                   const char* what, bool& dirty, vulkan::MemoryUse use) {
  bytes = std::max(bytes, kMinBufferSize);
  if (buffer && buffer.size() >= bytes) return;
  dirty = true;
  buffer = vulkan::Buffer();  // free first, so peak memory is not old + new
  buffer = vulkan::Buffer(ctx, bytes, usage, what, use);
}

void record_entry_barrier(const vulkan::Context& ctx, VkCommandBuffer cmd) {
  const VkMemoryBarrier barrier{VK_STRUCTURE_TYPE_MEMORY_BARRIER, nullptr, 0, 0};  // execution dependency (WAR)
  vkCmdPipelineBarrier(cmd,
                       VK_PIPELINE_STAGE_DRAW_INDIRECT_BIT | VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT |
                           VK_PIPELINE_STAGE_TRANSFER_BIT | graphics_stages(ctx),
                       VK_PIPELINE_STAGE_TRANSFER_BIT | VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT, 0, 1, &barrier, 0,
                       nullptr, 0, nullptr);
}

void record_exit_barrier(const vulkan::Context& ctx, VkCommandBuffer cmd) {
  const VkMemoryBarrier barrier{
      VK_STRUCTURE_TYPE_MEMORY_BARRIER, nullptr, VK_ACCESS_SHADER_WRITE_BIT,
      VK_ACCESS_INDIRECT_COMMAND_READ_BIT | VK_ACCESS_SHADER_READ_BIT | VK_ACCESS_HOST_READ_BIT};
  vkCmdPipelineBarrier(cmd, VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT,
                       VK_PIPELINE_STAGE_DRAW_INDIRECT_BIT | VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT |
                           VK_PIPELINE_STAGE_HOST_BIT | graphics_stages(ctx),
                       0, 1, &barrier, 0, nullptr, 0, nullptr);
}

void record_transfer_to_compute(VkCommandBuffer cmd) {
  const VkMemoryBarrier barrier{VK_STRUCTURE_TYPE_MEMORY_BARRIER, nullptr, VK_ACCESS_TRANSFER_WRITE_BIT,
                                VK_ACCESS_SHADER_READ_BIT | VK_ACCESS_SHADER_WRITE_BIT};
  vkCmdPipelineBarrier(cmd, VK_PIPELINE_STAGE_TRANSFER_BIT, VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT, 0, 1, &barrier, 0,
                       nullptr, 0, nullptr);
}

void record_compute_to_compute(VkCommandBuffer cmd, bool indirect) {
  VkMemoryBarrier barrier{VK_STRUCTURE_TYPE_MEMORY_BARRIER, nullptr,
                          VK_ACCESS_SHADER_READ_BIT | VK_ACCESS_SHADER_WRITE_BIT,
                          VK_ACCESS_SHADER_READ_BIT | VK_ACCESS_SHADER_WRITE_BIT};
  VkPipelineStageFlags dst = VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT;
  if (indirect) {
    barrier.dstAccessMask |= VK_ACCESS_INDIRECT_COMMAND_READ_BIT;
    dst |= VK_PIPELINE_STAGE_DRAW_INDIRECT_BIT;
  }
  vkCmdPipelineBarrier(cmd, VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT, dst, 0, 1, &barrier, 0, nullptr, 0, nullptr);
}

std::unique_ptr<vulkan::ComputePipeline> make_place_pipeline(const vulkan::Context& ctx, BvKind kind) {
  const std::uint32_t spec[1] = {static_cast<std::uint32_t>(kind)};
  const std::string name = "instance placing (" + std::string(to_string(kind)) + ")";
  return std::make_unique<vulkan::ComputePipeline>(
      ctx, vulkan::ComputePipelineDesc{cullpipe_place_instances_spv, PLACE_BINDING_COUNT, sizeof(PlaceParams), spec,
                                       name.c_str(), kPlaceTexelBindings});
}

void record_placing(VkCommandBuffer cmd, const vulkan::ComputePipeline& pipeline, VkDescriptorSet set,
                    std::size_t count, std::uint32_t max_groups) {
  vkCmdBindPipeline(cmd, VK_PIPELINE_BIND_POINT_COMPUTE, pipeline.pipeline());
  vkCmdBindDescriptorSets(cmd, VK_PIPELINE_BIND_POINT_COMPUTE, pipeline.layout(), 0, 1, &set, 0, nullptr);
  const std::uint64_t per_dispatch = std::uint64_t(max_groups) * PLACE_GROUP_SIZE;
  for (std::uint64_t first = 0; first < count; first += per_dispatch) {
    const PlaceParams params{std::uint32_t(count), std::uint32_t(first)};
    vkCmdPushConstants(cmd, pipeline.layout(), VK_SHADER_STAGE_COMPUTE_BIT, 0, sizeof(params), &params);
    vkCmdDispatch(cmd, vulkan::group_count(std::min<std::uint64_t>(per_dispatch, count - first), PLACE_GROUP_SIZE), 1,
                  1);
  }
  record_compute_to_compute(cmd);  // the culling passes read what it wrote
}

CullResult timed_pass(PassResources& resources, const std::function<void()>& prepare,
                      const std::function<void(VkCommandBuffer, VkQueryPool)>& record,
                      const std::function<CullResult()>& read) {
  const auto start = std::chrono::steady_clock::now();
  prepare();
  const double gpu_ns = resources.run(record);
  CullResult result = read();
  result.timings.gpu_ns = gpu_ns;
  result.timings.wall_ns =
      double(std::chrono::duration_cast<std::chrono::nanoseconds>(std::chrono::steady_clock::now() - start).count());
  return result;
}

void check_allocation_size(const vulkan::Context& ctx, VkDeviceSize bytes, const std::string& what) {
  VkPhysicalDeviceMaintenance3Properties m3{VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_MAINTENANCE_3_PROPERTIES};
  VkPhysicalDeviceProperties2 properties{VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_PROPERTIES_2, &m3, {}};
  vkGetPhysicalDeviceProperties2(ctx.physical_device(), &properties);
  if (bytes > m3.maxMemoryAllocationSize)
    throw std::length_error(what + " needs " + std::to_string(bytes) + " bytes (" + mib(bytes) +
                            "), more than one memory allocation can hold on " + ctx.info().name +
                            " (maxMemoryAllocationSize " + std::to_string(m3.maxMemoryAllocationSize) + " bytes, " +
                            mib(m3.maxMemoryAllocationSize) + ")");
}

CullResult read_outputs(const OutputBuffers& buffers, std::size_t object_count, std::size_t view_count,
                        std::size_t capacity, const CullOptions& options, std::size_t segment_objects) {
  if (segment_objects == 0 || segment_objects > object_count) segment_objects = object_count;
  CullResult result;
  result.views.resize(view_count);
  if (view_count == 0) return result;
  const auto counters = buffers.counters.as<const ViewCounters>();
  for (std::size_t v = 0; v < view_count; ++v) {
    ViewResult& out = result.views[v];
    const ViewCounters& c = counters[v];
    out.counts = {c.visible_count, c.inside_count, c.visible_count - c.inside_count, c.occluded_count};
    out.overflow = c.visible_count > capacity;
    out.node_tests = c.node_tests;
    out.object_tests = c.object_tests;
    const std::size_t listed = std::min<std::size_t>(c.visible_count, capacity);
    if (options.classes) {
      out.classes.resize(object_count);
      const std::uint32_t* all = buffers.classes.as<const std::uint32_t>().data();
      for (std::size_t first = 0; first < object_count; first += segment_objects) {
        const std::size_t n = std::min(segment_objects, object_count - first);
        const std::uint32_t* src = all + first * view_count + v * n;  // segment [view][object]
        for (std::size_t i = 0; i < n; ++i) out.classes[first + i] = static_cast<Classification>(src[i]);
      }
    }
    if (options.visible_ids) {
      const std::uint32_t* src = buffers.visible.as<const std::uint32_t>().data() + v * capacity;
      out.visible_ids.assign(src, src + listed);
    }
    if (options.draws) {
      const DrawCommand* src = buffers.draws.as<const DrawCommand>().data() + v * capacity;
      out.draws.assign(src, src + listed);
    }
  }
  return result;
}

PassResources::PassResources(const vulkan::Context& ctx, VkDescriptorSetLayout layout, std::uint32_t binding_count,
                             std::uint32_t texel_bindings, std::uint32_t record_bindings)
    : ctx_(ctx),
      binding_count_(binding_count),
      texel_bindings_(texel_bindings),
      record_bindings_(record_bindings),
      layout_(layout) {
  try {
    VkDevice dev = ctx_.device();
    ensure_sets(1);

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
  } catch (...) {
    release();
    throw;
  }
}

PassResources::~PassResources() { release(); }

void PassResources::release() {
  VkDevice dev = ctx_.device();
  // Our own passes are waited for in run(); on a borrowed device, the caller must not destroy
  // the owner while a command buffer it recorded into is pending (and we do not stall the
  // caller's queues).
  if (ctx_.owns_device()) vkDeviceWaitIdle(dev);
  if (query_pool_) vkDestroyQueryPool(dev, query_pool_, nullptr);
  if (cmd_) vkFreeCommandBuffers(dev, ctx_.command_pool(), 1, &cmd_);
  for (std::size_t set = 0; set < views_.size(); ++set) destroy_views(set);
  if (pool_) vkDestroyDescriptorPool(dev, pool_, nullptr);
  query_pool_ = VK_NULL_HANDLE;
  cmd_ = VK_NULL_HANDLE;
  pool_ = VK_NULL_HANDLE;
}

void PassResources::ensure_sets(std::size_t count) {
  if (count <= sets_.size()) return;
  VkDevice dev = ctx_.device();
  if (pool_) {
    // The sets may be referenced by a recording that has not finished on our own device.
    if (ctx_.owns_device()) vkDeviceWaitIdle(dev);
    vkDestroyDescriptorPool(dev, pool_, nullptr);
    pool_ = VK_NULL_HANDLE;
    sets_.clear();
    for (std::size_t set = 0; set < views_.size(); ++set) destroy_views(set);
  }
  std::uint32_t texels = 0, records = 0;
  for (std::uint32_t b = 0; b < binding_count_; ++b) {
    texels += texel(b) ? 1 : 0;
    records += record(b) ? 1 : 0;
  }
  VkDescriptorPoolSize pool_sizes[3];
  std::uint32_t size_count = 0;
  if (binding_count_ > texels + records)
    pool_sizes[size_count++] = {VK_DESCRIPTOR_TYPE_STORAGE_BUFFER,
                                (binding_count_ - texels - records) * std::uint32_t(count)};
  if (texels) pool_sizes[size_count++] = {VK_DESCRIPTOR_TYPE_UNIFORM_TEXEL_BUFFER, texels * std::uint32_t(count)};
  if (records) pool_sizes[size_count++] = {VK_DESCRIPTOR_TYPE_STORAGE_TEXEL_BUFFER, records * std::uint32_t(count)};
  VkDescriptorPoolCreateInfo pool_info{VK_STRUCTURE_TYPE_DESCRIPTOR_POOL_CREATE_INFO};
  pool_info.maxSets = std::uint32_t(count);
  pool_info.poolSizeCount = size_count;
  pool_info.pPoolSizes = pool_sizes;
  CULLPIPE_VK_CHECK(vkCreateDescriptorPool(dev, &pool_info, nullptr, &pool_));
  std::vector<VkDescriptorSetLayout> layouts(count, layout_);
  std::vector<VkDescriptorSet> sets(count);
  VkDescriptorSetAllocateInfo set_info{VK_STRUCTURE_TYPE_DESCRIPTOR_SET_ALLOCATE_INFO};
  set_info.descriptorPool = pool_;
  set_info.descriptorSetCount = std::uint32_t(count);
  set_info.pSetLayouts = layouts.data();
  CULLPIPE_VK_CHECK(vkAllocateDescriptorSets(dev, &set_info, sets.data()));
  sets_ = std::move(sets);
  views_.resize(sets_.size());
}

void PassResources::destroy_views(std::size_t set) {
  for (VkBufferView view : views_.at(set)) vkDestroyBufferView(ctx_.device(), view, nullptr);
  views_[set].clear();
}

void PassResources::write(std::span<const vulkan::Buffer* const> buffers) {
  std::vector<Range> ranges;
  for (const vulkan::Buffer* b : buffers) ranges.push_back({b});
  write(0, ranges);
}

void PassResources::write(std::size_t index, std::span<const Range> ranges) {
  std::vector<VkDescriptorBufferInfo> infos(binding_count_);
  std::vector<VkWriteDescriptorSet> writes(binding_count_);
  if (ranges.size() != binding_count_) throw std::logic_error("PassResources::write: one buffer per binding");
  if (index >= sets_.size()) throw std::logic_error("PassResources::write: no descriptor set " + std::to_string(index));
  // No pending work uses the set's old views (the cullers' record() contract: one recorded
  // pass at a time). The new views are made first, so a failure leaves the set as it was.
  std::vector<VkBufferView> views(binding_count_, VK_NULL_HANDLE);
  try {
    for (std::uint32_t b = 0; b < binding_count_; ++b) {
      if (!texel(b) && !record(b)) continue;
      VkBufferViewCreateInfo view_info{VK_STRUCTURE_TYPE_BUFFER_VIEW_CREATE_INFO};
      view_info.buffer = ranges[b].buffer->handle();
      view_info.format = texel(b) ? kTexelFormat : kRecordFormat;
      view_info.offset = ranges[b].offset;
      view_info.range = ranges[b].size;
      CULLPIPE_VK_CHECK(vkCreateBufferView(ctx_.device(), &view_info, nullptr, &views[b]));
    }
  } catch (...) {
    for (VkBufferView view : views)
      if (view) vkDestroyBufferView(ctx_.device(), view, nullptr);
    throw;
  }
  for (std::uint32_t b = 0; b < binding_count_; ++b) {
    infos[b] = {ranges[b].buffer->handle(), ranges[b].offset, ranges[b].size};
    writes[b] = {VK_STRUCTURE_TYPE_WRITE_DESCRIPTOR_SET};
    writes[b].dstSet = sets_[index];
    writes[b].dstBinding = b;
    writes[b].descriptorCount = 1;
    if (texel(b) || record(b)) {
      writes[b].descriptorType =
          texel(b) ? VK_DESCRIPTOR_TYPE_UNIFORM_TEXEL_BUFFER : VK_DESCRIPTOR_TYPE_STORAGE_TEXEL_BUFFER;
      writes[b].pTexelBufferView = &views[b];
    } else {
      writes[b].descriptorType = VK_DESCRIPTOR_TYPE_STORAGE_BUFFER;
      writes[b].pBufferInfo = &infos[b];
    }
  }
  vkUpdateDescriptorSets(ctx_.device(), binding_count_, writes.data(), 0, nullptr);
  destroy_views(index);
  for (VkBufferView view : views)
    if (view) views_[index].push_back(view);
}

double PassResources::run(const std::function<void(VkCommandBuffer, VkQueryPool)>& record) {
  CULLPIPE_VK_CHECK(vkResetCommandBuffer(cmd_, 0));
  VkCommandBufferBeginInfo begin{VK_STRUCTURE_TYPE_COMMAND_BUFFER_BEGIN_INFO};
  begin.flags = VK_COMMAND_BUFFER_USAGE_ONE_TIME_SUBMIT_BIT;
  CULLPIPE_VK_CHECK(vkBeginCommandBuffer(cmd_, &begin));
  if (query_pool_) vkCmdResetQueryPool(cmd_, query_pool_, 0, 2);
  record(cmd_, query_pool_);
  CULLPIPE_VK_CHECK(vkEndCommandBuffer(cmd_));
  ctx_.submit_and_wait(cmd_);
  if (!query_pool_) return 0.0;
  std::uint64_t stamps[2] = {0, 0};
  CULLPIPE_VK_CHECK(vkGetQueryPoolResults(ctx_.device(), query_pool_, 0, 2, sizeof(stamps), stamps,
                                          sizeof(std::uint64_t), VK_QUERY_RESULT_64_BIT | VK_QUERY_RESULT_WAIT_BIT));
  const std::uint32_t bits = ctx_.timestamp_valid_bits();
  const std::uint64_t mask = bits >= 64 ? ~0ull : (1ull << bits) - 1;
  return double((stamps[1] - stamps[0]) & mask) * ctx_.timestamp_period_ns();
}

void check_occlusion(const vulkan::Context& ctx, const CullOptions& options, std::size_t view_count) {
  if (!options.pyramid) return;
  const DepthPyramidPass& p = *options.pyramid;
  if (!p.built()) throw std::invalid_argument("occlusion culling: the depth pyramid has not been built");
  if (options.occlusion_views.size() != view_count)
    throw std::invalid_argument("occlusion culling: " + std::to_string(options.occlusion_views.size()) +
                                " occlusion views for " + std::to_string(view_count) + " views");
  for (const occlusion::OcclusionView& v : options.occlusion_views)
    occlusion::check_view(v, p.width(), p.height(), p.reversed_z(), options.occlusion_options);
  check_texel_range(ctx, VkDeviceSize(view_count) * sizeof(GpuOcclusionView),
                    std::to_string(view_count) + " occlusion views");
}

void write_occlusion_views(const CullOptions& options, std::span<GpuOcclusionView> out) {
  const auto levels = options.pyramid->levels();
  for (std::size_t v = 0; v < options.occlusion_views.size(); ++v) {
    const occlusion::OcclusionView& o = options.occlusion_views[v];
    GpuOcclusionView g{};
    g.view_proj = o.view_proj;
    g.width = o.width;
    g.height = o.height;
    g.reversed_z = o.reversed_z ? 1u : 0u;
    g.texels_per_axis = options.occlusion_options.texels_per_axis;
    g.level_count = std::uint32_t(levels.size());
    for (std::size_t l = 0; l < levels.size(); ++l)
      g.levels[l] = glm::uvec4(std::uint32_t(levels[l].offset), levels[l].width, levels[l].height, 0u);
    out[v] = g;
  }
}

}  // namespace cullpipe::gpu::detail
