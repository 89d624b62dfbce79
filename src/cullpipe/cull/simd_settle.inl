// Part of the SIMD kernels (simd_kernels.inl includes it once per instruction set). The flat pass:
// settle each vector by its bounds, resolve the few open objects, list the visible ids per run.
#include <cstddef>
#include <cstdint>

namespace cullpipe::fast::detail {
namespace CULLPIPE_SIMD_NS {
namespace {

// Every kind is first settled by a bound: per object a centre c and a bound b such that, with
// reach = b + PlaneSet::max_margin and s = n.c + d computed in float in any order, fused or
// not, s < -reach on some plane is the reference's OUTSIDE and s >= reach on every plane its
// INSIDE. Both are decided by the smallest s over the planes: three fused multiply-adds and a
// min per plane. The bound's lowest 8 bits hold q, from which (q b) lower_scale - max_margin is
// a lower bound on the straddling threshold: |s| < it settles INTERSECTING without the full
// test. A mirrored plane's distance is (d_i + d_j) - s_i, one subtraction for three FMAs.
// Proofs: docs/numerics.md, "Settling bounds", "Packed lower bounds" and "Mirrored planes".
// A NaN bound or margin settles nothing; objects the bound leaves open (those near a plane)
// are gathered per run, their records prefetched, and tested in full by `resolve`.
struct CentreArrays {
  const float *c_x, *c_y, *c_z, *bound;
};

/// Removes from ids[0..count) (ascending) the k values gone[0..k) (ascending, each one in ids).
inline void remove_ids(std::uint32_t* ids, std::uint32_t count, const std::uint32_t* gone, unsigned k) {
  auto find = [&](std::uint32_t from, std::uint32_t value) {  // its index, at or after `from`
    std::uint32_t hi = count;
    while (from < hi) {
      const std::uint32_t mid = from + (hi - from) / 2;
      if (ids[mid] < value)
        from = mid + 1;
      else
        hi = mid;
    }
    return from;
  };
  std::uint32_t at = find(0, gone[0]);
  for (unsigned j = 0; j < k; ++j) {  // the ids between gone[j] and gone[j + 1] move down j + 1
    const std::uint32_t next = j + 1 < k ? find(at + 1, gone[j + 1]) : count;
    __builtin_memmove(ids + at - j, ids + at + 1, (next - at - 1) * sizeof *ids);
    at = next;
  }
}

/// What one run's scan reads, and where it writes its vectors' visible lanes, their ids (when
/// appending), their settled INTERSECTING lanes (for classes) and the open objects.
struct RunScan {
  const CentreArrays* a;
  const PlaneSet* planes;
  const std::uint32_t* order;  // six plane indices in the order the loop reads them
  float lower_scale;
  std::size_t run, run_end, end;
  bool settles, no_planes;
  std::uint32_t* visible_bits;
  std::uint32_t* ids;
  std::uint32_t* crossing_bits;
  std::uint32_t* open;
};

/// A run's counts: visible lanes (open objects included), settled INTERSECTING, and open.
struct RunTally {
  std::uint32_t visible = 0, across = 0;
  unsigned opened = 0;
};

/// Settles the vectors of one run. Made once per (appending, classes, mirrored), so no test of
/// these runs per vector, and reading local copies of the planes and pointers and counting in
/// locals: no store in the loop can change them, so none is reloaded per vector. noinline: GCC
/// inlines it into cull_settled and then compiles the loop without a mirrored plane (the one
/// most views take) markedly slower (bench/NOTES.md, the flat CPU pass).
template <bool kAppend, bool kClasses, bool kMirror, class Prefetch>
__attribute__((noinline)) RunTally scan_run(const RunScan& r, Prefetch prefetch) {
  std::uint32_t visible_count = 0, across_count = 0;
  unsigned opened_count = 0;
  const float *const c_x = r.a->c_x, *const c_y = r.a->c_y, *const c_z = r.a->c_z, *const bound = r.a->bound;
  const PlaneSet& planes = *r.planes;
  float nx[6], ny[6], nz[6];
  vf d[6];
  for (unsigned k = 0; k < 6; ++k) {
    const std::uint32_t p = r.order[k];
    nx[k] = planes.nx[p], ny[k] = planes.ny[p], nz[k] = planes.nz[p], d[k] = splat(planes.d[p]);
  }
  const vf margin = splat(planes.max_margin), lower = splat(r.lower_scale);
  const vf mirror_d = splat(planes.d[planes.mirror_base] + planes.d[planes.mirror_plane]);
  std::uint32_t* const visible_bits = r.visible_bits;
  std::uint32_t* const run_ids = r.ids;
  std::uint32_t* const crossing_bits = r.crossing_bits;
  std::uint32_t* const open = r.open;
  const std::size_t run = r.run, run_end = r.run_end, end = r.end;
  // Vector b (objects i..i+W-1, `lanes` of them in range) found OUTSIDE (`beyond`), INSIDE
  // (`within`) and INTERSECTING (`across`); the rest are open.
  auto record = [&](std::size_t i, std::size_t b, std::uint32_t lanes, std::uint32_t beyond, std::uint32_t within,
                    std::uint32_t across) __attribute__((always_inline)) {
    const std::uint32_t visible = ~beyond & lanes;
    visible_bits[b] = visible;
    if constexpr (kAppend) append_ids(run_ids + visible_count, static_cast<std::uint32_t>(i), visible);
    visible_count += static_cast<std::uint32_t>(__builtin_popcount(visible));
    across &= lanes;
    across_count += static_cast<std::uint32_t>(__builtin_popcount(across));
    if constexpr (kClasses) crossing_bits[b] = across;
    for (std::uint32_t rest = visible & ~(within | across); rest != 0; rest &= rest - 1) {  // the open lanes
      const std::uint32_t object = static_cast<std::uint32_t>(i + static_cast<unsigned>(__builtin_ctz(rest)));
      prefetch(object);
      open[opened_count++] = object;
    }
  };
  auto settle = [&](std::size_t i, std::size_t b, std::uint32_t lanes) __attribute__((always_inline)) {
    const vf cx = load(c_x + i), cy = load(c_y + i), cz = load(c_z + i);
    const vf stored = load(bound + i);
    const vf reach = stored + margin;
    const vf first_s = mul_add(nz[0], cz, mul_add(ny[0], cy, mul_add(nx[0], cx, d[0])));
    vf m = first_s;
    for (unsigned k = 1; k < (kMirror ? 5 : 6); ++k) {
      const vf s = mul_add(nz[k], cz, mul_add(ny[k], cy, mul_add(nx[k], cx, d[k])));
      m = s < m ? s : m;
    }
    if constexpr (kMirror) {
      const vf s = mirror_d - first_s;
      m = s < m ? s : m;
    }
    const vf q = __builtin_convertvector(reinterpret_cast<vi>(stored) & 255, vf);
    const vf reach_in = mul_sub(q * stored, lower, margin);
    record(i, b, lanes, less_bits(m, -reach), at_least_bits(m, reach), less_bits(abs(m), reach_in));
  };
  auto tail_lanes = [&](std::size_t first) {
    return run_end - first >= W ? kAllLanes : (1u << (run_end - first)) - 1u;
  };
  std::size_t first = run, block = 0;  // the next vector's first object and index
  if (!r.settles || r.no_planes) {
    // No bound holds (every object open), or no planes (every object INSIDE).
    for (; first < run_end; first += W, ++block)
      record(first, block, tail_lanes(first), 0, r.no_planes ? kAllLanes : 0, 0);
    return {visible_count, across_count, opened_count};
  }
  // A cache line of each stream per step (kLine / W vectors, no lane checks), the line kAhead
  // floats on prefetched (the hardware prefetcher alone leaves the four streams short of the
  // memory's bandwidth). The lines whose prefetch stays in the chunk come first, in a loop of
  // their own, so that no line tests whether to prefetch.
  constexpr std::size_t kLine = 16, kAhead = 1024;  // floats
  static_assert(kLine % W == 0);
  const std::size_t lines_end = run_end - (run_end - run) % kLine;
  const std::size_t prefetched_end = end > kAhead ? smaller(lines_end, end - kAhead > run ? end - kAhead : run) : run;
  for (; first + kLine <= prefetched_end; first += kLine) {
    __builtin_prefetch(c_x + first + kAhead);
    __builtin_prefetch(c_y + first + kAhead);
    __builtin_prefetch(c_z + first + kAhead);
    __builtin_prefetch(bound + first + kAhead);
#pragma GCC unroll 4
    for (unsigned v = 0; v < kLine / W; ++v, ++block) settle(first + v * W, block, kAllLanes);
  }
  for (; first < lines_end; first += kLine) {
#pragma GCC unroll 4
    for (unsigned v = 0; v < kLine / W; ++v, ++block) settle(first + v * W, block, kAllLanes);
  }
  // The last vectors (loads past the end stay in the columns' spare vector).
  for (; first < run_end; first += W, ++block) settle(first, block, tail_lanes(first));
  return {visible_count, across_count, opened_count};
}

/// scan_run for a run's appending and classes, chosen once per run.
template <bool kMirror, class Prefetch>
RunTally scan_run_for(bool appending, bool classes, const RunScan& r, Prefetch prefetch) {
  if (appending)
    return classes ? scan_run<true, true, kMirror>(r, prefetch) : scan_run<true, false, kMirror>(r, prefetch);
  return classes ? scan_run<false, true, kMirror>(r, prefetch) : scan_run<false, false, kMirror>(r, prefetch);
}

template <class Prefetch, class Resolve>
ChunkCounts cull_settled(const CentreArrays& a, std::size_t begin, std::size_t end, const PlaneSet& planes,
                         float lower_scale, Prefetch prefetch, Resolve resolve, ChunkOutput out) {
  constexpr std::size_t kRunBlocks = kRunObjects / W;
  constexpr unsigned kRemovedAtMost = 64;  // appended ids removed one by one, at most
  static_assert(kRunObjects % W == 0);
  std::uint32_t run_bits[kRunBlocks], crossing_bits[kRunBlocks];
  std::uint32_t open[kRunBlocks * W];  // objects left open in this run
  // The planes in the order the loop reads them, padded to six with copies of the first (a
  // repeated plane leaves the smallest distance as it is), so it has a fixed trip count. With
  // a mirrored pair (PlaneSet::mirrored), its base plane first and the mirrored plane left
  // out: five planes, the sixth distance (d_base + d_mirrored) less the first's.
  const bool mirrored = planes.mirrored;
  std::uint32_t order[6] = {};
  unsigned listed = 0;
  if (mirrored) order[listed++] = planes.mirror_base;
  for (std::uint32_t k = 0; k < planes.count; ++k)
    if (!mirrored || (k != planes.mirror_base && k != planes.mirror_plane)) order[listed++] = k;
  for (unsigned k = listed; k < 6; ++k) order[k] = order[0];
  const bool settles = planes.unit_normals, no_planes = planes.count == 0;
  const bool bound_settles = settles && !__builtin_isnan(planes.max_margin);  // a NaN margin settles nothing
  const bool listed_by_runs = out.ids && out.runs && out.bits;
  ChunkCounts counts;
  for (std::size_t run = begin; run < end; run += kRunBlocks * W) {
    const std::size_t run_end = smaller(end, run + kRunBlocks * W);
    // Each vector's visible lanes, counted as they are found (open objects as visible until
    // resolved), written where a dense run leaves them: the counts and the bits need no second
    // pass over the run. The settled visible objects are INSIDE or (`across`) INTERSECTING,
    // so the INSIDE count is the visible count less the open objects and the settled
    // INTERSECTING ones, plus those resolved INSIDE.
    std::uint32_t* const run_visible_bits = listed_by_runs ? out.bits + (run - begin) / W : run_bits;
    // A run guessed sparse appends its visible lanes' ids as it finds them, its open objects
    // among them until resolved (removed after if OUTSIDE): the appends overlap the loads
    // instead of taking a loop of their own after the run.
    const std::size_t run_index = (run - begin) / kRunObjects;
    // (Not where no bound can settle an object: every object would be appended, most of them
    // to be removed.)
    const bool appending =
        out.ids && bound_settles && (!listed_by_runs || !(out.runs[run_index] & (kDenseRun | kListedDense)));
    const RunScan scan{&a,        &planes,          order,   lower_scale,   run, run_end, end, settles,
                       no_planes, run_visible_bits, out.ids, crossing_bits, open};
    const RunTally tally = mirrored ? scan_run_for<true>(appending, out.classes != nullptr, scan, prefetch)
                                    : scan_run_for<false>(appending, out.classes != nullptr, scan, prefetch);
    std::uint32_t run_visible = tally.visible;
    const std::uint32_t run_across = tally.across;
    const unsigned open_count = tally.opened;
    std::uint32_t run_inside = run_visible - open_count - run_across;
    const std::uint32_t appended = run_visible;
    unsigned gone = 0;  // the open objects found OUTSIDE, gathered at the front of `open`
    for (unsigned o = 0; o < open_count; o += W) {
      const unsigned count = static_cast<unsigned>(smaller(W, open_count - o));
      std::uint32_t outside, crossing;
      resolve(open + o, count, outside, crossing);
      for (unsigned l = 0; l < count; ++l) {
        const std::size_t at = open[o + l] - run;
        const std::uint32_t bit = 1u << (at % W);
        if (outside >> l & 1u) {
          run_visible_bits[at / W] &= ~bit;
          --run_visible;
          open[gone++] = open[o + l];  // (read above: gone <= o + l)
        } else if (crossing >> l & 1u) {
          if (out.classes) crossing_bits[at / W] |= bit;
        } else {
          ++run_inside;
        }
      }
    }
    counts.visible += run_visible;
    counts.inside += run_inside;
    if (out.classes) {
      ChunkOutput classes_only;
      classes_only.classes = out.classes;
      ChunkCounts unused;
      for (std::size_t i = run, b = 0; i < run_end; i += W, ++b)
        emit(i, begin, static_cast<unsigned>(smaller(W, end - i)), ~run_visible_bits[b], crossing_bits[b], classes_only,
             unused);
    }
    if (!out.ids) continue;
    const bool dense = run_visible * kDenseShare > run_end - run;
    // Every vector's visible lanes appended from `bits`, none skipped: a test per vector would
    // mispredict about once per 70 objects.
    auto list_run = [&] {
      std::uint32_t* ids = out.ids;
      for (std::size_t i = run, b = 0; i < run_end; i += W, ++b)
        ids = append_ids(ids, static_cast<std::uint32_t>(i), run_visible_bits[b]);
    };
    if (appending) {
      if (gone > kRemovedAtMost)
        list_run();  // many gone: listed again from the bits
      else if (gone)
        remove_ids(out.ids, appended, open, gone);
      if (out.runs) out.runs[run_index] = run_visible | (dense ? kListedDense : 0u);
    } else if (dense && listed_by_runs) {  // no ids: its vectors' visible lanes are in `bits`
      out.runs[run_index] = kDenseRun | run_visible;
      continue;
    } else {
      list_run();
      if (out.runs) out.runs[run_index] = run_visible;
    }
    out.ids += run_visible;
  }
  return counts;
}

}  // namespace
}  // namespace CULLPIPE_SIMD_NS
}  // namespace cullpipe::fast::detail
