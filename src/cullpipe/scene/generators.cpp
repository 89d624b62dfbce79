#include "cullpipe/scene/generators.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <glm/ext/matrix_transform.hpp>
#include <memory>

#include "cullpipe/bounds/mesh_bounds.hpp"
#include "cullpipe/bounds/sphere_fit.hpp"
#include "cullpipe/core/splitmix.hpp"

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

// Streets: blocks of kLotsX x kLotsZ lots; every lot faces a street.
constexpr std::size_t kLotsX = 4, kLotsZ = 2;
constexpr double kLotWidth = 12.0, kLotDepth = 15.0;  // along x, along z
constexpr double kAvenueWidth = 14.0;                 // streets along z, between block columns
constexpr double kStreetWidth = 10.0;                 // streets along x, between block rows
constexpr float kBuildingGap = 0.5f;                  // between neighbouring buildings
constexpr float kEyeHeight = 1.8f;

struct StreetGrid {
  static constexpr double kPitchX = double(kLotsX) * kLotWidth + kAvenueWidth;
  static constexpr double kPitchZ = double(kLotsZ) * kLotDepth + kStreetWidth;
  std::size_t block_columns = 1, block_rows = 1, lot_columns = kLotsX;
  double x0 = 0.0, z0 = 0.0;  // min corner of the first block

  explicit StreetGrid(std::size_t count) {
    const std::size_t n = std::max<std::size_t>(count, 1);
    const std::size_t blocks = (n + kLotsX * kLotsZ - 1) / (kLotsX * kLotsZ);
    // Columns so that the city's width is about its depth.
    block_columns = std::max<std::size_t>(1, std::size_t(std::lround(std::sqrt(double(blocks) * kPitchZ / kPitchX))));
    lot_columns = block_columns * kLotsX;
    const std::size_t lot_rows = (n + lot_columns - 1) / lot_columns;
    block_rows = (lot_rows + kLotsZ - 1) / kLotsZ;
    x0 = -0.5 * (double(block_columns) * kPitchX - kAvenueWidth);
    z0 = -0.5 * (double(block_rows) * kPitchZ - kStreetWidth);
  }
  Aabb lot(std::size_t i) const {
    const std::size_t c = i % lot_columns, r = i / lot_columns;
    const double x = x0 + double(c / kLotsX) * kPitchX + double(c % kLotsX) * kLotWidth;
    const double z = z0 + double(r / kLotsZ) * kPitchZ + double(r % kLotsZ) * kLotDepth;
    return {glm::vec3(float(x), 0.0f, float(z)), glm::vec3(float(x + kLotWidth), 0.0f, float(z + kLotDepth))};
  }
  // Centre lines of the streets before block column c and block row r (c == block_columns,
  // r == block_rows: the ones after the last block).
  float avenue_x(std::size_t c) const { return float(x0 + double(c) * kPitchX - 0.5 * kAvenueWidth); }
  float street_z(std::size_t r) const { return float(z0 + double(r) * kPitchZ - 0.5 * kStreetWidth); }
  float diagonal() const { return float(std::hypot(double(block_columns) * kPitchX, double(block_rows) * kPitchZ)); }
};

// A building filling `lot` but for the gaps to its neighbours; some set back from the street,
// a few turned inside the lot (and shrunk so their corners stay in it).
SceneObject street_building(Rng& rng, const Aabb& lot, bool faces_min_z) {
  const float u = rng.uniform();
  const float height = rng.uniform() < 0.05f ? 40.0f + 80.0f * u : 8.0f + 32.0f * u * u;  // a few towers
  float half_w = 0.5f * (lot.max.x - lot.min.x) - 0.5f * kBuildingGap;
  float half_d = 0.5f * (lot.max.z - lot.min.z) - 0.5f * kBuildingGap;
  glm::vec3 centre = 0.5f * (lot.min + lot.max);
  const float shape = rng.uniform();
  glm::mat4 turn(1.0f);
  if (shape < 0.15f) {  // set back: shallower, kept at the street front
    const float keep = rng.uniform(0.55f, 0.9f);
    centre.z += (faces_min_z ? -1.0f : 1.0f) * half_d * (1.0f - keep);
    half_d *= keep;
  } else if (shape < 0.23f) {
    const float angle = (rng.uniform() < 0.5f ? -1.0f : 1.0f) * rng.uniform(0.15f, 0.5f);
    const float c = std::cos(angle), s = std::abs(std::sin(angle));
    // The turned box's AABB spans w c + d s by w s + d c; 0.98 leaves room for rounding.
    const float fit = 0.98f * std::min(half_w / (half_w * c + half_d * s), half_d / (half_w * s + half_d * c));
    half_w *= fit;
    half_d *= fit;
    turn = glm::rotate(glm::mat4(1.0f), angle, glm::vec3(0, 1, 0));
  }
  SceneObject o;
  o.local_bounds = {glm::vec3(-half_w, 0.0f, -half_d), glm::vec3(half_w, height, half_d)};
  o.world = glm::translate(glm::mat4(1.0f), centre) * turn;
  return o;
}

