// Insertion BVH builders (Goldsmith & Salmon 1987; Bittner, Hapala & Havran 2015): objects
// enter one at a time as new leaves beside the node whose choice adds least surface area,
// optionally followed by tree rotations along the insertion path (Kopta et al. 2012).
#include <algorithm>
#include <cmath>
#include <compare>
#include <glm/geometric.hpp>
#include <numeric>
#include <tuple>
#include <vector>

#include "cullpipe/bvh/box_ops.hpp"
#include "cullpipe/bvh/builders.hpp"
#include "cullpipe/bvh/sibling_search.inl"
#include "cullpipe/core/splitmix.hpp"

namespace cullpipe::bvh {

using detail::measure;
using detail::Measure;
using detail::merged;

namespace {

// A node of the tree while it grows: parent links for walking up, object counts for breaking
// ties towards the smaller subtree.
struct DynNode {
  Aabb box;
  std::uint32_t parent = kNone, left = kNone, right = kNone;
  std::uint32_t object = 0;  ///< leaves
  std::uint32_t count = 1;   ///< objects below
  bool leaf() const { return left == kNone; }
};

constexpr std::uint32_t kOne = 1;

class DynamicTree {
 public:
  explicit DynamicTree(std::size_t objects) { nodes_.reserve(2 * objects); }

  enum class Search { Greedy, BranchAndBound };

  void insert(std::uint32_t object, const Aabb& box, Search search, bool rotations) {
    const std::uint32_t leaf = add({box, kNone, kNone, kNone, object, 1});
    if (root_ == kNone) {
      root_ = leaf;
      return;
    }
    const std::uint32_t sibling = search == Search::Greedy ? find_greedy(box) : find_best(box);
    // The sibling's place goes to a new inner node over (sibling, leaf).
    const std::uint32_t old_parent = nodes_[sibling].parent;
    const std::uint32_t parent =
        add({merged(nodes_[sibling].box, box), old_parent, sibling, leaf, 0, nodes_[sibling].count + 1});
    nodes_[sibling].parent = parent;
    nodes_[leaf].parent = parent;
    if (old_parent == kNone)
      root_ = parent;
    else
      replace_child(old_parent, sibling, parent);
    // Grow the ancestors' boxes, rotating at each node on the way up when asked.
    for (std::uint32_t i = parent; i != kNone; i = nodes_[i].parent) {
      DynNode& n = nodes_[i];
      n.box = merged(nodes_[n.left].box, nodes_[n.right].box);
      n.count = nodes_[n.left].count + nodes_[n.right].count;
      if (rotations) rotate(i);
    }
  }

  /// The tree as a Tree value (root at 0, objects[k] = k, one object per leaf).
  Tree to_tree(std::size_t objects) const {
    Tree tree;
    if (root_ == kNone) return tree;
    tree.objects.resize(objects);
    std::iota(tree.objects.begin(), tree.objects.end(), 0u);
    tree.nodes.resize(nodes_.size());
    const auto index = [&](std::uint32_t i) { return i == 0 ? root_ : i == root_ ? 0 : i; };
    for (std::uint32_t i = 0; i < nodes_.size(); ++i) {
      const DynNode& d = nodes_[i];
      Node& n = tree.nodes[index(i)];
      n.box = d.box;
      if (d.leaf()) {
        n.first = d.object;
        n.count = 1;
      } else {
        n.left = index(d.left);
        n.right = index(d.right);
      }
    }
    return tree;
  }

 private:
  std::uint32_t add(const DynNode& n) {
    nodes_.push_back(n);
    return std::uint32_t(nodes_.size() - 1);
  }

  void replace_child(std::uint32_t parent, std::uint32_t old_child, std::uint32_t new_child) {
    DynNode& p = nodes_[parent];
    (p.left == old_child ? p.left : p.right) = new_child;
    nodes_[new_child].parent = parent;
  }

