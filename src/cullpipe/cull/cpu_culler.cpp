#include "cullpipe/cull/cpu_culler.hpp"

#include <algorithm>
#include <bit>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <limits>
#include <new>
#include <stdexcept>
#include <string>

#include "cullpipe/core/aligned_vector.hpp"
#include "cullpipe/core/thread_pool.hpp"
#include "cullpipe/cull/kernel_select.hpp"
#include "cullpipe/cull/simd_kernels.hpp"
#include "cullpipe/geom/plane_bounds.hpp"

namespace cullpipe::fast {

namespace {

constexpr std::size_t kPad = 16;  // widest vector, in floats

bool cpu_runs(Isa isa) {
#if defined(CULLPIPE_HAVE_X86_KERNELS)
  switch (isa) {
    case Isa::Portable:
      return true;
    case Isa::Avx2:
      return __builtin_cpu_supports("avx2") && __builtin_cpu_supports("fma");
    case Isa::Avx512:
      return __builtin_cpu_supports("avx512f");
  }
  return false;
#else
  return isa == Isa::Portable;
#endif
}

}  // namespace

namespace detail {

KernelTable kernels(Isa isa) {
#if defined(CULLPIPE_HAVE_X86_KERNELS)
  if (isa == Isa::Avx512) return avx512_kernels();
  if (isa == Isa::Avx2) return avx2_kernels();
#endif
  (void)isa;
  return portable_kernels();
}

PlaneSet plane_set(const Frustum& f) {
  PlaneSet s;
  s.count = static_cast<std::uint32_t>(std::min<std::size_t>(f.plane_count, 6));
  s.unit_normals = true;
  for (std::uint32_t k = 0; k < s.count; ++k) {
    const glm::vec3 n = f.planes[k].normal;
    s.nx[k] = n.x;
    s.ny[k] = n.y;
    s.nz[k] = n.z;
    s.d[k] = f.planes[k].d;
    s.unit_normals = s.unit_normals && plane_bounds::unit_normal(n);
    const float margin = plane_bounds::plane_margin(f.planes[k].d);
    s.max_margin = std::isnan(s.max_margin) || std::isnan(margin) ? std::numeric_limits<float>::quiet_NaN()
                                                                  : std::max(s.max_margin, margin);
  }
  // The lower bounds' factors: the smallest |n|_1 and |n|_2, rounded down, times 2^-8 (q's step) and
  // 1 - 2^-12 (the packing's 2^-15 and the kernel's roundings); 0 outside [1/2, 2].
  // Proof: docs/numerics.md, Packed lower bounds.
  double l1 = std::numeric_limits<double>::infinity(), l2 = l1;
  for (std::uint32_t k = 0; k < s.count; ++k) {
    const double x = s.nx[k], y = s.ny[k], z = s.nz[k];
    l1 = std::min(l1, std::fabs(x) + std::fabs(y) + std::fabs(z));
    l2 = std::min(l2, std::sqrt(x * x + y * y + z * z));
  }
  auto scale = [](double c) {
    return c >= 0.5 && c <= 2.0 ? static_cast<float>(c * (1.0 - 0x1p-30) * 0x1p-8 * (1.0 - 0x1p-12)) : 0.0f;
  };
  s.lower_scale_l1 = scale(l1);
  s.lower_scale_l2 = scale(l2);
  // The first pair of planes whose normals are opposite within kMirrorSlack (float sums are
  // exact in double). The bounds cover its distance: docs/numerics.md, Mirrored planes.
  auto mirrors = [&](std::uint32_t i, std::uint32_t j) {
    return std::fabs(double(s.nx[i]) + s.nx[j]) <= kMirrorSlack &&
           std::fabs(double(s.ny[i]) + s.ny[j]) <= kMirrorSlack && std::fabs(double(s.nz[i]) + s.nz[j]) <= kMirrorSlack;
  };
  for (std::uint32_t i = 0; i < s.count && !s.mirrored; ++i)
    for (std::uint32_t j = i + 1; j < s.count && !s.mirrored; ++j)
      if (mirrors(i, j)) s.mirrored = true, s.mirror_base = i, s.mirror_plane = j;
  return s;
}

}  // namespace detail

namespace {

/// Frees the columns, which come from CacheLineAllocator: on a cache line, and from 4 MiB on
/// a 2 MiB boundary with transparent huge pages asked for.
struct ColumnsFree {
  std::size_t floats = 0;
  void operator()(float* p) const { cullpipe::detail::CacheLineAllocator<float>().deallocate(p, floats); }
};

}  // namespace

std::string_view to_string(Isa isa) {
  switch (isa) {
    case Isa::Portable:
      return "portable";
    case Isa::Avx2:
      return "avx2";
    case Isa::Avx512:
      return "avx512";
  }
  return "invalid";
}

std::optional<Isa> parse_isa(std::string_view name) {
  for (Isa isa : {Isa::Portable, Isa::Avx2, Isa::Avx512})
    if (name == to_string(isa)) return isa;
  return std::nullopt;
}

bool isa_supported(Isa isa) { return cpu_runs(isa); }

std::vector<Isa> supported_isas() {
  std::vector<Isa> isas;
  for (Isa isa : {Isa::Portable, Isa::Avx2, Isa::Avx512})
    if (cpu_runs(isa)) isas.push_back(isa);
  return isas;
}

Isa best_isa() {
  Isa best = Isa::Portable;
  for (Isa isa : {Isa::Avx2, Isa::Avx512})
    if (cpu_runs(isa)) best = isa;
  if (const char* env = std::getenv("CULLPIPE_ISA")) {
    const std::optional<Isa> wanted = parse_isa(env);
    if (wanted && static_cast<int>(*wanted) < static_cast<int>(best)) best = *wanted;
  }
  return best;
}

struct CpuCuller::Impl {
  explicit Impl(unsigned threads) : pool(threads) {}
  ThreadPool pool;
  detail::KernelTable table{};
  std::size_t chunk = 16384;
  std::size_t padded = 0;  // floats per component array
  std::unique_ptr<float[], ColumnsFree> data;
  std::size_t capacity = 0;          // floats allocated
  std::vector<const float*> arrays;  // component array starts
  float* records = nullptr;          // per-object records after the arrays (OBB), or null
  std::size_t record_size = 0;       // floats per record
  // Per view: visible ids, written per chunk into slots of chunk + kPad, then gathered; and
  // per chunk the visible lanes of every run's vectors and a word per run (ChunkOutput).
  std::vector<std::unique_ptr<std::uint32_t[]>> scratch, bits, runs;
  std::size_t scratch_size = 0, bits_size = 0, runs_size = 0;
  std::vector<detail::ChunkCounts> chunk_counts;  // [view * chunks + chunk]
  std::vector<std::size_t> offsets;               // [view * chunks + chunk]: first id's index in the view's list
  std::vector<detail::PlaneSet> planes;           // per view of the current pass

