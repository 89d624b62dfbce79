#pragma once
#include <vulkan/vulkan.h>

#include <cstdint>
#include <span>
#include <string>

#include "cullpipe/vulkan/context.hpp"

namespace cullpipe::vulkan {

/// What a compute pipeline is built from.
struct ComputePipelineDesc {
  std::span<const std::uint32_t> spirv;           ///< SPIR-V words, entry point "main"
  std::uint32_t binding_count = 0;                ///< bindings 0..n-1 of set 0: storage buffers, except those below
  std::uint32_t push_constant_size = 0;           ///< bytes; checked against the device limit
  std::span<const std::uint32_t> specialization;  ///< values of constant_id 0..n-1 (32-bit each)
  const char* name = "compute pipeline";          ///< for error messages
  std::uint32_t uniform_texel_bindings = 0;       ///< bit i set: binding i is a uniform texel buffer
  std::uint32_t storage_texel_bindings = 0;       ///< bit i set: binding i is a storage texel buffer
};

/// Why `words` is not a structurally sound SPIR-V module (header, then instructions that
/// exactly fill the words), or an empty string. ComputePipeline refuses such a module with
/// vulkan::Error before the driver sees it.
std::string spirv_problem(std::span<const std::uint32_t> words);

/// A compute pipeline with its descriptor-set layout and pipeline layout. Move-free; the
/// owner keeps it alive while command buffers that use it are pending.
class ComputePipeline {
 public:
  ComputePipeline(const Context& ctx, const ComputePipelineDesc& desc);
  ~ComputePipeline();
  ComputePipeline(const ComputePipeline&) = delete;
  ComputePipeline& operator=(const ComputePipeline&) = delete;

  VkPipeline pipeline() const { return pipeline_; }
  VkPipelineLayout layout() const { return layout_; }
  VkDescriptorSetLayout set_layout() const { return set_layout_; }
  std::uint32_t push_constant_size() const { return push_constant_size_; }

 private:
  void release();

  VkDevice device_;
  VkDescriptorSetLayout set_layout_ = VK_NULL_HANDLE;
  VkPipelineLayout layout_ = VK_NULL_HANDLE;
  VkPipeline pipeline_ = VK_NULL_HANDLE;
  std::uint32_t push_constant_size_ = 0;
};

/// Workgroups needed for `items` invocations at `group_size` per group (ceiling division).
constexpr std::uint32_t group_count(std::uint64_t items, std::uint32_t group_size) {
  return std::uint32_t((items + group_size - 1) / group_size);
}

}  // namespace cullpipe::vulkan
