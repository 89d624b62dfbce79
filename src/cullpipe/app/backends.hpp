#pragma once
// Runs one kind of volume through the CPU reference and/or the GPU and compares them.
#include <chrono>
#include <functional>
#include <memory>
#include <optional>
#include <ostream>
#include <span>
#include <string_view>
#include <vector>

#include "cullpipe/app/commands.hpp"
#include "cullpipe/bvh/builders.hpp"
#include "cullpipe/bvh/bvh.hpp"
#include "cullpipe/cull/compare.hpp"
#include "cullpipe/cull/cpu_bvh_culler.hpp"
#include "cullpipe/cull/cpu_culler.hpp"
#include "cullpipe/cull/reference.hpp"
#include "cullpipe/gpu/bvh_culler.hpp"
#include "cullpipe/gpu/gpu_culler.hpp"
#include "cullpipe/scene/scene.hpp"
#include "cullpipe/vulkan/check.hpp"
#include "cullpipe/vulkan/context.hpp"

namespace cullpipe::app {

struct BackendResults {
  std::vector<std::vector<Classification>> cpu;  ///< [view][object], empty when the CPU did not run
  std::vector<std::vector<Classification>> gpu;  ///< [view][object], empty when the GPU did not run
  std::vector<reference::CullCounts> cpu_counts, gpu_counts;
  std::vector<std::vector<std::uint32_t>> gpu_visible_ids;
  bool gpu_overflow = false;
  double cpu_ns = 0.0;              ///< all views, on the CPU path that ran
  std::string cpu_path;             ///< which: "reference" or "fast (avx512, 2 threads)"
  bool fast_checked = false;        ///< the fast path's answers were compared with the reference's (untimed)
  std::size_t fast_mismatches = 0;  ///< differences between the fast path and the reference
  double gpu_ns = 0.0;              ///< all views, GPU timestamps
  double gpu_wall_ns = 0.0;         ///< all views, including submission and readback
  /// The uploads of the paths that keep their own copy of the scene (0: none ran): the fast
  /// CPU culler's and the GPU culler's, the first into fresh buffers (allocation included).
  double cpu_upload_ns = 0.0, gpu_upload_ns = 0.0;
  std::size_t mismatches = 0;
  std::vector<std::string> mismatch_reports;  ///< the first few, described in full
  /// Per view: node boxes and objects tested (the CPU's counts when it ran, else the GPU's);
  /// flat culling tests no nodes and every object.
  std::vector<std::size_t> node_tests, object_tests;
};

/// Lazily created Vulkan context + culler, shared by the calls of one command.
struct GpuBackend {
  DeviceOptions options;
  std::unique_ptr<vulkan::Context> context;
  std::unique_ptr<gpu::GpuCuller> culler;
  std::unique_ptr<gpu::BvhCuller> bvh_culler;

