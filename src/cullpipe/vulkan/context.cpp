#include "cullpipe/vulkan/context.hpp"

#include <algorithm>
#include <cctype>
#include <cstdio>
#include <cstdlib>
#include <cstring>

#include "cullpipe/vulkan/check.hpp"

namespace cullpipe::vulkan {

const char* result_name(VkResult r) {
  switch (r) {
#define CULLPIPE_RESULT(x) \
  case x:                  \
    return #x;
    CULLPIPE_RESULT(VK_SUCCESS)
    CULLPIPE_RESULT(VK_NOT_READY)
    CULLPIPE_RESULT(VK_TIMEOUT)
    CULLPIPE_RESULT(VK_EVENT_SET)
    CULLPIPE_RESULT(VK_EVENT_RESET)
    CULLPIPE_RESULT(VK_INCOMPLETE)
    CULLPIPE_RESULT(VK_ERROR_OUT_OF_HOST_MEMORY)
    CULLPIPE_RESULT(VK_ERROR_OUT_OF_DEVICE_MEMORY)
    CULLPIPE_RESULT(VK_ERROR_INITIALIZATION_FAILED)
    CULLPIPE_RESULT(VK_ERROR_DEVICE_LOST)
    CULLPIPE_RESULT(VK_ERROR_MEMORY_MAP_FAILED)
    CULLPIPE_RESULT(VK_ERROR_LAYER_NOT_PRESENT)
    CULLPIPE_RESULT(VK_ERROR_EXTENSION_NOT_PRESENT)
    CULLPIPE_RESULT(VK_ERROR_FEATURE_NOT_PRESENT)
    CULLPIPE_RESULT(VK_ERROR_INCOMPATIBLE_DRIVER)
    CULLPIPE_RESULT(VK_ERROR_TOO_MANY_OBJECTS)
    CULLPIPE_RESULT(VK_ERROR_FORMAT_NOT_SUPPORTED)
    CULLPIPE_RESULT(VK_ERROR_FRAGMENTED_POOL)
    CULLPIPE_RESULT(VK_ERROR_UNKNOWN)
    CULLPIPE_RESULT(VK_ERROR_OUT_OF_POOL_MEMORY)
    CULLPIPE_RESULT(VK_ERROR_INVALID_EXTERNAL_HANDLE)
    CULLPIPE_RESULT(VK_ERROR_FRAGMENTATION)
    CULLPIPE_RESULT(VK_ERROR_INVALID_OPAQUE_CAPTURE_ADDRESS)
    CULLPIPE_RESULT(VK_PIPELINE_COMPILE_REQUIRED)
#undef CULLPIPE_RESULT
    default:
      return "VK_RESULT_UNKNOWN";
  }
}

namespace {

constexpr const char* kValidationLayer = "VK_LAYER_KHRONOS_validation";
constexpr const char* kNoDeviceHint =
    "no Vulkan device found (install mesa-vulkan-drivers for lavapipe, or check VK_ICD_FILENAMES); "
    "the CPU backend (--backend cpu) still works";

std::string lower(std::string s) {
  std::transform(s.begin(), s.end(), s.begin(), [](unsigned char c) { return char(std::tolower(c)); });
  return s;
}

const char* type_name(VkPhysicalDeviceType t) {
  switch (t) {
    case VK_PHYSICAL_DEVICE_TYPE_DISCRETE_GPU:
      return "discrete";
    case VK_PHYSICAL_DEVICE_TYPE_INTEGRATED_GPU:
      return "integrated";
    case VK_PHYSICAL_DEVICE_TYPE_VIRTUAL_GPU:
      return "virtual";
    case VK_PHYSICAL_DEVICE_TYPE_CPU:
      return "cpu";
    default:
      return "other";
  }
}

DeviceInfo describe(VkPhysicalDevice pd) {
  VkPhysicalDeviceDriverProperties driver{VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_DRIVER_PROPERTIES, nullptr, {}, {}, {}, {}};
  VkPhysicalDeviceProperties2 props{VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_PROPERTIES_2, &driver, {}};
  VkPhysicalDeviceProperties basic{};
  vkGetPhysicalDeviceProperties(pd, &basic);
  DeviceInfo info;
  info.name = basic.deviceName;
  info.type = type_name(basic.deviceType);
  info.api_version = basic.apiVersion;
  if (basic.apiVersion >= VK_API_VERSION_1_2) {
    vkGetPhysicalDeviceProperties2(pd, &props);
    info.driver = std::string(driver.driverName) + " " + driver.driverInfo;
  }
  return info;
}

// Creates the instance; with validation, `messenger` is chained into the create info so
// messages raised during vkCreateInstance/vkDestroyInstance are reported too.
VkInstance create_instance(bool validation, const VkDebugUtilsMessengerCreateInfoEXT* messenger) {
  std::uint32_t api = 0;
  if (vkEnumerateInstanceVersion(&api) != VK_SUCCESS || api < VK_API_VERSION_1_2)
    throw Error("the Vulkan loader supports only API " + std::to_string(VK_API_VERSION_MAJOR(api)) + "." +
                std::to_string(VK_API_VERSION_MINOR(api)) + "; cullpipe needs Vulkan 1.2");

  std::vector<const char*> layers, extensions;
  VkValidationFeaturesEXT features{VK_STRUCTURE_TYPE_VALIDATION_FEATURES_EXT, nullptr, 0, nullptr, 0, nullptr};
  static const VkValidationFeatureEnableEXT enables[] = {VK_VALIDATION_FEATURE_ENABLE_SYNCHRONIZATION_VALIDATION_EXT};
  if (validation) {
    std::uint32_t n = 0;
    vkEnumerateInstanceLayerProperties(&n, nullptr);
    std::vector<VkLayerProperties> available(n);
    vkEnumerateInstanceLayerProperties(&n, available.data());
    const bool found = std::any_of(available.begin(), available.end(), [](const VkLayerProperties& l) {
      return std::strcmp(l.layerName, kValidationLayer) == 0;
    });
    if (!found)
      throw Error(std::string("validation was requested but ") + kValidationLayer +
                  " is not installed (Debian: apt-get install vulkan-validationlayers)");
    layers.push_back(kValidationLayer);
    extensions.push_back(VK_EXT_DEBUG_UTILS_EXTENSION_NAME);
    extensions.push_back(VK_EXT_VALIDATION_FEATURES_EXTENSION_NAME);
    features.enabledValidationFeatureCount = 1;
    features.pEnabledValidationFeatures = enables;
    features.pNext = messenger;
  }
  VkApplicationInfo app{VK_STRUCTURE_TYPE_APPLICATION_INFO, nullptr, "cullpipe", 1, "cullpipe", 1, VK_API_VERSION_1_2};
  VkInstanceCreateInfo info{VK_STRUCTURE_TYPE_INSTANCE_CREATE_INFO};
  info.pNext = validation ? &features : nullptr;
  info.pApplicationInfo = &app;
  info.enabledLayerCount = std::uint32_t(layers.size());
  info.ppEnabledLayerNames = layers.data();
  info.enabledExtensionCount = std::uint32_t(extensions.size());
  info.ppEnabledExtensionNames = extensions.data();
  VkInstance instance = VK_NULL_HANDLE;
  const VkResult r = vkCreateInstance(&info, nullptr, &instance);
  if (r == VK_ERROR_INCOMPATIBLE_DRIVER) throw Error(kNoDeviceHint, r);
  check(r, "vkCreateInstance");
  return instance;
}

std::vector<VkPhysicalDevice> physical_devices(VkInstance instance) {
  std::uint32_t n = 0;
  check(vkEnumeratePhysicalDevices(instance, &n, nullptr), "vkEnumeratePhysicalDevices");
  std::vector<VkPhysicalDevice> devices(n);
  if (n) check(vkEnumeratePhysicalDevices(instance, &n, devices.data()), "vkEnumeratePhysicalDevices");
  devices.resize(n);
  return devices;
}

// Returns the compute queue family index, or -1 if the device is unusable for cullpipe.
int usable_queue_family(VkPhysicalDevice pd, std::string& why) {
  VkPhysicalDeviceProperties props{};
  vkGetPhysicalDeviceProperties(pd, &props);
  if (props.apiVersion < VK_API_VERSION_1_2) {
    why = "supports only Vulkan " + std::to_string(VK_API_VERSION_MAJOR(props.apiVersion)) + "." +
          std::to_string(VK_API_VERSION_MINOR(props.apiVersion));
    return -1;
  }
  VkPhysicalDeviceSubgroupProperties sub{VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_SUBGROUP_PROPERTIES};
  VkPhysicalDeviceProperties2 p2{VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_PROPERTIES_2, &sub, {}};
  vkGetPhysicalDeviceProperties2(pd, &p2);
  const VkSubgroupFeatureFlags needed = VK_SUBGROUP_FEATURE_BASIC_BIT | VK_SUBGROUP_FEATURE_BALLOT_BIT;
  if (!(sub.supportedStages & VK_SHADER_STAGE_COMPUTE_BIT) || (sub.supportedOperations & needed) != needed) {
    why = "lacks subgroup basic+ballot operations in compute shaders";
    return -1;
  }
  std::uint32_t n = 0;
  vkGetPhysicalDeviceQueueFamilyProperties(pd, &n, nullptr);
  std::vector<VkQueueFamilyProperties> families(n);
  vkGetPhysicalDeviceQueueFamilyProperties(pd, &n, families.data());
  // Prefer a compute queue that also does graphics (the renderer draws from the culling
  // output on the same queue), then one with timestamps.
  int best = -1, best_score = -1;
  for (std::uint32_t i = 0; i < n; ++i) {
    if (!(families[i].queueFlags & VK_QUEUE_COMPUTE_BIT)) continue;
    const int score =
        ((families[i].queueFlags & VK_QUEUE_GRAPHICS_BIT) ? 2 : 0) + (families[i].timestampValidBits ? 1 : 0);
    if (score > best_score) best = int(i), best_score = score;
  }
  if (best < 0) why = "has no compute queue";
  return best;
}

}  // namespace

std::vector<DeviceInfo> list_devices() {
  VkInstance instance = create_instance(false, nullptr);
  std::vector<DeviceInfo> out;
  try {
    for (VkPhysicalDevice pd : physical_devices(instance)) out.push_back(describe(pd));
  } catch (...) {
    vkDestroyInstance(instance, nullptr);
    throw;
  }
  vkDestroyInstance(instance, nullptr);
  return out;
}

void Context::reserve_memory(VkDeviceSize bytes, const std::string& what) const {
  const VkDeviceSize budget = memory_budget_.load();
  const VkDeviceSize before = memory_in_use_.fetch_add(bytes);
  if (budget && before + bytes > budget) {
    memory_in_use_ -= bytes;
    throw Error("allocating " + what + " failed: VK_ERROR_OUT_OF_DEVICE_MEMORY (memory budget of " +
                    std::to_string(budget) + " bytes, " + std::to_string(before) + " in use)",
                VK_ERROR_OUT_OF_DEVICE_MEMORY);
  }
}

Context::Context(const ContextOptions& options)
    : on_message_(options.on_message),
      map_device_memory_(options.map_device_memory),
      memory_budget_(options.memory_budget) {
  try {
    VkDebugUtilsMessengerCreateInfoEXT info{VK_STRUCTURE_TYPE_DEBUG_UTILS_MESSENGER_CREATE_INFO_EXT};
    info.messageSeverity =
        VK_DEBUG_UTILS_MESSAGE_SEVERITY_WARNING_BIT_EXT | VK_DEBUG_UTILS_MESSAGE_SEVERITY_ERROR_BIT_EXT;
    info.messageType = VK_DEBUG_UTILS_MESSAGE_TYPE_GENERAL_BIT_EXT | VK_DEBUG_UTILS_MESSAGE_TYPE_VALIDATION_BIT_EXT |
                       VK_DEBUG_UTILS_MESSAGE_TYPE_PERFORMANCE_BIT_EXT;
    info.pfnUserCallback = &Context::debug_callback;
    info.pUserData = this;
    instance_ = create_instance(options.validation, options.validation ? &info : nullptr);
    if (options.validation) {
      auto create = reinterpret_cast<PFN_vkCreateDebugUtilsMessengerEXT>(
          vkGetInstanceProcAddr(instance_, "vkCreateDebugUtilsMessengerEXT"));
      if (!create) throw Error("vkCreateDebugUtilsMessengerEXT is not available");
      CULLPIPE_VK_CHECK(create(instance_, &info, nullptr, &messenger_));
    }

    const std::vector<VkPhysicalDevice> devices = physical_devices(instance_);
    if (devices.empty()) throw Error(kNoDeviceHint);

    std::string filter = options.device_filter;
    if (filter.empty())
      if (const char* env = std::getenv("CULLPIPE_DEVICE")) filter = env;
    filter = lower(filter);

    std::string rejected;
    int chosen = -1, chosen_family = -1, chosen_rank = 99;
    for (std::size_t i = 0; i < devices.size(); ++i) {
      const DeviceInfo d = describe(devices[i]);
      if (!filter.empty() && lower(d.name).find(filter) == std::string::npos) {
        rejected += "\n  " + d.name + " (" + d.type + "): name does not match";
        continue;
      }
      std::string why;
      const int family = usable_queue_family(devices[i], why);
      if (family < 0) {
        rejected += "\n  " + d.name + " (" + d.type + "): " + why;
        continue;
      }
      // Rank: discrete/integrated GPU first, then virtual, then CPU, in enumeration order.
      const int rank = (d.type == "discrete" || d.type == "integrated") ? 0 : d.type == "virtual" ? 1 : 2;
      if (rank < chosen_rank) {
        chosen = int(i);
        chosen_family = family;
        chosen_rank = rank;
      }
    }
    if (chosen < 0)
      throw Error("no usable Vulkan device" + (filter.empty() ? std::string() : " matching '" + filter + "'") +
                  "; devices seen:" + rejected);

    physical_device_ = devices[std::size_t(chosen)];
    queue_family_ = std::uint32_t(chosen_family);
    read_device_properties();

    // Features the renderer's indirect draws use, when the device has them.
    VkPhysicalDeviceVulkan12Features f12{VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_VULKAN_1_2_FEATURES};
    VkPhysicalDeviceFeatures2 f2{VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_FEATURES_2, &f12, {}};
    vkGetPhysicalDeviceFeatures2(physical_device_, &f2);
    VkPhysicalDeviceVulkan12Features enable12{VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_VULKAN_1_2_FEATURES};
    enable12.drawIndirectCount = f12.drawIndirectCount;
    VkPhysicalDeviceFeatures2 enable{VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_FEATURES_2, &enable12, {}};
    enable.features.multiDrawIndirect = f2.features.multiDrawIndirect;
    enable.features.drawIndirectFirstInstance = f2.features.drawIndirectFirstInstance;
    enable.features.pipelineStatisticsQuery = f2.features.pipelineStatisticsQuery;
    enable.features.geometryShader = f2.features.geometryShader;  // (gl_PrimitiveID in fragment shaders)
    draw_indirect_count_ =
        f12.drawIndirectCount && f2.features.multiDrawIndirect && f2.features.drawIndirectFirstInstance;
    pipeline_statistics_ = f2.features.pipelineStatisticsQuery;
    primitive_ids_ = f2.features.geometryShader;

    const float priority = 1.0f;
    VkDeviceQueueCreateInfo queue_info{VK_STRUCTURE_TYPE_DEVICE_QUEUE_CREATE_INFO};
    queue_info.queueFamilyIndex = queue_family_;
    queue_info.queueCount = 1;
    queue_info.pQueuePriorities = &priority;
    VkDeviceCreateInfo device_info{VK_STRUCTURE_TYPE_DEVICE_CREATE_INFO};
    device_info.pNext = &enable;
    device_info.queueCreateInfoCount = 1;
    device_info.pQueueCreateInfos = &queue_info;
    CULLPIPE_VK_CHECK(vkCreateDevice(physical_device_, &device_info, nullptr, &device_));
    vkGetDeviceQueue(device_, queue_family_, 0, &queue_);
    create_pool_and_fence();
  } catch (...) {
    destroy();
    throw;
  }
}

Context::Context(const ExternalDevice& external) : owns_device_(false) {
  if (!external.instance || !external.physical_device || !external.device || !external.queue)
    throw Error("ExternalDevice: instance, physical device, device and queue must all be given");
  instance_ = external.instance;
  physical_device_ = external.physical_device;
  device_ = external.device;
  queue_ = external.queue;
  queue_family_ = external.queue_family;
  try {
    std::string why;
    if (usable_queue_family(physical_device_, why) < 0)
      throw Error("ExternalDevice: " + describe(physical_device_).name + " " + why);
    std::uint32_t nfam = 0;
    vkGetPhysicalDeviceQueueFamilyProperties(physical_device_, &nfam, nullptr);
    std::vector<VkQueueFamilyProperties> families(nfam);
    vkGetPhysicalDeviceQueueFamilyProperties(physical_device_, &nfam, families.data());
    if (queue_family_ >= nfam || !(families[queue_family_].queueFlags & VK_QUEUE_COMPUTE_BIT))
      throw Error("ExternalDevice: queue family " + std::to_string(queue_family_) + " has no compute support");
    read_device_properties();
    draw_indirect_count_ = external.draw_indirect_count;  // the caller chose the device's features
    pipeline_statistics_ = external.pipeline_statistics;
    primitive_ids_ = external.primitive_ids;
    create_pool_and_fence();
  } catch (...) {
    destroy();
    throw;
  }
}

void Context::read_device_properties() {
  info_ = describe(physical_device_);
  vkGetPhysicalDeviceProperties(physical_device_, &properties_);
  vkGetPhysicalDeviceMemoryProperties(physical_device_, &memory_properties_);
  std::uint32_t nfam = 0;
  vkGetPhysicalDeviceQueueFamilyProperties(physical_device_, &nfam, nullptr);
  std::vector<VkQueueFamilyProperties> families(nfam);
  vkGetPhysicalDeviceQueueFamilyProperties(physical_device_, &nfam, families.data());
  timestamp_valid_bits_ = families[queue_family_].timestampValidBits;
  timestamp_period_ns_ = timestamp_valid_bits_ > 0 ? properties_.limits.timestampPeriod : 0.0;
  queue_flags_ = families[queue_family_].queueFlags;
}

void Context::create_pool_and_fence() {
  VkCommandPoolCreateInfo pool_info{VK_STRUCTURE_TYPE_COMMAND_POOL_CREATE_INFO};
  pool_info.flags = VK_COMMAND_POOL_CREATE_RESET_COMMAND_BUFFER_BIT;
  pool_info.queueFamilyIndex = queue_family_;
  CULLPIPE_VK_CHECK(vkCreateCommandPool(device_, &pool_info, nullptr, &command_pool_));
  VkFenceCreateInfo fence_info{VK_STRUCTURE_TYPE_FENCE_CREATE_INFO};
  CULLPIPE_VK_CHECK(vkCreateFence(device_, &fence_info, nullptr, &fence_));
}

Context::~Context() { destroy(); }

void Context::destroy() {
  if (device_) {
    // A borrowed device may be busy with the caller's work: do not wait for it (our own
    // submissions are waited for in submit_and_wait).
    if (owns_device_) vkDeviceWaitIdle(device_);
    if (fence_) vkDestroyFence(device_, fence_, nullptr);
    if (command_pool_) vkDestroyCommandPool(device_, command_pool_, nullptr);
    if (owns_device_) vkDestroyDevice(device_, nullptr);
  }
  if (!owns_device_) {  // borrowed: the caller destroys them
    device_ = VK_NULL_HANDLE;
    instance_ = VK_NULL_HANDLE;
  }
  if (messenger_) {
    auto destroy_messenger = reinterpret_cast<PFN_vkDestroyDebugUtilsMessengerEXT>(
        vkGetInstanceProcAddr(instance_, "vkDestroyDebugUtilsMessengerEXT"));
    if (destroy_messenger) destroy_messenger(instance_, messenger_, nullptr);
  }
  if (instance_) vkDestroyInstance(instance_, nullptr);
  fence_ = VK_NULL_HANDLE;
  command_pool_ = VK_NULL_HANDLE;
  device_ = VK_NULL_HANDLE;
  messenger_ = VK_NULL_HANDLE;
  instance_ = VK_NULL_HANDLE;
}

VKAPI_ATTR VkBool32 VKAPI_CALL Context::debug_callback(VkDebugUtilsMessageSeverityFlagBitsEXT severity,
                                                       VkDebugUtilsMessageTypeFlagsEXT,
                                                       const VkDebugUtilsMessengerCallbackDataEXT* data, void* user) {
  auto* self = static_cast<Context*>(user);
  std::string text = std::string("[vulkan validation ") +
                     (severity & VK_DEBUG_UTILS_MESSAGE_SEVERITY_ERROR_BIT_EXT ? "error" : "warning") + "] " +
                     (data && data->pMessage ? data->pMessage : "(no message)");
  self->message_count_.fetch_add(1);
  {
    std::lock_guard lock(self->messages_mutex_);
    self->messages_.push_back(text);
  }
  if (self->on_message_)
    self->on_message_(text);
  else
    std::fprintf(stderr, "%s\n", text.c_str());
  return VK_FALSE;
}

std::vector<std::string> Context::take_validation_messages() {
  std::lock_guard lock(messages_mutex_);
  std::vector<std::string> out;
  out.swap(messages_);
  return out;
}

std::uint32_t Context::find_memory_type(std::uint32_t type_bits, VkMemoryPropertyFlags required,
                                        VkMemoryPropertyFlags preferred) const {
  int fallback = -1;
  for (std::uint32_t i = 0; i < memory_properties_.memoryTypeCount; ++i) {
    if (!(type_bits & (1u << i))) continue;
    const VkMemoryPropertyFlags flags = memory_properties_.memoryTypes[i].propertyFlags;
    if ((flags & required) != required) continue;
    if ((flags & preferred) == preferred) return i;
    if (fallback < 0) fallback = int(i);
  }
  if (fallback < 0) throw Error("no Vulkan memory type with the required properties");
  return std::uint32_t(fallback);
}

void Context::submit_and_wait(VkCommandBuffer cmd) const {
  VkSubmitInfo submit{VK_STRUCTURE_TYPE_SUBMIT_INFO};
  submit.commandBufferCount = 1;
  submit.pCommandBuffers = &cmd;
  CULLPIPE_VK_CHECK(vkResetFences(device_, 1, &fence_));
  CULLPIPE_VK_CHECK(vkQueueSubmit(queue_, 1, &submit, fence_));
  CULLPIPE_VK_CHECK(vkWaitForFences(device_, 1, &fence_, VK_TRUE, UINT64_MAX));
}

}  // namespace cullpipe::vulkan