  // Goldsmith-Salmon descent along one path, as in Box2D v3 (b2FindBestSibling): every node on
  // the path and every leaf child of it is scored by its full cost (the new parent's area plus
  // what each ancestor gains) and the best is kept. The path continues into the inner child
  // with the smaller lower bound on the cost of a sibling at or below it, inherited + what the
  // child gains + min(area(new box), area(child)), and stops when neither bound can beat the
  // best, or at two leaves. Ties: equal costs prefer the node with fewer objects (so a leaf),
  // equal bounds the child whose centre is nearer, then the one with fewer objects. So equal
  // boxes build a balanced tree, not a chain (which collapse_leaves could not repair).
  std::uint32_t find_greedy(const Aabb& box) const {
    const Measure own = measure(box);
    const glm::dvec3 centre = glm::dvec3(box.center());
    std::uint32_t i = root_;
    Measure direct = measure(merged(nodes_[i].box, box)), area = measure(nodes_[i].box), inherited{};
    std::uint32_t best = root_;
    Measure best_cost = direct;
    const auto offer = [&](std::uint32_t node, const Measure& cost) {
      if (std::tie(cost, nodes_[node].count) < std::tie(best_cost, nodes_[best].count)) best_cost = cost, best = node;
    };
    struct Child {
      std::uint32_t node = kNone;
      Measure direct, area, bound;
      double distance = 0.0;
    };
    while (!nodes_[i].leaf()) {
      const DynNode& n = nodes_[i];
      offer(i, direct + inherited);
      inherited = inherited + (direct - area);
      Child inner[2];
      int inner_count = 0;
      for (const std::uint32_t c : {n.left, n.right}) {
        const Measure grown = measure(merged(nodes_[c].box, box));
        if (nodes_[c].leaf()) {
          offer(c, grown + inherited);
          continue;
        }
        Child& ch = inner[inner_count++];
        ch.node = c;
        ch.direct = grown;
        ch.area = measure(nodes_[c].box);
        ch.bound = inherited + (grown - ch.area) + std::min(own, ch.area);
        const glm::dvec3 d = glm::dvec3(nodes_[c].box.center()) - centre;
        ch.distance = glm::dot(d, d);
      }
      // Below an inner child the best possible is (bound, one object).
      const Child* next = nullptr;
      for (int k = 0; k < inner_count; ++k) {
        const Child& ch = inner[k];
        if (!(std::tie(ch.bound, kOne) < std::tie(best_cost, nodes_[best].count))) continue;
        if (!next || std::tie(ch.bound, ch.distance, nodes_[ch.node].count) <
                         std::tie(next->bound, next->distance, nodes_[next->node].count))
          next = &ch;
      }
      if (!next) break;
      i = next->node;
      direct = next->direct;
      area = next->area;
    }
    return best;
  }

  // Branch and bound (Bittner et al. 2015), shared with DynamicTree::insert (sibling_search.inl).
  std::uint32_t find_best(const Aabb& box) { return detail::best_sibling(View{nodes_}, root_, box, heap_); }

  // The best of the four child/grandchild swaps at node a by the area they save (the swap
  // changes only the box of the child that receives a grandchild), applied when it saves any.
  void rotate(std::uint32_t a) {
    const std::uint32_t b = nodes_[a].left, c = nodes_[a].right;
    Measure best{};  // a swap must save something (strictly less than zero change)
    std::uint32_t take = kNone, give = kNone,
                  into = kNone;  // swap child `give` of a with grandchild `take` under `into`
    const auto consider = [&](std::uint32_t child, std::uint32_t other) {
      const DynNode& o = nodes_[other];
      if (o.leaf()) return;
      for (const auto& [grandchild, stays] : {std::pair{o.left, o.right}, std::pair{o.right, o.left}}) {
        const Measure change = measure(merged(nodes_[child].box, nodes_[stays].box)) - measure(o.box);
        if (change < best) best = change, give = child, take = grandchild, into = other;
      }
    };
    consider(b, c);
    consider(c, b);
    if (take == kNone) return;
    replace_child(a, give, take);
    replace_child(into, take, give);
    DynNode& n = nodes_[into];
    n.box = merged(nodes_[n.left].box, nodes_[n.right].box);
    n.count = nodes_[n.left].count + nodes_[n.right].count;
  }

  // The nodes as detail::best_sibling reads them.
  struct View {
    const std::vector<DynNode>& nodes;
    const Aabb& box(std::uint32_t i) const { return nodes[i].box; }
    bool leaf(std::uint32_t i) const { return nodes[i].leaf(); }
    std::uint32_t left(std::uint32_t i) const { return nodes[i].left; }
    std::uint32_t right(std::uint32_t i) const { return nodes[i].right; }
    std::uint32_t count(std::uint32_t i) const { return nodes[i].count; }
  };

  std::vector<DynNode> nodes_;
  std::uint32_t root_ = kNone;
  detail::SiblingHeap heap_;
};

Tree build_insertion(std::span<const Aabb> boxes, const BuildOptions& options, DynamicTree::Search search) {
  // Insertion order: ids, or a fixed pseudo-random permutation (Fisher-Yates with SplitMix64,
  // the same on every platform) so that objects given in spatial order do not build a skewed tree.
  std::vector<std::uint32_t> order(boxes.size());
  std::iota(order.begin(), order.end(), 0u);
  if (options.insertion_order == InsertionOrder::Shuffled) {
    SplitMix64 rng{0x5eed5eedull};
    for (std::size_t i = order.size(); i > 1; --i) std::swap(order[i - 1], order[std::size_t(rng.next() % i)]);
  }
  DynamicTree tree(boxes.size());
  for (std::uint32_t i : order) tree.insert(i, boxes[i], search, options.rotations);
  return collapse_leaves(tree.to_tree(boxes.size()), options.max_leaf_size);
}

}  // namespace

Tree build_insertion_greedy(std::span<const Aabb> boxes, const BuildOptions& options) {
  return build_insertion(boxes, options, DynamicTree::Search::Greedy);
}

Tree build_insertion_bnb(std::span<const Aabb> boxes, const BuildOptions& options) {
  return build_insertion(boxes, options, DynamicTree::Search::BranchAndBound);
}

}  // namespace cullpipe::bvh
