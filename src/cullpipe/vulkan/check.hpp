#pragma once
#include <vulkan/vulkan.h>

#include <stdexcept>
#include <string>

namespace cullpipe::vulkan {

/// A failed Vulkan call or an unusable device. `result` is VK_SUCCESS for errors that are not
/// a VkResult (for example "no Vulkan device").
class Error : public std::runtime_error {
 public:
  Error(const std::string& what, VkResult result = VK_SUCCESS) : std::runtime_error(what), result_(result) {}
  VkResult result() const { return result_; }

 private:
  VkResult result_;
};

/// The enumerant name of a VkResult, e.g. "VK_ERROR_OUT_OF_DEVICE_MEMORY".
const char* result_name(VkResult result);

/// Throws vulkan::Error("<call> failed: <VK_...>") unless result is VK_SUCCESS.
inline void check(VkResult result, const char* call) {
  if (result != VK_SUCCESS) throw Error(std::string(call) + " failed: " + result_name(result), result);
}

}  // namespace cullpipe::vulkan

/// Checks a VkResult-returning call, naming the call in the error.
#define CULLPIPE_VK_CHECK(call) ::cullpipe::vulkan::check((call), #call)
