#pragma once
#include <cstdint>
#include <memory>
#include <span>
#include <string>
#include <type_traits>
#include <vector>

#include "cullpipe/core/prefetch.hpp"
#include "cullpipe/geom/aabb.hpp"
#include "cullpipe/geom/classification.hpp"
#include "cullpipe/geom/frustum.hpp"
#include "cullpipe/geom/obb.hpp"
#include "cullpipe/geom/sphere.hpp"

/// Bounding volume hierarchies over object AABBs: the binned-SAH top-down builder, quality
/// metrics, validation, the depth-first flattening with skip indices, and the scalar
/// hierarchical traversal that is the reference for GPU traversal.
namespace cullpipe {
class ThreadPool;
}

namespace cullpipe::bvh {

inline constexpr std::uint32_t kNone = 0xffffffffu;

/// One node of a binary tree. A leaf holds objects [first, first + count) of Tree::objects;
/// an inner node has two children.
struct Node {
  Aabb box;
  std::uint32_t left = kNone;
  std::uint32_t right = kNone;
  std::uint32_t first = 0;
  std::uint32_t count = 0;
  bool leaf() const { return left == kNone; }
  bool operator==(const Node&) const = default;
};

/// A plain tree value: nodes (root first) and the object order its leaves refer to.
struct Tree {
  std::vector<Node> nodes;
  std::vector<std::uint32_t> objects;  ///< object ids; each leaf owns a contiguous range
  bool operator==(const Tree&) const = default;
};

struct TopDownOptions {
  std::uint32_t max_leaf_size = 4;  ///< a node with at most this many objects becomes a leaf
  std::uint32_t bins = 16;          ///< SAH candidates per axis (centroid bins)
  /// Leaves where the SAH says, max_leaf_size a cap: the tree is built with leaves of one
  /// object, then every subtree of at most max_leaf_size objects that is no cheaper than one
  /// leaf (a node test costing 1, each object in a leaf `object_cost`) becomes one
  /// (collapse_leaves, bottom up, so each leaf decision is the best for its subtree). With
  /// object_cost 1 (the SAH metric's) few leaves grow past one object; below 1 leaves grow, as
  /// for a pass that tests a leaf's objects together (the GPU hierarchy tests 16 at once).
  bool sah_leaves = false;
  float object_cost = 1.0f;
};

/// Top-down build: split along each axis at the best of `bins` evenly spaced centroid bins by
/// the surface area heuristic (cost = traversal 1 + sum over children of area ratio x objects);
/// a node becomes a leaf exactly when it holds <= max_leaf_size objects (with sah_leaves, see
/// there). Objects with equal
/// centroids are split by median. O(n log n). Boxes must be valid (min <= max).
///
/// With a `pool` of several threads, the build runs on all of them and gives the same tree,
/// node for node and bit for bit, as on one: the nodes above a cut fixed by the object count
/// (n / 16, at least 4,096 objects) share every pass over their objects among the threads,
/// and the subtrees below it are built as tasks. On 2 threads, 10^6 objects build 1.5x
/// faster (leaves of 4) and 1.7x (leaves of 1) through a kept BinnedSahBuilder; the passes
/// above the cut run at the speed of memory (bench/NOTES.md).
Tree build_binned_sah(std::span<const Aabb> boxes, const TopDownOptions& options = {}, ThreadPool* pool = nullptr);

namespace detail {
struct BinnedScratch;
}

/// build_binned_sah for an engine that rebuilds every frame: the same tree, but the builder
/// keeps its per-object working memory (68 bytes per object; 148 once it has built on several
/// threads with leaves of more than one object) and `tree` keeps its storage between builds,
/// so a rebuild of no more objects than before faults in no fresh pages (a noticeable share of
/// a first build's time). Uses AVX2 where the CPU has it, like build_binned_sah. One build at a
/// time: a builder is not shared between threads that build at once (a build given a pool
/// uses the pool's threads itself).
class BinnedSahBuilder {
 public:
  BinnedSahBuilder();
  ~BinnedSahBuilder();
  BinnedSahBuilder(BinnedSahBuilder&&) noexcept;
  BinnedSahBuilder& operator=(BinnedSahBuilder&&) noexcept;
  /// Replaces `tree` with build_binned_sah(boxes, options, pool).
  void build(std::span<const Aabb> boxes, const TopDownOptions& options, Tree& tree, ThreadPool* pool = nullptr);
  /// Frees the working memory (the next build allocates it again).
  void release();

