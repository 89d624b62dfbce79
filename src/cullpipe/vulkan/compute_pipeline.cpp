#include "cullpipe/vulkan/compute_pipeline.hpp"

#include <string>
#include <vector>

#include "cullpipe/vulkan/check.hpp"

namespace cullpipe::vulkan {

std::string spirv_problem(std::span<const std::uint32_t> words) {
  // The module's structure (SPIR-V spec 2.3-2.4): a 5-word header (magic, version, generator,
  // id bound, 0), then instructions whose first word holds their word count in the high
  // 16 bits. Drivers are not required to survive malformed modules, so they never get one.
  if (words.size() < 5) return "shorter than the 5-word header (" + std::to_string(words.size()) + " words)";
  if (words[0] != 0x07230203u) return "bad magic number";
  const std::uint32_t major = words[1] >> 16 & 0xff;
  if (major != 1 || (words[1] & 0xff0000ffu) != 0) return "unknown version word";
  if (words[3] == 0) return "id bound of 0";
  if (words[4] != 0) return "reserved header word is not 0";
  std::size_t at = 5, instructions = 0;
  while (at < words.size()) {
    const std::uint32_t count = words[at] >> 16;
    if (count == 0) return "instruction at word " + std::to_string(at) + " has a word count of 0";
    if (count > words.size() - at)
      return "instruction at word " + std::to_string(at) + " runs past the end (truncated module?)";
    at += count;
    ++instructions;
  }
  if (instructions == 0) return "no instructions";
  return {};
}

ComputePipeline::ComputePipeline(const Context& ctx, const ComputePipelineDesc& desc)
    : device_(ctx.device()), push_constant_size_(desc.push_constant_size) {
  const std::string name = desc.name;
  if (const std::string why = spirv_problem(desc.spirv); !why.empty())
    throw Error(name + ": SPIR-V is corrupt: " + why);
  if (desc.push_constant_size > ctx.properties().limits.maxPushConstantsSize)
    throw Error(name + ": needs " + std::to_string(desc.push_constant_size) +
                " bytes of push constants, device allows " +
                std::to_string(ctx.properties().limits.maxPushConstantsSize));

  VkShaderModule module = VK_NULL_HANDLE;
  try {
    std::vector<VkDescriptorSetLayoutBinding> bindings(desc.binding_count);
    for (std::uint32_t i = 0; i < desc.binding_count; ++i) {
      const bool texel = i < 32 && (desc.uniform_texel_bindings >> i & 1u),
                 storage_texel = i < 32 && (desc.storage_texel_bindings >> i & 1u);
      bindings[i] = {i,
                     texel           ? VK_DESCRIPTOR_TYPE_UNIFORM_TEXEL_BUFFER
                     : storage_texel ? VK_DESCRIPTOR_TYPE_STORAGE_TEXEL_BUFFER
                                     : VK_DESCRIPTOR_TYPE_STORAGE_BUFFER,
                     1, VK_SHADER_STAGE_COMPUTE_BIT, nullptr};
    }
    VkDescriptorSetLayoutCreateInfo set_info{VK_STRUCTURE_TYPE_DESCRIPTOR_SET_LAYOUT_CREATE_INFO};
    set_info.bindingCount = std::uint32_t(bindings.size());
    set_info.pBindings = bindings.data();
    CULLPIPE_VK_CHECK(vkCreateDescriptorSetLayout(device_, &set_info, nullptr, &set_layout_));

    VkPushConstantRange range{VK_SHADER_STAGE_COMPUTE_BIT, 0, desc.push_constant_size};
    VkPipelineLayoutCreateInfo layout_info{VK_STRUCTURE_TYPE_PIPELINE_LAYOUT_CREATE_INFO};
    layout_info.setLayoutCount = 1;
    layout_info.pSetLayouts = &set_layout_;
    layout_info.pushConstantRangeCount = desc.push_constant_size ? 1 : 0;
    layout_info.pPushConstantRanges = &range;
    CULLPIPE_VK_CHECK(vkCreatePipelineLayout(device_, &layout_info, nullptr, &layout_));

    VkShaderModuleCreateInfo module_info{VK_STRUCTURE_TYPE_SHADER_MODULE_CREATE_INFO};
    module_info.codeSize = desc.spirv.size_bytes();
    module_info.pCode = desc.spirv.data();
    CULLPIPE_VK_CHECK(vkCreateShaderModule(device_, &module_info, nullptr, &module));

    std::vector<VkSpecializationMapEntry> entries(desc.specialization.size());
    for (std::uint32_t i = 0; i < entries.size(); ++i)
      entries[i] = {i, std::uint32_t(i * sizeof(std::uint32_t)), sizeof(std::uint32_t)};
    VkSpecializationInfo spec{std::uint32_t(entries.size()), entries.data(), desc.specialization.size_bytes(),
                              desc.specialization.data()};
    VkComputePipelineCreateInfo info{VK_STRUCTURE_TYPE_COMPUTE_PIPELINE_CREATE_INFO};
    info.stage = {VK_STRUCTURE_TYPE_PIPELINE_SHADER_STAGE_CREATE_INFO};
    info.stage.stage = VK_SHADER_STAGE_COMPUTE_BIT;
    info.stage.module = module;
    info.stage.pName = "main";
    info.stage.pSpecializationInfo = entries.empty() ? nullptr : &spec;
    info.layout = layout_;
    const VkResult r = vkCreateComputePipelines(device_, VK_NULL_HANDLE, 1, &info, nullptr, &pipeline_);
    if (r != VK_SUCCESS) throw Error(name + ": vkCreateComputePipelines failed: " + result_name(r), r);
    vkDestroyShaderModule(device_, module, nullptr);
  } catch (...) {
    if (module) vkDestroyShaderModule(device_, module, nullptr);
    release();
    throw;
  }
}

ComputePipeline::~ComputePipeline() { release(); }

void ComputePipeline::release() {
  if (pipeline_) vkDestroyPipeline(device_, pipeline_, nullptr);
  if (layout_) vkDestroyPipelineLayout(device_, layout_, nullptr);
  if (set_layout_) vkDestroyDescriptorSetLayout(device_, set_layout_, nullptr);
  pipeline_ = VK_NULL_HANDLE;
  layout_ = VK_NULL_HANDLE;
  set_layout_ = VK_NULL_HANDLE;
}

}  // namespace cullpipe::vulkan
