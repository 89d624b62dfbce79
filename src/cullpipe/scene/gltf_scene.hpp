#pragma once
#include <cstdint>
#include <string>
#include <vector>

#include "cullpipe/bounds/mesh_bounds.hpp"
#include "cullpipe/scene/scene.hpp"

namespace cullpipe {

struct GltfSceneOptions {
  int scene = -1;                    ///< index in scenes[]; -1: the file's default scene (scene 0 if none is marked)
  std::string camera;                ///< "": a camera framing the scene; else a camera's name or its index in cameras[]
  bounds::MeshBoundsOptions bounds;  ///< OBB and sphere builders for every mesh primitive
  bool keep_triangles = true;        ///< keep each primitive's triangles (SceneObject::triangles), for drawing
};

/// A glTF camera as found in the file.
struct GltfCamera {
  int index = 0;     ///< in cameras[]
  std::string name;  ///< the camera's name, else its node's name, else "camera N"
  int node = -1;     ///< the first node of the chosen scene that places it; -1 when none does
};

struct GltfScene {
  Scene scene;
  std::vector<GltfCamera> cameras;
  std::size_t zero_scale_instances = 0;  ///< primitive instances skipped: singular world transform (nothing to draw)
};

/// Reads a .gltf or .glb file into a scene. Every node of the chosen scene is visited with
/// its TRS or matrix transform composed down the hierarchy (in double); every mesh primitive
/// instance becomes one object whose volumes come from its own vertex positions (one
/// bounds::MeshBounds per primitive, shared by every node that uses the mesh), with
/// ObjectOrigin naming its node, mesh and primitive. Mirrored and non-uniformly scaled
/// instances are supported. Images are never loaded (missing images are not an error). The
/// camera is the chosen glTF camera placed by its node (perspective or orthographic), or a
/// camera framing the scene.
///
/// Throws InputError naming the file and the element for malformed input: unreadable JSON or
/// buffers, accessors or indices out of range, wrong component types, empty or non-finite
/// positions, a node with two parents or a cycle in the node graph, a non-affine matrix, a
/// zero quaternion, an unknown scene or camera, a required geometry-compression extension.
GltfScene load_gltf_scene(const std::string& path, const GltfSceneOptions& options = {});

/// True for paths ending in .gltf or .glb (any case).
bool is_gltf_path(const std::string& path);

}  // namespace cullpipe
