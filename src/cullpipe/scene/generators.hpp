#pragma once
#include <cstdint>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "cullpipe/scene/scene.hpp"

namespace cullpipe {

/// Procedural scene kinds. All place boxes at constant density, so the scene grows with N.
enum class SceneKind {
  Uniform,    ///< randomly rotated boxes spread uniformly through a cube
  Clustered,  ///< boxes in Gaussian clusters (about sqrt(N)/4 of them) at uniform positions
  City,       ///< buildings on a street grid: footprints 4-8, heights 4-60, some rotated
  /// Buildings packed into city blocks (street_lots) seen from street level, with a camera
  /// path (Scene::path) walking a loop of streets near the centre.
  Streets,
  /// Instances of one triangle mesh (a lumpy sphere of 6,400 triangles, rock_mesh) on the
  /// city's grid, each turned, scaled unevenly (2-4 wide, 2-14 high) and one in four mirrored,
  /// seen from street level: many instanced meshes with real depth complexity.
  Meshes,
};

std::optional<SceneKind> parse_scene_kind(std::string_view name);

/// A latitude-longitude sphere of `radius` centred on the origin: (rings + 1) x segments
/// vertices (each pole `segments` times), 2 x rings x segments triangles wound counter-clockwise
/// seen from outside (those at the poles have two corners at one place: no area).
TriangleMesh uv_sphere_mesh(int rings, int segments, float radius);
/// The `meshes` scene's mesh for `seed`: uv_sphere_mesh(40, 80, 1) with smooth lumps, each
/// vertex moved along its direction by up to 15% by a few low-frequency waves.
TriangleMesh rock_mesh(std::uint64_t seed);
std::string_view to_string(SceneKind kind);

/// A deterministic scene of `count` objects (0 allowed) for `seed`: the same arguments give
/// the same scene (own RNG, no std:: distributions, whose output differs between standard
/// libraries). The camera looks across the scene so a part of it is visible; a `streets`
/// scene's camera stands in a street, the first keyframe of its path.
Scene generate_scene(SceneKind kind, std::size_t count, std::uint64_t seed);

/// The lots of a `streets` scene of `count` buildings, in building order (footprints in x-z,
/// y zero): blocks of 4 x 2 lots, each 12 along x and 15 along z, between streets 14 wide
/// (along z) and 10 wide (along x), on a roughly square grid of blocks centred on the origin
/// and filled row by row of lots. Building i stands inside lot i, 0.25 or more from its edges.
std::vector<Aabb> street_lots(std::size_t count);

/// How `replicate_scene` places the copies.
enum class InstanceLayout {
  Grid,    ///< a square grid in the x-z plane, cells 1.25 times the model's larger horizontal extent
  Random,  ///< uniform positions in a square of the same area, each copy turned about +y at random
};
std::optional<InstanceLayout> parse_instance_layout(std::string_view name);  ///< grid | random

/// The most objects a scene may hold (about 4 GiB of objects and volumes).
inline constexpr std::size_t kMaxSceneObjects = std::size_t(1) << 25;

/// A scene of `copies` copies of `model`'s objects (for scale tests and benchmarks): copy k's
/// objects keep their mesh (shared, so millions of objects stay cheap) and origin, with
/// origin.instance = k, and are moved by the layout; deterministic per `seed`. For copies > 1
/// the camera looks across the result from inside one corner, so part of it is visible, and
/// the result has no camera path (the copies move the model off it); for
/// copies == 1 the scene is returned unchanged. Throws InputError when the result would have
/// more than kMaxSceneObjects objects.
Scene replicate_scene(const Scene& model, std::size_t copies, InstanceLayout layout, std::uint64_t seed);

/// Parses "KIND:N" (e.g. "city:2000", "uniform:1e6", "streets:10000"). Throws InputError on a bad spec.
std::pair<SceneKind, std::size_t> parse_generate_spec(std::string_view spec);

}  // namespace cullpipe
