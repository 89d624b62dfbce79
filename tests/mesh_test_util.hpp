#pragma once
// Meshes and instance transforms for the cluster tests.
#include <cmath>
#include <cstdint>

#include "cullpipe/geom/instance.hpp"
#include "cullpipe/scene/generators.hpp"
#include "cullpipe/scene/scene.hpp"
#include "test_util.hpp"

namespace cullpipe::test {

// A latitude-longitude sphere of radius r: 2 x rings x segments triangles, wound outwards.
inline TriangleMesh uv_sphere(int rings, int segments, float r) { return uv_sphere_mesh(rings, segments, r); }

// A random affine transform: rotation, scale per axis in [0.2, 5] (non-uniform), a mirror with
// probability 1/2, and a translation up to `reach` on each axis.
inline Transform3x4 random_transform(Rng& rng, float reach = 100.0f) {
  const glm::mat3 r = rng.rotation();
  glm::vec3 k = rng.vec3(0.2f, 5.0f);
  if (rng.uniform(0.0f, 1.0f) < 0.5f) k.x = -k.x;
  Transform3x4 t;
  for (int row = 0; row < 3; ++row)
    t.rows[std::size_t(row)] = glm::vec4(r[0][row] * k.x, r[1][row] * k.y, r[2][row] * k.z, rng.uniform(-reach, reach));
  return t;
}

}  // namespace cullpipe::test
