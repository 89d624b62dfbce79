// cullpipe-bench: every culling method side by side on the same scenes, in one run, with the
// machine's own memory read bandwidth (measured in the same run) as the yardstick.
//
// Methods (each cell: one method, one volume kind, N objects, one visible fraction, one order):
//   reference  scalar CPU reference, one thread, per-object classes (reference::classify_all)
//   cpu-fast   SIMD + threads (fast::CpuCuller), per-object classes and the visible list
//   cpu-read   the memory floor: the 16 bytes per object every cpu-fast pass reads (centre and
//              bound), with its loads and threads and no tests; read in two orders in turn
//              (the pass's own, the four arrays side by side, and one array after another),
//              the faster median taken
//   cpu-bvh    scalar hierarchical traversal (bvh::cull_hierarchical), a class per object
//   cpu-fast-bvh  the same traversal on every core with SIMD kernels (fast::CpuBvhCuller), the visible
//                 list; straddling nodes of <= 160 objects (96 for OBBs) test their objects as one
//                 range (its defaults)
//   gpu-flat   GpuCuller, visible list compacted on the device (time between timestamps)
//   gpu-bvh    BvhCuller, visible list
// Each method that keeps its own copy of the scene (cpu-fast, cpu-fast-bvh, gpu-flat, gpu-bvh)
// also has its upload timed: what an engine pays per frame when objects move (median of
// repeated uploads into the buffers the first one allocated).
// The hierarchies (binned SAH, leaves of bvh::kCullingLeafSize = 16) are built over the volumes' enclosing boxes.
// Scenes: the first N objects of one uniform random scene, in shuffled order or sorted along the
// Morton curve; the camera's field of view is chosen so that about 1%, 10%, 50% are visible.
// Every cell's answers are checked once against the reference before it is timed; ns/object
// is the median over repeats, each method's repeats back to back after an untimed pass (so
// objects that fit the caches are measured in cache, for every method alike). Without
// --repeats, a cell repeats by size (3 to 51 times) and until it has taken 50 ms (at most 1001
// times).
//
// usage: cullpipe-bench [--methods m,..] [--bv aabb,obb,sphere] [--sizes 1e3,..] [--fractions 0.01,..]
//                       [--order shuffled,sorted] [--views K] [--ortho] [--repeats R] [--threads T] [--isa NAME]
//                       [--device NAME] [--validation] [--csv FILE] [--json FILE] [--plot PREFIX]
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <functional>
#include <glm/common.hpp>
#include <glm/vec4.hpp>
#include <map>
#include <memory>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <thread>
#include <vector>

#include "bench_util.hpp"
#include "cullpipe/bvh/builders.hpp"
#include "cullpipe/bvh/bvh.hpp"
#include "cullpipe/core/splitmix.hpp"
#include "cullpipe/cull/cpu_bvh_culler.hpp"
#include "cullpipe/cull/cpu_culler.hpp"
#include "cullpipe/cull/reference.hpp"
#include "cullpipe/gpu/bvh_culler.hpp"
#include "cullpipe/gpu/gpu_culler.hpp"
#include "cullpipe/scene/generators.hpp"
#include "cullpipe/vulkan/context.hpp"

using namespace cullpipe;
using namespace cullpipe::bench;

