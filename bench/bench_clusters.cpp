// bench_clusters: cluster culling against object culling, in one run.
//   frames  the renderer with two-phase occlusion culling, objects culled whole against objects
//           and then their clusters, with OBBs where they are tighter (the default) and with
//           boxes alone (three renderers, frames interleaved along the same path):
//           the triangles submitted (pipeline statistics) and the frame's wall time (record,
//           submit, wait, read the image back), medians over the frames after the first; the
//           first and last frames' images checked against the unculled one. Scenes: the shared
//           scenes' FlightHelmet, 2CylinderEngine and ReciprocatingSaw on an orbit path, and the
//           generated `meshes` scene (instances of one mesh), walking and turning at street level.
//   pass    the cluster pass over P (instance, cluster) pairs, with boxes alone and with OBBs,
//           against the flat ordered pass with draws over P objects (the placed cluster boxes),
//           GPU time, medians of repeats.
// Ratios are within one run: clusters over objects.
//
// usage: bench_clusters [--meshes N] [--frames F] [--pairs P] [--width W] [--height H]
//                       [--repeats R] [--device NAME] [--validation] [--json FILE]
#include <cstdio>
#include <filesystem>
#include <memory>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "bench_util.hpp"
#include "cullpipe/gpu/cluster_culler.hpp"
#include "cullpipe/gpu/gpu_culler.hpp"
#include "cullpipe/render/image.hpp"
#include "cullpipe/render/renderer.hpp"
#include "cullpipe/scene/clusters.hpp"
#include "cullpipe/scene/generators.hpp"
#include "cullpipe/scene/gltf_scene.hpp"
#include "cullpipe/vulkan/context.hpp"

using namespace cullpipe;
using namespace cullpipe::bench;

