// Bottom-up (agglomerative) BVH builders: brute force and priority queue (Walter et al. 2008,
// exact greedy clustering by merged surface area) and PLOC (Meister & Bittner 2018, the same
// greedy rule restricted to Morton-order neighbourhoods).
#include <algorithm>
#include <cmath>
#include <compare>
#include <functional>
#include <numeric>
#include <queue>
#include <stdexcept>
#include <string>
#include <tuple>
#include <vector>

#include "cullpipe/bvh/box_ops.hpp"
#include "cullpipe/bvh/builders.hpp"
#include "cullpipe/core/thread_pool.hpp"

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
  if (n > std::size_t(kNone - 1) / 2)
    throw std::length_error("build_agglomerative_local: " + std::to_string(n) + " objects; at most " +
                            std::to_string((kNone - 1) / 2) + " fit 32-bit node indices");
  const std::uint32_t radius = std::max<std::uint32_t>(options.neighbours, 1);
  std::vector<Node> pool = leaf_pool(boxes);

  // The clusters in Morton order: their pool ids and boxes (and room to compact them into).
  std::vector<std::uint32_t> id = morton_order(boxes), next_id(n);
  std::vector<Aabb> box(n), next_box(n);
  for (std::size_t i = 0; i < n; ++i) box[i] = boxes[id[i]];

  std::vector<LocalKey> best(n);
  std::vector<std::uint32_t> nearest(n);
  enum : char { kUntouched, kAbsorbed, kGrown };  // a cluster's fate in the current pass
  std::vector<char> state(n);
  // On several threads, a pass over at least kShared clusters is cut into one chunk per
  // thread. Every step gives what the one-thread pass gives: a cluster's candidates are
  // offered to it in the same order (a chunk first offers the pairs reaching into it from the
  // `radius` positions before it, then its own), merges take pool ids in position order (each
  // chunk's start is the earlier chunks' count), and the compaction keeps the order.
  ThreadPool* const threads = options.pool != nullptr && options.pool->size() > 1 ? options.pool : nullptr;
  constexpr std::size_t kShared = 1u << 14;
  std::vector<std::size_t> chunk_merges, chunk_kept;
  std::size_t m = n;
  while (m > 1) {
    const std::size_t chunks = threads != nullptr && m >= kShared ? threads->size() : 1;
    const auto chunk_range = [&](std::size_t c) {
      return std::pair<std::uint32_t, std::uint32_t>(std::uint32_t(m * c / chunks),
                                                     std::uint32_t(m * (c + 1) / chunks));
    };
    const auto run = [&](auto&& chunk) {
      if (chunks == 1) {
        chunk(std::size_t(0));
      } else {
        threads->parallel_for(chunks, chunk);
      }
    };
    // Nearest neighbour of each cluster within `radius` positions each side; each pair's cost
    // is computed once (twice at a chunk's start) and offered to both ends.
    auto search = [&](std::size_t c) {
      const std::uint32_t b = chunk_range(c).first, e = chunk_range(c).second;
      std::fill(best.begin() + b, best.begin() + e, LocalKey{{INFINITY, INFINITY}, kNone, kNone, kNone});
      const auto offer = [&](std::uint32_t i, std::uint32_t j) {
        LocalKey key{measure(merged(box[i], box[j])), j - i, i & 1u, i};
        // A NaN cost (boxes reaching to infinity along a flat axis: infinity times 0) counts
        // as the worst real cost, so every cluster still gets a nearest neighbour (else it kept
        // last pass's, and the chain guard could merge a cluster with itself).
        if (std::isnan(key.cost.area) || std::isnan(key.cost.perimeter)) key.cost = {INFINITY, INFINITY};
        if (i >= b && key < best[i]) best[i] = key, nearest[i] = j;
        if (j < e && key < best[j]) best[j] = key, nearest[j] = i;
      };
      for (std::uint32_t i = b > radius ? b - radius : 0; i < b; ++i)
        for (std::uint32_t j = b; j < std::min<std::size_t>(e, std::size_t(i) + radius + 1); ++j) offer(i, j);
      for (std::uint32_t i = b; i < e; ++i) {
        const std::uint32_t end = std::uint32_t(std::min<std::size_t>(m, std::size_t(i) + radius + 1));
        for (std::uint32_t j = i + 1; j < end; ++j) offer(i, j);
      }
    };
    run(search);
    // Merge mutual nearest neighbours; the new cluster takes the lower position.
    chunk_merges.assign(chunks + 1, 0);
    auto count_merges = [&](std::size_t c) {
      const std::uint32_t b = chunk_range(c).first, e = chunk_range(c).second;
      std::size_t k = 0;
      for (std::uint32_t i = b; i < e; ++i) k += i < nearest[i] && nearest[nearest[i]] == i;
      chunk_merges[c + 1] = k;
      std::fill(state.begin() + b, state.begin() + e, kUntouched);
    };
    run(count_merges);
    for (std::size_t c = 0; c < chunks; ++c) chunk_merges[c + 1] += chunk_merges[c];
    const std::size_t first_new = pool.size();
    pool.resize(first_new + chunk_merges[chunks]);
    // (A cluster j absorbed by i of another chunk is never the lower end of a pair, so no
    // chunk writes what another reads.)
    auto merge_mutual = [&](std::size_t c) {
      const std::uint32_t b = chunk_range(c).first, e = chunk_range(c).second;
      std::size_t at = first_new + chunk_merges[c];
      for (std::uint32_t i = b; i < e; ++i) {
        const std::uint32_t j = nearest[i];
        if (!(i < j && nearest[j] == i)) continue;
        box[i] = merged(box[i], box[j]);
        pool[at] = {box[i], std::min(id[i], id[j]), std::max(id[i], id[j]), 0, pool[id[i]].count + pool[id[j]].count};
        id[i] = std::uint32_t(at++);
        state[i] = kGrown;
        state[j] = kAbsorbed;
      }
    };
    run(merge_mutual);
    // Guard against long chains of preference (e.g. nested boxes, where the exact rule merges
    // one pair per pass and the build would take quadratic time): when mutual pairs are rare,
    // also merge each unmerged cluster with its unmerged nearest neighbour, in order.
    if (chunk_merges[chunks] * 64 < m) {
      for (std::uint32_t i = 0; i < m; ++i) {
        const std::uint32_t j = nearest[i];
        if (state[i] != kUntouched || state[j] != kUntouched) continue;
        const std::uint32_t lo = std::min(i, j), hi = std::max(i, j);
        box[lo] = merged(box[lo], box[hi]);
        id[lo] = merge(pool, id[lo], id[hi], box[lo]);
        state[lo] = kGrown;
        state[hi] = kAbsorbed;
      }
    }
    // The survivors, in order, into the other arrays.
    chunk_kept.assign(chunks + 1, 0);
    auto count_kept = [&](std::size_t c) {
      const std::uint32_t b = chunk_range(c).first, e = chunk_range(c).second;
      chunk_kept[c + 1] =
          std::size_t(std::count_if(state.begin() + b, state.begin() + e, [](char s) { return s != kAbsorbed; }));
    };
    run(count_kept);
    for (std::size_t c = 0; c < chunks; ++c) chunk_kept[c + 1] += chunk_kept[c];
    auto compact = [&](std::size_t c) {
      const std::uint32_t b = chunk_range(c).first, e = chunk_range(c).second;
      std::size_t w = chunk_kept[c];
      for (std::uint32_t i = b; i < e; ++i) {
        if (state[i] == kAbsorbed) continue;
        next_id[w] = id[i];
        next_box[w] = box[i];
        ++w;
      }
    };
    run(compact);
    id.swap(next_id);
    box.swap(next_box);
    m = chunk_kept[chunks];
  }
  const std::uint32_t root = id[0];
  return finish(std::move(pool), root, n, options.max_leaf_size);
}

}  // namespace cullpipe::bvh