// A walk around the blocks nearest the centre (two by two where the city has them), eye at
// kEyeHeight on the street centre lines, looking ahead. The view turns over the last 16 units
// before each corner and the corner itself, and the eye cuts the corner inside the
// intersection. Closed: the last keyframe is the first.
std::vector<Camera> street_loop(const StreetGrid& grid, const Camera& lens) {
  const std::size_t c0 = grid.block_columns >= 2 ? grid.block_columns / 2 - 1 : 0;
  const std::size_t r0 = grid.block_rows >= 2 ? grid.block_rows / 2 - 1 : 0;
  const std::size_t c1 = std::min(c0 + 2, grid.block_columns), r1 = std::min(r0 + 2, grid.block_rows);
  const float xa = grid.avenue_x(c0), xb = grid.avenue_x(c1), za = grid.street_z(r0), zb = grid.street_z(r1);
  const std::array<glm::vec3, 4> corners = {glm::vec3(xa, kEyeHeight, za), glm::vec3(xb, kEyeHeight, za),
                                            glm::vec3(xb, kEyeHeight, zb), glm::vec3(xa, kEyeHeight, zb)};
  constexpr float kLook = 30.0f;  // target distance ahead
  constexpr float kTurn = 16.0f;  // the view starts turning this far before a corner
  constexpr float kCut = 4.0f;    // the eye leaves and rejoins the centre lines this far from a crossing
  auto key = [&](const glm::vec3& eye, const glm::vec3& dir) {
    Camera c = lens;
    c.eye = eye;
    c.target = eye + kLook * glm::normalize(dir);
    return c;
  };
  std::vector<Camera> path;
  path.push_back(key(0.5f * (corners[0] + corners[1]), corners[1] - corners[0]));
  for (std::size_t k = 1; k <= 4; ++k) {
    const glm::vec3& c = corners[k % 4];
    const glm::vec3 in = glm::normalize(c - corners[k - 1]), out = glm::normalize(corners[(k + 1) % 4] - c);
    path.push_back(key(c - kTurn * in, in));
    path.push_back(key(c - kCut * in, in + out));
    path.push_back(key(c + kCut * out, out));
  }
  path.push_back(path.front());
  return path;
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
  if (name == "streets") return SceneKind::Streets;
  if (name == "meshes") return SceneKind::Meshes;
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
    case SceneKind::Streets:
      return "streets";
    case SceneKind::Meshes:
      return "meshes";
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
    case SceneKind::Meshes: {
      auto mesh = std::make_shared<TriangleMesh>(rock_mesh(seed));
      auto bounds = std::make_shared<const bounds::MeshBounds>(mesh->positions);
      const Aabb local = bounds::aabb_of_points(mesh->positions);
      const std::size_t per_row = std::max<std::size_t>(1, std::size_t(std::ceil(std::sqrt(double(count)))));
      const float spacing = 10.0f, origin = -0.5f * spacing * float(per_row - 1);
      for (std::size_t i = 0; i < count; ++i) {
        const float x = origin + spacing * float(i % per_row), z = origin + spacing * float(i / per_row);
        const float w = rng.uniform(2.0f, 4.0f), d = rng.uniform(2.0f, 4.0f), h = rng.uniform(2.0f, 14.0f);
        SceneObject o;
        o.local_bounds = local;
        o.world = glm::rotate(glm::translate(glm::mat4(1.0f), glm::vec3(x, h, z)), rng.uniform(0.0f, 6.2831853f),
                              glm::vec3(0, 1, 0));
        o.world = glm::scale(o.world, glm::vec3(rng.uniform() < 0.25f ? -w : w, h, d));
        o.mesh = bounds;
        o.triangles = mesh;
        scene.objects.push_back(o);
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
    case SceneKind::Streets: {
      const StreetGrid grid(count);
      for (std::size_t i = 0; i < count; ++i)
        scene.objects.push_back(street_building(rng, grid.lot(i), (i / grid.lot_columns) % kLotsZ == 0));
      break;
    }
  }
  aim_camera(scene);
  if (kind == SceneKind::City || kind == SceneKind::Meshes) {  // street level rather than from above
    const Aabb b = scene.bounds();
    const float r = std::max(glm::length(b.extent()) * 0.5f, 1.0f);
    scene.camera.eye = glm::vec3(0.45f * r, 12.0f, 0.45f * r);
    scene.camera.target = glm::vec3(0.0f, 6.0f, 0.0f);
  }
  if (kind == SceneKind::Streets) {
    const StreetGrid grid(count);
    Camera lens;
    lens.near_plane = 0.1f;
    lens.far_plane = std::max(grid.diagonal(), 100.0f);  // sees the whole city from anywhere in it
    scene.path = street_loop(grid, lens);
    scene.camera = scene.path.front();
  }
  return scene;
}

TriangleMesh uv_sphere_mesh(int rings, int segments, float radius) {
  TriangleMesh m;
  for (int i = 0; i <= rings; ++i)
    for (int j = 0; j < segments; ++j) {
      const float theta = float(i) / float(rings) * 3.14159265f, phi = float(j) / float(segments) * 6.2831853f;
      m.positions.push_back(
          radius * glm::vec3(std::sin(theta) * std::cos(phi), std::cos(theta), std::sin(theta) * std::sin(phi)));
    }
  const auto at = [&](int i, int j) { return std::uint32_t(i * segments + (j % segments)); };
  for (int i = 0; i < rings; ++i)
    for (int j = 0; j < segments; ++j) {
      m.indices.insert(m.indices.end(), {at(i, j), at(i, j + 1), at(i + 1, j)});
      m.indices.insert(m.indices.end(), {at(i, j + 1), at(i + 1, j + 1), at(i + 1, j)});
    }
  return m;
}

TriangleMesh rock_mesh(std::uint64_t seed) {
  constexpr int kRings = 40, kSegments = 80;
  TriangleMesh m = uv_sphere_mesh(kRings, kSegments, 1.0f);
  // Smooth lumps: a few low-frequency waves over the sphere (a pole's copies move together, so
  // the mesh stays closed), so that neighbouring triangles face much the same way.
  Rng rng{{seed * 0x9E3779B97F4A7C15ull + 17}};
  const float a = rng.uniform(0.0f, 6.2831853f), b = rng.uniform(0.0f, 6.2831853f), c = rng.uniform(0.0f, 6.2831853f);
  for (int i = 0; i <= kRings; ++i)
    for (int j = 0; j < kSegments; ++j) {
      const float theta = float(i) / float(kRings) * 3.14159265f;
      const float phi = i == 0 || i == kRings ? 0.0f : float(j) / float(kSegments) * 6.2831853f;
      const float lump = 1.0f + 0.1f * std::sin(2.0f * theta + a) * std::cos(3.0f * phi + b) +
                         0.05f * std::cos(3.0f * theta + c) * std::sin(2.0f * phi + a);
      m.positions[std::size_t(i * kSegments + j)] *= lump;
    }
  return m;
}

std::pair<SceneKind, std::size_t> parse_generate_spec(std::string_view spec) {
  const auto colon = spec.find(':');
  const std::string kind_name(spec.substr(0, colon));
  const auto kind = parse_scene_kind(kind_name);
  if (!kind)
    throw InputError("--generate " + std::string(spec) + ": unknown kind '" + kind_name +
                     "' (uniform, clustered, city, streets, meshes)");
  if (colon == std::string_view::npos)
    throw InputError("--generate " + std::string(spec) + ": expected KIND:N, e.g. city:2000");
  const std::string n_text(spec.substr(colon + 1));
  char* end = nullptr;
  const double n = std::strtod(n_text.c_str(), &end);
  if (n_text.empty() || *end != '\0' || !(n >= 0.0) || n > 1e9 || n != std::floor(n))
    throw InputError("--generate " + std::string(spec) + ": N must be a whole number from 0 to 1e9");
  return {*kind, std::size_t(n)};
}

std::vector<Aabb> street_lots(std::size_t count) {
  const StreetGrid grid(count);
  std::vector<Aabb> lots(count);
  for (std::size_t i = 0; i < count; ++i) lots[i] = grid.lot(i);
  return lots;
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
  out.camera = model.camera;  // out.path stays empty: the copies move the model off it
  aim_camera(out);
  return out;
}

}  // namespace cullpipe
