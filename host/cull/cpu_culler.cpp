#include "cull/cpu_culler.hpp"

#include <algorithm>
#include <cstdlib>
#include <cstring>
#include <limits>
#include <new>
#include <stdexcept>
#include <string>

#include "cull/simd_kernels.hpp"
#include "cull/thread_pool.hpp"

namespace cullpipe::fast {

namespace {

constexpr std::size_t kPad = 16;  // widest vector, in floats

bool cpu_runs(Isa isa) {
#if defined(CULLPIPE_HAVE_X86_KERNELS)
  switch (isa) {
    case Isa::Portable: return true;
    case Isa::Avx2: return __builtin_cpu_supports("avx2");
    case Isa::Avx512: return __builtin_cpu_supports("avx512f");
  }
  return false;
#else
  return isa == Isa::Portable;
#endif
}

detail::KernelTable kernels(Isa isa) {
#if defined(CULLPIPE_HAVE_X86_KERNELS)
  if (isa == Isa::Avx512) return detail::avx512_kernels();
  if (isa == Isa::Avx2) return detail::avx2_kernels();
#endif
  (void)isa;
  return detail::portable_kernels();
}

detail::PlaneSet plane_set(const Frustum& f) {
  detail::PlaneSet s;
  s.count = static_cast<std::uint32_t>(std::min<std::size_t>(f.plane_count, 6));
  for (std::uint32_t k = 0; k < s.count; ++k) {
    s.nx[k] = f.planes[k].normal.x;
    s.ny[k] = f.planes[k].normal.y;
    s.nz[k] = f.planes[k].normal.z;
    s.d[k] = f.planes[k].d;
  }
  return s;
}

struct AlignedFree {
  void operator()(float* p) const { ::operator delete[](p, std::align_val_t(64)); }
};

}  // namespace

std::string_view to_string(Isa isa) {
  switch (isa) {
    case Isa::Portable: return "portable";
    case Isa::Avx2: return "avx2";
    case Isa::Avx512: return "avx512";
  }
  return "invalid";
}

std::optional<Isa> parse_isa(std::string_view name) {
  for (Isa isa : {Isa::Portable, Isa::Avx2, Isa::Avx512})
    if (name == to_string(isa)) return isa;
  return std::nullopt;
}

bool isa_supported(Isa isa) { return cpu_runs(isa); }

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
  std::size_t padded = 0;     // floats per component array
  std::unique_ptr<float[], AlignedFree> data;
  std::size_t capacity = 0;   // floats allocated
  std::vector<const float*> arrays;  // component array starts
  // Per view: visible ids, written per chunk into slots of chunk + kPad, then gathered.
  std::vector<std::unique_ptr<std::uint32_t[]>> scratch;
  std::size_t scratch_size = 0;
  std::vector<detail::ChunkCounts> chunk_counts;  // [view * chunks + chunk]
  std::vector<std::size_t> offsets;               // [view * chunks + chunk]: first id's index in the view's list
  std::vector<detail::PlaneSet> planes;           // per view of the current pass

  /// Room for `components` arrays of `count` objects, each padded with zeros to kPad.
  float* reserve(std::size_t components, std::size_t count) {
    padded = (count + kPad - 1) / kPad * kPad + kPad;  // one spare vector: loads past the end stay in bounds
    const std::size_t floats = components * padded;
    if (floats > capacity) {
      data.reset(static_cast<float*>(::operator new[](floats * sizeof(float), std::align_val_t(64))));
      capacity = floats;
    }
    arrays.resize(components);
    for (std::size_t c = 0; c < components; ++c) {
      arrays[c] = data.get() + c * padded;
      std::memset(data.get() + c * padded + count, 0, (padded - count) * sizeof(float));  // the padding
    }
    return data.get();
  }
  float* column(std::size_t c) { return data.get() + c * padded; }
};

