// The fast CPU path (cull/cpu_culler) against the scalar reference: every kernel this machine
// runs, several thread counts and chunk sizes, sizes around the vector widths, boundary cases
// (objects exactly on planes, -0 normals, NaN and infinite values, denormals), several views.
#include <gtest/gtest.h>

#include <algorithm>
#include <atomic>
#include <bit>
#include <cfenv>
#include <chrono>
#include <cmath>
#include <cstdlib>
#include <limits>
#include <map>
#include <mutex>
#include <new>
#include <string>
#include <thread>
#include <vector>
#if defined(__SSE__)
#include <xmmintrin.h>
#endif

#include "cullpipe/bvh/builders.hpp"
#include "cullpipe/bvh/bvh.hpp"
#include "cullpipe/core/thread_pool.hpp"
#include "cullpipe/cull/compare.hpp"
#include "cullpipe/cull/cpu_bvh_culler.hpp"
#include "cullpipe/cull/cpu_culler.hpp"
#include "cullpipe/cull/kernel_select.hpp"
#include "cullpipe/cull/reference.hpp"
#include "cullpipe/geom/plane_bounds.hpp"
#include "cullpipe/geom/pn_vertex.hpp"
#include "cullpipe/scene/camera.hpp"
#include "edge_sets.hpp"
#include "test_util.hpp"

// Counts operator new calls, so a test can check that a steady pass allocates nothing; and
// fails one on request, so a test can stop a pass part way.
namespace {
std::atomic<long> g_allocations{0};
std::atomic<bool> g_fail_next_allocation{false};  // the next operator new throws std::bad_alloc
}  // namespace
// The replacement new allocates with malloc, so its deletes free; GCC cannot see that
// pairing through inlined allocators and warns.
#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wpragmas"
#pragma GCC diagnostic ignored "-Wmismatched-new-delete"
void* operator new(std::size_t n) {
  ++g_allocations;
  if (g_fail_next_allocation.exchange(false)) throw std::bad_alloc();
  if (void* p = std::malloc(n ? n : 1)) return p;
  throw std::bad_alloc();
}
void operator delete(void* p) noexcept { std::free(p); }
void operator delete(void* p, std::size_t) noexcept { std::free(p); }
#pragma GCC diagnostic pop

