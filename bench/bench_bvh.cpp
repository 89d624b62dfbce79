// bench_bvh: BVH builders and hierarchical culling, measured in one run, medians of repeats.
//
// Part "build": for each builder and object count, the median build time (one thread, after an
// untimed build), objects per second and the tree's SAH cost, also as a ratio to binned SAH's
// cost.
// Part "cull": flat against hierarchical culling of the same objects, on the CPU (scalar
// reference vs scalar traversal; fast::CpuCuller vs fast::CpuBvhCuller, both writing the
// visible list) and on the GPU (flat pass vs hierarchical pass, timestamps), with the camera's
// field of view chosen so that about 1%, 10%, 50%, ... of the objects are visible. Every
// hierarchical answer is checked: CPU traversal == flat reference, GPU and fast CPU == CPU
// traversal (classes or list, and test counts; the fast CPU hierarchy's counts against the
// scalar traversal with its range_objects, whose node and object tests get their own columns).
//
// Part "build" also times the binned SAH build on every core against one thread, interleaved.
//
// usage: bench_bvh [--part build|cull|all] [--sizes 1000,...] [--builders a,b|all] [--threads T]
//                  [--cull-size N] [--leaf-size L] [--fractions 0.01,0.1,0.5] [--repeats R] [--device NAME]
//                  [--json FILE]
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <nlohmann/json.hpp>
#include <sstream>
#include <string>
#include <vector>

#include "bench_util.hpp"
#include "cullpipe/bvh/builders.hpp"
#include "cullpipe/bvh/bvh.hpp"
#include "cullpipe/core/thread_pool.hpp"
#include "cullpipe/cull/cpu_bvh_culler.hpp"
#include "cullpipe/cull/cpu_culler.hpp"
#include "cullpipe/cull/reference.hpp"
#include "cullpipe/gpu/bvh_culler.hpp"
#include "cullpipe/gpu/gpu_culler.hpp"
#include "cullpipe/scene/generators.hpp"
#include "cullpipe/vulkan/context.hpp"

using namespace cullpipe;
using namespace cullpipe::bench;

