#pragma once
// Volume sets at the edge of the plane bounds that let the fast CPU kernels and the GPU flat
// pass settle most objects without the reference's full test (host/cull/plane_bounds.hpp):
// each set comes with views of one plane each, and the answers must still be the reference's.
#include <cmath>
#include <cstdlib>
#include <limits>
#include <vector>

#include "geom/pn_vertex.hpp"
#include "test_util.hpp"

namespace cullpipe::test {

template <class Volume>
struct EdgeSet {
  std::vector<Volume> volumes;
  std::vector<Frustum> views;  // one plane each
};

// The AABB kernel settles most boxes by their centre distance against a bound on the half
// diagonal plus margins for every rounding; the rest get the p/n-vertex test. Boxes whose
// extents follow the normal (so the half diagonal is exactly the projected radius and only the
// margins separate the bound from the answer), with a vertex within float steps of slanted
// planes far from the origin; inverted, flat and point boxes; huge and non-finite coordinates.
inline EdgeSet<Aabb> aabb_edge_set() {
  Rng rng(23);
  std::vector<Frustum> views;
  for (float d : {0.0f, 900.0f, -3000.0f, 1e6f}) {
    const glm::vec4 plane(glm::normalize(rng.vec3(-1, 1) + glm::vec3(0.1f)), d);
    views.push_back(Frustum::from_planes({&plane, 1}));
  }
  std::vector<Aabb> boxes;
  for (const Frustum& view : views) {
    const Plane& plane = view.planes[0];
    const glm::vec3 n = plane.normal;
    const glm::vec3 on_plane = -plane.d * n;
    for (int i = 0; i < 600; ++i) {
      const float lambda = i % 10 == 0 ? 0.0f : rng.uniform(0.01f, 3.0f);  // some point boxes
      const glm::vec3 e = lambda * glm::abs(n) + (i % 3 == 0 ? rng.vec3(0.0f, 0.5f) : glm::vec3(0.0f));
      const glm::vec3 c = on_plane + rng.vec3(-50, 50) - glm::dot(rng.vec3(-50, 50), n) * n;
      Aabb b{c - e, c + e};
      // Move the box along n so the p-vertex (or the n-vertex) lies on the plane, then nudge
      // every coordinate by the same few float steps.
      const PnVertices v = pn_vertices(n, b);
      const glm::vec3 shift = -plane.distance(i % 2 ? v.p : v.n) * n;
      const int steps = i % 13 - 6;
      for (int k = 0; k < 3; ++k) {
        b.min[k] += shift[k];
        b.max[k] += shift[k];
        for (int s = 0; s < std::abs(steps); ++s) {
          b.min[k] = std::nextafter(b.min[k], steps > 0 ? 1e30f : -1e30f);
          b.max[k] = std::nextafter(b.max[k], steps > 0 ? 1e30f : -1e30f);
        }
      }
      if (i % 50 == 7) std::swap(b.min, b.max);  // inverted
      boxes.push_back(b);
    }
  }
  const float inf = std::numeric_limits<float>::infinity(), nan = std::numeric_limits<float>::quiet_NaN();
  for (float v : {inf, -inf, nan, 3e38f, -3e38f, 1e36f, 1e-40f, -1e-40f}) {
    boxes.push_back({{v, 0, 0}, {1, 1, 1}});
    boxes.push_back({{-1, -1, -1}, {1, v, 1}});
    boxes.push_back({{v, v, v}, {v, v, v}});
  }
  const std::size_t sharp = boxes.size();
  while (boxes.size() < 9000) boxes.push_back(boxes[rng.next() % sharp]);  // more than two runs
  // The same planes with normals of length 2, built by hand: no bound may settle anything.
  for (std::size_t v = 0, count = views.size(); v < count; ++v) {
    Frustum scaled = views[v];
    scaled.planes[0].normal *= 2.0f;
    scaled.planes[0].d *= 2.0f;
    views.push_back(scaled);
  }
  return {boxes, views};
}

}  // namespace cullpipe::test