 private:
  std::unique_ptr<detail::BinnedScratch> scratch_;
};

/// Quality of a tree.
struct Metrics {
  double sah_cost = 0.0;  ///< sum over inner nodes of area/root area + over leaves of area/root area x count
  std::size_t nodes = 0, leaves = 0, depth = 0;
  std::size_t max_leaf_size = 0;
};
Metrics metrics(const Tree& tree);

/// "" when the tree is valid for `boxes`: every object in exactly one leaf, every node box
/// encloses its children's boxes and its objects' boxes; else what is wrong and where.
std::string check_tree(const Tree& tree, std::span<const Aabb> boxes);

/// The tree in depth-first order: a node's first child follows it; `skip` is the index of the
/// node after its subtree; every subtree's objects are the contiguous range [first, first +
/// count) of `objects` (so an INSIDE subtree is accepted as one range).
struct FlatNode {
  Aabb box;
  std::uint32_t skip = 0;
  std::uint32_t first = 0;
  std::uint32_t count = 0;
  bool leaf = false;
  bool operator==(const FlatNode&) const = default;
};
struct FlatTree {
  std::vector<FlatNode> nodes;
  std::vector<std::uint32_t> objects;
};
FlatTree flatten(const Tree& tree);

/// Why `tree` is not a flattened tree over `volumes` as flatten() lays one out, or an empty
/// string: the object list is a permutation of the volumes' ids; every volume and box is
/// valid (invalid_reason); the root covers every object and node; an inner node has exactly
/// two children (the next node, and the node at that one's skip) whose object ranges split
/// its own; a leaf's skip is the next node; every box encloses its children and its objects'
/// enclosing_box(). `depth`, when given, receives each node's depth (root 1). The cullers
/// check this on upload: the traversals index by these links and ranges, and a box that does
/// not enclose could drop a visible object. O(nodes + objects).
std::string check_flat_tree(const FlatTree& tree, std::span<const Aabb> volumes,
                            std::vector<std::uint32_t>* depth = nullptr);
std::string check_flat_tree(const FlatTree& tree, std::span<const Obb> volumes,
                            std::vector<std::uint32_t>* depth = nullptr);
std::string check_flat_tree(const FlatTree& tree, std::span<const Sphere> volumes,
                            std::vector<std::uint32_t>* depth = nullptr);
/// check_flat_tree's checks of the tree alone, over `object_count` objects: all but the
/// volumes' validity and the leaves' enclosure of them. For a caller that gathers the volumes
/// in tree order anyway and checks those two on its copy (volume_in_leaf), sparing a second
/// gather; on a failure there, check_flat_tree says what is wrong.
std::string check_flat_structure(const FlatTree& tree, std::size_t object_count,
                                 std::vector<std::uint32_t>* depth = nullptr);
/// The check check_flat_tree makes of each object in a leaf with box `leaf`: the volume is
/// valid (is_valid) and its enclosing_box() inside `leaf` (leaf_encloses, which assumes a
/// valid volume).
bool volume_in_leaf(const Aabb& leaf, const Aabb& volume);
bool volume_in_leaf(const Aabb& leaf, const Obb& volume);
bool volume_in_leaf(const Aabb& leaf, const Sphere& volume);
bool leaf_encloses(const Aabb& leaf, const Aabb& volume);
bool leaf_encloses(const Aabb& leaf, const Obb& volume);
bool leaf_encloses(const Aabb& leaf, const Sphere& volume);
/// The volumes of the leaves among nodes [first_node, end_node) of a tree that passed
/// check_flat_structure, in tree order (a run of nodes holds a run of the object order):
/// visit(slot, volume) for each that passes volume_in_leaf, gathered from `volumes` by the
/// tree's ids with prefetches ahead; false at the first that does not. Runs of nodes split a
/// tree's volumes among threads, each gathered and checked once. kKnownValid: every volume
/// has passed is_valid already, so only leaf_encloses is checked (no volume's validity is
/// checked twice).
template <bool kKnownValid = false, class Volume, class Visit>
bool visit_leaf_volumes(const FlatTree& tree, std::span<const Volume> volumes, std::size_t first_node,
                        std::size_t end_node, Visit&& visit) {
  const std::size_t n = tree.objects.size();
  for (std::size_t i = first_node; i < end_node; ++i) {
    const FlatNode& node = tree.nodes[i];
    if (!node.leaf) continue;
    for (std::size_t k = node.first, last = std::size_t(node.first) + node.count; k < last; ++k) {
      if (k + kGatherAhead < n) prefetch_object(&volumes[tree.objects[k + kGatherAhead]]);
      const Volume& v = volumes[tree.objects[k]];
      if (!(kKnownValid ? leaf_encloses(node.box, v) : volume_in_leaf(node.box, v))) return false;
      visit(k, v);
    }
  }
  return true;
}

/// The p/n-vertex test of `box` against the planes of `frustum` in `mask` (bit k = plane k):
/// OUTSIDE at the first such plane the box is behind, else INTERSECTING when it straddles any
/// (their bits go to `straddled`: a child must still test those), else INSIDE. The node test
/// of every hierarchical traversal (CPU, fast CPU; the shader mirrors it).
Classification classify_masked(const Aabb& box, const Frustum& frustum, std::uint32_t mask, std::uint32_t& straddled);

/// Hierarchies over OBBs or spheres: the tree is built over each volume's enclosing box and
/// its nodes are tested with a margin, so that a node is OUTSIDE (or INSIDE a plane) only when
/// every volume in it is, as the volume's own float test computes it (boxes need no margin:
/// float sums and products are monotone). The margin is kBvhMarginScale x (sum over axes of the
/// node's largest |coordinate| + |d|) + kBvhMarginFloor, far above the rounding of both tests
/// for unit normals; nodes within it of a plane are INTERSECTING and their objects get their
/// own test, so every object's class equals flat culling's. Proof: docs/numerics.md, BVH node
/// margins.
inline constexpr float kBvhMarginScale = 0x1p-16f;
/// Added to every margin so that rounding of subnormal numbers is covered too.
inline constexpr float kBvhMarginFloor = 0x1p-120f;
/// Beyond this reach + |d| a plane decides nothing at a node (distances could overflow).
inline constexpr float kBvhMarginLimit = 0x1p120f;
/// The error bound behind the margin takes unit plane normals (as Frustum::from_planes and
/// from_view_proj make them, to 1e-6): hierarchical culling of OBBs and spheres throws
/// std::invalid_argument for a frustum whose normals are further than this from length 1.
inline constexpr double kBvhUnitNormalTolerance = 4e-6;
/// Throws std::invalid_argument unless every active plane of `frustum` has a unit normal
/// (within kBvhUnitNormalTolerance); `who` names the caller.
void require_unit_normals(const Frustum& frustum, const char* who);

/// The box a hierarchy stores for a volume: its axis-aligned bounds computed in double and
/// rounded outward (one float step beyond, after the double sums are rounded up), so it
/// contains the volume (docs/numerics.md, BVH node margins).
Aabb enclosing_box(const Obb& box);
Aabb enclosing_box(const Sphere& sphere);
inline Aabb enclosing_box(const Aabb& box) { return box; }
template <class Volume>
std::vector<Aabb> enclosing_boxes(std::span<const Volume> volumes) {
  std::vector<Aabb> boxes(volumes.size());
  for (std::size_t i = 0; i < volumes.size(); ++i) boxes[i] = enclosing_box(volumes[i]);
  return boxes;
}

/// classify_masked with the margin above: the node test of hierarchies over OBBs and spheres.
/// OUTSIDE when the p-vertex is more than the margin behind a plane in `mask`; a plane goes to
/// `straddled` unless the n-vertex is at least the margin in front. Past kBvhMarginLimit (or
/// with NaN) a plane decides nothing: it is straddled.
Classification classify_masked_margin(const Aabb& box, const Frustum& frustum, std::uint32_t mask,
                                      std::uint32_t& straddled);

/// The object tests of hierarchical culling, on the planes in `mask` only; the same float
/// operations as the reference's flat tests (cull/reference.hpp).
Classification classify_object(const Aabb& box, const Frustum& frustum, std::uint32_t mask);
Classification classify_object(const Obb& box, const Frustum& frustum, std::uint32_t mask);
Classification classify_object(const Sphere& sphere, const Frustum& frustum, std::uint32_t mask);

/// The node test of a hierarchy over `Volume`.
template <class Volume>
Classification classify_node(const Aabb& box, const Frustum& frustum, std::uint32_t mask, std::uint32_t& straddled) {
  if constexpr (std::is_same_v<Volume, Aabb>)
    return classify_masked(box, frustum, mask, straddled);
  else
    return classify_masked_margin(box, frustum, mask, straddled);
}

/// The scalar hierarchical cull (the reference for GPU traversal): each node box is tested
/// with the p/n-vertex test against the planes its parent straddles (plane masking, Assarsson
/// & Moller 2000); OUTSIDE drops the subtree, INSIDE accepts its object range without tests,
/// INTERSECTING descends; leaf objects are tested against the remaining planes. Because float
/// sums and products are monotone, an object inside its node's box gets the same class as
/// flat culling gives it.
struct HierarchicalResult {
  std::vector<Classification> classes;  ///< per object id
  std::size_t node_tests = 0;
  std::size_t object_tests = 0;
  std::size_t visible = 0, inside = 0;
  /// occlusion::cull_hierarchical: objects the frustum keeps and the pyramid hides, and the
  /// occlusion tests made (of nodes and objects)
  std::size_t occluded = 0, occlusion_tests = 0;
  bool operator==(const HierarchicalResult&) const = default;
};
/// How cull_hierarchical walks a tree.
struct TraversalOptions {
  /// When nonzero, a straddling node with at most this many objects tests its objects (each
  /// against the planes the node straddles) instead of descending: fewer node tests, more
  /// object tests, and each object range is contiguous (fast::CpuBvhCuller tests ranges as
  /// streams). 0: only leaves test their objects, and every straddling inner node descends,
  /// an empty one too (the classic traversal; the GPU culler's).
  std::uint32_t range_objects = 0;
  /// Whether a straddling `node` tests its objects rather than descending: a leaf, or with
  /// range_objects a node of at most that many objects.
  bool tests_objects_of(const FlatNode& node) const {
    return node.leaf || (range_objects != 0 && node.count <= range_objects);
  }
  bool operator==(const TraversalOptions&) const = default;
};

HierarchicalResult cull_hierarchical(const FlatTree& tree, std::span<const Aabb> boxes, const Frustum& frustum,
                                     const TraversalOptions& options = {});
/// The same over OBBs or spheres: the tree's node boxes must enclose enclosing_box() of each of
/// its volumes (build the tree over enclosing_boxes()). Every object's class equals flat
/// culling's (see kBvhMarginScale).
HierarchicalResult cull_hierarchical(const FlatTree& tree, std::span<const Obb> volumes, const Frustum& frustum,
                                     const TraversalOptions& options = {});
HierarchicalResult cull_hierarchical(const FlatTree& tree, std::span<const Sphere> volumes, const Frustum& frustum,
                                     const TraversalOptions& options = {});

}  // namespace cullpipe::bvh
