#include "scene/generators.hpp"

#include <algorithm>
#include <cmath>
#include <glm/ext/matrix_transform.hpp>

#include "core/splitmix.hpp"

namespace cullpipe {
namespace {

struct Rng : SplitMix64 {
  float normal() {  // Box-Muller
    const float u1 = std::max(uniform(), 1e-7f), u2 = uniform();
    return std::sqrt(-2.0f * std::log(u1)) * std::cos(6.2831853f * u2);
  }
};

glm::mat4 random_rotation(Rng& rng) {
  glm::mat4 m(1.0f);
  m = glm::rotate(m, rng.uniform(0.0f, 6.2831853f), glm::vec3(0, 1, 0));
  m = glm::rotate(m, rng.uniform(0.0f, 6.2831853f), glm::vec3(1, 0, 0));
  m = glm::rotate(m, rng.uniform(0.0f, 6.2831853f), glm::vec3(0, 0, 1));
  return m;
}

SceneObject random_box(Rng& rng, const glm::vec3& position) {
  SceneObject o;
  const glm::vec3 half(rng.uniform(0.25f, 1.0f), rng.uniform(0.25f, 1.0f), rng.uniform(0.25f, 1.0f));
  o.local_bounds = {-half, half};
  o.world = glm::translate(glm::mat4(1.0f), position) * random_rotation(rng);
  return o;
}

void aim_camera(Scene& scene) {
  const Aabb b = scene.bounds();
  const glm::vec3 c = b.center();
  const float r = std::max(glm::length(b.extent()) * 0.5f, 1.0f);
  // From just inside one corner of the scene, looking at its centre: near objects inside,
  // far and side objects outside, many crossing the planes.
  scene.camera.target = c;
  scene.camera.eye = c + glm::vec3(0.55f * r, 0.25f * r, 0.55f * r);
  scene.camera.near_plane = std::max(0.01f * r / 100.0f, 0.05f);
  scene.camera.far_plane = 1.2f * r;
}

}  // namespace

std::optional<SceneKind> parse_scene_kind(std::string_view name) {
  if (name == "uniform") return SceneKind::Uniform;
  if (name == "clustered") return SceneKind::Clustered;
  if (name == "city") return SceneKind::City;
  return std::nullopt;
}

std::string_view to_string(SceneKind kind) {
  switch (kind) {
    case SceneKind::Uniform:
      return "uniform";
    case SceneKind::Clustered:
      return "clustered";
    case SceneKind::City:
      return "city";
  }
  return "?";
}

Scene generate_scene(SceneKind kind, std::size_t count, std::uint64_t seed) {
  Rng rng{{seed * 0x2545F4914F6CDD1Dull + std::uint64_t(kind) + 1}};
  Scene scene;
  scene.name = std::string(to_string(kind)) + ":" + std::to_string(count) + " seed " + std::to_string(seed);
  scene.objects.reserve(count);
  const float side = 8.0f * std::cbrt(float(std::max<std::size_t>(count, 1)));  // constant density
  switch (kind) {
    case SceneKind::Uniform:
      for (std::size_t i = 0; i < count; ++i) {
        const glm::vec3 p(rng.uniform(-0.5f, 0.5f) * side, rng.uniform(-0.5f, 0.5f) * side,
                          rng.uniform(-0.5f, 0.5f) * side);
        scene.objects.push_back(random_box(rng, p));
      }
      break;
    case SceneKind::Clustered: {
      const std::size_t clusters = std::max<std::size_t>(1, std::size_t(std::sqrt(double(count)) / 4.0));
      std::vector<glm::vec3> centers(clusters);
      for (glm::vec3& c : centers)
        c = glm::vec3(rng.uniform(-0.5f, 0.5f), rng.uniform(-0.5f, 0.5f), rng.uniform(-0.5f, 0.5f)) * side;
      const float spread = side / (2.0f * std::cbrt(float(clusters)));
      for (std::size_t i = 0; i < count; ++i) {
        const glm::vec3& c = centers[std::size_t(rng.next() % clusters)];
        const glm::vec3 p = c + glm::vec3(rng.normal(), rng.normal(), rng.normal()) * (0.25f * spread);
        scene.objects.push_back(random_box(rng, p));
      }
      break;
    }
    case SceneKind::City: {
      const std::size_t per_row = std::max<std::size_t>(1, std::size_t(std::ceil(std::sqrt(double(count)))));
      const float spacing = 10.0f;
      const float origin = -0.5f * spacing * float(per_row - 1);
      for (std::size_t i = 0; i < count; ++i) {
        const float x = origin + spacing * float(i % per_row);
        const float z = origin + spacing * float(i / per_row);
        const float w = rng.uniform(2.0f, 4.0f), d = rng.uniform(2.0f, 4.0f);
        const float u = rng.uniform();
        const float h = 2.0f + 28.0f * u * u * u;  // mostly low, a few towers
        SceneObject o;
        o.local_bounds = {glm::vec3(-w, 0.0f, -d), glm::vec3(w, 2.0f * h, d)};
        o.world = glm::translate(glm::mat4(1.0f), glm::vec3(x, 0.0f, z));
        if (rng.uniform() < 0.25f) o.world = glm::rotate(o.world, rng.uniform(0.0f, 1.5707963f), glm::vec3(0, 1, 0));
        scene.objects.push_back(o);
      }
      break;
    }
  }
  aim_camera(scene);
  if (kind == SceneKind::City) {  // street level rather than from above
    const Aabb b = scene.bounds();
    const float r = std::max(glm::length(b.extent()) * 0.5f, 1.0f);
    scene.camera.eye = glm::vec3(0.45f * r, 12.0f, 0.45f * r);
    scene.camera.target = glm::vec3(0.0f, 6.0f, 0.0f);
  }
  return scene;
}

std::pair<SceneKind, std::size_t> parse_generate_spec(std::string_view spec) {
  const auto colon = spec.find(':');
  const std::string kind_name(spec.substr(0, colon));
  const auto kind = parse_scene_kind(kind_name);
  if (!kind)
    throw InputError("--generate " + std::string(spec) + ": unknown kind '" + kind_name +
                     "' (uniform, clustered, city)");
  if (colon == std::string_view::npos)
    throw InputError("--generate " + std::string(spec) + ": expected KIND:N, e.g. city:2000");
  const std::string n_text(spec.substr(colon + 1));
  char* end = nullptr;
  const double n = std::strtod(n_text.c_str(), &end);
  if (n_text.empty() || *end != '\0' || !(n >= 0.0) || n > 1e9 || n != std::floor(n))
    throw InputError("--generate " + std::string(spec) + ": N must be a whole number from 0 to 1e9");
  return {*kind, std::size_t(n)};
}

std::optional<InstanceLayout> parse_instance_layout(std::string_view name) {
  if (name == "grid") return InstanceLayout::Grid;
  if (name == "random") return InstanceLayout::Random;
  return std::nullopt;
}

Scene replicate_scene(const Scene& model, std::size_t copies, InstanceLayout layout, std::uint64_t seed) {
  if (copies == 0) throw InputError("--instances must be at least 1");
  if (copies == 1) return model;
  if (model.objects.size() > kMaxSceneObjects / copies)
    throw InputError(std::to_string(copies) + " copies of " + std::to_string(model.objects.size()) +
                     " objects exceed the limit of " + std::to_string(kMaxSceneObjects) + " objects per scene");
  const Aabb b = model.bounds();
  const glm::vec3 c = b.center(), e = b.extent();
  const float cell = std::max({e.x, e.z, 0.25f * e.y, 1e-3f}) * 1.25f;
  const std::size_t side = std::size_t(std::ceil(std::sqrt(double(copies))));
  Scene out;
  out.name = model.name + " x" + std::to_string(copies);
  out.objects.reserve(model.objects.size() * copies);
  Rng rng;
  rng.state = seed;
  const glm::mat4 to_origin = glm::translate(glm::mat4(1.0f), glm::vec3(-c.x, 0.0f, -c.z));
  for (std::size_t k = 0; k < copies; ++k) {
    glm::mat4 place;
    if (layout == InstanceLayout::Grid) {
      const float x = (float(k % side) - 0.5f * float(side - 1)) * cell,
                  z = (float(k / side) - 0.5f * float(side - 1)) * cell;
      place = glm::translate(glm::mat4(1.0f), glm::vec3(x, 0.0f, z)) * to_origin;
    } else {
      const float half = 0.5f * float(side) * cell;
      const glm::vec3 at(rng.uniform(-half, half), 0.0f, rng.uniform(-half, half));
      place = glm::rotate(glm::translate(glm::mat4(1.0f), at), rng.uniform(0.0f, 6.2831853f), glm::vec3(0, 1, 0)) *
              to_origin;
    }
    for (const SceneObject& o : model.objects) {
      SceneObject copy = o;
      copy.world = place * o.world;
      copy.origin.instance = int(k);
      out.objects.push_back(std::move(copy));
    }
  }
  out.camera = model.camera;
  aim_camera(out);
  return out;
}

}  // namespace cullpipe
