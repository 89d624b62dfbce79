// Hierarchical culling on the GPU (shaders/cull_bvh.comp) against the scalar CPU traversal
// (bvh::cull_hierarchical) bit for bit, and against flat culling object by object, on the
// Vulkan device chosen by CULLPIPE_DEVICE with validation (including synchronization
// validation) on: any message fails.
#include <gtest/gtest.h>
#include <unistd.h>

#include <algorithm>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <glm/gtc/matrix_transform.hpp>
#include <memory>

#include "bvh_test_util.hpp"
#include "cullpipe/bvh/builders.hpp"
#include "cullpipe/bvh/bvh.hpp"
#include "cullpipe/cull/compare.hpp"
#include "cullpipe/cull/reference.hpp"
#include "cullpipe/geom/validate.hpp"
#include "cullpipe/gpu/bvh_culler.hpp"
#include "cullpipe/scene/generators.hpp"
#include "cullpipe/scene/gltf_scene.hpp"
#include "cullpipe/vulkan/check.hpp"
#include "edge_sets.hpp"
#include "gpu_test_env.hpp"
#include "test_util.hpp"

namespace cullpipe {
namespace {

using GpuBvhEnvironment = test::GpuTestEnvironment<gpu::BvhCuller>;
const auto* const kEnvironment = ::testing::AddGlobalTestEnvironment(new GpuBvhEnvironment);
using GpuBvh = test::GpuTest<gpu::BvhCuller>;

// Culls `boxes` through `flat` on the GPU, all views in one pass, and checks every view: the
// classes equal the CPU hierarchical traversal's object by object (and flat culling's), the
// counters and the node/object test counts equal the CPU's, and the visible list holds each
// visible object exactly once. A mismatch prints the object, the planes and both answers.
template <class Volume>
gpu::CullResult expect_agreement(gpu::BvhCuller& culler, const bvh::FlatTree& flat, const std::vector<Volume>& boxes,
                                 const std::vector<Frustum>& frusta, const gpu::CullOptions& options = {}) {
  const std::span<const Volume> volumes(boxes);
  culler.upload(flat, volumes);
  gpu::CullResult result = culler.cull(frusta, options);
  EXPECT_EQ(result.views.size(), frusta.size());
  const std::size_t capacity = options.visible_capacity ? options.visible_capacity : boxes.size();
  for (std::size_t v = 0; v < frusta.size() && v < result.views.size(); ++v) {
    const bvh::HierarchicalResult cpu = bvh::cull_hierarchical(flat, volumes, frusta[v]);
    std::vector<Classification> flat_classes(boxes.size());
    const reference::CullCounts counts = reference::classify_all(volumes, frusta[v], flat_classes);
    EXPECT_EQ(cpu.classes, flat_classes) << "CPU hierarchical vs flat, view " << v;
    const gpu::ViewResult& g = result.views[v];
    // Without classes the counters, test counts and list are checked (and no classes come back).
    const std::span<const Classification> gpu_classes =
        options.classes ? std::span<const Classification>(g.classes) : cpu.classes;
    if (!options.classes) {
      EXPECT_TRUE(g.classes.empty()) << "view " << v;
    }
    const Agreement a = check_agreement<Volume>(volumes, frusta[v], cpu.classes, counts, gpu_classes, g.counts,
                                                g.visible_ids, capacity);
    EXPECT_TRUE(a.ok()) << a.mismatches << " mismatches in view " << v
                        << "; first: " << (a.reports.empty() ? "" : a.reports[0]);
    EXPECT_EQ(g.node_tests, cpu.node_tests) << "view " << v;
    EXPECT_EQ(g.object_tests, cpu.object_tests) << "view " << v;
    EXPECT_EQ(g.overflow, counts.visible > capacity) << "view " << v;
  }
  return result;
}

bvh::FlatTree flat_tree(const std::vector<Aabb>& boxes, std::uint32_t leaf = 4) {
  return bvh::flatten(bvh::build_binned_sah(boxes, {leaf, 16}));
}

std::vector<Frustum> test_frusta() {
  return {Frustum::from_view_proj(test::test_view_proj()), Frustum::from_view_proj(test::test_view_proj(100.0f, 0.5f)),
          Frustum::from_view_proj(test::test_view_proj(20.0f, 2.0f))};
}

std::vector<Frustum> path_frusta(const Scene& scene, std::size_t count) {
  std::vector<Frustum> frusta;
  for (const Camera& c : camera_path(scene.camera, scene.bounds(), count))
    frusta.push_back(Frustum::from_view_proj(c.view_proj()));
  return frusta;
}

TEST_F(GpuBvh, RandomSetsEverySizeAndLeafSize) {
  test::Rng rng{41};
  for (std::size_t n : {0u, 1u, 2u, 3u, 63u, 64u, 65u, 129u, 1000u, 20000u}) {
    std::vector<Aabb> boxes(n);
    for (Aabb& b : boxes) b = test::random_aabb(rng, 40.0f, 3.0f);
    for (std::uint32_t leaf : {1u, 4u, 16u}) {
      SCOPED_TRACE("n = " + std::to_string(n) + ", leaf " + std::to_string(leaf));
      expect_agreement(culler(), flat_tree(boxes, leaf), boxes, test_frusta());
    }
  }
}

template <class Volume>
bvh::FlatTree tree_over(const std::vector<Volume>& volumes, std::uint32_t leaf = 4) {
  return flat_tree(bvh::enclosing_boxes(std::span<const Volume>(volumes)), leaf);
}

// Writing classes or not is a pipeline of its own (WRITE_CLASSES in cull_bvh.comp): without
// them the counters, test counts and list still equal the CPU traversal's, and a pass asking
// for classes after one that did not gets this pass's classes (each kind's upload changes them).
TEST_F(GpuBvh, TheListIsTheSameWithAndWithoutClasses) {
  test::Rng rng{44};
  const test::RandomVolumes v = test::random_volumes(rng, 5000, 40.0f, 3.0f);
  for (bool classes : {false, true, false, true}) {
    SCOPED_TRACE(classes ? "classes" : "no classes");
    gpu::CullOptions options;
    options.classes = classes;
    expect_agreement(culler(), flat_tree(v.aabbs, 16), v.aabbs, test_frusta(), options);
    expect_agreement(culler(), tree_over(v.obbs, 16), v.obbs, test_frusta(), options);
    expect_agreement(culler(), tree_over(v.spheres, 16), v.spheres, test_frusta(), options);
  }
}

// The boxes of straddling leaves are settled by their centre bound, as the flat pass's are:
// boxes within float steps of the bound's edge (and far from the origin) get the CPU
// traversal's answers, and views of non-unit normals or planes past the margin's range settle
// nothing (test::aabb_edge_set, its valid boxes: a tree holds no others).
TEST_F(GpuBvh, BoxesAtTheEdgeOfTheirCentreBound) {
  const test::EdgeSet<Aabb> set = test::aabb_edge_set();
  std::vector<Aabb> boxes;
  for (const Aabb& b : set.volumes)
    if (is_valid(b)) boxes.push_back(b);
  for (std::uint32_t leaf : {4u, 16u, 300u}) {
    SCOPED_TRACE("leaf " + std::to_string(leaf));
    const gpu::CullResult r = expect_agreement(culler(), flat_tree(boxes, leaf), boxes, set.views);
    const std::vector<Classification>& mixed = r.views[1].classes;
    for (Classification c : {Classification::Outside, Classification::Intersecting, Classification::Inside})
      EXPECT_GT(std::count(mixed.begin(), mixed.end(), c), 100) << "the edge set is mixed: " << to_string(c);
  }
}

// The walk's stacks in shared memory (a GPU's default) and in the records image (a CPU
// device's) give the same answers and test counts.
TEST_F(GpuBvh, BothPlacesOfTheWalkStackAgree) {
  const bool default_place = culler().walk_stack_in_records();
  struct Restore {
    gpu::BvhCuller& c;
    bool in_records;
    ~Restore() { c.set_walk_stack_in_records(in_records); }
  } restore{culler(), default_place};
  test::Rng rng{45};
  const test::RandomVolumes v = test::random_volumes(rng, 20000, 40.0f, 3.0f);
  for (bool in_records : {false, true}) {
    SCOPED_TRACE(in_records ? "stacks in the records" : "stacks in shared memory");
    culler().set_walk_stack_in_records(in_records);
    EXPECT_EQ(culler().walk_stack_in_records(), in_records);
    for (std::uint32_t leaf : {1u, 16u}) {
      expect_agreement(culler(), flat_tree(v.aabbs, leaf), v.aabbs, test_frusta());
      expect_agreement(culler(), tree_over(v.spheres, leaf), v.spheres, test_frusta());
    }
    gpu::CullOptions no_classes;
    no_classes.classes = false;
    expect_agreement(culler(), tree_over(v.obbs, 16), v.obbs, test_frusta(), no_classes);
  }
}

TEST_F(GpuBvh, ObbAndSphereHierarchiesAgree) {
  test::Rng rng{43};
  for (std::size_t n : {0u, 1u, 65u, 5000u}) {
    const test::RandomVolumes v = test::random_volumes(rng, n, 40.0f, 3.0f);
    for (std::uint32_t leaf : {1u, 4u, 16u, 300u}) {  // (16: whole chunks; 300: leaves of many chunks)
      SCOPED_TRACE("n = " + std::to_string(n) + ", leaf " + std::to_string(leaf));
      expect_agreement(culler(), tree_over(v.obbs, leaf), v.obbs, test_frusta());
      expect_agreement(culler(), tree_over(v.spheres, leaf), v.spheres, test_frusta());
    }
  }
  // Draws, a short list and the kind switching back to boxes on the same culler.
  const test::RandomVolumes v = test::random_volumes(rng, 3000, 40.0f, 3.0f);
  std::vector<gpu::DrawCommand> templates(v.spheres.size());
  for (std::size_t i = 0; i < templates.size(); ++i)
    templates[i] = {std::uint32_t(3 + i % 7), 1, std::uint32_t(i), 0, 0, 0};
  culler().upload_draws(templates);
  gpu::CullOptions options;
  options.draws = true;
  options.visible_capacity = 100;
  expect_agreement(culler(), tree_over(v.spheres), v.spheres, test_frusta(), options);
  EXPECT_EQ(culler().kind(), BvKind::Sphere);
  expect_agreement(culler(), flat_tree(v.aabbs), v.aabbs, test_frusta());
  EXPECT_EQ(culler().kind(), BvKind::Aabb);
}

TEST_F(GpuBvh, ObbAndSphereHierarchiesRefuseNonUnitNormals) {
  // The node margin's error bound takes unit normals (boxes need none).
  test::Rng rng{53};
  const test::RandomVolumes v = test::random_volumes(rng, 100, 20.0f, 2.0f);
  Frustum f = Frustum::from_view_proj(test::test_view_proj());
  f.planes[0].normal *= 0.5f;
  culler().upload(tree_over(v.spheres), std::span<const Sphere>(v.spheres));
  EXPECT_THROW(culler().cull(std::span(&f, 1)), std::invalid_argument);
  culler().upload(flat_tree(v.aabbs), std::span<const Aabb>(v.aabbs));
  EXPECT_NO_THROW(culler().cull(std::span(&f, 1)));
}

TEST_F(GpuBvh, VolumesAtThePlanesFarFromTheOriginAgree) {
  // Spheres and OBBs touching the planes of a camera 10^5 from the origin, among them volumes
  // whose node a margin-free test would misjudge: the GPU must make exactly the CPU's
  // decisions (classes and test counts), which equal flat culling's.
  test::Rng rng{47};
  const glm::vec3 eye(1.0e5f, -3.0e4f, 2.0e5f);
  const Frustum f = test::frustum_at(eye);
  const test::TouchingVolumes set = test::touching_volumes(f, eye, rng, 20000);
  EXPECT_GT(set.contradicting, 0u);
  for (std::uint32_t leaf : {1u, 4u, 16u, 40u}) {
    expect_agreement(culler(), tree_over(set.spheres, leaf), set.spheres, {f});
    expect_agreement(culler(), tree_over(set.obbs, leaf), set.obbs, {f});
  }
}

TEST_F(GpuBvh, GeneratedScenesManyViewsInOnePass) {
  for (SceneKind kind : {SceneKind::Uniform, SceneKind::Clustered, SceneKind::City}) {
    SCOPED_TRACE(std::string(to_string(kind)));
    const Scene scene = generate_scene(kind, 50000, 9);
    const std::vector<Aabb> boxes = world_aabbs(scene);
    const gpu::CullResult r = expect_agreement(culler(), flat_tree(boxes), boxes, path_frusta(scene, 8));
    // The hierarchy pays: far fewer tests than objects in the first view.
    ASSERT_FALSE(r.views.empty());
    std::printf("  %s: %zu of %zu visible, %zu node + %zu object tests on the GPU\n",
                std::string(to_string(kind)).c_str(), r.views[0].counts.visible, boxes.size(), r.views[0].node_tests,
                r.views[0].object_tests);
    EXPECT_LT(r.views[0].node_tests + r.views[0].object_tests, boxes.size() / 2);
  }
}

TEST_F(GpuBvh, EveryBuilderAgrees) {
  const Scene scene = generate_scene(SceneKind::Clustered, 3000, 4);
  const std::vector<Aabb> boxes = world_aabbs(scene);
  for (const bvh::BuilderInfo& b : bvh::builders()) {
    if (b.name == "agglomerative-brute") continue;  // O(n^3): its own tests use small n
    SCOPED_TRACE(std::string(b.name));
    const bvh::FlatTree flat = bvh::flatten(bvh::build(b.name, boxes));
    expect_agreement(culler(), flat, boxes, path_frusta(scene, 4));
  }
}

TEST_F(GpuBvh, EverythingInsideEverythingOutsideAndDeepTrees) {
  // One frustum holds every object (accepted at the root with one node test), one holds none.
  std::vector<Aabb> boxes;
  test::Rng rng{3};
  for (int i = 0; i < 5000; ++i) boxes.push_back(test::random_aabb(rng, 1.0f, 0.2f));
  for (Aabb& b : boxes) b = {b.min + glm::vec3(0, 0, 5.0f), b.max + glm::vec3(0, 0, 5.0f)};  // around z = 4.5
  const glm::mat4 view_proj = test::test_view_proj(90.0f, 1.0f);
  const glm::mat4 away = view_proj * glm::translate(glm::mat4(1.0f), glm::vec3(0, 0, 10.0f));  // all behind the camera
  const gpu::CullResult r = expect_agreement(culler(), flat_tree(boxes), boxes,
                                             {Frustum::from_view_proj(view_proj), Frustum::from_view_proj(away)});
  ASSERT_EQ(r.views.size(), 2u);
  EXPECT_EQ(r.views[0].counts.inside, boxes.size());
  EXPECT_EQ(r.views[0].node_tests, 1u);
  EXPECT_EQ(r.views[0].object_tests, 0u);
  EXPECT_EQ(r.views[1].counts.visible, 0u);
  EXPECT_EQ(r.views[1].node_tests, 1u);
  // Points on a line with one object per leaf: the tree is deep.
  std::vector<Aabb> line;
  for (int i = 0; i < 3000; ++i)
    line.push_back({glm::vec3(float(i) * 0.02f - 30.0f, 0, 0), glm::vec3(float(i) * 0.02f - 30.0f, 0.1f, 0)});
  expect_agreement(culler(), flat_tree(line, 1), line, test_frusta());
  EXPECT_GE(culler().levels(), 12u);
  // All boxes identical.
  const std::vector<Aabb> same(777, Aabb{glm::vec3(-1), glm::vec3(1)});
  expect_agreement(culler(), flat_tree(same, 2), same, test_frusta());
}

// A chain: every inner node holds one object's leaf and the rest of the chain, so the tree is
// as deep as it has objects (far deeper than a cut subtree may be).
bvh::Tree chain_tree(const std::vector<Aabb>& boxes) {
  const auto n = std::uint32_t(boxes.size());
  bvh::Tree t;
  for (std::uint32_t k = 0; k < n; ++k) t.objects.push_back(k);
  if (n == 0) return t;
  t.nodes.resize(2 * std::size_t(n) - 1);
  Aabb rest = boxes[n - 1];
  t.nodes[2 * (n - 1)] = {rest, bvh::kNone, bvh::kNone, n - 1, 1};
  for (std::uint32_t k = n - 1; k-- > 0;) {
    t.nodes[2 * k + 1] = {boxes[k], bvh::kNone, bvh::kNone, k, 1};
    rest = {glm::min(rest.min, boxes[k].min), glm::max(rest.max, boxes[k].max)};
    t.nodes[2 * k] = {rest, 2 * k + 1, 2 * k + 2, k, n - k};
  }
  return t;
}

// The traversal's cut at every size, several views of 6, 5 and 1 planes in one pass: one
// invocation per leaf (the nodes above tested by many invocations, each test counted once),
// with the dispatch folded into y; small and large subtrees, the whole tree in one
// invocation, leaves larger than the cut, a chain far deeper than BVH_CUT_MAX_HEIGHT (cut
// into short subtrees whatever the size), and a visible list too short for the objects.
TEST_F(GpuBvh, EveryCutSizeAgrees) {
  test::Rng rng{59};
  std::vector<Aabb> boxes(6000);
  for (Aabb& b : boxes) b = test::random_aabb(rng, 40.0f, 3.0f);
  std::vector<Aabb> line;
  for (int i = 0; i < 400; ++i)
    line.push_back(
        {glm::vec3(float(i) * 0.2f - 40.0f, -1.0f, -20.0f), glm::vec3(float(i) * 0.2f - 39.9f, 1.0f, -19.0f)});
  const bvh::FlatTree chain = bvh::flatten(chain_tree(line));
  ASSERT_EQ(bvh::check_flat_tree(chain, std::span<const Aabb>(line)), "");
  const test::RandomVolumes v = test::random_volumes(rng, 3000, 40.0f, 3.0f);
  // Views of 6, 5 (no far plane) and 1 plane: unused plane slots must never count.
  std::vector<Frustum> frusta = test_frusta();
  std::vector<glm::vec4> planes;
  for (const Plane& p : frusta[0].active()) planes.emplace_back(p.normal, p.d);
  frusta.push_back(Frustum::from_planes(std::span(planes).first(5)));
  frusta.push_back(Frustum::from_planes(std::span(planes).first(1)));
  // The culler is shared by the suite's tests: its settings come back whatever happens here.
  struct Restore {
    gpu::BvhCuller& c;
    std::uint32_t objects;
    ~Restore() {
      c.set_subtree_objects(objects);
      c.set_max_groups_per_dispatch(0);
    }
  } restore{culler(), culler().subtree_objects()};
  for (std::uint32_t cut : {1u, 3u, 64u, 1000u, 1u << 30}) {
    SCOPED_TRACE("subtrees of <= " + std::to_string(cut) + " objects");
    culler().set_subtree_objects(cut);
    // With one object per subtree, thousands of workgroups per view: fold them into y, three
    // along x, so that groups past the last view exist (and return).
    culler().set_max_groups_per_dispatch(cut == 1 ? 3 : 0);
    for (std::uint32_t leaf : {1u, 4u, 300u}) {
      SCOPED_TRACE("leaf " + std::to_string(leaf));
      const bvh::FlatTree flat = flat_tree(boxes, leaf);
      expect_agreement(culler(), flat, boxes, frusta);
      gpu::CullOptions short_list;  // many workgroups filling a short list
      short_list.visible_capacity = 50;
      expect_agreement(culler(), flat, boxes, frusta, short_list);
      std::size_t leaves = 0;
      for (const bvh::FlatNode& node : flat.nodes) leaves += node.leaf ? 1 : 0;
      if (cut == 1) {
        EXPECT_EQ(culler().cut_count(), leaves);
      }
      if (cut == 1u << 30 && leaf == 4) {
        EXPECT_EQ(culler().cut_count(), 1u);
      }
    }
    expect_agreement(culler(), chain, line, frusta);
    EXPECT_GE(culler().cut_count(), line.size() / (gpu::BVH_CUT_MAX_HEIGHT + 1));
    expect_agreement(culler(), tree_over(v.obbs), v.obbs, frusta);
    expect_agreement(culler(), tree_over(v.spheres), v.spheres, frusta);
  }
  EXPECT_THROW(culler().set_subtree_objects(0), std::invalid_argument);
}

// Every node straddles a plane (each box crosses z = 0), so the subgroups walk every node of
// their subtrees: the walk stack grows with the subtrees' depth (complete subtrees of 2^14
// leaves in one cut, then many cuts of 1024 and of 3 objects), and every node and object is
// tested once, as the CPU traversal tests it.
TEST_F(GpuBvh, EveryNodeStraddlingAPlaneWalksTheWholeTree) {
  std::vector<Aabb> boxes;
  for (int x = 0; x < 128; ++x)
    for (int y = 0; y < 128; ++y)
      boxes.push_back({glm::vec3(float(x), float(y), -1.0f), glm::vec3(float(x) + 0.5f, float(y) + 0.5f, 1.0f)});
  const glm::vec4 plane(0, 0, 1, 0);
  const std::vector<Frustum> frusta = {Frustum::from_planes({&plane, 1})};
  struct Restore {
    gpu::BvhCuller& c;
    std::uint32_t objects;
    ~Restore() { c.set_subtree_objects(objects); }
  } restore{culler(), culler().subtree_objects()};
  for (std::uint32_t cut : {1u << 30, 1024u, 3u}) {
    SCOPED_TRACE("subtrees of <= " + std::to_string(cut) + " objects");
    culler().set_subtree_objects(cut);
    const bvh::FlatTree flat = flat_tree(boxes, 1);
    const gpu::CullResult r = expect_agreement(culler(), flat, boxes, frusta);
    ASSERT_EQ(r.views.size(), 1u);
    EXPECT_EQ(r.views[0].node_tests, flat.nodes.size());  // every node, once
    EXPECT_EQ(r.views[0].object_tests, boxes.size());
    EXPECT_EQ(r.views[0].counts.intersecting, boxes.size());
  }
}

// The walk stack of cull_bvh.comp, replayed on the host with every node INTERSECTING (the
// most it can hold): each round takes the top min(size, lanes) entries in order and pushes the
// two children of each inner one in that order. Returns the largest size it reaches.
std::size_t largest_walk_stack(const bvh::FlatTree& t, std::span<const std::uint32_t> cut_nodes, std::size_t lanes) {
  std::vector<std::uint32_t> stack(cut_nodes.begin(), cut_nodes.end());
  std::size_t largest = stack.size();
  while (!stack.empty()) {
    const std::size_t take = std::min(stack.size(), lanes);
    const std::vector<std::uint32_t> taken(stack.end() - std::ptrdiff_t(take), stack.end());
    stack.resize(stack.size() - take);
    for (std::uint32_t node : taken)
      if (!t.nodes[node].leaf) {
        stack.push_back(node + 1);
        stack.push_back(t.nodes[node + 1].skip);
      }
    largest = std::max(largest, stack.size());
  }
  return largest;
}

// The bound the shader's shared memory is sized by (BVH_STACK_PER_INVOCATION entries per
// lane) holds for subtrees of the greatest cut height: one complete subtree of 2^19 leaves, and
// one per lane of 2^12 leaves, at subgroup sizes from 1 to 64.
TEST(GpuBvhWalk, StackStaysWithinItsSharedMemory) {
  for (std::uint32_t height : {12u, gpu::BVH_CUT_MAX_HEIGHT}) {
    std::vector<Aabb> boxes;
    for (std::uint32_t i = 0; i < (1u << height); ++i)
      boxes.push_back({glm::vec3(float(i), 0, 0), glm::vec3(float(i) + 0.5f, 1, 1)});
    const bvh::FlatTree flat = bvh::flatten(bvh::build_binned_sah(boxes, {1, 16}));
    ASSERT_EQ(bvh::metrics(bvh::build_binned_sah(boxes, {1, 16})).depth,
              height + 1);  // complete: height levels below the root
    for (std::size_t lanes : {1u, 2u, 8u, 32u, 64u}) {
      // Subtrees of the same shape under every lane (replays of the one tree: their nodes are
      // told apart by an offset, which the replay does not need).
      const std::vector<std::uint32_t> cuts(height == 12 ? lanes : 1, 0u);
      const std::size_t largest = largest_walk_stack(flat, cuts, lanes);
      EXPECT_LE(largest, lanes * gpu::BVH_STACK_PER_INVOCATION) << "height " << height << ", " << lanes << " lanes";
      EXPECT_GT(largest, lanes * height / 2) << "the replay walks the tree";
    }
  }
}

// The camera inside objects (a room around the eye, boxes the eye sits in), next to objects
// of 1e-30 and 1e30 extent: defined answers, never culled when they contain the eye.
TEST_F(GpuBvh, CameraInsideObjectsAndExtremeSizes) {
  test::Rng rng{19};
  std::vector<Aabb> boxes;
  const glm::vec3 eye(0, 0, 10);                                          // test_view_proj's eye
  boxes.push_back({eye - glm::vec3(100.0f), eye + glm::vec3(100.0f)});    // a room around the camera
  boxes.push_back({eye - glm::vec3(1.0f), eye + glm::vec3(1.0f)});        // the eye in a box past the near plane
  boxes.push_back({eye - glm::vec3(0.01f), eye + glm::vec3(0.01f)});      // ... in one within the near distance
  boxes.push_back({glm::vec3(-1e30f), glm::vec3(1e30f)});                 // everything
  boxes.push_back({glm::vec3(0, 0, 0), glm::vec3(1e-30f)});               // tiny, in view
  boxes.push_back({glm::vec3(0, 0, 20), glm::vec3(0, 0, 20) + 1e-30f});   // tiny, behind the camera
  boxes.push_back({glm::vec3(-1e30f, -1e30f, 1e29f), glm::vec3(1e30f)});  // huge, all behind the camera
  for (int i = 0; i < 3000; ++i) boxes.push_back(test::random_aabb(rng, 30.0f, 2.0f));
  const std::vector<Frustum> frusta = test_frusta();
  const gpu::CullResult r = expect_agreement(culler(), flat_tree(boxes, 2), boxes, frusta);
  for (const gpu::ViewResult& v : r.views) {
    EXPECT_EQ(v.classes[0], Classification::Intersecting);
    EXPECT_EQ(v.classes[1], Classification::Intersecting);  // contains the eye and crosses the near plane
    EXPECT_EQ(v.classes[2], Classification::Outside);       // contains the eye, but ends before the near plane
    EXPECT_EQ(v.classes[3], Classification::Intersecting);
    EXPECT_EQ(v.classes[5], Classification::Outside);
    EXPECT_EQ(v.classes[6], Classification::Outside);
  }
  EXPECT_EQ(r.views[0].classes[4], Classification::Inside);
}

TEST_F(GpuBvh, DrawsAndVisibleListOverflow) {
  test::Rng rng{12};
  std::vector<Aabb> boxes(8000);
  for (Aabb& b : boxes) b = test::random_aabb(rng, 40.0f, 3.0f);
  std::vector<gpu::DrawCommand> templates(boxes.size());
  for (std::uint32_t i = 0; i < templates.size(); ++i) templates[i] = {36, 1, 36 * i, -int(i), i, 0};
  const bvh::FlatTree flat = flat_tree(boxes);
  culler().upload(flat, boxes);
  culler().upload_draws(templates);
  gpu::CullOptions options;
  options.draws = true;
  for (bool classes : {true, false}) {  // (without classes: a pipeline of its own)
    SCOPED_TRACE(classes ? "classes" : "no classes");
    options.classes = classes;
    const gpu::CullResult r = expect_agreement(culler(), flat, boxes, test_frusta(), options);
    for (const gpu::ViewResult& v : r.views) {
      ASSERT_EQ(v.draws.size(), v.visible_ids.size());
      for (std::size_t k = 0; k < v.draws.size(); ++k) {
        gpu::DrawCommand expected = templates[v.visible_ids[k]];
        expected.object_id = v.visible_ids[k];
        ASSERT_EQ(std::memcmp(&v.draws[k], &expected, sizeof expected), 0) << k;
      }
    }
  }
  options.classes = true;
  options.visible_capacity = 100;  // fewer than visible: counted in full, flagged, list full
  const gpu::CullResult small = expect_agreement(culler(), flat, boxes, test_frusta(), options);
  for (const gpu::ViewResult& v : small.views) {
    EXPECT_TRUE(v.overflow);
    EXPECT_EQ(v.visible_ids.size(), 100u);
    EXPECT_EQ(v.draws.size(), 100u);
  }
}

TEST_F(GpuBvh, RefitAfterMotionStaysExact) {
  const Scene scene = generate_scene(SceneKind::City, 20000, 2);
  std::vector<Aabb> boxes = world_aabbs(scene);
  bvh::FlatTree flat = flat_tree(boxes);
  const std::vector<Frustum> frusta = path_frusta(scene, 3);
  test::Rng rng{77};
  for (int frame = 0; frame < 3; ++frame) {
    for (Aabb& b : boxes) {
      const glm::vec3 d = rng.vec3(-2.0f, 2.0f);
      b = {b.min + d, b.max + d};
    }
    bvh::refit(flat, boxes);
    expect_agreement(culler(), flat, boxes, frusta);
  }
}

// The real glTF scenes: every object's world AABB, the scene's own camera path.
TEST_F(GpuBvh, GltfScenesAgree) {
  const std::filesystem::path dir = std::filesystem::path(CULLPIPE_SHARED_DIR) / "scenes";
  if (!std::filesystem::exists(dir)) GTEST_SKIP() << dir << " not present";
  std::size_t files = 0;
  for (const auto& sub : std::filesystem::directory_iterator(dir)) {
    if (!sub.is_directory()) continue;
    for (const auto& file : std::filesystem::directory_iterator(sub.path())) {
      if (file.path().extension() != ".gltf") continue;
      SCOPED_TRACE(file.path().string());
      ++files;
      const GltfScene g = load_gltf_scene(file.path().string());
      const std::vector<Aabb> boxes = world_aabbs(g.scene);
      expect_agreement(culler(), flat_tree(boxes), boxes, path_frusta(g.scene, 6));
      const Scene big = replicate_scene(g.scene, 100, InstanceLayout::Random, 5);
      const std::vector<Aabb> big_boxes = world_aabbs(big);
      expect_agreement(culler(), flat_tree(big_boxes), big_boxes, path_frusta(big, 4));
    }
  }
  EXPECT_EQ(files, 10u);
}

TEST_F(GpuBvh, RecordsIntoTheCallersCommandBuffer) {
  const vulkan::Context& ctx = *GpuBvhEnvironment::context;
  const Scene scene = generate_scene(SceneKind::Uniform, 10000, 5);
  const std::vector<Aabb> boxes = world_aabbs(scene);
  const bvh::FlatTree flat = flat_tree(boxes);
  culler().upload(flat, boxes);
  const std::vector<Frustum> frusta = path_frusta(scene, 2);
  VkDevice dev = ctx.device();
  VkCommandPoolCreateInfo pool_info{VK_STRUCTURE_TYPE_COMMAND_POOL_CREATE_INFO};
  pool_info.queueFamilyIndex = ctx.queue_family();
  VkCommandPool pool = VK_NULL_HANDLE;
  ASSERT_EQ(vkCreateCommandPool(dev, &pool_info, nullptr, &pool), VK_SUCCESS);
  VkCommandBufferAllocateInfo alloc{VK_STRUCTURE_TYPE_COMMAND_BUFFER_ALLOCATE_INFO, nullptr, pool,
                                    VK_COMMAND_BUFFER_LEVEL_PRIMARY, 1};
  VkCommandBuffer cmd = VK_NULL_HANDLE;
  ASSERT_EQ(vkAllocateCommandBuffers(dev, &alloc, &cmd), VK_SUCCESS);
  VkCommandBufferBeginInfo begin{VK_STRUCTURE_TYPE_COMMAND_BUFFER_BEGIN_INFO};
  ASSERT_EQ(vkBeginCommandBuffer(cmd, &begin), VK_SUCCESS);
  culler().record(cmd, frusta);
  ASSERT_EQ(vkEndCommandBuffer(cmd), VK_SUCCESS);
  ctx.submit_and_wait(cmd);
  const gpu::CullResult recorded = culler().read_results();
  ASSERT_EQ(recorded.views.size(), frusta.size());
  for (std::size_t v = 0; v < frusta.size(); ++v) {
    const bvh::HierarchicalResult cpu = bvh::cull_hierarchical(flat, boxes, frusta[v]);
    EXPECT_EQ(recorded.views[v].classes, cpu.classes);
    EXPECT_EQ(recorded.views[v].node_tests, cpu.node_tests);
  }
  vkDestroyCommandPool(dev, pool, nullptr);
}

// A bad volume anywhere in a large tree is refused with bvh::check_flat_tree's message before
// anything is written, so the last upload still culls.
TEST_F(GpuBvh, ABadVolumeInALargeTreeIsRefusedAndTheLastUploadKept) {
  test::Rng rng{47};
  const std::size_t n = 50000;
  const test::RandomVolumes v = test::random_volumes(rng, n, 60.0f, 2.0f);
  const bvh::FlatTree flat = flat_tree(v.aabbs);
  const bvh::FlatTree obb_flat = tree_over(v.obbs);
  const std::vector<Frustum> frusta = test_frusta();
  culler().upload(flat, std::span<const Aabb>(v.aabbs));
  auto expect_refused = [&](const bvh::FlatTree& tree, const auto& volumes, const std::string& what) {
    const std::string why = bvh::check_flat_tree(tree, std::span(volumes));
    SCOPED_TRACE(what + ": " + why);
    ASSERT_FALSE(why.empty());
    try {
      culler().upload(tree, std::span(volumes));
      ADD_FAILURE() << "accepted";
    } catch (const std::invalid_argument& e) {
      EXPECT_EQ(std::string(e.what()), "BvhCuller::upload: " + why);
    }
  };
  for (std::size_t slot : {std::size_t(0), n / 2, n - 1}) {
    std::vector<Aabb> boxes = v.aabbs;
    boxes[flat.objects[slot]].min.z -= 500.0f;  // out of its leaf
    expect_refused(flat, boxes, "a box out of its leaf at slot " + std::to_string(slot));
    std::vector<Obb> obbs = v.obbs;
    obbs[obb_flat.objects[slot]].half_extents.x = NAN;
    expect_refused(obb_flat, obbs, "a NaN OBB at slot " + std::to_string(slot));
  }
  const gpu::CullResult kept = culler().cull(frusta);  // no upload in between
  ASSERT_EQ(kept.views.size(), frusta.size());
  for (std::size_t view = 0; view < frusta.size(); ++view) {
    const bvh::HierarchicalResult cpu = bvh::cull_hierarchical(flat, std::span<const Aabb>(v.aabbs), frusta[view]);
    EXPECT_EQ(kept.views[view].classes, cpu.classes) << "view " << view;
    EXPECT_EQ(kept.views[view].counts.visible, cpu.visible) << "view " << view;
    EXPECT_EQ(kept.views[view].counts.inside, cpu.inside) << "view " << view;
    EXPECT_EQ(kept.views[view].node_tests, cpu.node_tests) << "view " << view;
    EXPECT_EQ(kept.views[view].object_tests, cpu.object_tests) << "view " << view;
    EXPECT_EQ(kept.views[view].visible_ids.size(), cpu.visible) << "view " << view;
  }
}

TEST_F(GpuBvh, BadTreesAndOptionsAreClearErrors) {
  std::vector<Aabb> boxes(100, Aabb{glm::vec3(-1), glm::vec3(1)});
  bvh::FlatTree flat = flat_tree(boxes);
  std::vector<Aabb> fewer(boxes.begin(), boxes.end() - 1);
  EXPECT_THROW(culler().upload(flat, fewer), std::invalid_argument);
  bvh::FlatTree twice = flat;
  twice.objects[1] = twice.objects[0];
  EXPECT_THROW(culler().upload(twice, boxes), std::invalid_argument);
  bvh::FlatTree bad_skip = flat;
  bad_skip.nodes[0].skip = 0;
  EXPECT_THROW(culler().upload(bad_skip, boxes), std::invalid_argument);
  bvh::FlatTree bad_range = flat;
  bad_range.nodes.back().first = 99;
  bad_range.nodes.back().count = 5;
  EXPECT_THROW(culler().upload(bad_range, boxes), std::invalid_argument);
  bvh::FlatTree bad_box = flat;
  bad_box.nodes[1].box.min.x = NAN;
  EXPECT_THROW(culler().upload(bad_box, boxes), std::invalid_argument);
  bvh::FlatTree small_box = flat;  // a node box that does not enclose its children
  small_box.nodes[0].box.max.x = 0.5f;
  EXPECT_THROW(culler().upload(small_box, boxes), std::invalid_argument);
  std::vector<Aabb> nan_boxes = boxes;
  nan_boxes[3].max.y = NAN;
  EXPECT_THROW(culler().upload(flat, nan_boxes), std::invalid_argument);
  // Two leaves that both claim every object: ids and links are in range, but the ranges do
  // not split the root's (the traversal's scratch slices assume they do).
  bvh::FlatTree overlapping;
  overlapping.objects.resize(boxes.size());
  for (std::uint32_t i = 0; i < boxes.size(); ++i) overlapping.objects[i] = i;
  const Aabb all{glm::vec3(-1), glm::vec3(1)};
  const auto n = std::uint32_t(boxes.size());
  overlapping.nodes = {{all, 3, 0, n, false}, {all, 2, 0, n, true}, {all, 3, 0, n, true}};
  EXPECT_THROW(culler().upload(overlapping, boxes), std::invalid_argument);
  culler().upload(flat, boxes);
  gpu::CullOptions ordered;
  ordered.ordered = true;
  EXPECT_THROW(culler().cull(test_frusta(), ordered), std::invalid_argument);
  gpu::CullOptions draws;
  draws.draws = true;
  culler().upload_draws(std::vector<gpu::DrawCommand>(99));
  EXPECT_THROW(culler().cull(test_frusta(), draws), std::invalid_argument);
  // More views than the buffers hold (here the classes and the visible list, 4 bytes per
  // object and view in storage buffers, give out first): a clear length_error before anything
  // is allocated.
  const std::size_t too_many_views =
      GpuBvhEnvironment::context->properties().limits.maxStorageBufferRange / (4 * boxes.size()) + 1;
  if (too_many_views < 5'000'000) {
    const std::vector<Frustum> views(too_many_views, test_frusta()[0]);
    EXPECT_THROW(culler().cull(views), std::length_error);
  }
  // And the culler still works after every rejection.
  expect_agreement(culler(), flat, boxes, test_frusta());
}

}  // namespace
}  // namespace cullpipe

