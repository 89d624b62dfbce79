// Bottom-up (agglomerative) BVH builders: brute force and priority queue (Walter et al. 2008,
// exact greedy clustering by merged surface area) and PLOC (Meister & Bittner 2018, the same
// greedy rule restricted to Morton-order neighbourhoods).
#include <algorithm>
#include <cmath>
#include <compare>
#include <functional>
#include <numeric>
#include <queue>
#include <tuple>
#include <vector>

#include "bvh/box_ops.hpp"
#include "bvh/builders.hpp"

namespace cullpipe::bvh {

using detail::measure;
using detail::Measure;
using detail::merged;

namespace {

// A candidate pair of clusters (ids lo < hi) in a total order, so both exact builders make
// the same merges even when costs tie: by cost (detail::measure of the merged box), then by objects in the pair (equal
// boxes merge into a balanced tree), then by a hash of the ids (so among equal pairs the clusters do not all want the
// same partner, which would make the priority queue re-pair nearly every cluster after each merge), then by the ids.
struct PairKey {
  Measure cost;
  std::uint32_t objects = 0;
  std::uint64_t hash = 0;
  std::uint32_t lo = 0, hi = 0;
  auto operator<=>(const PairKey&) const = default;
};
constexpr PairKey kNoPair{{INFINITY, INFINITY}, kNone, ~std::uint64_t(0), kNone, kNone};

std::uint64_t mix(std::uint64_t x) {  // the SplitMix64 finaliser
  x = (x ^ (x >> 30)) * 0xbf58476d1ce4e5b9ull;
  x = (x ^ (x >> 27)) * 0x94d049bb133111ebull;
  return x ^ (x >> 31);
}

// Pool nodes carry their cluster's object count in `count`, inner ones too while building
// (collapse_leaves reads counts of leaves only).
PairKey pair_key(const std::vector<Node>& pool, std::uint32_t a, std::uint32_t b) {
  const std::uint32_t lo = std::min(a, b), hi = std::max(a, b);
  return {measure(merged(pool[a].box, pool[b].box)), pool[a].count + pool[b].count, mix(std::uint64_t(lo) << 32 | hi),
          lo, hi};
}

// One leaf per object: pool[i] holds object i.
std::vector<Node> leaf_pool(std::span<const Aabb> boxes) {
  std::vector<Node> pool;
  pool.reserve(2 * boxes.size());
  for (std::size_t i = 0; i < boxes.size(); ++i) pool.push_back({boxes[i], kNone, kNone, std::uint32_t(i), 1});
  return pool;
}

// Appends the inner node over clusters a and b (the lower id on the left); returns its id.
std::uint32_t merge(std::vector<Node>& pool, std::uint32_t a, std::uint32_t b, const Aabb& box) {
  pool.push_back({box, std::min(a, b), std::max(a, b), 0, pool[a].count + pool[b].count});
  return std::uint32_t(pool.size() - 1);
}

// The pool as a Tree (the root moved to index 0, objects[i] = i), then leaves collapsed.
Tree finish(std::vector<Node> pool, std::uint32_t root, std::size_t n, std::uint32_t max_leaf_size) {
  Tree tree;
  tree.objects.resize(n);
  std::iota(tree.objects.begin(), tree.objects.end(), 0u);
  if (root != 0) {
    std::swap(pool[0], pool[root]);
    for (Node& node : pool) {
      if (node.leaf()) continue;
      for (std::uint32_t* c : {&node.left, &node.right}) *c = *c == 0 ? root : *c == root ? 0 : *c;
    }
  }
  tree.nodes = std::move(pool);
  return collapse_leaves(tree, max_leaf_size);
}

// ---- PLOC -----------------------------------------------------------------------------------

// 21 bits spread to every third bit of 63.
std::uint64_t spread_bits(std::uint64_t x) {
  x &= 0x1fffff;
  x = (x | x << 32) & 0x1f00000000ffffull;
  x = (x | x << 16) & 0x1f0000ff0000ffull;
  x = (x | x << 8) & 0x100f00f00f00f00full;
  x = (x | x << 4) & 0x10c30c30c30c30c3ull;
  x = (x | x << 2) & 0x1249249249249249ull;
  return x;
}

// A pair of positions lo < hi in the current cluster list: cost, then the nearer pair, then
// pairs starting at even positions (so runs of equal boxes pair off (0,1), (2,3), ... rather
// than one pair per pass), then the position. A total order, so the least pair considered is
// always mutual and every pass merges at least once.
struct LocalKey {
  Measure cost;
  std::uint32_t distance = 0, odd = 0, lo = 0;
  auto operator<=>(const LocalKey&) const = default;
};

}  // namespace

std::vector<std::uint32_t> morton_order(std::span<const Aabb> boxes) {
  const std::size_t n = boxes.size();
  glm::dvec3 lo(INFINITY), hi(-INFINITY);
  for (const Aabb& b : boxes) {
    const glm::dvec3 c = glm::dvec3(b.center());
    lo = glm::min(lo, c);
    hi = glm::max(hi, c);
  }
  // Cubic cells (one scale for all axes): per-axis scaling would stretch a flat scene's thin
  // axis to as many cells as its long ones and put objects far apart next to each other.
  constexpr double kCells = double(1u << 21);
  const double extent = std::max({hi.x - lo.x, hi.y - lo.y, hi.z - lo.z});
  const double scale = extent > 0.0 && std::isfinite(kCells / extent) ? kCells / extent : 0.0;
  std::vector<std::pair<std::uint64_t, std::uint32_t>> keyed(n);
  for (std::size_t i = 0; i < n; ++i) {
    const glm::dvec3 q =
        glm::clamp((glm::dvec3(boxes[i].center()) - lo) * scale, glm::dvec3(0.0), glm::dvec3(kCells - 1.0));
    const std::uint64_t code =
        spread_bits(std::uint64_t(q.x)) << 2 | spread_bits(std::uint64_t(q.y)) << 1 | spread_bits(std::uint64_t(q.z));
    keyed[i] = {code, std::uint32_t(i)};
  }
  std::sort(keyed.begin(), keyed.end());
  std::vector<std::uint32_t> order(n);
  for (std::size_t i = 0; i < n; ++i) order[i] = keyed[i].second;
  return order;
}

Tree build_agglomerative_brute(std::span<const Aabb> boxes, const BuildOptions& options) {
  const std::size_t n = boxes.size();
  if (n == 0) return {};
  std::vector<Node> pool = leaf_pool(boxes);
  std::vector<std::uint32_t> active(n);  // live cluster ids, ascending (a new id is the largest)
  std::iota(active.begin(), active.end(), 0u);
  while (active.size() > 1) {
    PairKey best = kNoPair;
    std::size_t best_i = 0, best_j = 0;
    for (std::size_t i = 0; i < active.size(); ++i)
      for (std::size_t j = i + 1; j < active.size(); ++j) {
        const PairKey key = pair_key(pool, active[i], active[j]);
        if (key < best) best = key, best_i = i, best_j = j;
      }
    const std::uint32_t id = merge(pool, best.lo, best.hi, merged(pool[best.lo].box, pool[best.hi].box));
    active.erase(active.begin() + std::ptrdiff_t(best_j));
    active.erase(active.begin() + std::ptrdiff_t(best_i));
    active.push_back(id);
  }
  return finish(std::move(pool), active[0], n, options.max_leaf_size);
}

Tree build_agglomerative_pq(std::span<const Aabb> boxes, const BuildOptions& options) {
  const std::size_t n = boxes.size();
  if (n == 0) return {};
  std::vector<Node> pool = leaf_pool(boxes);
  std::vector<char> alive(2 * n - 1, 0);
  std::fill(alive.begin(), alive.begin() + std::ptrdiff_t(n), 1);
  std::size_t live = n;

  struct Entry {
    PairKey key;
    std::uint32_t cluster;  // whose best pair this is (the other is key.lo or key.hi)
    std::uint32_t partner() const { return key.lo == cluster ? key.hi : key.lo; }
    bool operator>(const Entry& o) const { return std::tie(key, cluster) > std::tie(o.key, o.cluster); }
  };
  std::priority_queue<Entry, std::vector<Entry>, std::greater<Entry>> queue;
  // The best pair of cluster c among the live clusters. Every live cluster has one entry in the
  // queue; an entry whose partner still lives is exact (boxes never change), and the entry of
  // the newer cluster of the least live pair has a key no greater than that pair's (the older
  // one was alive whenever it was computed), so the first valid entry popped is the least pair.
  const auto best_entry = [&](std::uint32_t c) {
    Entry e{kNoPair, c};
    for (std::uint32_t x = 0; x < pool.size(); ++x)
      if (alive[x] && x != c) e.key = std::min(e.key, pair_key(pool, c, x));
    return e;
  };
  if (n > 1)
    for (std::uint32_t i = 0; i < n; ++i) queue.push(best_entry(i));
  std::uint32_t root = 0;
  while (live > 1) {
    const Entry e = queue.top();
    queue.pop();
    if (!alive[e.cluster]) continue;
    const std::uint32_t partner = e.partner();
    if (!alive[partner]) {  // stale: pair again
      queue.push(best_entry(e.cluster));
      continue;
    }
    root = merge(pool, e.key.lo, e.key.hi, merged(pool[e.key.lo].box, pool[e.key.hi].box));
    alive[e.key.lo] = alive[e.key.hi] = 0;
    alive[root] = 1;
    if (--live > 1) queue.push(best_entry(root));
  }
  return finish(std::move(pool), root, n, options.max_leaf_size);
}

Tree build_agglomerative_local(std::span<const Aabb> boxes, const BuildOptions& options) {
  const std::size_t n = boxes.size();
  if (n == 0) return {};
  const std::uint32_t radius = std::max<std::uint32_t>(options.neighbours, 1);
  std::vector<Node> pool = leaf_pool(boxes);

  // The clusters in Morton order: their pool ids and boxes.
  std::vector<std::uint32_t> id = morton_order(boxes);
  std::vector<Aabb> box(n);
  for (std::size_t i = 0; i < n; ++i) box[i] = boxes[id[i]];

  std::vector<LocalKey> best(n);
  std::vector<std::uint32_t> nearest(n);
  enum : char { kUntouched, kAbsorbed, kGrown };  // a cluster's fate in the current pass
  std::vector<char> state(n);
  std::size_t m = n;
  while (m > 1) {
    // Nearest neighbour of each cluster within `radius` positions each side; each pair's cost
    // is computed once and offered to both ends.
    std::fill(best.begin(), best.begin() + std::ptrdiff_t(m), LocalKey{{INFINITY, INFINITY}, kNone, kNone, kNone});
    for (std::uint32_t i = 0; i < m; ++i) {
      const std::uint32_t end = std::uint32_t(std::min<std::size_t>(m, std::size_t(i) + radius + 1));
      for (std::uint32_t j = i + 1; j < end; ++j) {
        const LocalKey key{measure(merged(box[i], box[j])), j - i, i & 1u, i};
        if (key < best[i]) best[i] = key, nearest[i] = j;
        if (key < best[j]) best[j] = key, nearest[j] = i;
      }
    }
    // Merge mutual nearest neighbours; the new cluster takes the lower position.
    std::fill(state.begin(), state.begin() + std::ptrdiff_t(m), kUntouched);
    std::size_t merges = 0;
    const auto merge_at = [&](std::uint32_t i, std::uint32_t j) {  // i < j
      box[i] = merged(box[i], box[j]);
      id[i] = merge(pool, id[i], id[j], box[i]);
      state[i] = kGrown;
      state[j] = kAbsorbed;
      ++merges;
    };
    for (std::uint32_t i = 0; i < m; ++i) {
      const std::uint32_t j = nearest[i];
      if (i < j && nearest[j] == i) merge_at(i, j);
    }
    // Guard against long chains of preference (e.g. nested boxes, where the exact rule merges
    // one pair per pass and the build would take quadratic time): when mutual pairs are rare,
    // also merge each unmerged cluster with its unmerged nearest neighbour, in order.
    if (merges * 64 < m) {
      for (std::uint32_t i = 0; i < m; ++i) {
        const std::uint32_t j = nearest[i];
        if (state[i] == kUntouched && state[j] == kUntouched) merge_at(std::min(i, j), std::max(i, j));
      }
    }
    std::size_t w = 0;
    for (std::size_t i = 0; i < m; ++i) {
      if (state[i] == kAbsorbed) continue;
      id[w] = id[i];
      box[w] = box[i];
      ++w;
    }
    m = w;
  }
  const std::uint32_t root = id[0];
  return finish(std::move(pool), root, n, options.max_leaf_size);
}

}  // namespace cullpipe::bvh
