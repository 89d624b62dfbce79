// tinygltf's implementation lives in this file. Its switches (TINYGLTF_NO_STB_IMAGE,
// _NO_STB_IMAGE_WRITE, _NO_EXTERNAL_IMAGE) are compile definitions of cullpipe_scene, so every
// file that includes tiny_gltf.h sees the same class definitions.
#define TINYGLTF_IMPLEMENTATION
#include "cullpipe/scene/gltf_model.hpp"

#include <cctype>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <exception>
#include <new>

#include "cullpipe/scene/scene.hpp"

namespace cullpipe::gltf {
namespace {

// Loading images is switched off: accept any image without decoding it.
bool skip_image(tinygltf::Image*, const int, std::string*, std::string*, int, int, const unsigned char*, int, void*) {
  return true;
}

// The first byte of accessor `acc`'s data, after checking that `count` elements of
// `element_size` bytes at the view's stride lie inside its buffer view and buffer. `what`
// names the accessor in errors. Range checks by subtraction, so no sum can wrap around
// (every offset comes from the file).
const unsigned char* accessor_data(const tinygltf::Model& model, const tinygltf::Accessor& acc,
                                   std::size_t element_size, std::size_t& stride, const std::string& what) {
  if (acc.bufferView < 0 || std::size_t(acc.bufferView) >= model.bufferViews.size())
    throw InputError(what + "has no valid buffer view");
  const tinygltf::BufferView& view = model.bufferViews[std::size_t(acc.bufferView)];
  if (view.buffer < 0 || std::size_t(view.buffer) >= model.buffers.size())
    throw InputError(what + "uses buffer view " + std::to_string(acc.bufferView) + " whose buffer does not exist");
  const std::vector<unsigned char>& data = model.buffers[std::size_t(view.buffer)].data;
  stride = view.byteStride ? view.byteStride : element_size;
  if (stride < element_size)
    throw InputError(what + "has a byte stride of " + std::to_string(stride) + ", less than its element size " +
                     std::to_string(element_size));
  if (view.byteOffset > data.size() || view.byteLength > data.size() - view.byteOffset)
    throw InputError(what + "uses buffer view " + std::to_string(acc.bufferView) + ", which reads past its buffer");
  if (acc.byteOffset > view.byteLength || view.byteLength - acc.byteOffset < element_size)
    throw InputError(what + "reads past its buffer view");
  const std::size_t room = view.byteLength - acc.byteOffset - element_size;  // bytes after the first element
  if ((acc.count - 1) > room / stride) throw InputError(what + "reads past its buffer view");
  return data.data() + view.byteOffset + acc.byteOffset;
}

}  // namespace

bool ends_with_ci(const std::string& s, const char* suffix) {
  const std::size_t n = std::strlen(suffix);
  if (s.size() < n) return false;
  for (std::size_t i = 0; i < n; ++i)
    if (std::tolower(static_cast<unsigned char>(s[s.size() - n + i])) != suffix[i]) return false;
  return true;
}

tinygltf::Model load_model(const std::string& path) {
  tinygltf::TinyGLTF loader;
  loader.SetImageLoader(&skip_image, nullptr);
  tinygltf::Model model;
  std::string err, warn;
  bool ok = false;
  // tinygltf reports bad files through `err`, except where its own checks miss a case and a
  // standard container throws: a GLB buffer of byteLength 0 with a BIN chunk reaches
  // data.at(0) of an empty vector (std::out_of_range). Such a file is as unreadable as the
  // others. (Out of memory is not the file's fault to report: bad_alloc passes on.)
  try {
    ok = ends_with_ci(path, ".glb") ? loader.LoadBinaryFromFile(&model, &err, &warn, path)
                                    : loader.LoadASCIIFromFile(&model, &err, &warn, path);
  } catch (const std::bad_alloc&) {
    throw;
  } catch (const std::exception& e) {
    throw InputError(path + ": not a readable glTF file: the glTF reader failed on malformed data (" + e.what() + ")");
  }
  if (!ok) throw InputError(path + ": not a readable glTF file: " + (err.empty() ? std::string("unknown error") : err));
  return model;
}

Positions read_positions(const tinygltf::Model& model, std::size_t mesh, std::size_t primitive,
                         const std::string& where) {
  const tinygltf::Primitive& prim = model.meshes[mesh].primitives[primitive];
  const auto it = prim.attributes.find("POSITION");
  if (it == prim.attributes.end()) throw InputError(where + "no POSITION attribute");
  const int ai = it->second;
  if (ai < 0 || std::size_t(ai) >= model.accessors.size())
    throw InputError(where + "POSITION accessor " + std::to_string(ai) + " does not exist");
  const tinygltf::Accessor& acc = model.accessors[std::size_t(ai)];
  const std::string what = where + "POSITION accessor " + std::to_string(ai) + " ";
  if (acc.sparse.isSparse) throw InputError(what + "is sparse (not supported)");
  if (acc.type != TINYGLTF_TYPE_VEC3) throw InputError(what + "is not VEC3");
  if (acc.componentType != TINYGLTF_COMPONENT_TYPE_FLOAT)
    throw InputError(what + "has component type " + std::to_string(acc.componentType) +
                     ", not FLOAT (quantized positions are not supported)");
  if (acc.count == 0) throw InputError(what + "has no vertices (an empty mesh has no bounds)");
  std::size_t stride = 0;
  const unsigned char* base = accessor_data(model, acc, 12, stride, what);
  Positions out;
  out.points.reserve(acc.count);
  for (std::size_t i = 0; i < acc.count; ++i) {
    float v[3];
    std::memcpy(v, base + i * stride, sizeof v);
    for (float c : v)
      if (!std::isfinite(c))
        throw InputError(what + "vertex " + std::to_string(i) + " has a NaN or infinite coordinate");
    out.points.emplace_back(v[0], v[1], v[2]);
  }
  if (acc.minValues.size() == 3 && acc.maxValues.size() == 3) {
    Aabb b;
    for (int k = 0; k < 3; ++k) {
      b.min[k] = float(acc.minValues[std::size_t(k)]);
      b.max[k] = float(acc.maxValues[std::size_t(k)]);
    }
    out.declared = b;
  }
  return out;
}

std::vector<std::uint32_t> read_indices(const tinygltf::Model& model, const tinygltf::Primitive& primitive,
                                        std::size_t vertex_count, const std::string& where) {
  std::vector<std::uint32_t> out;
  if (primitive.indices < 0) {
    out.resize(vertex_count);
    for (std::size_t i = 0; i < vertex_count; ++i) out[i] = std::uint32_t(i);
    return out;
  }
  if (std::size_t(primitive.indices) >= model.accessors.size())
    throw InputError(where + "index accessor " + std::to_string(primitive.indices) + " does not exist");
  const tinygltf::Accessor& acc = model.accessors[std::size_t(primitive.indices)];
  const std::string what = where + "index accessor " + std::to_string(primitive.indices) + " ";
  if (acc.sparse.isSparse) throw InputError(what + "is sparse (not supported)");
  if (acc.type != TINYGLTF_TYPE_SCALAR) throw InputError(what + "is not SCALAR");
  std::size_t size = 0;
  switch (acc.componentType) {
    case TINYGLTF_COMPONENT_TYPE_UNSIGNED_BYTE:
      size = 1;
      break;
    case TINYGLTF_COMPONENT_TYPE_UNSIGNED_SHORT:
      size = 2;
      break;
    case TINYGLTF_COMPONENT_TYPE_UNSIGNED_INT:
      size = 4;
      break;
    default:
      throw InputError(what + "has component type " + std::to_string(acc.componentType) +
                       ", not UNSIGNED_BYTE, UNSIGNED_SHORT or UNSIGNED_INT");
  }
  if (acc.count == 0) return out;
  std::size_t stride = 0;
  const unsigned char* base = accessor_data(model, acc, size, stride, what);
  out.reserve(acc.count);
  for (std::size_t i = 0; i < acc.count; ++i) {
    std::uint32_t index = 0;
    const unsigned char* p = base + i * stride;
    if (size == 1) {
      index = *p;
    } else if (size == 2) {
      std::uint16_t v;
      std::memcpy(&v, p, 2);
      index = v;
    } else {
      std::memcpy(&index, p, 4);
    }
    if (index >= vertex_count)
      throw InputError(what + "element " + std::to_string(i) + " is " + std::to_string(index) + ", past the " +
                       std::to_string(vertex_count) + " vertices");
    out.push_back(index);
  }
  return out;
}

std::vector<std::uint32_t> triangle_list(int mode, const std::vector<std::uint32_t>& indices) {
  std::vector<std::uint32_t> out;
  const std::size_t n = indices.size();
  switch (mode) {
    case TINYGLTF_MODE_TRIANGLES:
      out.assign(indices.begin(), indices.begin() + std::ptrdiff_t(n - n % 3));
      break;
    case TINYGLTF_MODE_TRIANGLE_STRIP:
      for (std::size_t i = 2; i < n; ++i) {
        if (i % 2 == 0)
          out.insert(out.end(), {indices[i - 2], indices[i - 1], indices[i]});
        else
          out.insert(out.end(), {indices[i - 1], indices[i - 2], indices[i]});
      }
      break;
    case TINYGLTF_MODE_TRIANGLE_FAN:
      for (std::size_t i = 2; i < n; ++i) out.insert(out.end(), {indices[i - 1], indices[i], indices[0]});
      break;
    default:  // points and lines: nothing to fill
      break;
  }
  return out;
}

}  // namespace cullpipe::gltf
