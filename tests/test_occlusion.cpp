// The depth pyramid and the scalar occlusion test: the pyramid against brute force for every
// size, and the test against ray-cast ground truth (an object with a pixel whose depth passes
// the depth test is never occluded), over random scenes, cameras and viewports.
#include <gtest/gtest.h>

#include <cmath>
#include <glm/mat4x4.hpp>
#include <limits>
#include <optional>
#include <vector>

#include "cullpipe/bvh/builders.hpp"
#include "cullpipe/cull/compare.hpp"
#include "cullpipe/cull/depth_pyramid.hpp"
#include "cullpipe/cull/occlusion.hpp"
#include "cullpipe/cull/software_depth.hpp"
#include "cullpipe/scene/camera.hpp"
#include "occlusion_test_util.hpp"
#include "test_util.hpp"

namespace cullpipe {
namespace {

using occlusion::DepthPyramid;
using occlusion::Footprint;
using occlusion::OcclusionOptions;
using occlusion::OcclusionView;
using test::cast;
using test::Caster;
using test::random_camera;
using test::random_volume;
using test::Ray;
using test::render_depth;

TEST(DepthPyramid, LevelsHalveDownToOnePixel) {
  const auto levels = occlusion::pyramid_levels(960, 540);
  ASSERT_EQ(levels.size(), 10u);  // 960x540, 480x270, 240x135, 120x67, 60x33, 30x16, 15x8, 7x4, 3x2, 1x1
  EXPECT_EQ(levels[3], (occlusion::PyramidLevel{120, 67, 960 * 540 + 480 * 270 + 240 * 135}));
  EXPECT_EQ(levels[8].width, 3u);
  EXPECT_EQ(levels[8].height, 2u);
  EXPECT_EQ(occlusion::pyramid_levels(1, 1).size(), 1u);
  EXPECT_EQ(occlusion::pyramid_levels(1, 7).size(), 3u);  // 1x7, 1x3, 1x1
  EXPECT_THROW(occlusion::pyramid_levels(0, 5), std::invalid_argument);
  EXPECT_THROW(occlusion::build_depth_pyramid(std::vector<float>(6), 2, 2, false), std::invalid_argument);
}

// Every texel holds exactly the farthest depth of the pixels it covers (texel_of's rule), for
// odd, even, thin and one-pixel sizes: conservative and no looser than it must be.
// A unorm value q lets through fragments up to (q + 1) / N (q - 1 reversed): the pyramid's float
// for it is at least that far, and at most four float steps beyond, for every 16-bit value and
// for 24-bit values at the ends and at random. It fails if a step of the rounding is taken out.
TEST(DepthPyramid, UnormDepthFloatsBoundWhatTheyLetThrough) {
  auto check = [](std::uint32_t q, unsigned bits) {
    const double n = double((1u << bits) - 1u);
    const float far = occlusion::unorm_depth_float(q, bits, false), rev = occlusion::unorm_depth_float(q, bits, true);
    const double far_bound = (double(q) + 1.0) / n, rev_bound = (double(q) - 1.0) / n;
    ASSERT_GE(double(far), far_bound) << bits << " bits, q " << q;
    ASSERT_LE(double(rev), rev_bound) << bits << " bits, q " << q << " reversed";
    ASSERT_LE(double(far), far_bound * (1.0 + 0x1p-21)) << bits << " bits, q " << q;
    ASSERT_GE(double(rev), rev_bound - std::abs(rev_bound) * 0x1p-21 - 1e-30) << bits << " bits, q " << q;
  };
  for (std::uint32_t q = 0; q <= 0xffffu; ++q) {
    check(q, 16);
    if (::testing::Test::HasFatalFailure()) return;
  }
  test::Rng rng(3);
  for (std::uint32_t q : {0u, 1u, 2u, 3u, 0xfffffeu, 0xffffffu, 0x800000u, 0x7fffffu}) check(q, 24);
  for (int i = 0; i < 200000; ++i) check(std::uint32_t(rng.next() % 0x1000000u), 24);
  EXPECT_EQ(occlusion::unorm_depth_float(0x12345678u, 24, false), occlusion::unorm_depth_float(0x345678u, 24, false));
  EXPECT_THROW(occlusion::unorm_depth_float(0, 32, false), std::invalid_argument);
}

TEST(DepthPyramid, EveryTexelIsTheFarthestOfThePixelsItCovers) {
  test::Rng rng(7);
  std::vector<std::pair<std::uint32_t, std::uint32_t>> sizes = {{1, 1}, {1, 2}, {2, 1},  {3, 3},   {5, 1},  {1, 9},
                                                                {7, 5}, {8, 8}, {17, 6}, {31, 33}, {64, 3}, {100, 67}};
  for (int i = 0; i < 20; ++i)
    sizes.push_back({1 + std::uint32_t(rng.next() % 70), 1 + std::uint32_t(rng.next() % 70)});
  for (const bool reversed : {false, true})
    for (const auto& [w, h] : sizes) {
      std::vector<float> depth(std::size_t(w) * h);
      for (float& d : depth) d = rng.uniform();
      const DepthPyramid p = occlusion::build_depth_pyramid(depth, w, h, reversed);
      for (unsigned k = 0; k < p.levels.size(); ++k) {
        const auto& level = p.levels[k];
        std::vector<float> expected(std::size_t(level.width) * level.height, reversed ? 2.0f : -1.0f);
        for (std::uint32_t y = 0; y < h; ++y)
          for (std::uint32_t x = 0; x < w; ++x) {
            float& e = expected[std::size_t(occlusion::texel_of(y, k, level.height)) * level.width +
                                occlusion::texel_of(x, k, level.width)];
            const float d = depth[std::size_t(y) * w + x];
            e = reversed ? std::min(e, d) : std::max(e, d);
          }
        for (std::uint32_t y = 0; y < level.height; ++y)
          for (std::uint32_t x = 0; x < level.width; ++x)
            ASSERT_EQ(p.at(k, x, y), expected[std::size_t(y) * level.width + x])
                << w << "x" << h << (reversed ? " reversed" : "") << ", level " << k << ", texel " << x << "," << y;
      }
    }
}

/// Whether some pixel's centre sees `v` at a depth that passes the test against `depth`
/// (`owns`), and whether some pixel's centre sees it at all (`covers`).
template <class Volume>
void pixels_of(const Caster& k, const std::vector<float>& depth, const Volume& v, bool& owns, bool& covers) {
  owns = covers = false;
  for (std::uint32_t y = 0; y < k.height; ++y)
    for (std::uint32_t x = 0; x < k.width; ++x)
      if (const auto hit = cast(k, k.ray(x, y), v)) {
        covers = true;
        const double stored = depth[std::size_t(y) * k.width + x];
        if (k.reversed ? *hit > stored : *hit < stored) {
          owns = true;
          return;
        }
      }
}

template <class Volume>
void expect_conservative(std::uint64_t seed, int scenes) {
  std::size_t tested = 0, hidden = 0, culled = 0, refined_more = 0;
  test::Rng rng(seed);
  for (int s = 0; s < scenes; ++s) {
    const Camera cam = random_camera(rng, s % 8);
    const std::uint32_t w = 8 + std::uint32_t(rng.next() % 57), h = 8 + std::uint32_t(rng.next() % 41);
    const glm::mat4 vp = cam.view_proj();
    const Caster k(vp, w, h, cam.reversed_z);
    std::vector<Volume> occluders;
    for (int i = 0; i < 6; ++i) occluders.push_back(random_volume<Volume>(rng, 8.0f, 6.0f));
    const std::vector<float> depth = render_depth(k, occluders);
    const DepthPyramid pyramid = occlusion::build_depth_pyramid(depth, w, h, cam.reversed_z);
    const OcclusionView view{vp, w, h, cam.reversed_z};
    const Frustum frustum = Frustum::from_view_proj(vp);
    for (int i = 0; i < 40; ++i) {
      const Volume v = random_volume<Volume>(rng, 12.0f, 2.0f);
      bool owns, covers;
      pixels_of(k, depth, v, owns, covers);
      // Refined: hidden exactly where either test alone hides it.
      const auto hides = [&](const OcclusionOptions& o) {
        return occlusion::classify(v, frustum, view, pyramid, o) == Classification::Occluded;
      };
      const bool coarse = hides({4}), fine = hides({16}), refined = hides({4, 16});
      EXPECT_EQ(refined, coarse || fine) << "scene " << s << ", volume " << i;
      refined_more += refined && !coarse;
      for (const OcclusionOptions options : {OcclusionOptions{2}, OcclusionOptions{4}, OcclusionOptions{8},
                                             OcclusionOptions{16}, OcclusionOptions{2, 16}, OcclusionOptions{4, 8}}) {
        const std::uint32_t texels = options.texels_per_axis;
        const Classification c = occlusion::classify(v, frustum, view, pyramid, options);
        ++tested;
        hidden += covers && !owns;  // seen by some pixel centre, behind the depth at every one
        culled += c == Classification::Occluded;
        if (owns) {
          ASSERT_NE(c, Classification::Occluded)
              << "scene " << s << " (camera variant " << s % 8 << ", " << w << "x" << h << "), volume " << i << ", "
              << texels << " texels per axis (refined at " << options.refine_texels_per_axis
              << "): owns a pixel but was found occluded";
        }
      }
    }
  }
  // (It also culls most of the volumes that some pixel centre sees and every one sees hidden: a
  // test that never culls would pass the check above.)
  EXPECT_GT(culled, hidden / 2) << culled << " of " << hidden << " hidden";
  EXPECT_GT(refined_more, 0u) << "no volume that only the refining test hides";
  std::printf("%zu volume tests, %zu seen and hidden, %zu occluded\n", tested, hidden, culled);
}

// Hierarchical occlusion against the flat test: the same class for every object, whatever the
// leaf size, texel count and traversal; and nodes found occluded spare their objects' tests.
template <class Volume>
void expect_hierarchy_equals_flat(std::uint64_t seed, int scenes) {
  test::Rng rng(seed);
  std::size_t kept = 0, tests = 0, occluded = 0;
  for (int s = 0; s < scenes; ++s) {
    const Camera cam = random_camera(rng, s % 8);
    const std::uint32_t w = 16 + std::uint32_t(rng.next() % 81), h = 16 + std::uint32_t(rng.next() % 61);
    const glm::mat4 vp = cam.view_proj();
    const Caster k(vp, w, h, cam.reversed_z);
    std::vector<Volume> objects;
    for (int i = 0; i < 6; ++i) objects.push_back(random_volume<Volume>(rng, 8.0f, 6.0f));
    const std::vector<float> depth = render_depth(k, objects);  // the first six occlude
    for (int i = 0; i < 400; ++i) objects.push_back(random_volume<Volume>(rng, 12.0f, 1.0f));
    const DepthPyramid pyramid = occlusion::build_depth_pyramid(depth, w, h, cam.reversed_z);
    const OcclusionView view{vp, w, h, cam.reversed_z};
    const Frustum frustum = Frustum::from_view_proj(vp);
    const std::vector<Aabb> boxes = bvh::enclosing_boxes(std::span<const Volume>(objects));
    for (const std::uint32_t leaf : {1u, 4u}) {
      const bvh::FlatTree tree = bvh::flatten(bvh::build_binned_sah(boxes, {leaf, 16}));
      for (const std::uint32_t texels : {2u, 4u, 8u, 16u}) {
        std::vector<Classification> flat(objects.size());
        const reference::CullCounts counts =
            occlusion::classify_all(std::span<const Volume>(objects), frustum, view, pyramid, {texels}, flat);
        for (const std::uint32_t range : {0u, 8u}) {
          const bvh::HierarchicalResult r = occlusion::cull_hierarchical(
              tree, std::span<const Volume>(objects), frustum, view, pyramid, {texels}, bvh::TraversalOptions{range});
          for (std::size_t i = 0; i < objects.size(); ++i)
            ASSERT_EQ(r.classes[i], flat[i])
                << "scene " << s << " (camera variant " << s % 8 << ", " << w << "x" << h << "), leaves of " << leaf
                << ", " << texels << " texels per axis, range_objects " << range << ": object " << i << " "
                << describe(objects[i]) << ", view-projection row 0 " << vp[0][0] << " " << vp[1][0] << " " << vp[2][0]
                << " " << vp[3][0] << "; hierarchy says " << to_string(r.classes[i]) << ", flat says "
                << to_string(flat[i]);
          EXPECT_EQ(r.occluded, counts.occluded);
          EXPECT_EQ(r.visible, counts.visible);
          kept += counts.visible + counts.occluded;
          occluded += counts.occluded;
          tests += r.occlusion_tests;
        }
      }
    }
  }
  EXPECT_GT(occluded, kept / 10) << occluded << " of " << kept << " kept by the frusta";
  std::printf("%zu objects kept by the frusta, %zu occluded, %zu occlusion tests in the hierarchy\n", kept, occluded,
              tests);
}

TEST(HierarchicalOcclusion, BoxClassesEqualTheFlatTest) { expect_hierarchy_equals_flat<Aabb>(21, 24); }
TEST(HierarchicalOcclusion, ObbClassesEqualTheFlatTest) { expect_hierarchy_equals_flat<Obb>(22, 24); }
TEST(HierarchicalOcclusion, SphereClassesEqualTheFlatTest) { expect_hierarchy_equals_flat<Sphere>(23, 24); }

// Behind a wall filling the view, a grid of boxes is hidden by a few node tests: the hierarchy
// makes far fewer occlusion tests than there are boxes, and the classes still equal the flat's.
TEST(HierarchicalOcclusion, OccludedNodesSpareTheirObjectsTests) {
  Camera cam;
  cam.eye = {0, 0, 10};
  cam.target = {0, 0, 0};
  cam.aspect = 1.0f;
  const glm::mat4 vp = cam.view_proj();
  const std::uint32_t w = 64, h = 64;
  const Caster k(vp, w, h, false);
  const std::vector<Aabb> wall = {{{-100, -100, -1}, {100, 100, 0}}};
  const DepthPyramid pyramid = occlusion::build_depth_pyramid(render_depth(k, wall), w, h, false);
  const OcclusionView view{vp, w, h, false};
  const Frustum frustum = Frustum::from_view_proj(vp);
  std::vector<Aabb> boxes;
  for (int x = 0; x < 20; ++x)
    for (int y = 0; y < 20; ++y)
      for (int z = 0; z < 5; ++z) {
        const glm::vec3 c(float(x) - 9.5f, float(y) - 9.5f, -3.0f - 2.0f * float(z));
        boxes.push_back({c - 0.3f, c + 0.3f});
      }
  const bvh::FlatTree tree = bvh::flatten(bvh::build_binned_sah(boxes, {4, 16}));
  std::vector<Classification> flat(boxes.size());
  const reference::CullCounts counts =
      occlusion::classify_all(std::span<const Aabb>(boxes), frustum, view, pyramid, {}, flat);
  const bvh::HierarchicalResult r =
      occlusion::cull_hierarchical(tree, std::span<const Aabb>(boxes), frustum, view, pyramid);
  EXPECT_EQ(r.classes, flat);
  EXPECT_EQ(counts.visible, 0u);
  EXPECT_GT(counts.occluded, boxes.size() / 2);
  EXPECT_LT(r.occlusion_tests, boxes.size() / 20) << r.occlusion_tests << " occlusion tests";
}

// A NaN depth occludes nothing, at any level: every texel above it is NaN, so a node over it is
// not hidden where an object reading it is kept, and the two walks still agree.
TEST(HierarchicalOcclusion, ANanTexelHidesNothingAtAnyLevel) {
  const std::uint32_t w = 64, h = 64;
  std::vector<float> depth(std::size_t(w) * h, 0.0f);  // the nearest depth everywhere
  depth[31 * w + 31] = std::numeric_limits<float>::quiet_NaN();
  const DepthPyramid pyramid = occlusion::build_depth_pyramid(depth, w, h, false);
  for (unsigned k = 0; k < pyramid.levels.size(); ++k) {
    const auto& level = pyramid.levels[k];
    EXPECT_TRUE(
        std::isnan(pyramid.at(k, occlusion::texel_of(31, k, level.width), occlusion::texel_of(31, k, level.height))))
        << "level " << k;
  }
  Camera cam;
  cam.eye = {0, 0, 10};
  cam.target = {0, 0, 0};
  cam.aspect = 1.0f;
  const glm::mat4 vp = cam.view_proj();
  const OcclusionView view{vp, w, h, false};
  const Frustum frustum = Frustum::from_view_proj(vp);
  std::vector<Aabb> boxes;
  for (int x = 0; x < 16; ++x)
    for (int y = 0; y < 16; ++y) {
      const glm::vec3 c(float(x) - 8.0f, float(y) - 8.0f, -2.0f);
      boxes.push_back({c - 0.2f, c + 0.2f});
    }
  std::vector<Classification> flat(boxes.size());
  const reference::CullCounts counts =
      occlusion::classify_all(std::span<const Aabb>(boxes), frustum, view, pyramid, {}, flat);
  EXPECT_GT(counts.visible, 0u);  // the boxes over the NaN pixel
  EXPECT_GT(counts.occluded, counts.visible);
  for (const std::uint32_t leaf : {1u, 4u}) {
    const bvh::FlatTree tree = bvh::flatten(bvh::build_binned_sah(boxes, {leaf, 16}));
    EXPECT_EQ(occlusion::cull_hierarchical(tree, std::span<const Aabb>(boxes), frustum, view, pyramid).classes, flat)
        << "leaves of " << leaf;
  }
}

// The software depth against ray-cast ground truth: at every pixel centre the ray-cast depth of
// the occluder boxes is no farther than the software depth of the buffer pixel covering it, for
// buffers of the viewport's size and smaller, every kind of camera; and it covers something.
TEST(SoftwareDepth, NeverNearerThanTheRayCastDepth) {
  test::Rng rng(41);
  std::size_t covered[8] = {};  // pixels written, per camera variant
  for (int s = 0; s < 1600; ++s) {
    const Camera cam = random_camera(rng, s % 8);
    const std::uint32_t w = 16 + std::uint32_t(rng.next() % 81), h = 16 + std::uint32_t(rng.next() % 61);
    const glm::mat4 vp = cam.view_proj();
    const Caster k(vp, w, h, cam.reversed_z);
    std::vector<Obb> boxes;
    for (int i = 0; i < 6; ++i) boxes.push_back(random_volume<Obb>(rng, 8.0f, 6.0f));
    // Every fourth scene also a plate thin to rounding level, a flat box and a thin sheet: faces
    // seen edge on and planes from near-singular solves.
    if (s % 4 == 0) {
      for (int i = 0; i < 8; ++i) {
        Obb plate = random_volume<Obb>(rng, 4.0f, 6.0f);
        plate.half_extents.z = std::ldexp(glm::length(plate.center) + 1.0f, -44 - int(rng.next() % 10));
        boxes.push_back(plate);
      }
      Obb flat = random_volume<Obb>(rng, 4.0f, 6.0f);
      flat.half_extents.y = 0.0f;
      boxes.push_back(flat);
      Obb sheet = random_volume<Obb>(rng, 4.0f, 6.0f);
      sheet.half_extents.x = 1e-6f;
      boxes.push_back(sheet);
    }
    const std::vector<float> truth = render_depth(k, boxes);
    std::vector<occlusion::OccluderBox> occluders;
    for (const Obb& b : boxes) occluders.push_back(occlusion::occluder_box(b));
    const OcclusionView view{vp, w, h, cam.reversed_z};
    for (const std::uint32_t divisor : {1u, 3u, 4u}) {
      const std::uint32_t sw = std::max(1u, w / divisor), sh = std::max(1u, h / divisor);
      const occlusion::SoftwareDepth soft = occlusion::rasterise_occluders(occluders, view, sw, sh);
      for (std::uint32_t y = 0; y < h; ++y)
        for (std::uint32_t x = 0; x < w; ++x) {
          const std::uint32_t px = std::uint32_t((x + 0.5) * sw / w), py = std::uint32_t((y + 0.5) * sh / h);
          const float cpu = soft.depth[std::size_t(py) * sw + px], ray = truth[std::size_t(y) * w + x];
          ASSERT_TRUE(cam.reversed_z ? cpu <= ray : cpu >= ray)
              << "scene " << s << " (camera variant " << s % 8 << ", " << w << "x" << h << "), " << sw << "x" << sh
              << " buffer: pixel " << x << "," << y << " ray-cast depth " << ray << ", software depth " << cpu;
        }
      for (float d : soft.depth) covered[s % 8] += d != (cam.reversed_z ? 0.0f : 1.0f);
    }
  }
  for (int variant = 0; variant < 8; ++variant) EXPECT_GT(covered[variant], 100u) << "camera variant " << variant;
}

TEST(SoftwareDepth, RefusesABufferLargerThanTheViewport) {
  const OcclusionView view{test::test_view_proj(), 8, 8, false};
  EXPECT_THROW(occlusion::rasterise_occluders({}, view, 9, 8), std::invalid_argument);
  EXPECT_THROW(occlusion::rasterise_occluders({}, view, 0, 8), std::invalid_argument);
  EXPECT_EQ(occlusion::rasterise_occluders({}, view, 4, 2).depth, std::vector<float>(8, 1.0f));
}

TEST(Occlusion, BoxesThatOwnAPixelAreNeverOccluded) { expect_conservative<Aabb>(11, 96); }
TEST(Occlusion, ObbsThatOwnAPixelAreNeverOccluded) { expect_conservative<Obb>(12, 96); }
TEST(Occlusion, SpheresThatOwnAPixelAreNeverOccluded) { expect_conservative<Sphere>(13, 96); }

// A wall filling the view hides a box behind it; a box in front of it, or level with its face,
// is kept; a box crossing the near plane or behind the eye is kept.
TEST(Occlusion, KnownAnswersBehindAWall) {
  for (const bool reversed : {false, true}) {
    Camera cam;
    cam.eye = {0, 0, 10};
    cam.target = {0, 0, 0};
    cam.aspect = 1.0f;
    cam.reversed_z = reversed;
    const glm::mat4 vp = cam.view_proj();
    const std::uint32_t w = 33, h = 17;
    const Caster k(vp, w, h, reversed);
    const std::vector<Aabb> wall = {{{-100, -100, -1}, {100, 100, 0}}};
    const DepthPyramid pyramid = occlusion::build_depth_pyramid(render_depth(k, wall), w, h, reversed);
    const OcclusionView view{vp, w, h, reversed};
    const Frustum frustum = Frustum::from_view_proj(vp);
    auto cls = [&](const Aabb& b, std::uint32_t texels) {
      return occlusion::classify(b, frustum, view, pyramid, {texels});
    };
    for (const std::uint32_t texels : {2u, 4u, 8u, 16u}) {
      EXPECT_EQ(cls({{-1, -1, -5}, {1, 1, -3}}, texels), Classification::Occluded) << texels;
      EXPECT_EQ(cls({{-50, -50, -30}, {50, 50, -20}}, texels), Classification::Occluded) << texels;
      EXPECT_NE(cls({{-1, -1, 1}, {1, 1, 3}}, texels), Classification::Occluded) << texels;   // in front
      EXPECT_NE(cls({{-1, -1, -2}, {1, 1, 0}}, texels), Classification::Occluded) << texels;  // level with the face
      EXPECT_NE(cls({{-1, -1, 9.95f}, {1, 1, 12}}, texels), Classification::Occluded)
          << texels;  // through the near plane
    }
    // Behind the eye and still in the frustum's side planes: not projected, kept.
    const Footprint behind = occlusion::footprint(Aabb{{-1, -1, 11}, {1, 1, 12}}, view);
    EXPECT_FALSE(behind.projected);
  }
}

TEST(Occlusion, BadViewsAreRefusedByName) {
  const DepthPyramid pyramid = occlusion::build_depth_pyramid(std::vector<float>(12, 1.0f), 4, 3, false);
  const Frustum frustum = Frustum::from_view_proj(test::test_view_proj());
  const Aabb box{{-1, -1, -1}, {1, 1, 1}};
  auto message = [&](const OcclusionView& v, const OcclusionOptions& o = {}) -> std::string {
    try {
      occlusion::classify(box, frustum, v, pyramid, o);
    } catch (const std::invalid_argument& e) {
      return e.what();
    }
    return "";
  };
  EXPECT_NE(message({test::test_view_proj(), 5, 3, false}).find("does not match"), std::string::npos);
  EXPECT_NE(message({test::test_view_proj(), 4, 3, true}).find("reversed-Z view"), std::string::npos);
  glm::mat4 nan_matrix = test::test_view_proj();
  nan_matrix[2][1] = std::numeric_limits<float>::quiet_NaN();
  EXPECT_NE(message({nan_matrix, 4, 3, false}).find("non-finite"), std::string::npos);
  EXPECT_NE(message({test::test_view_proj(), 4, 3, false}, {3}).find("texels_per_axis"), std::string::npos);
  for (const std::uint32_t refine : {1u, 6u, 32u})
    EXPECT_NE(message({test::test_view_proj(), 4, 3, false}, {4, refine}).find("refine_texels_per_axis"),
              std::string::npos)
        << refine;
  EXPECT_EQ(message({test::test_view_proj(), 4, 3, false}, {4, 16}), "");
  EXPECT_EQ(message({test::test_view_proj(), 4, 3, false}, {16, 4}), "");  // (no second test)
  EXPECT_EQ(message({test::test_view_proj(), 4, 3, false}), "");
}

}  // namespace
}  // namespace cullpipe