namespace cullpipe {
namespace {

using fast::CpuCuller;
using fast::CpuCullerConfig;
using fast::CpuCullOptions;
using fast::CpuViewResult;
using fast::Isa;
using test::aabb_edge_set;
using test::EdgeSet;
using test::obb_edge_set;
using test::sphere_edge_set;

/// A node of a hand-made flat tree.
bvh::FlatNode flat_node(const Aabb& box, std::uint32_t skip, std::uint32_t first, std::uint32_t count, bool leaf) {
  bvh::FlatNode n;
  n.box = box;
  n.skip = skip;
  n.first = first;
  n.count = count;
  n.leaf = leaf;
  return n;
}

/// `scaled_normals`: also a frustum whose normals are not unit (which hierarchies over OBBs and
/// spheres refuse).
std::vector<Frustum> test_views(bool scaled_normals = true) {
  std::vector<Frustum> views;
  views.push_back(Frustum::from_view_proj(test::test_view_proj()));
  views.push_back(Frustum::from_view_proj(test::test_view_proj(20.0f, 1.0f)));
  // Axis-aligned planes with -0 and +0 normal components: the p/n-vertex choice must treat
  // -0 as positive, like the reference.
  const std::vector<glm::vec4> planes = {{1, -0.0f, 0, 5}, {-1, 0, -0.0f, 5}, {-0.0f, 1, 0, 5},
                                         {0, -1, 0, 5},    {0, 0, 1, 30},     {-0.0f, -0.0f, -1, 30}};
  views.push_back(Frustum::from_planes(planes));
  views.push_back(Frustum{});  // no planes: everything INSIDE
  if (!scaled_normals) return views;
  // Normals of length 2 and 0.5, built by hand (the factories normalise): the OBB kernel's
  // plane bound assumes unit normals and must not be used here.
  Frustum scaled;
  scaled.plane_count = 3;
  scaled.planes[0] = {{2, 0, 0}, 10};
  scaled.planes[1] = {{0, -0.5f, 0}, 2.5f};
  scaled.planes[2] = {{0, 1.2f, -1.6f}, 40};
  views.push_back(scaled);
  return views;
}

/// Fails with the object, the planes and both answers at the first difference; checks the
/// counts and that the visible list is exactly the visible objects in object order (what
/// `options` asked for; the outputs not asked for are empty).
template <class Volume>
void expect_equal_to_reference(std::span<const Volume> volumes, const Frustum& f, const CpuViewResult& r,
                               const std::string& what, const CpuCullOptions& options = {}) {
  std::vector<Classification> expected(volumes.size());
  const reference::CullCounts counts = reference::classify_all(volumes, f, expected);
  if (options.classes) {
    ASSERT_EQ(r.classes.size(), volumes.size()) << what;
    const std::size_t i = first_mismatch(expected, r.classes);
    ASSERT_EQ(i, npos) << what << ": object " << i << ": " << describe(volumes[i]) << "; frustum " << describe(f)
                       << "; reference says " << to_string(expected[i]) << ", fast CPU says "
                       << to_string(r.classes[i]);
  } else {
    EXPECT_TRUE(r.classes.empty()) << what;
  }
  EXPECT_EQ(r.counts, counts) << what;
  std::vector<std::uint32_t> ids;
  if (options.visible_ids)
    for (std::size_t k = 0; k < expected.size(); ++k)
      if (is_visible(expected[k])) ids.push_back(static_cast<std::uint32_t>(k));
  EXPECT_EQ(r.visible_ids, ids) << what;
}

template <class Volume>
void check_everywhere(const std::vector<Volume>& volumes, const std::string& what,
                      std::vector<Frustum> views = test_views(), std::vector<unsigned> thread_counts = {1u, 2u, 3u},
                      std::vector<std::size_t> chunks = {16u, 48u, 16384u}) {
  for (Isa isa : fast::supported_isas())
    for (unsigned threads : thread_counts)
      for (std::size_t chunk : chunks) {
        CpuCuller culler({threads, isa, chunk});
        culler.upload(std::span<const Volume>(volumes));
        // Both outputs, the list alone (the benchmarks' pass: no class writes, no crossing
        // bits) and the classes alone.
        for (const CpuCullOptions options :
             {CpuCullOptions{true, true}, CpuCullOptions{false, true}, CpuCullOptions{true, false}}) {
          const std::vector<CpuViewResult> results = culler.cull(views, options);
          ASSERT_EQ(results.size(), views.size());
          for (std::size_t v = 0; v < views.size(); ++v)
            expect_equal_to_reference(std::span<const Volume>(volumes), views[v], results[v],
                                      what + " n=" + std::to_string(volumes.size()) +
                                          " isa=" + std::string(to_string(isa)) +
                                          " threads=" + std::to_string(threads) + " chunk=" + std::to_string(chunk) +
                                          " classes=" + std::to_string(options.classes) +
                                          " ids=" + std::to_string(options.visible_ids) + " view " + std::to_string(v),
                                      options);
        }
      }
}

TEST(CpuCuller, RandomAabbsObbsAndSpheresOfEverySizeAroundTheVectorWidths) {
  test::Rng rng(7);
  for (std::size_t n : {0u, 1u, 3u, 4u, 5u, 7u, 8u, 9u, 15u, 16u, 17u, 31u, 33u, 47u, 100u, 1000u, 5003u}) {
    const test::RandomVolumes v = test::random_volumes(rng, n, 30.0f, 4.0f);
    check_everywhere(v.aabbs, "aabb");
    check_everywhere(v.obbs, "obb");
    check_everywhere(v.spheres, "sphere");
  }
}

TEST(CpuCuller, FindsMirroredPlanesAndCullsOrthographicViews) {
  // A perspective frustum's near and far planes mirror each other when its depth range is
  // modest (with near / far = 10^-4 the float matrix tilts the far plane by far more than
  // kMirrorSlack); an orthographic one's three pairs always do. The kernels take the first
  // pair's mirrored distance from its base's.
  Camera camera;
  camera.eye = {3, 40, 70};
  camera.target = {5, -2, -10};
  camera.near_plane = 20.0f;
  camera.far_plane = 200.0f;
  std::vector<Frustum> views;
  views.push_back(Frustum::from_view_proj(camera.view_proj()));
  const fast::detail::PlaneSet perspective = fast::detail::plane_set(views.back());
  EXPECT_TRUE(perspective.mirrored && perspective.mirror_base == 4 && perspective.mirror_plane == 5)
      << describe(views.back());
  camera.infinite_far = true;  // five planes, none mirrored
  EXPECT_FALSE(fast::detail::plane_set(Frustum::from_view_proj(camera.view_proj())).mirrored);
  camera.infinite_far = false;
  camera.orthographic = true;
  for (float half_height : {5.0f, 40.0f}) {
    camera.ortho_half_height = half_height;
    views.push_back(Frustum::from_view_proj(camera.view_proj()));
    const fast::detail::PlaneSet set = fast::detail::plane_set(views.back());
    EXPECT_TRUE(set.mirrored && set.mirror_base == 0 && set.mirror_plane == 1) << describe(views.back());
  }
  // Slanted: light from the side, as a shadow cascade's.
  camera.eye = {60, 50, -20};
  views.push_back(Frustum::from_view_proj(camera.view_proj()));
  EXPECT_TRUE(fast::detail::plane_set(views.back()).mirrored);
  test::Rng rng(31);
  const test::RandomVolumes v = test::random_volumes(rng, 5003, 30.0f, 4.0f);
  check_everywhere(v.aabbs, "aabb, orthographic", views);
  check_everywhere(v.obbs, "obb, orthographic", views);
  check_everywhere(v.spheres, "sphere, orthographic", views);
}

TEST(CpuCuller, VisibleListsMixDenseAndSparseRuns) {
  // Blocks of 2,500 objects (not aligned with the kernels' runs of 4,096 or the chunks) that are
  // all visible, none, 10% and 60% visible, behind or in front of one plane: a chunk's runs mix
  // those whose ids are listed as found and the dense ones listed from their bits afterwards.
  test::Rng rng(11);
  const std::size_t n = 23000;
  test::RandomVolumes v = test::random_volumes(rng, n, 30.0f, 4.0f);
  for (std::size_t i = 0; i < n; ++i) {
    const std::size_t block = i / 2500 % 4;
    const float share = block == 0 ? 1.0f : block == 1 ? 0.0f : block == 2 ? 0.1f : 0.6f;
    const float dx = rng.uniform(0.0f, 1.0f) < share ? 50.0f : -50.0f;
    v.aabbs[i].min.x += dx;
    v.aabbs[i].max.x += dx;
    v.obbs[i].center.x += dx;
    v.spheres[i].center.x += dx;
  }
  Frustum unit, scaled;  // x >= 0; the scaled one takes the spheres' test without the bound
  unit.plane_count = scaled.plane_count = 1;
  unit.planes[0] = {{1, 0, 0}, 0};
  scaled.planes[0] = {{2, 0, 0}, 0};
  const std::vector<Frustum> views = {unit, scaled};
  check_everywhere(v.aabbs, "aabb runs", views, {1u, 2u}, {4096u, 10000u, 16384u});
  check_everywhere(v.obbs, "obb runs", views, {1u, 2u}, {4096u, 10000u, 16384u});
  check_everywhere(v.spheres, "sphere runs", views, {1u, 2u}, {4096u, 10000u, 16384u});
}

TEST(CpuCuller, VisibleListsStayExactWhenRunsChangeBetweenPasses) {
  // A run lists its ids as it classifies them when the last pass found it sparse, else from its
  // bits afterwards (if it is still sparse) or not at all (if dense). One culler, one plane
  // moved pass after pass so runs turn dense, sparse and empty, in every order. Thin slabs just
  // behind the plane are left open by the bound and found OUTSIDE: in the first run about 3,000
  // of them (the run listed again from its bits), in the second 10 (removed one by one from
  // its list), the rest of the runs mixed.
  test::Rng rng(23);
  const std::size_t n = 3 * 4096 + 1500;
  std::vector<Aabb> boxes(n);
  for (std::size_t i = 0; i < n; ++i) {
    const std::size_t run = i / 4096;
    const float u = rng.uniform(0.0f, 1.0f);
    const bool slab = run == 0 ? u < 0.75f : run == 1 ? i % 4096 < 400 && i % 40 == 0 : u < 0.3f;
    const bool far_in = run == 1 ? u < 0.05f : u < 0.5f;
    const float x = rng.uniform(-50.0f, 50.0f), y = rng.uniform(-50.0f, 50.0f);
    if (slab) {
      const float top = rng.uniform(-0.9f, -0.1f) * (u < 0.9f ? 1.0f : -1.0f);  // most behind the plane, some in front
      boxes[i] = {{x - 10, y - 10, top - 0.05f}, {x + 10, y + 10, top}};
    } else {
      const float z = far_in ? rng.uniform(5.0f, 60.0f) : rng.uniform(-60.0f, -5.0f);
      boxes[i] = {{x - 1, y - 1, z - 1}, {x + 1, y + 1, z + 1.5f}};
    }
  }
  auto plane_at = [](float d) {
    Frustum f;
    f.plane_count = 1;
    f.planes[0] = {{0, 0, 1}, d};  // z + d >= 0
    return f;
  };
  const float shifts[] = {0.0f, 100.0f, 0.0f, -100.0f, 0.0f, 100.0f, 100.0f, 0.0f, 0.02f, -3.0f, 0.0f};
  for (Isa isa : fast::supported_isas())
    for (unsigned threads : {1u, 2u})
      for (std::size_t chunk : {4096u, 16384u}) {
        CpuCuller culler({threads, isa, chunk});
        culler.upload(std::span<const Aabb>(boxes));
        std::vector<CpuViewResult> results;
        int pass = 0;
        for (float d : shifts)
          for (const CpuCullOptions options : {CpuCullOptions{false, true}, CpuCullOptions{true, true}}) {
            const Frustum views[2] = {plane_at(d), plane_at(-d)};  // each view keeps its own guesses
            culler.cull(views, options, results);
            for (int v = 0; v < 2; ++v)
              expect_equal_to_reference(std::span<const Aabb>(boxes), views[v], results[static_cast<std::size_t>(v)],
                                        "isa=" + std::string(to_string(isa)) + " threads=" + std::to_string(threads) +
                                            " chunk=" + std::to_string(chunk) + " pass " + std::to_string(pass) +
                                            " view " + std::to_string(v),
                                        options);
            ++pass;
          }
      }
}

TEST(CpuCuller, BothReadOrdersOfTheMemoryFloorReadEveryCentreAndBound) {
  // The benchmarks' floor reads the centres and bounds one array after another or side by
  // side; either gives the OR of the bits of every centre coordinate and bound. The boxes are
  // chosen so that each of the four arrays has a bit no other array has, and the last box's
  // centre x a bit no other float has (both checked below): a read that skips an array, reads
  // one for another or stops before the last object gives another OR.
  auto bits = [](float f) { return std::bit_cast<std::uint32_t>(f); };
  for (Isa isa : fast::supported_isas())
    for (std::size_t n : {1u, 16u, 17u, 40000u})
      for (std::size_t chunk : {16u, 48u, 16384u}) {
        std::vector<Aabb> boxes(n, Aabb{{1e-3f, 5e-10f, -2.5f}, {1e-3f, 5e-10f, -1.5f}});
        boxes.back() = {{3e-3f, 5e-10f, -2.5f}, {3e-3f, 5e-10f, -1.5f}};
        std::vector<glm::vec4> centre_bounds(n);
        plane_bounds::aabb_centre_bounds(boxes, centre_bounds);
        for (std::size_t i = 0; i < n; ++i)  // as the culler stores them
          centre_bounds[i].w = plane_bounds::pack_lower(centre_bounds[i].w, plane_bounds::aabb_lower(boxes[i]));
        std::uint32_t column[4] = {}, x_before_last = 0;
        for (std::size_t i = 0; i < n; ++i)
          for (int k = 0; k < 4; ++k) column[k] |= bits(centre_bounds[i][k]);
        for (std::size_t i = 0; i + 1 < n; ++i) x_before_last |= bits(centre_bounds[i].x);
        const std::uint32_t expected = column[0] | column[1] | column[2] | column[3];
        for (int k = 0; k < 4; ++k)
          ASSERT_NE(column[k] & ~(column[(k + 1) % 4] | column[(k + 2) % 4] | column[(k + 3) % 4]), 0u)
              << "array " << k << " has no bit of its own";
        ASSERT_NE(bits(centre_bounds.back().x) & ~(x_before_last | column[1] | column[2] | column[3]), 0u)
            << "the last x has no bit of its own";
        CpuCuller culler({2, isa, chunk});
        culler.upload(std::span<const Aabb>(boxes));
        EXPECT_EQ(culler.touch_bounds(true), expected) << to_string(isa) << " n=" << n << " chunk=" << chunk;
        EXPECT_EQ(culler.touch_streamed_side_by_side(), expected) << to_string(isa) << " n=" << n << " chunk=" << chunk;
      }
  CpuCuller empty;
  EXPECT_EQ(empty.touch_streamed_side_by_side(), 0u);
}

TEST(CpuCuller, ObjectsTouchingPlanesExactly) {
  // Boxes whose faces lie on the planes of the axis-aligned view (distance exactly 0) and
  // degenerate boxes (points, flat slabs).
  std::vector<Aabb> boxes;
  std::vector<Sphere> spheres;
  for (float a : {-6.0f, -5.0f, -4.0f, 0.0f, 4.0f, 5.0f, 6.0f})
    for (float b : {-5.0f, 0.0f, 5.0f}) {
      boxes.push_back({{a, b, -30}, {a, b, -30}});
      boxes.push_back({{a, -5, -30}, {5, b, 30}});
      boxes.push_back({{-5, a, b}, {a, 5, b}});
      spheres.push_back({{a, b, 0}, 1.0f});
      spheres.push_back({{a, b, -29}, 0.0f});
    }
  check_everywhere(boxes, "aabb on planes");
  check_everywhere(spheres, "sphere on planes");
}

TEST(CpuCuller, NanInfinityAndDenormalValuesGiveTheReferenceAnswer) {
  const float nan = std::numeric_limits<float>::quiet_NaN(), inf = std::numeric_limits<float>::infinity();
  const float denorm = std::numeric_limits<float>::denorm_min();
  std::vector<Aabb> boxes;
  std::vector<Obb> obbs;
  std::vector<Sphere> spheres;
  for (float v : {nan, inf, -inf, denorm, -denorm, 1e30f, -1e30f, 1e-30f, 0.0f, -0.0f, 3.0f}) {
    boxes.push_back({{v, 0, 0}, {1, 1, 1}});
    boxes.push_back({{-1, -1, -1}, {v, v, v}});
    boxes.push_back({{v, v, v}, {v, v, v}});
    Obb o;
    o.center = {v, 0, -5};
    o.half_extents = {1, v, 1};
    obbs.push_back(o);
    o.basis[1] = glm::vec3(v, 0, 0);
    obbs.push_back(o);
    spheres.push_back({{0, v, -5}, 1.0f});
    spheres.push_back({{0, 0, -5}, v});
  }
  check_everywhere(boxes, "aabb special");
  check_everywhere(obbs, "obb special");
  check_everywhere(spheres, "sphere special");
}

/// Checks an edge set everywhere, after checking that its answers against `views[mixed]` are
/// mixed: all three classes occur.
template <class Volume>
void check_edge_set(const EdgeSet<Volume>& set, std::size_t mixed, const std::string& what) {
  std::vector<Classification> classes(set.volumes.size());
  reference::classify_all(std::span<const Volume>(set.volumes), set.views[mixed], classes);
  for (Classification c : {Classification::Outside, Classification::Intersecting, Classification::Inside})
    EXPECT_GT(std::count(classes.begin(), classes.end(), c), 100) << what << ": " << to_string(c);
  check_everywhere(set.volumes, what, set.views);
}

TEST(CpuCuller, ObbsAtTheEdgeOfTheirPlaneBound) { check_edge_set(obb_edge_set(), 0, "obb at the bound"); }

TEST(CpuCuller, AabbsAtTheEdgeOfTheirPlaneBound) { check_edge_set(aabb_edge_set(), 1, "aabb at the bound"); }

TEST(CpuCuller, SpheresAtTheEdgeOfTheirPlaneBound) { check_edge_set(sphere_edge_set(), 1, "sphere at the bound"); }

TEST(CpuCuller, AabbsAtTheEdgeOfTheirLowerBound) {
  check_edge_set(test::aabb_lower_edge_set(), 0, "aabb at the lower bound");
}

TEST(CpuCuller, ObbsAtTheEdgeOfTheirLowerBound) {
  check_edge_set(test::obb_lower_edge_set(), 0, "obb at the lower bound");
}

TEST(CpuCuller, SpheresAtTheEdgeOfTheirLowerBound) {
  check_edge_set(test::sphere_lower_edge_set(), 0, "sphere at the lower bound");
}

TEST(CpuCuller, PackedLowerBoundsStayBoundsAndReadBackBelowTheLowerBound) {
  using plane_bounds::pack_lower;
  auto bits = [](float f) { return std::bit_cast<std::uint32_t>(f); };
  const float inf = std::numeric_limits<float>::infinity(), nan = std::numeric_limits<float>::quiet_NaN();
  test::Rng rng(5);
  for (int i = 0; i < 100000; ++i) {
    const float bound = std::ldexp(rng.uniform(1.0f, 2.0f), static_cast<int>(rng.next() % 250) - 125);
    const double lower = double(bound) * rng.uniform(-0.5f, 1.5f);
    const float packed = pack_lower(bound, lower);
    ASSERT_GE(packed, bound) << bound;
    ASSERT_LE(double(packed), double(bound) * (1.0 + 0x1p-14)) << bound;
    const std::uint32_t q = bits(packed) & 255u;
    ASSERT_LE(double(q) * double(packed) / 256.0, std::max(0.0, lower) * (1.0 + 0x1p-15)) << bound << " " << lower;
    if (bound > 0x1p119f || lower <= 0.0) {
      ASSERT_EQ(q, 0u) << bound << " " << lower;
    }
    if (bound <= 0x1p118f && lower > double(bound) * 0.5) {
      ASSERT_GE(q, 127u) << bound << " " << lower;  // (it does carry one)
    }
    ASSERT_LT(double(q) * double(packed), 0x1p127) << bound;
  }
  EXPECT_EQ(bits(pack_lower(nan, 1.0)), bits(nan));
  EXPECT_EQ(pack_lower(inf, 1.0), inf);
  EXPECT_EQ(bits(pack_lower(0.0f, 1.0)), 0u);
  EXPECT_EQ(pack_lower(std::numeric_limits<float>::max(), 1e38), inf);  // rounding up carries into the exponent
  EXPECT_EQ(bits(pack_lower(std::nextafter(2.0f, 0.0f), 1.9)),
            bits(2.0f) | 243u);  // 1.999... carries to 2, q = floor(256 * 0.95 = 243.2)
}

#if defined(__SSE__)
TEST(CpuCuller, AgreesUnderFlushToZeroSetAfterThePoolStarted) {
  // An engine may turn FTZ/DAZ on at any time, on its own thread. Planes through the origin
  // and boxes whose plane distances are themselves subnormal: with DAZ a distance of -1e-40
  // reads as 0 (not behind the plane), without it the box is OUTSIDE. Every chunk, whichever
  // thread runs it, must use the caller's mode, as the reference on the caller's thread does.
  std::vector<Aabb> boxes;
  for (int i = 0; i < 1'000'000; ++i) {  // enough work that the workers wake in time to take some
    const float tiny = std::numeric_limits<float>::denorm_min() * float(1 + i % 50) * (i % 2 ? 1.0f : -1.0f);
    boxes.push_back({{tiny - 1.0f, -1, -1}, {tiny, 1, 1}});
  }
  const glm::vec4 planes[2] = {{1, 0, 0, 0}, {0, 0, 1, 5}};
  const Frustum f = Frustum::from_planes(planes);
  for (unsigned threads : {2u, 3u}) {
    CpuCullerConfig config;
    config.threads = threads;
    config.chunk_objects = 4096;  // many chunks
    CpuCuller culler(config);
    culler.upload(std::span<const Aabb>(boxes));
    std::vector<Classification> without_daz(boxes.size());
    reference::classify_all(std::span<const Aabb>(boxes), f, without_daz);
    const unsigned saved = _mm_getcsr();
    _mm_setcsr(saved | 0x8040);  // FTZ | DAZ, after the pool's threads exist
    const std::vector<CpuViewResult> r = culler.cull({&f, 1});
    std::vector<Classification> with_daz(boxes.size());
    const reference::CullCounts counts = reference::classify_all(std::span<const Aabb>(boxes), f, with_daz);
    _mm_setcsr(saved);
    ASSERT_NE(with_daz, without_daz) << "the case must be sharp: DAZ changes the reference's answer";
    const std::size_t i = first_mismatch(with_daz, r[0].classes);
    EXPECT_EQ(i, npos) << "threads=" << threads << ": object " << i << " " << describe(boxes[i])
                       << ": reference under DAZ says " << to_string(with_daz[i]) << ", fast CPU says "
                       << to_string(r[0].classes[i]);
    EXPECT_EQ(r[0].counts, counts);
  }
}

// The bounds are computed at upload; the engine's float mode then (FTZ / DAZ, rounding) must
// not matter, and culling in any mode must give what the reference gives in that mode.
// (Under DAZ at upload, a subnormal extent read as 0 would leave its part of the radius out of
// the OBB bound.)
template <class Volume>
void expect_mode_independent(const EdgeSet<Volume>& set, const std::string& what) {
  const unsigned saved = _mm_getcsr();
  const unsigned rounding[4] = {0x0000, 0x2000, 0x4000, 0x6000};  // nearest, down, up, toward zero
  const unsigned flush[2] = {0x0000, 0x8040};                     // none, FTZ | DAZ
  CpuCullerConfig config;
  config.threads = 2;
  config.chunk_objects = 1024;
  for (unsigned upload_mode : {0x0000u, 0x8040u, 0x2000u, 0x6000u | 0x8040u}) {
    CpuCuller culler(config);
    _mm_setcsr((saved & ~0xE040u) | upload_mode);
    culler.upload(std::span<const Volume>(set.volumes));
    for (unsigned r : rounding)
      for (unsigned f : flush) {
        _mm_setcsr((saved & ~0xE040u) | r | f);
        const std::vector<CpuViewResult> results = culler.cull(set.views);
        std::vector<std::vector<Classification>> expected(set.views.size(),
                                                          std::vector<Classification>(set.volumes.size()));
        for (std::size_t v = 0; v < set.views.size(); ++v)
          reference::classify_all(std::span<const Volume>(set.volumes), set.views[v], expected[v]);
        _mm_setcsr(saved);
        for (std::size_t v = 0; v < set.views.size(); ++v) {
          const std::size_t i = first_mismatch(expected[v], results[v].classes);
          ASSERT_EQ(i, npos) << what << ": upload mode " << std::hex << upload_mode << ", cull mode " << (r | f)
                             << std::dec << ", view " << v << ", object " << i << " " << describe(set.volumes[i])
                             << "; frustum " << describe(set.views[v]) << ": reference says "
                             << to_string(expected[v][i]) << ", fast CPU says " << to_string(results[v].classes[i]);
        }
      }
  }
  _mm_setcsr(saved);
}

TEST(CpuCuller, BoundsHoldInEveryFloatModeAtUploadAndCull) {
  expect_mode_independent(obb_edge_set(), "obb");
  expect_mode_independent(aabb_edge_set(), "aabb");
  expect_mode_independent(sphere_edge_set(), "sphere");
  expect_mode_independent(test::aabb_lower_edge_set(), "aabb, lower bound");
  expect_mode_independent(test::obb_lower_edge_set(), "obb, lower bound");
  expect_mode_independent(test::sphere_lower_edge_set(), "sphere, lower bound");
}
#endif

TEST(CpuCuller, OptionsLeaveOutputsEmptyAndResultsAreReused) {
  test::Rng rng(3);
  std::vector<Sphere> spheres(777);
  for (Sphere& s : spheres) s = test::random_sphere(rng, 30.0f, 3.0f);
  CpuCuller culler;
  culler.upload(std::span<const Sphere>(spheres));
  const std::vector<Frustum> views = test_views();
  std::vector<CpuViewResult> results;
  CpuCullOptions options;
  options.classes = false;
  culler.cull(views, options, results);
  ASSERT_EQ(results.size(), views.size());
  EXPECT_TRUE(results[0].classes.empty());
  std::vector<Classification> expected(spheres.size());
  EXPECT_EQ(results[0].counts, reference::classify_all(std::span<const Sphere>(spheres), views[0], expected));
  options.classes = true;
  options.visible_ids = false;
  culler.cull(std::span<const Frustum>(views).first(1), options, results);
  ASSERT_EQ(results.size(), 1u);
  EXPECT_TRUE(results[0].visible_ids.empty());
  EXPECT_EQ(results[0].classes, expected);
  // A smaller upload of another kind on the same culler.
  std::vector<Aabb> boxes(20);
  for (Aabb& b : boxes) b = test::random_aabb(rng, 30.0f, 3.0f);
  culler.upload(std::span<const Aabb>(boxes));
  EXPECT_EQ(culler.kind(), BvKind::Aabb);
  culler.cull(views, {}, results);
  for (std::size_t v = 0; v < views.size(); ++v)
    expect_equal_to_reference(std::span<const Aabb>(boxes), views[v], results[v], "reuse");
}

TEST(CpuCuller, ASteadyPassAllocatesNothing) {
  test::Rng rng{17};
  std::vector<Aabb> boxes(100000);
  for (Aabb& b : boxes) b = test::random_aabb(rng, 30.0f, 3.0f);
  CpuCullerConfig config;
  config.threads = 2;
  CpuCuller culler(config);
  culler.upload(std::span<const Aabb>(boxes));
  const std::vector<Frustum> views = test_views();
  std::vector<CpuViewResult> results;
  culler.cull(views, {}, results);  // sizes settle
  const long before = g_allocations.load();
  for (int frame = 0; frame < 10; ++frame) culler.cull(views, {}, results);
  EXPECT_EQ(g_allocations.load() - before, 0) << "allocations in ten steady passes";
  for (std::size_t v = 0; v < views.size(); ++v)
    expect_equal_to_reference(std::span<const Aabb>(boxes), views[v], results[v], "steady");
}

TEST(CpuCuller, ReportsItsKernelsAndRejectsOnesTheCpuLacks) {
  EXPECT_TRUE(fast::isa_supported(Isa::Portable));
  EXPECT_TRUE(fast::isa_supported(fast::best_isa()));
  EXPECT_EQ(fast::parse_isa("avx2"), Isa::Avx2);
  EXPECT_EQ(fast::parse_isa("sse9"), std::nullopt);
  for (Isa isa : {Isa::Avx2, Isa::Avx512})
    if (!fast::isa_supported(isa)) {
      CpuCullerConfig config;
      config.isa = isa;
      EXPECT_THROW(CpuCuller{config}, std::invalid_argument);
    }
  CpuCullerConfig config;
  config.threads = 3;
  EXPECT_EQ(CpuCuller(config).threads(), 3u);
}

// The traversal a CpuBvhCuller pass with default options makes (ranges of 160 objects for
// boxes and spheres, 96 for OBBs: pinned here, as the README and the CLI say).
static_assert(fast::CpuBvhCullOptions::default_range_objects(BvKind::Aabb) == 160 &&
              fast::CpuBvhCullOptions::default_range_objects(BvKind::Sphere) == 160 &&
              fast::CpuBvhCullOptions::default_range_objects(BvKind::Obb) == 96);
bvh::TraversalOptions fast_traversal(BvKind kind) { return {fast::CpuBvhCullOptions::default_range_objects(kind)}; }

void expect_same_traversal(const bvh::HierarchicalResult& expected, const bvh::HierarchicalResult& got,
                           const std::string& what) {
  ASSERT_EQ(got.classes.size(), expected.classes.size()) << what;
  const std::size_t i = first_mismatch(expected.classes, got.classes);
  ASSERT_EQ(i, npos) << what << ": object " << i << ": scalar traversal says " << to_string(expected.classes[i])
                     << ", fast says " << to_string(got.classes[i]);
  EXPECT_EQ(got.node_tests, expected.node_tests) << what;
  EXPECT_EQ(got.object_tests, expected.object_tests) << what;
  EXPECT_EQ(got.visible, expected.visible) << what;
  EXPECT_EQ(got.inside, expected.inside) << what;
}

// The visible list of a CpuBvhCuller pass: the tree's object order, filtered by the expected
// classes.
void expect_visible_list(const bvh::HierarchicalResult& expected, const bvh::FlatTree& tree,
                         const std::vector<std::uint32_t>& ids, const std::string& what) {
  std::vector<std::uint32_t> want;
  for (std::uint32_t o : tree.objects)
    if (expected.classes[o] != Classification::Outside) want.push_back(o);
  EXPECT_EQ(ids, want) << what;
}

TEST(CpuBvhCuller, EqualsTheScalarTraversalExactly) {
  test::Rng rng{11};
  std::vector<Frustum> views = test_views();
  // A frustum that holds everything (the root is INSIDE) and one that holds nothing.
  const glm::vec4 everything[1] = {{0, 0, 1, 1e6f}};
  const glm::vec4 nothing[1] = {{0, 0, 1, -1e6f}};
  views.push_back(Frustum::from_planes(everything));
  views.push_back(Frustum::from_planes(nothing));
  for (std::size_t n : {0u, 1u, 2u, 5u, 100u, 3000u, 70000u}) {
    std::vector<Aabb> boxes(n);
    for (Aabb& b : boxes) b = test::random_aabb(rng, 30.0f, 2.0f);
    for (const char* builder : {"binned-sah", "agglomerative-local", "insertion-greedy"}) {
      if (n > 3000 && std::string(builder) != "binned-sah") continue;
      bvh::BuildOptions options;
      options.max_leaf_size = n % 2 ? 1 : 6;
      const bvh::FlatTree tree = bvh::flatten(bvh::build(builder, boxes, options));
      for (Isa isa : fast::supported_isas())
        for (unsigned threads : {1u, 2u, 3u}) {
          fast::CpuBvhCuller culler(threads, isa);
          culler.upload(tree, boxes);
          bvh::HierarchicalResult reused;
          for (std::size_t v = 0; v < views.size(); ++v) {
            const std::string what = std::string(builder) + " n=" + std::to_string(n) +
                                     " isa=" + std::string(to_string(isa)) + " threads=" + std::to_string(threads) +
                                     " view " + std::to_string(v);
            culler.cull(views[v], reused);  // the default options
            expect_same_traversal(bvh::cull_hierarchical(tree, boxes, views[v], fast_traversal(BvKind::Aabb)), reused,
                                  what);
            if (HasFatalFailure()) return;
          }
          // Object ranges from leaves only, from nodes of up to 5 objects, and from nodes larger
          // than a subtree task (the whole tree at the smaller n); the visible list with and
          // without the classes.
          for (std::uint32_t range : {0u, 5u, 20000u})
            for (std::size_t v = 0; v < views.size(); ++v) {
              const std::string what = std::string(builder) + " n=" + std::to_string(n) +
                                       " isa=" + std::string(to_string(isa)) + " threads=" + std::to_string(threads) +
                                       " ranges " + std::to_string(range) + " view " + std::to_string(v);
              const bvh::HierarchicalResult expected = bvh::cull_hierarchical(tree, boxes, views[v], {range});
              std::vector<std::uint32_t> ids{7, 7, 7};
              for (bool classes : {true, false}) {
                bvh::HierarchicalResult listed;
                const fast::CpuBvhCullOptions cull_options{classes, true, range};
                culler.cull(views[v], cull_options, listed, ids);
                if (classes) expect_same_traversal(expected, listed, what);
                expect_visible_list(expected, tree, ids, what + (classes ? " (list and classes)" : " (list only)"));
                EXPECT_EQ(listed.classes.size(), classes ? n : 0u) << what;
                EXPECT_EQ(listed.node_tests, expected.node_tests) << what;
                EXPECT_EQ(listed.object_tests, expected.object_tests) << what;
                EXPECT_EQ(listed.visible, expected.visible) << what;
                EXPECT_EQ(listed.inside, expected.inside) << what;
                if (HasFatalFailure()) return;
              }
            }
        }
    }
  }
}

// Boxes on integer coordinates against axis-aligned planes through integers: many boxes
// touch a plane exactly (distance +0 or -0), some are points, some have -0 corners; leaves of
// 1, 7 and 300 objects (one lane, part of a vector, many vectors). Every instruction set's
// walk must give the scalar traversal's classes, counts and list.
TEST(CpuBvhCuller, TouchingBoxesAndLargeLeavesEqualTheScalarTraversal) {
  test::Rng rng{23};
  std::vector<Aabb> boxes(60000);  // several subtree tasks (one per 8192 objects at most)
  for (Aabb& b : boxes) {
    const glm::vec3 lo = glm::floor(rng.vec3(-24.0f, 24.0f));
    const glm::vec3 size = glm::floor(rng.vec3(0.0f, 3.0f));
    b = {lo, lo + size};
    for (int a = 0; a < 3; ++a) {
      if (b.min[a] == 0.0f && rng.uniform(0.0f, 1.0f) < 0.5f) b.min[a] = -0.0f;
      if (b.max[a] == 0.0f && rng.uniform(0.0f, 1.0f) < 0.5f) b.max[a] = -0.0f;
    }
  }
  std::vector<Frustum> views = test_views();
  const std::vector<glm::vec4> slab = {{1, 0, 0, 4},  {-1, 0, 0, 3}, {0, 1, 0, 0},
                                       {0, -1, 0, 6}, {0, 0, 1, 2},  {0, 0, -1, 2}};
  views.push_back(Frustum::from_planes(slab));
  const std::vector<glm::vec4> corner = {{1, 0, 0, -0.0f}, {0, -1, 0, 0}, {0, 0, -1, 1}};
  views.push_back(Frustum::from_planes(corner));
  for (std::uint32_t leaf : {1u, 7u, 300u}) {
    bvh::BuildOptions options;
    options.max_leaf_size = leaf;
    const bvh::FlatTree tree = bvh::flatten(bvh::build("binned-sah", boxes, options));
    for (Isa isa : fast::supported_isas()) {
      fast::CpuBvhCuller culler(2, isa);
      culler.upload(tree, boxes);
      for (std::uint32_t range : {0u, 3u, fast::CpuBvhCullOptions::default_range_objects(BvKind::Aabb), 1000u})
        for (std::size_t v = 0; v < views.size(); ++v) {
          const std::string what = "leaf " + std::to_string(leaf) + " isa=" + std::string(to_string(isa)) + " ranges " +
                                   std::to_string(range) + " view " + std::to_string(v);
          const bvh::HierarchicalResult expected = bvh::cull_hierarchical(tree, boxes, views[v], {range});
          std::vector<std::uint32_t> ids;
          bvh::HierarchicalResult got;
          const fast::CpuBvhCullOptions cull_options{true, true, range};
          culler.cull(views[v], cull_options, got, ids);
          expect_same_traversal(expected, got, what);
          expect_visible_list(expected, tree, ids, what);
          if (HasFatalFailure()) return;
        }
    }
  }
}

// OBB and sphere hierarchies at the node margin's edges: volumes touching axis planes (and a
// float step inside them), and volumes past 2^120 where the margin decides nothing. Every
// instruction set's walk must give the scalar traversal's classes, counts and list.
TEST(CpuBvhCuller, MarginEdgesAndHugeCoordinatesEqualTheScalarTraversal) {
  test::Rng rng{29};
  std::vector<Sphere> spheres;
  std::vector<Obb> obbs;
  for (int i = 0; i < 40000; ++i) {
    glm::vec3 c = glm::floor(rng.vec3(-20.0f, 20.0f));
    const float r = std::floor(rng.uniform(0.0f, 4.0f));
    if (i % 3 == 0) c.x = r;                                                           // touching x = 0 from inside
    if (i % 5 == 0) c.y = -r;                                                          // touching y = 0 from inside
    if (i % 7 == 0) c.x = std::nextafter(r, 0.0f);                                     // a float step across
    if (i % 97 == 0) c = glm::vec3(0x1p121f * float(1 + i % 3), -0x1p122f, 0x1p121f);  // past 2^120
    spheres.push_back({c, r});
    Obb b;
    b.center = c;
    b.basis = i % 2 ? glm::mat3(1.0f) : rng.rotation();
    b.half_extents = glm::vec3(r, r * 0.5f, r);
    obbs.push_back(b);
  }
  std::vector<Frustum> views = test_views(false);
  const std::vector<glm::vec4> axis_planes = {{1, 0, 0, 0}, {0, -1, 0, 0}, {0, 0, 1, 10}, {0, 0, -1, 10}};
  views.push_back(Frustum::from_planes(axis_planes));
  const std::vector<glm::vec4> far_planes = {{1, 0, 0, -0x1p121f}, {0, -1, 0, 0}};
  views.push_back(Frustum::from_planes(far_planes));
  const bvh::FlatTree sphere_tree =
      bvh::flatten(bvh::build("binned-sah", bvh::enclosing_boxes(std::span<const Sphere>(spheres))));
  const bvh::FlatTree obb_tree =
      bvh::flatten(bvh::build("binned-sah", bvh::enclosing_boxes(std::span<const Obb>(obbs))));
  for (Isa isa : fast::supported_isas()) {
    fast::CpuBvhCuller culler(2, isa);
    for (std::uint32_t range : {0u, fast::CpuBvhCullOptions::default_range_objects(BvKind::Obb),
                                fast::CpuBvhCullOptions::default_range_objects(BvKind::Aabb),
                                100000u})  // (the last: the whole tree one range)
      for (std::size_t v = 0; v < views.size(); ++v) {
        const std::string what =
            "isa=" + std::string(to_string(isa)) + " ranges " + std::to_string(range) + " view " + std::to_string(v);
        std::vector<std::uint32_t> ids;
        bvh::HierarchicalResult got;
        const fast::CpuBvhCullOptions options{true, true, range};
        culler.upload(sphere_tree, std::span<const Sphere>(spheres));
        const bvh::HierarchicalResult s =
            bvh::cull_hierarchical(sphere_tree, std::span<const Sphere>(spheres), views[v], {range});
        culler.cull(views[v], options, got, ids);
        expect_same_traversal(s, got, "spheres " + what);
        expect_visible_list(s, sphere_tree, ids, "spheres " + what);
        culler.upload(obb_tree, std::span<const Obb>(obbs));
        const bvh::HierarchicalResult o =
            bvh::cull_hierarchical(obb_tree, std::span<const Obb>(obbs), views[v], {range});
        culler.cull(views[v], options, got, ids);
        expect_same_traversal(o, got, "obbs " + what);
        expect_visible_list(o, obb_tree, ids, "obbs " + what);
        if (HasFatalFailure()) return;
      }
  }
}

// Several views in one pass: each view's classes, counts and list equal the scalar
// traversal's for that view alone (views of 6, 4, 1 and no planes, everything and nothing
// visible), for every volume kind, with and without classes and list.
TEST(CpuBvhCuller, SeveralViewsInOnePassEqualOnePassEach) {
  test::Rng rng{37};
  const test::RandomVolumes v = test::random_volumes(rng, 50000, 30.0f, 2.0f);
  std::vector<Frustum> views = test_views(false);
  const glm::vec4 everything[1] = {{0, 0, 1, 1e6f}};
  const glm::vec4 nothing[1] = {{0, 0, 1, -1e6f}};
  views.push_back(Frustum::from_planes(everything));
  views.push_back(Frustum::from_planes(nothing));
  views.push_back(Frustum::from_view_proj(test::test_view_proj(5.0f, 1.0f)));
  const bvh::FlatTree box_tree = bvh::flatten(bvh::build("binned-sah", v.aabbs));
  const bvh::FlatTree obb_tree =
      bvh::flatten(bvh::build("binned-sah", bvh::enclosing_boxes(std::span<const Obb>(v.obbs))));
  const bvh::FlatTree sphere_tree =
      bvh::flatten(bvh::build("binned-sah", bvh::enclosing_boxes(std::span<const Sphere>(v.spheres))));
  std::vector<fast::CpuBvhViewResult> results(2);  // resized by the pass
  for (unsigned threads : {1u, 3u}) {
    fast::CpuBvhCuller culler(threads);
    for (int kind = 0; kind < 3; ++kind) {
      const bvh::FlatTree& tree = kind == 0 ? box_tree : kind == 1 ? obb_tree : sphere_tree;
      if (kind == 0) culler.upload(tree, std::span<const Aabb>(v.aabbs));
      if (kind == 1) culler.upload(tree, std::span<const Obb>(v.obbs));
      if (kind == 2) culler.upload(tree, std::span<const Sphere>(v.spheres));
      for (const fast::CpuBvhCullOptions options :
           {fast::CpuBvhCullOptions{true, true}, fast::CpuBvhCullOptions{false, true},
            fast::CpuBvhCullOptions{true, false}}) {
        culler.cull(views, options, results);
        ASSERT_EQ(results.size(), views.size());
        for (std::size_t view = 0; view < views.size(); ++view) {
          const std::string what = "kind " + std::to_string(kind) + " threads=" + std::to_string(threads) + " view " +
                                   std::to_string(view) + (options.classes ? " classes" : "") +
                                   (options.visible_ids ? " list" : "");
          const bvh::HierarchicalResult expected =
              kind == 0 ? bvh::cull_hierarchical(tree, std::span<const Aabb>(v.aabbs), views[view],
                                                 fast_traversal(BvKind::Aabb))
              : kind == 1
                  ? bvh::cull_hierarchical(tree, std::span<const Obb>(v.obbs), views[view], fast_traversal(BvKind::Obb))
                  : bvh::cull_hierarchical(tree, std::span<const Sphere>(v.spheres), views[view],
                                           fast_traversal(BvKind::Sphere));
          const bvh::HierarchicalResult& got = results[view].result;
          if (options.classes) {
            expect_same_traversal(expected, got, what);
          } else {
            EXPECT_TRUE(got.classes.empty()) << what;
            EXPECT_EQ(got.node_tests, expected.node_tests) << what;
            EXPECT_EQ(got.object_tests, expected.object_tests) << what;
            EXPECT_EQ(got.visible, expected.visible) << what;
            EXPECT_EQ(got.inside, expected.inside) << what;
          }
          if (options.visible_ids) expect_visible_list(expected, tree, results[view].visible_ids, what);
          if (HasFatalFailure()) return;
        }
      }
    }
    culler.cull(std::span<const Frustum>(), {}, results);
    EXPECT_TRUE(results.empty());
  }
}

// A tree with an empty inner node (two empty leaves under it): check_flat_tree accepts it. With
// range_objects 0 the traversal is the classic one and descends into the empty node (5 node
// tests, as the GPU makes); with ranges of 1 the empty node is a range of no objects (3); with
// 32 the root is one range (1). The fast culler makes the scalar traversal's tests each time.
TEST(CpuBvhCuller, EmptyNodesDescendOnlyWithoutRanges) {
  const std::vector<Aabb> boxes = {{{-1, -1, -1}, {1, 1, 1}}, {{2, 2, 2}, {3, 3, 3}}};
  auto node = [](std::uint32_t skip, std::uint32_t first, std::uint32_t count, bool leaf) {
    return flat_node({{-10, -10, -10}, {10, 10, 10}}, skip, first, count, leaf);
  };
  bvh::FlatTree tree;
  tree.nodes = {node(5, 0, 2, false), node(4, 0, 0, false), node(3, 0, 0, true), node(4, 0, 0, true),
                node(5, 0, 2, true)};
  tree.objects = {0, 1};
  ASSERT_EQ(bvh::check_flat_tree(tree, std::span<const Aabb>(boxes)), "");
  const glm::vec4 plane[1] = {{1, 0, 0, 0}};  // x >= 0: every node straddles it
  const Frustum f = Frustum::from_planes(plane);
  for (std::uint32_t range : {0u, 1u, 32u}) {
    const bvh::HierarchicalResult expected = bvh::cull_hierarchical(tree, std::span<const Aabb>(boxes), f, {range});
    EXPECT_EQ(expected.node_tests, range == 0   ? 5u
                                   : range == 1 ? 3u
                                                : 1u)
        << "ranges " << range;  // (32: the root is a range)
    for (Isa isa : fast::supported_isas()) {
      fast::CpuBvhCuller culler(1, isa);
      culler.upload(tree, std::span<const Aabb>(boxes));
      const fast::CpuBvhCullOptions options{true, true, range};
      bvh::HierarchicalResult got;
      std::vector<std::uint32_t> ids;
      culler.cull(f, options, got, ids);
      const std::string what = "ranges " + std::to_string(range) + " isa=" + std::string(to_string(isa));
      expect_same_traversal(expected, got, what);
      expect_visible_list(expected, tree, ids, what);
    }
  }
}

// An empty straddling leaf at a position that is not a multiple of the vector width, walked
// as a subtree task of its own (its marks are zero words): it lists nothing and marks nothing.
// (A range loop over vectors aligned below its first object once wrote a mark word past its
// own: past the bitmap here, which AddressSanitizer reports.)
TEST(CpuBvhCuller, AnEmptyLeafTaskAtAnUnalignedPositionMarksNothing) {
  test::Rng rng{47};
  const std::uint32_t n = 16385;  // two subtree tasks (one per 8192 objects), 16385 % 16 = 1
  std::vector<Aabb> boxes(n);
  for (Aabb& b : boxes) {
    const glm::vec3 c{rng.uniform(-9.0f, 9.0f), rng.uniform(-9.0f, 9.0f), rng.uniform(-9.0f, 9.0f)};
    b = {c - 0.5f, c + 0.5f};
  }
  auto node = [](std::uint32_t skip, std::uint32_t first, std::uint32_t count, bool leaf) {
    return flat_node({{-10, -10, -10}, {10, 10, 10}}, skip, first, count, leaf);
  };
  bvh::FlatTree tree;
  // The root; a leaf of every object; an empty leaf after them.
  tree.nodes = {node(3, 0, n, false), node(2, 0, n, true), node(3, n, 0, true)};
  tree.objects.resize(n);
  for (std::uint32_t k = 0; k < n; ++k) tree.objects[k] = k;
  ASSERT_EQ(bvh::check_flat_tree(tree, std::span<const Aabb>(boxes)), "");
  const glm::vec4 plane[1] = {{1, 0, 0, 0}};  // x >= 0: both leaves straddle it
  const Frustum f = Frustum::from_planes(plane);
  const bvh::HierarchicalResult expected =
      bvh::cull_hierarchical(tree, std::span<const Aabb>(boxes), f, fast_traversal(BvKind::Aabb));
  for (Isa isa : fast::supported_isas())
    for (unsigned threads : {1u, 2u}) {
      fast::CpuBvhCuller culler(threads, isa);
      culler.upload(tree, std::span<const Aabb>(boxes));
      bvh::HierarchicalResult got;
      std::vector<std::uint32_t> ids;
      culler.cull(f, {true, true}, got, ids);
      const std::string what = "isa=" + std::string(to_string(isa)) + " threads " + std::to_string(threads);
      expect_same_traversal(expected, got, what);
      expect_visible_list(expected, tree, ids, what);
    }
}

// The visible-list kernel of every instruction set against a scalar listing: zero, full and
// partial words, a partial last word, and room for the vector stores or only for the ids; and
// runs of zero words of every length up to three times the vector of words the kernel skips at
// once (8 with AVX-512, 4 with AVX2, 2 portable), ending anywhere, the last word too; and
// leaves every word clear for the next pass.
TEST(CpuBvhCuller, ListKernelListsTheMarkedIds) {
  test::Rng rng{43};
  for (Isa isa : fast::supported_isas()) {
    const fast::detail::KernelTable table = fast::detail::kernels(isa);
    for (std::size_t objects : {1u, 63u, 64u, 65u, 200u, 448u, 1100u, 4160u}) {
      const std::size_t words = (objects + 63) / 64;
      std::vector<std::uint32_t> from(objects);
      for (std::size_t k = 0; k < objects; ++k) from[k] = static_cast<std::uint32_t>(1000 + 7 * k);
      for (int pattern = 0; pattern < 32; ++pattern) {
        std::vector<std::uint64_t> marks(words);
        for (std::size_t w = 0; w < words; ++w) {
          // Patterns 0-5: zero, full, sparse, dense words in turn. 6-30: zero words but every
          // (pattern - 5)th, which is sparse, dense or full in turn (runs of 1-24 zero words:
          // up to three vectors' worth with AVX-512). 31: all zero.
          int kind = (pattern + static_cast<int>(w)) % 4;
          if (pattern >= 6) {
            const std::size_t gap = static_cast<std::size_t>(pattern - 5);
            kind = pattern == 31 || (w + 1) % gap != 0 ? 0 : 1 + static_cast<int>((w + 1) / gap % 3);
          }
          std::uint64_t bits = 0;
          for (unsigned b = 0; b < 64; ++b)
            if (kind == 1 || (kind == 2 && rng.uniform(0.0f, 1.0f) < 0.1f) ||
                (kind == 3 && rng.uniform(0.0f, 1.0f) < 0.7f))
              bits |= 1ull << b;
          marks[w] = bits;
        }
        if (objects % 64) marks.back() &= (1ull << (objects % 64)) - 1;  // no bit past the objects
        std::vector<std::uint32_t> want;
        for (std::size_t k = 0; k < objects; ++k)
          if (marks[k / 64] >> (k % 64) & 1u) want.push_back(from[k]);
        // Room for exactly the ids, for 16 more (the vector stores), and for half of them (marks
        // left set by a pass that stopped: the first ids, up to out_end).
        for (const std::size_t room : {want.size(), want.size() + 16, want.size() / 2}) {
          const std::size_t listed = std::min(room, want.size());
          std::vector<std::uint32_t> out(room + 1, 0xdeadbeefu);  // one guard past the room
          std::vector<std::uint64_t> cleared = marks;             // (the kernel clears the words it lists)
          std::uint32_t* end = table.list(cleared.data(), words, from.data(), out.data(), out.data() + room);
          const std::string what = std::string(to_string(isa)) + " objects " + std::to_string(objects) + " pattern " +
                                   std::to_string(pattern) + " room " + std::to_string(room);
          EXPECT_EQ(cleared, std::vector<std::uint64_t>(words, 0)) << what << ": marks left set";
          ASSERT_EQ(end - out.data(), static_cast<std::ptrdiff_t>(listed)) << what;
          EXPECT_EQ(std::vector<std::uint32_t>(out.begin(), out.begin() + std::ptrdiff_t(listed)),
                    std::vector<std::uint32_t>(want.begin(), want.begin() + std::ptrdiff_t(listed)))
              << what;
          EXPECT_EQ(out[room], 0xdeadbeefu) << what << ": wrote past out_end";
        }
      }
    }
  }
}

// An engine culls every frame: once the sizes have settled, a pass (one view or several,
// classes, list or both, any range size) allocates nothing.
TEST(CpuBvhCuller, ASteadyPassAllocatesNothing) {
  test::Rng rng{41};
  const test::RandomVolumes v = test::random_volumes(rng, 100000, 30.0f, 2.0f);
  const bvh::FlatTree tree = bvh::flatten(bvh::build("binned-sah", v.aabbs));
  fast::CpuBvhCuller culler(2);
  culler.upload(tree, std::span<const Aabb>(v.aabbs));
  const std::vector<Frustum> views = test_views(false);
  std::vector<fast::CpuBvhViewResult> results;
  bvh::HierarchicalResult single;
  std::vector<std::uint32_t> ids;
  const fast::CpuBvhCullOptions both{true, true}, ranges_of_8{false, true, 8};
  auto frame = [&] {
    culler.cull(views, both, results);
    culler.cull(views, ranges_of_8, results);
    for (const Frustum& f : views) culler.cull(f, both, single, ids);
    culler.cull(views[0], single);
  };
  frame();  // sizes settle
  const long before = g_allocations.load();
  for (int i = 0; i < 10; ++i) frame();
  EXPECT_EQ(g_allocations.load() - before, 0) << "allocations in ten steady frames";
  const bvh::HierarchicalResult expected =
      bvh::cull_hierarchical(tree, std::span<const Aabb>(v.aabbs), views[0], fast_traversal(BvKind::Aabb));
  expect_same_traversal(expected, single, "steady");
}

// The marks a walk sets are cleared by the listing, so a pass stopped between the two (here by
// a visible list that cannot grow) leaves them set: the next pass must clear them before it
// walks, or the objects the stopped pass found visible show up in its list.
TEST(CpuBvhCuller, APassStoppedBeforeItsListingLeavesTheNextOneExact) {
  test::Rng rng{47};
  const test::RandomVolumes v = test::random_volumes(rng, 20000, 30.0f, 2.0f);
  const std::span<const Aabb> boxes(v.aabbs);
  const bvh::FlatTree tree = bvh::flatten(bvh::build("binned-sah", v.aabbs));
  const std::vector<Frustum> views = test_views(false);
  auto listed = [&](const Frustum& f) {  // the scalar traversal's visible ids, in tree order
    const bvh::HierarchicalResult h = bvh::cull_hierarchical(tree, boxes, f, fast_traversal(BvKind::Aabb));
    std::vector<std::uint32_t> ids;
    for (std::uint32_t o : tree.objects)
      if (is_visible(h.classes[o])) ids.push_back(o);
    return ids;
  };
  const std::vector<std::uint32_t> first = listed(views[0]), second = listed(views[2]);
  // (The premise: the stopped pass sees objects the next one does not.)
  ASSERT_FALSE(second.empty());
  std::vector<bool> in_second(v.aabbs.size());
  for (std::uint32_t o : second) in_second[o] = true;
  ASSERT_TRUE(std::any_of(first.begin(), first.end(), [&](std::uint32_t o) { return !in_second[o]; }));
  for (unsigned threads : {1u, 2u}) {
    fast::CpuBvhCuller culler(threads);
    culler.upload(tree, boxes);
    const fast::CpuBvhCullOptions ids_only{false, true};
    bvh::HierarchicalResult r;
    std::vector<std::uint32_t> settled, empty, ids;
    culler.cull(views[0], ids_only, r, settled);  // the culler's own storage sized
    g_fail_next_allocation = true;                // the next allocation: `empty`'s, after the walk
    EXPECT_THROW(culler.cull(views[0], ids_only, r, empty), std::bad_alloc);
    ASSERT_FALSE(g_fail_next_allocation.load());
    culler.cull(views[2], ids_only, r, ids);
    EXPECT_EQ(ids, second) << threads << " threads";
    culler.cull(views[0], ids_only, r, ids);
    EXPECT_EQ(ids, first) << threads << " threads";
  }
}

TEST(CpuBvhCuller, RejectsKernelsTheCpuLacks) {
  for (Isa isa : {Isa::Avx2, Isa::Avx512})
    if (!fast::isa_supported(isa)) {
      EXPECT_THROW(fast::CpuBvhCuller(2, isa), std::invalid_argument);
    }
  EXPECT_EQ(fast::CpuBvhCuller(2).isa(), fast::best_isa());
}

TEST(CpuBvhCuller, RefusesATreeOfOtherBoxes) {
  std::vector<Aabb> boxes(10, Aabb{{0, 0, 0}, {1, 1, 1}});
  const bvh::FlatTree tree = bvh::flatten(bvh::build("binned-sah", boxes));
  fast::CpuBvhCuller culler(2);
  EXPECT_THROW(culler.upload(tree, std::span<const Aabb>(boxes).first(9)), std::invalid_argument);
  bvh::FlatTree repeated = tree;
  repeated.objects[1] = repeated.objects[0];  // an id twice (and one missing)
  EXPECT_THROW(culler.upload(repeated, boxes), std::invalid_argument);
  // Inner nodes are checked too: the traversal follows their links and ranges.
  bvh::FlatTree bad_link = tree;
  bad_link.nodes[1].skip = std::uint32_t(tree.nodes.size()) + 5;
  EXPECT_THROW(culler.upload(bad_link, boxes), std::invalid_argument);
  bvh::FlatTree bad_range = tree;
  bad_range.nodes[1].count += 1;
  EXPECT_THROW(culler.upload(bad_range, boxes), std::invalid_argument);
  // A refused upload leaves the last good one in place.
  culler.upload(tree, boxes);
  EXPECT_THROW(culler.upload(bad_link, boxes), std::invalid_argument);
  const glm::vec4 all[1] = {{0, 0, 1, 1e6f}};
  EXPECT_EQ(culler.cull(Frustum::from_planes(all)).visible, boxes.size());
}

// The volumes are checked as the threads gather them (valid, inside their leaf's box): a bad
// one anywhere, in any kind, is refused with bvh::check_flat_tree's message, and the upload
// before it still culls as it did.
TEST(CpuBvhCuller, RefusesABadVolumeWhereverItIsAndKeepsTheLastUpload) {
  test::Rng rng{41};
  const std::size_t n = 40000;  // many parts on every thread
  const test::RandomVolumes v = test::random_volumes(rng, n, 30.0f, 2.0f);
  const std::vector<Frustum> views = test_views(false);
  const bvh::FlatTree box_tree = bvh::flatten(bvh::build("binned-sah", v.aabbs));
  const bvh::FlatTree obb_tree =
      bvh::flatten(bvh::build("binned-sah", bvh::enclosing_boxes(std::span<const Obb>(v.obbs))));
  const bvh::FlatTree sphere_tree =
      bvh::flatten(bvh::build("binned-sah", bvh::enclosing_boxes(std::span<const Sphere>(v.spheres))));
  fast::CpuBvhCuller culler(3);
  culler.upload(box_tree, std::span<const Aabb>(v.aabbs));
  const bvh::HierarchicalResult before = culler.cull(views[0]);
  auto expect_refused = [&](const auto& tree, const auto& volumes, const std::string& what) {
    SCOPED_TRACE(what);
    const std::string why = bvh::check_flat_tree(tree, std::span(volumes));
    ASSERT_FALSE(why.empty());
    try {
      culler.upload(tree, std::span(volumes));
      ADD_FAILURE() << "accepted";
    } catch (const std::invalid_argument& e) {
      EXPECT_EQ(std::string(e.what()), "CpuBvhCuller::upload: " + why);
    }
    EXPECT_EQ(culler.kind(), BvKind::Aabb);
    expect_same_traversal(before, culler.cull(views[0]), what);
  };
  for (std::size_t slot : {std::size_t(0), n / 3, n / 2 + 17, n - 1}) {  // tree-order slots: first, middle parts, last
    const std::uint32_t id = box_tree.objects[slot];
    std::vector<Aabb> boxes = v.aabbs;
    boxes[id].max.x = std::numeric_limits<float>::quiet_NaN();
    expect_refused(box_tree, boxes, "a NaN box at slot " + std::to_string(slot));
    boxes = v.aabbs;
    boxes[id].max.y += 1000.0f;  // valid, but out of its leaf
    expect_refused(box_tree, boxes, "a box out of its leaf at slot " + std::to_string(slot));
    std::vector<Obb> obbs = v.obbs;
    obbs[obb_tree.objects[slot]].center.z -= 1000.0f;
    expect_refused(obb_tree, obbs, "an OBB out of its leaf at slot " + std::to_string(slot));
    std::vector<Sphere> spheres = v.spheres;
    spheres[sphere_tree.objects[slot]].radius = -1.0f;
    expect_refused(sphere_tree, spheres, "a negative radius at slot " + std::to_string(slot));
  }
  // A good upload of another kind after the refusals, then boxes again: as fresh.
  culler.upload(sphere_tree, std::span<const Sphere>(v.spheres));
  expect_same_traversal(
      bvh::cull_hierarchical(sphere_tree, std::span<const Sphere>(v.spheres), views[1], fast_traversal(BvKind::Sphere)),
      culler.cull(views[1]), "spheres after the refusals");
  culler.upload(box_tree, std::span<const Aabb>(v.aabbs));
  expect_same_traversal(before, culler.cull(views[0]), "boxes again");
}

// Trees of other sizes, leaf sizes and volume kinds uploaded one after another on one culler:
// each culls as a fresh culler would (nothing of an earlier upload leaks into a later one).
TEST(CpuBvhCuller, UploadsOneAfterAnotherCullAsAFreshCuller) {
  test::Rng rng{23};
  const std::vector<Frustum> views = test_views(false);
  fast::CpuBvhCuller culler(2);
  for (std::size_t n : {3000u, 101u, 20000u, 1u, 5001u}) {
    const test::RandomVolumes v = test::random_volumes(rng, n, 30.0f, 2.0f);
    bvh::BuildOptions options;
    options.max_leaf_size = n % 2 ? 1 : 8;
    const bvh::FlatTree box_tree = bvh::flatten(bvh::build("binned-sah", v.aabbs, options));
    const bvh::FlatTree obb_tree =
        bvh::flatten(bvh::build("binned-sah", bvh::enclosing_boxes(std::span<const Obb>(v.obbs)), options));
    const bvh::FlatTree sphere_tree =
        bvh::flatten(bvh::build("binned-sah", bvh::enclosing_boxes(std::span<const Sphere>(v.spheres)), options));
    bvh::HierarchicalResult got;
    for (const Frustum& view : views) {
      culler.upload(box_tree, std::span<const Aabb>(v.aabbs));
      culler.cull(view, got);
      expect_same_traversal(
          bvh::cull_hierarchical(box_tree, std::span<const Aabb>(v.aabbs), view, fast_traversal(BvKind::Aabb)), got,
          "boxes n=" + std::to_string(n));
      culler.upload(obb_tree, std::span<const Obb>(v.obbs));
      culler.cull(view, got);
      expect_same_traversal(
          bvh::cull_hierarchical(obb_tree, std::span<const Obb>(v.obbs), view, fast_traversal(BvKind::Obb)), got,
          "obbs n=" + std::to_string(n));
      culler.upload(sphere_tree, std::span<const Sphere>(v.spheres));
      culler.cull(view, got);
      expect_same_traversal(
          bvh::cull_hierarchical(sphere_tree, std::span<const Sphere>(v.spheres), view, fast_traversal(BvKind::Sphere)),
          got, "spheres n=" + std::to_string(n));
      if (HasFatalFailure()) return;
    }
  }
}

TEST(CpuBvhCuller, ObbsAndSpheresEqualTheScalarTraversalAndFlatCulling) {
  test::Rng rng{17};
  const std::vector<Frustum> views = test_views(false);
  for (std::size_t n : {0u, 1u, 7u, 3000u, 40000u}) {
    const test::RandomVolumes v = test::random_volumes(rng, n, 30.0f, 2.0f);
    const bvh::FlatTree obb_tree =
        bvh::flatten(bvh::build("binned-sah", bvh::enclosing_boxes(std::span<const Obb>(v.obbs))));
    const bvh::FlatTree sphere_tree =
        bvh::flatten(bvh::build("binned-sah", bvh::enclosing_boxes(std::span<const Sphere>(v.spheres))));
    for (Isa isa : fast::supported_isas())
      for (unsigned threads : {1u, 2u, 3u}) {
        fast::CpuBvhCuller culler(threads, isa);
        bvh::HierarchicalResult got;
        for (std::size_t view = 0; view < views.size(); ++view) {
          const std::string what = "n=" + std::to_string(n) + " isa=" + std::string(to_string(isa)) +
                                   " threads=" + std::to_string(threads) + " view " + std::to_string(view);
          culler.upload(obb_tree, std::span<const Obb>(v.obbs));
          EXPECT_EQ(culler.kind(), BvKind::Obb);
          culler.cull(views[view], got);
          expect_same_traversal(
              bvh::cull_hierarchical(obb_tree, std::span<const Obb>(v.obbs), views[view], fast_traversal(BvKind::Obb)),
              got, "obb " + what);
          std::vector<Classification> flat(n);
          reference::classify_all(std::span<const Obb>(v.obbs), views[view], flat);
          EXPECT_EQ(got.classes, flat) << "obb " << what;
          std::vector<std::uint32_t> ids;
          bvh::HierarchicalResult listed;
          culler.cull(views[view], {false, true}, listed, ids);
          expect_visible_list(got, obb_tree, ids, "obb list " + what);
          culler.upload(sphere_tree, std::span<const Sphere>(v.spheres));
          culler.cull(views[view], got);
          culler.cull(views[view], {false, true}, listed, ids);
          expect_visible_list(got, sphere_tree, ids, "sphere list " + what);
          expect_same_traversal(bvh::cull_hierarchical(sphere_tree, std::span<const Sphere>(v.spheres), views[view],
                                                       fast_traversal(BvKind::Sphere)),
                                got, "sphere " + what);
          reference::classify_all(std::span<const Sphere>(v.spheres), views[view], flat);
          EXPECT_EQ(got.classes, flat) << "sphere " << what;
          if (HasFatalFailure()) return;
        }
      }
  }
}

TEST(CpuBvhCuller, RefusesLeavesThatDoNotEncloseTheirVolumes) {
  test::Rng rng{19};
  const test::RandomVolumes v = test::random_volumes(rng, 200, 30.0f, 2.0f);
  fast::CpuBvhCuller culler(2);
  // A tree over the spheres' centres only (not their enclosing boxes).
  std::vector<Aabb> centres;
  for (const Sphere& s : v.spheres) centres.push_back({s.center, s.center});
  const bvh::FlatTree tree = bvh::flatten(bvh::build("binned-sah", centres));
  try {
    culler.upload(tree, std::span<const Sphere>(v.spheres));
    ADD_FAILURE() << "a tree over the centres was accepted";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("enclosing_boxes"), std::string::npos) << e.what();
  }
}

// A worker that wakes late, after the caller finished a call and started the next, must not
// run the next call's tasks in the float mode it loaded for the first: every task runs in the
// mode of the call that issued it, even when it changes every call.
TEST(ThreadPool, EveryTaskRunsInItsCallersFloatMode) {
#if defined(__SSE__)
  ThreadPool pool(3);
  const unsigned saved = _mm_getcsr();
  constexpr unsigned kControl = 0xFFC0u;  // rounding, FTZ, DAZ and the exception masks (not the flags)
  for (int round = 0; round < 3000; ++round) {
    const unsigned mode = round % 2 ? saved | 0x8040u : saved & ~0x8040u;  // flush-to-zero and denormals-are-zero
    std::vector<unsigned> seen(16);
    _mm_setcsr(mode);
    pool.parallel_for(seen.size(), [&](std::size_t t) { seen[t] = _mm_getcsr(); });
    _mm_setcsr(saved);
    for (unsigned m : seen) ASSERT_EQ(m & kControl, mode & kControl) << "round " << round;
  }
#else
  GTEST_SKIP() << "no MXCSR";
#endif
}

// The workers sleep after their spin and wake for the next call; thread_index() names the
// running thread (the same index always the same thread), and a pool destroyed while its
// workers spin shuts down.
TEST(ThreadPool, WakesAfterSleepingAndIndexesItsThreads) {
  ThreadPool pool(3);
  std::map<unsigned, std::thread::id> owner;
  std::mutex m;
  for (int round = 0; round < 6; ++round) {
    if (round % 2) std::this_thread::sleep_for(std::chrono::milliseconds(2));  // past the spin
    std::vector<int> hits(64, 0);
    pool.parallel_for(hits.size(), [&](std::size_t t) {
      const unsigned index = pool.thread_index();
      std::lock_guard lock(m);
      ++hits[t];
      EXPECT_LT(index, pool.size());
      const auto [it, fresh] = owner.emplace(index, std::this_thread::get_id());
      EXPECT_EQ(it->second, std::this_thread::get_id()) << "index " << index << " on two threads";
      (void)fresh;
    });
    for (int h : hits) ASSERT_EQ(h, 1);
  }
  EXPECT_EQ(owner.at(0), std::this_thread::get_id());
  EXPECT_EQ(pool.thread_index(), 0u);
  for (int k = 0; k < 20; ++k) {
    ThreadPool short_lived(2);
    std::atomic<int> ran{0};
    short_lived.parallel_for(8, [&](std::size_t) { ++ran; });
    EXPECT_EQ(ran.load(), 8);
  }
}

// Calls back to back, of 2 to 40 tasks, with pauses past the spin now and then (so the
// workers sleep and the caller may sleep waiting for them): every task runs once, in its own
// call. Each call's tasks write to storage that ends with the call, so a task run after its
// call returned (a worker that read a call late) is a use after scope under AddressSanitizer,
// and a task of one call run with another's count or lambda shows in the hits.
TEST(ThreadPool, CallsBackToBackRunEveryTaskOnceInItsOwnCall) {
  ThreadPool pool(3);
  for (int round = 0; round < 20000; ++round) {
    if (round % 2500 == 1249) std::this_thread::sleep_for(std::chrono::microseconds(300));
    const std::size_t tasks = 2 + static_cast<std::size_t>(round * 7919 % 39);
    std::vector<int> hits(tasks, 0);
    std::atomic<int> wrong_call{0};
    pool.parallel_for(tasks, [&](std::size_t t) {
      if (t >= hits.size())
        wrong_call.fetch_add(1);
      else
        ++hits[t];
    });
    ASSERT_EQ(wrong_call.load(), 0) << "round " << round;
    for (std::size_t t = 0; t < tasks; ++t) ASSERT_EQ(hits[t], 1) << "round " << round << " task " << t;
  }
}

TEST(ThreadPool, RunsEveryTaskOnceAndRethrows) {
  ThreadPool pool(3);
  for (int round = 0; round < 200; ++round) {
    std::vector<int> hits(97, 0);
    pool.parallel_for(hits.size(), [&](std::size_t t) { ++hits[t]; });
    for (int h : hits) ASSERT_EQ(h, 1);
  }
  EXPECT_THROW(pool.parallel_for(10,
                                 [](std::size_t t) {
                                   if (t == 7) throw std::runtime_error("task 7");
                                 }),
               std::runtime_error);
  int after = 0;
  pool.parallel_for(1, [&](std::size_t) { ++after; });
  EXPECT_EQ(after, 1);
  // On one thread too, the tasks after a throwing one still run.
  ThreadPool alone(1);
  std::vector<int> hits(10, 0);
  EXPECT_THROW(alone.parallel_for(hits.size(),
                                  [&](std::size_t t) {
                                    ++hits[t];
                                    if (t == 3) throw std::runtime_error("task 3");
                                  }),
               std::runtime_error);
  EXPECT_EQ(hits, std::vector<int>(10, 1));
}

}  // namespace
}  // namespace cullpipe
