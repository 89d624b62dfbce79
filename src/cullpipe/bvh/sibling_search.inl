#pragma once
// The branch-and-bound sibling search of insertion (Bittner, Hapala & Havran 2015), shared by
// build_insertion_bnb and DynamicTree::insert. Internal to src/cullpipe/bvh: an .inl, which the
// install rule (public *.hpp) leaves behind, as it leaves box_ops.hpp.
#include <algorithm>
#include <cstdint>
#include <functional>
#include <utility>
#include <vector>

#include "cullpipe/bvh/box_ops.hpp"
#include "cullpipe/bvh/bvh.hpp"

namespace cullpipe::bvh::detail {

/// The search's priority queue, kept by the caller so that its storage is reused.
using SiblingHeap = std::vector<std::pair<Measure, std::uint32_t>>;

/// The sibling with the least total cost for a new leaf of box `box`: the new parent's area
/// plus the area every ancestor gains ("inherited" cost). Nodes are visited by increasing
/// inherited cost; a subtree is skipped when its lower bound, area(box) + the inherited cost of
/// its root, cannot beat the best found. Among equal costs the search keeps the first found
/// (shallower) node, then descends from it while a child costs no more, into the child with
/// fewer objects, so equal boxes build a balanced tree, not a chain. `nodes` answers box(i),
/// leaf(i), left(i), right(i) and count(i) (objects below node i).
template <class Nodes>
std::uint32_t best_sibling(const Nodes& nodes, std::uint32_t root, const Aabb& box, SiblingHeap& heap) {
  const Measure own = measure(box);
  std::uint32_t best = root;
  Measure best_cost = measure(merged(nodes.box(root), box)), best_inherited{};
  using Item = std::pair<Measure, std::uint32_t>;  // (inherited cost, node)
  heap.clear();
  heap.push_back({Measure{}, root});
  while (!heap.empty()) {
    std::pop_heap(heap.begin(), heap.end(), std::greater<Item>());
    const auto [inherited, i] = heap.back();
    heap.pop_back();
    if (!(inherited + own < best_cost)) break;  // every remaining node inherits at least as much
    const Measure combined = measure(merged(nodes.box(i), box));
    if (combined + inherited < best_cost) best_cost = combined + inherited, best = i, best_inherited = inherited;
    if (nodes.leaf(i)) continue;
    const Measure below = inherited + (combined - measure(nodes.box(i)));
    if (!(below + own < best_cost)) continue;
    for (std::uint32_t c : {nodes.left(i), nodes.right(i)}) {
      heap.push_back({below, c});
      std::push_heap(heap.begin(), heap.end(), std::greater<Item>());
    }
  }
  while (!nodes.leaf(best)) {
    const Measure below = best_inherited + (measure(merged(nodes.box(best), box)) - measure(nodes.box(best)));
    std::uint32_t next = kNone;
    for (const std::uint32_t c : {nodes.left(best), nodes.right(best)})
      if (measure(merged(nodes.box(c), box)) + below <= best_cost &&
          (next == kNone || nodes.count(c) < nodes.count(next)))
        next = c;
    if (next == kNone) break;
    best = next;
    best_inherited = below;
  }
  return best;
}

}  // namespace cullpipe::bvh::detail
