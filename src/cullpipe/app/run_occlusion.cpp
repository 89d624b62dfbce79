// `cullpipe run --occlusion`: two-phase occlusion frames through the headless renderer along the
// scene's camera path. Each frame's classes (the renderer's flat pass, and with --cull bvh the
// hierarchical pass on the same pyramid) are checked object by object against the scalar
// reference on that frame's pyramid, and the objects owning a pixel of the unculled image (an id
// buffer) against what was drawn.
#include <array>
#include <cstdio>
#include <nlohmann/json.hpp>
#include <ostream>

#include "cullpipe/app/backends.hpp"
#include "cullpipe/app/commands.hpp"
#include "cullpipe/app/scene_source.hpp"
#include "cullpipe/core/thread_pool.hpp"
#include "cullpipe/cull/clusters.hpp"
#include "cullpipe/cull/compare.hpp"
#include "cullpipe/cull/occlusion.hpp"
#include "cullpipe/cull/software_depth.hpp"
#include "cullpipe/geom/cone.hpp"
#include "cullpipe/gpu/bvh_culler.hpp"
#include "cullpipe/render/renderer.hpp"
#include "cullpipe/scene/cull_case_io.hpp"
#include "cullpipe/scene/json_util.hpp"

namespace cullpipe::app {
namespace {

std::string pad(const std::string& s, std::size_t width) {
  return s.size() >= width ? s : std::string(width - s.size(), ' ') + s;
}

std::string format_ratio(double value) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%.2f", value);
  return buf;
}

/// One frame's numbers, as printed and written to --json.
struct FrameReport {
  std::size_t frustum = 0;      // kept by the frustum (drawn + occluded)
  std::size_t first_phase = 0;  // drawn for the pyramid: last frame's visible objects
  std::size_t drawn = 0;        // drawn in the second phase
  std::size_t occluded = 0;
  std::size_t owning = 0;           // own a pixel of the unculled image
  std::size_t false_positives = 0;  // drawn, but own no pixel
  std::size_t missed = 0;           // own a pixel, but culled: must be 0
  std::size_t mismatches = 0;       // classes differing from the reference's
  std::size_t cpu_occluded = 0;     // the CPU path's occluded (software depth of the box objects)
  std::size_t cpu_missed = 0;       // own a pixel, but the CPU path hid them: must be 0
  // --clusters: the pairs per class (clusters::ClusterClass's values), the cluster pass's draws,
  // the triangles submitted, and pairs differing from the reference's.
  std::array<std::size_t, clusters::kClusterClassCount> clusters{};
  std::size_t cluster_draws = 0, cluster_mismatches = 0;
  std::uint64_t triangles = 0;
  std::uint64_t object_triangles = 0;              // the kept objects' triangles, drawn whole
  std::optional<std::uint64_t> visible_triangles;  // owning a pixel (devices with primitive ids)
};

/// The cluster pass's classes of one frame against clusters::classify's on the frame's pyramid,
/// given the object pass's classes; a report per mismatch (the first few).
std::size_t check_clusters_frame(const render::Renderer& renderer, const render::FrameStats& stats,
                                 const std::vector<InverseFrame>& frames,
                                 const std::vector<std::optional<Obb>>& placed_obbs, const Camera& camera,
                                 const Frustum& frustum, const occlusion::OcclusionView& view,
                                 const occlusion::DepthPyramid& pyramid, const occlusion::OcclusionOptions& options,
                                 std::size_t frame, std::vector<std::string>& reports) {
  const auto& boxes = renderer.cluster_boxes();
  const auto& cones = renderer.cluster_cones();
  const auto& instances = renderer.cluster_instances();
  clusters::ClusterView cv{frustum, camera.eye, !camera.orthographic, &view, &pyramid, options};
  std::size_t p = 0, mismatches = 0;
  for (std::size_t i = 0; i < instances.size(); ++i) {
    const gpu::ClusterInstance& in = instances[i];
    clusters::ClusterView v = cv;
    v.backface = cv.backface && in.backface;
    for (std::uint32_t k = 0; k < in.cluster_count; ++k, ++p) {
      const std::uint32_t c = in.first_cluster + k;
      const std::optional<Obb>& placed = placed_obbs[p];
      const clusters::ClusterClass want = clusters::classify(
          boxes[c], cones[c], in.transform, frames[i], is_visible(stats.classes[i]), v, placed ? &*placed : nullptr);
      const clusters::ClusterClass got =
          p < stats.cluster_pair_classes.size() ? stats.cluster_pair_classes[p] : clusters::ClusterClass::Drawn;
      if (got == want) continue;
      if (++mismatches + reports.size() <= 10)
        reports.push_back("frame " + std::to_string(frame) + ": object " + std::to_string(i) + " cluster " +
                          std::to_string(k) + " (box " + describe(boxes[c]) + ", cone cutoff " +
                          std::to_string(cones[c].cutoff) + "): GPU " + std::string(to_string(got)) + ", reference " +
                          std::string(to_string(want)));
    }
  }
  return mismatches;
}

/// The checks of one frame for one kind of volume: the renderer's classes against the
/// reference's on the frame's pyramid, and with a tree the hierarchical pass's against both.
template <class Volume>
std::size_t check_frame(const std::vector<Volume>& volumes, const Frustum& frustum,
                        const occlusion::OcclusionView& view, const gpu::DepthPyramidPass& pass,
                        const occlusion::OcclusionOptions& options, const std::vector<Classification>& flat_classes,
                        const bvh::FlatTree* tree, gpu::BvhCuller* bvh_culler, std::vector<std::string>& reports) {
  const occlusion::DepthPyramid pyramid = pass.read();
  std::vector<Classification> expected(volumes.size());
  occlusion::classify_all(std::span<const Volume>(volumes), frustum, view, pyramid, options, expected);
  std::size_t mismatches = 0;
  auto compare = [&](const std::vector<Classification>& got, const char* who) {
    for (std::size_t i = 0; i < volumes.size(); ++i) {
      if (got[i] == expected[i]) continue;
      if (++mismatches <= 5)
        reports.push_back(std::string(who) + ": " + describe_mismatch(i, volumes[i], frustum, expected[i], got[i]));
    }
  };
  compare(flat_classes, "flat pass");
  if (tree) {
    const bvh::HierarchicalResult cpu =
        occlusion::cull_hierarchical(*tree, std::span<const Volume>(volumes), frustum, view, pyramid, options);
    compare(cpu.classes, "hierarchical reference");
    gpu::CullOptions gpu_options;
    gpu_options.visible_ids = false;
    gpu_options.pyramid = &pass;
    gpu_options.occlusion_views = {view};
    gpu_options.occlusion_options = options;
    const gpu::CullResult r = bvh_culler->cull(std::span(&frustum, 1), gpu_options);
    compare(r.views[0].classes, "hierarchical pass");
  }
  return mismatches;
}

}  // namespace

