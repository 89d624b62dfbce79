// Fuzzes the fast CPU cullers (src/cullpipe/cull) against the scalar reference, bit for bit. The bytes
// describe a scene: the volume kind, up to 256 volumes (boxes, spheres or OBBs with small-integer
// coordinates at a chosen scale, so that many touch a plane exactly), copies of them side by side
// (up to 33,280 objects, enough for several subtree tasks), a frustum of 1-6 planes (for boxes
// possibly unnormalised, even with a zero normal), a tree (from a builder, or split at the
// bytes' positions with empty nodes, big leaves and any depth), a range size, a thread count
// and a chunk size. For every instruction set the machine runs:
//   - fast::CpuCuller's classes, counts and visible list equal reference::classify_all's;
//   - bvh::cull_hierarchical's classes equal the reference's;
//   - fast::CpuBvhCuller's classes, counts, node and object test counts equal
//     bvh::cull_hierarchical's with the same range size, its visible list is the visible
//     objects in tree order (with and without classes), and a two-view pass gives each view
//     what a pass of its own gives.
// Any difference prints the object, its volume, the planes and both answers, and aborts.
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <glm/gtc/quaternion.hpp>
#include <numeric>
#include <random>
#include <span>
#include <string>
#include <type_traits>
#include <vector>

#include "cullpipe/bvh/box_ops.hpp"
#include "cullpipe/bvh/builders.hpp"
#include "cullpipe/bvh/bvh.hpp"
#include "cullpipe/cull/compare.hpp"
#include "cullpipe/cull/cpu_bvh_culler.hpp"
#include "cullpipe/cull/cpu_culler.hpp"
#include "cullpipe/cull/reference.hpp"
#include "cullpipe/geom/frustum.hpp"

namespace {

using namespace cullpipe;
using fast::Isa;

/// The input, read front to back; past its end every byte is 0.
class Bytes {
 public:
  Bytes(const std::uint8_t* data, std::size_t size) : data_(data), size_(size) {}
  std::uint8_t u8() { return at_ < size_ ? data_[at_++] : 0; }
  std::int16_t i16() { return static_cast<std::int16_t>(u8() | u8() << 8); }
  std::uint32_t u32() {
    return std::uint32_t(u8()) | std::uint32_t(u8()) << 8 | std::uint32_t(u8()) << 16 | std::uint32_t(u8()) << 24;
  }

 private:
  const std::uint8_t* data_;
  std::size_t size_, at_ = 0;
};

template <class Volume>
[[noreturn]] void fail(const std::string& what, const std::vector<Volume>& volumes, const Frustum& f,
                       std::size_t object, int expected, int got) {
  std::fprintf(stderr, "fuzz_cull: %s\n", what.c_str());
  if (object < volumes.size()) std::fprintf(stderr, "  object %zu: %s\n", object, describe(volumes[object]).c_str());
  std::fprintf(stderr, "  planes %s\n", describe(f).c_str());
  std::fprintf(stderr, "  expected %d, got %d\n", expected, got);
  std::abort();
}

/// A value of the scene's grid: a small integer (most land on a plane's zero exactly) times the
/// scale.
float coord(Bytes& in, float scale) { return float(in.i16() % 64) * scale; }
float extent(Bytes& in, float scale) { return float(in.u8() % 16) * scale; }

Aabb make(Bytes& in, float scale, Aabb*) {
  const glm::vec3 c{coord(in, scale), coord(in, scale), coord(in, scale)};
  const glm::vec3 e{extent(in, scale), extent(in, scale), extent(in, scale)};
  return {c - e, c + e};
}
Sphere make(Bytes& in, float scale, Sphere*) {
  return {{coord(in, scale), coord(in, scale), coord(in, scale)}, extent(in, scale)};
}
Obb make(Bytes& in, float scale, Obb*) {
  Obb b;
  b.center = {coord(in, scale), coord(in, scale), coord(in, scale)};
  glm::quat q(float(in.i16() % 8), float(in.i16() % 8), float(in.i16() % 8), float(in.i16() % 8));
  if (glm::length(q) == 0.0f) q = glm::quat(1, 0, 0, 0);
  b.basis = glm::mat3_cast(glm::normalize(q));
  b.half_extents = {extent(in, scale), extent(in, scale), extent(in, scale)};
  return b;
}
Aabb moved(Aabb b, glm::vec3 by) { return {b.min + by, b.max + by}; }
Sphere moved(Sphere s, glm::vec3 by) { return {s.center + by, s.radius}; }
Obb moved(Obb b, glm::vec3 by) {
  b.center += by;
  return b;
}

/// A tree split at the bytes' positions: any split of a node's range, an empty side too; a node
/// becomes a leaf when the bytes say so, at depth 40, or when it is empty. Boxes enclose their
/// objects' enclosing boxes (an empty leaf gets a box of its own from the bytes).
struct SplitTree {
  Bytes& in;
  const std::vector<Aabb>& boxes;  // per object id
  const std::vector<std::uint32_t>& objects;
  float scale;
  bvh::FlatTree tree;