namespace {

struct Config {
  std::size_t meshes = 10000, frames = 24, pairs = 1000000;
  std::uint32_t width = 960, height = 540;
  int repeats = 9;
  std::string device, json;
  bool validation = false;
};

struct FrameRow {
  std::string scene;
  std::size_t objects = 0, frames = 0, clusters = 0;
  double object_triangles = 0, cluster_triangles = 0, box_triangles = 0;  // medians per frame
  double object_frame_ns = 0, cluster_frame_ns = 0, box_frame_ns = 0;
  std::size_t differing_frames = 0;
};

FrameRow run_frames(const vulkan::Context& ctx, const std::string& name, const Scene& scene,
                    const std::vector<Camera>& path, const Config& cfg) {
  render::RendererConfig config;
  config.width = cfg.width;
  config.height = cfg.height;
  render::Renderer objects(ctx, scene, config);
  config.clusters = true;
  render::Renderer clusters(ctx, scene, config);
  config.cluster_options.obbs = false;
  render::Renderer boxes(ctx, scene, config);
  FrameRow row;
  row.scene = name;
  row.objects = scene.objects.size();
  std::vector<double> ot, ct, bt, of, cf, bf;
  for (std::size_t f = 0; f < path.size(); ++f) {
    render::FrameStats os, cs, bs;
    auto t0 = Clock::now();
    objects.render(path[f], render::CullMode::Occlusion, &os);
    const double o_ns = since(t0);
    t0 = Clock::now();
    const render::Image image = clusters.render(path[f], render::CullMode::Occlusion, &cs);
    const double c_ns = since(t0);
    t0 = Clock::now();
    boxes.render(path[f], render::CullMode::Occlusion, &bs);
    const double b_ns = since(t0);
    row.clusters = cs.clusters;
    if (f == 0 || f + 1 == path.size())
      row.differing_frames +=
          render::count_different_pixels(image, clusters.render(path[f], render::CullMode::None)) != 0;
    if (f == 0) continue;  // the first frame has no visibility to start from
    ot.push_back(double(os.primitives));
    ct.push_back(double(cs.primitives));
    bt.push_back(double(bs.primitives));
    of.push_back(o_ns);
    cf.push_back(c_ns);
    bf.push_back(b_ns);
  }
  row.frames = ot.size();
  row.object_triangles = median(ot);
  row.cluster_triangles = median(ct);
  row.object_frame_ns = median(of);
  row.cluster_frame_ns = median(cf);
  row.box_triangles = median(bt);
  row.box_frame_ns = median(bf);
  return row;
}

struct PassRow {
  std::size_t pairs = 0, drawn = 0, obb_drawn = 0;
  double cluster_ns = 0, obb_ns = 0, flat_ns = 0;
};

PassRow run_pass(const vulkan::Context& ctx, const Config& cfg) {
  // Instances of a sphere of about 1,000 clusters, spread through a cube, seen from outside.
  const TriangleMesh mesh = uv_sphere_mesh(180, 344, 1.0f);
  const MeshClusters mc = build_clusters(mesh);
  std::vector<Aabb> boxes;
  std::vector<BackfaceCone> cones;
  std::vector<std::optional<Obb>> obbs;
  for (const Cluster& c : mc.clusters) boxes.push_back(c.box), cones.push_back(c.cone), obbs.push_back(c.obb);
  const std::size_t count = std::max<std::size_t>(1, cfg.pairs / boxes.size());
  const Scene layout = generate_scene(SceneKind::Uniform, count, 3);
  std::vector<gpu::ClusterInstance> instances;
  std::vector<Aabb> placed;
  for (const SceneObject& o : layout.objects) {
    const Transform3x4 t = Transform3x4::from_mat4(o.world);
    instances.push_back({t, 0, std::uint32_t(boxes.size()), true});
    for (const Aabb& b : boxes) placed.push_back(instance_volume(b, t));
  }
  gpu::ClusterCuller pass(ctx);
  pass.upload(boxes, cones, instances);
  std::vector<gpu::DrawCommand> draws(pass.pair_count(), gpu::DrawCommand{3, 1, 0, 0, 0, 0});
  pass.upload_draws(draws);
  gpu::ClusterCuller obb_pass(ctx);
  obb_pass.upload(boxes, cones, instances, obbs);
  obb_pass.upload_draws(draws);
  gpu::GpuCuller flat(ctx);
  flat.upload(std::span<const Aabb>(placed));
  flat.upload_draws(draws);
  const Camera cam = layout.camera;
  gpu::ClusterFrame frame;
  frame.frustum = Frustum::from_view_proj(cam.view_proj());
  frame.eye = cam.eye;
  gpu::CullOptions options;
  options.ordered = true;
  options.draws = true;
  options.classes = false;
  options.visible_ids = false;
  PassRow row;
  row.pairs = pass.pair_count();
  std::vector<double> c_ns, o_ns, f_ns;
  for (int r = 0; r < cfg.repeats + 1; ++r) {  // the first of each warms up
    const gpu::ClusterResult cr = pass.cull(frame);
    const gpu::ClusterResult orr = obb_pass.cull(frame);
    const gpu::CullResult fr = flat.cull(std::span(&frame.frustum, 1), options);
    row.drawn = cr.drawn;
    row.obb_drawn = orr.drawn;
    if (r == 0) continue;
    c_ns.push_back(cr.gpu_ns > 0 ? cr.gpu_ns : cr.wall_ns);
    o_ns.push_back(orr.gpu_ns > 0 ? orr.gpu_ns : orr.wall_ns);
    f_ns.push_back(fr.timings.gpu_ns > 0 ? fr.timings.gpu_ns : fr.timings.wall_ns);
  }
  row.cluster_ns = median(c_ns);
  row.obb_ns = median(o_ns);
  row.flat_ns = median(f_ns);
  return row;
}

}  // namespace

