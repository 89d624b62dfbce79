#pragma once
#include <cstdint>
#include <memory>
#include <span>
#include <vector>

#include "bvh/bvh.hpp"
#include "geom/aabb.hpp"
#include "geom/frustum.hpp"

namespace cullpipe::fast {

class ThreadPool;

/// Hierarchical culling on the CPU with every core: the traversal of bvh::cull_hierarchical
/// (plane masking, INSIDE subtrees accepted as ranges, leaf objects tested against the planes
/// their leaf straddles), split into subtrees that the threads take one at a time. The result
/// equals bvh::cull_hierarchical's exactly: every class, the node and object test counts, the
/// visible and inside counts.
///
/// The top of the tree is walked breadth first on the calling thread until there are enough
/// subtrees for the threads (about 16 per thread); each subtree is then walked depth first by
/// one thread. INSIDE ranges are split into chunks so one large accepted subtree still uses
/// every core. Objects are written by id, and a subtree's objects are its own, so no two
/// threads write the same class.
class CpuBvhCuller {
 public:
  /// threads = 0: every core.
  explicit CpuBvhCuller(unsigned threads = 0);
  ~CpuBvhCuller();
  CpuBvhCuller(const CpuBvhCuller&) = delete;
  CpuBvhCuller& operator=(const CpuBvhCuller&) = delete;

  /// Copies the tree and the boxes (in tree order, so a leaf's boxes are adjacent in memory).
  /// Throws std::invalid_argument unless the tree's object list is a permutation of the ids
  /// of `boxes`.
  void upload(const bvh::FlatTree& tree, std::span<const Aabb> boxes);

  bvh::HierarchicalResult cull(const Frustum& frustum);
  /// The same into `result`, reusing its storage.
  void cull(const Frustum& frustum, bvh::HierarchicalResult& result);

  unsigned threads() const;

 private:
  std::unique_ptr<ThreadPool> pool_;
  bvh::FlatTree tree_;
  std::vector<Aabb> boxes_in_tree_order_;
};

}  // namespace cullpipe::fast
