#pragma once
#include <optional>
#include <string>
#include <variant>
#include <vector>

#include "cullpipe/geom/aabb.hpp"
#include "cullpipe/geom/classification.hpp"
#include "cullpipe/geom/frustum.hpp"
#include "cullpipe/geom/obb.hpp"
#include "cullpipe/geom/sphere.hpp"
#include "cullpipe/scene/scene.hpp"

namespace cullpipe {

using Volume = std::variant<Aabb, Obb, Sphere>;

/// A self-contained culling problem: frusta and volumes, as read by `cullpipe classify` and
/// written by `cullpipe run --dump`. JSON schema:
///   {"frustum": F} or {"frusta": [F, ...]}, where F is {"planes": [[nx,ny,nz,d], ...]} (1..6
///   planes, inward: p is inside when n.p + d >= 0) or {"view_proj": [16 numbers, column-major]};
///   "volumes": [V, ...], where V is one of
///     {"aabb": {"min": [x,y,z], "max": [x,y,z]}}
///     {"aabb": {"center": [..], "half_extents": [..]}}
///     {"sphere": {"center": [..], "radius": r}}
///     {"obb": {"center": [..], "half_extents": [..], "axes": [[..],[..],[..]]}}  (unit, orthogonal)
///   A volume may carry "class" (one frustum) or "classes" (one per frustum), an "id", and
///   "object": {"gltf": {"node", "mesh", "primitive", "instance"}, "aabb", "obb", "sphere"}
///   (where a glTF object came from and all its world-space volumes); they are written by
///   --dump and ignored on reading.
struct CullCase {
  /// A dumped object's origin and world-space volumes.
  struct Object {
    ObjectOrigin origin;
    Aabb aabb;
    Obb obb;
    Sphere sphere;
  };
  std::vector<Frustum> frusta;
  bool multi_view = false;  ///< written as "frusta" rather than "frustum"
  std::vector<Volume> volumes;
  std::vector<Object> objects;  ///< empty, or one per volume (written only)
  /// Work done per view (written only, as "tests": [{"view", "cull", "node_tests", "object_tests"}],
  /// with "range_objects" for "bvh").
  struct Tests {
    std::string cull;  ///< "flat" or "bvh"
    std::size_t node_tests = 0, object_tests = 0;
    std::uint32_t range_objects = 0;  ///< "bvh": the traversal's bvh::TraversalOptions::range_objects
  };
  std::vector<Tests> tests;
};

/// Parses a cull case; throws InputError naming `source` and the JSON path of what is wrong
/// (syntax, missing or mistyped fields, NaN/Inf, negative extents or radii, a singular or
/// degenerate view-projection matrix, non-orthonormal OBB axes).
CullCase parse_cull_case(const std::string& text, const std::string& source);

/// One volume as compact JSON in the schema above, e.g. {"sphere":{"center":[..],"radius":r}}.
std::string volume_to_json_text(const Volume& v);

/// Serialises a cull case, with each volume's classes per frustum when `classes` is given
/// (classes[view][volume]) and optional object ids.
std::string cull_case_to_json(const CullCase& c, const std::vector<std::vector<Classification>>* classes = nullptr,
                              const std::vector<std::uint32_t>* ids = nullptr);

}  // namespace cullpipe
