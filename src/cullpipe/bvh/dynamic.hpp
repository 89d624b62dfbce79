#pragma once
// A hierarchy over objects that move, come and go: refitted each frame while its quality holds,
// edited in place as objects are inserted and removed, rebuilt on a thread of its own once it
// has degraded, and swapped in when that build is done, so no frame waits for a build.
#include <cstddef>
#include <future>
#include <memory>
#include <span>
#include <string>
#include <vector>

#include "cullpipe/bvh/builders.hpp"
#include "cullpipe/geom/aabb.hpp"

namespace cullpipe::bvh {

struct DynamicTreeOptions {
  /// Rebuild once the tree's SAH cost (Metrics::sah_cost) exceeds this many times its cost
  /// right after its build (DynamicTree::quality): the cost of a fresh build over the boxes as
  /// they are now is not known without making one, and a fresh tree's cost is what a rebuild
  /// gets back to.
  double rebuild_ratio = 1.3;
  std::string builder = "binned-sah";  ///< a name bvh::build takes
  BuildOptions build;                  ///< its options
};

/// What DynamicTree::update did.
enum class TreeStep {
  Refitted,        ///< the tree was refitted; its quality holds, or a rebuild is under way
  RebuildStarted,  ///< refitted, and a rebuild over a copy of the boxes started on its thread
  Swapped,         ///< a finished rebuild replaced the tree, refitted to the boxes given now
  Rebuilt,         ///< the object count changed: the tree was rebuilt before returning
};

/// A hierarchy over objects that come, go and move. Object ids are dense, as InstanceSet's
/// slots: insert() appends id object_count(), remove(id) moves the last id into id's place.
///
/// tree() is a plain Tree (root at node 0, every node reachable from it, check_tree, metrics,
/// flatten and refit take it as any other) with one allowance: remove() can leave entries of
/// tree().objects that no leaf owns, set to kNone, until insert() reuses them or update()
/// compacts the list (so right after update() there are none). Nothing that walks the tree from
/// its root reads them.
class DynamicTree {
 public:
  /// Builds the first tree now. Throws as bvh::build does (a bad builder name or option).
  explicit DynamicTree(std::span<const Aabb> boxes, DynamicTreeOptions options = {});
  /// Waits for a rebuild under way.
  ~DynamicTree();
  DynamicTree(const DynamicTree&) = delete;
  DynamicTree& operator=(const DynamicTree&) = delete;

  /// The frame's boxes (by object id, as before): a finished rebuild is swapped in, with the
  /// insertions and removals made since it started replayed on it (dropping it instead would
  /// starve the rebuilds of an engine that edits every frame); then the tree is refitted to
  /// them; if its quality has fallen past the ratio and no rebuild is under way, one starts
  /// over a copy of these boxes, on one thread of its own (BuildOptions::pool is used only for
  /// the builds made here, before returning). A count other than object_count() rebuilds now
  /// (a rebuild under way is waited for and dropped). A rebuild that threw is dropped, and a new
  /// one starts at once if the tree still needs it; its error is kept (last_error()).
  TreeStep update(std::span<const Aabb> boxes);

  /// Adds an object of box `box` as id object_count(): a leaf of its own (whatever
  /// BuildOptions::max_leaf_size; a rebuild collapses such leaves) beside the node whose choice
  /// adds least SAH cost (the branch and bound of build_insertion_bnb), its ancestors' boxes
  /// grown. For boxes small against the scene the search visits about twice the tree's depth
  /// in nodes (3-5 microseconds each into 10^6 objects, bench/NOTES.md); quality() counts the
  /// object from the next update(). Throws std::invalid_argument when `box` is not valid
  /// (invalid_reason: NaN, infinite, min > max), the tree unchanged.
  void insert(const Aabb& box);
  /// insert() of each box in turn (ids object_count() on). Every box is checked first: on an
  /// invalid one none is inserted.
  void insert(std::span<const Aabb> boxes);
  /// Removes object `id`; then the object with the last id (object_count() - 1) takes id `id`,
  /// as InstanceSet::remove moves the last slot. A leaf left empty goes, its sibling taking its
  /// parent's place, and the ancestors' boxes shrink to their children's; a leaf that keeps
  /// other objects keeps its box, which still encloses them, until update() refits it.
  /// O(depth + leaf size), the list's compaction aside (amortised O(1)). Throws
  /// std::invalid_argument when id >= object_count(), the tree unchanged.
  void remove(std::uint32_t id);
  /// remove() of each id in turn, each naming the objects as numbered after the removals before
  /// it. Every id is checked first (ids[k] < object_count() - k): on a bad one none is removed.
  void remove(std::span<const std::uint32_t> ids);

  const Tree& tree() const { return tree_; }
  std::size_t object_count() const { return links_.leaf_of.size(); }
  /// The tree's SAH cost over its cost right after its build (1 for a fresh tree), as of the
  /// last update(). Objects inserted since count as they were placed, and by their number (a
  /// fresh tree over more objects costs more too); with fewer objects than at the build, the
  /// build's cost is scaled down by objects now / objects then. Both err towards an early
  /// rebuild, which costs a thread, not a frame: on random, clustered and city sets of 10^5
  /// the quality was never below the tree's cost over a fresh build's, and growing a set by
  /// 1.3-2x or shrinking it to about 0.6x crossed the default ratio without any degradation.
  double quality() const { return quality_; }
  bool rebuilding() const { return pending_.valid(); }
  std::size_t rebuilds() const { return rebuilds_; }  ///< swapped in or made by a count change
  const std::string& last_error() const { return last_error_; }

 private:
  // What insert and remove need beside the tree: per node its parent (kNone at the root) and
  // the number of objects below it (the search's tie-break towards the smaller subtree); per
  // object id its leaf and its position in tree.objects.
  struct Links {
    std::vector<std::uint32_t> parent, below, leaf_of, position;
  };
  struct Built {
    Tree tree;
    Links links;
    double cost = 0.0;  // SAH cost right after the build
    std::size_t objects = 0;
  };
  // An insertion (removed == kNone) or a removal made while a rebuild is under way.
  struct Edit {
    Aabb box;
    std::uint32_t removed = kNone;
  };
  struct Scratch;

  static Built make(const std::vector<Aabb>& boxes, const DynamicTreeOptions& options);
  void take(Built&& built);
  void insert_one(const Aabb& box);
  void remove_one(std::uint32_t id);
  std::uint32_t add_node(const Node& node, std::uint32_t parent, std::uint32_t below);
  void place_node(std::uint32_t from, std::uint32_t to);
  void free_node(std::uint32_t i);
  void free_position(std::uint32_t k);
  void compact_objects();

  DynamicTreeOptions options_;
  Tree tree_;
  Links links_;
  std::vector<std::uint32_t> free_positions_;  // entries of tree_.objects no leaf owns
  std::unique_ptr<Scratch> scratch_;
  double quality_ = 1.0, built_cost_ = 1.0;
  std::size_t built_objects_ = 0, rebuilds_ = 0;
  std::future<Built> pending_;
  std::vector<Edit> edits_;  // since the rebuild under way started, replayed on its tree
  std::string last_error_;
};

}  // namespace cullpipe::bvh