namespace {

/// A CSV field (RFC 4180): quoted, with quotes doubled, when it holds a comma, quote or newline.
std::string csv_field(const std::string& text) {
  if (text.find_first_of(",\"\n") == std::string::npos) return text;
  std::string quoted = "\"";
  for (char c : text) quoted += c == '"' ? std::string("\"\"") : std::string(1, c);
  return quoted + "\"";
}

const char* const kProgram = "cullpipe-bench";
const std::vector<std::string> kMethods = {"reference",    "cpu-fast", "cpu-read", "cpu-bvh",
                                           "cpu-fast-bvh", "gpu-flat", "gpu-bvh"};

struct Cell {
  std::string method, bv, order;
  std::size_t n = 0;
  std::size_t views = 1;  ///< views per pass (--views); times per object are per object and view
  double target_fraction = 0, visible_fraction = 0;
  int repeats = 0;
  double ns = 0;         ///< median time of one pass (GPU: between timestamps)
  double wall_ns = 0;    ///< GPU: median wall time of a pass (record, submit, wait, read back)
  double upload_ns = 0;  ///< median time of the method's upload of the scene (0: the method has no upload of its own)
  std::size_t bytes_per_object = 0;
  std::optional<bool> agree;  ///< nullopt when there is nothing to check (cpu-read)
  std::string note;           ///< why a method did not run
  bool orthographic = false;  ///< the cameras' projection (--ortho)
};

struct Config {
  std::vector<std::string> methods = kMethods;
  std::vector<std::string> bvs = {"aabb", "obb", "sphere"};
  std::vector<std::size_t> sizes = {1000, 10000, 100000, 1000000, 4000000, 16000000};
  std::vector<double> fractions = {0.01, 0.1, 0.5};
  std::vector<std::string> orders = {"shuffled", "sorted"};
  std::size_t views = 1;      // views per pass, on a circle around the scene
  bool orthographic = false;  // orthographic cameras (a shadow map's) instead of perspective ones
  int repeats = 0;            // 0: by size
  unsigned threads = 0;
  std::optional<fast::Isa> isa;
  bool validation = false;  // Vulkan validation layers on; any message makes the exit status 1
  std::string device, csv, json, plot;
};

bool wants(const Config& c, const std::string& method) {
  return std::find(c.methods.begin(), c.methods.end(), method) != c.methods.end();
}

/// The GPU side, created on first use; its absence is a note, not an error.
struct Gpu {
  std::unique_ptr<vulkan::Context> ctx;
  std::unique_ptr<gpu::GpuCuller> flat;
  std::unique_ptr<gpu::BvhCuller> bvh;
  std::string error;
};

// Bytes per object a GPU pass's upload stored (the flat AABB pass also keeps a 16-byte centre
// bound, and reads its record only for the boxes that bound leaves open).
template <class Volume>
std::size_t gpu_bytes_per_object(bool flat);
template <>
std::size_t gpu_bytes_per_object<Aabb>(bool flat) {
  return sizeof(gpu::GpuAabb) + (flat ? sizeof(glm::vec4) : 0);
}
template <>
std::size_t gpu_bytes_per_object<Obb>(bool) {
  return sizeof(gpu::GpuObb);
}
template <>
std::size_t gpu_bytes_per_object<Sphere>(bool) {
  return sizeof(gpu::GpuSphere);
}

/// Median time of repeated calls of `upload` after an untimed first one (which allocates): the
/// steady state of an engine that uploads every frame.
template <class F>
double time_upload(F&& upload, std::size_t n) {
  upload();
  const int repeats = n >= 4'000'000 ? 3 : 5;
  std::vector<double> times;
  for (int r = 0; r < repeats; ++r) {
    const auto t0 = Clock::now();
    upload();
    times.push_back(since(t0));
  }
  return median(times);
}

/// Measures one (volume kind, N, order) for every fraction; appends the cells.
template <class Volume>
void run_scene(const Config& config, const std::string& bv, const std::string& order,
               const std::vector<Volume>& volumes, const std::vector<Aabb>& boxes, const Aabb& bounds,
               fast::CpuCuller& fast_culler, fast::CpuBvhCuller& fast_bvh, Gpu& gpu, std::vector<Cell>& cells,
               bool& all_agree) {
  const std::size_t n = volumes.size();
  const std::span<const Volume> vspan(volumes);
  const bool is_aabb = std::is_same_v<Volume, Aabb>;
  std::map<std::string, double> upload_ns;  // by method
  if (wants(config, "cpu-fast"))
    upload_ns["cpu-fast"] = time_upload([&] { fast_culler.upload(vspan); }, n);
  else
    fast_culler.upload(vspan);  // (it also finds each fraction's field of view)

  // The BVH (binned SAH, leaves of bvh::kCullingLeafSize) over the volumes' enclosing boxes,
  // built once per scene; not part of the timed passes.
  const bool bvh_methods = wants(config, "cpu-bvh") || wants(config, "cpu-fast-bvh") || wants(config, "gpu-bvh");
  bvh::FlatTree tree;
  bvh::BuildOptions leaves;
  leaves.max_leaf_size = bvh::kCullingLeafSize;
  if (bvh_methods) tree = bvh::flatten(bvh::build("binned-sah", is_aabb ? boxes : bvh::enclosing_boxes(vspan), leaves));
  if (bvh_methods && wants(config, "cpu-fast-bvh"))
    upload_ns["cpu-fast-bvh"] = time_upload([&] { fast_bvh.upload(tree, vspan); }, n);

  std::string gpu_flat_note, gpu_bvh_note;
  if (gpu.flat && wants(config, "gpu-flat")) {
    try {
      upload_ns["gpu-flat"] = time_upload([&] { gpu.flat->upload(vspan); }, n);
    } catch (const std::length_error& e) {
      gpu_flat_note = std::string("too large: ") + e.what();
    }
  }
  if (gpu.bvh && bvh_methods && wants(config, "gpu-bvh")) {
    try {
      upload_ns["gpu-bvh"] = time_upload([&] { gpu.bvh->upload(tree, vspan); }, n);
    } catch (const std::length_error& e) {
      gpu_bvh_note = std::string("too large: ") + e.what();
    }
  }

  fast::CpuCullOptions list_only_cpu;
  list_only_cpu.classes = false;
  std::vector<std::uint32_t> fast_bvh_ids;
  std::vector<fast::CpuBvhViewResult> fast_bvh_views;
  fast::CpuCullOptions counts_only;
  counts_only.classes = counts_only.visible_ids = false;
  std::vector<fast::CpuViewResult> fast_results;
  for (double fraction : config.fractions) {
    double achieved = 0;
    Camera camera;
    frustum_for_fraction(
        bounds, n, fraction,
        [&](const Frustum& v) {
          fast_culler.cull({&v, 1}, counts_only, fast_results);
          return fast_results[0].counts.visible;
        },
        achieved, &camera, config.orthographic);
    // --views K: K cameras with that lens evenly on a circle around the scene (the first where
    // the one found stands: camera_path), culled in one pass; `achieved` becomes their mean
    // visible share.
    std::vector<Frustum> views;
    for (const Camera& c : camera_path(camera, bounds, config.views))
      views.push_back(Frustum::from_view_proj(c.view_proj()));
    const std::size_t view_count = views.size();
    const int reps = config.repeats > 0
                         ? config.repeats
                         : int(std::clamp<std::size_t>(20'000'000 / std::max<std::size_t>(n * view_count, 1), 3, 51));

    // The reference answers, then every method checked against them once.
    std::vector<std::vector<Classification>> ref(view_count, std::vector<Classification>(n));
    std::vector<reference::CullCounts> ref_counts(view_count);
    std::vector<std::vector<std::uint32_t>> ref_ids(view_count);
    std::size_t visible_sum = 0;
    for (std::size_t v = 0; v < view_count; ++v) {
      ref_counts[v] = reference::classify_all(vspan, views[v], ref[v]);
      for (std::size_t i = 0; i < n; ++i)
        if (is_visible(ref[v][i])) ref_ids[v].push_back(static_cast<std::uint32_t>(i));
      visible_sum += ref_counts[v].visible;
    }
    if (n > 0) achieved = double(visible_sum) / double(n * view_count);

    struct Timed {
      std::string method;
      std::function<void(std::vector<double>&, std::vector<double>&)> pass;  // appends time (and wall time)
      std::vector<double> times, walls;
      Cell cell;
      bool two_orders = false;  // cpu-read: `walls` holds the times of a second read order
    };
    std::vector<Timed> timed;
    auto add = [&](const std::string& method, std::size_t bytes, std::optional<bool> agree, std::string note,
                   std::function<void(std::vector<double>&, std::vector<double>&)> pass) {
      Timed t;
      t.method = method;
      t.cell = {method, bv, order, n,     view_count, fraction,        achieved,           reps,
                0,      0,  0,     bytes, agree,      std::move(note), config.orthographic};
      if (const auto u = upload_ns.find(method); u != upload_ns.end() && t.cell.note.empty())
        t.cell.upload_ns = u->second;
      if (t.cell.note.empty()) t.pass = std::move(pass);
      timed.push_back(std::move(t));
    };
    std::vector<Classification> scratch(n);
    if (wants(config, "reference"))
      add("reference", sizeof(Volume), true, "", [&](std::vector<double>& t, std::vector<double>&) {
        const auto t0 = Clock::now();
        for (const Frustum& f : views) reference::classify_all(vspan, f, scratch);
        t.push_back(since(t0));
      });
    // The timed passes of the fast and GPU methods produce what an engine consumes: the counts
    // and the visible list (no per-object classes); each is checked in that mode and with
    // classes before it is timed.
    if (wants(config, "cpu-fast")) {
      bool ok = true;
      fast_culler.cull(views, {}, fast_results);
      for (std::size_t v = 0; v < view_count; ++v)
        ok = ok && fast_results[v].classes == ref[v] && fast_results[v].counts == ref_counts[v] &&
             fast_results[v].visible_ids == ref_ids[v];
      fast_culler.cull(views, list_only_cpu, fast_results);
      for (std::size_t v = 0; v < view_count; ++v)
        ok = ok && fast_results[v].counts == ref_counts[v] && fast_results[v].visible_ids == ref_ids[v];
      add("cpu-fast", fast_culler.bytes_per_object(), ok, "", [&](std::vector<double>& t, std::vector<double>&) {
        const auto t0 = Clock::now();
        fast_culler.cull(views, list_only_cpu, fast_results);
        t.push_back(since(t0));
      });
    }
    if (wants(config, "cpu-read")) {
      // Both orders of reading the arrays, in turn: the pass's own (side by side) and one
      // array after another; the faster median is the floor.
      add("cpu-read", fast::CpuCuller::kStreamedBytesPerObject, std::nullopt, "",
          [&](std::vector<double>& t, std::vector<double>& w) {
            auto t0 = Clock::now();
            volatile std::uint32_t sink = fast_culler.touch_streamed_side_by_side();
            t.push_back(since(t0));
            t0 = Clock::now();
            sink = fast_culler.touch_bounds(true);
            w.push_back(since(t0));
            (void)sink;
          });
      timed.back().two_orders = true;
    }
    // The scalar traversal's answers per view (the hierarchical methods' oracle), made once.
    std::vector<bvh::HierarchicalResult> h;
    auto traversed = [&] {
      if (h.empty())
        for (const Frustum& f : views) h.push_back(bvh::cull_hierarchical(tree, vspan, f));
    };
    if (wants(config, "cpu-bvh")) {
      // Every class equals flat culling's (for OBBs and spheres thanks to the node margin).
      traversed();
      bool ok = true;
      for (std::size_t v = 0; v < view_count; ++v)
        ok = ok && h[v].classes == ref[v] && h[v].visible == ref_counts[v].visible &&
             h[v].inside == ref_counts[v].inside;
      add("cpu-bvh", sizeof(Volume), ok, "", [&](std::vector<double>& t, std::vector<double>&) {
        const auto t0 = Clock::now();
        for (const Frustum& f : views) {
          const bvh::HierarchicalResult r = bvh::cull_hierarchical(tree, vspan, f);
          (void)r;
        }
        t.push_back(since(t0));
      });
    }
    bvh::HierarchicalResult fast_h;
    if (wants(config, "cpu-fast-bvh")) {
      traversed();
      bool ok = true;
      if (view_count > 1) fast_bvh.cull(views, {false, true}, fast_bvh_views);  // the timed mode of several views
      for (std::size_t v = 0; v < view_count; ++v) {
        // Its traversal tests the objects of small straddling nodes as ranges: the scalar
        // traversal's counts with the same range_objects; the classes do not depend on it.
        const bvh::HierarchicalResult hf = bvh::cull_hierarchical(
            tree, vspan, views[v], {fast::CpuBvhCullOptions::default_range_objects(kind_of<Volume>())});
        fast_bvh.cull(views[v], fast_h);
        ok = ok && fast_h.classes == h[v].classes && hf.classes == h[v].classes && fast_h.node_tests == hf.node_tests &&
             fast_h.object_tests == hf.object_tests && fast_h.visible == h[v].visible && fast_h.inside == h[v].inside;
        fast_bvh.cull(views[v], {false, true}, fast_h, fast_bvh_ids);
        std::vector<std::uint32_t> in_tree_order;  // the list comes in the tree's object order
        for (std::uint32_t o : tree.objects)
          if (is_visible(h[v].classes[o])) in_tree_order.push_back(o);
        ok = ok && fast_bvh_ids == in_tree_order && fast_h.visible == ref_counts[v].visible &&
             fast_h.inside == ref_counts[v].inside && fast_h.node_tests == hf.node_tests &&
             fast_h.object_tests == hf.object_tests;
        if (view_count > 1) {
          const bvh::HierarchicalResult& r = fast_bvh_views[v].result;
          ok = ok && fast_bvh_views[v].visible_ids == in_tree_order && r.visible == h[v].visible &&
               r.inside == h[v].inside && r.node_tests == hf.node_tests && r.object_tests == hf.object_tests;
        }
      }
      add("cpu-fast-bvh", sizeof(Volume), ok, "", [&](std::vector<double>& t, std::vector<double>&) {
        const auto t0 = Clock::now();
        if (view_count == 1)
          fast_bvh.cull(views[0], {false, true}, fast_h, fast_bvh_ids);
        else
          fast_bvh.cull(views, {false, true}, fast_bvh_views);
        t.push_back(since(t0));
      });
    }
    gpu::CullOptions list_only;
    list_only.classes = false;
    if (wants(config, "gpu-flat")) {
      std::string note = !gpu.flat ? "no GPU: " + gpu.error : gpu_flat_note;
      std::optional<bool> ok;
      if (note.empty()) {
        // Both the checked pass (classes) and the timed one (the visible list only, which
        // skips the class writes) are checked: classes exactly, the list as a set.
        const gpu::CullResult g = gpu.flat->cull(views);  // also the warm-up (pipeline compile)
        gpu::CullResult listed = gpu.flat->cull(views, list_only);
        ok = true;
        for (std::size_t v = 0; v < view_count; ++v) {
          std::vector<std::uint32_t> ids = listed.views[v].visible_ids;
          std::sort(ids.begin(), ids.end());
          ok = *ok && g.views[v].classes == ref[v] && g.views[v].counts == ref_counts[v] &&
               listed.views[v].counts == ref_counts[v] && ids == ref_ids[v];
        }
      }
      add("gpu-flat", gpu_bytes_per_object<Volume>(true), ok, note,
          [&](std::vector<double>& t, std::vector<double>& w) {
            const gpu::CullResult g = gpu.flat->cull(views, list_only);
            t.push_back(g.timings.gpu_ns);
            w.push_back(g.timings.wall_ns);
          });
    }
    if (wants(config, "gpu-bvh")) {
      std::string note = !gpu.bvh ? "no GPU: " + gpu.error : gpu_bvh_note;
      std::optional<bool> ok;
      if (note.empty()) {
        traversed();
        const gpu::CullResult g = gpu.bvh->cull(views);
        gpu::CullResult listed = gpu.bvh->cull(views, list_only);  // the timed mode
        ok = true;
        for (std::size_t v = 0; v < view_count; ++v) {
          std::vector<std::uint32_t> ids = listed.views[v].visible_ids;
          std::sort(ids.begin(), ids.end());
          ok = *ok && g.views[v].classes == h[v].classes && g.views[v].counts.visible == h[v].visible &&
               g.views[v].counts.inside == h[v].inside && g.views[v].node_tests == h[v].node_tests &&
               g.views[v].object_tests == h[v].object_tests && ids == ref_ids[v] &&
               listed.views[v].counts == ref_counts[v] && listed.views[v].node_tests == h[v].node_tests &&
               listed.views[v].object_tests == h[v].object_tests;
        }
      }
      add("gpu-bvh", gpu_bytes_per_object<Volume>(false), ok, note,
          [&](std::vector<double>& t, std::vector<double>& w) {
            const gpu::CullResult g = gpu.bvh->cull(views, list_only);
            t.push_back(g.timings.gpu_ns);
            w.push_back(g.timings.wall_ns);
          });
    }

    // Each method's repeats back to back after one untimed pass, so every method runs with the
    // caches as it leaves them (interleaving would hand one method's cache to the next).
    // Without --repeats a method also repeats until its cell has taken kMinCellNs (at most
    // kMaxRepeats times): a fast pass of 50 microseconds would otherwise be the median of a
    // millisecond's worth of passes, at the mercy of whatever else the machine did then.
    constexpr double kMinCellNs = 50e6;
    constexpr int kMaxRepeats = 1001;
    for (Timed& t : timed) {
      if (!t.pass) continue;
      std::vector<double> warm_times, warm_walls;
      t.pass(warm_times, warm_walls);
      const auto start = Clock::now();
      for (int r = 0; r < reps || (config.repeats == 0 && r < kMaxRepeats && since(start) < kMinCellNs); ++r)
        t.pass(t.times, t.walls);
      t.cell.repeats = static_cast<int>(t.times.size());
    }
    for (Timed& t : timed) {
      t.cell.ns = median(t.times);
      t.cell.wall_ns = median(t.walls);
      if (t.two_orders) t.cell.ns = std::min(t.cell.ns, t.cell.wall_ns), t.cell.wall_ns = 0;
      if (t.cell.agree && !*t.cell.agree) all_agree = false;
      cells.push_back(t.cell);
    }
    // Print this fraction's rows.
    double ref_ns = 0;
    for (const Timed& t : timed)
      if (t.method == "reference") ref_ns = t.cell.ns;
    for (const Timed& t : timed) {
      const Cell& c = t.cell;
      const double dn = double(std::max<std::size_t>(n, 1)), dnv = dn * double(view_count);  // objects; objects x views
      if (!c.note.empty()) {
        std::printf("%-12s %-7s %-9s %9zu %6.1f%%   (%s)\n", c.method.c_str(), bv.c_str(), order.c_str(), n,
                    100 * achieved, c.note.c_str());
        continue;
      }
      const double gbps = c.ns > 0 ? double(c.bytes_per_object) * dn / c.ns : 0.0;
      std::printf("%-12s %-7s %-9s %9zu %6.1f%% %5d %10.3f %10.1f %8.2f %8.2f %10s %11s %6s\n", c.method.c_str(),
                  bv.c_str(), order.c_str(), n, 100 * achieved, c.repeats, c.ns / dnv,
                  c.ns > 0 ? dnv / c.ns * 1e3 : 0.0, gbps, ref_ns > 0 && c.ns > 0 ? ref_ns / c.ns : 0.0,
                  c.wall_ns > 0 ? std::to_string(c.wall_ns / dnv).substr(0, 8).c_str() : "-",
                  c.upload_ns > 0 ? std::to_string(c.upload_ns / dn).substr(0, 8).c_str() : "-",
                  !c.agree   ? "-"
                  : *c.agree ? "yes"
                             : "NO");
    }
    std::fflush(stdout);
  }
}

/// Median bandwidth of reading a buffer 8x larger than the last-level cache (at least 256 MiB)
/// with the fast path's loads and threads, in GB/s.
double measure_read_bandwidth(fast::CpuCuller& culler) {
  std::vector<float> buffer(std::size_t(64) << 20, 1.0f);  // 256 MiB
  std::vector<double> times;
  volatile std::uint32_t sink = 0;
  for (int r = 0; r < 9; ++r) {
    const auto t0 = Clock::now();
    sink = sink | culler.touch(buffer);
    times.push_back(since(t0));
  }
  return double(buffer.size() * sizeof(float)) / median(times);
}

void write_plots(const Config& config, const std::vector<Cell>& cells) {
  // One PNG per volume kind: ns/object against N, one line per method, log scales; shuffled
  // order at the middle fraction asked for.
  const double fraction = config.fractions[config.fractions.size() / 2];
  const std::string order = std::find(config.orders.begin(), config.orders.end(), "shuffled") != config.orders.end()
                                ? "shuffled"
                                : config.orders.front();
  for (const std::string& bv : config.bvs) {
    const std::string data = config.plot + "-" + bv + ".dat", script = config.plot + "-" + bv + ".gp",
                      png = config.plot + "-" + bv + ".png";
    std::ofstream out(data);
    std::vector<std::string> plotted;
    for (const std::string& method : config.methods) {
      bool any = false;
      for (const Cell& c : cells)
        if (c.method == method && c.bv == bv && c.order == order && c.target_fraction == fraction && c.note.empty() &&
            c.ns > 0) {
          if (!any) out << "\"" << method << "\"\n";
          any = true;
          out << c.n << " " << c.ns / double(std::max<std::size_t>(c.n * c.views, 1)) << "\n";
        }
      if (any) {
        out << "\n\n";
        plotted.push_back(method);
      }
    }
    out.close();
    if (plotted.empty()) continue;
    std::ofstream gp(script);
    gp << "set terminal pngcairo size 900,560 noenhanced\nset output '" << png << "'\n"
       << "set title '" << bv << ", " << order << ", ~" << fraction * 100
       << "% visible: time per object (lower is better)'\n"
       << "set logscale xy\nset xlabel 'objects N'\nset ylabel 'ns per object'\nset key outside right\nset grid\n"
       << "plot for [i=0:" << plotted.size() - 1 << "] '" << data
       << "' index i using 1:2 with linespoints title columnheader(1)\n";
    gp.close();
    const std::string command = "gnuplot '" + script + "'";
    if (std::system(command.c_str()) != 0) {
      std::fprintf(stderr, "%s: gnuplot failed or is missing (install gnuplot-nox; scripts/bench.sh does)\n", kProgram);
      std::exit(1);
    }
    std::remove(data.c_str());
    std::remove(script.c_str());
    std::printf("plot: %s\n", png.c_str());
  }
}

}  // namespace

