#pragma once
#include <array>
#include <cstddef>
#include <glm/mat4x4.hpp>
#include <span>

#include "cullpipe/geom/plane.hpp"

namespace cullpipe {

/// A convex view volume as up to six inward-facing, normalised planes.
/// Planes in order: left, right, bottom, top, then the two depth planes (z >= 0, z <= w).
/// A depth plane at infinity (infinite-far or reversed-Z infinite projection) is dropped,
/// leaving five planes; `plane_count` says how many of `planes` are used.
struct Frustum {
  std::array<Plane, 6> planes{};
  std::size_t plane_count = 0;

  std::span<const Plane> active() const { return {planes.data(), plane_count}; }

  /// Extracts the planes of `view_proj` (column-major, Vulkan clip space x,y in [-w,w],
  /// z in [0,w]) by Gribb-Hartmann: left = r3+r0, right = r3-r0, bottom = r3+r1, top = r3-r1,
  /// z>=0 plane = r2, z<=w plane = r3-r2, where ri is row i. Each plane is divided by |n|.
  /// Throws std::invalid_argument when the matrix has non-finite entries, is singular, or
  /// yields a degenerate plane (zero normal that is not a plane at infinity).
  static Frustum from_view_proj(const glm::mat4& view_proj);

  /// Builds a frustum from explicit planes (1..6). A plane whose normal length differs from 1
  /// by more than 1e-6 is normalised; a unit plane is kept bit for bit, so planes written by
  /// `cullpipe run --dump` read back unchanged.
  /// Throws std::invalid_argument on a non-finite value or a zero normal.
  static Frustum from_planes(std::span<const glm::vec4> planes);

  bool operator==(const Frustum&) const = default;
};

}  // namespace cullpipe
