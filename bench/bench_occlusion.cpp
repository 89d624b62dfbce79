// bench_occlusion: occlusion culling on the generated streets, along their street-level path,
// in one run.
//   frames  the renderer's frame (wall: record, submit, wait, read the image back) with frustum
//           culling alone and with two-phase occlusion culling, the two renderers' frames
//           interleaved, medians over the path's frames after the first; objects drawn, objects
//           owning a pixel of the unculled image (id buffer), drawn / owning, and any object
//           owning a pixel that was culled (must be none)
//   passes  on one frame's depth pyramid (the occlusion renderer's, mid-path): the flat and
//           hierarchical passes' wall time (record, submit, wait, read the counters) with and
//           without the pyramid, medians of repeats, and their answers against the reference's (occlusion::classify_all
//           and occlusion::cull_hierarchical); the pyramid's build time
// Ratios are within one run: occlusion over frustum-only, hierarchical over flat.
//
// usage: bench_occlusion [--sizes 1e3,1e4,..] [--frames F] [--width W] [--height H] [--texels T] [--refine-texels R]
//                        [--repeats R] [--device NAME] [--validation] [--json FILE]
#include <cstdio>
#include <functional>
#include <memory>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "bench_util.hpp"
#include "cullpipe/bvh/builders.hpp"
#include "cullpipe/core/thread_pool.hpp"
#include "cullpipe/cull/occlusion.hpp"
#include "cullpipe/cull/software_depth.hpp"
#include "cullpipe/gpu/bvh_culler.hpp"
#include "cullpipe/gpu/gpu_culler.hpp"
#include "cullpipe/render/renderer.hpp"
#include "cullpipe/scene/generators.hpp"
#include "cullpipe/vulkan/context.hpp"

using namespace cullpipe;
using namespace cullpipe::bench;

