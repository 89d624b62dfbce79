#pragma once
#include <exception>
#include <new>
#include <ostream>
#include <stdexcept>

#include "cullpipe/app/commands.hpp"
#include "cullpipe/scene/scene.hpp"
#include "cullpipe/vulkan/check.hpp"

namespace cullpipe::app {

/// Runs a command body, turning exceptions into an "error: ..." line and an exit code.
template <class F>
int guarded(std::ostream& err, F&& body) {
  try {
    return body();
  } catch (const InputError& e) {
    err << "error: " << e.what() << "\n";
    return kExitBadInput;
  } catch (const vulkan::Error& e) {
    err << "error: Vulkan: " << e.what() << "\n";
    if (e.result() == VK_ERROR_OUT_OF_DEVICE_MEMORY || e.result() == VK_ERROR_OUT_OF_HOST_MEMORY)
      err << "(the scene does not fit the device's memory; try a smaller scene, or --backend cpu)\n";
    return kExitNoDevice;
  } catch (const std::length_error& e) {
    err << "error: too large: " << e.what() << "\n";
    return kExitBadInput;
  } catch (const std::bad_alloc&) {
    err << "error: out of host memory (the scene is too large for this machine)\n";
    return kExitBadInput;
  } catch (const std::exception& e) {
    err << "internal error: " << e.what() << "\n";
    return kExitInternal;
  }
}

}  // namespace cullpipe::app