  Aabb build(std::uint32_t first, std::uint32_t count, unsigned depth) {
    const std::size_t index = tree.nodes.size();
    tree.nodes.emplace_back();
    const std::uint8_t how = in.u8();
    Aabb box;
    const bool leaf = count == 0 || depth >= 40 || how % 8 == 0;
    if (leaf) {
      if (count == 0) {
        box = make(in, scale, static_cast<Aabb*>(nullptr));
      } else {
        box = boxes[objects[first]];
        for (std::uint32_t k = first + 1; k < first + count; ++k) box = bvh::detail::merged(box, boxes[objects[k]]);
      }
    } else {
      // Mostly near the middle (so trees of many objects stay shallow); sometimes anywhere, or
      // all on one side (an empty child).
      const std::uint32_t left = how % 8 == 1   ? 0
                                 : how % 8 == 2 ? count
                                 : how % 8 == 3 ? in.u32() % (count + 1)
                                                : count / 2 + (count > 8 ? in.u8() % (count / 4 + 1) : 0) - count / 8;
      box = build(first, left, depth + 1);
      box = bvh::detail::merged(box, build(first + left, count - left, depth + 1));
    }
    bvh::FlatNode& node = tree.nodes[index];
    node.box = box;
    node.first = first;
    node.count = count;
    node.leaf = leaf;
    node.skip = static_cast<std::uint32_t>(tree.nodes.size());
    return box;
  }
};

template <class Volume>
void run(Bytes& in, std::uint8_t flags) {
  static const float kScales[] = {1.0f, 0.25f, 1.0f / 1024, 1000.0f, 3.0f, 1e-30f, 1e30f / 64, 0.1f};
  const float scale = kScales[in.u8() % 8];
  const std::size_t base = 1 + in.u8();
  static const std::size_t kCopies[] = {1, 1, 2, 7, 40, 130};  // (256 x 130: four subtree tasks)
  const std::size_t copies = kCopies[in.u8() % 6];
  std::vector<Volume> volumes;
  for (std::size_t i = 0; i < base; ++i) volumes.push_back(make(in, scale, static_cast<Volume*>(nullptr)));
  // Copies side by side along x, one grid of 160 steps apart (the coordinates span +-64 + 16).
  for (std::size_t c = 1; c < copies; ++c)
    for (std::size_t i = 0; i < base; ++i)
      volumes.push_back(moved(volumes[i], glm::vec3(float(c) * 160.0f * scale, 0.0f, 0.0f)));
  const std::size_t n = volumes.size();

  // The frustum: planes of small-integer coefficients, at the scene's scale.
  const unsigned plane_count = 1 + in.u8() % 6;
  std::vector<glm::vec4> raw(plane_count);
  for (glm::vec4& p : raw)
    p = {float(in.i16() % 5), float(in.i16() % 5), float(in.i16() % 5), float(in.i16() % 200) * scale};
  Frustum f;
  if (std::is_same_v<Volume, Aabb> && (flags & 0x08)) {  // as given: unnormalised, a zero normal too
    for (const glm::vec4& p : raw) f.planes[f.plane_count++] = Plane::from_vec4(p);
  } else {
    try {
      f = Frustum::from_planes(raw);
    } catch (const std::invalid_argument&) {
      return;  // a zero normal: no frustum (documented)
    }
  }

  // The tree over the volumes' enclosing boxes: a builder's, or one split at the bytes' positions.
  const std::vector<Aabb> boxes = bvh::enclosing_boxes(std::span<const Volume>(volumes));
  bvh::FlatTree tree;
  if (flags & 0x10) {
    std::vector<std::uint32_t> objects(n);
    std::iota(objects.begin(), objects.end(), 0u);
    std::mt19937 shuffle(in.u32());
    if (flags & 0x20) std::shuffle(objects.begin(), objects.end(), shuffle);
    SplitTree split{in, boxes, objects, scale, {}};
    split.build(0, static_cast<std::uint32_t>(n), 0);
    split.tree.objects = objects;
    tree = std::move(split.tree);
  } else {
    static const char* const kBuilders[] = {"binned-sah", "median", "mean", "agglomerative-local"};
    bvh::BuildOptions options;
    options.max_leaf_size = 1 + in.u8() % 32;
    tree = bvh::flatten(bvh::build(kBuilders[in.u8() % 4], boxes, options));
  }
  if (const std::string why = bvh::check_flat_tree(tree, std::span<const Volume>(volumes)); !why.empty()) {
    std::fprintf(stderr, "fuzz_cull: the fuzzer's own tree is invalid: %s\n", why.c_str());
    std::abort();
  }

  static const std::uint32_t kRanges[] = {0, 1, 7, 33, 96, 160, 200, 5000};  // (96, 160: the defaults)
  const std::uint32_t range = kRanges[in.u8() % 8];
  const unsigned threads = 1 + in.u8() % 3;
  static const std::size_t kChunks[] = {16, 48, 16384};
  const std::size_t chunk = kChunks[in.u8() % 3];

  // The reference, and the hierarchy's scalar traversal.
  std::vector<Classification> ref(n);
  const reference::CullCounts ref_counts = reference::classify_all(std::span<const Volume>(volumes), f, ref);
  const bvh::HierarchicalResult expected = bvh::cull_hierarchical(tree, std::span<const Volume>(volumes), f, {range});
  for (std::size_t i = 0; i < n; ++i)
    if (expected.classes[i] != ref[i])
      fail("cull_hierarchical's class differs from the reference's", volumes, f, i, int(ref[i]),
           int(expected.classes[i]));
  if (expected.visible != ref_counts.visible || expected.inside != ref_counts.inside)
    fail("cull_hierarchical's counts differ from the reference's", volumes, f, n, int(ref_counts.visible),
         int(expected.visible));
  std::vector<std::uint32_t> ref_ids, tree_ids;
  for (std::size_t i = 0; i < n; ++i)
    if (is_visible(ref[i])) ref_ids.push_back(static_cast<std::uint32_t>(i));
  for (std::uint32_t o : tree.objects)
    if (is_visible(ref[o])) tree_ids.push_back(o);

  for (Isa isa : fast::supported_isas()) {
    const std::string at = std::string(" (isa ") + std::string(to_string(isa)) + ", " + std::to_string(threads) +
                           " threads, range " + std::to_string(range) + ", " + std::to_string(n) + " objects, " +
                           std::to_string(tree.nodes.size()) + " nodes)";
    // Flat. A run guesses from the last pass whether to list its ids as it classifies them:
    // a fresh culler's first pass guesses every run sparse (the dense ones list and flag
    // themselves); after a pass that finds every run dense, the sparse runs are listed from
    // their bits; the pass after that guesses from it.
    fast::CpuCuller flat({threads, isa, chunk});
    flat.upload(std::span<const Volume>(volumes));
    const Frustum everything;  // no planes: every object INSIDE
    static const char* const kPasses[] = {", a fresh culler's pass", ", after an all-dense pass",
                                          ", the pass after that"};
    for (const char* pass : kPasses) {
      if (pass == kPasses[1])
        (void)flat.cull(std::span<const Frustum>(&everything, 1), fast::CpuCullOptions{false, true});
      const std::vector<fast::CpuViewResult> got = flat.cull(std::span<const Frustum>(&f, 1));
      for (std::size_t i = 0; i < n; ++i)
        if (got[0].classes[i] != ref[i])
          fail("CpuCuller's class differs from the reference's" + at + pass, volumes, f, i, int(ref[i]),
               int(got[0].classes[i]));
      if (!(got[0].counts == ref_counts))
        fail("CpuCuller's counts differ" + at + pass, volumes, f, n, int(ref_counts.visible),
             int(got[0].counts.visible));
      if (got[0].visible_ids != ref_ids)
        fail("CpuCuller's visible list differs" + at + pass, volumes, f, n, int(ref_ids.size()),
             int(got[0].visible_ids.size()));
    }
    // Two views in one call (each chunk read once for both): the first as alone, the second
    // seeing everything INSIDE.
    const Frustum two_views[2] = {f, everything};
    const std::vector<fast::CpuViewResult> two = flat.cull(two_views);
    for (std::size_t i = 0; i < n; ++i)
      if (two[0].classes[i] != ref[i])
        fail("CpuCuller's class differs with two views" + at, volumes, f, i, int(ref[i]), int(two[0].classes[i]));
    if (!(two[0].counts == ref_counts) || two[0].visible_ids != ref_ids)
      fail("CpuCuller's counts or list differ with two views" + at, volumes, f, n, int(ref_counts.visible),
           int(two[0].counts.visible));
    if (two[1].counts.visible != n || two[1].counts.inside != n || two[1].visible_ids.size() != n)
      fail("CpuCuller's second view (no planes) is not all INSIDE" + at, volumes, everything, n, int(n),
           int(two[1].counts.inside));

    // Hierarchical: classes and list, the list alone, two views.
    fast::CpuBvhCuller fast_bvh(threads, isa);
    fast_bvh.upload(tree, std::span<const Volume>(volumes));
    bvh::HierarchicalResult h;
    std::vector<std::uint32_t> ids;
    fast_bvh.cull(f, {true, true, range}, h, ids);
    for (std::size_t i = 0; i < n; ++i)
      if (h.classes[i] != expected.classes[i])
        fail("CpuBvhCuller's class differs" + at, volumes, f, i, int(expected.classes[i]), int(h.classes[i]));
    if (h.node_tests != expected.node_tests)
      fail("CpuBvhCuller's node tests differ" + at, volumes, f, n, int(expected.node_tests), int(h.node_tests));
    if (h.object_tests != expected.object_tests)
      fail("CpuBvhCuller's object tests differ" + at, volumes, f, n, int(expected.object_tests), int(h.object_tests));
    if (h.visible != expected.visible || h.inside != expected.inside)
      fail("CpuBvhCuller's counts differ" + at, volumes, f, n, int(expected.inside), int(h.inside));
    if (ids != tree_ids)
      fail("CpuBvhCuller's visible list differs" + at, volumes, f, n, int(tree_ids.size()), int(ids.size()));
    bvh::HierarchicalResult listed;
    std::vector<std::uint32_t> listed_ids;
    fast_bvh.cull(f, {false, true, range}, listed, listed_ids);
    if (listed_ids != tree_ids || listed.visible != expected.visible || listed.inside != expected.inside ||
        !listed.classes.empty())
      fail("CpuBvhCuller's list-only pass differs" + at, volumes, f, n, int(tree_ids.size()), int(listed_ids.size()));
    Frustum all;  // a second view that sees everything (every volume is INSIDE its one plane)
    all.planes[0] = Plane{{0.0f, 0.0f, 1.0f}, 1e35f};
    all.plane_count = 1;
    const Frustum views[2] = {f, all};
    std::vector<fast::CpuBvhViewResult> both;
    fast_bvh.cull(views, {true, true, range}, both);
    if (both[0].result.classes != h.classes || both[0].visible_ids != ids ||
        both[0].result.node_tests != h.node_tests || both[0].result.object_tests != h.object_tests)
      fail("CpuBvhCuller's two-view pass differs from its one-view pass" + at, volumes, f, n, int(ids.size()),
           int(both[0].visible_ids.size()));
    if (both[1].visible_ids != tree.objects || both[1].result.inside != n)
      fail("CpuBvhCuller's everything view lost objects" + at, volumes, f, n, int(n), int(both[1].visible_ids.size()));
  }
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  Bytes in(data, size);
  const std::uint8_t flags = in.u8();
  switch (flags % 3) {
    case 0:
      run<Aabb>(in, flags);
      break;
    case 1:
      run<Sphere>(in, flags);
      break;
    default:
      run<Obb>(in, flags);
      break;
  }
  return 0;
}
