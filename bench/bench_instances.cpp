// bench_instances: a frame loop over a camera path through a scene of instances, a fraction of
// them moving each frame, culled on the GPU three ways in one run:
//  - world:  the CPU places every object (InstanceSet::world_volumes, every core) and uploads
//            the world volumes (GpuCuller::upload), as an engine without instances does;
//  - moved:  only the moved objects' transforms are sent (GpuCuller::update) and placed by the GPU;
//  - placed: every object's transform is sent and placed by the GPU each frame (the cost of
//            transforming in the shader, against world's cull of ready volumes; not for OBBs,
//            which are placed on the host);
//  - tree:   (boxes) a BVH built once over the placed boxes; the moved objects' transforms are
//            sent (BvhCuller::update), placed and the tree refitted above them by the GPU
//            (BvhCuller::refit), then culled hierarchically. Its "pass wall" column times the
//            placing and refit, "gpu" the refit alone, and "cull gpu" the hierarchical cull; then
//            every object is sent again and every node refitted. The refit's GPU time over
//            world's flat cull alone is the figure the refit is measured by.
// Per frame: CPU time of the move (new transforms into the set, the same for all three), of the
// send (world: placing and uploading; moved and placed: the update), of the pass's recording,
// submission and wait, and the GPU time between timestamps (placing and culling). Every frame's
// classes are checked against the reference on the set's placed volumes, for every method.
//
// usage: bench_instances [--objects N] [--moving F] [--frames F] [--bv aabb,obb,sphere]
//                        [--device NAME] [--validation] [--json FILE]
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <fstream>
#include <map>
#include <nlohmann/json.hpp>
#include <numeric>
#include <random>
#include <string>
#include <thread>
#include <vector>

#include "bench_util.hpp"
#include "cullpipe/bvh/builders.hpp"
#include "cullpipe/core/thread_pool.hpp"
#include "cullpipe/cull/instances.hpp"
#include "cullpipe/cull/reference.hpp"
#include "cullpipe/gpu/bvh_culler.hpp"
#include "cullpipe/gpu/gpu_culler.hpp"
#include "cullpipe/scene/generators.hpp"
#include "cullpipe/vulkan/context.hpp"

using namespace cullpipe;
using namespace cullpipe::bench;

