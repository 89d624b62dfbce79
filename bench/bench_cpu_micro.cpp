// bench_cpu_micro: Google Benchmark micro benchmarks of the CPU culling paths, one object
// kind and size per benchmark: the scalar reference, the fast path per instruction set and
// thread count, and its memory floor (the same loads with no tests). Items/s = objects/s.
//
// usage: bench_cpu_micro [--benchmark_filter=REGEX] [--benchmark_repetitions=N] ...
#include <benchmark/benchmark.h>

#include <string>
#include <vector>

#include "cullpipe/cull/cpu_culler.hpp"
#include "cullpipe/cull/reference.hpp"
#include "cullpipe/scene/generators.hpp"

using namespace cullpipe;

namespace {

struct Data {
  std::vector<Aabb> boxes;
  std::vector<Obb> obbs;
  std::vector<Sphere> spheres;
  Frustum frustum;
};

// One uniform scene of a million objects seen by its own camera (about 60% visible), shared.
const Data& data() {
  static const Data d = [] {
    const Scene scene = generate_scene(SceneKind::Uniform, 1'000'000, 3);
    return Data{world_aabbs(scene), world_obbs(scene), world_spheres(scene),
                Frustum::from_view_proj(scene.camera.view_proj())};
  }();
  return d;
}

template <class Volume>
const std::vector<Volume>& volumes() {
  if constexpr (std::is_same_v<Volume, Aabb>)
    return data().boxes;
  else if constexpr (std::is_same_v<Volume, Obb>)
    return data().obbs;
  else
    return data().spheres;
}

template <class Volume>
void reference_cull(benchmark::State& state) {
  const std::span<const Volume> v(volumes<Volume>().data(), std::size_t(state.range(0)));
  std::vector<Classification> out(v.size());
  for (auto _ : state) benchmark::DoNotOptimize(reference::classify_all(v, data().frustum, out));
  state.SetItemsProcessed(state.iterations() * state.range(0));
}

/// range(0): objects; range(1): threads; range(2): fast::Isa.
template <class Volume>
void fast_cull(benchmark::State& state) {
  const fast::Isa isa = fast::Isa(state.range(2));
  if (!fast::isa_supported(isa)) {
    state.SkipWithError("instruction set not supported here");
    return;
  }
  fast::CpuCuller culler({unsigned(state.range(1)), isa});
  culler.upload(std::span<const Volume>(volumes<Volume>().data(), std::size_t(state.range(0))));
  std::vector<fast::CpuViewResult> results;
  for (auto _ : state) {
    culler.cull({&data().frustum, 1}, {}, results);
    benchmark::DoNotOptimize(results.data());
  }
  state.SetItemsProcessed(state.iterations() * state.range(0));
}

template <class Volume>
void fast_read_floor(benchmark::State& state) {
  fast::CpuCuller culler({unsigned(state.range(1))});
  culler.upload(std::span<const Volume>(volumes<Volume>().data(), std::size_t(state.range(0))));
  // What every pass reads of every object: centre and bound, 16 bytes.
  for (auto _ : state) benchmark::DoNotOptimize(culler.touch_bounds(true));
  state.SetItemsProcessed(state.iterations() * state.range(0));
  state.SetBytesProcessed(state.iterations() * state.range(0) * std::int64_t(fast::CpuCuller::kStreamedBytesPerObject));
}

void fast_args(benchmark::internal::Benchmark* b) {
  for (std::int64_t n : {10'000, 1'000'000})
    for (std::int64_t threads : {1, 2})
      for (fast::Isa isa : {fast::Isa::Portable, fast::Isa::Avx2, fast::Isa::Avx512})
        b->Args({n, threads, std::int64_t(isa)});
  b->ArgNames({"n", "threads", "isa"})->UseRealTime();
}

}  // namespace

BENCHMARK(reference_cull<Aabb>)->Arg(10'000)->Arg(1'000'000)->ArgName("n");
BENCHMARK(reference_cull<Obb>)->Arg(1'000'000)->ArgName("n");
BENCHMARK(reference_cull<Sphere>)->Arg(1'000'000)->ArgName("n");
BENCHMARK(fast_cull<Aabb>)->Apply(fast_args);
BENCHMARK(fast_cull<Obb>)->Apply(fast_args);
BENCHMARK(fast_cull<Sphere>)->Apply(fast_args);
BENCHMARK(fast_read_floor<Aabb>)->Args({1'000'000, 2})->ArgNames({"n", "threads"})->UseRealTime();

BENCHMARK_MAIN();