namespace cullpipe {
namespace {

std::size_t resident_bytes() {
  std::FILE* f = std::fopen("/proc/self/statm", "r");
  if (!f) return 0;
  unsigned long pages = 0, resident = 0;
  const int got = std::fscanf(f, "%lu %lu", &pages, &resident);
  std::fclose(f);
  return got == 2 ? std::size_t(resident) * std::size_t(sysconf(_SC_PAGESIZE)) : 0;
}

// An engine culls every frame for hours: a thousand passes on one context, flat and
// hierarchical, alternating view counts and options, must not grow the process's memory, and
// every pass stays exact.
TEST_F(GpuBvh, ThousandsOfPassesDoNotGrowMemory) {
  const Scene scene = generate_scene(SceneKind::City, 5000, 8);
  const std::vector<Aabb> boxes = world_aabbs(scene);
  const bvh::FlatTree flat = flat_tree(boxes);
  const std::vector<Frustum> frusta = path_frusta(scene, 4);
  gpu::GpuCuller flat_culler(*GpuBvhEnvironment::context);
  flat_culler.upload(std::span<const Aabb>(boxes));
  culler().upload(flat, boxes);
  const bvh::HierarchicalResult expected = bvh::cull_hierarchical(flat, boxes, frusta[1]);
  auto pass = [&](int i) {
    const std::span<const Frustum> views(frusta.data(), std::size_t(1 + i % 4));
    const gpu::CullOptions options{i % 7 == 0, true, std::size_t(i % 3 == 0 ? 100 : 0)};
    const gpu::CullResult b = culler().cull(views, options), f = flat_culler.cull(views, options);
    if (views.size() > 1 &&
        (b.views[1].counts.visible != expected.visible || f.views[1].counts.visible != expected.visible))
      ADD_FAILURE() << "pass " << i << " disagrees";
  };
  for (int i = 0; i < 100; ++i) pass(i);  // warm up: pipelines, buffers at their largest
  const std::size_t before = resident_bytes();
  for (int i = 0; i < 1000; ++i) pass(i);
  const std::size_t after = resident_bytes();
  std::printf("  resident memory: %.1f MiB before, %.1f MiB after 1000 more passes of each culler\n",
              before / 1048576.0, after / 1048576.0);
#if defined(__SANITIZE_ADDRESS__)
  // AddressSanitizer keeps freed memory in quarantine, so resident memory grows regardless;
  // LeakSanitizer checks for leaks at exit instead.
  (void)after;
#else
  EXPECT_LT(after, before + 8u * 1024 * 1024) << "memory grows with every pass";
#endif
}

}  // namespace
}  // namespace cullpipe
