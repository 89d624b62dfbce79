#include "scene/gltf_points.hpp"

#include <cmath>
#include <cstring>

#include "scene/scene.hpp"

#define TINYGLTF_IMPLEMENTATION
#define TINYGLTF_NO_STB_IMAGE
#define TINYGLTF_NO_STB_IMAGE_WRITE
#define TINYGLTF_NO_EXTERNAL_IMAGE
#include <tiny_gltf.h>

namespace cullpipe {
namespace {

bool ends_with_ci(const std::string& s, const char* suffix) {
  const std::size_t n = std::strlen(suffix);
  if (s.size() < n) return false;
  for (std::size_t i = 0; i < n; ++i)
    if (std::tolower(static_cast<unsigned char>(s[s.size() - n + i])) != suffix[i]) return false;
  return true;
}

// Loading images is switched off: accept any image without decoding it.
bool skip_image(tinygltf::Image*, const int, std::string*, std::string*, int, int, const unsigned char*, int, void*) {
  return true;
}

}  // namespace

std::vector<GltfMeshPoints> load_gltf_mesh_points(const std::string& path) {
  tinygltf::TinyGLTF loader;
  loader.SetImageLoader(&skip_image, nullptr);
  tinygltf::Model model;
  std::string err, warn;
  const bool ok = ends_with_ci(path, ".glb") ? loader.LoadBinaryFromFile(&model, &err, &warn, path)
                                             : loader.LoadASCIIFromFile(&model, &err, &warn, path);
  if (!ok) throw InputError(path + ": not a readable glTF file: " + (err.empty() ? std::string("unknown error") : err));

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
      const auto it = mesh.primitives[p].attributes.find("POSITION");
      if (it == mesh.primitives[p].attributes.end()) throw InputError(where + "no POSITION attribute");
      const int ai = it->second;
      if (ai < 0 || std::size_t(ai) >= model.accessors.size())
        throw InputError(where + "POSITION accessor " + std::to_string(ai) + " does not exist");
      const tinygltf::Accessor& acc = model.accessors[std::size_t(ai)];
      const std::string what = where + "POSITION accessor " + std::to_string(ai) + " ";
      if (acc.sparse.isSparse) throw InputError(what + "is sparse (not supported)");
      if (acc.type != TINYGLTF_TYPE_VEC3) throw InputError(what + "is not VEC3");
      if (acc.componentType != TINYGLTF_COMPONENT_TYPE_FLOAT)
        throw InputError(what + "has component type " + std::to_string(acc.componentType) + ", not FLOAT (quantized positions are not supported)");
      if (acc.count == 0) continue;
      if (acc.bufferView < 0 || std::size_t(acc.bufferView) >= model.bufferViews.size())
        throw InputError(what + "has no valid buffer view");
      const tinygltf::BufferView& view = model.bufferViews[std::size_t(acc.bufferView)];
      if (view.buffer < 0 || std::size_t(view.buffer) >= model.buffers.size())
        throw InputError(what + "uses buffer view " + std::to_string(acc.bufferView) + " whose buffer does not exist");
      const std::vector<unsigned char>& data = model.buffers[std::size_t(view.buffer)].data;
      const std::size_t stride = view.byteStride ? view.byteStride : 12;
      if (stride < 12) throw InputError(what + "has a byte stride of " + std::to_string(stride) + ", less than 12");
      // Range checks by subtraction, so no sum can wrap around (offsets come from the file).
      if (view.byteOffset > data.size() || view.byteLength > data.size() - view.byteOffset)
        throw InputError(what + "uses buffer view " + std::to_string(acc.bufferView) + ", which reads past its buffer");
      if (acc.byteOffset > view.byteLength || view.byteLength - acc.byteOffset < 12)
        throw InputError(what + "reads past its buffer view");
      const std::size_t room = view.byteLength - acc.byteOffset - 12;  // bytes after the first element
      if ((acc.count - 1) > room / stride) throw InputError(what + "reads past its buffer view");
      const unsigned char* base = data.data() + view.byteOffset + acc.byteOffset;
      for (std::size_t i = 0; i < acc.count; ++i) {
        float v[3];
        std::memcpy(v, base + i * stride, sizeof v);
        for (float c : v)
          if (!std::isfinite(c)) throw InputError(what + "vertex " + std::to_string(i) + " has a NaN or infinite coordinate");
        mp.positions.emplace_back(v[0], v[1], v[2]);
      }
      if (acc.minValues.size() == 3 && acc.maxValues.size() == 3) {
        for (int k = 0; k < 3; ++k) {
          declared.min[k] = std::min(declared.min[k], float(acc.minValues[std::size_t(k)]));
          declared.max[k] = std::max(declared.max[k], float(acc.maxValues[std::size_t(k)]));
        }
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