namespace {

struct Config {
  std::vector<std::size_t> sizes = {1000, 10000, 100000};
  std::size_t frames = 240;
  std::uint32_t width = 960, height = 540, texels = 4, refine_texels = 16;
  int repeats = 15;
  std::string device, json;
  bool validation = false;
};

/// One scene's numbers.
struct Row {
  std::size_t n = 0, frames = 0;
  double frustum_frame_ns = 0, occlusion_frame_ns = 0;
  double frustum_drawn = 0, occlusion_drawn = 0, owning = 0;  // means over the frames after the first
  std::size_t missed = 0;
  double flat_ns = 0, flat_occlusion_ns = 0, bvh_ns = 0, bvh_occlusion_ns = 0, pyramid_ns = 0;
  double cpu_path_ns = 0;                          // the CPU path per frame (median): rasterise, pyramid, classify
  std::size_t gpu_occluded = 0, cpu_occluded = 0;  // over the frames after the first
  std::size_t pass_frustum_kept = 0, pass_occluded = 0;
  bool agree = true;
};

/// The median wall time of a pass (record, submit, wait, read the counters back) after an
/// untimed one. (Wall, not timestamps: after the renderer's frames lavapipe's timestamps around
/// a culling pass read far below its wall time, 0.02-0.05 ms for passes of 0.4 ms.)
double median_wall_ns(int repeats, const std::function<gpu::CullResult()>& pass) {
  pass();  // untimed: pipelines, buffers
  std::vector<double> times;
  for (int r = 0; r < repeats; ++r) times.push_back(pass().timings.wall_ns);
  return median(times);
}

/// The flat and hierarchical passes with and without the pyramid of the frame `renderer` drew
/// last, seen by `camera`; their answers against the reference's; the pyramid's build time.
void measure_passes(const vulkan::Context& ctx, std::span<const Aabb> boxes, const Camera& camera,
                    const render::Renderer& renderer, const Config& config, Row& row) {
  const std::size_t n = boxes.size();
  const occlusion::OcclusionOptions occlusion_options{config.texels, config.refine_texels};
  const Frustum frustum = Frustum::from_view_proj(camera.view_proj());
  const gpu::DepthPyramidPass& pass = *renderer.pyramid();
  const occlusion::DepthPyramid pyramid = pass.read();
  const occlusion::OcclusionView view{camera.view_proj(), config.width, config.height, camera.reversed_z};
  std::vector<Classification> expected(n);
  const reference::CullCounts counts =
      occlusion::classify_all(boxes, frustum, view, pyramid, occlusion_options, expected);
  row.pass_frustum_kept = counts.visible + counts.occluded;
  row.pass_occluded = counts.occluded;
  const bvh::FlatTree tree = bvh::flatten(bvh::build("binned-sah", boxes, {.max_leaf_size = bvh::kCullingLeafSize}));
  const bvh::HierarchicalResult hierarchical =
      occlusion::cull_hierarchical(tree, boxes, frustum, view, pyramid, occlusion_options);
  gpu::GpuCuller flat(ctx);
  gpu::BvhCuller bvh(ctx);
  flat.upload(boxes);
  bvh.upload(tree, boxes);
  gpu::CullOptions frustum_only;
  frustum_only.classes = false;
  frustum_only.visible_ids = false;
  gpu::CullOptions with_pyramid = frustum_only;
  with_pyramid.pyramid = &pass;
  with_pyramid.occlusion_views = {view};
  with_pyramid.occlusion_options = occlusion_options;
  const auto one = std::span(&frustum, 1);
  row.flat_ns = median_wall_ns(config.repeats, [&] { return flat.cull(one, frustum_only); });
  row.flat_occlusion_ns = median_wall_ns(config.repeats, [&] { return flat.cull(one, with_pyramid); });
  row.bvh_ns = median_wall_ns(config.repeats, [&] { return bvh.cull(one, frustum_only); });
  row.bvh_occlusion_ns = median_wall_ns(config.repeats, [&] { return bvh.cull(one, with_pyramid); });
  // Their answers, once, with classes.
  gpu::CullOptions checked = with_pyramid;
  checked.classes = true;
  checked.visible_ids = true;
  row.agree = flat.cull(one, checked).views[0].classes == expected &&
              bvh.cull(one, checked).views[0].classes == hierarchical.classes && hierarchical.classes == expected;
  // The pyramid's build: the frame's depth copied and reduced again (GPU time, median).
  std::vector<double> builds;
  gpu::DepthPyramidPass timed(ctx);
  for (int r = 0; r <= config.repeats; ++r) {
    timed.build(renderer.depth_source(), camera.reversed_z);
    if (r > 0) builds.push_back(timed.last_gpu_ns());
  }
  row.pyramid_ns = median(builds);
}

Row measure(const vulkan::Context& ctx, std::size_t n, const Config& config) {
  Row row;
  row.n = n;
  const Scene scene = generate_scene(SceneKind::Streets, n, 1);
  const std::vector<Camera> path = scene_camera_path(scene, std::max<std::size_t>(config.frames, 2));
  render::RendererConfig rc;
  rc.width = config.width;
  rc.height = config.height;
  rc.occlusion.texels_per_axis = config.texels;
  rc.occlusion.refine_texels_per_axis = config.refine_texels;
  render::Renderer frustum_renderer(ctx, scene, rc), occlusion_renderer(ctx, scene, rc);
  // The CPU path: every building a box occluder, a buffer of a quarter of the viewport's sides.
  const std::vector<occlusion::OccluderBox> occluders = render::box_occluders(scene);
  const std::vector<Aabb> boxes = world_aabbs(scene);
  ThreadPool pool;
  std::vector<double> cpu_ns;

  // Frames: the two renderers interleaved, each on its own frames along the path; at the middle
  // frame, the passes on that frame's pyramid.
  std::vector<double> frustum_ns, occlusion_ns;
  const std::size_t mid = path.size() / 2;
  for (std::size_t f = 0; f < path.size(); ++f) {
    render::FrameStats fs, os;
    auto t0 = Clock::now();
    frustum_renderer.render(path[f], render::CullMode::Frustum, &fs);
    const double tf = since(t0);
    t0 = Clock::now();
    occlusion_renderer.render(path[f], render::CullMode::Occlusion, &os);
    const double to = since(t0);
    if (f == mid) measure_passes(ctx, boxes, path[f], occlusion_renderer, config, row);
    const std::vector<bool> owners = occlusion_renderer.pixel_owners(path[f]);
    for (std::size_t i = 0; i < owners.size(); ++i) row.missed += owners[i] && !is_visible(os.classes[i]);
    std::vector<Classification> cpu(boxes.size());
    t0 = Clock::now();
    const reference::CullCounts cpu_counts = occlusion::cull_with_software_depth(
        std::span<const Aabb>(boxes), std::span<const occlusion::OccluderBox>(occluders),
        Frustum::from_view_proj(path[f].view_proj()),
        {path[f].view_proj(), config.width, config.height, path[f].reversed_z}, std::max(1u, config.width / 4),
        std::max(1u, config.height / 4), rc.occlusion, std::span<Classification>(cpu), &pool);
    const double tc = since(t0);
    for (std::size_t i = 0; i < owners.size(); ++i) row.missed += owners[i] && !is_visible(cpu[i]);
    if (f == 0) continue;  // the first occlusion frame knows nothing visible
    frustum_ns.push_back(tf);
    occlusion_ns.push_back(to);
    cpu_ns.push_back(tc);
    row.gpu_occluded += os.occluded;
    row.cpu_occluded += cpu_counts.occluded;
    row.frustum_drawn += double(fs.draws);
    row.occlusion_drawn += double(os.draws);
    for (bool o : owners) row.owning += o;
  }
  row.frames = frustum_ns.size();
  row.frustum_frame_ns = median(frustum_ns);
  row.occlusion_frame_ns = median(occlusion_ns);
  row.cpu_path_ns = median(cpu_ns);
  row.frustum_drawn /= double(row.frames);
  row.occlusion_drawn /= double(row.frames);
  row.owning /= double(row.frames);
  return row;
}

}  // namespace

