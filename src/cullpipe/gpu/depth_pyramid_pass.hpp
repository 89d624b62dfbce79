#pragma once
// The depth pyramid on the GPU: copies a depth image into level 0 of one float buffer (unorm
// depth through a conversion pass, shaders/depth_unorm.comp) and reduces it level by level
// (shaders/depth_pyramid.comp), giving the bits occlusion::build_depth_pyramid (or
// build_unorm_depth_pyramid) gives on the CPU.
#include <vulkan/vulkan.h>

#include <cstdint>
#include <memory>
#include <span>
#include <string>
#include <vector>

#include "cullpipe/cull/depth_pyramid.hpp"
#include "cullpipe/vulkan/buffer.hpp"
#include "cullpipe/vulkan/compute_pipeline.hpp"
#include "cullpipe/vulkan/context.hpp"

namespace cullpipe::gpu {

namespace detail {
class PassResources;
}

/// A depth image to reduce: the renderer's depth attachment or any an engine hands in. The
/// image needs VK_IMAGE_USAGE_TRANSFER_SRC_BIT; `layout` is its layout when the pass runs, and
/// it is in that layout again after (the pass moves it to TRANSFER_SRC_OPTIMAL for its copy
/// unless it is GENERAL or TRANSFER_SRC_OPTIMAL already). Earlier depth writes to it are made
/// visible by the pass's own barrier.
struct DepthSource {
  VkImage image = VK_NULL_HANDLE;
  VkImageLayout layout = VK_IMAGE_LAYOUT_DEPTH_STENCIL_ATTACHMENT_OPTIMAL;
  /// D32_SFLOAT or D32_SFLOAT_S8_UINT (the stored floats kept), or D16_UNORM, D16_UNORM_S8_UINT,
  /// X8_D24_UNORM_PACK32 or D24_UNORM_S8_UINT (each value q kept as
  /// occlusion::unorm_depth_float(q): the farthest depth a fragment it lets through can have,
  /// rounded outward); others are refused by name.
  VkFormat format = VK_FORMAT_D32_SFLOAT;
  std::uint32_t width = 0, height = 0;
};

/// Why `source` cannot be reduced (the format, layout or size, named), or an empty string.
std::string depth_source_problem(const DepthSource& source);

class DepthPyramidPass {
 public:
  explicit DepthPyramidPass(const vulkan::Context& ctx);
  ~DepthPyramidPass();
  DepthPyramidPass(const DepthPyramidPass&) = delete;
  DepthPyramidPass& operator=(const DepthPyramidPass&) = delete;

  /// Sizes the pyramid for a width x height depth image (levels as occlusion::pyramid_levels);
  /// nothing changes when the size is the same. Throws std::invalid_argument for a size of 0 or
  /// past occlusion::kMaxViewportSide, std::length_error past the device's buffer limits; the
  /// pyramid is as it was then.
  void resize(std::uint32_t width, std::uint32_t height);

  /// Records the pass into `cmd` (a queue with transfer and compute): resizes for `source` if
  /// needed, copies it and builds every level; after it, compute shaders, indirect draws and
  /// the host may read texels(). Throws std::invalid_argument naming what is wrong with
  /// `source` (depth_source_problem) before recording anything.
  void record(VkCommandBuffer cmd, const DepthSource& source, bool reversed_z);

  /// record() on the pass's own command buffer, submitted and waited for; the pyramid read back.
  occlusion::DepthPyramid build(const DepthSource& source, bool reversed_z);

  /// The pyramid as the last completed record() left it, read back (the caller has waited).
  occlusion::DepthPyramid read() const;

  /// Every level's texels, level k from levels()[k].offset floats in.
  const vulkan::Buffer& texels() const { return texels_; }
  std::span<const occlusion::PyramidLevel> levels() const { return levels_; }
  std::uint32_t width() const { return width_; }
  std::uint32_t height() const { return height_; }
  /// The depth direction of the last record() (the pyramid's farthest is the smallest if true).
  bool reversed_z() const { return reversed_z_; }
  /// Whether record() has run since the last resize: texels() holds a pyramid once that
  /// command buffer has executed (build() waits for it).
  bool built() const { return built_; }
  /// Changes whenever texels() is a new buffer, and is never the same for two buffers of any
  /// passes (descriptor sets holding the old one must be written again); never 0.
  std::uint64_t generation() const { return generation_; }
  /// GPU time of the last build(), nanoseconds (0 without timestamps).
  double last_gpu_ns() const { return last_gpu_ns_; }

 private:
  const vulkan::Context& ctx_;
  std::unique_ptr<vulkan::ComputePipeline> pipeline_;
  std::unique_ptr<detail::PassResources> resources_;
  vulkan::Buffer texels_;
  // Unorm depth: the copied integers, and the pass that turns them into level 0 (made on first use).
  vulkan::Buffer raw_;
  std::unique_ptr<vulkan::ComputePipeline> unorm_pipeline_;
  std::unique_ptr<detail::PassResources> unorm_resources_;
  bool unorm_descriptors_dirty_ = true;
  std::uint64_t unorm_generation_ = 0;  // the texels' generation its descriptor set holds
  void prepare_unorm(unsigned bits);    // the raw buffer, pipeline and set for unorm depth
  std::vector<occlusion::PyramidLevel> levels_;
  std::uint32_t width_ = 0, height_ = 0;
  double last_gpu_ns_ = 0.0;
  bool reversed_z_ = false;
  bool built_ = false;
  std::uint64_t generation_ = 0;
};

}  // namespace cullpipe::gpu
