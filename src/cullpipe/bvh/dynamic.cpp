#include "cullpipe/bvh/dynamic.hpp"

#include <chrono>
#include <exception>
#include <stdexcept>
#include <system_error>

#include "cullpipe/bvh/bvh.hpp"

namespace cullpipe::bvh {

namespace {

// SAH cost with a floor: a tree of one point box has cost 0, and quality divides by it.
double sah_cost(const Tree& tree) {
  const double cost = metrics(tree).sah_cost;
  return cost > 0.0 ? cost : 1.0;
}

}  // namespace

DynamicTree::Built DynamicTree::make(const std::vector<Aabb>& boxes, const DynamicTreeOptions& options) {
  Built b;
  b.tree = build(options.builder, boxes, options.build);
  b.cost = sah_cost(b.tree);
  return b;
}

DynamicTree::DynamicTree(std::span<const Aabb> boxes, DynamicTreeOptions options) : options_(std::move(options)) {
  Built b = make(std::vector<Aabb>(boxes.begin(), boxes.end()), options_);
  tree_ = std::move(b.tree);
  cost_ = built_cost_ = b.cost;
  count_ = boxes.size();
}

DynamicTree::~DynamicTree() {
  if (pending_.valid()) pending_.wait();
}

TreeStep DynamicTree::update(std::span<const Aabb> boxes) {
  if (boxes.size() != count_) {
    if (pending_.valid()) {
      pending_.wait();
      pending_ = {};
    }
    Built b = make(std::vector<Aabb>(boxes.begin(), boxes.end()), options_);
    tree_ = std::move(b.tree);
    cost_ = built_cost_ = b.cost;
    count_ = boxes.size();
    ++rebuilds_;
    return TreeStep::Rebuilt;
  }
  TreeStep step = TreeStep::Refitted;
  if (pending_.valid() && pending_.wait_for(std::chrono::seconds(0)) == std::future_status::ready) {
    try {
      Built b = pending_.get();
      tree_ = std::move(b.tree);
      built_cost_ = b.cost;
      ++rebuilds_;
      step = TreeStep::Swapped;
    } catch (const std::exception& e) {  // the old tree stays; the next update may try again
      last_error_ = e.what();
    }
    pending_ = {};
  }
  // The objects moved since the copy the rebuild started from (or since the last frame): the
  // tree's topology stays, its boxes follow them.
  refit(tree_, boxes);
  cost_ = sah_cost(tree_);
  if (step == TreeStep::Refitted && !pending_.valid() && cost_ > options_.rebuild_ratio * built_cost_) {
    try {
      pending_ =
          std::async(std::launch::async, &DynamicTree::make, std::vector<Aabb>(boxes.begin(), boxes.end()), options_);
      step = TreeStep::RebuildStarted;
    } catch (const std::system_error& e) {  // no thread to be had: refitting goes on
      last_error_ = e.what();
    }
  }
  return step;
}

}  // namespace cullpipe::bvh
