#pragma once
#include <string>

#include "cullpipe/app/commands.hpp"
#include "cullpipe/bounds/aabb_update.hpp"
#include "cullpipe/scene/scene.hpp"

namespace cullpipe::app {

/// A scene loaded from the command line's scene options, with what the report needs.
struct LoadedScene {
  Scene scene;
  std::string source;  ///< the file, or "generated"
  bool from_gltf = false;
  std::size_t zero_scale_instances = 0;
  bounds::AabbUpdate aabb_update = bounds::AabbUpdate::HullRecompute;
  double load_ns = 0.0;
};

/// Loads (or generates) the scene and repeats it --instances times. Throws InputError for bad
/// option values, options that do not apply (--camera on a non-glTF scene) and bad files.
LoadedScene load_scene_source(const SceneOptions& o);

}  // namespace cullpipe::app