  /// Room for `components` arrays of `count` objects, each padded with zeros to kPad, then
  /// `record_floats` floats per object (records, also padded with zeros).
  float* reserve(std::size_t components, std::size_t count, std::size_t record_floats = 0) {
    padded = (count + kPad - 1) / kPad * kPad + kPad;  // one spare vector: loads past the end stay in bounds
    const std::size_t floats = (components + record_floats) * padded;
    if (floats > capacity) {
      data = std::unique_ptr<float[], ColumnsFree>(cullpipe::detail::CacheLineAllocator<float>().allocate(floats),
                                                   ColumnsFree{floats});
      capacity = floats;
    }
    arrays.resize(components);
    for (std::size_t c = 0; c < components; ++c) {
      arrays[c] = data.get() + c * padded;
      std::memset(data.get() + c * padded + count, 0, (padded - count) * sizeof(float));  // the padding
    }
    record_size = record_floats;
    records = record_floats ? data.get() + components * padded : nullptr;  // 64-byte aligned: padded % 16 == 0
    if (records) std::memset(records + count * record_floats, 0, (padded - count) * record_floats * sizeof(float));
    return data.get();
  }
  float* column(std::size_t c) { return data.get() + c * padded; }
};

CpuCuller::CpuCuller(const CpuCullerConfig& config) {
  isa_ = config.isa.value_or(best_isa());
  if (!isa_supported(isa_))
    throw std::invalid_argument("CpuCuller: this CPU (or build) cannot run the " + std::string(to_string(isa_)) +
                                " kernels");
  impl_ = std::make_unique<Impl>(config.threads);
  impl_->table = detail::kernels(isa_);
  impl_->chunk = std::max<std::size_t>(kPad, (config.chunk_objects + kPad - 1) / kPad * kPad);
}

CpuCuller::~CpuCuller() = default;

unsigned CpuCuller::threads() const { return impl_->pool.size(); }

namespace {
void check_count(std::size_t n) {
  if (n > std::numeric_limits<std::uint32_t>::max())
    throw std::length_error("CpuCuller: " + std::to_string(n) + " objects; object ids are 32-bit (at most 4294967295)");
}
}  // namespace

template <std::size_t Columns, std::size_t RecordFloats, class Volume, class Store>
void CpuCuller::upload_columns(std::span<const Volume> volumes, Store store) {
  check_count(volumes.size());
  count_ = 0;  // stays 0 if the allocation fails
  impl_->reserve(Columns, volumes.size(), RecordFloats);
  float* c[Columns + 1];
  for (std::size_t k = 0; k < Columns; ++k) c[k] = impl_->column(k);
  c[Columns] = impl_->records;
  // In tasks of `chunk` objects on the pool: the bounds take a few square roots per object.
  const std::size_t n = volumes.size(), per_task = impl_->chunk;
  impl_->pool.parallel_for((n + per_task - 1) / per_task, [&](std::size_t t) {
    const plane_bounds::NearestNoFlush mode;
    const std::size_t end = std::min(n, (t + 1) * per_task);
    for (std::size_t i = t * per_task; i < end; ++i) store(volumes[i], c, i);
  });
  kind_ = kind_of<Volume>();
  count_ = volumes.size();
}

namespace {

// How upload() stores object i of each kind: its centre and packed plane bound in the arrays,
// the rest in its record (as the kernels read them).
constexpr std::size_t kAabbColumns = 4, kObbColumns = 4, kSphereColumns = 5;
void store_aabb(const Aabb& b, float* const* c, std::size_t i) {
  glm::vec3 centre;
  c[3][i] = plane_bounds::pack_lower(plane_bounds::aabb_plane_bound(b, centre), plane_bounds::aabb_lower(b));
  c[0][i] = centre.x, c[1][i] = centre.y, c[2][i] = centre.z;
  float* record = c[4] + i * detail::kAabbRecordFloats;  // as cull_aabb's resolve reads it
  for (int a = 0; a < 3; ++a) {
    record[a] = b.min[a];
    record[3 + a] = b.max[a];
  }
  record[6] = record[7] = 0.0f;
}
void store_obb(const Obb& b, float* const* c, std::size_t i) {
  c[0][i] = b.center.x, c[1][i] = b.center.y, c[2][i] = b.center.z;
  c[3][i] = plane_bounds::pack_lower(plane_bounds::obb_plane_bound(b), plane_bounds::obb_lower(b));
  float* record = c[4] + i * detail::kObbRecordFloats;  // as classify_obb_records reads it
  for (int a = 0; a < 3; ++a) {
    record[a] = b.center[a];
    record[3 + a] = b.basis[0][a];
    record[6 + a] = b.basis[1][a];
    record[9 + a] = b.basis[2][a];
    record[12 + a] = b.half_extents[a];
  }
  record[15] = 0.0f;
}
void store_sphere(const Sphere& s, float* const* c, std::size_t i) {
  c[0][i] = s.center.x, c[1][i] = s.center.y, c[2][i] = s.center.z;
  c[3][i] = plane_bounds::pack_lower(plane_bounds::sphere_plane_bound(s), plane_bounds::sphere_lower(s));
  c[4][i] = s.radius;
}

}  // namespace

void CpuCuller::upload(std::span<const Aabb> volumes) {
  static_assert(detail::kAabbRecordFloats == 8);
  upload_columns<kAabbColumns, detail::kAabbRecordFloats>(volumes, store_aabb);
  instanced_ = false;
}

void CpuCuller::upload(std::span<const Obb> volumes) {
  static_assert(detail::kObbRecordFloats == 16);
  instanced_ = false;
  upload_columns<kObbColumns, detail::kObbRecordFloats>(volumes, store_obb);
}

void CpuCuller::upload(std::span<const Sphere> volumes) {
  upload_columns<kSphereColumns, 0>(volumes, store_sphere);
  instanced_ = false;
}

template <class Volume>
void CpuCuller::place(const InstanceSet<Volume>& set, std::span<const std::uint32_t> slots) {
  constexpr std::size_t columns = std::is_same_v<Volume, Aabb>  ? kAabbColumns
                                  : std::is_same_v<Volume, Obb> ? kObbColumns
                                                                : kSphereColumns;
  float* c[columns + 1];
  for (std::size_t k = 0; k < columns; ++k) c[k] = impl_->column(k);
  c[columns] = impl_->records;
  const std::size_t n = slots.empty() ? set.size() : slots.size(), per_task = impl_->chunk;
  impl_->pool.parallel_for((n + per_task - 1) / per_task, [&](std::size_t t) {
    const plane_bounds::NearestNoFlush mode;
    const std::size_t end = std::min(n, (t + 1) * per_task);
    for (std::size_t k = t * per_task; k < end; ++k) {
      const std::size_t i = slots.empty() ? k : slots[k];
      if constexpr (std::is_same_v<Volume, Aabb>)
        store_aabb(set.world_volume(i), c, i);
      else if constexpr (std::is_same_v<Volume, Obb>)
        store_obb(set.world_volume(i), c, i);
      else
        store_sphere(set.world_volume(i), c, i);
    }
  });
}

template <class Volume>
void CpuCuller::upload_instances(const InstanceSet<Volume>& set) {
  check_count(set.size());
  count_ = 0;  // stays 0 if the allocation fails
  instanced_ = false;
  if constexpr (std::is_same_v<Volume, Aabb>)
    impl_->reserve(kAabbColumns, set.size(), detail::kAabbRecordFloats);
  else if constexpr (std::is_same_v<Volume, Obb>)
    impl_->reserve(kObbColumns, set.size(), detail::kObbRecordFloats);
  else
    impl_->reserve(kSphereColumns, set.size(), 0);
  place(set, {});
  kind_ = kind_of<Volume>();
  count_ = set.size();
  instanced_ = true;
}

template <class Volume>
void CpuCuller::update_instances(const InstanceSet<Volume>& set, std::span<const std::uint32_t> slots) {
  if (!instanced_ || kind_ != kind_of<Volume>())
    throw std::invalid_argument("CpuCuller::update: no " + std::string(cullpipe::to_string(kind_of<Volume>())) +
                                " instances were uploaded (call upload(instances) first)");
  set.check_slots(slots, "CpuCuller::update");
  if (set.size() != count_) {  // the arrays' stride follows the count: every object again
    upload_instances(set);
    return;
  }
  if (!slots.empty()) place(set, slots);
}

void CpuCuller::upload(const InstanceSet<Aabb>& instances) { upload_instances(instances); }
void CpuCuller::upload(const InstanceSet<Obb>& instances) { upload_instances(instances); }
void CpuCuller::upload(const InstanceSet<Sphere>& instances) { upload_instances(instances); }
void CpuCuller::update(const InstanceSet<Aabb>& instances, std::span<const std::uint32_t> slots) {
  update_instances(instances, slots);
}
void CpuCuller::update(const InstanceSet<Obb>& instances, std::span<const std::uint32_t> slots) {
  update_instances(instances, slots);
}
void CpuCuller::update(const InstanceSet<Sphere>& instances, std::span<const std::uint32_t> slots) {
  update_instances(instances, slots);
}

std::size_t CpuCuller::bytes_per_object() const { return (impl_->arrays.size() + impl_->record_size) * sizeof(float); }

namespace {
/// Reads each of `spans`, split into tasks of at most `per_task` floats, and ORs what it read.
std::uint32_t touch_spans(ThreadPool& pool, const detail::KernelTable& table,
                          std::span<const std::span<const float>> spans, std::size_t per_task) {
  std::vector<std::size_t> first_task(spans.size() + 1, 0);  // tasks of span s: first_task[s] ..
  for (std::size_t s = 0; s < spans.size(); ++s)
    first_task[s + 1] = first_task[s] + std::max<std::size_t>(1, (spans[s].size() + per_task - 1) / per_task);
  std::vector<std::uint32_t> bits(first_task.back(), 0);
  pool.parallel_for(bits.size(), [&](std::size_t t) {
    const std::size_t s =
        static_cast<std::size_t>(std::upper_bound(first_task.begin(), first_task.end(), t) - first_task.begin()) - 1;
    const float* data = spans[s].data();
    const std::size_t begin = (t - first_task[s]) * per_task, end = std::min(spans[s].size(), begin + per_task);
    if (begin >= end) return;
    const std::size_t whole = begin + (end - begin) / kPad * kPad;
    std::uint32_t b = table.touch(data, begin, whole);
    for (std::size_t i = whole; i < end; ++i) {
      std::uint32_t word;
      std::memcpy(&word, data + i, sizeof word);
      b |= word;
    }
    bits[t] = b;
  });
  std::uint32_t all = 0;
  for (std::uint32_t b : bits) all |= b;
  return all;
}
}  // namespace

std::uint32_t CpuCuller::touch(std::span<const float> data) {
  return touch_spans(impl_->pool, impl_->table, {&data, 1}, impl_->chunk * 8);
}

std::uint32_t CpuCuller::touch_bounds(bool streamed_only) {
  // Only the objects' floats (rounded up to a vector), not the spare padding.
  if (!count_) return 0;
  const std::size_t used = (count_ + kPad - 1) / kPad * kPad;
  std::vector<std::span<const float>> spans;
  constexpr std::size_t kStreamed = kStreamedBytesPerObject / sizeof(float);  // the first columns: centre x y z, bound
  for (std::size_t c = 0; c < impl_->arrays.size() && (!streamed_only || c < kStreamed); ++c)
    spans.emplace_back(impl_->arrays[c], used);
  if (impl_->records && !streamed_only) spans.emplace_back(impl_->records, used * impl_->record_size);
  return touch_spans(impl_->pool, impl_->table, spans, impl_->chunk);
}

std::uint32_t CpuCuller::touch_streamed_side_by_side() {
  if (!count_) return 0;
  const std::size_t used = (count_ + kPad - 1) / kPad * kPad, chunks = (used + impl_->chunk - 1) / impl_->chunk;
  static_assert(kStreamedBytesPerObject == 4 * sizeof(float));  // the first four arrays
  const float* const columns[4] = {impl_->arrays[0], impl_->arrays[1], impl_->arrays[2], impl_->arrays[3]};
  std::vector<std::uint32_t> bits(chunks, 0);
  impl_->pool.parallel_for(chunks, [&](std::size_t t) {
    const std::size_t begin = t * impl_->chunk;
    bits[t] = impl_->table.touch_columns(columns, begin, std::min(used, begin + impl_->chunk));
  });
  std::uint32_t all = 0;
  for (std::uint32_t b : bits) all |= b;
  return all;
}

std::vector<CpuViewResult> CpuCuller::cull(std::span<const Frustum> views, const CpuCullOptions& options) {
  std::vector<CpuViewResult> results;
  cull(views, options, results);
  return results;
}

void CpuCuller::cull(std::span<const Frustum> views, const CpuCullOptions& options,
                     std::vector<CpuViewResult>& results) {
  Impl& m = *impl_;
  const std::size_t n = count_;
  const std::size_t chunks = std::max<std::size_t>(1, (n + m.chunk - 1) / m.chunk);
  results.resize(views.size());
  std::vector<detail::PlaneSet>& planes = m.planes;  // kept between calls: no allocation per pass
  planes.clear();
  for (const Frustum& f : views) planes.push_back(detail::plane_set(f));
  // Each chunk writes its visible ids at its own slot of the view's scratch (chunk size plus
  // the kernels' slack), then they are gathered in chunk order.
  // Dense runs (more than a quarter visible) leave their ids out of the scratch: they are
  // listed from the runs' bits straight into the result, each id written once instead of
  // twice (sparse runs write too few ids for it to matter).
  const std::size_t slot = m.chunk + kPad;
  const std::size_t bits_slot = m.chunk / m.table.lanes,
                    runs_slot = (m.chunk + detail::kRunObjects - 1) / detail::kRunObjects;
  if (options.visible_ids) {
    auto room = [&](std::vector<std::unique_ptr<std::uint32_t[]>>& buffers, std::size_t& size, std::size_t need) {
      if (size < need) {  // too small: reallocate every view's
        buffers.clear();
        size = need;
      }
      if (buffers.size() < views.size()) buffers.resize(views.size());
      for (std::size_t v = 0; v < views.size(); ++v)
        if (!buffers[v]) buffers[v].reset(new std::uint32_t[size]());  // zeros: the kernels read `runs` as a guess
    };
    room(m.scratch, m.scratch_size, chunks * slot);
    room(m.bits, m.bits_size, chunks * bits_slot);
    room(m.runs, m.runs_size, chunks * runs_slot);
  }
  for (CpuViewResult& r : results) {
    if (options.classes)
      r.classes.resize(n);
    else
      r.classes.clear();
  }
  m.chunk_counts.assign(views.size() * chunks, {});

  const std::vector<const float*>& a = m.arrays;
  auto chunk_end = [&](std::size_t begin) { return std::min(n, begin + m.chunk); };
  // View v's chunk `chunk`, task v * chunks + chunk of the counts and offsets.
  auto cull_chunk = [&](std::size_t v, std::size_t chunk) {
    const std::size_t task = v * chunks + chunk;
    const std::size_t begin = chunk * m.chunk, end = chunk_end(begin);
    if (begin >= end) return;
    detail::ChunkOutput out;
    if (options.classes) out.classes = reinterpret_cast<std::uint8_t*>(results[v].classes.data()) + begin;
    if (options.visible_ids) {
      out.ids = m.scratch[v].get() + chunk * slot;
      out.bits = m.bits[v].get() + chunk * bits_slot;
      out.runs = m.runs[v].get() + chunk * runs_slot;
    }
    detail::ChunkCounts& counts = m.chunk_counts[task];
    switch (kind_) {
      case BvKind::Aabb:
        counts = m.table.aabb(detail::AabbArrays{a[0], a[1], a[2], a[3], m.records}, begin, end, planes[v], out);
        break;
      case BvKind::Obb:
        counts = m.table.obb(detail::ObbArrays{a[0], a[1], a[2], a[3], m.records}, begin, end, planes[v], out);
        break;
      case BvKind::Sphere:
        counts = m.table.sphere(detail::SphereArrays{a[0], a[1], a[2], a[3], a[4]}, begin, end, planes[v], out);
        break;
    }
  };
  // Several views: each chunk read from memory once for all of them. With enough chunks to
  // keep every thread busy, a task is one chunk and every view in turn, its centres and bounds
  // (256 KiB) in the thread's L2 after the first; with fewer, a task is one chunk and one view,
  // tasks of one chunk next to each other, so that every thread works.
  const std::size_t view_count = views.size();
  if (view_count > 1 && chunks >= 4 * std::size_t(m.pool.size())) {
    m.pool.parallel_for(chunks, [&](std::size_t chunk) {
      for (std::size_t v = 0; v < view_count; ++v) cull_chunk(v, chunk);
    });
  } else {
    m.pool.parallel_for(view_count * chunks, [&](std::size_t t) { cull_chunk(t % view_count, t / view_count); });
  }

  m.offsets.assign(views.size() * chunks, 0);
  for (std::size_t v = 0; v < views.size(); ++v) {
    CpuViewResult& r = results[v];
    r.counts = {};
    for (std::size_t c = 0; c < chunks; ++c) {
      m.offsets[v * chunks + c] = r.counts.visible;
      r.counts.visible += m.chunk_counts[v * chunks + c].visible;
      r.counts.inside += m.chunk_counts[v * chunks + c].inside;
    }
    r.counts.intersecting = r.counts.visible - r.counts.inside;
    // resize, not clear + resize: a reused result only initialises what it grows by.
    r.visible_ids.resize(options.visible_ids ? r.counts.visible : 0);
  }
  if (!options.visible_ids) return;
  m.pool.parallel_for(views.size() * chunks, [&](std::size_t task) {
    const std::size_t v = task / chunks, chunk = task % chunks;
    const std::size_t begin = chunk * m.chunk, end = chunk_end(begin);
    if (begin >= end) return;
    const std::uint32_t* ids = m.scratch[v].get() + chunk * slot;
    const std::uint32_t* bits = m.bits[v].get() + chunk * bits_slot;
    const std::uint32_t* runs = m.runs[v].get() + chunk * runs_slot;
    std::uint32_t* out = results[v].visible_ids.data() + m.offsets[task];
    const std::uint32_t* const out_end = out + m.chunk_counts[task].visible;
    for (std::size_t run = begin, r = 0; run < end; run += detail::kRunObjects, ++r) {
      if (runs[r] & detail::kDenseRun) {
        const std::size_t vectors =
            (std::min(end, run + detail::kRunObjects) - run + m.table.lanes - 1) / m.table.lanes;
        out = m.table.expand(bits + (run - begin) / m.table.lanes, vectors, static_cast<std::uint32_t>(run), out,
                             out_end);
      } else {
        const std::uint32_t count = runs[r] & detail::kRunCount;
        out = std::copy(ids, ids + count, out);
        ids += count;
      }
    }
  });
}

}  // namespace cullpipe::fast
