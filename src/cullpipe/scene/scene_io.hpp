#pragma once
#include <string>

#include "cullpipe/scene/scene.hpp"

namespace cullpipe {

/// Reads a cullpipe scene file (JSON, "format": "cullpipe-scene", version 1):
///   {"format": "cullpipe-scene", "version": 1, "name": "...",
///    "camera": {"eye": [x,y,z], "target": [..], "up": [..], "fov_y_degrees": 60,
///               "aspect": 1.78, "near": 0.1, "far": 1000, "reversed_z": false, "infinite_far": false},
///    "path": [cameras in the format of "camera", optional: Scene::path],
///    "objects": [{"min": [..], "max": [..], "world": [16 numbers, column-major, optional]}]}
/// Throws InputError naming the file and the bad element.
Scene load_scene(const std::string& path);

/// Parses scene JSON text; `source` names it in errors.
Scene parse_scene(const std::string& text, const std::string& source);

/// Serialises a scene to JSON text in the format load_scene reads (floats round-trip exactly).
std::string scene_to_json(const Scene& scene);

/// Writes the scene atomically to `path`.
void save_scene(const std::string& path, const Scene& scene);

}  // namespace cullpipe
