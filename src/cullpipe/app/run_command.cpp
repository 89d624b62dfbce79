#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <nlohmann/json.hpp>
#include <ostream>

#include "cullpipe/app/backends.hpp"
#include "cullpipe/app/commands.hpp"
#include "cullpipe/app/guard.hpp"
#include "cullpipe/app/scene_source.hpp"
#include "cullpipe/geom/bv_kind.hpp"
#include "cullpipe/scene/cull_case_io.hpp"
#include "cullpipe/scene/generators.hpp"
#include "cullpipe/scene/gltf_scene.hpp"
#include "cullpipe/scene/json_util.hpp"
#include "cullpipe/scene/scene_io.hpp"

#ifndef CULLPIPE_SOURCE_SCENES_DIR
#define CULLPIPE_SOURCE_SCENES_DIR ""
#endif

namespace cullpipe::app {
namespace {

std::string format_ms(double ns) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%.3f", ns / 1e6);
  return buf;
}

std::string pad(const std::string& s, std::size_t width) {
  return s.size() >= width ? s : std::string(width - s.size(), ' ') + s;
}

std::string format_fixed(double value, int digits) {
  char buf[48];
  std::snprintf(buf, sizeof buf, "%.*f", digits, value);
  return buf;
}

CpuPath cpu_path(const RunOptions& o) { return o.cpu == "fast" ? CpuPath::Fast : CpuPath::Reference; }

// Hierarchical culling of one kind of volume: the tree is built over the volumes' enclosing
// boxes (the boxes themselves for AABBs).
template <class Volume>
BackendResults cull_kind_bvh(const std::vector<Volume>& volumes, std::span<const Frustum> frusta, const RunOptions& o,
                             GpuBackend& gpu_backend, std::vector<cullpipe::Volume>& dump_volumes, BuiltBvh& built) {
  const std::span<const Volume> span(volumes);
  built = build_bvh(o.builder, bvh::enclosing_boxes(span), o.leaf_size);
  if (!o.dump_path.empty()) dump_volumes.assign(volumes.begin(), volumes.end());
  return cull_bvh_on_backends(built.flat, span, frusta, o.backend, gpu_backend, /*warm_up=*/true, cpu_path(o),
                              o.range_objects);
}

// Culls one kind of volume; with a dump path, also keeps the volumes for the dump.
template <class Volume>
BackendResults cull_kind(const std::vector<Volume>& volumes, std::span<const Frustum> frusta, const RunOptions& o,
                         GpuBackend& gpu_backend, std::vector<cullpipe::Volume>& dump_volumes) {
  if (!o.dump_path.empty()) dump_volumes.assign(volumes.begin(), volumes.end());
  return cull_on_backends<Volume>(volumes, frusta, o.backend, gpu_backend, /*warm_up=*/true, {}, 10, cpu_path(o));
}

}  // namespace

std::string default_scene_path() {
  namespace fs = std::filesystem;
  std::vector<fs::path> candidates;
  std::error_code ec;
  const fs::path exe = fs::read_symlink("/proc/self/exe", ec);
  if (!ec) candidates.push_back(exe.parent_path().parent_path() / "share" / "cullpipe" / "scenes" / "default.json");
  if (*CULLPIPE_SOURCE_SCENES_DIR) candidates.push_back(fs::path(CULLPIPE_SOURCE_SCENES_DIR) / "default.json");
  for (const fs::path& p : candidates)
    if (fs::exists(p, ec)) return p.string();
  throw InputError("the default scene (scenes/default.json) was not found; looked in: " +
                   (candidates.empty() ? std::string("(nowhere)") : candidates.back().string()) +
                   "; pass --scene FILE or --generate KIND:N");
}