int run_occlusion(const RunOptions& o, const LoadedScene& loaded, BvKind bv, std::ostream& out, std::ostream& err) {
  if (o.backend == Backend::Cpu)
    throw InputError("--occlusion culls on the GPU against the depth the renderer draws: use --backend gpu or both");
  if (o.cpu == "fast") throw InputError("--occlusion checks against the reference: give --cpu reference");
  if (o.frames == 0) throw InputError("--frames must be at least 1");
  const Scene& scene = loaded.scene;
  const std::vector<Camera> path = scene_camera_path(scene, o.views);
  GpuBackend gpu{o.device, nullptr, nullptr, nullptr};
  const vulkan::Context& ctx = gpu.device();
  render::RendererConfig config;
  config.width = o.width;
  config.height = o.height;
  config.bv = bv;
  config.aabb_update = loaded.aabb_update;
  config.occlusion.texels_per_axis = o.texels;
  config.occlusion.refine_texels_per_axis = o.refine_texels;
  config.clusters = o.clusters;
  occlusion::check_view({glm::mat4(1.0f), o.width, o.height, false}, o.width, o.height, false, config.occlusion);
  render::Renderer renderer(ctx, scene, config);
  std::vector<InverseFrame> inverse_frames;  // --clusters: each object's, for the reference
  for (const gpu::ClusterInstance& in : renderer.cluster_instances())
    inverse_frames.push_back(inverse_frame(in.transform));
  std::vector<std::optional<Obb>> placed_obbs;  // and each pair's OBB placed, where its cluster has one
  for (const gpu::ClusterInstance& in : renderer.cluster_instances())
    for (std::uint32_t k = 0; k < in.cluster_count; ++k) {
      const std::optional<Obb>& obb = renderer.cluster_obbs()[in.first_cluster + k];
      placed_obbs.push_back(obb ? std::optional<Obb>(instance_volume(*obb, in.transform)) : std::nullopt);
    }

  // The volumes the renderer culls, and with --cull bvh a tree over them.
  const std::vector<Aabb> aabbs = world_aabbs(scene, loaded.aabb_update);
  const std::vector<Obb> obbs = bv == BvKind::Obb ? world_obbs(scene) : std::vector<Obb>();
  const std::vector<Sphere> spheres = bv == BvKind::Sphere ? world_spheres(scene) : std::vector<Sphere>();
  const bool hierarchical = o.cull == "bvh";
  BuiltBvh built;
  std::unique_ptr<gpu::BvhCuller> bvh_culler;
  if (hierarchical) {
    bvh_culler = std::make_unique<gpu::BvhCuller>(ctx);
    if (bv == BvKind::Aabb) {
      built = build_bvh(o.builder, aabbs, o.leaf_size);
      bvh_culler->upload(built.flat, std::span<const Aabb>(aabbs));
    } else if (bv == BvKind::Obb) {
      built = build_bvh(o.builder, bvh::enclosing_boxes(std::span<const Obb>(obbs)), o.leaf_size);
      bvh_culler->upload(built.flat, std::span<const Obb>(obbs));
    } else {
      built = build_bvh(o.builder, bvh::enclosing_boxes(std::span<const Sphere>(spheres)), o.leaf_size);
      bvh_culler->upload(built.flat, std::span<const Sphere>(spheres));
    }
  }

  const std::vector<occlusion::OccluderBox> occluders = render::box_occluders(scene);
  const std::uint32_t cpu_width = std::max(1u, o.width / o.software_divisor),
                      cpu_height = std::max(1u, o.height / o.software_divisor);
  ThreadPool pool;

  const std::size_t n = scene.objects.size();
  out << "cullpipe run --occlusion: " << (scene.name.empty() ? loaded.source : scene.name) << " (" << loaded.source
      << "), " << n << " objects, bv " << o.bv << ", " << o.width << "x" << o.height << ", " << o.texels
      << " texels per axis"
      << (o.refine_texels > o.texels ? " (then " + std::to_string(o.refine_texels) + " where that keeps an object)"
                                     : std::string())
      << ", device " << ctx.info().name << "\n";
  if (hierarchical)
    out << "  bvh: " << o.builder << ", leaves of <= " << o.leaf_size << ", " << built.metrics.nodes
        << " nodes; its pass is checked against the flat pass and the reference on each frame's pyramid\n";
  out << "  cpu path: " << occluders.size() << " box occluders rasterised at " << cpu_width << "x" << cpu_height
      << " on " << pool.size() << " threads\n";
  out << "\n  frame  objects  frustum  first phase  drawn  occluded  owning  false positives  drawn/owning  cpu "
         "occluded\n";

  std::vector<FrameReport> frames;
  std::vector<Frustum> frusta;
  std::vector<std::vector<Classification>> dumped;
  std::vector<std::string> reports;
  std::size_t mismatches = 0, missed = 0, cluster_mismatches = 0;
  for (std::size_t f = 0; f < o.frames; ++f) {
    const Camera& camera = path[f % path.size()];
    const Frustum frustum = Frustum::from_view_proj(camera.view_proj());
    render::FrameStats stats;
    renderer.render(camera, render::CullMode::Occlusion, &stats);
    const occlusion::OcclusionView view{camera.view_proj(), o.width, o.height, camera.reversed_z};
    FrameReport r;
    for (const Classification c : stats.classes) r.drawn += is_visible(c);  // (stats.draws counts clusters' draws)
    r.occluded = stats.occluded;
    r.frustum = r.drawn + stats.occluded;
    r.first_phase = stats.first_phase_draws;
    const gpu::DepthPyramidPass& pass = *renderer.pyramid();
    const bvh::FlatTree* tree = hierarchical ? &built.flat : nullptr;
    switch (bv) {
      case BvKind::Aabb:
        r.mismatches =
            check_frame(aabbs, frustum, view, pass, config.occlusion, stats.classes, tree, bvh_culler.get(), reports);
        break;
      case BvKind::Obb:
        r.mismatches =
            check_frame(obbs, frustum, view, pass, config.occlusion, stats.classes, tree, bvh_culler.get(), reports);
        break;
      case BvKind::Sphere:
        r.mismatches =
            check_frame(spheres, frustum, view, pass, config.occlusion, stats.classes, tree, bvh_culler.get(), reports);
        break;
    }
    if (o.clusters) {
      r.clusters = stats.cluster_classes;
      r.cluster_draws = stats.draws;
      r.triangles = stats.primitives;
      for (std::size_t i = 0; i < stats.classes.size(); ++i)
        if (is_visible(stats.classes[i])) r.object_triangles += renderer.triangles(i);
      r.visible_triangles = renderer.visible_triangles(camera);
      r.cluster_mismatches = check_clusters_frame(renderer, stats, inverse_frames, placed_obbs, camera, frustum, view,
                                                  pass.read(), config.occlusion, f, reports);
      cluster_mismatches += r.cluster_mismatches;
    }
    const std::vector<bool> owners = renderer.pixel_owners(camera);
    for (std::size_t i = 0; i < n; ++i) {
      const bool drawn = is_visible(stats.classes[i]);
      r.owning += owners[i];
      r.false_positives += drawn && !owners[i];
      r.missed += owners[i] && !drawn;
    }
    {  // The CPU path on the same frame, against the same owners.
      std::vector<Classification> cpu(n);
      auto cull = [&](auto volumes) {
        return occlusion::cull_with_software_depth(volumes, std::span<const occlusion::OccluderBox>(occluders), frustum,
                                                   view, cpu_width, cpu_height, config.occlusion,
                                                   std::span<Classification>(cpu), &pool);
      };
      r.cpu_occluded = bv == BvKind::Obb      ? cull(std::span<const Obb>(obbs)).occluded
                       : bv == BvKind::Sphere ? cull(std::span<const Sphere>(spheres)).occluded
                                              : cull(std::span<const Aabb>(aabbs)).occluded;
      for (std::size_t i = 0; i < n; ++i) r.cpu_missed += owners[i] && !is_visible(cpu[i]);
    }
    mismatches += r.mismatches;
    missed += r.missed + r.cpu_missed;
    out << pad(std::to_string(f), 7) << pad(std::to_string(n), 9) << pad(std::to_string(r.frustum), 9)
        << pad(std::to_string(r.first_phase), 13) << pad(std::to_string(r.drawn), 7)
        << pad(std::to_string(r.occluded), 10) << pad(std::to_string(r.owning), 8)
        << pad(std::to_string(r.false_positives), 17)
        << pad(r.owning ? format_ratio(double(r.drawn) / double(r.owning)) : "-", 14)
        << pad(std::to_string(r.cpu_occluded), 14) << "\n";
    if (o.clusters) {
      using clusters::ClusterClass;
      const auto count = [&](ClusterClass c) { return std::to_string(r.clusters[std::size_t(c)]); };
      out << "         clusters: " << count(ClusterClass::Drawn) << " drawn in " << r.cluster_draws << " draws, "
          << count(ClusterClass::ObjectCulled) << " of culled objects, " << count(ClusterClass::Outside) << " outside, "
          << count(ClusterClass::BackFacing) << " back-facing, " << count(ClusterClass::Occluded) << " occluded\n"
          << "         triangles: " << r.triangles << " submitted, " << r.object_triangles
          << " by the kept objects whole ("
          << (r.object_triangles ? format_ratio(double(r.triangles) / double(r.object_triangles)) : "-") << "x)";
      if (r.visible_triangles) out << ", " << *r.visible_triangles << " own a pixel";
      out << "\n";
    }
    frames.push_back(r);
    if (!o.dump_path.empty()) {
      frusta.push_back(frustum);
      dumped.push_back(stats.classes);
    }
  }
  out << "\n";
  if (mismatches == 0)
    out << "  agreement:     all " << n * o.frames << " object-frame classes equal the reference's ("
        << (hierarchical ? "flat pass == hierarchical pass == reference" : "flat pass == reference") << ")\n";
  else
    out << "  agreement:     " << mismatches << " MISMATCHES with the reference\n";
  if (o.clusters) {
    const std::size_t pairs = renderer.cluster_pair_count() * o.frames;
    if (cluster_mismatches == 0)
      out << "  clusters:      all " << pairs << " cluster-frame classes equal the reference's (clusters::classify)\n";
    else
      out << "  clusters:      " << cluster_mismatches << " cluster classes DIFFER from the reference's\n";
  }
  out << "  pixels:        "
      << (missed ? std::to_string(missed) + " objects owning a pixel were CULLED (GPU and CPU paths)"
                 : std::string("every object owning a pixel was drawn, and kept by the CPU path"))
      << "\n";

  if (!o.json_path.empty()) {
    nlohmann::json j;
    j["scene"] = scene.name;
    j["source"] = loaded.source;
    j["objects"] = n;
    j["bv"] = o.bv;
    j["cull"] = o.cull;
    j["occlusion"] = true;
    j["width"] = o.width;
    j["height"] = o.height;
    j["texels_per_axis"] = o.texels;
    j["refine_texels_per_axis"] = o.refine_texels > o.texels ? o.refine_texels : 0u;  // (0: one read)
    j["device"] = ctx.info().name;
    j["driver"] = ctx.info().driver;
    j["mismatches"] = mismatches;
    j["clusters"] = o.clusters;
    j["cluster_mismatches"] = cluster_mismatches;
    j["missed"] = missed;
    j["agree"] = mismatches == 0;
    nlohmann::json per_frame = nlohmann::json::array();
    for (const FrameReport& r : frames)
      per_frame.push_back(
          {{"frustum", r.frustum},
           {"first_phase", r.first_phase},
           {"drawn", r.drawn},
           {"occluded", r.occluded},
           {"owning", r.owning},
           {"false_positives", r.false_positives},
           {"missed", r.missed},
           {"mismatches", r.mismatches},
           {"cpu_occluded", r.cpu_occluded},
           {"cpu_missed", r.cpu_missed},
           {"clusters_drawn", r.clusters[std::size_t(clusters::ClusterClass::Drawn)]},
           {"clusters_object_culled", r.clusters[std::size_t(clusters::ClusterClass::ObjectCulled)]},
           {"clusters_outside", r.clusters[std::size_t(clusters::ClusterClass::Outside)]},
           {"clusters_back_facing", r.clusters[std::size_t(clusters::ClusterClass::BackFacing)]},
           {"clusters_occluded", r.clusters[std::size_t(clusters::ClusterClass::Occluded)]},
           {"cluster_draws", r.cluster_draws},
           {"triangles", r.triangles},
           {"object_triangles", r.object_triangles},
           {"visible_triangles", r.visible_triangles ? nlohmann::json(*r.visible_triangles) : nlohmann::json(nullptr)},
           {"cluster_mismatches", r.cluster_mismatches}});
    j["per_frame"] = per_frame;
    json_util::write_file_atomic(o.json_path, j.dump(2) + "\n");
  }
  if (!o.dump_path.empty()) {
    std::vector<cullpipe::Volume> volumes;
    if (bv == BvKind::Aabb) volumes.assign(aabbs.begin(), aabbs.end());
    if (bv == BvKind::Obb) volumes.assign(obbs.begin(), obbs.end());
    if (bv == BvKind::Sphere) volumes.assign(spheres.begin(), spheres.end());
    CullCase c{frusta, frusta.size() > 1, std::move(volumes), {}, {}};
    json_util::write_file_atomic(o.dump_path, cull_case_to_json(c, &dumped));
  }
  gpu.check_validation();
  mismatches += cluster_mismatches;
  if (mismatches || missed) {
    err << "error: ";
    if (mismatches) err << mismatches << " classes differ from the reference's" << (missed ? "; " : "");
    if (missed) err << missed << " objects owning a pixel were culled";
    err << (reports.empty() ? "\n" : "; first ones:\n");
    for (const std::string& m : reports) err << "  " << m << "\n";
    return kExitMismatch;
  }
  return kExitOk;
}

}  // namespace cullpipe::app