CpuCuller::CpuCuller(const CpuCullerConfig& config) {
  isa_ = config.isa.value_or(best_isa());
  if (!isa_supported(isa_))
    throw std::invalid_argument("CpuCuller: this CPU (or build) cannot run the " + std::string(to_string(isa_)) + " kernels");
  impl_ = std::make_unique<Impl>(config.threads);
  impl_->table = kernels(isa_);
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

template <std::size_t Columns, class Volume, class Store>
void CpuCuller::upload_columns(std::span<const Volume> volumes, Store store) {
  check_count(volumes.size());
  count_ = 0;  // stays 0 if the allocation fails
  impl_->reserve(Columns, volumes.size());
  float* c[Columns];
  for (std::size_t k = 0; k < Columns; ++k) c[k] = impl_->column(k);
  for (std::size_t i = 0; i < volumes.size(); ++i) store(volumes[i], c, i);
  kind_ = kind_of<Volume>();
  count_ = volumes.size();
}

void CpuCuller::upload(std::span<const Aabb> volumes) {
  upload_columns<6>(volumes, [](const Aabb& b, float* const* c, std::size_t i) {
    c[0][i] = b.min.x, c[1][i] = b.min.y, c[2][i] = b.min.z;
    c[3][i] = b.max.x, c[4][i] = b.max.y, c[5][i] = b.max.z;
  });
}

void CpuCuller::upload(std::span<const Obb> volumes) {
  upload_columns<15>(volumes, [](const Obb& b, float* const* c, std::size_t i) {
    for (int a = 0; a < 3; ++a) {
      c[a][i] = b.center[a];
      c[3 + a][i] = b.basis[0][a];
      c[6 + a][i] = b.basis[1][a];
      c[9 + a][i] = b.basis[2][a];
      c[12 + a][i] = b.half_extents[a];
    }
  });
}

void CpuCuller::upload(std::span<const Sphere> volumes) {
  upload_columns<4>(volumes, [](const Sphere& s, float* const* c, std::size_t i) {
    c[0][i] = s.center.x, c[1][i] = s.center.y, c[2][i] = s.center.z;
    c[3][i] = s.radius;
  });
}

std::size_t CpuCuller::bytes_per_object() const { return impl_->arrays.size() * sizeof(float); }

namespace {
/// Reads `columns` arrays of `floats` floats each, split into tasks, and ORs what it read.
std::uint32_t touch_columns(ThreadPool& pool, const detail::KernelTable& table, std::span<const float* const> columns,
                            std::size_t floats, std::size_t per_task) {
  const std::size_t per_column = std::max<std::size_t>(1, (floats + per_task - 1) / per_task);
  std::vector<std::uint32_t> bits(columns.size() * per_column, 0);
  pool.parallel_for(bits.size(), [&](std::size_t t) {
    const float* data = columns[t / per_column];
    const std::size_t begin = t % per_column * per_task, end = std::min(floats, begin + per_task);
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
  const float* column = data.data();
  return touch_columns(impl_->pool, impl_->table, {&column, 1}, data.size(), impl_->chunk * 8);
}

std::uint32_t CpuCuller::touch_bounds() {
  // Only the objects' floats (rounded up to a vector), not the spare padding.
  const std::size_t used = (count_ + kPad - 1) / kPad * kPad;
  return count_ ? touch_columns(impl_->pool, impl_->table, impl_->arrays, used, impl_->chunk) : 0;
}

std::vector<CpuViewResult> CpuCuller::cull(std::span<const Frustum> views, const CpuCullOptions& options) {
  std::vector<CpuViewResult> results;
  cull(views, options, results);
  return results;
}

void CpuCuller::cull(std::span<const Frustum> views, const CpuCullOptions& options, std::vector<CpuViewResult>& results) {
  Impl& m = *impl_;
  const std::size_t n = count_;
  const std::size_t chunks = std::max<std::size_t>(1, (n + m.chunk - 1) / m.chunk);
  results.resize(views.size());
  std::vector<detail::PlaneSet>& planes = m.planes;  // kept between calls: no allocation per pass
  planes.clear();
  for (const Frustum& f : views) planes.push_back(plane_set(f));
  // Each chunk writes its visible ids at its own slot of the view's scratch (chunk size plus
  // the kernels' slack), then they are gathered in chunk order.
  const std::size_t slot = m.chunk + kPad;
  if (options.visible_ids) {
    const std::size_t need = chunks * slot;
    if (m.scratch_size < need) {  // too small: reallocate every view's
      m.scratch.clear();
      m.scratch_size = need;
    }
    if (m.scratch.size() < views.size()) m.scratch.resize(views.size());
    for (std::size_t v = 0; v < views.size(); ++v)
      if (!m.scratch[v]) m.scratch[v].reset(new std::uint32_t[m.scratch_size]);
  }
  for (CpuViewResult& r : results) {
    if (options.classes) r.classes.resize(n);
    else r.classes.clear();
  }
  m.chunk_counts.assign(views.size() * chunks, {});

  const std::vector<const float*>& a = m.arrays;
  m.pool.parallel_for(views.size() * chunks, [&](std::size_t task) {
    const std::size_t v = task / chunks, chunk = task % chunks;
    const std::size_t begin = chunk * m.chunk, end = std::min(n, begin + m.chunk);
    if (begin >= end) return;
    detail::ChunkOutput out;
    if (options.classes) out.classes = reinterpret_cast<std::uint8_t*>(results[v].classes.data()) + begin;
    if (options.visible_ids) out.ids = m.scratch[v].get() + chunk * slot;
    detail::ChunkCounts& counts = m.chunk_counts[task];
    switch (kind_) {
      case BvKind::Aabb:
        counts = m.table.aabb(detail::AabbArrays{a[0], a[1], a[2], a[3], a[4], a[5]}, begin, end, planes[v], out);
        break;
      case BvKind::Obb:
        counts = m.table.obb(detail::ObbArrays{a[0], a[1], a[2], a[3], a[4], a[5], a[6], a[7], a[8], a[9], a[10], a[11], a[12],
                                               a[13], a[14]},
                             begin, end, planes[v], out);
        break;
      case BvKind::Sphere:
        counts = m.table.sphere(detail::SphereArrays{a[0], a[1], a[2], a[3]}, begin, end, planes[v], out);
        break;
    }
  });

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
    const std::uint32_t* ids = m.scratch[v].get() + chunk * slot;
    std::copy(ids, ids + m.chunk_counts[task].visible, results[v].visible_ids.data() + m.offsets[task]);
  });
}

}  // namespace cullpipe::fast