int main(int argc, char** argv) {
  Config cfg;
  CLI::App app{"Cluster culling against object culling: triangles, frame time, pass cost"};
  app.add_option("--meshes", cfg.meshes, "Instances in the generated meshes scene")->capture_default_str();
  app.add_option("--frames", cfg.frames, "Frames along each path")->capture_default_str()->check(CLI::Range(2, 100000));
  app.add_option("--pairs", cfg.pairs, "Pairs of the pass comparison")->capture_default_str();
  app.add_option("--width", cfg.width, "Image width")->capture_default_str();
  app.add_option("--height", cfg.height, "Image height")->capture_default_str();
  app.add_option("--repeats", cfg.repeats, "Repeats of the pass comparison")->capture_default_str();
  app.add_option("--device", cfg.device, "Vulkan device (substring of its name)");
  app.add_flag("--validation", cfg.validation, "Vulkan validation layers on (any message fails the run)");
  app.add_option("--json", cfg.json, "Also write the results as JSON");
  parse_command_line(app, argc, argv);

  vulkan::ContextOptions options;
  options.device_filter = cfg.device;
  options.validation = cfg.validation;
  std::size_t messages = 0;
  options.on_message = [&](std::string_view m) {
    ++messages;
    std::fprintf(stderr, "validation: %.*s\n", int(m.size()), m.data());
  };
  const vulkan::Context ctx(options);
  std::printf("bench_clusters on %s, device %s, %ux%u, %zu frames per path\n", cpu_model().c_str(),
              ctx.info().name.c_str(), cfg.width, cfg.height, cfg.frames);

  std::vector<FrameRow> rows;
  const std::filesystem::path shared = std::filesystem::path(CULLPIPE_SHARED_DIR) / "scenes";
  for (const char* name : {"FlightHelmet/FlightHelmet.gltf", "2CylinderEngine/2CylinderEngine.gltf",
                           "ReciprocatingSaw/ReciprocatingSaw.gltf"}) {
    if (!std::filesystem::exists(shared / name)) continue;
    const GltfScene g = load_gltf_scene((shared / name).string());
    Camera base = g.scene.camera;
    base.eye = base.target + (base.eye - base.target) * 0.6f;
    base.near_plane *= 0.2f;
    rows.push_back(run_frames(ctx, name, g.scene, camera_path(base, g.scene.bounds(), cfg.frames), cfg));
  }
  if (cfg.meshes > 0) {
    const Scene scene = generate_scene(SceneKind::Meshes, cfg.meshes, 1);
    // Walking and turning at street level: half a unit forward (the grid's cells are 10 apart)
    // and 1.4 degrees to the left a frame.
    std::vector<Camera> path;
    for (std::size_t f = 0; f < cfg.frames; ++f) {
      Camera cam = scene.camera;
      const glm::vec3 ahead = cam.target - cam.eye;
      const float a = 0.025f * float(f);
      const glm::vec3 turned(ahead.x * std::cos(a) - ahead.z * std::sin(a), ahead.y,
                             ahead.x * std::sin(a) + ahead.z * std::cos(a));
      cam.eye += glm::normalize(glm::vec3(ahead.x, 0.0f, ahead.z)) * (0.5f * float(f));
      cam.target = cam.eye + turned;
      path.push_back(cam);
    }
    rows.push_back(run_frames(ctx, "meshes:" + std::to_string(cfg.meshes), scene, path, cfg));
  }
  std::printf("\n%-40s %8s %8s %12s %12s %8s %8s %10s %10s %8s %10s %6s\n", "scene (occlusion)", "objects", "clusters",
              "tri objects", "tri clusters", "ratio", "boxes", "ms objects", "ms clusters", "speedup", "ms boxes",
              "diff");
  for (const FrameRow& r : rows)
    std::printf("%-40s %8zu %8zu %12.0f %12.0f %8.3f %8.3f %10.2f %10.2f %8.2f %10.2f %6zu\n", r.scene.c_str(),
                r.objects, r.clusters, r.object_triangles, r.cluster_triangles,
                r.cluster_triangles / r.object_triangles, r.box_triangles / r.object_triangles,
                r.object_frame_ns * 1e-6, r.cluster_frame_ns * 1e-6, r.object_frame_ns / r.cluster_frame_ns,
                r.box_frame_ns * 1e-6, r.differing_frames);
  std::printf("(ratio: clusters' triangles over objects'; boxes: the same with the clusters' boxes alone, no OBBs)\n");

  const PassRow pass = run_pass(ctx, cfg);
  std::printf("\npass over %zu: cluster pass %.2f ms (%zu drawn), flat ordered pass with draws %.2f ms: %.2fx\n",
              pass.pairs, pass.cluster_ns * 1e-6, pass.drawn, pass.flat_ns * 1e-6, pass.cluster_ns / pass.flat_ns);
  std::printf("  with OBBs: %.2f ms (%zu drawn): %.2fx the flat pass\n", pass.obb_ns * 1e-6, pass.obb_drawn,
              pass.obb_ns / pass.flat_ns);

  if (!cfg.json.empty()) {
    nlohmann::json j;
    j["device"] = ctx.info().name;
    j["cpu"] = cpu_model();
    j["width"] = cfg.width;
    j["height"] = cfg.height;
    for (const FrameRow& r : rows)
      j["frames"].push_back({{"scene", r.scene},
                             {"objects", r.objects},
                             {"clusters", r.clusters},
                             {"frames", r.frames},
                             {"object_triangles", r.object_triangles},
                             {"cluster_triangles", r.cluster_triangles},
                             {"object_frame_ns", r.object_frame_ns},
                             {"cluster_frame_ns", r.cluster_frame_ns},
                             {"box_triangles", r.box_triangles},
                             {"box_frame_ns", r.box_frame_ns},
                             {"differing_frames", r.differing_frames}});
    j["pass"] = {
        {"pairs", pass.pairs}, {"cluster_ns", pass.cluster_ns}, {"obb_ns", pass.obb_ns}, {"flat_ns", pass.flat_ns}};
    std::ofstream(cfg.json) << j.dump(2) << "\n";
  }
  bool bad = messages > 0;
  for (const FrameRow& r : rows) bad = bad || r.differing_frames > 0;
  if (bad) std::fprintf(stderr, "error: an image differed from the unculled one, or validation reported\n");
  return bad ? 1 : 0;
}
