#include "cullpipe/gpu/depth_pyramid_pass.hpp"

#include <atomic>
#include <bit>
#include <cstring>
#include <stdexcept>

#include "cullpipe/cull/occlusion.hpp"
#include "cullpipe/gpu/layout.hpp"
#include "cullpipe/gpu/pass_support.hpp"
#include "cullpipe/vulkan/check.hpp"

// SPIR-V of shaders/depth_pyramid.comp, compiled at build time.
#include "depth_pyramid.spv.h"
#include "depth_unorm.spv.h"

namespace cullpipe::gpu {

namespace {

constexpr std::uint32_t kTexelBinding = 1u << 1;  // the level below, read as texels

std::string format_name(VkFormat f) {
  switch (f) {
    case VK_FORMAT_D16_UNORM:
      return "VK_FORMAT_D16_UNORM";
    case VK_FORMAT_X8_D24_UNORM_PACK32:
      return "VK_FORMAT_X8_D24_UNORM_PACK32";
    case VK_FORMAT_D32_SFLOAT:
      return "VK_FORMAT_D32_SFLOAT";
    case VK_FORMAT_S8_UINT:
      return "VK_FORMAT_S8_UINT";
    case VK_FORMAT_D16_UNORM_S8_UINT:
      return "VK_FORMAT_D16_UNORM_S8_UINT";
    case VK_FORMAT_D24_UNORM_S8_UINT:
      return "VK_FORMAT_D24_UNORM_S8_UINT";
    case VK_FORMAT_D32_SFLOAT_S8_UINT:
      return "VK_FORMAT_D32_SFLOAT_S8_UINT";
    default:
      return "format " + std::to_string(int(f));
  }
}

bool has_stencil(VkFormat f) {
  return f == VK_FORMAT_D32_SFLOAT_S8_UINT || f == VK_FORMAT_D24_UNORM_S8_UINT || f == VK_FORMAT_D16_UNORM_S8_UINT;
}

// Bits of a unorm depth format's depth, 0 for float depth.
unsigned unorm_bits(VkFormat f) {
  if (f == VK_FORMAT_D16_UNORM || f == VK_FORMAT_D16_UNORM_S8_UINT) return 16;
  if (f == VK_FORMAT_X8_D24_UNORM_PACK32 || f == VK_FORMAT_D24_UNORM_S8_UINT) return 24;
  return 0;
}

/// The stages and accesses of depth writes before the pass (and depth tests after it), on a
/// queue with graphics; on a compute-only queue, all commands and memory writes.
void depth_stages(const vulkan::Context& ctx, VkPipelineStageFlags& stages, VkAccessFlags& writes,
                  VkAccessFlags& reads) {
  if (ctx.queue_flags() & VK_QUEUE_GRAPHICS_BIT) {
    stages = VK_PIPELINE_STAGE_EARLY_FRAGMENT_TESTS_BIT | VK_PIPELINE_STAGE_LATE_FRAGMENT_TESTS_BIT;
    writes = VK_ACCESS_DEPTH_STENCIL_ATTACHMENT_WRITE_BIT;
    reads = VK_ACCESS_DEPTH_STENCIL_ATTACHMENT_READ_BIT | VK_ACCESS_DEPTH_STENCIL_ATTACHMENT_WRITE_BIT;
  } else {
    stages = VK_PIPELINE_STAGE_ALL_COMMANDS_BIT;
    writes = VK_ACCESS_MEMORY_WRITE_BIT;
    reads = VK_ACCESS_MEMORY_READ_BIT | VK_ACCESS_MEMORY_WRITE_BIT;
  }
}

}  // namespace

std::string depth_source_problem(const DepthSource& s) {
  if (s.image == VK_NULL_HANDLE) return "no image";
  if (s.format != VK_FORMAT_D32_SFLOAT && s.format != VK_FORMAT_D32_SFLOAT_S8_UINT && unorm_bits(s.format) == 0)
    return "depth format " + format_name(s.format) +
           " is not supported (a depth format: VK_FORMAT_D32_SFLOAT, VK_FORMAT_D32_SFLOAT_S8_UINT, "
           "VK_FORMAT_D16_UNORM, "
           "VK_FORMAT_D16_UNORM_S8_UINT, VK_FORMAT_X8_D24_UNORM_PACK32 or VK_FORMAT_D24_UNORM_S8_UINT)";
  if (s.layout == VK_IMAGE_LAYOUT_UNDEFINED || s.layout == VK_IMAGE_LAYOUT_PREINITIALIZED)
    return "the depth image's layout is undefined: it holds no depth to reduce";
  if (s.width == 0 || s.height == 0 || s.width > occlusion::kMaxViewportSide || s.height > occlusion::kMaxViewportSide)
    return "a " + std::to_string(s.width) + "x" + std::to_string(s.height) + " depth image (each side 1 to " +
           std::to_string(occlusion::kMaxViewportSide) + ")";
  return {};
}

DepthPyramidPass::DepthPyramidPass(const vulkan::Context& ctx) : ctx_(ctx) {
  // Binding 0 writes a level, binding 1 reads the one below as texels (the same buffer).
  detail::check_texel_format(ctx_, "the depth pyramid");
  pipeline_ = std::make_unique<vulkan::ComputePipeline>(
      ctx_, vulkan::ComputePipelineDesc{
                cullpipe_depth_pyramid_spv, 2, sizeof(PyramidReduceParams), {}, "depth pyramid", kTexelBinding});
  resources_ = std::make_unique<detail::PassResources>(ctx_, pipeline_->set_layout(), 2, kTexelBinding);
}

DepthPyramidPass::~DepthPyramidPass() = default;

void DepthPyramidPass::resize(std::uint32_t width, std::uint32_t height) {
  if (width == width_ && height == height_ && texels_.handle() != VK_NULL_HANDLE) return;
  if (width > occlusion::kMaxViewportSide || height > occlusion::kMaxViewportSide)
    throw std::invalid_argument("depth pyramid: a " + std::to_string(width) + "x" + std::to_string(height) +
                                " depth image (each side 1 to " + std::to_string(occlusion::kMaxViewportSide) + ")");
  std::vector<occlusion::PyramidLevel> levels = occlusion::pyramid_levels(width, height);  // (throws for 0)
  // Whole texels of four floats, for the texel view the reduction reads.
  const VkDeviceSize floats = (levels.back().offset + 1 + 3) / 4 * 4, bytes = floats * sizeof(float);
  const std::string what = "depth pyramid of a " + std::to_string(width) + "x" + std::to_string(height) + " image";
  detail::check_storage_range(ctx_, bytes, what);
  detail::check_texel_range(ctx_, bytes, what);
  detail::check_allocation_size(ctx_, bytes, what);
  vulkan::Buffer texels(
      ctx_, bytes,
      VK_BUFFER_USAGE_STORAGE_BUFFER_BIT | VK_BUFFER_USAGE_UNIFORM_TEXEL_BUFFER_BIT | VK_BUFFER_USAGE_TRANSFER_DST_BIT,
      "depth pyramid");
  const vulkan::Buffer* bound[2] = {&texels, &texels};
  resources_->write(bound);
  texels_ = std::move(texels);
  levels_ = std::move(levels);
  built_ = false;
  static std::atomic<std::uint64_t> next_generation{1};
  generation_ = next_generation++;
  width_ = width;
  height_ = height;
}

void DepthPyramidPass::prepare_unorm(unsigned bits) {
  const VkDeviceSize pixels = VkDeviceSize(width_) * height_,
                     bytes = (bits == 16 ? (pixels + 1) / 2 : pixels) * sizeof(std::uint32_t);
  const std::string what = "unorm depth of a " + std::to_string(width_) + "x" + std::to_string(height_) + " image";
  detail::check_storage_range(ctx_, bytes, what);
  if (!unorm_pipeline_) {
    auto pipeline = std::make_unique<vulkan::ComputePipeline>(
        ctx_, vulkan::ComputePipelineDesc{
                  cullpipe_depth_unorm_spv, 2, sizeof(PyramidUnormParams), {}, "depth pyramid (unorm depth)"});
    unorm_resources_ = std::make_unique<detail::PassResources>(ctx_, pipeline->set_layout(), 2);
    unorm_pipeline_ = std::move(pipeline);
  }
  detail::ensure_buffer(ctx_, raw_, bytes, VK_BUFFER_USAGE_STORAGE_BUFFER_BIT | VK_BUFFER_USAGE_TRANSFER_DST_BIT,
                        "unorm depth buffer", unorm_descriptors_dirty_);
  if (unorm_descriptors_dirty_ || unorm_generation_ != generation_) {
    const vulkan::Buffer* bound[2] = {&texels_, &raw_};
    unorm_resources_->write(bound);
    unorm_descriptors_dirty_ = false;
    unorm_generation_ = generation_;
  }
}

void DepthPyramidPass::record(VkCommandBuffer cmd, const DepthSource& source, bool reversed_z) {
  if (const std::string why = depth_source_problem(source); !why.empty())
    throw std::invalid_argument("depth pyramid: " + why);
  resize(source.width, source.height);
  if (unorm_bits(source.format)) prepare_unorm(unorm_bits(source.format));
  VkPipelineStageFlags depth_stage;
  VkAccessFlags depth_writes, depth_reads;
  depth_stages(ctx_, depth_stage, depth_writes, depth_reads);
  const bool move = source.layout != VK_IMAGE_LAYOUT_GENERAL && source.layout != VK_IMAGE_LAYOUT_TRANSFER_SRC_OPTIMAL;
  const VkImageLayout copy_layout = move ? VK_IMAGE_LAYOUT_TRANSFER_SRC_OPTIMAL : source.layout;
  VkImageMemoryBarrier image{VK_STRUCTURE_TYPE_IMAGE_MEMORY_BARRIER};
  image.srcAccessMask = depth_writes;
  image.dstAccessMask = VK_ACCESS_TRANSFER_READ_BIT;
  image.oldLayout = source.layout;
  image.newLayout = copy_layout;
  image.srcQueueFamilyIndex = image.dstQueueFamilyIndex = VK_QUEUE_FAMILY_IGNORED;
  image.image = source.image;
  image.subresourceRange = {
      VkImageAspectFlags(VK_IMAGE_ASPECT_DEPTH_BIT | (has_stencil(source.format) ? VK_IMAGE_ASPECT_STENCIL_BIT : 0)), 0,
      1, 0, 1};
  // The last pass's readers of the pyramid finish before the copy overwrites level 0.
  const VkMemoryBarrier readers{VK_STRUCTURE_TYPE_MEMORY_BARRIER, nullptr,
                                VK_ACCESS_SHADER_READ_BIT | VK_ACCESS_SHADER_WRITE_BIT, VK_ACCESS_TRANSFER_WRITE_BIT};
  vkCmdPipelineBarrier(cmd, depth_stage | VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT, VK_PIPELINE_STAGE_TRANSFER_BIT, 0, 1,
                       &readers, 0, nullptr, 1, &image);
  VkBufferImageCopy copy{};
  copy.imageSubresource = {VK_IMAGE_ASPECT_DEPTH_BIT, 0, 0, 1};
  copy.imageExtent = {source.width, source.height, 1};
  const unsigned bits = unorm_bits(source.format);
  // Float depth is level 0 as it is; unorm depth (16 bits packed two to a word, 24 in a word
  // each) goes to the raw buffer first.
  vkCmdCopyImageToBuffer(cmd, source.image, copy_layout, bits ? raw_.handle() : texels_.handle(), 1, &copy);
  if (move) {
    image.srcAccessMask = VK_ACCESS_TRANSFER_READ_BIT;
    image.dstAccessMask = depth_reads;
    image.oldLayout = copy_layout;
    image.newLayout = source.layout;
    vkCmdPipelineBarrier(cmd, VK_PIPELINE_STAGE_TRANSFER_BIT, depth_stage, 0, 0, nullptr, 0, nullptr, 1, &image);
  }
  detail::record_transfer_to_compute(cmd);
  if (bits) {
    const std::uint32_t count = source.width * source.height;
    const PyramidUnormParams params{count, bits, reversed_z ? 1u : 0u,
                                    std::bit_cast<std::uint32_t>(static_cast<float>(1.0 / double((1u << bits) - 1u)))};
    vkCmdBindPipeline(cmd, VK_PIPELINE_BIND_POINT_COMPUTE, unorm_pipeline_->pipeline());
    const VkDescriptorSet unorm_set = unorm_resources_->set();
    vkCmdBindDescriptorSets(cmd, VK_PIPELINE_BIND_POINT_COMPUTE, unorm_pipeline_->layout(), 0, 1, &unorm_set, 0,
                            nullptr);
    vkCmdPushConstants(cmd, unorm_pipeline_->layout(), VK_SHADER_STAGE_COMPUTE_BIT, 0, sizeof(params), &params);
    vkCmdDispatch(cmd, vulkan::group_count(count, 64), 1, 1);
    detail::record_compute_to_compute(cmd);
  }
  vkCmdBindPipeline(cmd, VK_PIPELINE_BIND_POINT_COMPUTE, pipeline_->pipeline());
  const VkDescriptorSet set = resources_->set();
  vkCmdBindDescriptorSets(cmd, VK_PIPELINE_BIND_POINT_COMPUTE, pipeline_->layout(), 0, 1, &set, 0, nullptr);
  for (std::size_t k = 1; k < levels_.size(); ++k) {
    const occlusion::PyramidLevel &below = levels_[k - 1], &level = levels_[k];
    const PyramidReduceParams params{std::uint32_t(below.offset), below.width, below.height, reversed_z ? 1u : 0u,
                                     std::uint32_t(level.offset), level.width, level.height, 0u};
    vkCmdPushConstants(cmd, pipeline_->layout(), VK_SHADER_STAGE_COMPUTE_BIT, 0, sizeof(params), &params);
    vkCmdDispatch(cmd, vulkan::group_count(level.width, PYRAMID_GROUP_SIDE),
                  vulkan::group_count(level.height, PYRAMID_GROUP_SIDE), 1);
    detail::record_compute_to_compute(cmd);
  }
  detail::record_exit_barrier(ctx_, cmd);
  reversed_z_ = reversed_z;
  built_ = true;
}

occlusion::DepthPyramid DepthPyramidPass::build(const DepthSource& source, bool reversed_z) {
  if (const std::string why = depth_source_problem(source); !why.empty())
    throw std::invalid_argument("depth pyramid: " + why);
  resize(source.width, source.height);
  last_gpu_ns_ = resources_->run([&](VkCommandBuffer cmd, VkQueryPool timestamps) {
    if (timestamps) vkCmdWriteTimestamp(cmd, VK_PIPELINE_STAGE_TOP_OF_PIPE_BIT, timestamps, 0);
    record(cmd, source, reversed_z);
    if (timestamps) vkCmdWriteTimestamp(cmd, VK_PIPELINE_STAGE_BOTTOM_OF_PIPE_BIT, timestamps, 1);
  });
  return read();
}

occlusion::DepthPyramid DepthPyramidPass::read() const {
  if (!built_) throw std::logic_error("depth pyramid: read() before any record()");
  occlusion::DepthPyramid p;
  p.width = width_;
  p.height = height_;
  p.reversed_z = reversed_z_;
  p.levels = levels_;
  p.texels.resize(levels_.back().offset + 1);
  std::memcpy(p.texels.data(), texels_.data(), p.texels.size() * sizeof(float));
  return p;
}

}  // namespace cullpipe::gpu