namespace {

// Not a registry name: binned SAH through a BinnedSahBuilder kept between builds.
const char* const kReusedBuilder = "binned-sah (reused)";

// Largest n each builder is run at (quadratic and cubic builders are oracles, not tools).
std::size_t size_limit(const std::string& builder) {
  if (builder == "agglomerative-brute") return 1000;
  if (builder == "agglomerative-pq") return 20000;
  return SIZE_MAX;
}

nlohmann::json bench_builders(const std::vector<std::size_t>& sizes, std::vector<std::string> builders,
                              int repeats_override) {
  if (builders.empty() || (builders.size() == 1 && builders[0] == "all")) {
    builders.clear();
    for (const bvh::BuilderInfo& b : bvh::builders()) builders.emplace_back(b.name);
  }
  // binned SAH is also measured through a BinnedSahBuilder that keeps its memory, right after it.
  if (const auto it = std::find(builders.begin(), builders.end(), "binned-sah");
      it != builders.end() && std::find(builders.begin(), builders.end(), kReusedBuilder) == builders.end())
    builders.insert(it + 1, kReusedBuilder);
  std::printf("BVH builders: uniform random scene, leaves of <= 4, one thread, median build time\n\n");
  std::printf("%-26s %9s %8s %11s %9s %10s %11s\n", "builder", "N", "repeats", "build ms", "Mobj/s", "SAH cost",
              "SAH/binned");
  nlohmann::json cells = nlohmann::json::array();
  for (std::size_t n : sizes) {
    const std::vector<Aabb> boxes = world_aabbs(generate_scene(SceneKind::Uniform, n, 7));
    double binned_cost = 0.0;
    for (const std::string& name : builders) {
      if (n > size_limit(name)) continue;
      const int reps = repeats_override > 0
                           ? repeats_override
                           : int(std::clamp<std::size_t>(2'000'000 / std::max<std::size_t>(n, 1), 3, 25));
      std::vector<double> times;
      bvh::Tree tree;
      if (name == kReusedBuilder) {
        // An engine's per-frame rebuild: one BinnedSahBuilder and one tree kept between builds
        // (the untimed first build allocates their memory).
        bvh::BinnedSahBuilder builder;
        builder.build(boxes, {}, tree);
        for (int r = 0; r < reps; ++r) {
          const auto t0 = Clock::now();
          builder.build(boxes, {}, tree);
          times.push_back(since(t0));
        }
      } else {
        // One untimed build first: the first build in a process also faults in its fresh
        // memory (later builds may reuse the allocator's pages, or not).
        tree = bvh::build(name, boxes);
        for (int r = 0; r < reps; ++r) {
          const auto t0 = Clock::now();
          tree = bvh::build(name, boxes);
          times.push_back(since(t0));
        }
      }
      if (const std::string why = bvh::check_tree(tree, boxes); !why.empty()) {
        std::fprintf(stderr, "bench_bvh: %s built an invalid tree at n = %zu: %s\n", name.c_str(), n, why.c_str());
        std::exit(1);
      }
      const double t = median(times), cost = bvh::metrics(tree).sah_cost;
      if (name == "binned-sah") binned_cost = cost;
      const double ratio = binned_cost > 0 ? cost / binned_cost : 0.0;
      std::printf("%-26s %9zu %8d %11.2f %9.2f %10.2f %11.3f\n", name.c_str(), n, reps, t / 1e6, double(n) / t * 1e3,
                  cost, ratio);
      std::fflush(stdout);
      cells.push_back({{"builder", name},
                       {"n", n},
                       {"build_ns", t},
                       {"objects_per_s", double(n) / t * 1e9},
                       {"sah_cost", cost},
                       {"sah_over_binned", ratio}});
    }
    std::printf("\n");
  }
  return cells;
}

// The binned SAH build on one thread against the same build on `threads`, interleaved (so
// drift in the machine's memory state hits both), fresh and through a kept BinnedSahBuilder,
// with leaves of at most 4, of 1 and where the SAH says (at most 16); then PLOC likewise. The trees must be equal, node
// for node. What `pool`'s threads can do together on this machine: the throughput of a loop of dependent arithmetic (no
// memory traffic) on every thread at once, relative to one thread. On a virtual machine whose cores share physical ones
// with other work, this is well below the thread count, and no build can scale past it; median of repeats.
double machine_scaling(ThreadPool& pool) {
  auto spin = [](std::size_t) {
    volatile double x = 1.0;
    for (int i = 0; i < 20'000'000; ++i) x = x * 1.0000001 + 1e-9;
  };
  std::vector<double> ratios;
  for (int r = 0; r < 5; ++r) {
    auto t0 = Clock::now();
    spin(0);
    const double one = since(t0);
    t0 = Clock::now();
    pool.parallel_for(pool.size(), spin);
    ratios.push_back(double(pool.size()) * one / since(t0));
  }
  return median(ratios);
}

nlohmann::json bench_threaded(const std::vector<std::size_t>& sizes, unsigned threads, int repeats_override) {
  ThreadPool pool(threads);
  std::printf(
      "Binned SAH and PLOC on %u threads against one, uniform random scene, median build time (interleaved)\n\n",
      pool.size());
  const double ceiling = machine_scaling(pool);
  std::printf("The machine's own scaling (dependent arithmetic on every thread against one): %.2fx\n\n", ceiling);
  std::printf("%9s %5s %9s %12s %12s %8s %10s %s\n", "N", "leaf", "builder", "1 thread ms", "threads ms", "speedup",
              "SAH cost", "same tree");
  nlohmann::json cells = nlohmann::json::array();
  for (std::size_t n : sizes) {
    const std::vector<Aabb> boxes = world_aabbs(generate_scene(SceneKind::Uniform, n, 7));
    const int reps = repeats_override > 0
                         ? repeats_override
                         : int(std::clamp<std::size_t>(2'000'000 / std::max<std::size_t>(n, 1), 5, 25));
    // Leaves of at most 4, of 1, and where the SAH says (at most 16; built with leaves of 1,
    // then collapsed on one thread).
    for (const bvh::TopDownOptions options :
         {bvh::TopDownOptions{4, 16}, bvh::TopDownOptions{1, 16}, bvh::TopDownOptions{16, 16, true, 1.0f}})
      for (const bool reused : {false, true}) {
        const std::uint32_t leaf = options.max_leaf_size;
        const std::string leaf_name = (options.sah_leaves ? "sah" : "") + std::to_string(leaf);
        bvh::BinnedSahBuilder one_builder, many_builder;
        bvh::Tree one, many;
        const auto build_one = [&] {
          if (reused)
            one_builder.build(boxes, options, one);
          else
            one = bvh::build_binned_sah(boxes, options);
        };
        const auto build_many = [&] {
          if (reused)
            many_builder.build(boxes, options, many, &pool);
          else
            many = bvh::build_binned_sah(boxes, options, &pool);
        };
        build_one();  // untimed: the first build faults in its memory
        build_many();
        std::vector<double> t1, tn;
        for (int r = 0; r < reps; ++r) {
          auto t0 = Clock::now();
          build_one();
          t1.push_back(since(t0));
          t0 = Clock::now();
          build_many();
          tn.push_back(since(t0));
        }
        const bool same = one == many;
        const double a = median(t1), b = median(tn), cost = bvh::metrics(one).sah_cost;
        std::printf("%9zu %5s %9s %12.2f %12.2f %7.2fx %10.2f %s\n", n, leaf_name.c_str(), reused ? "reused" : "fresh",
                    a / 1e6, b / 1e6, a / b, cost, same ? "yes" : "NO");
        std::fflush(stdout);
        if (!same) throw std::runtime_error("the threaded build gave another tree at n = " + std::to_string(n));
        cells.push_back({{"n", n},
                         {"builder", "binned-sah"},
                         {"max_leaf_size", leaf},
                         {"sah_leaves", options.sah_leaves},
                         {"reused_builder", reused},
                         {"threads", pool.size()},
                         {"machine_scaling", ceiling},
                         {"one_thread_ns", a},
                         {"threaded_ns", b},
                         {"speedup", a / b},
                         {"sah_cost", cost}});
      }
    // PLOC (leaves of at most 4): its Morton sort, pool and final collapse stay on one thread.
    bvh::BuildOptions ploc;
    const auto build_ploc = [&](ThreadPool* p) {
      ploc.pool = p;
      return bvh::build("agglomerative-local", boxes, ploc);
    };
    std::vector<double> t1, tn;
    bool same = true;
    for (int r = 0; r < std::max(3, reps / 4); ++r) {
      auto t0 = Clock::now();
      const bvh::Tree one = build_ploc(nullptr);
      t1.push_back(since(t0));
      t0 = Clock::now();
      same &= build_ploc(&pool) == one;
      tn.push_back(since(t0));
    }
    const double a = median(t1), b = median(tn);
    std::printf("%9zu %5s %9s %12.2f %12.2f %7.2fx %10s %s\n", n, "4", "ploc", a / 1e6, b / 1e6, a / b, "",
                same ? "yes" : "NO");
    std::fflush(stdout);
    if (!same) throw std::runtime_error("threaded PLOC gave another tree at n = " + std::to_string(n));
    cells.push_back({{"n", n},
                     {"builder", "agglomerative-local"},
                     {"max_leaf_size", 4},
                     {"threads", pool.size()},
                     {"machine_scaling", ceiling},
                     {"one_thread_ns", a},
                     {"threaded_ns", b},
                     {"speedup", a / b}});
  }
  std::printf("\n");
  return cells;
}

nlohmann::json bench_cull(std::size_t n, std::uint32_t leaf_size, const std::vector<double>& fractions,
                          int repeats_override, const std::string& device, bool& all_agree) {
  vulkan::ContextOptions options;
  options.device_filter = device;
  vulkan::Context ctx(options);
  gpu::GpuCuller flat_culler(ctx);
  gpu::BvhCuller bvh_culler(ctx);
  const Scene scene = generate_scene(SceneKind::Uniform, n, 11);
  const std::vector<Aabb> boxes = world_aabbs(scene);
  const auto t0 = Clock::now();
  const bvh::FlatTree flat = bvh::flatten(bvh::build_binned_sah(boxes, {leaf_size, 16}));
  const double build_ns = since(t0);
  flat_culler.upload(std::span<const Aabb>(boxes));
  bvh_culler.upload(flat, boxes);
  fast::CpuCuller fast_flat;  // every core, the widest kernels
  fast::CpuBvhCuller fast_bvh;
  fast_flat.upload(std::span<const Aabb>(boxes));
  fast_bvh.upload(flat, boxes);
  fast::CpuCullOptions list_only;
  list_only.classes = false;
  std::vector<fast::CpuViewResult> fast_results;
  bvh::HierarchicalResult fast_h;
  std::vector<std::uint32_t> fast_ids;
  std::printf(
      "Hierarchical vs flat culling: %zu uniform random AABBs, binned-SAH tree, leaves of <= %u (%zu nodes, built in "
      "%.0f ms)\n",
      n, leaf_size, flat.nodes.size(), build_ns / 1e6);
  std::printf("gpu: %s, %s; fast CPU: %s kernels, %u threads\n\n", ctx.info().name.c_str(), ctx.info().driver.c_str(),
              std::string(fast::to_string(fast_flat.isa())).c_str(), fast_flat.threads());
  std::printf("%8s %8s %12s %12s %7s %12s %12s %7s %12s %12s %7s %11s %11s %11s %11s %6s\n", "target", "visible",
              "cpu flat ms", "cpu bvh ms", "cpu x", "fast flat ms", "fast bvh ms", "fast x", "gpu flat ms",
              "gpu bvh ms", "gpu x", "node tests", "obj tests", "fast nodes", "fast objs", "agree");
  nlohmann::json cells = nlohmann::json::array();
  const int reps = repeats_override > 0 ? repeats_override : 7;
  for (double fraction : fractions) {
    double achieved = 0.0;
    const Frustum f = frustum_for_fraction(
        scene.bounds(), boxes.size(), fraction,
        [&](const Frustum& v) { return bvh::cull_hierarchical(flat, boxes, v).visible; }, achieved);
    const Frustum views[1] = {f};
    std::vector<Classification> ref(boxes.size());
    std::vector<double> cpu_flat, cpu_bvh, fast_flat_ns, fast_bvh_ns, gpu_flat, gpu_bvh;
    bvh::HierarchicalResult h;
    reference::CullCounts counts;
    const gpu::CullOptions counters_only{false, false, 0};
    flat_culler.cull(views, counters_only);  // warm-up: pipelines compile on first use
    bvh_culler.cull(views, counters_only);
    for (int r = 0; r < reps; ++r) {  // interleaved, so drift hits all alike
      auto t = Clock::now();
      counts = reference::classify_all(std::span<const Aabb>(boxes), f, ref);
      cpu_flat.push_back(since(t));
      t = Clock::now();
      h = bvh::cull_hierarchical(flat, boxes, f);
      cpu_bvh.push_back(since(t));
      t = Clock::now();
      fast_flat.cull(views, list_only, fast_results);
      fast_flat_ns.push_back(since(t));
      t = Clock::now();
      fast_bvh.cull(f, {false, true}, fast_h, fast_ids);
      fast_bvh_ns.push_back(since(t));
      gpu_flat.push_back(flat_culler.cull(views, counters_only).timings.gpu_ns);
      gpu_bvh.push_back(bvh_culler.cull(views, counters_only).timings.gpu_ns);
    }
    const gpu::CullResult g = bvh_culler.cull(views);
    // The fast hierarchy's traversal (object ranges of small nodes): the scalar one's counts with its range_objects.
    const bvh::HierarchicalResult hf =
        bvh::cull_hierarchical(flat, boxes, f, {fast::CpuBvhCullOptions::default_range_objects(BvKind::Aabb)});
    std::vector<std::uint32_t> tree_order;  // the fast hierarchy's list: the visible ids in the tree's object order
    for (std::uint32_t o : flat.objects)
      if (is_visible(h.classes[o])) tree_order.push_back(o);
    const bool agree = h.classes == ref && g.views[0].classes == h.classes && g.views[0].node_tests == h.node_tests &&
                       g.views[0].object_tests == h.object_tests && g.views[0].counts == counts &&
                       fast_results[0].counts == counts && hf.classes == h.classes &&
                       fast_h.node_tests == hf.node_tests && fast_h.object_tests == hf.object_tests &&
                       fast_ids == tree_order;
    all_agree &= agree;
    const double cf = median(cpu_flat), cb = median(cpu_bvh), gf = median(gpu_flat), gb = median(gpu_bvh);
    const double ff = median(fast_flat_ns), fb = median(fast_bvh_ns);
    std::printf(
        "%7.1f%% %7.1f%% %12.3f %12.3f %7.2f %12.3f %12.3f %7.2f %12.3f %12.3f %7.2f %11zu %11zu %11zu %11zu %6s\n",
        100 * fraction, 100 * achieved, cf / 1e6, cb / 1e6, cf / cb, ff / 1e6, fb / 1e6, ff / fb, gf / 1e6, gb / 1e6,
        gf / std::max(gb, 1.0), h.node_tests, h.object_tests, hf.node_tests, hf.object_tests, agree ? "yes" : "NO");
    std::fflush(stdout);
    cells.push_back({{"target_fraction", fraction},
                     {"visible_fraction", achieved},
                     {"cpu_flat_ns", cf},
                     {"cpu_bvh_ns", cb},
                     {"fast_flat_ns", ff},
                     {"fast_bvh_ns", fb},
                     {"gpu_flat_ns", gf},
                     {"gpu_bvh_ns", gb},
                     {"node_tests", h.node_tests},
                     {"object_tests", h.object_tests},
                     {"fast_node_tests", hf.node_tests},
                     {"fast_object_tests", hf.object_tests},
                     {"fast_range_objects", fast::CpuBvhCullOptions::default_range_objects(BvKind::Aabb)},
                     {"agree", agree}});
  }
  return cells;
}

}  // namespace

