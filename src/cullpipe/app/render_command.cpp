#include <cstdio>
#include <glm/geometric.hpp>
#include <optional>
#include <ostream>

#include "cullpipe/app/backends.hpp"
#include "cullpipe/app/commands.hpp"
#include "cullpipe/app/guard.hpp"
#include "cullpipe/app/scene_source.hpp"
#include "cullpipe/geom/bv_kind.hpp"
#include "cullpipe/render/image.hpp"
#include "cullpipe/render/renderer.hpp"

namespace cullpipe::app {

int render_command(const RenderOptions& o, std::ostream& out, std::ostream& err) {
  return guarded(err, [&]() -> int {
    const auto bv = parse_bv_kind(o.bv);
    if (!bv) throw InputError("--bv " + o.bv + ": expected aabb, obb or sphere");
    if (o.out_path.empty()) throw InputError("--out FILE.png is required");
    if (o.views == 0 || o.view >= o.views) throw InputError("--view must be below --views");
    if (o.no_cull && o.check) throw InputError("give --no-cull or --check, not both");
    if (o.no_cull && o.occlusion) throw InputError("give --no-cull or --occlusion, not both");
    if (o.no_cull && o.clusters) throw InputError("give --no-cull or --clusters, not both");
    const LoadedScene loaded = load_scene_source(o);
    const Scene& scene = loaded.scene;
    const std::vector<Camera> path = scene_camera_path(scene, o.views);

    GpuBackend gpu{o.device, nullptr, nullptr, nullptr};
    const vulkan::Context& ctx = gpu.device();
    render::RendererConfig config;
    config.width = o.width;
    config.height = o.height;
    config.bv = *bv;
    config.aabb_update = loaded.aabb_update;
    config.occlusion.texels_per_axis = o.texels;
    config.occlusion.refine_texels_per_axis = o.refine_texels;
    config.clusters = o.clusters;
    config.cluster_options.cone_weight = o.cone_weight;
    config.cull_back_faces = !o.all_faces;
    render::Renderer renderer(ctx, scene, config);
    for (const std::string& why : renderer.cluster_fallbacks())
      out << "  drawn whole, not in clusters: " << why << "\n";
    const render::CullMode mode = o.no_cull     ? render::CullMode::None
                                  : o.occlusion ? render::CullMode::Occlusion
                                                : render::CullMode::Frustum;
    std::uint64_t all_triangles = 0;
    for (std::size_t i = 0; i < renderer.object_count(); ++i) all_triangles += renderer.triangles(i);
    out << "cullpipe render: " << loaded.source << ", " << scene.objects.size() << " objects, " << o.width << "x"
        << o.height << ", device " << ctx.info().name << "\n";

    // Every frame along the path (one frame by default); the last one is written.
    int code = kExitOk;
    render::FrameStats stats;
    render::Image image;
    Camera camera;
    for (std::size_t f = 0; f < o.frames; ++f) {
      camera = path[(o.view + f) % path.size()];
      image = renderer.render(camera, mode, &stats);
      std::size_t kept = 0;
      std::uint64_t kept_triangles = 0;  // what object-level culling submits
      for (std::size_t i = 0; i < stats.classes.size(); ++i)
        if (is_visible(stats.classes[i])) ++kept, kept_triangles += renderer.triangles(i);
      if (o.frames > 1) out << "  frame " << f << ":";
      if (o.no_cull) {
        out << "  no culling: " << stats.draws << " draws";
      } else {
        std::size_t inside = 0;
        for (Classification c : stats.classes) inside += c == Classification::Inside;
        out << "  culled with " << o.bv << ": " << kept << " of " << scene.objects.size() << " objects drawn ("
            << inside << " inside, " << kept - inside << " intersecting)";
        if (o.occlusion)
          out << "; " << kept + stats.occluded << " kept by the frustum, " << stats.occluded << " occluded, "
              << stats.first_phase_draws << (o.clusters ? " clusters" : "") << " drawn first";
        if (o.clusters) {
          using clusters::ClusterClass;
          const auto count = [&](ClusterClass c) { return stats.cluster_classes[std::size_t(c)]; };
          out << "\n    clusters: " << stats.clusters_drawn << " of " << stats.clusters << " drawn in " << stats.draws
              << " draws; " << count(ClusterClass::ObjectCulled) << " of culled objects, "
              << count(ClusterClass::Outside) << " outside, " << count(ClusterClass::BackFacing) << " back-facing, "
              << count(ClusterClass::Occluded) << " occluded";
          if (stats.primitives_counted)
            out << "\n    triangles: " << stats.primitives << " submitted, " << kept_triangles
                << " by the kept objects whole ("
                << (kept_triangles ? double(stats.primitives) / double(kept_triangles) : 0.0) << "x)";
        }
      }
      if (stats.primitives_counted && !o.clusters)
        out << ", " << stats.primitives << " of " << all_triangles << " triangles";
      out << "\n";
      if (o.check) {
        render::FrameStats all_stats;
        const render::Image all = renderer.render(camera, render::CullMode::None, &all_stats);
        const std::size_t diff = render::count_different_pixels(image, all);
        out << "  check: image without culling (" << all_stats.draws << " draws) "
            << (diff == 0 ? "is identical, pixel for pixel\n" : "DIFFERS in " + std::to_string(diff) + " pixels\n");
        if (diff) {
          err << "error: culling changed the image (" << diff << " pixels differ)\n";
          code = kExitMismatch;
        }
        {  // the objects owning a pixel of the unculled image, and any not drawn
          const std::vector<bool> owners = renderer.pixel_owners(camera);
          std::size_t owning = 0, dropped = 0;
          for (std::size_t i = 0; i < owners.size(); ++i)
            if (owners[i]) ++owning, dropped += !is_visible(stats.classes[i]);
          out << "  check: " << owning << " objects own a pixel, " << (dropped ? std::to_string(dropped) : "none")
              << " of them culled; drawn / owning " << (owning ? double(kept) / double(owning) : 0.0) << "\n";
          if (o.clusters && stats.primitives_counted)
            if (const std::optional<std::uint64_t> visible = renderer.visible_triangles(camera))
              out << "  check: " << *visible << " triangles own a pixel; submitted / owning "
                  << (*visible ? double(stats.primitives) / double(*visible) : 0.0) << "\n";
          if (dropped) {
            err << "error: " << dropped << " objects owning a pixel were culled\n";
            code = kExitMismatch;
          }
        }
      }
    }
    render::write_png(o.out_path, image);
    out << "  wrote " << o.out_path << "\n";

    if (!o.top_down_path.empty() && o.clusters) {
      render::write_png(o.top_down_path, render::cluster_top_down_image(renderer, stats, camera, 900));
      out << "  wrote " << o.top_down_path
          << " (top-down clusters: green drawn, violet occluded, blue back-facing, grey outside, dark grey of culled "
             "objects, white frustum)\n";
    } else if (!o.top_down_path.empty()) {
      std::vector<Classification> classes = stats.classes;
      if (classes.empty()) {  // --no-cull: classify for the picture anyway
        render::FrameStats culled;
        renderer.render(camera, true, &culled);
        classes = culled.classes;
      }
      render::write_png(o.top_down_path,
                        render::top_down_image(world_aabbs(scene, loaded.aabb_update), classes, camera, 900));
      out << "  wrote " << o.top_down_path
          << " (top-down: green inside, amber intersecting, violet occluded, grey outside, white frustum)\n";
    }
    if (!o.front_path.empty()) {
      render::FrameStats culled = stats;
      if (o.no_cull) renderer.render(camera, true, &culled);  // classify for the picture anyway
      const Aabb bounds = scene.bounds();
      const float extent = glm::length(bounds.max - bounds.min);
      const Camera front = render::front_view_camera(bounds, camera, float(o.width) / float(o.height));
      render::Image view = renderer.class_image(front, culled);
      render::draw_frustum(view, front, camera, 2.0f * extent + glm::length(camera.target - camera.eye));
      render::write_png(o.front_path, view);
      out << "  wrote " << o.front_path
          << (o.clusters
                  ? " (front clusters: green drawn, violet occluded, blue back-facing, grey outside, dark grey of "
                    "culled objects, white frustum)\n"
                  : " (front: green inside, amber intersecting, violet occluded, grey outside, white frustum)\n");
    }
    gpu.check_validation();
    return code;
  });
}

}  // namespace cullpipe::app
