#pragma once
// Internal interface between the CPU cullers (cpu_culler.cpp, cpu_bvh_culler.cpp) and the SIMD
// kernels. The kernels are compiled three times from simd_kernels.inl with different
// instruction sets (simd_portable.cpp, simd_avx2.cpp, simd_avx512.cpp), so this header holds
// plain data only: a kernel translation unit must not instantiate inline functions it shares
// with the rest of the program (the linker could keep its AVX-512 copy for everyone).
#include <cstddef>
#include <cstdint>

namespace cullpipe::fast::detail {

/// Up to six planes, one array per component (a copy of Frustum::active()).
struct PlaneSet {
  std::uint32_t count = 0;
  float nx[6]{}, ny[6]{}, nz[6]{}, d[6]{};
  /// Every normal's length is at most 1 + 2^-20, so the AABB, OBB and sphere bounds hold for these planes.
  bool unit_normals = false;
  /// The share of the settling margin that depends on the plane, 2^-18 |d| rounded up,
  /// at its largest over the planes (NaN past |d| = 2^120: nothing is settled).
  float max_margin = 0.0f;
  /// The factors of the lower bounds packed in the bounds (CentreArrays in simd_settle.inl):
  /// the smallest |n|_1 (boxes) and |n|_2 (OBBs) over the planes, rounded down, times 2^-8
  /// (1 - 2^-12); 0 (nothing settled by them) where that smallest norm is outside [1/2, 2].
  float lower_scale_l1 = 0.0f, lower_scale_l2 = 0.0f;
  /// Plane mirror_plane's normal is within kMirrorSlack of minus plane mirror_base's, in every
  /// component (a frustum's far and near planes; the first such pair): the flat kernels take
  /// its centre distance as (d[base] + d[plane]) - (the base plane's distance), one
  /// subtraction for three fused multiply-adds. The bounds allow for it (the proof:
  /// CentreArrays in simd_settle.inl).
  bool mirrored = false;
  std::uint32_t mirror_base = 0, mirror_plane = 0;
};

/// How far from exact negation a mirrored plane's normal may be, per component (PlaneSet).
constexpr float kMirrorSlack = 0x1p-21f;

/// Structure-of-arrays bounds; every array holds at least `padded` floats (a multiple of 16),
/// the padding zeros, so a kernel may load whole vectors past the last object.
/// AABBs in two parts, as OBBs below: centres and bounds as arrays, read for every box, and
/// per box a 32-byte record (min x y z, max x y z, two spare), read only for the boxes that the
/// bound does not settle.
constexpr std::size_t kAabbRecordFloats = 8;
struct AabbArrays {
  const float *c_x, *c_y, *c_z;  ///< centres, (min + max) / 2 rounded to nearest
  /// Per box, aabb_plane_bound(): with PlaneSet::max_margin, covers the half diagonal and every
  /// rounding of the reference's and the kernel's distances (or NaN: no bound); its lowest 8
  /// bits a lower bound (pack_lower).
  const float* bound;
  const float* records;  ///< box i at records + i * kAabbRecordFloats, 32-byte aligned
};
/// OBBs in two parts: the centres and bounds as arrays, read for every object, and per object
/// a 64-byte record (kObbRecordFloats floats: centre, axes u0 u1 u2, half extents, a spare),
/// read only for the objects that the bound does not settle.
constexpr std::size_t kObbRecordFloats = 16;
struct ObbArrays {
  const float *c_x, *c_y, *c_z;
  /// Per object, obb_plane_bound(): with PlaneSet::max_margin, at least |r| for the reference's
  /// projected radius r against any plane of a unit-normal PlaneSet, plus every rounding of the
  /// reference's and the kernel's centre distances (or NaN: no bound); its lowest 8 bits a
  /// lower bound (pack_lower).
  const float* bound;
  const float* records;  ///< object i at records + i * kObbRecordFloats, 64-byte aligned
};
/// Spheres: the centres and bounds, read for every sphere, and the radii, read only for the
/// spheres that the bound does not settle (and for all of them without unit normals).
struct SphereArrays {
  const float *c_x, *c_y, *c_z;
  /// Per sphere, sphere_plane_bound(): with PlaneSet::max_margin, covers |radius| and every
  /// rounding of the reference's and the kernel's centre distances (or NaN: no bound); its
  /// lowest 8 bits a lower bound (pack_lower).
  const float* bound;
  const float* radius;
};

/// A chunk is culled in runs of kRunObjects objects from its first (the last may be shorter).
constexpr std::size_t kRunObjects = 4096;
/// ChunkOutput::runs: the run wrote no ids, only its vectors' visible lanes (the low bits are
/// its visible count).
constexpr std::uint32_t kDenseRun = 0x80000000u;
/// ChunkOutput::runs: the run wrote its ids although it was dense (it guessed sparse), so the
/// next pass's guess for it is dense.
constexpr std::uint32_t kListedDense = 0x40000000u;
/// ChunkOutput::runs: the visible count (or the number of ids written) under the flags.
constexpr std::uint32_t kRunCount = 0x3fffffffu;
/// A run is dense when more than 1 / kDenseShare of its objects are visible.
constexpr std::size_t kDenseShare = 4;

/// Where one chunk's results go. `classes` (may be null) receives the class of objects
/// begin..end-1 at classes[0..]; `ids` (may be null) receives the ids of visible objects in
/// object order, at most end - begin of them, and may write up to 16 values beyond them.
/// With `runs`, `bits` and `ids`: every run sets bits[v] = the visible lanes of each of its
/// vectors (v = the vector's first object - begin, over the kernel's lanes; scratch where the
/// run wrote its ids), so `bits` holds a word per vector of the chunk. A run either writes its
/// ids and sets runs[r] = their number, | kListedDense if it was dense, or, if it was dense,
/// writes none and sets runs[r] = kDenseRun | its visible count. Which of the two a run does
/// follows a guess from what runs[r] holds on entry (the last pass's word, or 0; so `runs`
/// must hold initialised words): a run guessed sparse (neither flag) appends its ids as it
/// classifies its vectors, where the work overlaps the loads (where the bound can settle
/// objects: unit normals and a finite margin); one guessed dense, or one whose objects the
/// bound cannot settle, lists them afterwards only if it was sparse. Without `bits` every run
/// writes its ids. Listing the ids of dense runs from their bits,
/// straight into the result (ExpandKernel), writes them once instead of twice (to `ids`, then
/// copied).
struct ChunkOutput {
  std::uint8_t* classes = nullptr;
  std::uint32_t* ids = nullptr;
  std::uint32_t* bits = nullptr;
  std::uint32_t* runs = nullptr;
};

/// Visible (INSIDE + INTERSECTING) and INSIDE objects of one chunk.
struct ChunkCounts {
  std::uint32_t visible = 0;
  std::uint32_t inside = 0;
};

using AabbKernel = ChunkCounts (*)(const AabbArrays&, std::size_t begin, std::size_t end, const PlaneSet&, ChunkOutput);
using ObbKernel = ChunkCounts (*)(const ObbArrays&, std::size_t begin, std::size_t end, const PlaneSet&, ChunkOutput);
using SphereKernel = ChunkCounts (*)(const SphereArrays&, std::size_t begin, std::size_t end, const PlaneSet&,
                                     ChunkOutput);

/// Reads data[begin..end) (end - begin a multiple of 16 or data padded to one) and returns
/// the OR of its bits: the memory floor of a pass, with the same loads as the kernels.
using TouchKernel = std::uint32_t (*)(const float* data, std::size_t begin, std::size_t end);
/// Reads columns[0..3][begin..end) side by side, a vector of each per step (as the flat
/// kernels read the centres and bounds; end - begin a multiple of 16 or the columns padded to
/// one) and returns the OR of their bits.
using TouchColumnsKernel = std::uint32_t (*)(const float* const* columns, std::size_t begin, std::size_t end);

/// A hierarchy as the walk kernels read it (fast::CpuBvhCuller builds it on upload from a
/// bvh::FlatTree; object order is the flat tree's). Nodes are stored in sibling pairs: the two
/// children of a node are the two halves (slots 2p and 2p + 1) of one 64-byte pair record p, so
/// that testing them reads one cache line; pair 0 holds the root alone (slot 0).
constexpr std::size_t kWalkNodeFloats = 8;  ///< per slot: min x y z, object count (bits), max x y z, link (bits)
/// A slot's link: kWalkLeaf for a leaf, else the pair holding its children (first child in
/// the low slot).
constexpr std::uint32_t kWalkLeaf = 0x80000000u;
constexpr std::size_t kWalkAabbColumns = 6;    ///< min x y z, max x y z
constexpr std::size_t kWalkObbColumns = 15;    ///< centre, u0, u1, u2, half extents
constexpr std::size_t kWalkSphereColumns = 4;  ///< centre, radius
/// The volumes' blocks: kWalkBlock objects in tree order, each of their columns 16 floats (a
/// cache line), so an object range is one run of lines in memory, not a run per column.
constexpr std::size_t kWalkBlock = 16;
/// Where column 0 of the object at tree position `pos` lies in WalkTree::blocks, for volumes of
/// `columns` columns (column c is kWalkBlock floats further on).
constexpr std::size_t walk_block_offset(std::size_t pos, std::size_t columns) {
  return pos / kWalkBlock * kWalkBlock * columns + pos % kWalkBlock;
}
struct WalkTree {
  const float* nodes;  ///< kWalkNodeFloats per slot, 2 slots per pair
  /// The volumes in tree order, in blocks (kWalk*Columns columns for the kind): column c of
  /// the object at tree position k is blocks[(k / kWalkBlock) * kWalkBlock * columns +
  /// c * kWalkBlock + k % kWalkBlock]; the last block is padded with zeros, and one more
  /// block of zeros follows it (a prefetch of the block after a nonempty range stays in the
  /// array).
  const float* blocks;
  const std::uint32_t* ids;     ///< per object in tree order, its id
  std::uint32_t range_objects;  ///< bvh::TraversalOptions::range_objects
  /// The node test of hierarchies over OBBs and spheres (bvh::classify_masked_margin): the
  /// bvh constants, passed in so this header stays plain data.
  float margin_scale, margin_floor, margin_limit;
};

/// The subtree a walk tests: its root's slot, the root's object range [first, first + count),
/// and the planes its parent straddles.
struct WalkRoot {
  std::uint32_t slot, first, count, mask;
};

/// Where one walk's results go. `classes` (may be null): per object id. `marks` (may be
/// null): a bitmap of (the subtree's object count + 63) / 64 words, zero, that gets bit p set
/// for each visible object at position first + p of the subtree's range. `work`:
/// walk_work_words(work_capacity) words, work_capacity at least the number of nodes in the
/// subtree.
struct WalkOutput {
  std::uint8_t* classes = nullptr;
  std::uint64_t* marks = nullptr;
  std::uint32_t* work = nullptr;
  std::size_t work_capacity = 0;
};

/// The words of WalkOutput::work a walk of `nodes` nodes needs: its list of pairs to test
/// (pair, planes, first object) and its list of object ranges to test (first, count, planes),
/// each with room for a vector store of up to 16 lanes past its end.
constexpr std::size_t walk_work_words(std::size_t nodes) { return 6 * (nodes + 16); }

/// What one walk did: bvh::cull_hierarchical's counts for its subtree.
struct WalkCounts {
  std::uint64_t node_tests = 0, object_tests = 0;
  std::uint32_t visible = 0, inside = 0;
};

/// Tests the subtree at `root`, as bvh::cull_hierarchical does: the same tests, results and counts (not in the same
/// order).
using WalkKernel = WalkCounts (*)(const WalkTree&, WalkRoot, const PlaneSet&, WalkOutput);

/// Writes first + W v + l for every set bit l of bits[v], v = 0..vectors-1 (W: the kernels'
/// lanes), in that order from `out`, and returns the new end; never writes at or past out_end.
using ExpandKernel = std::uint32_t* (*)(const std::uint32_t* bits, std::size_t vectors, std::uint32_t first,
                                        std::uint32_t* out, const std::uint32_t* out_end);

/// Writes from[64 w + l] for every set bit l of marks[w], w = 0..words-1, in that order from
/// `out`, and returns the new end; never writes at or past out_end. Reads from[0, 64 (words -
/// 1)) whole (the words before the last) and, in the last word, only where a bit is set.
/// Leaves every word of marks zero.
using ListKernel = std::uint32_t* (*)(std::uint64_t* marks, std::size_t words, const std::uint32_t* from,
                                      std::uint32_t* out, const std::uint32_t* out_end);

struct KernelTable {
  AabbKernel aabb;
  ObbKernel obb;
  SphereKernel sphere;
  TouchKernel touch;
  TouchColumnsKernel touch_columns;
  WalkKernel walk_aabb, walk_obb, walk_sphere;
  ExpandKernel expand;
  ListKernel list;
  unsigned lanes;
};

KernelTable portable_kernels();
#if defined(CULLPIPE_HAVE_X86_KERNELS)
KernelTable avx2_kernels();
KernelTable avx512_kernels();
#endif

}  // namespace cullpipe::fast::detail
