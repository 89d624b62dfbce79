// Part of the SIMD kernels (simd_kernels.inl includes it once per instruction set). Hierarchy walks
// (fast::CpuBvhCuller): one subtree's nodes and object ranges, W at a time.
#include <cstddef>
#include <cstdint>

namespace cullpipe::fast::detail {
namespace CULLPIPE_SIMD_NS {
namespace {

// ---- Hierarchy walks (fast::CpuBvhCuller) ----
// bvh::cull_hierarchical's tests of one subtree, W at a time: a work list of sibling pairs
// (the two children of a straddling node, with the planes it straddles) is taken W / 2 pairs
// per step, their records transposed into vectors (one node per lane) and tested against the
// planes one by one. The object ranges of straddling leaves (and, with range_objects, of
// straddling nodes of at most that many objects) go to a second list, tested at the end in
// groups of up to 64 objects, W at a time, loaded straight from the volumes' blocks in tree
// order (WalkTree::blocks) against the planes their node straddles. Every lane does the scalar test's float operations
// in its order (bvh::classify_masked for boxes, classify_masked_margin for the nodes of OBB and sphere trees,
// classify_planes for OBBs and spheres) and the planes outside its mask count for nothing. The scalar tests stop at the
// first plane that rejects, which does not change their answer (OUTSIDE wins over anything found before or after), so
// testing every plane gives the same class, and the same straddled planes whenever the class is not OUTSIDE. Every node
// and object the depth-first traversal tests is tested here once, so the counts are its counts. The order of the tests
// is not its order, so the visible objects are marked in a bitmap (by position in the subtree's range), from which the
// caller lists them in tree order.

inline std::uint32_t bits_of(float word) {
  std::uint32_t bits;
  __builtin_memcpy(&bits, &word, sizeof bits);
  return bits;
}

inline vf larger(vf a, vf b) { return a < b ? b : a; }  // std::max's choice, per lane

/// For the box tests: each plane's p-vertex columns (4 + axis where the normal component is
/// >= 0, -0 too, as pn_vertices; else the axis), chosen once per walk. The n-vertex column is
/// the other one (p ^ 4).
struct BoxPlanes {
  std::uint32_t p[6][3];
  explicit BoxPlanes(const PlaneSet& planes) : p{} {
    for (std::uint32_t k = 0; k < planes.count; ++k) {
      p[k][0] = planes.nx[k] >= 0.0f ? 4 : 0;
      p[k][1] = planes.ny[k] >= 0.0f ? 5 : 1;
      p[k][2] = planes.nz[k] >= 0.0f ? 6 : 2;
    }
  }
};

/// bvh::classify_masked of W boxes (min x y z in box[0..2], max in box[4..6]) against the
/// planes in each lane's `mask`: `outside` nonzero where a p-vertex is behind, `straddled` the
/// planes whose n-vertex is behind. With `margin` (OBB and sphere trees),
/// classify_masked_margin.
inline void test_boxes(const vf* box, vi mask, std::uint32_t any, const PlaneSet& planes, const BoxPlanes& columns,
                       const WalkTree* margin, vi& outside, vi& straddled) {
  outside = straddled = vi{};
  const vf zero = {};
  vf reach = {};
  if (margin) {
    reach = (larger(abs(box[0]), abs(box[4])) + larger(abs(box[1]), abs(box[5]))) + larger(abs(box[2]), abs(box[6]));
  }
  for (; any != 0; any &= any - 1) {
    const std::uint32_t k = static_cast<std::uint32_t>(__builtin_ctz(any));
    const float nx = planes.nx[k], ny = planes.ny[k], nz = planes.nz[k], d = planes.d[k];
    const std::uint32_t* p = columns.p[k];
    const vf dp = ((nx * box[p[0]] + ny * box[p[1]]) + nz * box[p[2]]) + d;
    const vf dn = ((nx * box[p[0] ^ 4] + ny * box[p[1] ^ 4]) + nz * box[p[2] ^ 4]) + d;
    const vi bit = mask & static_cast<std::int32_t>(1u << k);
    if (margin) {
      const vf size = reach + __builtin_fabsf(d);
      const vi certain = size <= margin->margin_limit;  // false for NaN
      const vf m = margin->margin_scale * size + margin->margin_floor;
      outside |= (certain & (dp < -m)) & bit;
      straddled |= (~certain | (dn < m)) & bit;
    } else {
      outside |= (dp < zero) & bit;
      straddled |= (dn < zero) & bit;
    }
  }
}

/// classify_planes of W OBBs (centre, u0, u1, u2, half extents in col[0..14]).
inline void test_obbs(const vf* col, vi mask, std::uint32_t any, const PlaneSet& planes, vi& outside, vi& crossing) {
  outside = crossing = vi{};
  for (; any != 0; any &= any - 1) {
    const std::uint32_t k = static_cast<std::uint32_t>(__builtin_ctz(any));
    const float nx = planes.nx[k], ny = planes.ny[k], nz = planes.nz[k];
    const vf s = ((nx * col[0] + ny * col[1]) + nz * col[2]) + planes.d[k];
    const vf a0 = (nx * col[3] + ny * col[4]) + nz * col[5];
    const vf a1 = (nx * col[6] + ny * col[7]) + nz * col[8];
    const vf a2 = (nx * col[9] + ny * col[10]) + nz * col[11];
    const vf r = (abs(a0) * col[12] + abs(a1) * col[13]) + abs(a2) * col[14];
    const vi bit = mask & static_cast<std::int32_t>(1u << k);
    outside |= (s < -r) & bit;
    crossing |= (s < r) & bit;
  }
}

/// classify_planes of W spheres (centre, radius in col[0..3]).
inline void test_spheres(const vf* col, vi mask, std::uint32_t any, const PlaneSet& planes, vi& outside, vi& crossing) {
  outside = crossing = vi{};
  for (; any != 0; any &= any - 1) {
    const std::uint32_t k = static_cast<std::uint32_t>(__builtin_ctz(any));
    const vf s = ((planes.nx[k] * col[0] + planes.ny[k] * col[1]) + planes.nz[k] * col[2]) + planes.d[k];
    const vi bit = mask & static_cast<std::int32_t>(1u << k);
    outside |= (s < -col[3]) & bit;
    crossing |= (s < col[3]) & bit;
  }
}

enum class WalkKind { Aabb, Obb, Sphere };

/// Lane l = p[l / 2]: W / 2 items, each in two adjacent lanes.
inline vi load_doubled(const std::uint32_t* p) {
  typedef std::int32_t vh __attribute__((vector_size(W * 2)));
  vh h;
  __builtin_memcpy(&h, p, sizeof h);
#if CULLPIPE_SIMD_LANES == 16
  return __builtin_shufflevector(h, h, 0, 0, 1, 1, 2, 2, 3, 3, 4, 4, 5, 5, 6, 6, 7, 7);
#elif CULLPIPE_SIMD_LANES == 8
  return __builtin_shufflevector(h, h, 0, 0, 1, 1, 2, 2, 3, 3);
#else
  return __builtin_shufflevector(h, h, 0, 0, 1, 1);
#endif
}

/// Lanes 2k and 2k + 1 = lane 2k of v.
inline vi even_lanes_doubled(vi v) {
#if CULLPIPE_SIMD_LANES == 16
  return __builtin_shufflevector(v, v, 0, 0, 2, 2, 4, 4, 6, 6, 8, 8, 10, 10, 12, 12, 14, 14);
#elif CULLPIPE_SIMD_LANES == 8
  return __builtin_shufflevector(v, v, 0, 0, 2, 2, 4, 4, 6, 6);
#else
  return __builtin_shufflevector(v, v, 0, 0, 2, 2);
#endif
}

template <WalkKind Kind>
WalkCounts walk(const WalkTree& t, WalkRoot root, const PlaneSet& planes, WalkOutput out) {
  constexpr unsigned object_columns = Kind == WalkKind::Obb      ? kWalkObbColumns
                                      : Kind == WalkKind::Sphere ? kWalkSphereColumns
                                                                 : kWalkAabbColumns;
  static_assert(W % 2 == 0, "a step takes whole sibling pairs");
  const WalkTree* margin = Kind == WalkKind::Aabb ? nullptr : &t;
  const BoxPlanes columns(planes);
  constexpr std::size_t block_floats = kWalkBlock * object_columns;  // a block of the volumes (WalkTree::blocks)
  auto block_at = [&](std::uint32_t pos) { return t.blocks + walk_block_offset(pos, object_columns); };
  static_assert(kWalkBlock % W == 0, "a vector aligned to W lies within one block's column");
  WalkCounts counts;
  const std::uint32_t range_first = root.first;
  // Visible objects, one bit per position in the subtree's range.
  std::uint64_t* const marks = out.marks;
  auto mark_range = [&](std::uint32_t first, std::uint32_t count) {
    const std::uint32_t a = first - range_first, b = a + count - 1;  // count > 0
    const std::uint64_t low = ~std::uint64_t{0} << (a & 63), high = ~std::uint64_t{0} >> (63 - (b & 63));
    if (a / 64 == b / 64) {
      marks[a / 64] |= low & high;
      return;
    }
    marks[a / 64] |= low;
    for (std::uint32_t w = a / 64 + 1; w < b / 64; ++w) marks[w] = ~std::uint64_t{0};
    marks[b / 64] |= high;
  };

  // The work list: sibling pairs to test (pair, planes their parent straddles, first object of
  // the pair's range), taken W / 2 pairs (W slots, a lane each) per step. Breadth first: a
  // pair is tested a level after it was listed and its record prefetched (each pair is listed
  // once: work_capacity suffices). The subtree's root is listed as a pair with one slot
  // skipped (kSkipLow / kSkipHigh in its planes word).
  constexpr std::uint32_t kSkipLow = 1u << 30, kSkipHigh = 1u << 31, kPlaneBits = kSkipLow - 1u;
  const std::size_t span = out.work_capacity + 16;  // a list and the room a vector store may write past it
  std::uint32_t* const work_pair = out.work;
  std::uint32_t* const work_mask = work_pair + span;
  std::uint32_t* const work_first = work_mask + span;
  // The object ranges to test (first, count, planes): straddling leaves, and straddling nodes
  // of at most t.range_objects objects. Listed as they are found (their first lines
  // prefetched) and tested at the end, up to 64 objects at a time, straight from the blocks.
  std::uint32_t* const range_at = work_first + span;
  std::uint32_t* const range_count = range_at + span;
  std::uint32_t* const range_mask = range_count + span;
  std::size_t ranges = 0;
  const vu small_limit = vu{} + t.range_objects;

  const bool root_high = root.slot & 1u;  // the root's sibling (low slot) comes first in the pair's range
  work_pair[0] = root.slot / 2;
  work_mask[0] = root.mask | (root_high ? kSkipLow : kSkipHigh);
  work_first[0] =
      root_high ? root.first - bits_of(t.nodes[std::size_t(root.slot - 1) * kWalkNodeFloats + 3]) : root.first;
  std::size_t head = 0, tail = 1;
  vi lane_index;
  for (unsigned l = 0; l < W; ++l) lane_index[l] = static_cast<std::int32_t>(l);
  const vi odd = -(lane_index & 1);  // -1 in the high slots' lanes
  const vi skip_bit = (~odd & static_cast<std::int32_t>(kSkipLow)) |
                      (odd & static_cast<std::int32_t>(kSkipHigh));  // the slot's skip flag
  while (head != tail) {
    // W / 2 pairs from the list (reads past its end stay in its room), their slots a lane each.
    const unsigned pairs = static_cast<unsigned>(smaller(tail - head, W / 2));
    const vi in_use = lane_index < static_cast<std::int32_t>(2 * pairs);
    const vi listed_mask = load_doubled(work_mask + head);
    // Lanes past the pairs repeat the first pair (their reads stay in the tree).
    const vi pair = in_use ? load_doubled(work_pair + head) : vi{} + static_cast<std::int32_t>(work_pair[head]);
    alignas(64) std::uint32_t slot[W], first_of[W];
    const vi slots = reinterpret_cast<vi>(reinterpret_cast<vu>(pair) * 2u - reinterpret_cast<vu>(odd));
    __builtin_memcpy(slot, &slots, sizeof slot);
    const vi lane_mask = listed_mask & static_cast<std::int32_t>(kPlaneBits);
    const std::uint32_t valid = lane_bits((listed_mask & skip_bit) == 0) & lane_bits(in_use);  // the lanes in use
    std::uint32_t any = 0;  // the planes some lane tests (deep nodes straddle few)
    for (unsigned k = 0; k < pairs; ++k) any |= work_mask[head + k];
    any &= kPlaneBits;
    const vi low_first = load_doubled(work_first + head);
    head += pairs;
    vf col[8];  // min x y z, count, max x y z, link
    gather_columns<kWalkNodeFloats>(t.nodes, slot, W, col);
    alignas(64) std::uint32_t count_of[W], link_of[W];
    __builtin_memcpy(count_of, &col[3], sizeof count_of);
    __builtin_memcpy(link_of, &col[7], sizeof link_of);
    // The low slot's range comes first: the high slot's starts past it.
    const vi lane_first = reinterpret_cast<vi>(
        reinterpret_cast<vu>(low_first) + reinterpret_cast<vu>(odd & even_lanes_doubled(reinterpret_cast<vi>(col[3]))));
    __builtin_memcpy(first_of, &lane_first, sizeof first_of);
    vi outside, straddled;
    test_boxes(col, lane_mask, any, planes, columns, margin, outside, straddled);
    counts.node_tests += static_cast<unsigned>(__builtin_popcount(valid));
    const vi link = reinterpret_cast<vi>(col[7]), count = reinterpret_cast<vi>(col[3]);
    const std::uint32_t live = ~lane_bits(outside != 0) & valid;
    // Leaves (kWalkLeaf: the sign bit), and with range_objects the nodes of at most that many objects.
    const std::uint32_t ends =
        lane_bits(link < 0) | (t.range_objects ? lane_bits(reinterpret_cast<vu>(count) <= small_limit) : 0u);
    const std::uint32_t inner = live & ~ends & ~lane_bits(straddled == 0);
    // Straddling inner nodes: their children's pair listed, with the planes still to test.
    if (inner) {
      compress_store(work_pair + tail, link, inner);
      compress_store(work_mask + tail, straddled, inner);
      compress_store(work_first + tail, lane_first, inner);
      for (std::uint32_t rest = inner; rest != 0; rest &= rest - 1)
        __builtin_prefetch(t.nodes + std::size_t(link_of[__builtin_ctz(rest)]) * (2 * kWalkNodeFloats));
      tail += static_cast<unsigned>(__builtin_popcount(inner));
    }
    alignas(64) std::int32_t straddled_lanes[W];
    __builtin_memcpy(straddled_lanes, &straddled, sizeof straddled);
    for (std::uint32_t rest = live & ~inner; rest != 0; rest &= rest - 1) {
      const unsigned l = static_cast<unsigned>(__builtin_ctz(rest));
      const std::uint32_t planes_left = static_cast<std::uint32_t>(straddled_lanes[l]);
      const std::uint32_t first = first_of[l], n = count_of[l];
      if (planes_left == 0) {  // INSIDE: the whole range, no further tests
        if (out.classes)
          for (std::uint32_t k = first; k < first + n; ++k) out.classes[t.ids[k]] = kInside;
        if (marks && n) mark_range(first, n);
        counts.visible += n;
        counts.inside += n;
        continue;
      }
      // An empty straddling leaf (a tree may have them) has nothing to test; listed, its
      // range's first vector (aligned below `first`) would mark a word the subtree does not own.
      if (n == 0) continue;
      // A straddling leaf or small node: its objects, against the planes it straddles. Its
      // blocks are one run of lines: the first line of its first block and of the next
      // prefetched, the hardware prefetcher takes the rest.
      const float* const range_block = block_at(first);
      __builtin_prefetch(range_block);
      __builtin_prefetch(range_block + block_floats);
      range_at[ranges] = first;
      range_count[ranges] = n;
      range_mask[ranges++] = planes_left;
    }
  }

  // Boxes: each plane's p- and n-vertex columns (BoxPlanes) as offsets in a block, so a
  // range's vectors are loaded straight from the columns the plane needs.
  unsigned vertex_offset[6][6] = {};  // [plane][p x y z, n x y z]
  if constexpr (Kind == WalkKind::Aabb)
    for (std::uint32_t k = 0; k < planes.count; ++k)
      for (unsigned a = 0; a < 3; ++a) {
        const unsigned p = columns.p[k][a] & 4 ? 3 + a : a;  // max or min column
        vertex_offset[k][a] = static_cast<unsigned>(p * kWalkBlock);
        vertex_offset[k][3 + a] = static_cast<unsigned>((p >= 3 ? p - 3 : p + 3) * kWalkBlock);
      }
  for (std::size_t r = 0; r < ranges; ++r) {
    const std::uint32_t first = range_at[r], n = range_count[r], m = range_mask[r], end = first + n;
    counts.object_tests += n;
    // Up to 64 of the range's objects at a time, tested plane by plane (a plane's coefficients
    // and columns set up once), in vectors aligned to W (so within a block) from the one
    // holding `first`; the lanes before `first` and from `end` count for nothing. Their outside
    // and crossing lanes are gathered a bit per object in two words, then counted, marked and
    // classed once per 64, not per vector. The volumes are read from blocks (all columns of
    // kWalkBlock objects together), so a range is one run of cache lines.
    for (std::uint32_t at = first & ~(W - 1); at < end; at += 64) {
      const std::uint32_t size = end - at < 64 ? end - at : 64, low = at < first ? first - at : 0;
      std::uint64_t outside_bits = 0, crossing_bits = 0;
      if constexpr (Kind == WalkKind::Aabb) {  // test_boxes's operations, plane by plane
        const vf zero = {};
        for (std::uint32_t any = m; any != 0; any &= any - 1) {
          const std::uint32_t k = static_cast<std::uint32_t>(__builtin_ctz(any));
          const float nx = planes.nx[k], ny = planes.ny[k], nz = planes.nz[k], d = planes.d[k];
          const unsigned* const o = vertex_offset[k];
          for (std::uint32_t j = 0; j < size; j += W) {
            const float* const b = block_at(at + j);
            const vf dp = ((nx * load(b + o[0]) + ny * load(b + o[1])) + nz * load(b + o[2])) + d;
            const vf dn = ((nx * load(b + o[3]) + ny * load(b + o[4])) + nz * load(b + o[5])) + d;
            outside_bits |= std::uint64_t(less_bits(dp, zero)) << j;
            crossing_bits |= std::uint64_t(less_bits(dn, zero)) << j;
          }
        }
      } else {
        const vi mask = vi{} + static_cast<std::int32_t>(m);
        for (std::uint32_t j = 0; j < size; j += W) {
          const float* const b = block_at(at + j);
          vf col[object_columns];
          for (unsigned c = 0; c < object_columns; ++c) col[c] = load(b + c * kWalkBlock);
          vi outside, crossing;
          if constexpr (Kind == WalkKind::Obb)
            test_obbs(col, mask, m, planes, outside, crossing);
          else
            test_spheres(col, mask, m, planes, outside, crossing);
          outside_bits |= std::uint64_t(lane_bits(outside != 0)) << j;
          crossing_bits |= std::uint64_t(lane_bits(crossing != 0)) << j;
        }
      }
      const std::uint64_t valid =
          (size == 64 ? ~std::uint64_t{0} : (std::uint64_t{1} << size) - 1u) & (~std::uint64_t{0} << low);
      const std::uint64_t visible = ~outside_bits & valid;
      counts.visible += static_cast<std::uint32_t>(__builtin_popcountll(visible));
      counts.inside += static_cast<std::uint32_t>(__builtin_popcountll(visible & ~crossing_bits));
      if (out.classes)
        for (std::uint32_t l = low; l < size; ++l)
          out.classes[t.ids[at + l]] =
              visible >> l & 1u ? (crossing_bits >> l & 1u ? kIntersecting : kInside) : kOutside;
      if (marks) {
        if (at < range_first) {  // the subtree's range starts inside this vector (no lane below it is valid)
          marks[0] |= visible >> (range_first - at);
        } else {
          const std::uint32_t p = at - range_first, shift = p % 64;
          marks[p / 64] |= visible << shift;
          if (shift + size > 64) marks[p / 64 + 1] |= visible >> (64 - shift);
        }
      }
    }
  }

  return counts;
}

WalkCounts walk_aabb(const WalkTree& t, WalkRoot root, const PlaneSet& planes, WalkOutput out) {
  return walk<WalkKind::Aabb>(t, root, planes, out);
}
WalkCounts walk_obb(const WalkTree& t, WalkRoot root, const PlaneSet& planes, WalkOutput out) {
  return walk<WalkKind::Obb>(t, root, planes, out);
}
WalkCounts walk_sphere(const WalkTree& t, WalkRoot root, const PlaneSet& planes, WalkOutput out) {
  return walk<WalkKind::Sphere>(t, root, planes, out);
}

}  // namespace
}  // namespace CULLPIPE_SIMD_NS
}  // namespace cullpipe::fast::detail