int main(int argc, char** argv) {
  std::string part = "all", device, json_path;
  std::vector<std::size_t> sizes = {1000, 10000, 100000, 1000000};
  std::vector<std::string> builders = {"all"};
  std::vector<double> fractions = {0.01, 0.1, 0.5};
  std::size_t cull_size = 1000000;
  std::uint32_t leaf_size = bvh::kCullingLeafSize;  // (the cull part's tree)
  int repeats = 0;
  unsigned threads = 0;
  CLI::App app{"bench_bvh: every BVH builder's time and quality, and hierarchical against flat culling"};
  app.add_option("--part", part, "build | cull | all")
      ->capture_default_str()
      ->check(CLI::IsMember({"build", "cull", "all"}));
  add_counts_option(app, "--sizes", sizes, "Object counts of the build table")->default_str("1e3,1e4,1e5,1e6");
  app.add_option_function<std::string>(
         "--builders", [&](const std::string& v) { builders = split(v); }, "Builder names, or all")
      ->type_name("NAME,..")
      ->default_str("all");
  app.add_option_function<std::string>(
         "--cull-size", [&](const std::string& v) { cull_size = parse_counts(v, "--cull-size").front(); },
         "Objects in the cull table's scene")
      ->type_name("N")
      ->default_str("1e6");
  app.add_option("--leaf-size", leaf_size, "Most objects per leaf of the cull table's tree")
      ->capture_default_str()
      ->check(CLI::Range(1u, 1024u));
  add_fractions_option(app, "--fractions", fractions, "Visible fractions of the cull table")
      ->default_str("0.01,0.1,0.5");
  app.add_option("--repeats", repeats, "Repeats per cell (0: chosen by size)")
      ->capture_default_str()
      ->check(CLI::NonNegativeNumber);
  app.add_option("--threads", threads, "Threads of the threaded build table (0: every core)")
      ->capture_default_str()
      ->check(CLI::Range(0u, 256u));
  app.add_option("--device", device, "Vulkan device name substring");
  app.add_option("--json", json_path, "Write the results as JSON");
  bench::parse_command_line(app, argc, argv);
  nlohmann::json j;
  bool all_agree = true;
  try {
    if (part != "cull") j["build"] = bench_builders(sizes, builders, repeats);
    if (part != "cull") j["threaded_build"] = bench_threaded(sizes, threads, repeats);
    if (part != "build") j["cull"] = bench_cull(cull_size, leaf_size, fractions, repeats, device, all_agree);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "bench_bvh: %s\n", e.what());
    return 1;
  }
  if (!json_path.empty()) std::ofstream(json_path) << j.dump(2) << "\n";
  if (!all_agree) {
    std::fprintf(stderr, "bench_bvh: hierarchical and flat culling disagree in at least one cell\n");
    return 1;
  }
  return 0;
}
