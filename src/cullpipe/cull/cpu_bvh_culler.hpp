#pragma once
#include <cstdint>
#include <memory>
#include <optional>
#include <span>
#include <vector>

#include "cullpipe/bvh/bvh.hpp"
#include "cullpipe/core/aligned_vector.hpp"
#include "cullpipe/cull/cpu_culler.hpp"
#include "cullpipe/geom/aabb.hpp"
#include "cullpipe/geom/bv_kind.hpp"
#include "cullpipe/geom/frustum.hpp"
#include "cullpipe/geom/obb.hpp"
#include "cullpipe/geom/sphere.hpp"

namespace cullpipe {
class ThreadPool;
}

namespace cullpipe::fast {

namespace detail {
struct KernelTable;
struct PlaneSet;
}  // namespace detail

/// What a CpuBvhCuller pass fills.
struct CpuBvhCullOptions {
  bool classes = true;       ///< bvh::HierarchicalResult::classes, one per object id
  bool visible_ids = false;  ///< the ids of the visible objects, in the tree's object order
  /// bvh::TraversalOptions::range_objects: straddling nodes of at most this many objects test
  /// their objects as one range instead of descending (see the class comment for why); 0 is
  /// the classic traversal, bvh::cull_hierarchical's default and the GPU culler's. The
  /// classes do not depend on it; the node and object test counts do. Unset:
  /// default_range_objects of the kind of volumes uploaded.
  std::optional<std::uint32_t> range_objects;
  /// The default ranges: 160 objects for boxes and spheres, 96 for OBBs (whose objects cost
  /// 15 columns each to test, against 6 and 4).
  static constexpr std::uint32_t default_range_objects(BvKind kind) { return kind == BvKind::Obb ? 96 : 160; }
  /// range_objects, or the default for volumes of `kind`.
  std::uint32_t range_objects_for(BvKind kind) const { return range_objects.value_or(default_range_objects(kind)); }
};

/// One view's result of a multi-view CpuBvhCuller pass.
struct CpuBvhViewResult {
  bvh::HierarchicalResult result;          ///< classes (with CpuBvhCullOptions::classes), counts
  std::vector<std::uint32_t> visible_ids;  ///< with CpuBvhCullOptions::visible_ids, in the tree's object order
};

/// Hierarchical culling on the CPU with every core: the traversal of bvh::cull_hierarchical
/// (plane masking, INSIDE subtrees accepted as ranges, the objects of straddling leaves, and of
/// straddling nodes of at most CpuBvhCullOptions::range_objects objects, tested against the
/// planes their node straddles), split into subtrees that the threads take one at a time. The
/// result equals bvh::cull_hierarchical's with the same bvh::TraversalOptions::range_objects
/// exactly: every class, the node and object test counts, the visible and inside counts. (The
/// classes do not depend on range_objects; the test counts do.)
///
/// The top of the tree is walked breadth first on the calling thread until there are enough
/// subtrees for the threads (one per 131,072 objects, but 4 to 16 per thread, fewer for small
/// trees: at most one per 8192 objects);
/// each subtree is then tested by one thread with the SIMD walk kernels of the culler's
/// instruction set (detail::WalkKernel): W nodes at a time, one per lane, tested plane by
/// plane, each lane doing the scalar test's float operations in its order on the planes of its
/// own mask; then the object ranges it found, up to 64 objects at a time tested plane by
/// plane, W at a time, read straight from the volumes in tree order, in blocks of 16 objects
/// with a vector per column (a range is one run of cache lines there). The tests are the scalar traversal's, in another
/// order; the visible objects are marked in a bitmap and listed in tree order. INSIDE ranges are split into chunks so
/// one large accepted subtree still uses every core. Objects are written by id, and a subtree's objects are its own, so
/// no two threads write the same class.
///
/// Why object ranges: a node test costs several times what an object of a range does (records
/// gathered into lanes, work lists kept and prefetches, against contiguous loads), so near the
/// leaves a node's test saves fewer object tests than it costs. Ranges are tested in groups of
/// up to 64 objects, plane by plane, a bit per object. OBBs read more columns per object than
/// boxes and spheres, so their best range is shorter: the defaults are 160 objects for boxes
/// and spheres and 96 for OBBs (CpuBvhCullOptions::default_range_objects).
///
/// The objects may be AABBs, OBBs or spheres (bvh::cull_hierarchical's three forms: a tree
/// over OBBs or spheres is built over bvh::enclosing_boxes and its nodes are tested with a
/// margin, so every class still equals flat culling's: docs/numerics.md, BVH node margins).
class CpuBvhCuller {
 public:
  /// threads = 0: every core. isa: the kernels (default best_isa()); one the machine cannot
  /// run throws std::invalid_argument.
  explicit CpuBvhCuller(unsigned threads = 0, std::optional<Isa> isa = std::nullopt);
  ~CpuBvhCuller();
  CpuBvhCuller(const CpuBvhCuller&) = delete;
  CpuBvhCuller& operator=(const CpuBvhCuller&) = delete;

