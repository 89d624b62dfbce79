// Header-inline arithmetic stays uncontracted in a consumer's code. This file is built the way
// a consumer might build it: with FMA instructions and contraction on (GCC: fast, across
// statements; Clang: on, its default, within an expression), while the library is built with
// contraction off. Plane::distance and the OBB and sphere plane tests, inlined here, must give
// what the library computes, bit for bit; otherwise a consumer's own CPU answers would differ
// from the GPU's (CULLPIPE_EXACT_FP_BEGIN in geom/exact_fp.hpp is what keeps them equal).
#include <gtest/gtest.h>

#include <cmath>
#include <cstdint>
#include <glm/ext/matrix_transform.hpp>
#include <random>

#include "cullpipe/cull/reference.hpp"
#include "cullpipe/geom/obb.hpp"
#include "cullpipe/geom/plane.hpp"
#include "cullpipe/geom/volume_tests.hpp"

namespace cullpipe {
namespace {

// Not bracketed: what this file's flags do to a product and a sum.
float product_plus(float a, float b, float c) { return a * b + c; }

// n.p + d with every product and sum rounded on its own (a volatile store cannot be fused).
float distance_rounded(const Plane& plane, const glm::vec3& p) {
  volatile float x = plane.normal.x * p.x;
  volatile float y = plane.normal.y * p.y;
  volatile float z = plane.normal.z * p.z;
  volatile float s = x + y;
  s = s + z;
  return s + plane.d;
}

// Plane::distance as a consumer's own function calls it (kept out of line, so the loop around
// it cannot turn its products into one vector product).
[[gnu::noinline]] float consumer_distance(const Plane& plane, const glm::vec3& p) { return plane.distance(p); }

float uniform(std::mt19937& rng, float lo, float hi) { return std::uniform_real_distribution<float>(lo, hi)(rng); }

Plane random_plane(std::mt19937& rng) {
  const glm::vec3 n =
      glm::normalize(glm::vec3(uniform(rng, -1, 1), uniform(rng, -1, 1), uniform(rng, -1, 1)) + glm::vec3(1e-3f));
  return {n, uniform(rng, -10, 10)};
}

// This file really is contracted: otherwise the checks below would prove nothing.
bool file_contracts() {
  std::mt19937 rng(7);
  for (int i = 0; i < 1000; ++i) {
    const float a = uniform(rng, -2, 2), b = uniform(rng, -2, 2),
                c = -a * b;  // cancellation shows the fused product's tail
    volatile float a_v = a, b_v = b, c_v = c;
    if (product_plus(a_v, b_v, c_v) != static_cast<float>(a * b) + c) return true;
  }
  return false;
}

TEST(ConsumerContraction, PlaneDistanceIsRoundedAsTheLibraryRoundsIt) {
  if (!file_contracts()) GTEST_SKIP() << "this build does not contract a * b + c (no FMA, or not optimised)";
  std::mt19937 rng(11);
  int fused_would_differ = 0;
  for (int i = 0; i < 100000; ++i) {
    const Plane plane = random_plane(rng);
    // Points near the plane, where the sum cancels and a fused product would change the last bits.
    glm::vec3 p(uniform(rng, -10, 10), uniform(rng, -10, 10), uniform(rng, -10, 10));
    p -= plane.normal * plane.distance(p);
    const float expected = distance_rounded(plane, p);
    const float fused = std::fma(plane.normal.z, p.z, std::fma(plane.normal.y, p.y, plane.normal.x * p.x)) + plane.d;
    if (fused != expected) ++fused_would_differ;
    ASSERT_EQ(consumer_distance(plane, p), expected)
        << "plane (" << plane.normal.x << ", " << plane.normal.y << ", " << plane.normal.z << ", " << plane.d
        << "), point (" << p.x << ", " << p.y << ", " << p.z << ")";
  }
  EXPECT_GT(fused_would_differ, 1000) << "the inputs do not tell a fused distance from a rounded one";
}

TEST(ConsumerContraction, InlineObbAndSphereTestsAgreeWithTheLibrary) {
  if (!file_contracts()) GTEST_SKIP() << "this build does not contract a * b + c (no FMA, or not optimised)";
  std::mt19937 rng(13);
  const Frustum frustum = Frustum::from_view_proj(glm::mat4{
      {1.2f, 0.1f, 0.0f, 0.0f}, {0.0f, 1.5f, 0.2f, 0.0f}, {0.3f, 0.1f, -1.0f, -1.0f}, {0.5f, -0.3f, 0.9f, 4.0f}});
  int straddling = 0;
  for (int i = 0; i < 200000; ++i) {
    // Volumes that touch a plane to within rounding, where a contracted test would flip.
    const Plane& plane = frustum.planes[static_cast<std::size_t>(i) % frustum.plane_count];
    glm::vec3 c(uniform(rng, -3, 3), uniform(rng, -3, 3), uniform(rng, 1, 8));
    const float radius = uniform(rng, 0.0f, 0.5f);
    c -= plane.normal * (plane.distance(c) + radius);
    const Sphere sphere{c, radius};
    const glm::mat3 basis =
        glm::mat3(glm::rotate(glm::mat4(1.0f), uniform(rng, 0, 6.28f),
                              glm::normalize(glm::vec3(uniform(rng, -1, 1), uniform(rng, -1, 1), 1.0f))));
    const Obb box{c, basis, glm::vec3(uniform(rng, 0, 0.5f), uniform(rng, 0, 0.5f), uniform(rng, 0, 0.5f))};
    const Classification sphere_inline = classify_planes(sphere, frustum, kAllPlanes);
    const Classification box_inline = classify_planes(box, frustum, kAllPlanes);
    if (sphere_inline == Classification::Intersecting) ++straddling;
    ASSERT_EQ(sphere_inline, reference::classify(sphere, frustum))
        << "sphere (" << c.x << ", " << c.y << ", " << c.z << "; " << radius << ")";
    ASSERT_EQ(box_inline, reference::classify(box, frustum))
        << "OBB centre (" << c.x << ", " << c.y << ", " << c.z << ")";
  }
  EXPECT_GT(straddling, 1000);
}

}  // namespace
}  // namespace cullpipe
