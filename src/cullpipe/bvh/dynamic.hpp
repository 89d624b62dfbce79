#pragma once
// A hierarchy over objects that move: refitted each frame while its quality holds, rebuilt on a
// thread of its own once it has degraded, and swapped in when that build is done, so no frame
// waits for a build.
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
  /// right after its build: the cost of a fresh build over the boxes as they are now is not
  /// known without making one, and a fresh tree's cost is what a rebuild gets back to.
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

class DynamicTree {
 public:
  /// Builds the first tree now. Throws as bvh::build does (a bad builder name or option).
  explicit DynamicTree(std::span<const Aabb> boxes, DynamicTreeOptions options = {});
  /// Waits for a rebuild under way.
  ~DynamicTree();
  DynamicTree(const DynamicTree&) = delete;
  DynamicTree& operator=(const DynamicTree&) = delete;

  /// The frame's boxes (by object id, as before): a finished rebuild is swapped in, then the
  /// tree is refitted to them; if its quality has fallen past the ratio and no rebuild is under
  /// way, one starts over a copy of these boxes, on one thread of its own (BuildOptions::pool is
  /// used only for the builds made here, before returning). A different object count rebuilds
  /// now (a rebuild under way is waited for and dropped). A rebuild that threw is dropped, and a
  /// new one starts at once if the tree still needs it; its error is kept (last_error()).
  TreeStep update(std::span<const Aabb> boxes);

  const Tree& tree() const { return tree_; }
  /// The tree's SAH cost over its cost right after its build (1 for a fresh tree).
  double quality() const { return cost_ / built_cost_; }
  bool rebuilding() const { return pending_.valid(); }
  std::size_t rebuilds() const { return rebuilds_; }  ///< swapped in or made by a count change
  const std::string& last_error() const { return last_error_; }

 private:
  struct Built {
    Tree tree;
    double cost = 0.0;  // SAH cost right after the build
  };
  static Built make(const std::vector<Aabb>& boxes, const DynamicTreeOptions& options);

  DynamicTreeOptions options_;
  Tree tree_;
  double cost_ = 1.0, built_cost_ = 1.0;
  std::size_t count_ = 0, rebuilds_ = 0;
  std::future<Built> pending_;
  std::string last_error_;
};

}  // namespace cullpipe::bvh