  vulkan::Context& device() {
    if (!context) {
      vulkan::ContextOptions o;
      o.validation = options.validation;
      o.device_filter = options.device;
      o.memory_budget = VkDeviceSize(options.gpu_memory_mib * 1024.0 * 1024.0);
      context = std::make_unique<vulkan::Context>(o);
    }
    return *context;
  }
  gpu::GpuCuller& get() {
    if (!culler) culler = std::make_unique<gpu::GpuCuller>(device());
    return *culler;
  }
  gpu::BvhCuller& bvh() {
    if (!bvh_culler) bvh_culler = std::make_unique<gpu::BvhCuller>(device());
    return *bvh_culler;
  }
  /// Throws vulkan::Error when validation reported anything.
  void check_validation() const {
    if (context && context->validation_message_count() > 0)
      throw vulkan::Error(std::to_string(context->validation_message_count()) +
                          " Vulkan validation message(s) reported");
  }
};

/// A tree built for the command line: flattened, measured and timed.
struct BuiltBvh {
  bvh::FlatTree flat;
  bvh::Metrics metrics;
  double build_ns = 0.0;
};

/// The most objects the tool gives the exact agglomerative builders (oracles: O(n^3) and
/// O(n^2)); no limit for the others.
inline std::size_t builder_size_limit(std::string_view builder) {
  if (builder == "agglomerative-brute") return 2000;
  if (builder == "agglomerative-pq") return 20000;
  return SIZE_MAX;
}

/// Throws InputError unless `builder` names a builder (bvh::build's names).
inline void check_builder_name(const std::string& builder) {
  try {
    bvh::build(builder, std::span<const Aabb>{});
  } catch (const std::invalid_argument& e) {
    throw InputError(std::string("--builder: ") + e.what());
  }
}

/// Builds with the named builder (bvh::build); an unknown name, a bad leaf size or a scene too
/// large for an oracle builder is an InputError.
inline BuiltBvh build_bvh(const std::string& builder, std::span<const Aabb> boxes, std::uint32_t leaf_size) {
  if (leaf_size == 0) throw InputError("--leaf-size must be at least 1");
  check_builder_name(builder);
  if (boxes.size() > builder_size_limit(builder))
    throw InputError("--builder " + builder + " is an exact oracle for at most " +
                     std::to_string(builder_size_limit(builder)) + " objects; this scene has " +
                     std::to_string(boxes.size()) + " (try agglomerative-local)");
  bvh::BuildOptions options;
  options.max_leaf_size = leaf_size;
  BuiltBvh built;
  const auto start = std::chrono::steady_clock::now();
  bvh::Tree tree;
  try {
    tree = bvh::build(builder, boxes, options);
  } catch (const std::invalid_argument& e) {
    throw InputError(std::string("--builder: ") + e.what());
  }
  built.build_ns =
      double(std::chrono::duration_cast<std::chrono::nanoseconds>(std::chrono::steady_clock::now() - start).count());
  built.metrics = bvh::metrics(tree);
  built.flat = bvh::flatten(tree);
  return built;
}

/// Which CPU code culls: the scalar reference (the oracle) or the fast path (SIMD on every
/// core, bit-exact with the reference).
enum class CpuPath { Reference, Fast };

inline double elapsed_ns(std::chrono::steady_clock::time_point start) {
  return double(std::chrono::duration_cast<std::chrono::nanoseconds>(std::chrono::steady_clock::now() - start).count());
}

/// Appends one GPU pass's views to `r`.
inline void take_gpu_result(BackendResults& r, gpu::CullResult& g) {
  r.gpu_ns = g.timings.gpu_ns;
  r.gpu_wall_ns = g.timings.wall_ns;
  for (gpu::ViewResult& view : g.views) {
    r.gpu.push_back(std::move(view.classes));
    r.gpu_counts.push_back(view.counts);
    r.gpu_visible_ids.push_back(std::move(view.visible_ids));
    r.gpu_overflow |= view.overflow;
  }
}

/// Compares every view of `r` (both backends ran) object by object.
template <class Volume>
void compare_backends(BackendResults& r, std::span<const Volume> volumes, std::span<const Frustum> frusta,
                      std::span<const std::size_t> object_ids, std::size_t max_reports) {
  for (std::size_t v = 0; v < frusta.size(); ++v) {
    Agreement a = check_agreement<Volume>(volumes, frusta[v], r.cpu[v], r.cpu_counts[v], r.gpu[v], r.gpu_counts[v],
                                          r.gpu_visible_ids[v], volumes.size(), max_reports, object_ids);
    r.mismatches += a.mismatches;
    for (std::string& m : a.reports)
      if (r.mismatch_reports.size() < max_reports) r.mismatch_reports.push_back("view " + std::to_string(v) + ", " + m);
  }
}

/// The CPU traversal's range_objects over volumes of `kind`: `asked`, else the fast path's
/// default for CpuPath::Fast and 0 (the classic traversal, the GPU's) for the reference.
inline std::uint32_t cpu_range_objects(CpuPath cpu, std::optional<std::uint32_t> asked, BvKind kind) {
  return asked.value_or(cpu == CpuPath::Fast ? fast::CpuBvhCullOptions::default_range_objects(kind) : 0);
}

/// Hierarchical culling of `boxes` (AABBs, OBBs or spheres) through `tree`: on the CPU the
/// scalar traversal (bvh::cull_hierarchical) or, with CpuPath::Fast, fast::CpuBvhCuller, with
/// cpu_range_objects(cpu, range_objects, kind); on the GPU BvhCuller (range_objects 0); compared
/// object by object (the classes do not depend on range_objects; the test counts do, and each
/// side's are proved against the scalar traversal with its own).
template <class Volume>
BackendResults cull_bvh_on_backends(const bvh::FlatTree& tree, std::span<const Volume> boxes,
                                    std::span<const Frustum> frusta, Backend backend, GpuBackend& gpu_backend,
                                    bool warm_up, CpuPath cpu = CpuPath::Reference,
                                    std::optional<std::uint32_t> range_objects = std::nullopt,
                                    std::size_t max_reports = 10) {
  BackendResults r;
  const bvh::TraversalOptions traversal{cpu_range_objects(cpu, range_objects, kind_of<Volume>())};
  if (backend != Backend::Gpu) {
    auto take = [&](bvh::HierarchicalResult& h) {
      r.cpu_counts.push_back({h.visible, h.inside, h.visible - h.inside});
      r.node_tests.push_back(h.node_tests);
      r.object_tests.push_back(h.object_tests);
      r.cpu.push_back(std::move(h.classes));
    };
    if (cpu == CpuPath::Fast) {
      fast::CpuBvhCuller culler;
      const auto upload_start = std::chrono::steady_clock::now();
      culler.upload(tree, boxes);
      r.cpu_upload_ns = elapsed_ns(upload_start);
      std::vector<fast::CpuBvhViewResult> results;
      const fast::CpuBvhCullOptions classes_only{true, false, traversal.range_objects};
      if (warm_up && !frusta.empty()) culler.cull(frusta.first(1), classes_only, results);
      const auto start = std::chrono::steady_clock::now();
      culler.cull(frusta, classes_only, results);  // every view in one pass
      r.cpu_ns = elapsed_ns(start);
      for (fast::CpuBvhViewResult& v : results) take(v.result);
      r.cpu_path = "fast hierarchical (" + std::to_string(culler.threads()) +
                   " threads, ranges of <= " + std::to_string(traversal.range_objects) + " objects)";
      // The fast traversal is proved against the scalar one (untimed): classes and test counts.
      for (std::size_t v = 0; v < frusta.size(); ++v) {
        const bvh::HierarchicalResult h = bvh::cull_hierarchical(tree, boxes, frusta[v], traversal);
        std::size_t differ = h.node_tests != r.node_tests[v] || h.object_tests != r.object_tests[v] ? 1 : 0;
        for (std::size_t i = 0; i < h.classes.size(); ++i) differ += h.classes[i] != r.cpu[v][i];
        if (differ && r.mismatch_reports.size() < max_reports)
          r.mismatch_reports.push_back("view " + std::to_string(v) +
                                       ": the fast CPU traversal differs from the scalar one in " +
                                       std::to_string(differ) + " places");
        r.fast_mismatches += differ;
      }
      r.fast_checked = true;
    } else {
      const auto start = std::chrono::steady_clock::now();
      for (const Frustum& f : frusta) {
        bvh::HierarchicalResult h = bvh::cull_hierarchical(tree, boxes, f, traversal);
        take(h);
      }
      r.cpu_ns = elapsed_ns(start);
      r.cpu_path = "hierarchical reference (ranges of <= " + std::to_string(traversal.range_objects) + " objects)";
    }
  }
  if (backend != Backend::Cpu) {
    gpu::BvhCuller& culler = gpu_backend.bvh();
    const auto upload_start = std::chrono::steady_clock::now();
    culler.upload(tree, boxes);
    r.gpu_upload_ns = elapsed_ns(upload_start);
    if (warm_up) culler.cull(frusta, {false, false, 0});  // the first dispatch of each pipeline compiles it (lavapipe)
    gpu::CullResult g = culler.cull(frusta);
    gpu_backend.check_validation();
    const bool have_cpu_tests = !r.node_tests.empty();
    for (std::size_t v = 0; v < g.views.size(); ++v) {
      const gpu::ViewResult& view = g.views[v];
      if (!have_cpu_tests) {
        r.node_tests.push_back(view.node_tests);
        r.object_tests.push_back(view.object_tests);
        continue;
      }
      // The same traversal must make the same tests: the CPU's, or the scalar one's with the
      // GPU's range_objects (0) when the CPU's differs (untimed).
      std::size_t node_tests = r.node_tests[v], object_tests = r.object_tests[v];
      const char* against = "the CPU";
      if (traversal.range_objects != 0) {
        const bvh::HierarchicalResult h = bvh::cull_hierarchical(tree, boxes, frusta[v]);
        node_tests = h.node_tests;
        object_tests = h.object_tests;
        against = "the scalar traversal to the leaves";
      }
      if (view.node_tests != node_tests || view.object_tests != object_tests) {
        ++r.mismatches;
        if (r.mismatch_reports.size() < max_reports)
          r.mismatch_reports.push_back("view " + std::to_string(v) + ": the GPU made " +
                                       std::to_string(view.node_tests) + " node and " +
                                       std::to_string(view.object_tests) + " object tests, " + against + " " +
                                       std::to_string(node_tests) + " and " + std::to_string(object_tests));
      }
    }
    take_gpu_result(r, g);
  }
  if (backend == Backend::Both) compare_backends<Volume>(r, boxes, frusta, {}, max_reports);
  return r;
}

template <class Volume>
BackendResults cull_on_backends(std::span<const Volume> volumes, std::span<const Frustum> frusta, Backend backend,
                                GpuBackend& gpu_backend, bool warm_up, std::span<const std::size_t> object_ids = {},
                                std::size_t max_reports = 10, CpuPath cpu = CpuPath::Reference) {
  BackendResults r;
  if (backend != Backend::Gpu && cpu == CpuPath::Fast) {
    fast::CpuCuller culler;
    const auto upload_start = std::chrono::steady_clock::now();
    culler.upload(volumes);  // structure of arrays
    r.cpu_upload_ns = elapsed_ns(upload_start);
    fast::CpuCullOptions options;
    options.visible_ids = false;
    std::vector<fast::CpuViewResult> results;
    if (warm_up) culler.cull(frusta, options, results);
    const auto start = std::chrono::steady_clock::now();
    culler.cull(frusta, options, results);
    r.cpu_ns = elapsed_ns(start);
    for (fast::CpuViewResult& view : results) {
      r.cpu.push_back(std::move(view.classes));
      r.cpu_counts.push_back(view.counts);
    }
    r.cpu_path =
        "fast (" + std::string(fast::to_string(culler.isa())) + ", " + std::to_string(culler.threads()) + " threads)";
    // The fast path is itself proved against the scalar oracle, object by object (untimed).
    std::vector<Classification> ref(volumes.size());
    for (std::size_t v = 0; v < frusta.size(); ++v) {
      const reference::CullCounts counts = reference::classify_all(volumes, frusta[v], ref);
      r.fast_mismatches += count_mismatches(ref, r.cpu[v]) + (counts == r.cpu_counts[v] ? 0 : 1);
      for (std::size_t i = 0; i < ref.size() && r.mismatch_reports.size() < max_reports; ++i)
        if (ref[i] != r.cpu[v][i])
          r.mismatch_reports.push_back("view " + std::to_string(v) + ", object " + std::to_string(i) + ": " +
                                       describe(volumes[i]) + "; frustum " + describe(frusta[v]) + "; reference says " +
                                       std::string(to_string(ref[i])) + ", fast CPU path says " +
                                       std::string(to_string(r.cpu[v][i])));
    }
    r.fast_checked = true;
  } else if (backend != Backend::Gpu) {
    r.cpu.assign(frusta.size(), std::vector<Classification>(volumes.size()));
    const auto start = std::chrono::steady_clock::now();
    for (std::size_t v = 0; v < frusta.size(); ++v)
      r.cpu_counts.push_back(reference::classify_all(volumes, frusta[v], r.cpu[v]));
    r.cpu_ns = elapsed_ns(start);
    r.cpu_path = "reference";
  }
  if (backend != Backend::Cpu) {
    gpu::GpuCuller& culler = gpu_backend.get();
    const auto upload_start = std::chrono::steady_clock::now();
    culler.upload(volumes);
    r.gpu_upload_ns = elapsed_ns(upload_start);
    if (warm_up) culler.cull(frusta, {false, false, 0});  // the first dispatch compiles the pipeline (lavapipe)
    gpu::CullResult g = culler.cull(frusta);
    gpu_backend.check_validation();
    take_gpu_result(r, g);
  }
  if (backend == Backend::Both) compare_backends<Volume>(r, volumes, frusta, object_ids, max_reports);
  r.node_tests.assign(frusta.size(), 0);
  r.object_tests.assign(frusta.size(), volumes.size());
  return r;
}

}  // namespace cullpipe::app