namespace {

struct Config {
  std::size_t objects = 1'000'000;
  double moving = 0.1;
  std::size_t frames = 30;
  std::vector<std::string> kinds = {"aabb", "obb", "sphere"};
  std::string device, json_path;
  bool validation = false;
};

// Per method, per frame: milliseconds.
struct Times {
  std::vector<double> move, send, pass_wall, gpu, cull_gpu;
  std::vector<double> refit_gpu;  // tree: every object placed and every node refitted
};

struct Row {
  std::string bv;
  std::map<std::string, Times> methods;
  std::size_t moved_per_frame = 0;
  bool agree = true;
};

constexpr std::size_t kMeshes = 256;

template <class Volume>
Volume local_volume(const SceneObject& o) {
  if constexpr (std::is_same_v<Volume, Aabb>)
    return o.local_bounds;
  else if constexpr (std::is_same_v<Volume, Obb>)
    return Obb{o.local_bounds.center(), glm::mat3(1.0f), o.local_bounds.half_extent()};
  else
    return Sphere{o.local_bounds.center(), glm::length(o.local_bounds.half_extent()) * (1.0f + 0x1p-20f)};
}

template <class Volume>
bool agrees(const InstanceSet<Volume>& set, const gpu::CullResult& result, const Frustum& view) {
  std::vector<Volume> world(set.size());
  set.world_volumes(world);
  std::vector<Classification> cpu(world.size());
  const reference::CullCounts counts = reference::classify_all(std::span<const Volume>(world), view, cpu);
  return result.views.at(0).classes == cpu && result.views[0].counts == counts;
}

template <class Volume>
Row run(vulkan::Context& ctx, const Scene& scene, const Config& config) {
  Row row;
  row.bv = std::is_same_v<Volume, Aabb> ? "aabb" : std::is_same_v<Volume, Obb> ? "obb" : "sphere";
  std::vector<Volume> meshes;
  for (std::size_t m = 0; m < kMeshes && m < scene.objects.size(); ++m)
    meshes.push_back(local_volume<Volume>(scene.objects[m]));
  InstanceSet<Volume> set(meshes);
  std::vector<Transform3x4> base;
  for (std::size_t i = 0; i < scene.objects.size(); ++i) {
    base.push_back(Transform3x4::from_mat4(scene.objects[i].world));
    set.add(static_cast<std::uint32_t>(i % kMeshes), base.back());
  }
  set.clear_changes();
  ThreadPool pool(0);
  gpu::GpuCuller world_culler(ctx), moved_culler(ctx), placed_culler(ctx);
  std::vector<Volume> world(set.size());
  set.world_volumes(world, &pool);
  world_culler.upload(std::span<const Volume>(world));
  moved_culler.upload(set);
  if constexpr (!std::is_same_v<Volume, Obb>) placed_culler.upload(set);  // (not run for OBBs, see below)
  constexpr bool kTree = std::is_same_v<Volume, Aabb>;
  gpu::BvhCuller tree_culler(ctx);
  if constexpr (kTree) {
    bvh::BuildOptions build;
    build.pool = &pool;
    tree_culler.upload(bvh::flatten(bvh::build("binned-sah", world, build)), set);
  }
  const std::vector<Camera> path = scene_camera_path(scene, config.frames);
  std::vector<std::uint32_t> all(set.size());
  std::iota(all.begin(), all.end(), 0u);
  std::mt19937 rng(7);
  row.moved_per_frame = static_cast<std::size_t>(config.moving * double(set.size()));
  std::vector<InstanceId> ids(row.moved_per_frame);
  std::vector<Transform3x4> moves(row.moved_per_frame);
  const gpu::CullOptions options{.classes = true, .visible_ids = false};
  for (std::size_t frame = 0; frame <= config.frames; ++frame) {  // frame 0 warms up (pipelines, pages)
    const Frustum view = Frustum::from_view_proj(path[frame % path.size()].view_proj());
    // The move: a tenth of the objects (by default) step a little.
    for (std::size_t k = 0; k < ids.size(); ++k) ids[k] = static_cast<InstanceId>(rng() % set.size());
    std::sort(ids.begin(), ids.end());
    ids.erase(std::unique(ids.begin(), ids.end()), ids.end());
    moves.resize(ids.size());
    for (std::size_t k = 0; k < ids.size(); ++k) {
      moves[k] = base[ids[k]];
      for (glm::vec4& r : moves[k].rows) r.w += static_cast<float>(frame % 7) * 0.25f;
    }
    const auto t_move = Clock::now();
    set.set_transforms(ids, moves);
    const double move_ms = since(t_move) * 1e-6;
    const std::vector<std::uint32_t> changed = set.changed_slots();
    set.clear_changes();
    auto timed = [&](const std::string& method, gpu::GpuCuller& culler, auto&& send) {
      const auto t_send = Clock::now();
      send();
      const double send_ms = since(t_send) * 1e-6;
      const gpu::CullResult result = culler.cull(std::span<const Frustum>(&view, 1), options);
      row.agree = row.agree && agrees(set, result, view);
      if (frame == 0) return;
      Times& t = row.methods[method];
      t.move.push_back(move_ms);
      t.send.push_back(send_ms);
      t.pass_wall.push_back(result.timings.wall_ns * 1e-6);
      t.gpu.push_back(result.timings.gpu_ns * 1e-6);
      // The same pass again, with nothing left to place: the cull alone.
      t.cull_gpu.push_back(culler.cull(std::span<const Frustum>(&view, 1), options).timings.gpu_ns * 1e-6);
    };
    // Interleaved within each frame, so drift in the machine hits all three alike.
    timed("world", world_culler, [&] {
      set.world_volumes(world, &pool);
      world_culler.upload(std::span<const Volume>(world));
    });
    timed("moved", moved_culler, [&] { moved_culler.update(set, changed); });
    // (OBBs are placed on the host: sending every one is the world method's work again.)
    if constexpr (!std::is_same_v<Volume, Obb>) timed("placed", placed_culler, [&] { placed_culler.update(set, all); });
    if constexpr (kTree) {
      const auto t_send = Clock::now();
      tree_culler.update(set, changed);
      const double send_ms = since(t_send) * 1e-6;
      const gpu::CullTimings refit = tree_culler.refit();
      const gpu::CullResult result = tree_culler.cull(std::span<const Frustum>(&view, 1), options);
      row.agree = row.agree && agrees(set, result, view);
      if (frame != 0) {
        Times& t = row.methods["tree"];
        t.move.push_back(move_ms);
        t.send.push_back(send_ms);
        t.pass_wall.push_back(refit.wall_ns * 1e-6);
        t.gpu.push_back(refit.gpu_ns * 1e-6);
        t.cull_gpu.push_back(result.timings.gpu_ns * 1e-6);
        // Every object sent again: every object placed and every node refitted.
        tree_culler.update(set, all);
        t.refit_gpu.push_back(tree_culler.refit().gpu_ns * 1e-6);
      }
    }
    moves.resize(row.moved_per_frame);
    ids.resize(row.moved_per_frame);
  }
  return row;
}

}  // namespace

