// src/cullpipe/bvh: the binned-SAH builder, validation, flattening and the scalar hierarchical cull.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <limits>
#include <new>
#if defined(__SSE2__)
#include <xmmintrin.h>
#endif

#include "bvh_test_util.hpp"
#include "cullpipe/bvh/binned_sah.hpp"
#include "cullpipe/bvh/builders.hpp"
#include "cullpipe/bvh/bvh.hpp"
#include "cullpipe/core/thread_pool.hpp"
#include "cullpipe/cull/reference.hpp"
#include "cullpipe/scene/generators.hpp"
#include "cullpipe/scene/gltf_scene.hpp"
#include "test_util.hpp"

namespace cullpipe {
namespace {

// Structural checks of a flattened tree: children where the skip indices say, subtree object
// ranges nested and contiguous, boxes enclosing, every object once.
void expect_flat_tree_valid(const bvh::FlatTree& f, std::span<const Aabb> boxes) {
  if (boxes.empty()) {
    EXPECT_TRUE(f.nodes.empty());
    return;
  }
  ASSERT_EQ(f.objects.size(), boxes.size());
  std::vector<int> seen(boxes.size(), 0);
  for (std::uint32_t o : f.objects) ++seen.at(o);
  for (int s : seen) ASSERT_EQ(s, 1);
  ASSERT_EQ(f.nodes[0].skip, f.nodes.size());
  ASSERT_EQ(f.nodes[0].count, boxes.size());
  for (std::uint32_t i = 0; i < f.nodes.size(); ++i) {
    const bvh::FlatNode& n = f.nodes[i];
    ASSERT_GT(n.skip, i);
    if (n.leaf) {
      ASSERT_EQ(n.skip, i + 1) << i;
      for (std::uint32_t k = n.first; k < n.first + n.count; ++k) {
        const Aabb& b = boxes[f.objects[k]];
        ASSERT_TRUE(glm::all(glm::lessThanEqual(n.box.min, b.min)) && glm::all(glm::lessThanEqual(b.max, n.box.max)))
            << i;
      }
      continue;
    }
    const bvh::FlatNode& a = f.nodes[i + 1];
    ASSERT_LT(a.skip, n.skip) << i;
    const bvh::FlatNode& b = f.nodes[a.skip];
    ASSERT_EQ(b.skip, n.skip) << i;  // exactly two children
    ASSERT_EQ(a.first, n.first);
    ASSERT_EQ(b.first, a.first + a.count);
    ASSERT_EQ(n.count, a.count + b.count);
    for (const bvh::FlatNode* c : {&a, &b})
      ASSERT_TRUE(glm::all(glm::lessThanEqual(n.box.min, c->box.min)) &&
                  glm::all(glm::lessThanEqual(c->box.max, n.box.max)))
          << i;
  }
}

// The hierarchical cull gives every object exactly the flat reference's class, with fewer
// tests when much is outside.
void expect_same_as_flat(const std::vector<Aabb>& boxes, const std::vector<Frustum>& frusta, std::size_t leaf = 4) {
  const bvh::Tree tree = bvh::build_binned_sah(boxes, {std::uint32_t(leaf), 16});
  ASSERT_EQ(bvh::check_tree(tree, boxes), "");
  const bvh::FlatTree flat = bvh::flatten(tree);
  expect_flat_tree_valid(flat, boxes);
  test::expect_hierarchy_equals_flat(flat, boxes, frusta);
}

TEST(Bvh, RandomSetsOfEverySize) {
  test::Rng rng{5};
  for (std::size_t n : {0u, 1u, 2u, 3u, 5u, 17u, 100u, 1000u, 20000u}) {
    SCOPED_TRACE("n = " + std::to_string(n));
    std::vector<Aabb> boxes(n);
    for (Aabb& b : boxes) b = test::random_aabb(rng, 40.0f, 3.0f);
    for (std::size_t leaf : {1u, 4u, 16u})
      expect_same_as_flat(boxes, {Frustum::from_view_proj(test::test_view_proj())}, leaf);
  }
}

TEST(Bvh, GeneratedScenesAlongCameraPaths) {
  for (SceneKind kind : {SceneKind::Uniform, SceneKind::Clustered, SceneKind::City}) {
    SCOPED_TRACE(std::string(to_string(kind)));
    const Scene scene = generate_scene(kind, 30000, 3);
    std::vector<Frustum> frusta;
    for (const Camera& c : camera_path(scene.camera, scene.bounds(), 6))
      frusta.push_back(Frustum::from_view_proj(c.view_proj()));
    const std::vector<Aabb> boxes = world_aabbs(scene);
    expect_same_as_flat(boxes, frusta);
    // The hierarchy pays: INSIDE subtrees are accepted whole and OUTSIDE ones dropped, so far
    // fewer tests than objects (flat culling makes one per object).
    const bvh::FlatTree flat = bvh::flatten(bvh::build_binned_sah(boxes));
    const bvh::HierarchicalResult h = bvh::cull_hierarchical(flat, boxes, frusta[0]);
    std::printf("  %s: %zu of %zu visible, %zu node + %zu object tests\n", std::string(to_string(kind)).c_str(),
                h.visible, boxes.size(), h.node_tests, h.object_tests);
    EXPECT_LT(h.node_tests + h.object_tests, boxes.size() / 2) << h.visible;
  }
}

// Object ranges (TraversalOptions::range_objects): a straddling node of at most that many
// objects tests its objects instead of descending. The classes do not change (an object inside
// a node's box gets the node's INSIDE or OUTSIDE from its own test too); node tests only fall
// and object tests only rise as the ranges grow; a range as large as the tree tests the root
// and, if it straddles, every object.
TEST(Bvh, ObjectRangesChangeTheTestsButNoClass) {
  for (SceneKind kind : {SceneKind::Uniform, SceneKind::City}) {
    SCOPED_TRACE(std::string(to_string(kind)));
    const Scene scene = generate_scene(kind, 20000, 5);
    const std::vector<Aabb> boxes = world_aabbs(scene);
    const bvh::FlatTree flat = bvh::flatten(bvh::build_binned_sah(boxes, {2, 16}));
    for (const Camera& c : camera_path(scene.camera, scene.bounds(), 3)) {
      const Frustum f = Frustum::from_view_proj(c.view_proj());
      const bvh::HierarchicalResult leaves = bvh::cull_hierarchical(flat, boxes, f);
      EXPECT_EQ(leaves, bvh::cull_hierarchical(flat, boxes, f, {1}));  // (leaves of 1-2: a node of 1 is a leaf)
      bvh::HierarchicalResult last = leaves;
      for (std::uint32_t range : {2u, 3u, 8u, 32u, 1000u, 20000u}) {
        const bvh::HierarchicalResult r = bvh::cull_hierarchical(flat, boxes, f, {range});
        ASSERT_EQ(r.classes, leaves.classes) << "ranges of " << range;
        EXPECT_EQ(r.visible, leaves.visible);
        EXPECT_EQ(r.inside, leaves.inside);
        EXPECT_LE(r.node_tests, last.node_tests) << "ranges of " << range;
        EXPECT_GE(r.object_tests, last.object_tests) << "ranges of " << range;
        last = r;
      }
      EXPECT_EQ(last.node_tests, 1u);  // the root straddles these views: every object is tested
      EXPECT_EQ(last.object_tests, boxes.size());
    }
  }
}

TEST(Bvh, DegenerateSetsStayBalanced) {
  // All boxes identical (equal centroids): the builder halves ranges, so depth is ~log2(n).
  const std::vector<Aabb> same(1000, Aabb{glm::vec3(-1), glm::vec3(1)});
  const bvh::Tree t = bvh::build_binned_sah(same);
  EXPECT_EQ(bvh::check_tree(t, same), "");
  EXPECT_LE(bvh::metrics(t).depth, 10u);
  expect_same_as_flat(same, {Frustum::from_view_proj(test::test_view_proj())});
  // Points on a line, flat boxes, subnormal spreads.
  std::vector<Aabb> line;
  for (int i = 0; i < 500; ++i) line.push_back({glm::vec3(float(i), 0, 0), glm::vec3(float(i), 0, 0)});
  expect_same_as_flat(line, {Frustum::from_view_proj(test::test_view_proj())});
  std::vector<Aabb> tiny;
  for (int i = 0; i < 50; ++i) tiny.push_back({glm::vec3(float(i) * 1e-44f), glm::vec3(float(i) * 1e-44f)});
  EXPECT_EQ(bvh::check_tree(bvh::build_binned_sah(tiny), tiny), "");
}

// Sets that take every path of the binned builder: boxes, points with duplicates, a line, a
// flat sheet, equal boxes (the split by id), subnormal spreads, huge coordinates, boxes
// reaching to infinity (valid: min <= max).
std::vector<std::vector<Aabb>> builder_edge_sets() {
  std::vector<std::vector<Aabb>> sets;
  test::Rng rng{91};
  std::vector<Aabb> boxes(3000), points(2000), line, sheet, tiny, huge, infinite(400);
  for (Aabb& b : boxes) b = test::random_aabb(rng, 60.0f, 4.0f);
  for (Aabb& b : points) {
    const glm::vec3 p = rng.vec3(-20.0f, 20.0f);
    b = {p, p};
  }
  for (std::size_t i = 0; i < 400; ++i) points[i] = points[i + 800];
  for (int i = 0; i < 300; ++i) line.push_back({glm::vec3(float(i % 37), 0, 0), glm::vec3(float(i % 37) + 0.5f, 0, 0)});
  for (int i = 0; i < 300; ++i)
    sheet.push_back({glm::vec3(float(i % 17), float(i / 17), 0), glm::vec3(float(i % 17), float(i / 17), 0)});
  for (int i = 0; i < 60; ++i) tiny.push_back({glm::vec3(float(i) * 1e-44f), glm::vec3(float(i) * 1e-44f)});
  for (int i = 0; i < 200; ++i) {
    const glm::vec3 c = rng.vec3(-1.0f, 1.0f) * 1e37f;
    huge.push_back({c - glm::vec3(1e36f), c + glm::vec3(1e36f)});
  }
  for (Aabb& b : infinite) b = test::random_aabb(rng, 30.0f, 2.0f);
  for (std::size_t i = 0; i < 8; ++i) infinite[i * 7].max.x = INFINITY;
  for (std::size_t i = 0; i < 5; ++i) infinite[i * 11 + 3].min.y = -INFINITY;
  infinite[100] = {glm::vec3(INFINITY), glm::vec3(INFINITY)};
  infinite[101] = {glm::vec3(-INFINITY, 0, 0), glm::vec3(INFINITY, 0, 0)};
  sets = {boxes,
          points,
          line,
          sheet,
          infinite,
          std::vector<Aabb>(700, Aabb{glm::vec3(-1), glm::vec3(2)}),
          tiny,
          huge,
          std::vector<Aabb>(1, boxes[0]),
          {boxes[1], boxes[2]}};
  return sets;
}

// Trees equal bit for bit: node boxes compared as bytes (so -0 against +0 counts; Node has no
// padding), then the object order.
::testing::AssertionResult same_bits(const bvh::Tree& a, const bvh::Tree& b) {
  static_assert(sizeof(bvh::Node) == 40, "Node must have no padding to compare as bytes");
  if (a.nodes.size() != b.nodes.size())
    return ::testing::AssertionFailure() << a.nodes.size() << " against " << b.nodes.size() << " nodes";
  for (std::size_t i = 0; i < a.nodes.size(); ++i)
    if (std::memcmp(&a.nodes[i], &b.nodes[i], sizeof(bvh::Node)) != 0)
      return ::testing::AssertionFailure() << "node " << i << " differs";
  if (a.objects != b.objects) return ::testing::AssertionFailure() << "object orders differ";
  return ::testing::AssertionSuccess();
}

#if defined(__SSE2__)
// A host that flushes denormals (DAZ/FTZ, e.g. built with -ffast-math, or an engine that sets
// it) builds the same tree: no integer data goes through float arithmetic.
TEST(Bvh, BinnedBuildIsUnchangedWhenTheCpuFlushesDenormals) {
  test::Rng rng{77};
  std::vector<Aabb> boxes(3000);
  for (Aabb& b : boxes) b = test::random_aabb(rng, 40.0f, 3.0f);
  const bvh::Tree normal = bvh::build_binned_sah(boxes);
  const unsigned csr = _mm_getcsr();
  _mm_setcsr(csr | 0x8040);  // FTZ | DAZ
  bvh::Tree flushed, flushed_baseline;
  try {
    flushed = bvh::build_binned_sah(boxes);  // the AVX2 variant where the CPU has it
    bvh::detail::BinnedScratch scratch;
    bvh::detail::baseline::build(boxes, {}, scratch, flushed_baseline);
  } catch (...) {
    _mm_setcsr(csr);
    throw;
  }
  _mm_setcsr(csr);
  EXPECT_EQ(bvh::check_tree(flushed, boxes), "");
  EXPECT_TRUE(same_bits(flushed, normal));
  EXPECT_TRUE(same_bits(flushed_baseline, normal));
  // The edge sets too, both variants: flushing gives both the same tree, and the tree without
  // flushing unless a coordinate is subnormal (flushing then changes the boxes' minimums).
  for (const std::vector<Aabb>& set : builder_edge_sets()) {
    bool subnormal = false;
    for (const Aabb& b : set)
      for (int k = 0; k < 3; ++k)
        subnormal |= std::fpclassify(b.min[k]) == FP_SUBNORMAL || std::fpclassify(b.max[k]) == FP_SUBNORMAL;
    bvh::detail::BinnedScratch scratch;
    bvh::Tree base, wide, base_flushed, wide_flushed;
    bvh::detail::baseline::build(set, {}, scratch, base);
    if (bvh::detail::binned_sah_avx2_available()) bvh::detail::avx2::build(set, {}, scratch, wide);
    _mm_setcsr(csr | 0x8040);
    bvh::detail::baseline::build(set, {}, scratch, base_flushed);
    if (bvh::detail::binned_sah_avx2_available()) bvh::detail::avx2::build(set, {}, scratch, wide_flushed);
    _mm_setcsr(csr);
    const bool wide_too = bvh::detail::binned_sah_avx2_available();
    if (wide_too) {
      EXPECT_TRUE(same_bits(wide_flushed, base_flushed)) << set.size() << " objects";
    }
    if (subnormal) continue;
    EXPECT_TRUE(same_bits(base_flushed, base)) << set.size() << " objects";
    if (wide_too) {
      EXPECT_TRUE(same_bits(wide_flushed, wide)) << set.size() << " objects";
    }
  }
}
#endif

// The AVX2 variant (vectorised sweep, 8-lane box updates) and the baseline build the same tree,
// bit for bit, for every bin count and leaf size.
TEST(Bvh, BinnedBuilderVariantsBuildTheSameTree) {
  if (!bvh::detail::binned_sah_avx2_available())
    GTEST_SKIP() << "this CPU has no AVX2 (only the baseline variant runs)";
  for (const std::vector<Aabb>& set : builder_edge_sets())
    for (std::uint32_t leaf : {1u, 4u, 7u})
      for (std::uint32_t bins : {2u, 5u, 16u, 33u, 256u}) {
        bvh::detail::BinnedScratch a, b;
        bvh::Tree base, wide;
        bvh::detail::baseline::build(set, {leaf, bins}, a, base);
        bvh::detail::avx2::build(set, {leaf, bins}, b, wide);
        ASSERT_EQ(bvh::check_tree(base, set), "") << set.size() << " objects, leaf " << leaf << ", bins " << bins;
        ASSERT_TRUE(same_bits(wide, base)) << set.size() << " objects, leaf " << leaf << ", bins " << bins;
      }
}

// Sets large enough to be built on several threads (past the 4,096-object cut), taking every
// path of the shared passes at the top: boxes, duplicated points, a line, equal boxes (split
// by id from the root), subnormal spreads, huge coordinates and boxes reaching to infinity,
// zeros of both signs; and one set past 65,536 objects, where the cut is n / 16.
std::vector<std::vector<Aabb>> threaded_sets() {
  std::vector<std::vector<Aabb>> sets;
  test::Rng rng{93};
  std::vector<Aabb> boxes(30000), points(9000), line, tiny, huge, infinite(12000), zeros, big(150000);
  for (Aabb& b : boxes) b = test::random_aabb(rng, 60.0f, 4.0f);
  for (Aabb& b : points) {
    const glm::vec3 p = rng.vec3(-20.0f, 20.0f);
    b = {p, p};
  }
  for (std::size_t i = 0; i < 3000; ++i) points[i] = points[i + 4000];
  for (int i = 0; i < 9000; ++i)
    line.push_back({glm::vec3(float(i % 37), 0, 0), glm::vec3(float(i % 37) + 0.5f, 0, 0)});
  for (int i = 0; i < 6000; ++i)
    tiny.push_back({glm::vec3(float(i % 300) * 1e-44f), glm::vec3(float(i % 300) * 1e-44f)});
  for (int i = 0; i < 8000; ++i) {
    const glm::vec3 c = rng.vec3(-1.0f, 1.0f) * 1e37f;
    huge.push_back({c - glm::vec3(1e36f), c + glm::vec3(1e36f)});
  }
  for (Aabb& b : infinite) b = test::random_aabb(rng, 30.0f, 2.0f);
  for (std::size_t i = 0; i < 200; ++i) infinite[i * 37].max.x = INFINITY;
  for (std::size_t i = 0; i < 100; ++i) infinite[i * 53 + 3].min.y = -INFINITY;
  infinite[100] = {glm::vec3(INFINITY), glm::vec3(INFINITY)};
  infinite[101] = {glm::vec3(-INFINITY, 0, 0), glm::vec3(INFINITY, 0, 0)};
  for (int i = 0; i < 7000; ++i) {
    const float z = i % 3 == 0 ? -0.0f : 0.0f;
    const glm::vec3 p(float(i % 5) - 2.0f, z, i % 2 ? z : 0.0f);
    zeros.push_back({p, p + glm::vec3(i % 7 == 0 ? 0.0f : 1.0f)});
  }
  for (Aabb& b : big) b = test::random_aabb(rng, 1000.0f, 1.0f);
  sets = {boxes, points, line, tiny, huge, infinite, zeros, std::vector<Aabb>(9000, Aabb{glm::vec3(-1), glm::vec3(2)}),
          big};
  return sets;
}

// On a pool of 2, 3 or 4 threads, the binned builder (either variant) gives the one-thread
// tree, bit for bit, for several leaf sizes and bin counts; a reused builder too.
TEST(Bvh, BinnedBuildOnSeveralThreadsIsTheOneThreadTree) {
  ThreadPool pools[] = {ThreadPool(2), ThreadPool(3), ThreadPool(4)};
  const std::vector<std::vector<Aabb>> sets = threaded_sets();
  for (std::size_t k = 0; k < sets.size(); ++k) {
    const std::vector<Aabb>& set = sets[k];
    const bool big = set.size() > 100000;
    for (std::uint32_t leaf : {1u, 4u, 7u})
      for (std::uint32_t bins : {5u, 16u, 256u}) {
        if (big && (bins != 16u || leaf == 7u)) continue;
        SCOPED_TRACE("set " + std::to_string(k) + " (" + std::to_string(set.size()) + " objects), leaf " +
                     std::to_string(leaf) + ", bins " + std::to_string(bins));
        const bvh::Tree one = bvh::build_binned_sah(set, {leaf, bins});
        ASSERT_EQ(bvh::check_tree(one, set), "");
        for (ThreadPool& pool : pools) {
          if (big && pool.size() == 3) continue;
          ASSERT_TRUE(same_bits(bvh::build_binned_sah(set, {leaf, bins}, &pool), one)) << pool.size() << " threads";
          bvh::detail::BinnedScratch scratch;
          bvh::Tree base;
          bvh::detail::baseline::build(set, {leaf, bins}, scratch, base, &pool);
          ASSERT_TRUE(same_bits(base, one)) << "baseline variant, " << pool.size() << " threads";
        }
      }
  }
  bvh::BinnedSahBuilder builder;
  bvh::Tree tree;
  for (int round = 0; round < 2; ++round)
    for (std::size_t k : {0u, 6u, 1u}) {
      builder.build(sets[k], {}, tree, &pools[0]);
      ASSERT_TRUE(same_bits(tree, bvh::build_binned_sah(sets[k])))
          << "reused builder, set " << k << ", round " << round;
    }
}

// A builder kept between builds (growing, shrinking, other options) gives build_binned_sah's
// tree each time, into a tree it reuses; so does one moved from, moved into or released.
TEST(Bvh, BinnedSahBuilderReusesItsMemory) {
  const std::vector<std::vector<Aabb>> sets = builder_edge_sets();
  bvh::BinnedSahBuilder builder;
  bvh::Tree tree;
  for (int round = 0; round < 2; ++round)
    for (const std::vector<Aabb>& set : sets) {
      const bvh::TopDownOptions options{round == 0 ? 4u : 2u, round == 0 ? 16u : 9u};
      builder.build(set, options, tree);
      ASSERT_EQ(tree, bvh::build_binned_sah(set, options)) << set.size() << " objects, round " << round;
    }
  builder.build(std::span<const Aabb>(), {}, tree);
  EXPECT_TRUE(tree.nodes.empty() && tree.objects.empty());
  bvh::BinnedSahBuilder moved = std::move(builder);
  moved.build(sets[0], {}, tree);
  EXPECT_EQ(tree, bvh::build_binned_sah(sets[0]));
  builder.build(sets[1], {}, tree);  // NOLINT(bugprone-use-after-move): a moved-from builder still builds
  EXPECT_EQ(tree, bvh::build_binned_sah(sets[1]));
  moved.release();
  moved.build(sets[2], {}, tree);
  EXPECT_EQ(tree, bvh::build_binned_sah(sets[2]));
  // Working memory that cannot grow (here: a size past what new[] can count) throws, and the
  // scratch still builds after, also fewer objects than it held before.
  bvh::detail::BinnedScratch scratch;
  scratch.reserve(100);
  EXPECT_THROW(scratch.reserve(std::numeric_limits<std::size_t>::max() / 16), std::bad_alloc);
  ASSERT_LE(sets[6].size(), 100u);
  bvh::detail::baseline::build(sets[6], {}, scratch, tree);
  EXPECT_EQ(tree, bvh::build_binned_sah(sets[6]));
}

// Leaves where the SAH says: the leaves-of-one tree collapsed (collapse_leaves) with the cap and
// the object cost given; on any number of threads and through a kept builder the same tree;
// a lower object cost grows the leaves; bad costs refused.
TEST(Bvh, SahLeavesAreTheOneObjectTreeCollapsed) {
  ThreadPool pool(2);
  const std::vector<std::vector<Aabb>> sets = threaded_sets();
  bvh::BinnedSahBuilder builder;
  bvh::Tree kept;
  for (std::size_t k = 0; k < sets.size(); ++k) {
    const std::vector<Aabb>& set = sets[k];
    if (set.size() > 100000) continue;
    const bvh::Tree ones = bvh::build_binned_sah(set, {1, 16});
    for (const float cost : {1.0f, 0.5f, 0.125f}) {
      SCOPED_TRACE("set " + std::to_string(k) + " (" + std::to_string(set.size()) + " objects), object cost " +
                   std::to_string(cost));
      const bvh::TopDownOptions options{16, 16, true, cost};
      const bvh::Tree tree = bvh::build_binned_sah(set, options);
      ASSERT_EQ(bvh::check_tree(tree, set), "");
      ASSERT_EQ(tree, bvh::collapse_leaves(ones, 16, cost));
      ASSERT_TRUE(same_bits(bvh::build_binned_sah(set, options, &pool), tree)) << "2 threads";
      builder.build(set, options, kept, &pool);
      ASSERT_EQ(kept, tree) << "kept builder";
      const bvh::Metrics m = bvh::metrics(tree);
      EXPECT_LE(m.max_leaf_size, 16u);
      if (cost == 1.0f && std::isfinite(m.sah_cost)) {                     // (NaN with boxes reaching to infinity)
        EXPECT_LE(m.sah_cost, bvh::metrics(ones).sah_cost * (1 + 1e-12));  // never worse
      }
    }
    // Through the registry and build_top_down too, also for a top-down builder of another kind.
    bvh::BuildOptions options;
    options.max_leaf_size = 8;
    options.sah_leaves = true;
    options.object_cost = 0.25f;
    EXPECT_EQ(bvh::build("binned-sah", set, options), bvh::build_binned_sah(set, {8, 16, true, 0.25f}));
    options.max_leaf_size = 1;
    const bvh::Tree median_ones = bvh::build("median", set, options);
    options.max_leaf_size = 8;
    EXPECT_EQ(bvh::build("median", set, options), bvh::collapse_leaves(median_ones, 8, 0.25f));
  }
  // Random boxes: an object cost of 1 leaves most objects alone, 1/8 makes leaves of several.
  const std::vector<Aabb>& uniform = sets[0];
  const bvh::Metrics fine = bvh::metrics(bvh::build_binned_sah(uniform, {16, 16, true, 1.0f}));
  const bvh::Metrics coarse = bvh::metrics(bvh::build_binned_sah(uniform, {16, 16, true, 0.125f}));
  EXPECT_GT(fine.leaves, uniform.size() * 3 / 4);
  EXPECT_LT(coarse.leaves, uniform.size() / 4);
  for (const float bad : {0.0f, -1.0f, std::numeric_limits<float>::quiet_NaN(), std::numeric_limits<float>::infinity()})
    EXPECT_THROW(bvh::build_binned_sah(uniform, {4, 16, true, bad}), std::invalid_argument) << bad;
  EXPECT_THROW(bvh::collapse_leaves(bvh::build_binned_sah(uniform, {1, 16}), 4, 0.0f), std::invalid_argument);
}

TEST(Bvh, MetricsAndDeterminism) {
  test::Rng rng{8};
  std::vector<Aabb> boxes(5000);
  for (Aabb& b : boxes) b = test::random_aabb(rng, 50.0f, 2.0f);
  const bvh::Tree a = bvh::build_binned_sah(boxes), b = bvh::build_binned_sah(boxes);
  EXPECT_EQ(a, b);
  const bvh::Metrics m = bvh::metrics(a);
  EXPECT_EQ(m.nodes, a.nodes.size());
  EXPECT_EQ(m.leaves, (m.nodes + 1) / 2);
  EXPECT_LE(m.max_leaf_size, 4u);
  EXPECT_GT(m.sah_cost, 1.0);
  // SAH beats splitting by object id (a spatially meaningless tree) by a wide margin.
  bvh::Tree naive = bvh::build_binned_sah(std::vector<Aabb>(boxes.size(), Aabb{glm::vec3(0), glm::vec3(1)}));
  for (bvh::Node& n : naive.nodes) n.box = {glm::vec3(INFINITY), glm::vec3(-INFINITY)};
  // Refit the id-split tree's boxes bottom-up (children have larger indices than parents).
  for (std::size_t i = naive.nodes.size(); i-- > 0;) {
    bvh::Node& n = naive.nodes[i];
    if (n.leaf()) {
      for (std::uint32_t k = n.first; k < n.first + n.count; ++k)
        n.box = {glm::min(n.box.min, boxes[naive.objects[k]].min), glm::max(n.box.max, boxes[naive.objects[k]].max)};
    } else {
      n.box = {glm::min(naive.nodes[n.left].box.min, naive.nodes[n.right].box.min),
               glm::max(naive.nodes[n.left].box.max, naive.nodes[n.right].box.max)};
    }
  }
  EXPECT_EQ(bvh::check_tree(naive, boxes), "");
  EXPECT_LT(m.sah_cost * 3.0, bvh::metrics(naive).sah_cost);
  // check_tree finds broken trees.
  bvh::Tree broken = a;
  broken.objects[0] = broken.objects[1];
  EXPECT_NE(bvh::check_tree(broken, boxes), "");
  broken = a;
  broken.nodes[1].box.max.x -= 1.0f;
  EXPECT_NE(bvh::check_tree(broken, boxes), "");
}

TEST(Bvh, RealGltfScenes) {
  const std::filesystem::path dir = std::filesystem::path(CULLPIPE_SHARED_DIR) / "scenes";
  if (!std::filesystem::exists(dir)) GTEST_SKIP() << dir << " not present";
  for (const char* name :
       {"VC/VC.gltf", "ReciprocatingSaw/ReciprocatingSaw.gltf", "2CylinderEngine/2CylinderEngine.gltf"}) {
    SCOPED_TRACE(name);
    const Scene scene = replicate_scene(load_gltf_scene((dir / name).string()).scene, 50, InstanceLayout::Random, 2);
    std::vector<Frustum> frusta;
    for (const Camera& c : camera_path(scene.camera, scene.bounds(), 4))
      frusta.push_back(Frustum::from_view_proj(c.view_proj()));
    expect_same_as_flat(world_aabbs(scene), frusta);
  }
}

}  // namespace
}  // namespace cullpipe
