// bench_flat: the scalar CPU reference against flat GPU culling, side by side in one run.
// For each volume kind and object count N it reports the median of repeated runs, in ns per
// object: CPU reference time, GPU time between timestamps, and GPU wall time (record, submit,
// wait, read the counters back). Every cell is checked once: GPU classes == CPU classes.
//
// usage: bench_flat [--sizes 1000,10000,...] [--bv aabb,obb,sphere] [--repeats R]
//                   [--device NAME] [--csv FILE] [--json FILE]
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <iostream>
#include <nlohmann/json.hpp>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "bench_util.hpp"
#include "cullpipe/cull/reference.hpp"
#include "cullpipe/gpu/gpu_culler.hpp"
#include "cullpipe/scene/generators.hpp"
#include "cullpipe/vulkan/context.hpp"

using namespace cullpipe;
using namespace cullpipe::bench;

namespace {

struct Cell {
  std::string bv;
  std::size_t n = 0;
  double visible_fraction = 0;
  double cpu_ns = 0, gpu_ns = 0, gpu_wall_ns = 0;  // medians, whole pass
  double gpu_ordered_ns = 0, gpu_draws_ns = 0;     // GPU time with object-order ids; plus draw commands
  bool agree = false;
  std::string note;
};

template <class Volume>
Cell measure(gpu::GpuCuller& culler, const std::vector<Volume>& volumes, const Frustum& frustum, int repeats) {
  Cell cell;
  cell.n = volumes.size();
  std::vector<Classification> cpu(volumes.size());
  std::vector<double> cpu_times, gpu_times, wall_times;
  reference::CullCounts counts;
  for (int r = 0; r < repeats; ++r) {
    const auto t0 = std::chrono::steady_clock::now();
    counts = reference::classify_all(std::span<const Volume>(volumes), frustum, cpu);
    cpu_times.push_back(
        double(std::chrono::duration_cast<std::chrono::nanoseconds>(std::chrono::steady_clock::now() - t0).count()));
  }
  cell.visible_fraction = volumes.empty() ? 0.0 : double(counts.visible) / double(volumes.size());

  const Frustum views[1] = {frustum};
  try {
    culler.upload(std::span<const Volume>(volumes));
  } catch (const std::length_error& e) {
    cell.note = "gpu skipped: exceeds one storage buffer";
    cell.cpu_ns = median(cpu_times);
    return cell;
  }
  const gpu::CullResult checked = culler.cull(views);  // warm-up (pipeline compile) and check
  cell.agree = checked.views[0].classes == cpu && checked.views[0].counts == counts;
  // The same pass with object-order compaction, then also writing draw commands (checked
  // once each: the ordered ids are the CPU's visible objects in order).
  std::vector<gpu::DrawCommand> templates(volumes.size());
  for (std::uint32_t i = 0; i < templates.size(); ++i) templates[i] = {36, 1, 0, 0, i, 0};
  culler.upload_draws(templates);
  std::vector<std::uint32_t> expected;
  for (std::uint32_t i = 0; i < cpu.size(); ++i)
    if (cpu[i] != Classification::Outside) expected.push_back(i);
  const gpu::CullOptions ordered{false, true, 0, true, false}, draws{false, true, 0, true, true};
  // Object order is limited to one storage buffer of objects; bigger cells time the atomic
  // pass only.
  bool ordered_fits = true;
  try {
    cell.agree = cell.agree && culler.cull(views, ordered).views[0].visible_ids == expected &&
                 culler.cull(views, draws).views[0].draws.size() == expected.size();
  } catch (const std::length_error&) {
    ordered_fits = false;
    cell.note = "ordered skipped: more than one storage buffer";
  }
  const gpu::CullOptions counters_only{false, false, 0};
  const gpu::CullOptions ordered_timed{false, false, 0, true, false}, draws_timed{false, false, 0, true, true};
  std::vector<double> ordered_times, draw_times;
  for (int r = 0; r < repeats; ++r) {  // interleaved, so drift hits all three alike
    const gpu::CullResult g = culler.cull(views, counters_only);
    gpu_times.push_back(g.timings.gpu_ns);
    wall_times.push_back(g.timings.wall_ns);
    if (!ordered_fits) continue;
    ordered_times.push_back(culler.cull(views, ordered_timed).timings.gpu_ns);
    draw_times.push_back(culler.cull(views, draws_timed).timings.gpu_ns);
  }
  cell.gpu_ordered_ns = median(ordered_times);
  cell.gpu_draws_ns = median(draw_times);
  cell.cpu_ns = median(cpu_times);
  cell.gpu_ns = median(gpu_times);
  cell.gpu_wall_ns = median(wall_times);
  return cell;
}

}  // namespace

