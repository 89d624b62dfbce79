#pragma once
// Shared by the BVH test executables: the check that hierarchical culling over a tree gives
// every object exactly the flat reference's class.
#include <gtest/gtest.h>

#include <cmath>
#include <glm/gtc/matrix_transform.hpp>
#include <span>
#include <vector>

#include "cullpipe/bvh/bvh.hpp"
#include "cullpipe/cull/reference.hpp"
#include "test_util.hpp"

namespace cullpipe::test {

/// In every view, the scalar hierarchical cull over `flat` classifies every object as the flat
/// CPU reference does, with the same visible and inside counts and no more object tests than
/// objects. Volume: Aabb, Obb or Sphere (for the last two the tree is over their enclosing
/// boxes).
template <class Volume>
void expect_hierarchy_equals_flat(const bvh::FlatTree& flat, std::span<const Volume> volumes,
                                  const std::vector<Frustum>& frusta) {
  for (std::size_t v = 0; v < frusta.size(); ++v) {
    std::vector<Classification> cpu(volumes.size());
    const reference::CullCounts counts = reference::classify_all(volumes, frusta[v], cpu);
    const bvh::HierarchicalResult h = bvh::cull_hierarchical(flat, volumes, frusta[v]);
    ASSERT_EQ(h.classes.size(), cpu.size()) << "view " << v;
    for (std::size_t i = 0; i < cpu.size(); ++i)
      ASSERT_EQ(h.classes[i], cpu[i]) << "view " << v << ", object " << i << ": hierarchical "
                                      << to_string(h.classes[i]) << ", flat " << to_string(cpu[i]);
    EXPECT_EQ(h.visible, counts.visible);
    EXPECT_EQ(h.inside, counts.inside);
    EXPECT_LE(h.object_tests, volumes.size());
  }
}
template <class Volume>
void expect_hierarchy_equals_flat(const bvh::FlatTree& flat, const std::vector<Volume>& volumes,
                                  const std::vector<Frustum>& frusta) {
  expect_hierarchy_equals_flat(flat, std::span<const Volume>(volumes), frusta);
}

/// A camera at `eye` looking along kTouchingView (Vulkan clip space, y flipped), near 0.5,
/// far 200.
inline const glm::vec3 kTouchingView(0.1f, -0.05f, -1.0f);
inline Frustum frustum_at(const glm::vec3& eye, float fov_degrees = 50.0f) {
  glm::mat4 proj = glm::perspectiveRH_ZO(glm::radians(fov_degrees), 1.5f, 0.5f, 200.0f);
  proj[1][1] *= -1.0f;
  return Frustum::from_view_proj(proj * glm::lookAtRH(eye, eye + kTouchingView, glm::vec3(0, 1, 0)));
}

/// Whether the plain p/n-vertex test of `box` (no margin) contradicts the volume's own test on
/// one plane: the box's p-vertex behind while the volume is not wholly behind, or the box's
/// n-vertex in front while the volume is not wholly in front. A margin-free hierarchy could
/// give such a volume a class flat culling does not give it.
template <class Volume>
bool box_contradicts(const Volume& volume, const Aabb& box, const Plane& plane) {
  Frustum one;
  one.planes[0] = plane;
  one.plane_count = 1;
  std::uint32_t straddled = 0;
  const Classification by_box = bvh::classify_masked(box, one, 1u, straddled);
  const Classification own = reference::classify(volume, one);
  return (by_box == Classification::Outside && own != Classification::Outside) ||
         (by_box == Classification::Inside && own != Classification::Inside);
}

/// Spheres and OBBs touching the planes of `f` (seen from `eye` along kTouchingView): each at
/// signed distance +-(its size) from a point of a plane in front of the camera, some a few float
/// steps off. Of `candidates` per plane, those whose enclosing box box_contradicts() are all
/// kept, with every 61st of the rest; `contradicting` counts the former. Every class occurs in
/// both sets.
struct TouchingVolumes {
  std::vector<Sphere> spheres;
  std::vector<Obb> obbs;
  std::size_t contradicting = 0;
};
inline TouchingVolumes touching_volumes(const Frustum& f, const glm::vec3& eye, Rng& rng, int candidates) {
  TouchingVolumes set;
  for (std::size_t k = 0; k < f.plane_count; ++k) {
    const Plane& plane = f.planes[k];
    const glm::vec3& n = plane.normal;
    for (int i = 0; i < candidates; ++i) {
      const float depth = rng.uniform(2.0f, 60.0f);
      const glm::vec3 q =
          eye + kTouchingView * depth + glm::vec3(rng.uniform(-0.4f, 0.4f), rng.uniform(-0.3f, 0.3f), 0.0f) * depth;
      const glm::vec3 on_plane = q - n * plane.distance(q);
      const float size = std::pow(10.0f, rng.uniform(-3.0f, 0.0f));
      const float side = (i & 1) ? 1.0f : -1.0f;
      Sphere s{on_plane + n * (side * size), size};
      for (int step = i / 2 % 4; step > 0; --step)
        s.center[i % 3] = std::nextafter(s.center[i % 3], (i & 4) ? 1e30f : -1e30f);
      Obb b;
      b.basis = rng.rotation();
      b.half_extents = glm::vec3(size, size * 0.5f, size * 0.25f);
      // Placed so that its own test's s is +-r as it computes them.
      const float r = std::abs(n.x * b.basis[0].x + n.y * b.basis[0].y + n.z * b.basis[0].z) * b.half_extents.x +
                      std::abs(n.x * b.basis[1].x + n.y * b.basis[1].y + n.z * b.basis[1].z) * b.half_extents.y +
                      std::abs(n.x * b.basis[2].x + n.y * b.basis[2].y + n.z * b.basis[2].z) * b.half_extents.z;
      b.center = on_plane + n * (side * r);
      const bool sphere_hard = box_contradicts(s, bvh::enclosing_box(s), plane);
      const bool obb_hard = box_contradicts(b, bvh::enclosing_box(b), plane);
      set.contradicting += std::size_t(sphere_hard) + std::size_t(obb_hard);
      if (sphere_hard || i % 61 == 0) set.spheres.push_back(s);
      if (obb_hard || i % 61 == 0) set.obbs.push_back(b);
    }
  }
  auto every_class = [&](auto volumes) {
    std::vector<Classification> flat(volumes.size());
    const reference::CullCounts counts = reference::classify_all(volumes, f, flat);
    EXPECT_GT(counts.inside, 0u);
    EXPECT_GT(counts.intersecting, 0u);
    EXPECT_LT(counts.visible, volumes.size());
  };
  every_class(std::span<const Sphere>(set.spheres));
  every_class(std::span<const Obb>(set.obbs));
  return set;
}

}  // namespace cullpipe::test
