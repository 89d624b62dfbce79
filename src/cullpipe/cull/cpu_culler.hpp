#pragma once
#include <cstddef>
#include <cstdint>
#include <memory>
#include <optional>
#include <span>
#include <string_view>
#include <vector>

#include "cullpipe/cull/instances.hpp"
#include "cullpipe/cull/reference.hpp"
#include "cullpipe/geom/aabb.hpp"
#include "cullpipe/geom/bv_kind.hpp"
#include "cullpipe/geom/classification.hpp"
#include "cullpipe/geom/frustum.hpp"
#include "cullpipe/geom/obb.hpp"
#include "cullpipe/geom/sphere.hpp"

/// The fast CPU path: structure-of-arrays bounds, SIMD kernels chosen at run time (AVX-512,
/// AVX2, or a portable 4-lane build of the same source), and every core through a thread pool.
/// Results equal cullpipe::reference bit for bit: most objects are settled by bounds proved to
/// give its answer (docs/numerics.md, Settling bounds), the rest get its float operations in its
/// order, without contraction.
namespace cullpipe::fast {

/// Instruction set of the kernels (Avx2: AVX2 with FMA).
enum class Isa : std::uint8_t { Portable, Avx2, Avx512 };

std::string_view to_string(Isa isa);
/// "portable", "avx2" or "avx512"; nullopt otherwise.
std::optional<Isa> parse_isa(std::string_view name);
/// True when the kernels for `isa` are built into this binary and the CPU runs them.
bool isa_supported(Isa isa);
/// Every instruction set isa_supported() accepts, narrowest first (Portable always): to run a
/// check or a benchmark on each.
std::vector<Isa> supported_isas();
/// The widest supported instruction set. The environment variable CULLPIPE_ISA
/// (portable / avx2 / avx512) lowers it, e.g. to compare kernels or to test the portable path.
Isa best_isa();

struct CpuCullerConfig {
  /// Threads culling, the calling thread included; 0 means every core
  /// (std::thread::hardware_concurrency()).
  unsigned threads = 0;
  /// Kernels to use; default best_isa(). One the machine cannot run throws invalid_argument.
  std::optional<Isa> isa;
  /// Objects per task handed to a thread; rounded up to a multiple of 16.
  std::size_t chunk_objects = 16384;
};

struct CpuCullOptions {
  bool classes = true;      ///< fill CpuViewResult::classes
  bool visible_ids = true;  ///< fill CpuViewResult::visible_ids
};

/// One view's result.
struct CpuViewResult {
  std::vector<Classification> classes;     ///< per object, in object order (with options.classes)
  std::vector<std::uint32_t> visible_ids;  ///< INSIDE/INTERSECTING objects, in object order
  reference::CullCounts counts;
};

/// Flat frustum culling on the CPU. upload() converts the volumes to structure-of-arrays once;
/// cull() classifies them against any number of views. Not thread-safe (it is itself
/// parallel); one call at a time.
class CpuCuller {
 public:
  explicit CpuCuller(const CpuCullerConfig& config = {});
  ~CpuCuller();
  CpuCuller(const CpuCuller&) = delete;
  CpuCuller& operator=(const CpuCuller&) = delete;

  /// Replaces the volumes to cull. Throws std::length_error beyond 2^32 - 1 objects (ids are
  /// 32-bit). Volumes are not validated: like the reference, any floats give a defined answer
  /// (a NaN distance compares false, so it never rejects).
  void upload(std::span<const Aabb> volumes);
  void upload(std::span<const Obb> volumes);
  void upload(std::span<const Sphere> volumes);

  /// Instances (cull/instances.hpp): every object placed by instance_volume on the culling
  /// threads and stored as upload(volumes) stores it, so the answers are the reference's on
  /// instances.world_volumes(); objects are reported by slot.
  void upload(const InstanceSet<Aabb>& instances);
  void upload(const InstanceSet<Obb>& instances);
  void upload(const InstanceSet<Sphere>& instances);
  /// Places again only `slots` (InstanceSet::changed_slots(), ascending) of the set uploaded
  /// last; when its size has changed, every object (the arrays' layout follows the count).
  /// Throws std::invalid_argument, changing nothing, when no instances of the kind were
  /// uploaded, a slot is out of range or the slots are not ascending.
  void update(const InstanceSet<Aabb>& instances, std::span<const std::uint32_t> slots);
  void update(const InstanceSet<Obb>& instances, std::span<const std::uint32_t> slots);
  void update(const InstanceSet<Sphere>& instances, std::span<const std::uint32_t> slots);

  /// One result per view, each as a pass of its own would give. Several views (a camera and
  /// its shadow cascades, two eyes) share the pass: each chunk of objects is read from memory
  /// once and culled for every view while it is in the cache.
  std::vector<CpuViewResult> cull(std::span<const Frustum> views, const CpuCullOptions& options = {});
  /// The same, into `results` (resized to the view count), reusing its vectors' storage so a
  /// pass per frame allocates nothing once sizes settle.
  void cull(std::span<const Frustum> views, const CpuCullOptions& options, std::vector<CpuViewResult>& results);

  /// Reads every uploaded bound once with the same kernels' loads and threads but no tests,
  /// and returns the OR of the bits read, for benchmarks: chunk by chunk, one array after
  /// another. With `streamed_only`, only what a pass reads for every object (the centres and
  /// bounds, 16 bytes per object); else every byte the upload stored.
  std::uint32_t touch_bounds(bool streamed_only = false);
  /// Reads the centres and bounds in a pass's own order: chunk by chunk, the four arrays side
  /// by side, a vector of each per step (without the pass's software prefetch, which a plain
  /// read does not gain from). With touch_bounds(true), the memory floor of a pass: whichever
  /// of the two orders the machine reads faster.
  std::uint32_t touch_streamed_side_by_side();
  /// What a pass reads of every object (touch_bounds(true)): centre x y z and bound.
  static constexpr std::size_t kStreamedBytesPerObject = 4 * sizeof(float);
  /// Reads `data` the same way (e.g. a buffer larger than the caches, to measure read
  /// bandwidth). `data` is read in whole vectors: its size should be a multiple of 16.
  std::uint32_t touch(std::span<const float> data);
  /// Bytes per object of the uploaded bounds: 48 AABB, 80 OBB and 20 sphere: 16 of centre and
  /// plane bound in arrays, read for every object, and a 32- or 64-byte record (spheres: the
  /// radius) read for the few objects the bound leaves open.
  std::size_t bytes_per_object() const;

  BvKind kind() const { return kind_; }
  std::size_t object_count() const { return count_; }
  Isa isa() const { return isa_; }
  unsigned threads() const;

 private:
  // Stores `volumes` as Columns float arrays and RecordFloats floats per object:
  // `store(volume, columns, i)` writes object i; columns[Columns] is the first record.
  template <std::size_t Columns, std::size_t RecordFloats, class Volume, class Store>
  void upload_columns(std::span<const Volume> volumes, Store store);

  template <class Volume>
  void place(const InstanceSet<Volume>& set, std::span<const std::uint32_t> slots);  // empty: every slot
  template <class Volume>
  void upload_instances(const InstanceSet<Volume>& set);
  template <class Volume>
  void update_instances(const InstanceSet<Volume>& set, std::span<const std::uint32_t> slots);

  struct Impl;
  std::unique_ptr<Impl> impl_;
  bool instanced_ = false;
  BvKind kind_ = BvKind::Aabb;
  std::size_t count_ = 0;
  Isa isa_ = Isa::Portable;
};

}  // namespace cullpipe::fast