  /// Copies the tree and the volumes (in tree order, in blocks of 16 with a vector per
  /// column, so a node's volumes are one run of memory). Throws std::invalid_argument unless the tree's object list is
  /// a permutation of the ids of the volumes and every leaf's box encloses its volumes (their enclosing boxes):
  /// bvh::check_flat_tree, with its message; a refused upload leaves the last one. The threads
  /// gather and check the volumes together, into a second set of blocks that replaces the
  /// first when all have passed (the two take turns, so the blocks take twice their size:
  /// 2 x 24 bytes per box, 2 x 60 per OBB, 2 x 16 per sphere).
  void upload(const bvh::FlatTree& tree, std::span<const Aabb> boxes);
  void upload(const bvh::FlatTree& tree, std::span<const Obb> obbs);
  void upload(const bvh::FlatTree& tree, std::span<const Sphere> spheres);

  /// The kind of the volumes uploaded last.
  BvKind kind() const { return kind_; }

  /// Over OBBs or spheres the frustum needs unit plane normals (bvh::require_unit_normals;
  /// Frustum's factories make them), else std::invalid_argument. With default options (ranges
  /// of CpuBvhCullOptions::default_range_objects(kind())): the classes equal
  /// bvh::cull_hierarchical's with its defaults, the test counts those of
  /// bvh::cull_hierarchical(tree, volumes, frustum, {CpuBvhCullOptions::default_range_objects(kind())}).
  bvh::HierarchicalResult cull(const Frustum& frustum);
  /// The same into `result`, reusing its storage.
  void cull(const Frustum& frustum, bvh::HierarchicalResult& result);
  /// As `options` asks: without classes `result.classes` is left empty (its counts and test
  /// counts are always filled); with visible ids they go to `visible_ids` in the tree's object
  /// order (an INSIDE subtree is one copied range). An engine that wants the visible list
  /// skips the per-id class writes, which are scattered when the ids are not in tree order.
  void cull(const Frustum& frustum, const CpuBvhCullOptions& options, bvh::HierarchicalResult& result,
            std::vector<std::uint32_t>& visible_ids);
  /// Several views in one pass (a camera and its shadow cascades, say): one result per view,
  /// each as a pass of its own would give; the threads share the views' subtrees, so the pool
  /// wakes once and small views keep every core busy. `results` is resized and reused.
  void cull(std::span<const Frustum> views, const CpuBvhCullOptions& options, std::vector<CpuBvhViewResult>& results);

  unsigned threads() const;
  Isa isa() const { return isa_; }

 private:
  template <class Volume>
  void upload_impl(const bvh::FlatTree& tree, std::span<const Volume> volumes);
  struct Output {
    bvh::HierarchicalResult* result;
    std::vector<std::uint32_t>* visible_ids;
  };
  void cull_views(std::span<const Frustum> views, const CpuBvhCullOptions& options, std::span<const Output> outs);
  struct Task;
  struct Tally;

  std::unique_ptr<ThreadPool> pool_;
  Isa isa_;
  std::unique_ptr<detail::KernelTable> kernels_;
  bvh::FlatTree tree_;
  BvKind kind_ = BvKind::Aabb;
  // The tree as the walk kernels read it (detail::WalkTree): nodes in sibling pairs (64-byte
  // records on cache lines), each flat node's slot there, and the volumes in tree order in
  // blocks of detail::kWalkBlock (a node's range is one run of lines).
  cullpipe::detail::CacheLineVector<float> walk_nodes_;
  std::vector<std::uint32_t> slot_of_;
  cullpipe::detail::CacheLineVector<float> walk_blocks_;
  cullpipe::detail::CacheLineVector<float> spare_blocks_;  // the next upload's blocks (then the last one's)
  // Per-pass working storage, kept so passes reuse it.
  std::vector<Task> tasks_;
  std::vector<Task> frontier_;            // the top of the tree, breadth first; then the tasks' sort
  std::vector<std::uint32_t> order_;      // the tasks in the order the threads take them
  std::vector<std::uint64_t> sort_keys_;  // per task, the key of the sort at hand
  std::vector<Tally> tallies_;
  std::vector<std::uint64_t> marks_;              // the subtree tasks' visible objects, a bit each; zero between passes
  bool marks_clean_ = true;                       // false from a pass's walk until its listing has cleared marks_
  std::vector<std::vector<std::uint32_t>> work_;  // per pool thread: a walk's work lists
  std::vector<std::size_t> offsets_;
  std::vector<detail::PlaneSet> planes_;  // per view
  std::vector<Output> outputs_;
};

}  // namespace cullpipe::fast
