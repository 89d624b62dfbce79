// src/cullpipe/bvh top-down builders (every axis x position x cost), detailed metrics and the
// builder registry.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <set>
#include <stdexcept>
#include <string>

#include "bvh_test_util.hpp"
#include "cullpipe/bvh/binned_sah.hpp"
#include "cullpipe/bvh/builders.hpp"
#include "cullpipe/cull/reference.hpp"
#include "cullpipe/scene/generators.hpp"
#include "test_util.hpp"

namespace cullpipe {
namespace {

using bvh::SplitAxis;
using bvh::SplitCost;
using bvh::SplitPosition;

constexpr SplitAxis kAxes[] = {SplitAxis::Longest, SplitAxis::DistantCentroids, SplitAxis::Pca, SplitAxis::Best};
constexpr SplitPosition kPositions[] = {SplitPosition::Median, SplitPosition::Mean, SplitPosition::ExtentMedian,
                                        SplitPosition::Binned};
constexpr SplitCost kCosts[] = {SplitCost::Sah,     SplitCost::VolumeSum,  SplitCost::LargestVolume,
                                SplitCost::Overlap, SplitCost::Separation, SplitCost::SahOverlapGuarded};

// The registry's spelling of each value (so the names double as a test of the grammar).
const char* name(SplitAxis a) {
  switch (a) {
    case SplitAxis::Longest:
      return "longest";
    case SplitAxis::DistantCentroids:
      return "distant";
    case SplitAxis::Pca:
      return "pca";
    case SplitAxis::Best:
      return "best";
  }
  return "?";
}
const char* name(SplitPosition p) {
  switch (p) {
    case SplitPosition::Median:
      return "median";
    case SplitPosition::Mean:
      return "mean";
    case SplitPosition::ExtentMedian:
      return "extent";
    case SplitPosition::Binned:
      return "binned";
  }
  return "?";
}
const char* name(SplitCost c) {
  switch (c) {
    case SplitCost::Sah:
      return "sah";
    case SplitCost::VolumeSum:
      return "volume";
    case SplitCost::LargestVolume:
      return "largest";
    case SplitCost::Overlap:
      return "overlap";
    case SplitCost::Separation:
      return "separation";
    case SplitCost::SahOverlapGuarded:
      return "sah-guarded";
  }
  return "?";
}

struct Combination {
  SplitAxis axis;
  SplitPosition position;
  SplitCost cost;
  std::string spec() const {
    return std::string("top-down:axis=") + name(axis) + ",split=" + name(position) + ",cost=" + name(cost);
  }
  bvh::BuildOptions options(std::uint32_t leaf) const {
    bvh::BuildOptions o;
    o.max_leaf_size = leaf;
    o.axis = axis;
    o.position = position;
    o.cost = cost;
    return o;
  }
};

std::vector<Combination> all_combinations() {
  std::vector<Combination> out;
  for (SplitAxis a : kAxes)
    for (SplitPosition p : kPositions)
      for (SplitCost c : kCosts) out.push_back({a, p, c});
  return out;
}

// Structure beyond check_tree: a node is a leaf exactly when it holds <= max_leaf objects.
void expect_leaf_rule(const bvh::Tree& tree, std::uint32_t max_leaf) {
  const bvh::FlatTree flat = bvh::flatten(tree);  // gives each node its subtree's object count
  for (std::size_t i = 0; i < flat.nodes.size(); ++i) {
    const bvh::FlatNode& n = flat.nodes[i];
    if (n.leaf) {
      ASSERT_LE(n.count, max_leaf) << "leaf " << i;
      ASSERT_GT(n.count, 0u) << "empty leaf " << i;
    } else {
      ASSERT_GT(n.count, max_leaf) << "inner node " << i << " could have been a leaf";
    }
  }
}

// Everything a valid top-down tree over `boxes` must satisfy; returns the tree.
bvh::Tree build_and_check(std::span<const Aabb> boxes, const bvh::BuildOptions& options) {
  const bvh::Tree tree = bvh::build_top_down(boxes, options);
  EXPECT_EQ(bvh::check_tree(tree, boxes), "");
  expect_leaf_rule(tree, std::max<std::uint32_t>(options.max_leaf_size, 1));
  EXPECT_LE(bvh::metrics(tree).max_leaf_size, std::max<std::uint32_t>(options.max_leaf_size, 1));
  EXPECT_EQ(tree.nodes.size(), boxes.empty() ? 0u : 2 * bvh::metrics(tree).leaves - 1);
  return tree;
}

// The hierarchical cull over the tree gives every object the flat reference's class.
void expect_same_classes(const bvh::Tree& tree, std::span<const Aabb> boxes, const std::vector<Frustum>& frusta) {
  test::expect_hierarchy_equals_flat(bvh::flatten(tree), boxes, frusta);
}

TEST(TopDown, EveryCombinationOnRandomAndClusteredScenes) {
  test::Rng rng{11};
  std::vector<Aabb> random(700);
  for (Aabb& b : random) b = test::random_aabb(rng, 40.0f, 3.0f);
  const Scene clustered_scene = generate_scene(SceneKind::Clustered, 900, 4);
  const std::vector<Aabb> clustered = world_aabbs(clustered_scene);
  std::vector<Frustum> random_views{Frustum::from_view_proj(test::test_view_proj())};
  std::vector<Frustum> clustered_views;
  for (const Camera& c : camera_path(clustered_scene.camera, clustered_scene.bounds(), 2))
    clustered_views.push_back(Frustum::from_view_proj(c.view_proj()));

  for (const Combination& combo : all_combinations()) {
    SCOPED_TRACE(combo.spec());
    for (std::uint32_t leaf : {1u, 4u, 8u}) {
      SCOPED_TRACE("leaf " + std::to_string(leaf));
      for (int scene = 0; scene < 2; ++scene) {
        const std::vector<Aabb>& boxes = scene ? clustered : random;
        const bvh::Tree a = build_and_check(boxes, combo.options(leaf));
        EXPECT_EQ(a, bvh::build_top_down(boxes, combo.options(leaf))) << "not deterministic";
        expect_same_classes(a, boxes, scene ? clustered_views : random_views);
        if (HasFailure()) return;
      }
    }
  }
}

TEST(TopDown, EveryCombinationSplitsTwoDistantClustersAtTheRoot) {
  // Two groups of 8 boxes, far apart along z, each spread over the same large x-y square (so
  // any split along x or y mixes the groups into two large, overlapping children). Whatever
  // the axis rule, position or cost, the root must separate the groups. (Along z, the last
  // axis tried: a cost that does not discriminate would keep the first candidate, on x.)
  test::Rng rng{3};
  std::vector<Aabb> boxes;
  for (int group = 0; group < 2; ++group)
    for (int i = 0; i < 8; ++i) {
      const glm::vec3 c(rng.uniform(0.0f, 20.0f), rng.uniform(0.0f, 20.0f),
                        float(group) * 100.0f + rng.uniform(-1.0f, 1.0f));
      boxes.push_back({c - glm::vec3(4.0f, 4.0f, 0.5f), c + glm::vec3(4.0f, 4.0f, 0.5f)});
    }
  for (const Combination& combo : all_combinations()) {
    SCOPED_TRACE(combo.spec());
    const bvh::Tree tree = build_and_check(boxes, combo.options(2));
    const bvh::FlatTree flat = bvh::flatten(tree);
    const bvh::FlatNode& first = flat.nodes[1];
    ASSERT_EQ(first.count, 8u);
    std::set<int> groups;
    for (std::uint32_t k = first.first; k < first.first + first.count; ++k) groups.insert(int(flat.objects[k]) / 8);
    EXPECT_EQ(groups.size(), 1u);
  }
}

TEST(TopDown, DegenerateInputsForEveryCombination) {
  std::vector<std::pair<std::string, std::vector<Aabb>>> cases;
  cases.push_back({"empty", {}});
  cases.push_back({"one", {Aabb{glm::vec3(1, 2, 3), glm::vec3(2, 3, 4)}}});
  cases.push_back({"two", {Aabb{glm::vec3(0), glm::vec3(1)}, Aabb{glm::vec3(5), glm::vec3(6)}}});
  cases.push_back({"two equal", {Aabb{glm::vec3(0), glm::vec3(1)}, Aabb{glm::vec3(0), glm::vec3(1)}}});
  cases.push_back({"all equal", std::vector<Aabb>(200, Aabb{glm::vec3(-1), glm::vec3(1)})});
  cases.push_back({"all equal points", std::vector<Aabb>(77, Aabb{glm::vec3(3), glm::vec3(3)})});
  test::Rng rng{9};
  std::vector<Aabb> collinear, coplanar, points, spread_equal_centres, tiny;
  for (int i = 0; i < 300; ++i) {
    const glm::vec3 c = glm::vec3(1.0f, 2.0f, -3.0f) * rng.uniform(-10.0f, 10.0f);  // centres on a line
    const glm::vec3 h = rng.vec3(0.0f, 2.0f);
    collinear.push_back({c - h, c + h});
    const glm::vec3 p(rng.uniform(-20.0f, 20.0f), rng.uniform(-20.0f, 20.0f), 5.0f);  // flat boxes in a plane
    coplanar.push_back({p - glm::vec3(1, 1, 0), p + glm::vec3(1, 1, 0)});
    const glm::vec3 q = rng.vec3(-5.0f, 5.0f);  // zero-size boxes, with duplicates
    points.push_back({q, q});
    points.push_back({q, q});
    const glm::vec3 e = rng.vec3(0.0f, 4.0f);  // one centre, different sizes
    spread_equal_centres.push_back({-e, e});
    const glm::vec3 s(float(i) * 1e-44f);  // subnormal spread
    tiny.push_back({s, s});
  }
  cases.push_back({"collinear", collinear});
  cases.push_back({"coplanar", coplanar});
  cases.push_back({"points", points});
  cases.push_back({"equal centres", spread_equal_centres});
  cases.push_back({"subnormal", tiny});

  for (const auto& [label, boxes] : cases) {
    SCOPED_TRACE(label);
    for (const Combination& combo : all_combinations()) {
      SCOPED_TRACE(combo.spec());
      for (std::uint32_t leaf : {0u, 1u, 4u}) {  // 0 behaves as 1
        const bvh::Tree tree = build_and_check(boxes, combo.options(leaf));
        if (boxes.empty()) {
          EXPECT_TRUE(tree.nodes.empty() && tree.objects.empty());
        }
        if (boxes.size() == 1) {
          EXPECT_EQ(tree.nodes.size(), 1u);
        }
        // Equal centroids can only be halved by id: a balanced tree.
        if (label.starts_with("all equal") || label == "equal centres") {
          const std::size_t leaves_needed = (boxes.size() + std::max(leaf, 1u) - 1) / std::max(leaf, 1u);
          EXPECT_LE(bvh::metrics(tree).depth, std::size_t(std::ceil(std::log2(double(leaves_needed)))) + 1);
        }
        if (HasFailure()) return;
      }
    }
  }
}

TEST(TopDown, HundredThousandObjects) {
  test::Rng rng{21};
  std::vector<Aabb> boxes(100000);
  for (Aabb& b : boxes) b = test::random_aabb(rng, 300.0f, 2.0f);
  std::vector<Aabb> line(100000);
  for (std::size_t i = 0; i < line.size(); ++i) {
    const glm::vec3 c =
        glm::vec3(3.0f, -1.0f, 2.0f) * (float(i % 5000) * 0.01f);  // collinear, 20 copies of each centre
    line[i] = {c - glm::vec3(0.5f), c + glm::vec3(0.5f)};
  }
  const std::vector<Aabb> same(100000, Aabb{glm::vec3(0), glm::vec3(1)});
  for (const char* builder : {"binned-sah", "median", "pca-median", "distant-median", "sah-guarded"}) {
    SCOPED_TRACE(builder);
    const bvh::Tree tree = bvh::build(builder, boxes);
    EXPECT_EQ(bvh::check_tree(tree, boxes), "");
    expect_leaf_rule(tree, 4);
    std::printf("  %-15s 1e5 random boxes: SAH cost %.3f, depth %zu\n", builder, bvh::metrics(tree).sah_cost,
                bvh::metrics(tree).depth);
  }
  for (const Combination& combo : {Combination{SplitAxis::Pca, SplitPosition::Mean, SplitCost::Sah},
                                   Combination{SplitAxis::Best, SplitPosition::Binned, SplitCost::Overlap},
                                   Combination{SplitAxis::Longest, SplitPosition::ExtentMedian, SplitCost::Sah}}) {
    SCOPED_TRACE(combo.spec());
    build_and_check(line, combo.options(4));
    const bvh::Tree t = build_and_check(same, combo.options(4));
    EXPECT_LE(bvh::metrics(t).depth, 16u);  // 25,000 leaves: halving by id gives depth 16
  }
}

TEST(TopDown, DefaultsAreBinnedSah) {
  test::Rng rng{5};
  std::vector<Aabb> boxes(5000);
  for (Aabb& b : boxes) b = test::random_aabb(rng, 50.0f, 2.0f);
  EXPECT_EQ(bvh::build_top_down(boxes), bvh::build_binned_sah(boxes));
  for (std::uint32_t leaf : {1u, 4u, 9u})
    for (std::uint32_t bins : {2u, 16u, 40u}) {
      bvh::BuildOptions o;
      o.max_leaf_size = leaf;
      o.bins = bins;
      EXPECT_EQ(bvh::build_top_down(boxes, o), bvh::build_binned_sah(boxes, {leaf, bins})) << leaf << " " << bins;
      EXPECT_EQ(bvh::build("binned-sah", boxes, o), bvh::build_binned_sah(boxes, {leaf, bins}));
      EXPECT_EQ(bvh::build("top-down", boxes, o), bvh::build_binned_sah(boxes, {leaf, bins}));
    }
}

TEST(TopDown, GenericBinnedSahMatchesTheFastBuilder) {
  // On zero-size boxes, the children of a split along an axis never overlap (their centres,
  // which are the boxes, lie on either side of a bin boundary), so the guarded SAH never
  // intervenes and its generic binned builder must give exactly build_binned_sah's tree.
  test::Rng rng{13};
  std::vector<Aabb> points(4000);
  for (Aabb& b : points) {
    const glm::vec3 p = rng.vec3(-50.0f, 50.0f) * glm::vec3(1.0f, 0.3f, 0.1f);
    b = {p, p};
  }
  for (std::size_t i = 0; i < 500; ++i) points[i] = points[i + 1000];  // some duplicates
  for (std::uint32_t leaf : {1u, 4u})
    for (std::uint32_t bins : {2u, 16u, 33u}) {
      bvh::BuildOptions o;
      o.max_leaf_size = leaf;
      o.bins = bins;
      o.cost = SplitCost::SahOverlapGuarded;
      const bvh::Tree generic = bvh::build_top_down(points, o);
      EXPECT_EQ(generic, bvh::build_binned_sah(points, {leaf, bins})) << leaf << " " << bins;
      // Each variant of the fast builder on its own (build_binned_sah runs one of them).
      bvh::detail::BinnedScratch scratch;
      bvh::Tree variant;
      bvh::detail::baseline::build(points, {leaf, bins}, scratch, variant);
      EXPECT_EQ(generic, variant) << "baseline, " << leaf << " " << bins;
      if (bvh::detail::binned_sah_avx2_available()) {
        bvh::detail::avx2::build(points, {leaf, bins}, scratch, variant);
        EXPECT_EQ(generic, variant) << "AVX2, " << leaf << " " << bins;
      }
    }
}

TEST(TopDown, SplitPositionsOnALine) {
  // Centres at x = 0 1 2 3 10 20 30 100 (y and z equal): the root's two children are
  //   median: {0 1 2 3} {10 20 30 100};  mean (21.125): {0 .. 20} {30 100};
  //   extent middle (50): {0 .. 30} {100}
  // for every axis rule (all directions are +-x here, so the sides may be swapped).
  const float xs[] = {0, 1, 2, 3, 10, 20, 30, 100};
  std::vector<Aabb> boxes;
  for (float x : xs) boxes.push_back({glm::vec3(x - 0.5f, 0, 0), glm::vec3(x + 0.5f, 1, 1)});
  const std::vector<std::pair<SplitPosition, std::set<std::uint32_t>>> expected = {
      {SplitPosition::Median, {0, 1, 2, 3}},
      {SplitPosition::Mean, {0, 1, 2, 3, 4, 5}},
      {SplitPosition::ExtentMedian, {0, 1, 2, 3, 4, 5, 6}}};
  for (SplitAxis axis : kAxes)
    for (const auto& [position, low] : expected)
      for (SplitCost cost : kCosts) {
        const Combination combo{axis, position, cost};
        SCOPED_TRACE(combo.spec());
        const bvh::FlatTree flat = bvh::flatten(build_and_check(boxes, combo.options(7)));
        const bvh::FlatNode& first = flat.nodes[1];
        const std::set<std::uint32_t> got(flat.objects.begin() + first.first,
                                          flat.objects.begin() + first.first + first.count);
        std::set<std::uint32_t> high;
        for (std::uint32_t i = 0; i < 8; ++i)
          if (!low.contains(i)) high.insert(i);
        EXPECT_TRUE(got == low || got == high);
      }
}

TEST(TopDown, BinnedSahBeatsMedianOnClusteredScenes) {
  // Binned SAH is far cheaper than the longest-axis median on clustered scenes; require 10%,
  // well inside the gap, so that no seed makes the test flaky.
  for (std::uint64_t seed : {1u, 2u, 3u}) {
    const std::vector<Aabb> boxes = world_aabbs(generate_scene(SceneKind::Clustered, 20000, seed));
    const double sah = bvh::metrics(bvh::build("binned-sah", boxes)).sah_cost;
    const double median = bvh::metrics(bvh::build("median", boxes)).sah_cost;
    std::printf("  seed %llu: SAH cost binned-sah %.3f, median %.3f\n", static_cast<unsigned long long>(seed), sah,
                median);
    EXPECT_LT(sah * 1.1, median) << "seed " << seed;
  }
}

TEST(TopDown, GuardedSahPassesOverHeavilyOverlappingSplits) {
  // One box filling the scene plus 400 small ones inside it. Whichever child gets the big box
  // is the whole scene, so a split's overlap is the other child's volume: SAH's choice (about
  // half the objects each side) overlaps in about half the volume, and the guarded SAH must
  // instead take a split whose other child is at most a quarter of the volume.
  test::Rng rng{8};
  std::vector<Aabb> boxes{Aabb{glm::vec3(0), glm::vec3(10)}};
  for (int i = 0; i < 400; ++i) {
    const glm::vec3 c = rng.vec3(0.5f, 9.5f);
    boxes.push_back({c - glm::vec3(0.2f), c + glm::vec3(0.2f)});
  }
  const auto root_overlap = [&](const char* builder) {
    const bvh::Tree t = bvh::build(builder, boxes);
    EXPECT_EQ(bvh::check_tree(t, boxes), "");
    const Aabb& l = t.nodes[t.nodes[0].left].box;
    const Aabb& r = t.nodes[t.nodes[0].right].box;
    const glm::vec3 e = glm::max(glm::min(l.max, r.max) - glm::max(l.min, r.min), glm::vec3(0));
    return double(e.x) * e.y * e.z / 1000.0;
  };
  const double sah = root_overlap("binned-sah"), guarded = root_overlap("sah-guarded");
  std::printf("  root children overlap / root volume: binned-sah %.3f, sah-guarded %.3f\n", sah, guarded);
  EXPECT_GT(sah, 0.25);
  EXPECT_LE(guarded, 0.25);
  EXPECT_GT(guarded, 0.1);  // the best SAH among the acceptable splits: as large a small side as allowed
}

TEST(TopDown, PcaFollowsAnOrientedScene) {
  // Centres spread +-100 along d = (1, -1, 0)/sqrt2 and +-60 across it (along (1, 1, 0)/sqrt2):
  // the principal axis is d, while the longest coordinate axis (x) mixes both spreads. The
  // PCA median's root split must be (nearly) the split at the median along d; the x median's
  // is far from it.
  test::Rng rng{17};
  const glm::vec3 d = glm::normalize(glm::vec3(1, -1, 0)), across = glm::normalize(glm::vec3(1, 1, 0));
  std::vector<Aabb> boxes;
  std::vector<float> along;
  for (int i = 0; i < 2000; ++i) {
    const float t = rng.uniform(-100.0f, 100.0f);
    const glm::vec3 c = d * t + across * rng.uniform(-60.0f, 60.0f) + glm::vec3(0, 0, rng.uniform(-1.0f, 1.0f));
    boxes.push_back({c - glm::vec3(0.25f), c + glm::vec3(0.25f)});
    along.push_back(t);
  }
  std::vector<float> sorted = along;
  std::nth_element(sorted.begin(), sorted.begin() + 1000, sorted.end());
  const float median_t = sorted[1000];
  // Fraction of objects on the "wrong" side of the ideal split (the smaller of the two ways
  // of matching the root's children to the two halves).
  const auto mismatch = [&](const char* builder) {
    const bvh::FlatTree flat = bvh::flatten(bvh::build(builder, boxes));
    const bvh::FlatNode& first = flat.nodes[1];
    std::size_t low_in_first = 0;
    for (std::uint32_t k = first.first; k < first.first + first.count; ++k)
      low_in_first += along[flat.objects[k]] < median_t;
    const double f = double(low_in_first) / double(first.count);
    return std::min(f, 1.0 - f);
  };
  EXPECT_LT(mismatch("pca-median"), 0.03);
  EXPECT_GT(mismatch("median"), 0.10);
}

// ------------------------------------------------------------------- detailed metrics

TEST(DetailedMetrics, HandBuiltTree) {
  // root [0,4]x[0,2]x[0,1] (volume 8)
  //   left leaf  [0,2]x[0,2]x[0,1] (4), 2 objects
  //   right      [1,4]x[0,2]x[0,1] (6)
  //     leaf [1,2]x[0,1]x[0,1] (1), 1 object;  leaf [3,4]x[0,2]x[0,1] (2), 3 objects
  bvh::Tree t;
  t.objects = {0, 1, 2, 3, 4, 5};
  t.nodes.resize(5);
  t.nodes[0] = {{glm::vec3(0, 0, 0), glm::vec3(4, 2, 1)}, 1, 2, 0, 0};
  t.nodes[1] = {{glm::vec3(0, 0, 0), glm::vec3(2, 2, 1)}, bvh::kNone, bvh::kNone, 0, 2};
  t.nodes[2] = {{glm::vec3(1, 0, 0), glm::vec3(4, 2, 1)}, 3, 4, 0, 0};
  t.nodes[3] = {{glm::vec3(1, 0, 0), glm::vec3(2, 1, 1)}, bvh::kNone, bvh::kNone, 2, 1};
  t.nodes[4] = {{glm::vec3(3, 0, 0), glm::vec3(4, 2, 1)}, bvh::kNone, bvh::kNone, 3, 3};
  const bvh::DetailedMetrics m = bvh::detailed_metrics(t);
  const bvh::Metrics basic = bvh::metrics(t);
  EXPECT_EQ(m.basic.sah_cost, basic.sah_cost);
  EXPECT_EQ(m.basic.nodes, 5u);
  EXPECT_EQ(m.basic.leaves, 3u);
  EXPECT_EQ(m.basic.depth, 3u);
  EXPECT_EQ(m.total_volume, 21.0 / 8.0);   // (8 + 4 + 6 + 1 + 2) / 8
  EXPECT_EQ(m.overlap_volume, 2.0 / 8.0);  // root's children share [1,2]x[0,2]x[0,1]; node 2's are disjoint
  EXPECT_EQ(m.leaf_sizes, (std::vector<std::size_t>{0, 1, 1, 1}));
  EXPECT_DOUBLE_EQ(m.mean_leaf_depth, 8.0 / 3.0);  // depths 2, 3, 3
  EXPECT_EQ(m.balance, 1.0);                       // depth 3 / (ceil(log2 3) + 1)

  // A chain: depth 4 over 4 leaves is 4 / (2 + 1).
  bvh::Tree chain;
  chain.objects = {0, 1, 2, 3};
  const Aabb unit{glm::vec3(0), glm::vec3(1)};
  chain.nodes = {{unit, 1, 2, 0, 0},
                 {unit, bvh::kNone, bvh::kNone, 0, 1},
                 {unit, 3, 4, 0, 0},
                 {unit, bvh::kNone, bvh::kNone, 1, 1},
                 {unit, 5, 6, 0, 0},
                 {unit, bvh::kNone, bvh::kNone, 2, 1},
                 {unit, bvh::kNone, bvh::kNone, 3, 1}};
  const bvh::DetailedMetrics c = bvh::detailed_metrics(chain);
  EXPECT_EQ(c.balance, 4.0 / 3.0);
  EXPECT_EQ(c.mean_leaf_depth, (2.0 + 3.0 + 4.0 + 4.0) / 4.0);
  EXPECT_EQ(c.total_volume, 7.0);
  EXPECT_EQ(c.overlap_volume, 3.0);  // every pair of children coincides with its parent
  EXPECT_EQ(c.leaf_sizes, (std::vector<std::size_t>{0, 4}));
}

TEST(DetailedMetrics, EmptyFlatAndSingleLeafTrees) {
  const bvh::DetailedMetrics empty = bvh::detailed_metrics(bvh::Tree{});
  EXPECT_EQ(empty.basic.nodes, 0u);
  EXPECT_EQ(empty.total_volume, 0.0);
  EXPECT_EQ(empty.overlap_volume, 0.0);
  EXPECT_EQ(empty.mean_leaf_depth, 0.0);
  EXPECT_EQ(empty.balance, 0.0);
  EXPECT_TRUE(empty.leaf_sizes.empty());

  // Flat scene: root volume 0, so the volume ratios are 0 (never NaN).
  std::vector<Aabb> flat;
  for (int i = 0; i < 50; ++i) flat.push_back({glm::vec3(float(i), 0, 0), glm::vec3(float(i) + 0.5f, 1, 0)});
  const bvh::DetailedMetrics f = bvh::detailed_metrics(bvh::build_top_down(flat));
  EXPECT_EQ(f.total_volume, 0.0);
  EXPECT_EQ(f.overlap_volume, 0.0);
  EXPECT_FALSE(std::isnan(f.balance) || std::isnan(f.mean_leaf_depth));

  const std::vector<Aabb> three(3, Aabb{glm::vec3(0), glm::vec3(2)});
  const bvh::DetailedMetrics one = bvh::detailed_metrics(bvh::build_top_down(three));
  EXPECT_EQ(one.total_volume, 1.0);
  EXPECT_EQ(one.overlap_volume, 0.0);
  EXPECT_EQ(one.leaf_sizes, (std::vector<std::size_t>{0, 0, 0, 1}));
  EXPECT_EQ(one.mean_leaf_depth, 1.0);
  EXPECT_EQ(one.balance, 1.0);
}

TEST(DetailedMetrics, BuiltTreesAreConsistent) {
  test::Rng rng{2};
  std::vector<Aabb> boxes(3000);
  for (Aabb& b : boxes) b = test::random_aabb(rng, 30.0f, 2.0f);
  for (const char* builder : {"binned-sah", "median", "overlap"}) {
    SCOPED_TRACE(builder);
    const bvh::Tree tree = bvh::build(builder, boxes);
    const bvh::DetailedMetrics m = bvh::detailed_metrics(tree);
    std::size_t leaves = 0, objects = 0;
    for (std::size_t k = 0; k < m.leaf_sizes.size(); ++k) leaves += m.leaf_sizes[k], objects += k * m.leaf_sizes[k];
    EXPECT_EQ(leaves, m.basic.leaves);
    EXPECT_EQ(objects, boxes.size());
    EXPECT_EQ(m.leaf_sizes.size(), m.basic.max_leaf_size + 1);
    EXPECT_GE(m.total_volume, 1.0);
    EXPECT_GE(m.overlap_volume, 0.0);
    EXPECT_GE(m.balance, 1.0);  // no tree over n leaves is shallower than ceil(log2 n) + 1
    EXPECT_LE(m.mean_leaf_depth, double(m.basic.depth));
    EXPECT_GE(m.mean_leaf_depth, std::log2(double(m.basic.leaves)));  // Kraft: sum 2^-depth <= 1
  }
}

// --------------------------------------------------------------------------- registry

TEST(Registry, ListsEveryBuilderOnce) {
  const std::vector<std::string> expected = {"binned-sah",
                                             "median",
                                             "mean",
                                             "extent-median",
                                             "pca-median",
                                             "distant-median",
                                             "volume",
                                             "largest-volume",
                                             "overlap",
                                             "separation",
                                             "sah-guarded",
                                             "agglomerative-brute",
                                             "agglomerative-pq",
                                             "agglomerative-local",
                                             "insertion-greedy",
                                             "insertion-bnb"};
  std::vector<std::string> names;
  for (const bvh::BuilderInfo& b : bvh::builders()) {
    names.emplace_back(b.name);
    EXPECT_FALSE(b.description.empty()) << b.name;
  }
  EXPECT_EQ(names, expected);
}

TEST(Registry, NamedTopDownBuildersUseTheirSplits) {
  test::Rng rng{4};
  std::vector<Aabb> boxes(800);
  for (Aabb& b : boxes) b = test::random_aabb(rng, 30.0f, 2.0f);
  const std::vector<std::pair<std::string, Combination>> named = {
      {"binned-sah", {SplitAxis::Best, SplitPosition::Binned, SplitCost::Sah}},
      {"median", {SplitAxis::Longest, SplitPosition::Median, SplitCost::Sah}},
      {"mean", {SplitAxis::Longest, SplitPosition::Mean, SplitCost::Sah}},
      {"extent-median", {SplitAxis::Longest, SplitPosition::ExtentMedian, SplitCost::Sah}},
      {"pca-median", {SplitAxis::Pca, SplitPosition::Median, SplitCost::Sah}},
      {"distant-median", {SplitAxis::DistantCentroids, SplitPosition::Median, SplitCost::Sah}},
      {"volume", {SplitAxis::Best, SplitPosition::Binned, SplitCost::VolumeSum}},
      {"largest-volume", {SplitAxis::Best, SplitPosition::Binned, SplitCost::LargestVolume}},
      {"overlap", {SplitAxis::Best, SplitPosition::Binned, SplitCost::Overlap}},
      {"separation", {SplitAxis::Best, SplitPosition::Binned, SplitCost::Separation}},
      {"sah-guarded", {SplitAxis::Best, SplitPosition::Binned, SplitCost::SahOverlapGuarded}},
  };
  std::set<std::vector<std::uint32_t>> distinct;  // the named builders really differ
  for (const auto& [builder, combo] : named) {
    SCOPED_TRACE(builder);
    bvh::BuildOptions o;  // the name overrides whatever split the options ask for
    o.axis = SplitAxis::Pca;
    o.position = SplitPosition::Mean;
    o.cost = SplitCost::Overlap;
    o.max_leaf_size = 3;
    const bvh::Tree t = bvh::build(builder, boxes, o);
    EXPECT_EQ(t, bvh::build_top_down(boxes, combo.options(3)));
    distinct.insert(t.objects);
  }
  EXPECT_GE(distinct.size(), 9u);
}

TEST(Registry, ParametricTopDownGrammar) {
  test::Rng rng{6};
  std::vector<Aabb> boxes(300);
  for (Aabb& b : boxes) b = test::random_aabb(rng, 30.0f, 2.0f);
  for (const Combination& combo : all_combinations()) {
    SCOPED_TRACE(combo.spec());
    EXPECT_EQ(bvh::build(combo.spec(), boxes, combo.options(4)), bvh::build_top_down(boxes, combo.options(4)));
    // Parameters in any order; the options' split fields are overridden.
    const std::string reordered = std::string("top-down:cost=") + name(combo.cost) + ",axis=" + name(combo.axis) +
                                  ",split=" + name(combo.position);
    EXPECT_EQ(bvh::build(reordered, boxes), bvh::build_top_down(boxes, combo.options(4)));
  }
  // Parts left out keep the options' values.
  bvh::BuildOptions o;
  o.axis = SplitAxis::Longest;
  o.cost = SplitCost::Overlap;
  o.max_leaf_size = 2;
  bvh::BuildOptions expected = o;
  expected.position = SplitPosition::Mean;
  EXPECT_EQ(bvh::build("top-down:split=mean", boxes, o), bvh::build_top_down(boxes, expected));
  EXPECT_EQ(bvh::build("top-down", boxes, o), bvh::build_top_down(boxes, o));
  EXPECT_EQ(bvh::build("top-down:", boxes, o), bvh::build_top_down(boxes, o));
}

// The message of the invalid_argument that build(name) throws ("" when it does not throw one).
std::string build_error(const std::string& builder) {
  try {
    (void)bvh::build(builder, {});
  } catch (const std::invalid_argument& e) {
    return e.what();
  } catch (const std::logic_error&) {  // a builder not written yet: the name was accepted
  }
  return "";
}

TEST(Registry, BadNamesAndParametersThrowNamingThePartAndTheBuilders) {
  const std::vector<std::pair<std::string, std::string>> bad = {
      {"no-such-builder", "no-such-builder"},
      {"", "unknown name"},
      {"Binned-SAH", "Binned-SAH"},
      {"binned-sah ", "binned-sah "},
      {"top-down:axis=diagonal", "diagonal"},
      {"top-down:split=quartile", "quartile"},
      {"top-down:cost=cheap", "cheap"},
      {"top-down:speed=fast", "speed"},
      {"top-down:axis", "not key=value"},
      {"top-down:axis=pca,", "empty parameter"},
      {"top-down:,axis=pca", "not key=value"},
      {"top-down:axis=pca,axis=best", "twice"},
      {"top-downs", "top-downs"},
      {"median+rotations", "+rotations"},
      {"binned-sah+rotations", "+rotations"},
      {"insertion-greedy+spin", "insertion-greedy+spin"},
  };
  for (const auto& [builder, part] : bad) {
    SCOPED_TRACE("'" + builder + "'");
    const std::string message = build_error(builder);
    ASSERT_FALSE(message.empty()) << "no std::invalid_argument";
    EXPECT_NE(message.find(part), std::string::npos) << message;
    EXPECT_NE(message.find("binned-sah"), std::string::npos) << message;  // lists the known builders
    EXPECT_NE(message.find("insertion-bnb"), std::string::npos) << message;
    EXPECT_NE(message.find("top-down:axis="), std::string::npos) << message;
  }
}

TEST(Registry, EveryNameParses) {
  // The bottom-up and insertion builders live elsewhere; here only that their names (and
  // "+rotations" on the insertion ones) reach them: no std::invalid_argument on empty input.
  for (const bvh::BuilderInfo& b : bvh::builders()) EXPECT_EQ(build_error(std::string(b.name)), "") << b.name;
  EXPECT_EQ(build_error("insertion-greedy+rotations"), "");
  EXPECT_EQ(build_error("insertion-bnb+rotations"), "");
  for (const Combination& combo : all_combinations()) EXPECT_EQ(build_error(combo.spec()), "") << combo.spec();
}

}  // namespace
}  // namespace cullpipe
