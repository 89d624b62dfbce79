#include "cullpipe/scene/gltf_scene.hpp"

#include <algorithm>
#include <array>
#include <cctype>
#include <cmath>
#include <cstring>
#include <glm/geometric.hpp>
#include <glm/gtc/quaternion.hpp>
#include <map>
#include <memory>
#include <utility>

#include "cullpipe/bounds/points.hpp"
#include "cullpipe/scene/generators.hpp"
#include "cullpipe/scene/gltf_model.hpp"

namespace cullpipe {
namespace {

using glm::dmat4;
using glm::dvec3;

std::string idx(const char* array, std::size_t i) { return std::string(array) + "[" + std::to_string(i) + "]"; }

// The node's local transform (matrix, or T * R * S), checked: finite, affine, unit-able quaternion.
dmat4 local_transform(const tinygltf::Node& node, const std::string& where) {
  auto finite = [&](const std::vector<double>& v, const char* what) {
    for (double x : v)
      if (!std::isfinite(x)) throw InputError(where + what + " has a NaN or infinite value");
  };
  if (!node.matrix.empty()) {
    if (node.matrix.size() != 16)
      throw InputError(where + "matrix has " + std::to_string(node.matrix.size()) + " values, not 16");
    finite(node.matrix, "matrix");
    dmat4 m;
    for (int c = 0; c < 4; ++c)
      for (int r = 0; r < 4; ++r) m[c][r] = node.matrix[std::size_t(4 * c + r)];
    if (m[0][3] != 0.0 || m[1][3] != 0.0 || m[2][3] != 0.0 || m[3][3] != 1.0)
      throw InputError(where + "matrix is not affine (its last row must be 0 0 0 1)");
    return m;
  }
  dmat4 m(1.0);
  if (!node.scale.empty()) {
    if (node.scale.size() != 3) throw InputError(where + "scale does not have 3 values");
    finite(node.scale, "scale");
    for (int k = 0; k < 3; ++k) m[k][k] = node.scale[std::size_t(k)];
  }
  if (!node.rotation.empty()) {
    if (node.rotation.size() != 4) throw InputError(where + "rotation does not have 4 values");
    finite(node.rotation, "rotation");
    glm::dquat q(node.rotation[3], node.rotation[0], node.rotation[1], node.rotation[2]);  // w, x, y, z
    const double len = glm::length(q);
    if (!(len > 0.0)) throw InputError(where + "rotation is the zero quaternion");
    q = q / len;
    m = dmat4(glm::mat3_cast(q)) * m;
  }
  if (!node.translation.empty()) {
    if (node.translation.size() != 3) throw InputError(where + "translation does not have 3 values");
    finite(node.translation, "translation");
    m[3] = glm::dvec4(node.translation[0], node.translation[1], node.translation[2], 1.0);
  }
  return m;
}

// Extensions that change how positions are stored: without a decoder the geometry is unreadable.
bool is_geometry_extension(const std::string& name) {
  return name == "KHR_draco_mesh_compression" || name == "KHR_mesh_quantization" || name == "EXT_meshopt_compression";
}

Camera gltf_camera(const tinygltf::Camera& cam, const dmat4& world, const std::string& where) {
  Camera out;
  const dvec3 eye(world * glm::dvec4(0, 0, 0, 1));
  const dvec3 forward(world * glm::dvec4(0, 0, -1, 0)), up(world * glm::dvec4(0, 1, 0, 0));
  const double fl = glm::length(forward), ul = glm::length(up);
  if (!(fl > 0.0) || !(ul > 0.0) || !std::isfinite(fl) || !std::isfinite(ul) ||
      glm::length(glm::cross(forward / fl, up / ul)) < 1e-6)
    throw InputError(where + "is placed by a singular or degenerate node transform");
  out.eye = glm::vec3(eye);
  out.target = glm::vec3(eye + forward / fl);
  out.up = glm::vec3(up / ul);
  if (cam.type == "perspective") {
    const tinygltf::PerspectiveCamera& p = cam.perspective;
    if (!(p.yfov > 0.0 && p.yfov < 3.14159265358979)) throw InputError(where + "yfov must be between 0 and pi");
    if (!(p.znear > 0.0) || !std::isfinite(p.znear)) throw InputError(where + "znear must be positive");
    out.fov_y_degrees = float(p.yfov * 180.0 / 3.14159265358979323846);
    if (p.aspectRatio > 0.0 && std::isfinite(p.aspectRatio)) out.aspect = float(p.aspectRatio);
    out.near_plane = float(p.znear);
    if (p.zfar > 0.0) {
      if (!(p.zfar > p.znear) || !std::isfinite(p.zfar)) throw InputError(where + "zfar must be larger than znear");
      out.far_plane = float(p.zfar);
    } else {
      out.infinite_far = true;
    }
  } else if (cam.type == "orthographic") {
    const tinygltf::OrthographicCamera& o = cam.orthographic;
    if (!(o.xmag != 0.0 && o.ymag != 0.0) || !std::isfinite(o.xmag) || !std::isfinite(o.ymag))
      throw InputError(where + "xmag and ymag must be non-zero");
    if (!(o.znear >= 0.0) || !(o.zfar > o.znear) || !std::isfinite(o.zfar))
      throw InputError(where + "needs 0 <= znear < zfar");
    out.orthographic = true;
    out.ortho_half_height = float(std::abs(o.ymag));
    out.aspect = float(std::abs(o.xmag) / std::abs(o.ymag));
    out.near_plane = float(o.znear);
    out.far_plane = float(o.zfar);
  } else {
    throw InputError(where + "has type \"" + cam.type + "\", not perspective or orthographic");
  }
  return out;
}

}  // namespace

bool is_gltf_path(const std::string& path) {
  return gltf::ends_with_ci(path, ".gltf") || gltf::ends_with_ci(path, ".glb");
}

GltfScene load_gltf_scene(const std::string& path, const GltfSceneOptions& options) {
  const tinygltf::Model model = gltf::load_model(path);
  const std::string file = path + ": ";
  for (const std::string& ext : model.extensionsRequired)
    if (is_geometry_extension(ext))
      throw InputError(file + "requires extension " + ext +
                       ", which cullpipe cannot decode (positions are unreadable without it)");

  // Parents: glTF nodes form disjoint trees, so each node has at most one parent.
  const std::size_t node_count = model.nodes.size();
  std::vector<int> parent(node_count, -1);
  for (std::size_t i = 0; i < node_count; ++i)
    for (int c : model.nodes[i].children) {
      if (c < 0 || std::size_t(c) >= node_count)
        throw InputError(file + idx("nodes", i) + ".children lists node " + std::to_string(c) +
                         ", which does not exist");
      if (std::size_t(c) == i)
        throw InputError(file + idx("nodes", i) + " is its own child (a cycle in the node graph)");
      if (parent[std::size_t(c)] >= 0)
        throw InputError(file + idx("nodes", std::size_t(c)) + " has two parents: nodes[" +
                         std::to_string(parent[std::size_t(c)]) + "] and nodes[" + std::to_string(i) + "]");
      parent[std::size_t(c)] = int(i);
    }
  // Cycles: with one parent each, a node is in (or under) a cycle when walking up never ends.
  {
    std::vector<char> state(node_count, 0);  // 0 unknown, 1 on the current walk, 2 reaches a root
    for (std::size_t start = 0; start < node_count; ++start) {
      std::vector<std::size_t> walk;
      for (std::size_t n = start;;) {
        if (state[n] == 2) break;
        if (state[n] == 1)
          throw InputError(file + idx("nodes", n) + " is its own ancestor (a cycle in the node graph)");
        state[n] = 1;
        walk.push_back(n);
        if (parent[n] < 0) break;
        n = std::size_t(parent[n]);
      }
      for (std::size_t m : walk) state[m] = 2;
    }
  }

  // Which roots to visit.
  std::vector<int> roots;
  std::string scene_name;
  if (model.scenes.empty()) {
    if (options.scene > 0)
      throw InputError(file + "has no scenes[]; scene " + std::to_string(options.scene) + " does not exist");
    for (std::size_t i = 0; i < node_count; ++i)
      if (parent[i] < 0) roots.push_back(int(i));
  } else {
    const int s = options.scene >= 0 ? options.scene : std::max(model.defaultScene, 0);
    if (std::size_t(s) >= model.scenes.size())
      throw InputError(file + "scene " + std::to_string(s) + " does not exist (the file has " +
                       std::to_string(model.scenes.size()) + " scenes)");
    roots = model.scenes[std::size_t(s)].nodes;
    scene_name = model.scenes[std::size_t(s)].name;
    std::vector<char> listed(node_count, 0);
    for (int r : roots) {
      const std::string where = file + idx("scenes", std::size_t(s)) + ".nodes: ";
      if (r < 0 || std::size_t(r) >= node_count)
        throw InputError(where + "node " + std::to_string(r) + " does not exist");
      if (parent[std::size_t(r)] >= 0)
        throw InputError(where + "nodes[" + std::to_string(r) + "] is not a root (it is a child of nodes[" +
                         std::to_string(parent[std::size_t(r)]) + "])");
      if (listed[std::size_t(r)]++) throw InputError(where + "nodes[" + std::to_string(r) + "] is listed twice");
    }
  }

  GltfScene out;
  out.scene.name = scene_name.empty() ? path : scene_name;
  for (std::size_t c = 0; c < model.cameras.size(); ++c) {
    GltfCamera info;
    info.index = int(c);
    info.name = model.cameras[c].name;
    out.cameras.push_back(info);
  }
  std::vector<dmat4> camera_world(model.cameras.size());

  // Each primitive's volumes and triangles, built the first time a node uses its mesh.
  struct Primitive {
    std::shared_ptr<const bounds::MeshBounds> bounds;
    std::shared_ptr<const TriangleMesh> triangles;
  };
  // Keyed by what defines the geometry (POSITION accessor, index accessor, mode), so meshes
  // that share accessors share the work and the memory.
  // (And by whether its material is double-sided: drawn with both faces, as glTF asks.)
  std::map<std::array<int, 4>, Primitive> cache;
  auto primitive = [&](std::size_t m, std::size_t p) -> const Primitive& {
    const tinygltf::Primitive& source = model.meshes[m].primitives[p];
    const auto pos_it = source.attributes.find("POSITION");
    const bool double_sided = source.material >= 0 && std::size_t(source.material) < model.materials.size() &&
                              model.materials[std::size_t(source.material)].doubleSided;
    Primitive& slot = cache[{pos_it == source.attributes.end() ? -1 : pos_it->second, source.indices, source.mode,
                             double_sided ? 1 : 0}];
    if (!slot.bounds) {
      const std::string where = file + idx("meshes", m) + ".primitives[" + std::to_string(p) + "]: ";
      gltf::Positions pos = gltf::read_positions(model, m, p, where);
      const tinygltf::Primitive& prim = model.meshes[m].primitives[p];
      std::vector<std::uint32_t> indices = gltf::read_indices(model, prim, pos.points.size(), where);
      try {
        slot.bounds = std::make_shared<const bounds::MeshBounds>(pos.points, options.bounds);
      } catch (const bounds::BadPoints& e) {
        throw InputError(where + e.what());
      }
      if (options.keep_triangles) {
        auto tri = std::make_shared<TriangleMesh>();
        tri->indices = gltf::triangle_list(prim.mode, indices);
        tri->positions = std::move(pos.points);
        tri->double_sided = double_sided;
        slot.triangles = std::move(tri);
      }
    }
    return slot;
  };

  // Depth-first over the trees, composing transforms in double (an explicit stack: the
  // hierarchy may be deeper than the call stack allows).
  struct Item {
    int node;
    dmat4 parent_world;
  };
  std::vector<Item> stack;
  for (auto it = roots.rbegin(); it != roots.rend(); ++it) stack.push_back({*it, dmat4(1.0)});
  while (!stack.empty()) {
    const Item item = stack.back();
    stack.pop_back();
    const std::size_t n = std::size_t(item.node);
    const tinygltf::Node& node = model.nodes[n];
    const std::string where = file + idx("nodes", n) + ": ";
    const dmat4 world = item.parent_world * local_transform(node, where);
    if (node.camera >= 0) {
      if (std::size_t(node.camera) >= model.cameras.size())
        throw InputError(where + "camera " + std::to_string(node.camera) + " does not exist");
      GltfCamera& info = out.cameras[std::size_t(node.camera)];
      if (info.node < 0) {
        info.node = int(n);
        camera_world[std::size_t(node.camera)] = world;
        if (info.name.empty()) info.name = node.name;
      }
    }
    if (node.mesh >= 0) {
      if (std::size_t(node.mesh) >= model.meshes.size())
        throw InputError(where + "mesh " + std::to_string(node.mesh) + " does not exist");
      const std::size_t m = std::size_t(node.mesh);
      const double det = glm::determinant(glm::dmat3(world));
      for (std::size_t p = 0; p < model.meshes[m].primitives.size(); ++p) {
        const Primitive& prim = primitive(m, p);
        if (!(std::abs(det) > 0.0) ||
            glm::determinant(glm::mat3(glm::mat4(world))) == 0.0f) {  // scale 0: draws nothing
          ++out.zero_scale_instances;
          continue;
        }
        if (out.scene.objects.size() >= kMaxSceneObjects)
          throw InputError(file + "has more than " + std::to_string(kMaxSceneObjects) +
                           " mesh primitive instances (the most a scene may hold)");
        SceneObject o;
        o.world = glm::mat4(world);
        o.local_bounds = prim.bounds->local_aabb();
        o.mesh = prim.bounds;
        o.triangles = prim.triangles;
        o.origin = {int(n), int(m), int(p), 0};
        out.scene.objects.push_back(std::move(o));
      }
    }
    for (auto c = node.children.rbegin(); c != node.children.rend(); ++c) stack.push_back({*c, world});
  }
  for (GltfCamera& c : out.cameras)
    if (c.name.empty()) c.name = "camera " + std::to_string(c.index);

  validate(out.scene, path);

  if (options.camera.empty()) {
    out.scene.camera = framing_camera(out.scene.bounds());
  } else {
    int chosen = -1;
    for (const GltfCamera& c : out.cameras)
      if (c.name == options.camera) chosen = c.index;
    if (chosen < 0 && !options.camera.empty() && std::all_of(options.camera.begin(), options.camera.end(), [](char ch) {
          return std::isdigit(static_cast<unsigned char>(ch));
        })) {
      const unsigned long v = std::stoul(options.camera.substr(0, 9));
      if (options.camera.size() <= 9 && v < out.cameras.size()) chosen = int(v);
    }
    if (chosen < 0) {
      std::string names;
      for (const GltfCamera& c : out.cameras)
        names += (names.empty() ? "" : ", ") + std::to_string(c.index) + " \"" + c.name + "\"";
      throw InputError(file + "no camera \"" + options.camera + "\"; the file has " +
                       (names.empty() ? std::string("no cameras") : "cameras " + names));
    }
    const GltfCamera& c = out.cameras[std::size_t(chosen)];
    if (c.node < 0) throw InputError(file + "camera \"" + c.name + "\" is not placed by any node of the scene");
    out.scene.camera = gltf_camera(model.cameras[std::size_t(chosen)], camera_world[std::size_t(chosen)],
                                   file + idx("cameras", std::size_t(chosen)) + " (\"" + c.name + "\") ");
  }
  return out;
}

}  // namespace cullpipe