int main(int argc, char** argv) {
  Config config;
  CLI::App app{"bench_instances: moving instances culled on the GPU, against re-uploading world volumes"};
  app.add_option("--objects", config.objects, "Objects in the scene")
      ->capture_default_str()
      ->check(CLI::PositiveNumber);
  app.add_option("--moving", config.moving, "Fraction of the objects moving each frame")
      ->capture_default_str()
      ->check(CLI::Range(0.0, 1.0));
  app.add_option("--frames", config.frames, "Frames along the camera path (medians over them)")
      ->capture_default_str()
      ->check(CLI::PositiveNumber);
  add_names_option(app, "--bv", config.kinds, {"aabb", "obb", "sphere"}, "Bounding volumes")
      ->default_str("aabb,obb,sphere");
  app.add_option("--device", config.device, "Vulkan device name substring");
  app.add_flag("--validation", config.validation, "Vulkan validation layers on; any message makes the exit status 1");
  app.add_option("--json", config.json_path, "Write the results as JSON");
  bench::parse_command_line(app, argc, argv);

  vulkan::ContextOptions options;
  options.device_filter = config.device;
  options.validation = config.validation;
  vulkan::Context ctx(options);
  std::printf("bench_instances: %zu objects, %.0f%% moving per frame, %zu frames (medians), a pass of one view\n",
              config.objects, 100 * config.moving, config.frames);
  std::printf("cpu: %s, %u hardware threads; gpu: %s, %s\n\n", cpu_model().c_str(), std::thread::hardware_concurrency(),
              ctx.info().name.c_str(), ctx.info().driver.c_str());
  const Scene scene = generate_scene(SceneKind::Uniform, config.objects, 1);
  std::vector<Row> rows;
  for (const std::string& kind : config.kinds)
    rows.push_back(kind == "aabb"  ? run<Aabb>(ctx, scene, config)
                   : kind == "obb" ? run<Obb>(ctx, scene, config)
                                   : run<Sphere>(ctx, scene, config));

  std::printf("%-7s %-7s %10s %10s %12s %10s %12s\n", "bv", "method", "move ms", "send ms", "pass wall ms", "gpu ms",
              "cull gpu ms");
  bool all_agree = true;
  nlohmann::json j;
  j["cpu"] = cpu_model();
  j["threads"] = std::thread::hardware_concurrency();
  j["device"] = ctx.info().name;
  j["objects"] = config.objects;
  j["moving"] = config.moving;
  j["frames"] = config.frames;
  j["rows"] = nlohmann::json::array();
  for (const Row& row : rows) {
    all_agree &= row.agree;
    for (const char* method : {"world", "moved", "placed", "tree"}) {
      if (!row.methods.contains(method)) continue;
      const Times& t = row.methods.at(method);
      std::printf("%-7s %-7s %10.2f %10.2f %12.2f %10.2f %12.2f\n", row.bv.c_str(), method, median(t.move),
                  median(t.send), median(t.pass_wall), median(t.gpu), median(t.cull_gpu));
      j["rows"].push_back({{"bv", row.bv},
                           {"method", method},
                           {"move_ms", median(t.move)},
                           {"send_ms", median(t.send)},
                           {"pass_wall_ms", median(t.pass_wall)},
                           {"gpu_ms", median(t.gpu)},
                           {"cull_gpu_ms", median(t.cull_gpu)},
                           {"refit_gpu_ms", t.refit_gpu.empty() ? 0.0 : median(t.refit_gpu)},
                           {"agree", row.agree}});
    }
    const Times &w = row.methods.at("world"), &m = row.methods.at("moved");
    std::printf("%-7s moved send / world send %.3f, with the move %.3f; gpu over world's: moved %.2f", row.bv.c_str(),
                median(m.send) / median(w.send), (median(m.move) + median(m.send)) / median(w.send),
                median(m.gpu) / median(w.gpu));
    if (row.methods.contains("placed"))
      std::printf(", placed %.2f", median(row.methods.at("placed").gpu) / median(w.gpu));
    std::printf("\n");
    if (row.methods.contains("tree")) {
      const Times& r = row.methods.at("tree");
      std::printf(
          "%-7s tree over world's flat cull alone, gpu: refit above the moved objects %.2f (%.2f ms), "
          "of every node %.2f (%.2f ms); hierarchical cull %.2f\n",
          row.bv.c_str(), median(r.gpu) / median(w.cull_gpu), median(r.gpu), median(r.refit_gpu) / median(w.cull_gpu),
          median(r.refit_gpu), median(r.cull_gpu) / median(w.cull_gpu));
    }
  }
  if (!config.json_path.empty()) std::ofstream(config.json_path) << j.dump(2) << "\n";
  int status = 0;
  if (!all_agree) {
    std::fprintf(stderr, "bench_instances: a pass disagrees with the reference on the placed volumes\n");
    status = 1;
  }
  if (ctx.validation_message_count() > 0) {
    std::printf("%zu Vulkan validation message(s)\n", std::size_t(ctx.validation_message_count()));
    status = 1;
  }
  return status;
}