int main(int argc, char** argv) {
  std::vector<std::size_t> sizes = {1000, 10000, 100000, 1000000, 4000000};
  std::vector<std::string> kinds = {"aabb", "obb", "sphere"};
  int repeats = 0;  // 0: chosen per size
  std::string device, csv_path, json_path;
  CLI::App app{"bench_flat: the scalar CPU reference against flat GPU culling"};
  add_counts_option(app, "--sizes", sizes, "Object counts")->default_str("1e3,1e4,1e5,1e6,4e6");
  add_names_option(app, "--bv", kinds, {"aabb", "obb", "sphere"}, "Bounding volumes")->default_str("aabb,obb,sphere");
  app.add_option("--repeats", repeats, "Repeats per cell (0: chosen by size)")
      ->capture_default_str()
      ->check(CLI::NonNegativeNumber);
  app.add_option("--device", device, "Vulkan device name substring");
  app.add_option("--csv", csv_path, "Write the results as CSV");
  app.add_option("--json", json_path, "Write the results as JSON");
  bench::parse_command_line(app, argc, argv);

  vulkan::ContextOptions options;
  options.device_filter = device;
  vulkan::Context ctx(options);
  gpu::GpuCuller culler(ctx);
  std::printf("bench_flat: scalar CPU reference vs flat GPU culling, medians of repeats\n");
  std::printf("cpu: %s, %u hardware threads (reference is single-threaded)\n", cpu_model().c_str(),
              std::thread::hardware_concurrency());
  std::printf("gpu: %s, %s\n\n", ctx.info().name.c_str(), ctx.info().driver.c_str());
  std::printf("%-7s %9s %8s %8s %12s %12s %12s %10s %12s %12s %6s\n", "bv", "N", "visible", "repeats", "cpu ns/obj",
              "gpu ns/obj", "wall ns/obj", "cpu/gpu", "ordered/gpu", "+draws/gpu", "agree");

  std::vector<Cell> cells;
  bool all_agree = true;
  const std::size_t largest = *std::max_element(sizes.begin(), sizes.end());
  const Scene scene = generate_scene(SceneKind::Uniform, largest, 1);
  for (const std::string& kind : kinds) {
    const auto bv = parse_bv_kind(kind);
    if (!bv) {
      std::fprintf(stderr, "bench_flat: unknown --bv %s\n", kind.c_str());
      return 2;
    }
    for (std::size_t n : sizes) {
      // The first n objects of one large scene, seen by that scene's camera.
      Scene part;
      part.objects.assign(scene.objects.begin(), scene.objects.begin() + std::ptrdiff_t(n));
      part.camera = scene.camera;
      const Frustum frustum = Frustum::from_view_proj(part.camera.view_proj());
      const int reps =
          repeats > 0 ? repeats : int(std::clamp<std::size_t>(20'000'000 / std::max<std::size_t>(n, 1), 5, 101));
      Cell cell;
      if (*bv == BvKind::Aabb) cell = measure(culler, world_aabbs(part), frustum, reps);
      if (*bv == BvKind::Obb) cell = measure(culler, world_obbs(part), frustum, reps);
      if (*bv == BvKind::Sphere) cell = measure(culler, world_spheres(part), frustum, reps);
      cell.bv = kind;
      const double dn = double(std::max<std::size_t>(n, 1));
      if (cell.gpu_ns == 0 && !cell.note.empty()) {
        std::printf("%-7s %9zu %7.1f%% %8d %12.2f   (%s)\n", kind.c_str(), n, 100 * cell.visible_fraction, reps,
                    cell.cpu_ns / dn, cell.note.c_str());
      } else {
        all_agree &= cell.agree;
        std::printf("%-7s %9zu %7.1f%% %8d %12.2f %12.2f %12.2f %10.2f %12.2f %12.2f %6s\n", kind.c_str(), n,
                    100 * cell.visible_fraction, reps, cell.cpu_ns / dn, cell.gpu_ns / dn, cell.gpu_wall_ns / dn,
                    cell.cpu_ns / std::max(cell.gpu_ns, 1.0), cell.gpu_ordered_ns / std::max(cell.gpu_ns, 1.0),
                    cell.gpu_draws_ns / std::max(cell.gpu_ns, 1.0), cell.agree ? "yes" : "NO");
        if (!cell.note.empty()) std::printf("        (%s)\n", cell.note.c_str());
      }
      std::fflush(stdout);
      cells.push_back(cell);
    }
  }

  if (!csv_path.empty()) {
    std::ofstream csv(csv_path);
    csv << "bv,n,visible_fraction,cpu_ns_per_object,gpu_ns_per_object,gpu_wall_ns_per_object,cpu_over_gpu,"
           "gpu_ordered_ns_per_object,gpu_ordered_draws_ns_per_object,agree,note\n";
    for (const Cell& c : cells) {
      const double dn = double(std::max<std::size_t>(c.n, 1));
      csv << c.bv << "," << c.n << "," << c.visible_fraction << "," << c.cpu_ns / dn << "," << c.gpu_ns / dn << ","
          << c.gpu_wall_ns / dn << "," << (c.gpu_ns > 0 ? c.cpu_ns / c.gpu_ns : 0.0) << "," << c.gpu_ordered_ns / dn
          << "," << c.gpu_draws_ns / dn << "," << c.agree << "," << c.note << "\n";
    }
  }
  if (!json_path.empty()) {
    nlohmann::json j;
    j["cpu"] = cpu_model();
    j["threads"] = std::thread::hardware_concurrency();
    j["device"] = ctx.info().name;
    j["driver"] = ctx.info().driver;
    j["cells"] = nlohmann::json::array();
    for (const Cell& c : cells) {
      const double dn = double(std::max<std::size_t>(c.n, 1));
      j["cells"].push_back({{"method", "reference_vs_gpu_flat"},
                            {"bv", c.bv},
                            {"n", c.n},
                            {"visible_fraction", c.visible_fraction},
                            {"cpu_ns_per_object", c.cpu_ns / dn},
                            {"gpu_ns_per_object", c.gpu_ns / dn},
                            {"gpu_ordered_ns_per_object", c.gpu_ordered_ns / dn},
                            {"gpu_ordered_draws_ns_per_object", c.gpu_draws_ns / dn},
                            {"gpu_wall_ns_per_object", c.gpu_wall_ns / dn},
                            {"agree", c.agree},
                            {"note", c.note}});
    }
    std::ofstream(json_path) << j.dump(2) << "\n";
  }
  if (!all_agree) {
    std::fprintf(stderr, "bench_flat: GPU and CPU disagree in at least one cell\n");
    return 1;
  }
  return 0;
}
