#include "cullpipe/scene/gltf_points.hpp"

#include <algorithm>
#include <cmath>

#include "cullpipe/scene/gltf_model.hpp"

namespace cullpipe {

std::vector<GltfMeshPoints> load_gltf_mesh_points(const std::string& path) {
  const tinygltf::Model model = gltf::load_model(path);
  std::vector<GltfMeshPoints> out;
  for (std::size_t m = 0; m < model.meshes.size(); ++m) {
    const tinygltf::Mesh& mesh = model.meshes[m];
    GltfMeshPoints mp;
    mp.mesh = int(m);
    mp.name = mesh.name.empty() ? "mesh " + std::to_string(m) : mesh.name;
    bool all_declared = true;
    Aabb declared{glm::vec3(INFINITY), glm::vec3(-INFINITY)};
    for (std::size_t p = 0; p < mesh.primitives.size(); ++p) {
      const std::string where = path + ": meshes[" + std::to_string(m) + "].primitives[" + std::to_string(p) + "]: ";
      gltf::Positions pos = gltf::read_positions(model, m, p, where);
      mp.positions.insert(mp.positions.end(), pos.points.begin(), pos.points.end());
      if (pos.declared) {
        declared.min = glm::min(declared.min, pos.declared->min);
        declared.max = glm::max(declared.max, pos.declared->max);
      } else {
        all_declared = false;
      }
    }
    if (all_declared && !mp.positions.empty()) mp.declared_bounds = declared;
    out.push_back(std::move(mp));
  }
  return out;
}

}  // namespace cullpipe
