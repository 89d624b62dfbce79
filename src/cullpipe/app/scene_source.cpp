#include "cullpipe/app/scene_source.hpp"

#include <chrono>

#include "cullpipe/app/commands.hpp"
#include "cullpipe/scene/generators.hpp"
#include "cullpipe/scene/gltf_scene.hpp"
#include "cullpipe/scene/scene_io.hpp"

namespace cullpipe::app {

LoadedScene load_scene_source(const SceneOptions& o) {
  if (!o.scene_path.empty() && !o.generate.empty()) throw InputError("give --scene or --generate, not both");
  const auto obb_method = bounds::parse_obb_method(o.obb);
  if (!obb_method) throw InputError("--obb " + o.obb + ": expected pca, dito, hull-face or exact");
  const auto sphere_method = bounds::parse_sphere_method(o.sphere);
  if (!sphere_method) throw InputError("--sphere " + o.sphere + ": expected ritter, refined or exact");
  const auto aabb_update = bounds::parse_aabb_update(o.aabb_update);
  if (!aabb_update)
    throw InputError("--aabb-update " + o.aabb_update + ": expected recompute, hull, transform-box or hill-climb");
  const auto layout = parse_instance_layout(o.layout);
  if (!layout) throw InputError("--layout " + o.layout + ": expected grid or random");

  LoadedScene out;
  Scene& scene = out.scene;
  std::string& source = out.source;
  bool& from_gltf = out.from_gltf;
  const auto load_start = std::chrono::steady_clock::now();
  if (!o.generate.empty()) {
    const auto [kind, n] = parse_generate_spec(o.generate);
    scene = generate_scene(kind, n, o.seed);
    source = "generated";
  } else {
    source = o.scene_path.empty() ? default_scene_path() : o.scene_path;
    if (is_gltf_path(source)) {
      GltfSceneOptions g;
      g.scene = o.gltf_scene;
      g.camera = o.camera;
      g.bounds = {*obb_method, *sphere_method};
      GltfScene loaded = load_gltf_scene(source, g);
      scene = std::move(loaded.scene);
      out.zero_scale_instances = loaded.zero_scale_instances;
      from_gltf = true;
    } else {
      scene = load_scene(source);
    }
  }
  if (!from_gltf && (!o.camera.empty() || o.gltf_scene >= 0))
    throw InputError("--camera and --gltf-scene apply to glTF scenes only (" + source + " is not .gltf or .glb)");
  scene = replicate_scene(scene, o.instances, *layout, o.seed);
  out.load_ns = double(
      std::chrono::duration_cast<std::chrono::nanoseconds>(std::chrono::steady_clock::now() - load_start).count());

  out.aabb_update = *aabb_update;
  return out;
}

}  // namespace cullpipe::app
