#include <gtest/gtest.h>

#include <bit>
#include <cmath>
#include <cstdint>
#if defined(__SSE__)
#include <xmmintrin.h>
#endif
#include <glm/ext/matrix_clip_space.hpp>
#include <glm/ext/matrix_transform.hpp>
#include <limits>

#include "cullpipe/geom/aabb.hpp"
#include "cullpipe/geom/frustum.hpp"
#include "cullpipe/geom/obb.hpp"
#include "cullpipe/geom/rounding.hpp"
#include "cullpipe/geom/sphere.hpp"
#include "cullpipe/geom/validate.hpp"
#include "test_util.hpp"

namespace cullpipe {
namespace {

TEST(Aabb, FormsRoundTripExactlyOnDyadicValues) {
  const Aabb box{{-1.5f, 2.0f, -8.25f}, {3.5f, 6.0f, 0.75f}};
  EXPECT_EQ(to_min_max(to_min_diameter(box)), box);
  EXPECT_EQ(to_min_max(to_center_radius(box)), box);
  const AabbCenterRadius cr = to_center_radius(box);
  EXPECT_EQ(cr.center, glm::vec3(1.0f, 4.0f, -3.75f));
  EXPECT_EQ(cr.radius, glm::vec3(2.5f, 2.0f, 4.5f));
  EXPECT_EQ(to_min_diameter(box).diameter, glm::vec3(5.0f, 4.0f, 9.0f));
}

TEST(Aabb, FormsRoundTripWithinRoundingOnRandomValues) {
  test::Rng rng{7};
  for (int i = 0; i < 10000; ++i) {
    const Aabb box = test::random_aabb(rng, 1000.0f, 50.0f);
    const Aabb a = to_min_max(to_center_radius(box));
    const Aabb b = to_min_max(to_min_diameter(box));
    const float tol = 1e-4f;  // ~ulp of 1000
    for (int k = 0; k < 3; ++k) {
      EXPECT_NEAR(a.min[k], box.min[k], tol);
      EXPECT_NEAR(a.max[k], box.max[k], tol);
      EXPECT_NEAR(b.max[k], box.max[k], tol);
      EXPECT_EQ(b.min[k], box.min[k]);
    }
  }
}

TEST(Aabb, TransformedEnclosesTransformedCorners) {
  test::Rng rng{3};
  for (int i = 0; i < 1000; ++i) {
    const Aabb box = test::random_aabb(rng, 10.0f, 5.0f);
    glm::mat4 m = glm::mat4(rng.rotation());
    m = glm::scale(m, rng.vec3(0.1f, 3.0f));
    m[3] = glm::vec4(rng.vec3(-20.0f, 20.0f), 1.0f);
    const Aabb t = box.transformed(m);
    for (const glm::vec3& c : box.corners()) {  // exact corners, no slack
      const glm::dvec3 p = glm::dvec3(glm::dmat4(m) * glm::dvec4(glm::dvec3(c), 1.0));
      for (int k = 0; k < 3; ++k) {
        ASSERT_LE(double(t.min[k]), p[k]);
        ASSERT_GE(double(t.max[k]), p[k]);
      }
    }
  }
}

// A box 10^32 long and 4.5 wide, rotated (found by the bounds fuzzer): the centre/extent form
// of Arvo's method computed c' and |M| h near 10^32 each, and their sum lost the far side of
// the 4.5 (max.x came out 0 where a corner lies at 3). Every corner, transformed in double as
// AabbUpdate::Recompute transforms points, must be inside.
TEST(Aabb, TransformedKeepsASmallSideBesideAHugeOne) {
  const Aabb box{{0.0f, 0.0f, 0.0f}, {4.5f, 7.301667457314601e+32f, 562954315497472.0f}};
  for (const glm::vec3& axis : {glm::vec3(1, 2, 3), glm::vec3(-3, 1, 2), glm::vec3(0, 0, 1)})
    for (float angle : {0.7f, 2.0f, -1.1f}) {
      const glm::mat4 m = glm::rotate(glm::mat4(1.0f), angle, glm::normalize(axis));
      const Aabb t = box.transformed(m);
      for (const glm::vec3& c : box.corners()) {
        const glm::dvec3 p = glm::dvec3(glm::dmat4(m) * glm::dvec4(glm::dvec3(c), 1.0));
        for (int k = 0; k < 3; ++k) {
          ASSERT_LE(double(t.min[k]), p[k]) << "angle " << angle << " axis " << k;
          ASSERT_GE(double(t.max[k]), p[k]) << "angle " << angle << " axis " << k;
        }
      }
    }
}

TEST(Obb, BaseAxesRoundTrip) {
  test::Rng rng{11};
  for (int i = 0; i < 1000; ++i) {
    const Obb b = test::random_obb(rng, 10.0f, 4.0f);
    const Obb r = to_basis_radius(to_base_axes(b));
    for (int k = 0; k < 3; ++k) {
      EXPECT_NEAR(r.center[k], b.center[k], 1e-4f);
      EXPECT_NEAR(r.half_extents[k], b.half_extents[k], 1e-4f);
      if (b.half_extents[k] > 1e-3f) {
        for (int j = 0; j < 3; ++j) EXPECT_NEAR(r.basis[k][j], b.basis[k][j], 1e-3f);
      }
    }
    EXPECT_EQ(invalid_reason(r), "");
  }
}

TEST(Obb, ZeroEdgeStillGivesOrthonormalBasis) {
  const ObbBaseAxes flat{{0, 0, 0}, {glm::vec3(2, 0, 0), glm::vec3(0, 0, 0), glm::vec3(0, 0, 3)}};
  const Obb b = to_basis_radius(flat);
  EXPECT_EQ(invalid_reason(b), "");
  EXPECT_EQ(b.half_extents, glm::vec3(1.0f, 0.0f, 1.5f));
  EXPECT_EQ(b.center, glm::vec3(1.0f, 0.0f, 1.5f));
}

TEST(Obb, FromTransformedAabbEnclosesCornersEvenWithShear) {
  test::Rng rng{5};
  for (int i = 0; i < 500; ++i) {
    const Aabb box = test::random_aabb(rng, 5.0f, 2.0f);
    glm::mat4 m = glm::mat4(rng.rotation());
    m[1] += m[0] * rng.uniform(-0.5f, 0.5f);  // shear
    m[3] = glm::vec4(rng.vec3(-10.0f, 10.0f), 1.0f);
    const Obb o = Obb::from_transformed_aabb(box, m);
    ASSERT_EQ(invalid_reason(o), "");
    for (const glm::vec3& c : box.corners()) {  // exact corners on the stored axes, no slack
      const glm::dvec3 p = glm::dvec3(glm::dmat4(m) * glm::dvec4(glm::dvec3(c), 1.0)) - glm::dvec3(o.center);
      for (int k = 0; k < 3; ++k) ASSERT_LE(std::abs(glm::dot(p, glm::dvec3(o.basis[k]))), double(o.half_extents[k]));
    }
  }
}

TEST(Validate, NamesWhatIsWrong) {
  const float nan = std::numeric_limits<float>::quiet_NaN(), inf = std::numeric_limits<float>::infinity();
  EXPECT_EQ(invalid_reason(Aabb{{0, nan, 0}, {1, 1, 1}}), "min.y is NaN");
  EXPECT_EQ(invalid_reason(Aabb{{0, 0, 0}, {1, 1, inf}}), "max.z is infinite");
  EXPECT_EQ(invalid_reason(Aabb{{2, 0, 0}, {1, 1, 1}}), "min.x > max.x");
  EXPECT_EQ(invalid_reason(Aabb{{1, 1, 1}, {1, 1, 1}}), "");  // a point box is valid
  EXPECT_EQ(invalid_reason(Sphere{{0, 0, 0}, -1.0f}), "radius is negative");
  EXPECT_EQ(invalid_reason(Sphere{{0, 0, 0}, nan}), "radius is NaN");
  Obb o;
  o.half_extents = {1, -1, 1};
  EXPECT_EQ(invalid_reason(o), "half_extents.y is negative");
  o.half_extents = {1, 1, 1};
  o.basis[2] = glm::vec3(1, 0, 0);
  EXPECT_EQ(invalid_reason(o), "axes[0] and axes[2] are not orthogonal");
}

// float_below / float_above replace std::nextafter toward -inf / +inf bit for bit (signed
// zeros, subnormals, the largest floats, infinities, NaN), and round_down / round_up built on
// them bracket doubles tightly.
TEST(Rounding, FloatStepsAreNextafterBitForBit) {
  const float inf = std::numeric_limits<float>::infinity();
  std::vector<float> values = {0.0f,
                               -0.0f,
                               std::numeric_limits<float>::denorm_min(),
                               -std::numeric_limits<float>::denorm_min(),
                               std::numeric_limits<float>::min(),
                               -std::numeric_limits<float>::min(),
                               std::numeric_limits<float>::max(),
                               -std::numeric_limits<float>::max(),
                               1.0f,
                               -1.0f,
                               inf,
                               -inf,
                               std::numeric_limits<float>::quiet_NaN()};
  test::Rng rng{7};
  for (int i = 0; i < 100000; ++i) values.push_back(std::bit_cast<float>(std::uint32_t(rng.next())));
  for (float f : values) {
    const float down = std::nextafter(f, -inf), up = std::nextafter(f, inf);
    if (std::isnan(f)) {
      EXPECT_TRUE(std::isnan(float_below(f)) && std::isnan(float_above(f)));
      continue;
    }
    EXPECT_EQ(std::bit_cast<std::uint32_t>(float_below(f)), std::bit_cast<std::uint32_t>(down)) << f;
    EXPECT_EQ(std::bit_cast<std::uint32_t>(float_above(f)), std::bit_cast<std::uint32_t>(up)) << f;
  }
#if defined(__SSE__)
  {  // the same steps with subnormals read as zero and results flushed (DAZ + FTZ), against
     // nextafter's answers above (nextafter steps on the integer bits, in any mode)
    std::vector<float> below(values.size()), above(values.size());
    {
      struct Mode {
        unsigned saved = _mm_getcsr();
        Mode() {
          _mm_setcsr(saved | 0x8040u);
          asm volatile("" ::: "memory");  // (the float work stays between the mode changes)
        }
        ~Mode() {
          asm volatile("" ::: "memory");
          _mm_setcsr(saved);
        }
      } mode;
      for (std::size_t i = 0; i < values.size(); ++i)
        below[i] = float_below(values[i]), above[i] = float_above(values[i]);
    }
    for (std::size_t i = 0; i < values.size(); ++i) {
      const float f = values[i];
      if (std::isnan(f)) continue;
      EXPECT_EQ(std::bit_cast<std::uint32_t>(below[i]), std::bit_cast<std::uint32_t>(std::nextafter(f, -inf)))
          << std::hex << std::bit_cast<std::uint32_t>(f);
      EXPECT_EQ(std::bit_cast<std::uint32_t>(above[i]), std::bit_cast<std::uint32_t>(std::nextafter(f, inf)))
          << std::hex << std::bit_cast<std::uint32_t>(f);
    }
  }
#endif
  // Doubles of 53 random bits with exponents from -151 to 148 (the float subnormals, and
  // smaller where the leading bits are zeros), the float boundaries and their neighbours,
  // double subnormals, zeros and infinities.
  std::vector<double> doubles;
  for (int i = 0; i < 100000; ++i)
    doubles.push_back((double(rng.next() >> 11) * 0x1p-53 - 0.5) * std::ldexp(1.0, int(rng.next() % 300) - 150));
  for (double b : {0x1p-126, 0x1p-149, 0x1p-150, 0x1.8p-150, 0x1p-1000, 0x1p-1074, 0x1p-1022, 0.0, 3e-40, 1e-45,
                   double(std::numeric_limits<float>::max()), 0x1.fffffffp127, 0x1p128, 1e300,
                   std::numeric_limits<double>::infinity()})
    for (double v : {b, std::nextafter(b, 0.0), std::nextafter(b, 1.0)}) doubles.push_back(v), doubles.push_back(-v);
  std::vector<float> lows, highs;
  for (double v : doubles) {
    const float lo = round_down(v), hi = round_up(v);
    EXPECT_LE(double(lo), v);
    EXPECT_GE(double(hi), v);
    EXPECT_TRUE(lo == hi ? double(lo) == v : float_above(lo) == hi) << v;
    lows.push_back(lo), highs.push_back(hi);
  }
#if defined(__SSE__)
  // The same floats, bit for bit, in every rounding direction with FTZ, DAZ, both or neither
  // (under FTZ a plain conversion to float would flush a subnormal result to zero, and round_up
  // of 3e-40 would come out as 2^-149; under DAZ a comparison would read a subnormal as zero, so
  // round_down could come out above v). The barriers keep the compiler from moving the float
  // work across the mode changes (it does not know the mode is state).
  for (unsigned rounding : {0x0000u, 0x2000u, 0x4000u, 0x6000u})
    for (unsigned flush : {0x0000u, 0x8000u, 0x0040u, 0x8040u}) {
      const unsigned mode = rounding | flush;
      std::vector<float> mode_lows(doubles.size()), mode_highs(doubles.size());
      {
        struct Mode {
          unsigned saved = _mm_getcsr();
          explicit Mode(unsigned bits) {
            _mm_setcsr((saved & ~0xE040u) | bits);
            asm volatile("" ::: "memory");
          }
          ~Mode() {
            asm volatile("" ::: "memory");
            _mm_setcsr(saved);
          }
        } set(mode);
        for (std::size_t i = 0; i < doubles.size(); ++i)
          mode_lows[i] = round_down(doubles[i]), mode_highs[i] = round_up(doubles[i]);
      }
      int wrong = 0;
      for (std::size_t i = 0; i < doubles.size() && wrong < 5; ++i)
        if (std::bit_cast<std::uint32_t>(mode_lows[i]) != std::bit_cast<std::uint32_t>(lows[i]) ||
            std::bit_cast<std::uint32_t>(mode_highs[i]) != std::bit_cast<std::uint32_t>(highs[i])) {
          ++wrong;
          ADD_FAILURE() << "MXCSR bits " << std::hex << mode << ": " << std::hexfloat << doubles[i] << " rounds to ["
                        << mode_lows[i] << ", " << mode_highs[i] << "], not [" << lows[i] << ", " << highs[i] << "]";
        }
    }
#endif
}

// is_valid is invalid_reason(v).empty(), on volumes broken one value at a time.
TEST(Validate, IsValidAgreesWithInvalidReason) {
  const float specials[] = {std::numeric_limits<float>::quiet_NaN(),
                            std::numeric_limits<float>::infinity(),
                            -std::numeric_limits<float>::infinity(),
                            -1.0f,
                            0.0f,
                            2.0f,
                            0.999f,
                            1.0005f,
                            -0.0f};
  test::Rng rng{5};
  int invalid = 0;
  for (int i = 0; i < 2000; ++i) {
    Aabb a = test::random_aabb(rng, 10.0f, 2.0f);
    Obb o = test::random_obb(rng, 10.0f, 2.0f);
    Sphere s = test::random_sphere(rng, 10.0f, 2.0f);
    const float v = specials[rng.next() % std::size(specials)];
    const int at = int(rng.next() % 16);
    if (i % 4) {  // one value replaced (a quarter stay as generated)
      if (at < 3)
        a.min[at] = v;
      else if (at < 6)
        a.max[at - 3] = v;
      if (at < 3)
        o.center[at] = v;
      else if (at < 6)
        o.half_extents[at - 3] = v;
      else if (at < 15)
        o.basis[(at - 6) / 3][(at - 6) % 3] = v;
      if (at < 3)
        s.center[at] = v;
      else if (at == 3)
        s.radius = v;
    }
    EXPECT_EQ(is_valid(a), invalid_reason(a).empty()) << i;
    EXPECT_EQ(is_valid(o), invalid_reason(o).empty()) << i;
    EXPECT_EQ(is_valid(s), invalid_reason(s).empty()) << i;
    invalid += !is_valid(a) + !is_valid(o) + !is_valid(s);
  }
  EXPECT_GT(invalid, 1000);  // both answers were seen
  EXPECT_LT(invalid, 5500);
  // Each condition alone: unit but not orthogonal axes, a negative half extent, -0 radius and
  // half extents (valid), an inverted box, a point box (valid).
  Obb o;
  o.basis[1] = glm::normalize(glm::vec3(0.01f, 1.0f, 0.0f));  // 0.01 off orthogonal, unit length
  EXPECT_EQ(is_valid(o), invalid_reason(o).empty());
  EXPECT_FALSE(is_valid(o));
  o = Obb{};
  o.half_extents = {1.0f, -0.0f, 1.0f};
  EXPECT_TRUE(is_valid(o) && invalid_reason(o).empty());
  o.half_extents.z = -1e-30f;
  EXPECT_FALSE(is_valid(o) || invalid_reason(o).empty());
  EXPECT_TRUE(is_valid(Sphere{{0, 0, 0}, -0.0f}) && invalid_reason(Sphere{{0, 0, 0}, -0.0f}).empty());
  EXPECT_FALSE(is_valid(Aabb{{0, 0, 1}, {1, 1, 0.5f}}) || invalid_reason(Aabb{{0, 0, 1}, {1, 1, 0.5f}}).empty());
  EXPECT_TRUE(is_valid(Aabb{{1, 1, 1}, {1, 1, 1}}));
}

// ---- frusta ---------------------------------------------------------------------------------

bool inside(const Frustum& f, const glm::vec3& p) {
  for (const Plane& pl : f.active())
    if (pl.distance(p) < 0.0f) return false;
  return true;
}

void expect_normalised(const Frustum& f) {
  for (const Plane& p : f.active()) EXPECT_NEAR(glm::length(p.normal), 1.0f, 1e-6f);
}

glm::mat4 view() { return glm::lookAtRH(glm::vec3(0, 0, 10), glm::vec3(0), glm::vec3(0, 1, 0)); }

// Camera at z = 10 looking down -z; near 1, far 100, 90 degree vertical fov, aspect 2.
void expect_perspective_classification(const Frustum& f, bool finite_far) {
  expect_normalised(f);
  EXPECT_TRUE(inside(f, {0, 0, 0}));               // straight ahead
  EXPECT_TRUE(inside(f, {0, 0, 8.5f}));            // just past the near plane (z = 9)
  EXPECT_FALSE(inside(f, {0, 0, 9.5f}));           // between camera and near plane
  EXPECT_FALSE(inside(f, {0, 0, 20}));             // behind the camera
  EXPECT_TRUE(inside(f, {0, 9.5f, 0}));            // tan(45) * 10 = 10: just inside top
  EXPECT_FALSE(inside(f, {0, 10.5f, 0}));          // just outside top
  EXPECT_FALSE(inside(f, {0, -10.5f, 0}));         // outside bottom
  EXPECT_TRUE(inside(f, {19.5f, 0, 0}));           // aspect 2: half width 20 at distance 10
  EXPECT_FALSE(inside(f, {20.5f, 0, 0}));          // outside right
  EXPECT_FALSE(inside(f, {-20.5f, 0, 0}));         // outside left
  EXPECT_TRUE(inside(f, {0, 0, -89}));             // before far (distance 99)
  EXPECT_EQ(inside(f, {0, 0, -91}), !finite_far);  // beyond far (distance 101)
  EXPECT_EQ(inside(f, {0, 0, -1e6f}), !finite_far);
}

glm::mat4 flip_y(glm::mat4 p) {
  p[1][1] *= -1.0f;
  return p;
}

TEST(Frustum, PerspectiveVulkanDepthZeroToOne) {
  const glm::mat4 proj = flip_y(glm::perspectiveRH_ZO(glm::radians(90.0f), 2.0f, 1.0f, 100.0f));
  const Frustum f = Frustum::from_view_proj(proj * view());
  EXPECT_EQ(f.plane_count, 6u);
  expect_perspective_classification(f, true);
}

TEST(Frustum, ReversedZ) {
  // Reversed Z: near maps to depth 1, far to 0. Same as swapping near and far arguments.
  const glm::mat4 proj = flip_y(glm::perspectiveRH_ZO(glm::radians(90.0f), 2.0f, 100.0f, 1.0f));
  const Frustum f = Frustum::from_view_proj(proj * view());
  EXPECT_EQ(f.plane_count, 6u);
  expect_perspective_classification(f, true);
}

TEST(Frustum, InfiniteFarDropsTheFarPlane) {
  glm::mat4 proj(0.0f);  // depth = (-z - near) / -z: 0 at the near plane, 1 at infinity
  const float focal = 1.0f / std::tan(glm::radians(45.0f));
  proj[0][0] = focal / 2.0f;
  proj[1][1] = -focal;
  proj[2][2] = -1.0f;
  proj[2][3] = -1.0f;
  proj[3][2] = -1.0f;  // near = 1
  const Frustum f = Frustum::from_view_proj(proj * view());
  EXPECT_EQ(f.plane_count, 5u);
  expect_perspective_classification(f, false);
}

TEST(Frustum, ReversedZInfiniteFar) {
  glm::mat4 proj(0.0f);  // depth = near / -z_view
  const float focal = 1.0f / std::tan(glm::radians(45.0f));
  proj[0][0] = focal / 2.0f;
  proj[1][1] = -focal;
  proj[2][3] = -1.0f;
  proj[3][2] = 1.0f;  // near = 1
  const Frustum f = Frustum::from_view_proj(proj * view());
  EXPECT_EQ(f.plane_count, 5u);
  expect_perspective_classification(f, false);
}

TEST(Frustum, Orthographic) {
  const glm::mat4 proj = flip_y(glm::orthoRH_ZO(-4.0f, 4.0f, -2.0f, 2.0f, 1.0f, 30.0f));
  const Frustum f = Frustum::from_view_proj(proj * view());
  EXPECT_EQ(f.plane_count, 6u);
  expect_normalised(f);
  EXPECT_TRUE(inside(f, {3.9f, 1.9f, 0}));
  EXPECT_FALSE(inside(f, {4.1f, 0, 0}));
  EXPECT_FALSE(inside(f, {0, -2.1f, 0}));
  EXPECT_TRUE(inside(f, {0, 0, -19.9f}));   // depth 29.9
  EXPECT_FALSE(inside(f, {0, 0, -20.1f}));  // depth 30.1
  EXPECT_FALSE(inside(f, {0, 0, 9.1f}));    // depth 0.9
  // Orthographic side planes are exactly axis aligned.
  EXPECT_EQ(f.planes[0].normal, glm::vec3(1, 0, 0));
}

TEST(Frustum, RejectsBadMatrices) {
  EXPECT_THROW(Frustum::from_view_proj(glm::mat4(0.0f)), std::invalid_argument);
  glm::mat4 m = test::test_view_proj();
  m[2][1] = std::numeric_limits<float>::quiet_NaN();
  EXPECT_THROW(Frustum::from_view_proj(m), std::invalid_argument);
  glm::mat4 rank3 = test::test_view_proj();
  rank3[1] = rank3[0];  // two equal columns: singular
  EXPECT_THROW(Frustum::from_view_proj(rank3), std::invalid_argument);
}

TEST(Frustum, FromPlanesNormalisesButKeepsUnitPlanesBitExact) {
  const glm::vec4 planes[2] = {{2, 0, 0, 4}, {0.6f, 0.8f, 0, 0.1f}};
  const Frustum f = Frustum::from_planes(planes);
  EXPECT_EQ(f.plane_count, 2u);
  EXPECT_EQ(f.planes[0], (Plane{{1, 0, 0}, 2}));
  EXPECT_EQ(f.planes[1].as_vec4(), planes[1]);  // |n| = 1 within 1e-6: unchanged
  const glm::vec4 zero[1] = {{0, 0, 0, 1}};
  EXPECT_THROW(Frustum::from_planes(zero), std::invalid_argument);
  EXPECT_THROW(Frustum::from_planes(std::span<const glm::vec4>()), std::invalid_argument);
}

}  // namespace
}  // namespace cullpipe
