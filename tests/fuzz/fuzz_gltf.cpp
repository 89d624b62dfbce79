// Fuzzes the glTF loader (load_gltf_scene and load_gltf_mesh_points) with .gltf (JSON) and .glb
// (binary) files: an input starting with the GLB magic "glTF" is loaded as .glb.
#include <cstring>

#include "cullpipe/scene/gltf_points.hpp"
#include "cullpipe/scene/gltf_scene.hpp"
#include "fuzz_util.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  using namespace cullpipe;
  const bool glb = size >= 4 && std::memcmp(data, "glTF", 4) == 0;
  const std::string path = fuzz::write_temp(data, size, glb ? "input.glb" : "input.gltf");
  fuzz::expect_clean([&] {
    const GltfScene g = load_gltf_scene(path);
    // Whatever loads must give usable, finite world volumes.
    for (const Aabb& b : world_aabbs(g.scene))
      if (!(b.min.x <= b.max.x && b.min.y <= b.max.y && b.min.z <= b.max.z)) std::abort();
    world_obbs(g.scene);
    world_spheres(g.scene);
  });
  fuzz::expect_clean([&] { load_gltf_mesh_points(path); });
  return 0;
}
