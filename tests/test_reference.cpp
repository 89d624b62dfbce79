#include <gtest/gtest.h>

#include "cullpipe/cull/compare.hpp"
#include "cullpipe/cull/reference.hpp"
#include "test_util.hpp"

namespace cullpipe {
namespace {

using reference::classify;
using reference::classify_corners;
using reference::classify_pn;
constexpr Classification kOut = Classification::Outside, kIn = Classification::Inside,
                         kCross = Classification::Intersecting;

// The axis-aligned cube [-1, 1]^3 as six inward planes.
Frustum unit_cube() {
  const glm::vec4 planes[6] = {{1, 0, 0, 1}, {-1, 0, 0, 1}, {0, 1, 0, 1}, {0, -1, 0, 1}, {0, 0, 1, 1}, {0, 0, -1, 1}};
  return Frustum::from_planes(planes);
}

TEST(Reference, KnownAnswersAgainstACube) {
  const Frustum f = unit_cube();
  EXPECT_EQ(classify_pn({{-0.5f, -0.5f, -0.5f}, {0.5f, 0.5f, 0.5f}}, f), kIn);
  EXPECT_EQ(classify_pn({{-1, -1, -1}, {1, 1, 1}}, f), kIn);  // touching from inside counts as inside
  EXPECT_EQ(classify_pn({{2, 0, 0}, {3, 1, 1}}, f), kOut);
  EXPECT_EQ(classify_pn({{0.5f, 0, 0}, {1.5f, 0.5f, 0.5f}}, f), kCross);
  EXPECT_EQ(classify_pn({{1, 0, 0}, {2, 0, 0}}, f), kCross);     // touching from outside: not culled
  EXPECT_EQ(classify_pn({{-5, -5, -5}, {5, 5, 5}}, f), kCross);  // encloses the frustum

  EXPECT_EQ(classify(Sphere{{0, 0, 0}, 0.5f}, f), kIn);
  EXPECT_EQ(classify(Sphere{{1.2f, 0, 0}, 0.1f}, f), kOut);
  EXPECT_EQ(classify(Sphere{{1, 0, 0}, 0.5f}, f), kCross);
  EXPECT_EQ(classify(Sphere{{0, 0, 0}, 0.0f}, f), kIn);

  const float c = std::sqrt(0.5f);
  Obb rotated;  // square rotated 45 degrees about z: reaches 0.5*sqrt(2) along x and y
  rotated.basis = glm::mat3(glm::vec3(c, c, 0), glm::vec3(-c, c, 0), glm::vec3(0, 0, 1));
  rotated.half_extents = {0.5f, 0.5f, 0.5f};
  EXPECT_EQ(classify(rotated, f), kIn);
  rotated.center = {1.5f, 0, 0};  // reaches x = 1.5 - 0.707 < 1: crosses the plane x = 1
  EXPECT_EQ(classify(rotated, f), kCross);
  rotated.center = {1.8f, 0, 0};  // 1.8 - 0.707 > 1: outside
  EXPECT_EQ(classify(rotated, f), kOut);
}

TEST(Reference, PnVertexTestEqualsEightCornerTest) {
  test::Rng rng{42};
  const Frustum frusta[] = {Frustum::from_view_proj(test::test_view_proj()), unit_cube(),
                            Frustum::from_view_proj(test::test_view_proj(100.0f, 0.5f))};
  std::size_t counts[3] = {0, 0, 0};
  for (const Frustum& f : frusta)
    for (int i = 0; i < 100000; ++i) {
      const Aabb box = test::random_aabb(rng, 30.0f, i % 3 == 0 ? 0.0f : 8.0f);
      const Classification pn = classify_pn(box, f), corners = classify_corners(box, f);
      ASSERT_EQ(pn, corners) << describe(box) << " frustum " << describe(f);
      ++counts[std::size_t(pn)];
    }
  // The random set exercises all three answers.
  EXPECT_GT(counts[0], 1000u);
  EXPECT_GT(counts[1], 1000u);
  EXPECT_GT(counts[2], 1000u);
}

// Conservativeness: an exact separating-axis test in double finds the volume overlapping the
// frustum by more than `margin`: then the reference must not say OUTSIDE. And every INSIDE
// volume has all its points inside every plane (within rounding).
constexpr double kMargin = 1e-4;

// Checks one box against the exact test; counts boxes that truly overlap and boxes the
// plane test keeps although they are disjoint (conservative false positives).
void check_box(const Obb& box, Classification c, const Frustum& f, int& exact_hits, int& false_positives) {
  const std::array<test::dvec3, 3> dirs = {test::dvec3(box.basis[0]), test::dvec3(box.basis[1]),
                                           test::dvec3(box.basis[2])};
  if (test::frustum_box_intersect(f, test::corners_d(box, kMargin), dirs)) {
    ++exact_hits;
    ASSERT_NE(c, kOut) << describe(box) << " overlaps the frustum " << describe(f);
  }
  if (c == kIn) {
    for (const auto& p : test::corners_d(box)) ASSERT_GE(test::min_plane_distance(f, p), -1e-5) << describe(box);
  }
  const bool touches = test::frustum_box_intersect(f, test::corners_d(box), dirs);
  if (c == kOut) {
    ASSERT_FALSE(touches) << describe(box);
  }
  if (c == kCross && !touches) ++false_positives;
}

TEST(Reference, AabbIsConservative) {
  test::Rng rng{1};
  const Frustum f = Frustum::from_view_proj(test::test_view_proj());
  int exact_hits = 0, false_positives = 0;
  for (int i = 0; i < 50000; ++i) {
    const Aabb box = test::random_aabb(rng, 40.0f, 6.0f);
    Obb as_obb;  // the same box, for the exact test (identity basis, exact centre and extents)
    as_obb.center = box.center();
    as_obb.half_extents = box.half_extent();
    check_box(as_obb, classify_pn(box, f), f, exact_hits, false_positives);
    if (HasFatalFailure()) return;
  }
  EXPECT_GT(exact_hits, 5000);
}

TEST(Reference, ObbIsConservative) {
  test::Rng rng{2};
  const Frustum f = Frustum::from_view_proj(test::test_view_proj());
  int exact_hits = 0, false_positives = 0;
  for (int i = 0; i < 50000; ++i) {
    const Obb box = test::random_obb(rng, 40.0f, 6.0f);
    check_box(box, classify(box, f), f, exact_hits, false_positives);
    if (HasFatalFailure()) return;
  }
  EXPECT_GT(exact_hits, 5000);
  // The plane test is conservative, not exact: some disjoint boxes near frustum edges remain.
  EXPECT_GT(false_positives, 0);
}

TEST(Reference, SphereIsConservative) {
  test::Rng rng{3};
  const Frustum f = Frustum::from_view_proj(test::test_view_proj());
  int exact_hits = 0;
  for (int i = 0; i < 50000; ++i) {
    const Sphere s = test::random_sphere(rng, 40.0f, 6.0f);
    const Classification c = classify(s, f);
    const double dist = test::frustum_point_distance(f, test::dvec3(s.center));
    if (dist < double(s.radius) - kMargin) {
      ++exact_hits;
      ASSERT_NE(c, kOut) << describe(s) << " at distance " << dist << " from " << describe(f);
    }
    if (c == kOut) {
      ASSERT_GT(dist, double(s.radius) - 1e-5) << describe(s);
    }
    if (c == kIn) {
      // Every point of the sphere: the centre's plane distances all at least the radius.
      ASSERT_GE(test::min_plane_distance(f, test::dvec3(s.center)), double(s.radius) - 1e-5) << describe(s);
    }
  }
  EXPECT_GT(exact_hits, 5000);
}

// Zero-area frusta: a zero field of view, near == far, or a zero-width orthographic box make
// a singular or non-finite matrix, which Frustum::from_view_proj refuses. A sliver (a field of
// view of 1e-4 degrees) is a valid frustum; it keeps what lies on its axis and stays
// conservative.
TEST(Reference, ZeroAreaFrustaAreRefusedAndSliversStayConservative) {
  auto flip = [](glm::mat4 p) {
    p[1][1] *= -1.0f;
    return p;
  };
  const glm::mat4 view = glm::lookAtRH(glm::vec3(0, 0, 10), glm::vec3(0), glm::vec3(0, 1, 0));
  EXPECT_THROW(Frustum::from_view_proj(flip(glm::perspectiveRH_ZO(0.0f, 1.5f, 0.5f, 50.0f)) * view),
               std::invalid_argument);
  EXPECT_THROW(Frustum::from_view_proj(flip(glm::perspectiveRH_ZO(1.0f, 1.5f, 5.0f, 5.0f)) * view),
               std::invalid_argument);
  EXPECT_THROW(Frustum::from_view_proj(glm::orthoRH_ZO(2.0f, 2.0f, -1.0f, 1.0f, 0.5f, 50.0f) * view),
               std::invalid_argument);
  const Frustum sliver =
      Frustum::from_view_proj(flip(glm::perspectiveRH_ZO(glm::radians(1e-4f), 1.0f, 0.5f, 50.0f)) * view);
  EXPECT_EQ(classify_pn(Aabb{{-0.1f, -0.1f, -1}, {0.1f, 0.1f, 1}}, sliver), kCross);  // on the axis
  EXPECT_EQ(classify_pn(Aabb{{1, 1, -1}, {2, 2, 1}}, sliver), kOut);
  test::Rng rng{5};
  int exact_hits = 0, false_positives = 0;
  for (int i = 0; i < 20000; ++i) {
    Obb box = test::random_obb(rng, 3.0f, 1.0f);
    check_box(box, classify(box, sliver), sliver, exact_hits, false_positives);
    if (HasFatalFailure()) return;
  }
  EXPECT_GT(exact_hits, 10);
}

TEST(Reference, ClassifyAllCountsAndChecksSizes) {
  const Frustum f = unit_cube();
  const std::vector<Sphere> spheres = {{{0, 0, 0}, 0.1f}, {{5, 0, 0}, 1}, {{1, 0, 0}, 0.5f}, {{0, 0.5f, 0}, 0.2f}};
  std::vector<Classification> out(spheres.size());
  const reference::CullCounts counts = reference::classify_all(spheres, f, out);
  EXPECT_EQ(counts, (reference::CullCounts{3, 2, 1}));
  EXPECT_EQ(out, (std::vector<Classification>{kIn, kOut, kCross, kIn}));
  std::vector<Classification> wrong(1);
  EXPECT_THROW(reference::classify_all(spheres, f, wrong), std::invalid_argument);
}

TEST(Compare, ReportsTheFirstMismatchAndCounts) {
  const std::vector<Classification> a = {kIn, kOut, kCross}, b = {kIn, kCross, kCross};
  EXPECT_EQ(first_mismatch(a, a), npos);
  EXPECT_EQ(first_mismatch(a, b), 1u);
  EXPECT_EQ(count_mismatches(a, b), 1u);
  EXPECT_EQ(count_mismatches(a, std::vector<Classification>{kIn}), 2u);
  const std::string report = describe_mismatch(7, Aabb{{0, 0, 0}, {1, 2, 3}}, unit_cube(), kIn, kOut);
  EXPECT_NE(report.find("object 7"), std::string::npos);
  EXPECT_NE(report.find("aabb min (0, 0, 0) max (1, 2, 3)"), std::string::npos);
  EXPECT_NE(report.find("[1, 0, 0, 1]"), std::string::npos);
  EXPECT_NE(report.find("cpu says inside, gpu says outside"), std::string::npos);
}

TEST(Compare, AgreementCheckCatchesEveryKindOfDifference) {
  const Frustum f = unit_cube();
  const std::vector<Sphere> spheres = {{{0, 0, 0}, 0.1f}, {{5, 0, 0}, 1}, {{1, 0, 0}, 0.5f}};
  std::vector<Classification> cpu(3);
  const reference::CullCounts counts = reference::classify_all(spheres, f, cpu);
  const std::vector<std::uint32_t> ids = {2, 0};
  EXPECT_TRUE(check_agreement<Sphere>(spheres, f, cpu, counts, cpu, counts, ids, 3).ok());

  std::vector<Classification> wrong = cpu;  // one class flipped
  wrong[1] = kCross;
  const Agreement a =
      check_agreement<Sphere>(spheres, f, cpu, counts, wrong, counts, ids, 3, 10, std::vector<std::size_t>{10, 11, 12});
  EXPECT_EQ(a.mismatches, 1u);
  ASSERT_EQ(a.reports.size(), 1u);
  EXPECT_NE(a.reports[0].find("object 11: sphere center (5, 0, 0) radius 1"), std::string::npos) << a.reports[0];
  EXPECT_NE(a.reports[0].find("[1, 0, 0, 1]"), std::string::npos);
  EXPECT_NE(a.reports[0].find("cpu says outside, gpu says intersecting"), std::string::npos);

  reference::CullCounts bad_counts = counts;
  ++bad_counts.inside;
  EXPECT_EQ(check_agreement<Sphere>(spheres, f, cpu, counts, cpu, bad_counts, ids, 3).mismatches, 1u);
  const std::vector<std::uint32_t> duplicate = {2, 2}, missing = {2}, extra = {0, 1, 2};
  EXPECT_FALSE(check_agreement<Sphere>(spheres, f, cpu, counts, cpu, counts, duplicate, 3).ok());
  EXPECT_FALSE(check_agreement<Sphere>(spheres, f, cpu, counts, cpu, counts, missing, 3).ok());
  EXPECT_FALSE(check_agreement<Sphere>(spheres, f, cpu, counts, cpu, counts, extra, 3).ok());
  // With room for one id, any one visible object is a correct (overflowed) list.
  EXPECT_TRUE(check_agreement<Sphere>(spheres, f, cpu, counts, cpu, counts, missing, 1).ok());
  EXPECT_FALSE(check_agreement<Sphere>(spheres, f, cpu, counts, cpu, counts, std::vector<std::uint32_t>{1}, 1).ok());
}

}  // namespace
}  // namespace cullpipe
