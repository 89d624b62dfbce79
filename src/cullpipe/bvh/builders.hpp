#pragma once
#include <cstdint>
#include <functional>
#include <span>
#include <string>
#include <string_view>
#include <vector>

#include "cullpipe/bvh/bvh.hpp"

/// Every BVH builder, each taking per-object AABBs (centres are the box centres)
/// and returning a plain Tree value that check_tree accepts; plus refit, leaf collapsing,
/// extended metrics and the registry that picks a builder by name.
namespace cullpipe::bvh {

// ---------------------------------------------------------------- top-down (top_down.cpp)

/// How a top-down node chooses the direction to split along. Centroids are projected on it:
/// on x, y, z exactly (the float coordinate), on other directions as a dot product in double.
enum class SplitAxis {
  Longest,           ///< longest axis of the node's centroid box (first of x, y, z on ties)
  DistantCentroids,  ///< direction b - a through two nearly most distant centroids: a farthest from the node's
                     ///< first object's centroid, b farthest from a; the longest axis when a == b or when
                     ///< the centroids project flat on b - a (rounding)
  Pca,               ///< eigenvector of the largest eigenvalue of the centroids' covariance (power iteration
                     ///< in double from each of x, y, z, largest Rayleigh quotient kept); the longest axis when
                     ///< all centroids coincide or project flat
  Best,              ///< each of x, y, z, the best split under the cost (first axis on ties)
};
/// Where along the direction a node splits: objects whose projected centroid p lies below a
/// threshold t go to the first (left) child, the others to the second.
enum class SplitPosition {
  Median,        ///< the lower half: the floor(n / 2) smallest (p, id) pairs (ties broken by id)
  Mean,          ///< t = mean of p
  ExtentMedian,  ///< t = lo + (hi - lo) / 2, the middle of [lo, hi], the range of p (spatial median)
  Binned,        ///< [lo, hi] cut into `bins` equal bins, bin = min(bins - 1, floor((p - lo) * (bins / (hi - lo))))
                 ///< (in float on x, y, z, exactly as build_binned_sah; an extent so small that bins / extent
                 ///< overflows counts as flat);
                 ///< candidates: bins [0, k] left, k = 0 .. bins - 2; the best under the cost (lowest k on ties)
};
/// The cost a split is scored by (lower is better). L and R are the children's boxes, |L| and
/// |R| their object counts. The cost picks among candidates: the bins of Binned, and the three
/// axes of Best; a single candidate (e.g. Longest with Median) is taken whatever its cost.
enum class SplitCost {
  Sah,                ///< surface area heuristic: area(L) * |L| + area(R) * |R| (half areas, in double)
  VolumeSum,          ///< volume(L) + volume(R)
  LargestVolume,      ///< max(volume(L), volume(R))
  Overlap,            ///< volume(L intersect R) (0 when disjoint or touching)
  Separation,         ///< -(gap): L and R projected on the split direction give [l0, l1] and [r0, r1];
                      ///< gap = max(l0, r0) - min(l1, r1), their distance when disjoint, minus the length
                      ///< of their overlap otherwise (larger gap is better)
  SahOverlapGuarded,  ///< SAH, except when the SAH-best candidate's children overlap in more than a quarter of
                      ///< the node's volume: then the SAH-best of the candidates overlapping in at most a
                      ///< quarter, if there is one (a primary heuristic adjusted when a secondary scores badly)
};

/// The order insertion builders insert objects in.
enum class InsertionOrder {
  Shuffled,  ///< a fixed pseudo-random permutation (deterministic): robust to spatially sorted input
  Ids,       ///< id order, as an engine adding objects one by one would
};

/// Leaves of at most this many objects for trees built to be culled (`cullpipe run --cull bvh`,
/// the benchmarks): the GPU hierarchy tests a leaf's objects in chunks of 16 (cull_bvh.comp),
/// so smaller leaves only add node tests and much larger ones add object tests. The fast CPU
/// hierarchy, which tests small nodes' objects as ranges, and the scalar traversal hardly
/// depend on it. BuildOptions keeps 4, the builders' usual quality setting.
inline constexpr std::uint32_t kCullingLeafSize = 16;

/// Options of every builder; each builder reads the fields that concern it.
struct BuildOptions {
  std::uint32_t max_leaf_size = 4;  ///< leaves hold at most this many objects (>= 1)
  std::uint32_t bins = 16;          ///< SplitPosition::Binned bins per direction (clamped to 2..256)
  SplitAxis axis = SplitAxis::Best;
  SplitPosition position = SplitPosition::Binned;
  SplitCost cost = SplitCost::Sah;
  std::uint32_t neighbours = 4;  ///< fast agglomerative: partners searched among this many Morton neighbours each side
  bool rotations = false;        ///< insertion: rebalance by tree rotations along the insertion path
  InsertionOrder insertion_order = InsertionOrder::Shuffled;  ///< insertion builders' order
  /// Threads for the builders that run on several (binned-sah and agglomerative-local, each the
  /// same tree on any number of threads); null: the calling thread alone. Not owned.
  ThreadPool* pool = nullptr;
  /// Top-down builders: leaves where the SAH says, max_leaf_size a cap, an object in a leaf
  /// costing `object_cost` node tests (TopDownOptions::sah_leaves). The bottom-up and insertion
  /// builders always collapse their leaves by the SAH (with an object_cost of 1).
  bool sah_leaves = false;
  float object_cost = 1.0f;
};

/// The generic top-down builder (explicit stack, any depth), nodes emitted root first as
/// build_binned_sah does; centroids are the box centres. A node becomes a leaf exactly when
/// it holds <= max_leaf_size objects (0 counts as 1), so leaves never exceed max_leaf_size.
/// Otherwise each direction of `axis` (one, or x, y, z for Best) that the centroids do not
/// project flat on gives the candidates of `position`; candidates leaving a side empty are
/// dropped; `cost` picks one (earliest on ties) and the objects are partitioned stably. With
/// no candidate left (e.g. all centroids equal) the node is sorted by id and halved. With
/// Best/Binned/Sah it returns build_binned_sah(boxes, {max_leaf_size, bins, sah_leaves}) (the
/// same tree). With sah_leaves, built with leaves of one object, then collapse_leaves.
/// Deterministic; O(n log n) for balanced splits, O(n) extra memory.
Tree build_top_down(std::span<const Aabb> boxes, const BuildOptions& options = {});

// --------------------------------------------------------- bottom-up (agglomerative.cpp)

/// Agglomerative clustering (Walter et al. 2008): one cluster per object; repeatedly merge the
/// pair whose merged box has the least half surface area (double) until one is left; then
/// collapse_leaves to max_leaf_size. Ties (e.g. equal, flat or collinear boxes) are broken by
/// the half perimeter, then by fewer objects in the pair, then by a fixed hash of the cluster
/// ids, then by the ids, a total order, so equal boxes give a balanced tree and the result is
/// deterministic. Brute force: each step scans all pairs, O(n^3). An oracle for small n (<= ~300).
Tree build_agglomerative_brute(std::span<const Aabb> boxes, const BuildOptions& options = {});
/// Priority queue of (cluster, best partner, cost); entries validated when popped (cluster gone
/// -> dropped; partner gone -> re-pair and re-insert). Makes exactly the brute force's merges,
/// ties included, so the trees are equal. O(n^2) time for the partner scans (for n up to a few
/// thousand), O(n) memory.
Tree build_agglomerative_pq(std::span<const Aabb> boxes, const BuildOptions& options = {});
/// Fast variant (PLOC, Meister & Bittner 2018): clusters sorted by the 63-bit Morton code of
/// their box centres (cubic cells over the box of the centres); each pass finds every
/// cluster's nearest neighbour (least merged area) among `neighbours` clusters each side,
/// merges mutual nearest neighbours (the new cluster takes the lower position) and compacts,
/// until one cluster is left. When a pass merges fewer than 1/64 of the clusters (long chains
/// of preference, e.g. nested boxes), unmerged clusters are also merged with their unmerged
/// nearest neighbour, so passes stay geometric. Single-threaded. Its SAH cost is close to
/// build_binned_sah's; the default of 4 neighbours gives lower costs than 16.
Tree build_agglomerative_local(std::span<const Aabb> boxes, const BuildOptions& options = {});

// -------------------------------------------------------------- insertion (insertion.cpp)

/// Insertion builders (Bittner et al. 2015 / Goldsmith & Salmon 1987): objects inserted one by
/// one in options.insertion_order (default: a fixed shuffle), each as a new leaf whose sibling
/// S is the node whose choice adds least SAH cost: area(S u box) + the area each ancestor of S
/// gains. S's place goes to a new inner node
/// (S, leaf) and the ancestors' boxes grow; with options.rotations each node on the way up then
/// takes the best of its four child/grandchild swaps that lowers its child's area (Kopta et al.
/// 2012). The tree is then collapsed to max_leaf_size by collapse_leaves.
/// Order matters: inserted in id order, objects given in spatial order (e.g. the generated
/// city's grid rows) build trees several times binned SAH's cost; the default shuffle avoids
/// that. Time is O(n x depth); sets whose best tree is a chain (boxes nested inside each
/// other, inserted largest first) take quadratic time.
/// Greedy: one path from the root (as Box2D v3): nodes on the path and their leaf children are
/// scored by the full cost and the best kept; the path goes into the inner child with the
/// smaller lower bound on the cost below it, and ends when no bound beats the best.
Tree build_insertion_greedy(std::span<const Aabb> boxes, const BuildOptions& options = {});
/// Branch and bound: the best sibling anywhere in the tree (priority queue by inherited cost,
/// pruned by the lower bound area(new box) + inherited cost).
Tree build_insertion_bnb(std::span<const Aabb> boxes, const BuildOptions& options = {});

// ------------------------------------------------------------------- refit & leaves (refit.cpp)

/// After objects move: recompute every node box from `boxes` (same topology), children before
/// parents: a leaf's box is the union of its objects' boxes, an inner node's the union of its
/// children's. The Tree form accepts any node order (root first); it throws
/// std::invalid_argument when a child index is out of range or a node is reached twice. The
/// FlatTree form walks the nodes in reverse index order (children follow their parent).
void refit(Tree& tree, std::span<const Aabb> boxes);
void refit(FlatTree& tree, std::span<const Aabb> boxes);

/// Merge subtrees into leaves of at most max_leaf_size objects wherever that does not raise
/// the SAH cost (traversal 1, intersection `object_cost` per object): bottom up, a subtree of
/// at most max_leaf_size objects becomes one leaf when area x objects x object_cost <= area +
/// its children's best costs. An object_cost that is not positive and finite throws
/// std::invalid_argument. Boxes are kept. The result is laid out as build_binned_sah lays out its trees (root
/// at 0, the two children of a node adjacent, left subtree first, leaf object ranges in leaf
/// order), so with max_leaf_size 1 (or a tree already collapsed) only the layout can change.
/// Any node order is accepted; throws std::invalid_argument like refit on a malformed tree.
/// Used by the bottom-up and insertion builders.
Tree collapse_leaves(const Tree& tree, std::uint32_t max_leaf_size, float object_cost = 1.0f);

/// The object order along the 63-bit Morton (Z-order) curve of box centres, quantised in
/// cubic cells over the box of the centres, ties by id: a permutation of 0..n-1 that puts
/// objects near each other in space near each other in memory. Used by the PLOC builder;
/// also a cheap spatial sort of a scene.
std::vector<std::uint32_t> morton_order(std::span<const Aabb> boxes);

// ------------------------------------------------------------- metrics (detailed in top_down.cpp)

/// More measures of a tree, in double; all 0 (and leaf_sizes empty) for an empty tree. The
/// volume ratios are 0 when the root box has no volume (a flat scene).
struct DetailedMetrics {
  Metrics basic;                        ///< metrics(tree)
  double total_volume = 0.0;            ///< sum of all node volumes (root included) / root volume
  double overlap_volume = 0.0;          ///< sum over inner nodes of volume(left intersect right) / root volume
  std::vector<std::size_t> leaf_sizes;  ///< leaf_sizes[k] = leaves holding k objects; size = largest leaf + 1
  double mean_leaf_depth = 0.0;         ///< mean depth of the leaves, the root at depth 1 (as Metrics::depth)
  double balance = 0.0;                 ///< depth / (ceil(log2(leaves)) + 1): 1 = as shallow as a tree with that
                                        ///< many leaves can be, larger = deeper
};
DetailedMetrics detailed_metrics(const Tree& tree);

// ---------------------------------------------------------------------- registry (builders.cpp)

struct BuilderInfo {
  std::string_view name;
  std::string_view description;
};
/// The named builders with one-line descriptions, in a fixed order: the top-down ones
/// ("binned-sah" (the default), "median", "mean", "extent-median", "pca-median",
/// "distant-median", "volume", "largest-volume", "overlap", "separation", "sah-guarded"), then
/// "agglomerative-brute", "agglomerative-pq", "agglomerative-local", "insertion-greedy",
/// "insertion-bnb".
std::span<const BuilderInfo> builders();
/// Build by name. Names: those of builders() (a top-down name sets options' axis, position
/// and cost), plus "top-down" or "top-down:axis=A,split=P,cost=C" with A in
/// longest|distant|pca|best, P in median|mean|extent|binned, C in sah|volume|largest|overlap|
/// separation|sah-guarded, in any order, each at most once; a part left out keeps the value in
/// `options`. A trailing "+rotations" on an insertion name sets options.rotations. Names are
/// case-sensitive. Throws std::invalid_argument on an unknown name or a bad parameter, naming
/// the bad part and listing the known builders and the grammar.
Tree build(std::string_view name, std::span<const Aabb> boxes, BuildOptions options = {});

}  // namespace cullpipe::bvh