int main(int argc, char** argv) {
  Config config;
  CLI::App app{"bench_occlusion: occlusion culling on the generated streets: frame times, drawn / owning, pass times"};
  add_counts_option(app, "--sizes", config.sizes, "Buildings per streets scene (default 1e3,1e4,1e5)");
  app.add_option("--frames", config.frames, "Frames along the street path")
      ->capture_default_str()
      ->check(CLI::Range(std::size_t(2), std::size_t(10000)));
  app.add_option("--width", config.width, "Image width")->capture_default_str()->check(CLI::Range(1u, 16384u));
  app.add_option("--height", config.height, "Image height")->capture_default_str()->check(CLI::Range(1u, 16384u));
  app.add_option("--texels", config.texels, "Texels per axis the occlusion test reads: 2 | 4 | 8 | 16")
      ->capture_default_str()
      ->check(CLI::IsMember({2u, 4u, 8u, 16u}));
  app.add_option("--refine-texels", config.refine_texels,
                 "Objects the --texels test keeps are tested again at this many texels per axis (0: not)")
      ->capture_default_str()
      ->check(CLI::IsMember({0u, 4u, 8u, 16u}));
  app.add_option("--repeats", config.repeats, "Timed repeats of each pass (the median is reported)")
      ->capture_default_str()
      ->check(CLI::Range(1, 10000));
  app.add_option("--device", config.device, "Vulkan device name substring");
  app.add_flag("--validation", config.validation, "Vulkan validation layers on; any message makes the exit status 1");
  app.add_option("--json", config.json, "Write every row as JSON");
  parse_command_line(app, argc, argv);

  vulkan::ContextOptions options;
  options.validation = config.validation;
  options.device_filter = config.device;
  const vulkan::Context ctx(options);
  std::printf("bench_occlusion: streets along their path, %ux%u, %u texels per axis (refined at %u), %s; %s\n",
              config.width, config.height, config.texels, config.refine_texels, ctx.info().name.c_str(),
              cpu_model().c_str());
  std::printf("\n%9s %6s | %10s %10s %6s | %8s %8s %7s %7s %6s | %9s %9s %6s %9s %9s %6s %8s %9s | %7s %8s | %s\n",
              "objects", "frames", "frustum ms", "occl. ms", "speed", "drawn f", "drawn o", "owning", "d/own", "missed",
              "flat ms", "flat+o ms", "ratio", "bvh ms", "bvh+o ms", "ratio", "bvh/flat", "pyramid", "cpu ms",
              "cpu/gpu", "agree");
  nlohmann::json rows = nlohmann::json::array();
  bool ok = true;
  for (const std::size_t n : config.sizes) {
    const Row r = measure(ctx, n, config);
    ok = ok && r.agree && r.missed == 0;
    std::printf(
        "%9zu %6zu | %10.2f %10.2f %5.2fx | %8.1f %8.1f %7.1f %7.2f %6zu | %9.3f %9.3f %5.2fx %9.3f %9.3f %5.2fx "
        "%7.2fx %7.3fms | %7.2f %7.1f%% | %s\n",
        r.n, r.frames, r.frustum_frame_ns / 1e6, r.occlusion_frame_ns / 1e6, r.frustum_frame_ns / r.occlusion_frame_ns,
        r.frustum_drawn, r.occlusion_drawn, r.owning, r.owning > 0 ? r.occlusion_drawn / r.owning : 0.0, r.missed,
        r.flat_ns / 1e6, r.flat_occlusion_ns / 1e6, r.flat_occlusion_ns / r.flat_ns, r.bvh_ns / 1e6,
        r.bvh_occlusion_ns / 1e6, r.bvh_occlusion_ns / r.bvh_ns, r.bvh_occlusion_ns / r.flat_occlusion_ns,
        r.pyramid_ns / 1e6, r.cpu_path_ns / 1e6,
        r.gpu_occluded ? 100.0 * double(r.cpu_occluded) / double(r.gpu_occluded) : 0.0, r.agree ? "yes" : "NO");
    std::fflush(stdout);
    rows.push_back({{"objects", r.n},
                    {"frames", r.frames},
                    {"frustum_frame_ns", r.frustum_frame_ns},
                    {"occlusion_frame_ns", r.occlusion_frame_ns},
                    {"frustum_drawn", r.frustum_drawn},
                    {"occlusion_drawn", r.occlusion_drawn},
                    {"owning", r.owning},
                    {"missed", r.missed},
                    {"pass_frustum_kept", r.pass_frustum_kept},
                    {"pass_occluded", r.pass_occluded},
                    {"flat_ns", r.flat_ns},
                    {"flat_occlusion_ns", r.flat_occlusion_ns},
                    {"bvh_ns", r.bvh_ns},
                    {"bvh_occlusion_ns", r.bvh_occlusion_ns},
                    {"pyramid_ns", r.pyramid_ns},
                    {"cpu_path_ns", r.cpu_path_ns},
                    {"gpu_occluded", r.gpu_occluded},
                    {"cpu_occluded", r.cpu_occluded},
                    {"agree", r.agree}});
  }
  if (!config.json.empty()) {
    nlohmann::json j;
    j["device"] = ctx.info().name;
    j["cpu"] = cpu_model();
    j["width"] = config.width;
    j["height"] = config.height;
    j["texels_per_axis"] = config.texels;
    j["refine_texels_per_axis"] = config.refine_texels;
    j["rows"] = rows;
    std::ofstream(config.json) << j.dump(2) << "\n";
  }
  if (ctx.validation_message_count() > 0) {
    std::printf("%zu Vulkan validation message(s)\n", std::size_t(ctx.validation_message_count()));
    ok = false;
  }
  return ok ? 0 : 1;
}
