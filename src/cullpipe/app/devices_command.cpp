#include <ostream>

#include "cullpipe/app/commands.hpp"
#include "cullpipe/app/guard.hpp"
#include "cullpipe/vulkan/context.hpp"

namespace cullpipe::app {

int devices_command(std::ostream& out, std::ostream& err) {
  return guarded(err, [&]() -> int {
    const auto devices = vulkan::list_devices();
    if (devices.empty()) {
      err << "error: no Vulkan device found (install mesa-vulkan-drivers for lavapipe)\n";
      return kExitNoDevice;
    }
    for (std::size_t i = 0; i < devices.size(); ++i) {
      const auto& d = devices[i];
      out << i << ": " << d.name << " (" << d.type << ", Vulkan " << VK_API_VERSION_MAJOR(d.api_version) << "."
          << VK_API_VERSION_MINOR(d.api_version) << "." << VK_API_VERSION_PATCH(d.api_version) << ", " << d.driver
          << ")\n";
    }
    return kExitOk;
  });
}

}  // namespace cullpipe::app
