#include "cullpipe/vulkan/buffer.hpp"

#include <string>

#include "cullpipe/vulkan/check.hpp"

namespace cullpipe::vulkan {

Buffer::Buffer(const Context& ctx, VkDeviceSize size, VkBufferUsageFlags usage, const char* what, MemoryUse use)
    : ctx_(&ctx), device_(ctx.device()), size_(size) {
  const std::string context = std::string(what) + " (" + std::to_string(size) + " bytes)";
  VkBufferCreateInfo info{VK_STRUCTURE_TYPE_BUFFER_CREATE_INFO};
  info.size = size;
  info.usage = usage;
  info.sharingMode = VK_SHARING_MODE_EXCLUSIVE;
  VkResult r = vkCreateBuffer(device_, &info, nullptr, &buffer_);
  if (r != VK_SUCCESS) throw Error("creating " + context + " failed: " + result_name(r), r);

  VkMemoryRequirements req{};
  vkGetBufferMemoryRequirements(device_, buffer_, &req);
  try {
    ctx.reserve_memory(req.size, context);
    reserved_ = req.size;
    constexpr VkMemoryPropertyFlags host = VK_MEMORY_PROPERTY_HOST_VISIBLE_BIT | VK_MEMORY_PROPERTY_HOST_COHERENT_BIT,
                                    device = VK_MEMORY_PROPERTY_DEVICE_LOCAL_BIT;
    // Device use: device-local, and mapped only where it is host-visible too (unified memory).
    const VkMemoryPropertyFlags required = use == MemoryUse::Host ? host : device,
                                preferred = use == MemoryUse::Host ? device : host;
    if (Allocator* allocator = ctx.allocator()) {
      allocation_ = allocator->allocate(req, required, preferred, what);
      allocator_ = allocator;  // from here on reset() gives it back
      if (!allocation_.memory || (use == MemoryUse::Host && !allocation_.mapped))
        throw Error("the allocator gave " + context + (allocation_.memory ? " unmapped memory" : " no memory"),
                    VK_ERROR_MEMORY_MAP_FAILED);
      if (req.alignment && allocation_.offset % req.alignment)
        throw Error("the allocator gave " + context + " memory at offset " + std::to_string(allocation_.offset) +
                        ", not a multiple of its alignment " + std::to_string(req.alignment),
                    VK_ERROR_VALIDATION_FAILED_EXT);
      r = vkBindBufferMemory(device_, buffer_, allocation_.memory, allocation_.offset);
      if (r != VK_SUCCESS) throw Error("binding memory of " + context + " failed: " + result_name(r), r);
      if (use == MemoryUse::Host || ctx.map_device_memory()) mapped_ = allocation_.mapped;
    } else {
      VkMemoryAllocateInfo alloc{VK_STRUCTURE_TYPE_MEMORY_ALLOCATE_INFO};
      alloc.allocationSize = req.size;
      alloc.memoryTypeIndex = ctx.find_memory_type(req.memoryTypeBits, required, preferred);
      const VkMemoryPropertyFlags flags = ctx.memory_type_flags(alloc.memoryTypeIndex);
      r = vkAllocateMemory(device_, &alloc, nullptr, &memory_);
      if (r != VK_SUCCESS) throw Error("allocating memory for " + context + " failed: " + result_name(r), r);
      r = vkBindBufferMemory(device_, buffer_, memory_, 0);
      if (r != VK_SUCCESS) throw Error("binding memory of " + context + " failed: " + result_name(r), r);
      const bool map = use == MemoryUse::Host || (ctx.map_device_memory() && (flags & host) == host);
      if (map) {
        r = vkMapMemory(device_, memory_, 0, VK_WHOLE_SIZE, 0, &mapped_);
        if (r != VK_SUCCESS) throw Error("mapping " + context + " failed: " + result_name(r), r);
      }
    }
  } catch (...) {
    reset();
    throw;
  }
}

void copy_buffer(const Context& ctx, const Buffer& src, const Buffer& dst, VkDeviceSize bytes) {
  VkCommandBufferAllocateInfo alloc{VK_STRUCTURE_TYPE_COMMAND_BUFFER_ALLOCATE_INFO, nullptr, ctx.command_pool(),
                                    VK_COMMAND_BUFFER_LEVEL_PRIMARY, 1};
  VkCommandBuffer cmd = VK_NULL_HANDLE;
  CULLPIPE_VK_CHECK(vkAllocateCommandBuffers(ctx.device(), &alloc, &cmd));
  struct Free {
    const Context& ctx;
    VkCommandBuffer cmd;
    ~Free() { vkFreeCommandBuffers(ctx.device(), ctx.command_pool(), 1, &cmd); }
  } free_cmd{ctx, cmd};
  VkCommandBufferBeginInfo begin{VK_STRUCTURE_TYPE_COMMAND_BUFFER_BEGIN_INFO};
  begin.flags = VK_COMMAND_BUFFER_USAGE_ONE_TIME_SUBMIT_BIT;
  CULLPIPE_VK_CHECK(vkBeginCommandBuffer(cmd, &begin));
  // After every earlier use of dst (a pass reading the scene it replaces), then the copy, then
  // visible to every later compute shader and transfer on the queue (scene buffers are read by
  // the culling passes).
  const VkMemoryBarrier before{VK_STRUCTURE_TYPE_MEMORY_BARRIER, nullptr, 0, 0};
  vkCmdPipelineBarrier(cmd, VK_PIPELINE_STAGE_ALL_COMMANDS_BIT, VK_PIPELINE_STAGE_TRANSFER_BIT, 0, 1, &before, 0,
                       nullptr, 0, nullptr);
  const VkBufferCopy region{0, 0, bytes};
  vkCmdCopyBuffer(cmd, src.handle(), dst.handle(), 1, &region);
  const VkMemoryBarrier after{VK_STRUCTURE_TYPE_MEMORY_BARRIER, nullptr, VK_ACCESS_TRANSFER_WRITE_BIT,
                              VK_ACCESS_SHADER_READ_BIT | VK_ACCESS_SHADER_WRITE_BIT | VK_ACCESS_TRANSFER_READ_BIT |
                                  VK_ACCESS_TRANSFER_WRITE_BIT};
  vkCmdPipelineBarrier(cmd, VK_PIPELINE_STAGE_TRANSFER_BIT,
                       VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT | VK_PIPELINE_STAGE_TRANSFER_BIT, 0, 1, &after, 0, nullptr,
                       0, nullptr);
  CULLPIPE_VK_CHECK(vkEndCommandBuffer(cmd));
  ctx.submit_and_wait(cmd);
  ctx.count_staged(bytes);
}

Buffer Buffer::borrow(VkBuffer handle, VkDeviceSize size, void* mapped) {
  Buffer b;
  b.buffer_ = handle;
  b.size_ = size;
  b.mapped_ = mapped;
  b.borrowed_ = true;
  return b;
}

Buffer& Buffer::operator=(Buffer&& o) noexcept {
  if (this != &o) {
    reset();
    std::swap(ctx_, o.ctx_);
    std::swap(reserved_, o.reserved_);
    std::swap(device_, o.device_);
    std::swap(buffer_, o.buffer_);
    std::swap(memory_, o.memory_);
    std::swap(size_, o.size_);
    std::swap(mapped_, o.mapped_);
    std::swap(allocator_, o.allocator_);
    std::swap(allocation_, o.allocation_);
    std::swap(borrowed_, o.borrowed_);
  }
  return *this;
}

void Buffer::reset() {
  if (memory_) {
    if (mapped_) vkUnmapMemory(device_, memory_);
    vkFreeMemory(device_, memory_, nullptr);
  }
  if (buffer_ && !borrowed_) vkDestroyBuffer(device_, buffer_, nullptr);
  borrowed_ = false;
  if (allocator_) allocator_->free(allocation_);
  allocator_ = nullptr;
  allocation_ = {};
  if (ctx_ && reserved_) ctx_->release_memory(reserved_);
  reserved_ = 0;
  buffer_ = VK_NULL_HANDLE;
  memory_ = VK_NULL_HANDLE;
  mapped_ = nullptr;
  size_ = 0;
}

}  // namespace cullpipe::vulkan