int run_command(const RunOptions& o, std::ostream& out, std::ostream& err) {
  return guarded(err, [&]() -> int {
    const auto bv = parse_bv_kind(o.bv);
    if (!bv) throw InputError("--bv " + o.bv + ": expected aabb, obb or sphere");
    if (o.views == 0) throw InputError("--views must be at least 1");
    if (o.cull != "flat" && o.cull != "bvh") throw InputError("--cull " + o.cull + ": expected flat or bvh");
    if (o.cpu != "reference" && o.cpu != "fast") throw InputError("--cpu " + o.cpu + ": expected reference or fast");
    if (o.cpu == "fast" && o.backend == Backend::Gpu)
      throw InputError("--cpu fast needs the CPU side: use --backend cpu or both");
    const bool hierarchical = o.cull == "bvh";

    LoadedScene loaded = load_scene_source(o);
    if (o.occlusion || o.clusters) return run_occlusion(o, loaded, *bv, out, err);  // (--clusters: two phases)
    const Scene& scene = loaded.scene;
    const std::string& source = loaded.source;
    const bool from_gltf = loaded.from_gltf;
    const std::size_t zero_scale = loaded.zero_scale_instances;
    const double load_ns = loaded.load_ns;

    const std::vector<Camera> cameras = scene_camera_path(scene, o.views);
    std::vector<Frustum> frusta;
    for (std::size_t v = 0; v < cameras.size(); ++v) {
      try {
        frusta.push_back(Frustum::from_view_proj(cameras[v].view_proj()));
      } catch (const std::invalid_argument& e) {
        throw InputError(source + ": camera of view " + std::to_string(v) + ": " + e.what());
      }
    }

    GpuBackend gpu_backend{o.device, nullptr, nullptr};
    BackendResults r;
    std::vector<cullpipe::Volume> dump_volumes;
    BuiltBvh built;
    switch (*bv) {
      case BvKind::Aabb:
        r = hierarchical
                ? cull_kind_bvh(world_aabbs(scene, loaded.aabb_update), frusta, o, gpu_backend, dump_volumes, built)
                : cull_kind(world_aabbs(scene, loaded.aabb_update), frusta, o, gpu_backend, dump_volumes);
        break;
      case BvKind::Obb:
        r = hierarchical ? cull_kind_bvh(world_obbs(scene), frusta, o, gpu_backend, dump_volumes, built)
                         : cull_kind(world_obbs(scene), frusta, o, gpu_backend, dump_volumes);
        break;
      case BvKind::Sphere:
        r = hierarchical ? cull_kind_bvh(world_spheres(scene), frusta, o, gpu_backend, dump_volumes, built)
                         : cull_kind(world_spheres(scene), frusta, o, gpu_backend, dump_volumes);
        break;
    }

    const std::size_t n = scene.objects.size();
    const bool have_cpu = !r.cpu.empty(), have_gpu = !r.gpu.empty();
    const auto& counts = have_cpu ? r.cpu_counts : r.gpu_counts;
    out << "cullpipe run: " << (scene.name.empty() ? source : scene.name) << " (" << source << "), " << n
        << " objects, bv " << o.bv << ", " << frusta.size() << (frusta.size() == 1 ? " view" : " views");
    if (gpu_backend.context) out << ", device " << gpu_backend.context->info().name;
    out << "\n";
    if (from_gltf) {
      out << "  volumes from mesh vertices: obb " << o.obb << ", sphere " << o.sphere << ", world aabb "
          << o.aabb_update;
      if (zero_scale) out << "; " << zero_scale << " zero-scale instances skipped";
      out << "\n";
    }
    out << "  scene loaded in " << format_ms(load_ns) << " ms\n";
    if (hierarchical)
      out << "  bvh: " << o.builder << ", leaves of <= " << o.leaf_size << ", " << built.metrics.nodes
          << " nodes, depth " << built.metrics.depth << ", SAH cost " << format_fixed(built.metrics.sah_cost, 2)
          << ", built in " << format_ms(built.build_ns) << " ms\n";
    out << "\n  view  objects  visible   inside  intersecting  outside  node tests  object tests\n";
    const std::size_t shown = std::min<std::size_t>(frusta.size(), 16);
    for (std::size_t v = 0; v < shown; ++v) {
      const auto& c = counts[v];
      out << pad(std::to_string(v), 6) << pad(std::to_string(n), 9) << pad(std::to_string(c.visible), 9)
          << pad(std::to_string(c.inside), 9) << pad(std::to_string(c.intersecting), 14)
          << pad(std::to_string(n - c.visible), 9) << pad(std::to_string(r.node_tests[v]), 12)
          << pad(std::to_string(r.object_tests[v]), 14) << "\n";
    }
    if (shown < frusta.size()) out << "  ... " << frusta.size() - shown << " more views\n";
    out << "\n";
    const double object_views = double(std::max<std::size_t>(n * frusta.size(), 1));
    if (have_cpu)
      out << "  cpu " << r.cpu_path << ": " << format_ms(r.cpu_ns) << " ms ("
          << format_ms(r.cpu_ns / object_views * 1e6) << " ns per object-view)"
          << (r.cpu_upload_ns > 0 ? "; upload " + format_ms(r.cpu_upload_ns) + " ms" : "") << "\n";
    if (have_gpu)
      out << "  gpu:           " << format_ms(r.gpu_ns) << " ms on the GPU (timestamps), " << format_ms(r.gpu_wall_ns)
          << " ms wall with submit and readback; upload " << format_ms(r.gpu_upload_ns) << " ms\n";
    const std::string all_identical =
        "all " + std::to_string(n * frusta.size()) + " object-view classifications identical";
    if (have_cpu && have_gpu && r.mismatches == 0 && r.fast_mismatches == 0)
      out << "  agreement:     " << all_identical << " ("
          << (r.fast_checked ? "gpu == fast cpu == reference" : "gpu == cpu") << ")\n";
    else if (have_cpu && !have_gpu && r.fast_checked && r.fast_mismatches == 0)
      out << "  agreement:     " << all_identical << " (fast cpu == reference)\n";
    if (r.mismatches) out << "  agreement:     " << r.mismatches << " MISMATCHES between the GPU and the CPU\n";
    if (r.fast_mismatches)
      out << "  agreement:     " << r.fast_mismatches << " MISMATCHES between the fast CPU path and the reference\n";
    if (r.gpu_overflow) out << "  warning: the GPU visible-id list overflowed\n";

    if (!o.json_path.empty()) {
      nlohmann::json j;
      j["scene"] = scene.name;
      j["source"] = source;
      j["objects"] = n;
      j["bv"] = o.bv;
      j["cull"] = o.cull;
      if (hierarchical) {
        j["builder"] = o.builder;
        j["leaf_size"] = o.leaf_size;
        j["range_objects"] = have_cpu ? cpu_range_objects(cpu_path(o), o.range_objects, *bv) : 0;
        j["build_ns"] = built.build_ns;
        j["bvh"] = {{"nodes", built.metrics.nodes},
                    {"leaves", built.metrics.leaves},
                    {"depth", built.metrics.depth},
                    {"sah_cost", built.metrics.sah_cost}};
      }
      j["views"] = frusta.size();
      j["backend"] = o.backend == Backend::Both ? "both" : o.backend == Backend::Gpu ? "gpu" : "cpu";
      if (gpu_backend.context) {
        j["device"] = gpu_backend.context->info().name;
        j["driver"] = gpu_backend.context->info().driver;
      }
      if (have_cpu) {
        j["cpu_ns"] = r.cpu_ns;
        j["cpu_path"] = r.cpu_path;
        if (r.cpu_upload_ns > 0) j["cpu_upload_ns"] = r.cpu_upload_ns;
      }
      if (have_gpu) {
        j["gpu_ns"] = r.gpu_ns;
        j["gpu_wall_ns"] = r.gpu_wall_ns;
        j["gpu_upload_ns"] = r.gpu_upload_ns;
      }
      j["mismatches"] = r.mismatches;
      if (r.fast_checked) j["fast_mismatches"] = r.fast_mismatches;
      j["agree"] = (have_cpu && have_gpu) || r.fast_checked
                       ? nlohmann::json(r.mismatches == 0 && r.fast_mismatches == 0)
                       : nlohmann::json(nullptr);
      nlohmann::json per_view = nlohmann::json::array();
      for (std::size_t v = 0; v < counts.size(); ++v)
        per_view.push_back({{"visible", counts[v].visible},
                            {"inside", counts[v].inside},
                            {"intersecting", counts[v].intersecting},
                            {"node_tests", r.node_tests[v]},
                            {"object_tests", r.object_tests[v]}});
      j["per_view"] = per_view;
      json_util::write_file_atomic(o.json_path, j.dump(2) + "\n");
    }
    if (!o.dump_path.empty()) {
      CullCase c{frusta, frusta.size() > 1, std::move(dump_volumes), {}, {}};
      // The counts are the CPU traversal's when the CPU ran, else the GPU's (which descends to the leaves).
      const std::uint32_t range_objects = have_cpu ? cpu_range_objects(cpu_path(o), o.range_objects, *bv) : 0;
      for (std::size_t v = 0; v < frusta.size(); ++v)
        c.tests.push_back({o.cull, r.node_tests[v], r.object_tests[v], range_objects});
      if (from_gltf) {
        // Where each object came from, and all its world-space volumes.
        const std::vector<Aabb> aabbs = world_aabbs(scene, loaded.aabb_update);
        const std::vector<Obb> obbs = world_obbs(scene);
        const std::vector<Sphere> spheres = world_spheres(scene);
        c.objects.reserve(n);
        for (std::size_t i = 0; i < n; ++i)
          c.objects.push_back({scene.objects[i].origin, aabbs[i], obbs[i], spheres[i]});
      }
      json_util::write_file_atomic(o.dump_path, cull_case_to_json(c, have_cpu ? &r.cpu : &r.gpu));
    }

    if (r.mismatches || r.fast_mismatches) {
      err << "error: ";
      if (r.mismatches)
        err << "GPU and CPU disagree (" << r.mismatches << " differences)" << (r.fast_mismatches ? "; " : "");
      if (r.fast_mismatches)
        err << "the fast CPU path and the reference disagree (" << r.fast_mismatches << " differences)";
      err << "; first ones:\n";
      for (const std::string& m : r.mismatch_reports) err << "  " << m << "\n";
      return kExitMismatch;
    }
    return kExitOk;
  });
}

}  // namespace cullpipe::app
