#include "cullpipe/scene/scene_io.hpp"

#include <cstdio>
#include <filesystem>
#include <fstream>
#include <glm/gtc/matrix_inverse.hpp>

#include "cullpipe/geom/validate.hpp"
#include "cullpipe/scene/json_util.hpp"

namespace cullpipe {

void write_file_atomic(const std::string& path, std::string_view text) {
  const std::string tmp = path + ".tmp";
  {
    std::ofstream out(tmp, std::ios::binary | std::ios::trunc);
    if (!out) throw InputError(path + ": cannot write file");
    out << text;
    out.close();
    if (!out) {
      std::remove(tmp.c_str());
      throw InputError(path + ": write failed");
    }
  }
  std::error_code ec;
  std::filesystem::rename(tmp, path, ec);
  if (ec) {
    std::remove(tmp.c_str());
    throw InputError(path + ": cannot replace file: " + ec.message());
  }
}

using json_util::json;

namespace {

// `path` names the camera in errors: "camera", "path[2]".
Camera read_camera(const json_util::Reader& r, const json& c, const std::string& path) {
  Camera cam;
  cam.eye = r.vec3(r.member(c, path, "eye"), path + ".eye");
  cam.target = r.vec3(r.member(c, path, "target"), path + ".target");
  if (c.contains("up")) cam.up = r.vec3(c["up"], path + ".up");
  if (c.contains("fov_y_degrees")) cam.fov_y_degrees = r.number(c["fov_y_degrees"], path + ".fov_y_degrees");
  if (c.contains("aspect")) cam.aspect = r.number(c["aspect"], path + ".aspect");
  if (c.contains("near")) cam.near_plane = r.number(c["near"], path + ".near");
  if (c.contains("far")) cam.far_plane = r.number(c["far"], path + ".far");
  if (c.contains("reversed_z")) cam.reversed_z = r.boolean(c["reversed_z"], path + ".reversed_z");
  if (c.contains("infinite_far")) cam.infinite_far = r.boolean(c["infinite_far"], path + ".infinite_far");
  if (!(cam.fov_y_degrees > 0.0f && cam.fov_y_degrees < 180.0f)) r.fail(path + ".fov_y_degrees", "must be in (0, 180)");
  if (!(cam.aspect > 0.0f)) r.fail(path + ".aspect", "must be positive");
  if (!(cam.near_plane > 0.0f)) r.fail(path + ".near", "must be positive");
  if (!cam.infinite_far && !(cam.far_plane > cam.near_plane)) r.fail(path + ".far", "must be greater than near");
  return cam;
}

json camera_to_json(const Camera& c) {
  return {{"eye", json_util::to_json(c.eye)},
          {"target", json_util::to_json(c.target)},
          {"up", json_util::to_json(c.up)},
          {"fov_y_degrees", c.fov_y_degrees},
          {"aspect", c.aspect},
          {"near", c.near_plane},
          {"far", c.far_plane},
          {"reversed_z", c.reversed_z},
          {"infinite_far", c.infinite_far}};
}

}  // namespace

Scene parse_scene(const std::string& text, const std::string& source) {
  const json root = json_util::parse(text, source);
  const json_util::Reader r{source};
  const json& format = r.member(root, "(root)", "format");
  if (format != "cullpipe-scene") r.fail("format", "expected \"cullpipe-scene\"");
  const json& version = r.member(root, "(root)", "version");
  if (version != 1) r.fail("version", "unsupported version " + version.dump() + " (this cullpipe reads version 1)");

  Scene scene;
  if (auto it = root.find("name"); it != root.end() && it->is_string()) scene.name = it->get<std::string>();
  if (auto it = root.find("camera"); it != root.end()) scene.camera = read_camera(r, *it, "camera");
  if (auto it = root.find("path"); it != root.end()) {
    if (!it->is_array()) r.fail("path", "expected an array of cameras");
    scene.path.reserve(it->size());
    for (std::size_t i = 0; i < it->size(); ++i)
      scene.path.push_back(read_camera(r, (*it)[i], "path[" + std::to_string(i) + "]"));
  }
  const json& objects = r.member(root, "(root)", "objects");
  if (!objects.is_array()) r.fail("objects", "expected an array");
  scene.objects.reserve(objects.size());
  for (std::size_t i = 0; i < objects.size(); ++i) {
    const std::string path = "objects[" + std::to_string(i) + "]";
    const json& o = objects[i];
    SceneObject obj;
    obj.local_bounds.min = r.vec3(r.member(o, path, "min"), path + ".min");
    obj.local_bounds.max = r.vec3(r.member(o, path, "max"), path + ".max");
    if (o.contains("world")) obj.world = r.mat4(o["world"], path + ".world");
    scene.objects.push_back(obj);
  }
  validate(scene, source);
  return scene;
}

Scene load_scene(const std::string& path) { return parse_scene(json_util::read_file(path), path); }

std::string scene_to_json(const Scene& scene) {
  json root;
  root["format"] = "cullpipe-scene";
  root["version"] = 1;
  root["name"] = scene.name;
  root["camera"] = camera_to_json(scene.camera);
  if (!scene.path.empty()) {
    json path = json::array();
    for (const Camera& c : scene.path) path.push_back(camera_to_json(c));
    root["path"] = std::move(path);
  }
  json objects = json::array();
  for (const SceneObject& o : scene.objects) {
    json j = {{"min", json_util::to_json(o.local_bounds.min)}, {"max", json_util::to_json(o.local_bounds.max)}};
    if (o.world != glm::mat4(1.0f)) j["world"] = json_util::to_json(o.world);
    objects.push_back(std::move(j));
  }
  root["objects"] = std::move(objects);
  return root.dump(1) + "\n";
}

void save_scene(const std::string& path, const Scene& scene) {
  json_util::write_file_atomic(path, scene_to_json(scene));
}

}  // namespace cullpipe
