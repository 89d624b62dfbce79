#pragma once
#include <optional>
#include <string_view>

namespace cullpipe {

/// The kind of bounding volume a culling pass tests.
enum class BvKind { Aabb, Obb, Sphere };

constexpr std::string_view to_string(BvKind k) {
  return k == BvKind::Aabb ? "aabb" : k == BvKind::Obb ? "obb" : "sphere";
}

struct Aabb;
struct Obb;
struct Sphere;
/// The kind of a volume type.
template <class Volume>
constexpr BvKind kind_of();
template <>
constexpr BvKind kind_of<Aabb>() {
  return BvKind::Aabb;
}
template <>
constexpr BvKind kind_of<Obb>() {
  return BvKind::Obb;
}
template <>
constexpr BvKind kind_of<Sphere>() {
  return BvKind::Sphere;
}

inline std::optional<BvKind> parse_bv_kind(std::string_view s) {
  if (s == "aabb") return BvKind::Aabb;
  if (s == "obb") return BvKind::Obb;
  if (s == "sphere") return BvKind::Sphere;
  return std::nullopt;
}

}  // namespace cullpipe
