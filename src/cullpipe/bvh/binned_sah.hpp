#pragma once
// Internal to src/cullpipe/bvh (and its tests): build_binned_sah's variants, one per instruction set,
// all building the same tree, and the working memory BinnedSahBuilder keeps between builds.
#include <bit>
#include <cstddef>
#include <cstdint>
#include <memory>
#include <span>
#include <utility>
#include <vector>

#include "cullpipe/bvh/bvh.hpp"

namespace cullpipe {
class ThreadPool;
}

namespace cullpipe::bvh::detail {

/// A box as eight floats: its minimum corner (x, y, z, +inf) and its maximum corner negated
/// (-x, -y, -z, w). Growing a box by another is then one minimum over all eight lanes (one AVX
/// instruction), and -(-hi) gives hi back exactly. An object's record keeps its id's bits in w,
/// which is only ever read from records, never from the result of arithmetic (the bins' w lanes
/// take minimums of id bits and are never read): a host that flushes denormals builds the same
/// tree. 32 bytes.
struct alignas(32) Box8 {
  float v[8];
  std::uint32_t id() const { return std::bit_cast<std::uint32_t>(v[7]); }
  Aabb box() const { return {{v[0], v[1], v[2]}, {-v[4], -v[5], -v[6]}}; }
};

/// collapse_leaves' working memory, kept by a builder between builds.
struct CollapseScratch {
  std::vector<std::uint32_t> order, stack, count;
  std::vector<char> seen, as_leaf;
  std::vector<double> cost;
  std::vector<std::pair<std::uint32_t, std::uint32_t>> tasks;  // (node in the input, node in the output)
};
/// collapse_leaves(tree, max_leaf_size, object_cost) into `out` (its storage kept), with
/// `scratch`'s memory.
void collapse_leaves(const Tree& tree, std::uint32_t max_leaf_size, float object_cost, Tree& out,
                     CollapseScratch& scratch);

/// The builder's per-object working memory: two buffers of records (a split moves a node's
/// records from one to the other) and each record's three bin indices; for a build on several
/// threads, room for its subtrees' nodes (2 per object).
struct BinnedScratch {
  std::size_t capacity = 0;  ///< objects the buffers hold
  std::unique_ptr<Box8[]> buffer[2];
  std::unique_ptr<std::uint32_t[]> bin_of;
  std::size_t node_capacity = 0;  ///< objects `nodes` has room for
  struct RawDelete {
    void operator()(Node* p) const { ::operator delete[](p); }
  };
  std::unique_ptr<Node[], RawDelete> nodes;  ///< raw memory (operator new[]): see reserve_nodes
  /// SAH leaves (TopDownOptions::sah_leaves): the tree with leaves of one object, and the
  /// collapse's memory.
  Tree ones;
  CollapseScratch collapse;
  /// Room for n objects (kept when there already is; left uninitialised).
  void reserve(std::size_t n);
  /// Room for the nodes of n objects' subtrees (kept when there already is).
  void reserve_nodes(std::size_t n);
};

namespace baseline {
/// SSE2 on x86-64 (every x86-64 CPU has it), plain C++ elsewhere.
void build(std::span<const Aabb> boxes, const TopDownOptions& options, BinnedScratch& scratch, Tree& tree,
           ThreadPool* pool = nullptr);
}  // namespace baseline

namespace avx2 {
/// AVX2 (a target pragma on its functions alone); call only when binned_sah_avx2_available().
void build(std::span<const Aabb> boxes, const TopDownOptions& options, BinnedScratch& scratch, Tree& tree,
           ThreadPool* pool = nullptr);
}  // namespace avx2

/// True when the AVX2 variant is built in and this CPU runs it.
bool binned_sah_avx2_available();

}  // namespace cullpipe::bvh::detail
