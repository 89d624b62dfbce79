#pragma once
#include <cstdint>
#include <optional>
#include <string>
#include <string_view>

#include "scene/scene.hpp"

namespace cullpipe {

/// Procedural scene kinds. All place boxes at constant density, so the scene grows with N.
enum class SceneKind {
  Uniform,    ///< randomly rotated boxes spread uniformly through a cube
  Clustered,  ///< boxes in Gaussian clusters (about sqrt(N)/4 of them) at uniform positions
  City,       ///< buildings on a street grid: footprints 4-8, heights 4-60, some rotated
};

std::optional<SceneKind> parse_scene_kind(std::string_view name);
std::string_view to_string(SceneKind kind);

/// A deterministic scene of `count` objects (0 allowed) for `seed`: the same arguments give
/// the same scene (own RNG, no std:: distributions, whose output differs between standard
/// libraries). The camera looks across the scene so a part of it is visible.
Scene generate_scene(SceneKind kind, std::size_t count, std::uint64_t seed);

/// Parses "KIND:N" (e.g. "city:2000", "uniform:1e6"). Throws InputError on a bad spec.
std::pair<SceneKind, std::size_t> parse_generate_spec(std::string_view spec);

}  // namespace cullpipe
