#include "cullpipe/cull/reference.hpp"

#include <cmath>
#include <stdexcept>

#include "cullpipe/geom/pn_vertex.hpp"
#include "cullpipe/geom/volume_tests.hpp"

namespace cullpipe::reference {

Classification classify_pn(const Aabb& box, const Frustum& frustum) {
  bool intersecting = false;
  for (const Plane& plane : frustum.active()) {
    const PnVertices v = pn_vertices(plane.normal, box);
    if (plane.distance(v.p) < 0.0f) return Classification::Outside;
    if (plane.distance(v.n) < 0.0f) intersecting = true;
  }
  return intersecting ? Classification::Intersecting : Classification::Inside;
}

Classification classify_corners(const Aabb& box, const Frustum& frustum) {
  bool all_inside = true;
  for (const Plane& plane : frustum.active()) {
    int behind = 0;
    for (const glm::vec3& corner : box.corners())
      if (plane.distance(corner) < 0.0f) ++behind;
    if (behind == 8) return Classification::Outside;
    if (behind > 0) all_inside = false;
  }
  return all_inside ? Classification::Inside : Classification::Intersecting;
}

Classification classify(const Obb& box, const Frustum& frustum) { return classify_planes(box, frustum, kAllPlanes); }

Classification classify(const Sphere& sphere, const Frustum& frustum) {
  return classify_planes(sphere, frustum, kAllPlanes);
}

namespace {

template <class Volume>
CullCounts classify_all_impl(std::span<const Volume> volumes, const Frustum& frustum, std::span<Classification> out) {
  if (out.size() != volumes.size()) throw std::invalid_argument("classify_all: output size differs from input size");
  CullCounts counts;
  for (std::size_t i = 0; i < volumes.size(); ++i) {
    const Classification c = classify(volumes[i], frustum);
    out[i] = c;
    counts.inside += c == Classification::Inside;
    counts.intersecting += c == Classification::Intersecting;
  }
  counts.visible = counts.inside + counts.intersecting;
  return counts;
}

}  // namespace

CullCounts count_classes(std::span<const Classification> classes) {
  CullCounts counts;
  for (const Classification c : classes) {
    counts.inside += c == Classification::Inside;
    counts.intersecting += c == Classification::Intersecting;
    counts.occluded += c == Classification::Occluded;
  }
  counts.visible = counts.inside + counts.intersecting;
  return counts;
}

CullCounts classify_all(std::span<const Aabb> v, const Frustum& f, std::span<Classification> out) {
  return classify_all_impl(v, f, out);
}
CullCounts classify_all(std::span<const Obb> v, const Frustum& f, std::span<Classification> out) {
  return classify_all_impl(v, f, out);
}
CullCounts classify_all(std::span<const Sphere> v, const Frustum& f, std::span<Classification> out) {
  return classify_all_impl(v, f, out);
}

}  // namespace cullpipe::reference