int main(int argc, char** argv) {
  Config config;
  CLI::App app{"cullpipe-bench: every culling method side by side on generated scenes, with the memory read floor"};
  add_names_option(app, "--methods", config.methods, kMethods,
                   "Methods: reference, cpu-fast, cpu-read, cpu-bvh, cpu-fast-bvh, gpu-flat, gpu-bvh")
      ->default_str("all");
  add_names_option(app, "--bv", config.bvs, {"aabb", "obb", "sphere"}, "Bounding volumes")
      ->default_str("aabb,obb,sphere");
  add_counts_option(app, "--sizes", config.sizes, "Object counts")->default_str("1e3,1e4,1e5,1e6,4e6,16e6");
  add_fractions_option(app, "--fractions", config.fractions, "Visible fractions")->default_str("0.01,0.1,0.5");
  add_names_option(app, "--order", config.orders, {"shuffled", "sorted"}, "Object orders")
      ->default_str("shuffled,sorted");
  app.add_option("--views", config.views, "Views per pass, on a circle around the scene")
      ->capture_default_str()
      ->check(CLI::Range(1, 64));
  app.add_flag("--ortho", config.orthographic, "Orthographic cameras (a shadow map's) instead of perspective ones");
  app.add_option("--repeats", config.repeats, "Repeats per cell (0: chosen by size)")
      ->capture_default_str()
      ->check(CLI::NonNegativeNumber);
  app.add_option("--threads", config.threads, "Threads of the fast CPU paths and the GPU upload (0: every core)")
      ->capture_default_str();
  app.add_option_function<std::string>(
         "--isa",
         [&](const std::string& name) {
           config.isa = fast::parse_isa(name);
           if (!config.isa || !fast::isa_supported(*config.isa))
             throw CLI::ValidationError("--isa",
                                        name + ": not an instruction set this machine runs (portable, avx2, avx512)");
         },
         "Instruction set of the fast CPU kernels (default: the best this machine runs)")
      ->type_name("portable|avx2|avx512");
  app.add_option("--device", config.device, "Vulkan device name substring");
  app.add_flag("--validation", config.validation, "Vulkan validation layers on; any message makes the exit status 1");
  app.add_option("--csv", config.csv, "Write the results as CSV");
  app.add_option("--json", config.json, "Write the results as JSON");
  app.add_option("--plot", config.plot, "Write plots PREFIX-{aabb,obb,sphere}.png (needs gnuplot)");
  bench::parse_command_line(app, argc, argv);

  fast::CpuCullerConfig fast_config;
  fast_config.threads = config.threads;
  fast_config.isa = config.isa;
  fast::CpuCuller fast_culler(fast_config);
  fast::CpuBvhCuller fast_bvh(config.threads, config.isa);
  // Counted here, not read from vulkan::Context::validation_message_count: vkDestroyDevice, in
  // the context's destructor, reports what was left undestroyed, after the count could be read.
  std::size_t validation_messages = 0;  // (declared before gpu, so it outlives the context)
  Gpu gpu;
  if (wants(config, "gpu-flat") || wants(config, "gpu-bvh")) {
    try {
      vulkan::ContextOptions options;
      options.device_filter = config.device;
      options.validation = config.validation;
      options.on_message = [&](std::string_view message) {
        ++validation_messages;
        std::fprintf(stderr, "%s: validation: %.*s\n", kProgram, int(message.size()), message.data());
      };
      gpu.ctx = std::make_unique<vulkan::Context>(options);
      gpu::GpuCullerConfig flat_config;
      flat_config.upload_threads = config.threads;  // the same threads as the CPU paths
      gpu.flat = std::make_unique<gpu::GpuCuller>(*gpu.ctx, flat_config);
      gpu.bvh = std::make_unique<gpu::BvhCuller>(*gpu.ctx);
    } catch (const std::exception& e) {
      gpu.error = e.what();
      gpu.flat.reset();
      gpu.bvh.reset();
    }
  }
  const double read_gbps = measure_read_bandwidth(fast_culler);
  std::printf("cullpipe-bench: culling methods side by side, medians of repeats\n");
  std::printf("cpu: %s, %u hardware threads; fast path: %s kernels, %u threads\n", cpu_model().c_str(),
              std::thread::hardware_concurrency(), std::string(to_string(fast_culler.isa())).c_str(),
              fast_culler.threads());
  if (gpu.ctx)
    std::printf("gpu: %s, %s\n", gpu.ctx->info().name.c_str(), gpu.ctx->info().driver.c_str());
  else if (!gpu.error.empty())
    std::printf("gpu: none (%s)\n", gpu.error.c_str());
  std::printf("memory read bandwidth (256 MiB, %u threads): %.1f GB/s\n", fast_culler.threads(), read_gbps);
  std::printf("views per pass: %zu, %s cameras\n\n", config.views,
              config.orthographic ? "orthographic" : "perspective");
  std::printf("%-12s %-7s %-9s %9s %7s %5s %10s %10s %8s %8s %10s %11s %6s\n", "method", "bv", "order", "N", "visible",
              "reps", "ns/obj", "Mobj/s", "GB/s", "x ref", "wall ns/o", "upload ns/o", "agree");

  std::vector<Cell> cells;
  bool all_agree = true;
  const std::size_t largest = *std::max_element(config.sizes.begin(), config.sizes.end());
  const Scene scene = generate_scene(SceneKind::Uniform, largest, 1);
  const std::vector<Aabb> all_boxes = world_aabbs(scene);
  for (const std::string& bv : config.bvs) {
    std::vector<Obb> all_obbs;
    std::vector<Sphere> all_spheres;
    if (bv == "obb") all_obbs = world_obbs(scene);
    if (bv == "sphere") all_spheres = world_spheres(scene);
    for (std::size_t n : config.sizes) {
      // The first n objects, shuffled (a fixed random permutation) or sorted along the Morton
      // curve of their boxes.
      std::vector<std::uint32_t> shuffled(n);
      for (std::uint32_t i = 0; i < n; ++i) shuffled[i] = i;
      SplitMix64 rng{n};
      for (std::size_t i = n; i > 1; --i) std::swap(shuffled[i - 1], shuffled[rng.next() % i]);
      Aabb bounds{glm::vec3(INFINITY), glm::vec3(-INFINITY)};
      for (std::size_t i = 0; i < n; ++i)
        bounds = {glm::min(bounds.min, all_boxes[i].min), glm::max(bounds.max, all_boxes[i].max)};
      for (const std::string& order : config.orders) {
        std::vector<std::uint32_t> pick = shuffled;
        if (order == "sorted") pick = bvh::morton_order(std::span<const Aabb>(all_boxes.data(), n));
        std::vector<Aabb> boxes(n);
        for (std::size_t i = 0; i < n; ++i) boxes[i] = all_boxes[pick[i]];
        auto gather = [&](const auto& all) {
          std::remove_cvref_t<decltype(all)> out(n);
          for (std::size_t i = 0; i < n; ++i) out[i] = all[pick[i]];
          return out;
        };
        if (bv == "aabb")
          run_scene(config, bv, order, boxes, boxes, bounds, fast_culler, fast_bvh, gpu, cells, all_agree);
        if (bv == "obb")
          run_scene(config, bv, order, gather(all_obbs), boxes, bounds, fast_culler, fast_bvh, gpu, cells, all_agree);
        if (bv == "sphere")
          run_scene(config, bv, order, gather(all_spheres), boxes, bounds, fast_culler, fast_bvh, gpu, cells,
                    all_agree);
      }
    }
  }

  auto record = [&](const Cell& c) {
    const double dn = double(std::max<std::size_t>(c.n, 1)), dnv = dn * double(c.views);  // objects; objects x views
    double ref_ns = 0;
    for (const Cell& r : cells)
      if (r.method == "reference" && r.bv == c.bv && r.order == c.order && r.n == c.n &&
          r.target_fraction == c.target_fraction)
        ref_ns = r.ns;
    const double gbps = c.ns > 0 ? double(c.bytes_per_object) * dn / c.ns : 0.0;
    return nlohmann::json{{"method", c.method},
                          {"bv", c.bv},
                          {"n", c.n},
                          {"views", c.views},
                          {"projection", c.orthographic ? "orthographic" : "perspective"},
                          {"order", c.order},
                          {"target_fraction", c.target_fraction},
                          {"visible_fraction", c.visible_fraction},
                          {"repeats", c.repeats},
                          {"ns_per_object", c.ns / dnv},
                          {"objects_per_s", c.ns > 0 ? dnv / c.ns * 1e9 : 0.0},
                          {"bytes_per_object", c.bytes_per_object},
                          {"gb_per_s", gbps},
                          {"bandwidth_fraction", gbps / read_gbps},
                          {"read_bandwidth_gbps", read_gbps},
                          {"speedup_vs_reference", ref_ns > 0 && c.ns > 0 ? ref_ns / c.ns : 0.0},
                          {"gpu_wall_ns_per_object", c.wall_ns / dnv},
                          {"upload_ns_per_object", c.upload_ns / dn},
                          {"agree", c.agree ? nlohmann::json(*c.agree) : nlohmann::json()},
                          {"note", c.note}};
  };
  if (!config.csv.empty()) {
    std::ofstream csv(config.csv);
    const char* const columns[] = {"method",
                                   "bv",
                                   "n",
                                   "views",
                                   "projection",
                                   "order",
                                   "target_fraction",
                                   "visible_fraction",
                                   "repeats",
                                   "ns_per_object",
                                   "objects_per_s",
                                   "bytes_per_object",
                                   "gb_per_s",
                                   "bandwidth_fraction",
                                   "read_bandwidth_gbps",
                                   "speedup_vs_reference",
                                   "gpu_wall_ns_per_object",
                                   "upload_ns_per_object",
                                   "agree",
                                   "note"};
    for (std::size_t k = 0; k < std::size(columns); ++k) csv << (k ? "," : "") << columns[k];
    csv << "\n";
    for (const Cell& c : cells) {
      const nlohmann::json j = record(c);
      for (std::size_t k = 0; k < std::size(columns); ++k) {
        const nlohmann::json& v = j[columns[k]];
        csv << (k ? "," : "") << (v.is_string() ? csv_field(v.get<std::string>()) : v.is_null() ? "" : v.dump());
      }
      csv << "\n";
    }
  }
  if (!config.json.empty()) {
    nlohmann::json j;
    j["cpu"] = cpu_model();
    j["hardware_threads"] = std::thread::hardware_concurrency();
    j["fast_isa"] = std::string(to_string(fast_culler.isa()));
    j["fast_threads"] = fast_culler.threads();
    j["device"] = gpu.ctx ? gpu.ctx->info().name : "";
    j["driver"] = gpu.ctx ? gpu.ctx->info().driver : "";
    j["read_bandwidth_gbps"] = read_gbps;
    j["cells"] = nlohmann::json::array();
    for (const Cell& c : cells) j["cells"].push_back(record(c));
    std::ofstream(config.json) << j.dump(2) << "\n";
  }
  if (!config.plot.empty()) write_plots(config, cells);
  gpu.flat.reset();  // the device's objects destroyed, any message about them counted
  gpu.bvh.reset();
  gpu.ctx.reset();
  if (!all_agree) {
    std::fprintf(stderr, "%s: at least one method disagreed with the reference (see the agree column)\n", kProgram);
    return 1;
  }
  if (validation_messages > 0) {
    std::fprintf(stderr, "%s: %zu validation messages\n", kProgram, validation_messages);
    return 1;
  }
  return 0;
}
