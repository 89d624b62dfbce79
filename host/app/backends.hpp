#pragma once
// Runs one kind of volume through the CPU reference and/or the GPU and compares them.
#include <chrono>
#include <functional>
#include <memory>
#include <optional>
#include <ostream>
#include <span>
#include <vector>

#include "app/commands.hpp"
#include "cull/compare.hpp"
#include "cull/reference.hpp"
#include "gpu/gpu_culler.hpp"
#include "vk/check.hpp"
#include "vk/context.hpp"

namespace cullpipe::app {

struct BackendResults {
  std::vector<std::vector<Classification>> cpu;  ///< [view][object], empty when the CPU did not run
  std::vector<std::vector<Classification>> gpu;  ///< [view][object], empty when the GPU did not run
  std::vector<reference::CullCounts> cpu_counts, gpu_counts;
  std::vector<std::vector<std::uint32_t>> gpu_visible_ids;
  bool gpu_overflow = false;
  double cpu_ns = 0.0;       ///< all views, scalar reference
  double gpu_ns = 0.0;       ///< all views, GPU timestamps
  double gpu_wall_ns = 0.0;  ///< all views, including submission and readback
  std::size_t mismatches = 0;
  std::vector<std::string> mismatch_reports;  ///< the first few, described in full
};

/// Lazily created Vulkan context + culler, shared by the calls of one command.
struct GpuSession {
  DeviceOptions options;
  std::unique_ptr<vk::Context> context;
  std::unique_ptr<gpu::GpuCuller> culler;

  gpu::GpuCuller& get() {
    if (!culler) {
      vk::ContextOptions o;
      o.validation = options.validation;
      o.device_filter = options.device;
      context = std::make_unique<vk::Context>(o);
      culler = std::make_unique<gpu::GpuCuller>(*context);
    }
    return *culler;
  }
  /// Throws vk::Error when validation reported anything.
  void check_validation() const {
    if (context && context->validation_message_count() > 0)
      throw vk::Error(std::to_string(context->validation_message_count()) + " Vulkan validation message(s) reported");
  }
};

template <class Volume>
BackendResults cull_on_backends(std::span<const Volume> volumes, std::span<const Frustum> frusta, Backend backend,
                                GpuSession& session, bool warm_up, std::span<const std::size_t> object_ids = {},
                                std::size_t max_reports = 10) {
  BackendResults r;
  if (backend != Backend::Gpu) {
    r.cpu.assign(frusta.size(), std::vector<Classification>(volumes.size()));
    const auto start = std::chrono::steady_clock::now();
    for (std::size_t v = 0; v < frusta.size(); ++v) r.cpu_counts.push_back(reference::classify_all(volumes, frusta[v], r.cpu[v]));
    r.cpu_ns = double(std::chrono::duration_cast<std::chrono::nanoseconds>(std::chrono::steady_clock::now() - start).count());
  }
  if (backend != Backend::Cpu) {
    gpu::GpuCuller& culler = session.get();
    culler.upload(volumes);
    if (warm_up) culler.cull(frusta, {false, false, 0});  // the first dispatch compiles the pipeline (lavapipe)
    gpu::CullResult g = culler.cull(frusta);
    session.check_validation();
    r.gpu_ns = g.timings.gpu_ns;
    r.gpu_wall_ns = g.timings.wall_ns;
    for (gpu::ViewResult& view : g.views) {
      r.gpu.push_back(std::move(view.classes));
      r.gpu_counts.push_back(view.counts);
      r.gpu_visible_ids.push_back(std::move(view.visible_ids));
      r.gpu_overflow |= view.overflow;
    }
  }
  if (backend == Backend::Both) {
    for (std::size_t v = 0; v < frusta.size(); ++v) {
      Agreement a = check_agreement<Volume>(volumes, frusta[v], r.cpu[v], r.cpu_counts[v], r.gpu[v], r.gpu_counts[v],
                                            r.gpu_visible_ids[v], volumes.size(), max_reports, object_ids);
      r.mismatches += a.mismatches;
      for (std::string& m : a.reports)
        if (r.mismatch_reports.size() < max_reports) r.mismatch_reports.push_back("view " + std::to_string(v) + ", " + m);
    }
  }
  return r;
}

}  // namespace cullpipe::app
