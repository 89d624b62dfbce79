// Hierarchies over OBBs and spheres (src/cullpipe/bvh): enclosing boxes, the node test with a margin,
// and hierarchical culling that gives every object exactly the class flat culling gives it,
// including objects exactly on the planes and scenes far from the origin.
#include <gtest/gtest.h>

#include <cmath>
#include <glm/gtc/matrix_transform.hpp>
#include <limits>
#include <string>
#include <vector>

#include "bvh_test_util.hpp"
#include "cullpipe/bvh/builders.hpp"
#include "cullpipe/bvh/bvh.hpp"
#include "cullpipe/cull/reference.hpp"
#include "test_util.hpp"

namespace cullpipe {
namespace {

template <class Volume>
void expect_matches_flat(const std::vector<Volume>& volumes, const std::vector<Frustum>& frusta,
                         const std::string& builder = "binned-sah", std::uint32_t leaf = 4) {
  bvh::BuildOptions options;
  options.max_leaf_size = leaf;
  const std::vector<Aabb> boxes = bvh::enclosing_boxes(std::span<const Volume>(volumes));
  const bvh::Tree tree = bvh::build(builder, boxes, options);
  ASSERT_EQ(bvh::check_tree(tree, boxes), "");
  test::expect_hierarchy_equals_flat(bvh::flatten(tree), volumes, frusta);
}

TEST(BvhVolumes, EnclosingBoxesContainTheVolumes) {
  test::Rng rng{5};
  for (int i = 0; i < 2000; ++i) {
    const float scale = std::pow(10.0f, rng.uniform(-30.0f, 30.0f));
    Obb b = test::random_obb(rng, 1.0f, 1.0f);
    b.center *= scale;
    b.half_extents *= scale * rng.uniform(0.0f, 2.0f);
    const Aabb box = bvh::enclosing_box(b);
    for (int c = 0; c < 8; ++c) {  // every corner, in double
      for (int j = 0; j < 3; ++j) {
        double p = b.center[j];
        for (int k = 0; k < 3; ++k)
          p += double(b.basis[k][j]) * ((c >> k & 1) ? double(b.half_extents[k]) : -double(b.half_extents[k]));
        ASSERT_LE(double(box.min[j]), p) << i;
        ASSERT_GE(double(box.max[j]), p) << i;
      }
    }
    Sphere s{b.center, b.half_extents.x};
    const Aabb sb = bvh::enclosing_box(s);
    for (int j = 0; j < 3; ++j) {
      ASSERT_LT(double(sb.min[j]), double(s.center[j]) - double(s.radius));
      ASSERT_GT(double(sb.max[j]), double(s.center[j]) + double(s.radius));
    }
  }
}

TEST(BvhVolumes, EnclosingBoxOfAnObbWhoseCentreNearlyCancelsItsExtent) {
  // x extent = (1 - 2^-20)(1 + 2^-20) + 2^-55 = 1 - 2^-40 + 2^-55: a double sum of it drops
  // the 2^-55, and the centre 1 cancels the rest, so one float step after the subtraction
  // would not cover what was dropped.
  Obb b;
  b.center = glm::vec3(1.0f, 0.0f, 0.0f);
  b.basis = glm::mat3(glm::vec3(1.0f - 0x1p-20f, 0, 0), glm::vec3(0x1p-55f, 1, 0), glm::vec3(0, 0, 1));
  b.half_extents = glm::vec3(1.0f + 0x1p-20f, 1.0f, 1.0f);
  const Aabb box = bvh::enclosing_box(b);
  if constexpr (std::numeric_limits<long double>::digits >= 64) {
    const long double extent = (1.0L - 0x1p-20L) * (1.0L + 0x1p-20L) + 0x1p-55L;  // exact in 64 bits
    EXPECT_LE(static_cast<long double>(box.min.x), 1.0L - extent);
    EXPECT_GE(static_cast<long double>(box.max.x), 1.0L + extent);
  }
  EXPECT_LT(box.min.x, 0x1p-39f);  // and still tight
}

TEST(BvhVolumes, NonUnitPlaneNormalsAreRefused) {
  // The margin's error bound takes unit normals: a half-length normal would let a node be
  // dropped while a sphere in it is visible. Boxes do not need the margin.
  const glm::vec4 planes[1] = {{0.5f, 0.0f, 0.0f, 1.0f}};
  Frustum f = Frustum::from_planes(planes);                // normalises
  f.planes[0] = Plane{glm::vec3(0.5f, 0.0f, 0.0f), 1.0f};  // hand-built, not normalised
  const std::vector<Sphere> spheres = {{glm::vec3(0), 1.0f}};
  const std::vector<Aabb> boxes = bvh::enclosing_boxes(std::span<const Sphere>(spheres));
  const bvh::FlatTree tree = bvh::flatten(bvh::build("binned-sah", boxes));
  EXPECT_THROW(bvh::cull_hierarchical(tree, std::span<const Sphere>(spheres), f), std::invalid_argument);
  EXPECT_NO_THROW(bvh::cull_hierarchical(tree, std::span<const Aabb>(boxes), f));
  EXPECT_NO_THROW(bvh::cull_hierarchical(tree, std::span<const Sphere>(spheres), Frustum::from_planes(planes)));
}

// check_flat_structure is check_flat_tree without the volumes: the same message for a broken
// tree, nothing for a bad volume (which check_flat_tree and volume_in_leaf find).
TEST(BvhVolumes, TheStructureCheckIsTheTreeCheckWithoutVolumes) {
  test::Rng rng{5};
  const test::RandomVolumes v = test::random_volumes(rng, 500, 20.0f, 2.0f);
  const bvh::FlatTree tree = bvh::flatten(bvh::build("binned-sah", bvh::enclosing_boxes(std::span<const Obb>(v.obbs))));
  const std::span<const Obb> obbs(v.obbs);
  EXPECT_EQ(bvh::check_flat_structure(tree, obbs.size()), "");
  EXPECT_EQ(bvh::check_flat_tree(tree, obbs), "");
  bvh::FlatTree twice = tree, skip = tree, range = tree, box = tree;
  twice.objects[3] = twice.objects[2];
  skip.nodes[1].skip = std::uint32_t(tree.nodes.size()) + 2;
  range.nodes[1].count += 1;
  box.nodes[0].box.max.x = std::numeric_limits<float>::infinity();
  for (const bvh::FlatTree* bad : {&twice, &skip, &range, &box}) {
    const std::string why = bvh::check_flat_structure(*bad, obbs.size());
    EXPECT_NE(why, "");
    EXPECT_EQ(why, bvh::check_flat_tree(*bad, obbs));
  }
  EXPECT_NE(bvh::check_flat_structure(tree, obbs.size() - 1), "");
  // A bad volume: the tree is fine, the volume is not.
  std::vector<Obb> moved = v.obbs;
  const std::uint32_t id = tree.objects[7];
  moved[id].center.x += 1000.0f;
  EXPECT_EQ(bvh::check_flat_structure(tree, moved.size()), "");
  EXPECT_NE(bvh::check_flat_tree(tree, std::span<const Obb>(moved)), "");
  std::size_t leaf = 0;
  while (!(tree.nodes[leaf].leaf && tree.nodes[leaf].first <= 7 && 7 < tree.nodes[leaf].first + tree.nodes[leaf].count))
    ++leaf;
  EXPECT_TRUE(bvh::volume_in_leaf(tree.nodes[leaf].box, v.obbs[id]));
  EXPECT_FALSE(bvh::volume_in_leaf(tree.nodes[leaf].box, moved[id]));
  Sphere nan_sphere = v.spheres[0];
  nan_sphere.radius = std::numeric_limits<float>::quiet_NaN();
  EXPECT_FALSE(bvh::volume_in_leaf(Aabb{glm::vec3(-1e30f), glm::vec3(1e30f)}, nan_sphere));
  EXPECT_TRUE(bvh::volume_in_leaf(Aabb{glm::vec3(-1e30f), glm::vec3(1e30f)}, v.spheres[0]));
}

TEST(BvhVolumes, RandomObbsAndSpheresMatchFlat) {
  test::Rng rng{11};
  const std::vector<Frustum> frusta = {Frustum::from_view_proj(test::test_view_proj()),
                                       Frustum::from_view_proj(test::test_view_proj(100.0f, 0.5f)),
                                       Frustum::from_view_proj(test::test_view_proj(15.0f, 1.0f))};
  for (std::size_t n : {0u, 1u, 2u, 5u, 100u, 3000u}) {
    const test::RandomVolumes v = test::random_volumes(rng, n, 30.0f, 3.0f);
    for (const char* builder : {"binned-sah", "agglomerative-local", "insertion-greedy"}) {
      SCOPED_TRACE(std::string(builder) + ", n = " + std::to_string(n));
      expect_matches_flat(v.obbs, frusta, builder);
      expect_matches_flat(v.spheres, frusta, builder);
    }
    expect_matches_flat(v.spheres, frusta, "binned-sah", 1);
    expect_matches_flat(v.obbs, frusta, "binned-sah", 16);
  }
}

// Volumes touching the planes near the origin and 10^5 away from it; far away there must be
// some that a margin-free node test would misjudge, or the test would not be sharp.
TEST(BvhVolumes, VolumesTouchingThePlanesMatchFlat) {
  test::Rng rng{23};
  for (const glm::vec3 eye :
       {glm::vec3(0, 0, 10), glm::vec3(1.0e5f, -3.0e4f, 2.0e5f), glm::vec3(-4.0e4f, 7.0e4f, -9.0e4f)}) {
    const Frustum f = test::frustum_at(eye);
    const test::TouchingVolumes set = test::touching_volumes(f, eye, rng, 40000);
    SCOPED_TRACE("eye " + std::to_string(eye.x) + ", " + std::to_string(eye.y) + ", " + std::to_string(eye.z) + ": " +
                 std::to_string(set.contradicting) + " volumes a margin-free node test would misjudge");
    if (eye.x != 0.0f) {
      EXPECT_GT(set.contradicting, 0u);
    }
    for (std::uint32_t leaf : {1u, 4u}) {
      expect_matches_flat(set.spheres, {f}, "binned-sah", leaf);
      expect_matches_flat(set.obbs, {f}, "binned-sah", leaf);
    }
  }
}

TEST(BvhVolumes, TheMarginKeepsTheHierarchyUseful) {
  // A narrow view of many volumes: few nodes and objects are tested, as for boxes.
  test::Rng rng{31};
  const test::RandomVolumes v = test::random_volumes(rng, 20000, 100.0f, 1.0f);
  const Frustum f = Frustum::from_view_proj(test::test_view_proj(10.0f, 1.0f));
  const bvh::FlatTree spheres =
      bvh::flatten(bvh::build("binned-sah", bvh::enclosing_boxes(std::span<const Sphere>(v.spheres))));
  const bvh::FlatTree boxes = bvh::flatten(bvh::build("binned-sah", v.aabbs));
  const bvh::HierarchicalResult hs = bvh::cull_hierarchical(spheres, std::span<const Sphere>(v.spheres), f);
  const bvh::HierarchicalResult hb = bvh::cull_hierarchical(boxes, std::span<const Aabb>(v.aabbs), f);
  EXPECT_LT(hs.object_tests, v.spheres.size() / 20);
  EXPECT_LT(hs.node_tests, 3 * hb.node_tests);
}

TEST(BvhVolumes, AnOverflowingMarginDecidesNothing) {
  // Coordinates near FLT_MAX: the margin overflows, so no plane is decided at the node; the
  // objects are tested themselves.
  const float big = std::numeric_limits<float>::max() * 0.75f;
  const Aabb huge{glm::vec3(-big), glm::vec3(big)};
  const Frustum f = Frustum::from_view_proj(test::test_view_proj());
  std::uint32_t straddled = 0;
  const std::uint32_t all = (1u << f.plane_count) - 1u;
  EXPECT_EQ(bvh::classify_masked_margin(huge, f, all, straddled), Classification::Intersecting);
  EXPECT_EQ(straddled, all);
  const Aabb far_away{glm::vec3(big * 0.9f), glm::vec3(big)};
  EXPECT_EQ(bvh::classify_masked_margin(far_away, f, all, straddled), Classification::Intersecting);
  // Past 2^120 (before any overflow) nothing is decided either.
  const Aabb beyond{glm::vec3(0x1p121f), glm::vec3(0x1p122f)};
  EXPECT_EQ(bvh::classify_masked_margin(beyond, f, all, straddled), Classification::Intersecting);
  EXPECT_EQ(straddled, all);
  // Ordinary boxes are still decided.
  const Aabb behind{glm::vec3(-1, -1, 20), glm::vec3(1, 1, 22)};
  EXPECT_EQ(bvh::classify_masked_margin(behind, f, all, straddled), Classification::Outside);
}

}  // namespace
}  // namespace cullpipe
