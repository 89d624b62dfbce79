// `cullpipe bvh`: builds the scene's BVH with one, several or all builders and prints each
// tree's quality (SAH cost, volumes, depth, balance, leaf sizes) and build time.
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <nlohmann/json.hpp>
#include <ostream>
#include <sstream>
#include <string>

#include "cullpipe/app/backends.hpp"
#include "cullpipe/app/commands.hpp"
#include "cullpipe/app/guard.hpp"
#include "cullpipe/app/scene_source.hpp"
#include "cullpipe/bvh/builders.hpp"
#include "cullpipe/core/thread_pool.hpp"
#include "cullpipe/scene/json_util.hpp"

namespace cullpipe::app {

namespace {

std::string format_cost(float c) {
  std::ostringstream s;
  s << c;
  return s.str();
}

std::string fixed(double value, int digits) {
  char buf[48];
  std::snprintf(buf, sizeof buf, "%.*f", digits, value);
  return buf;
}

std::string right(const std::string& s, std::size_t width) {
  return s.size() >= width ? s : std::string(width - s.size(), ' ') + s;
}

std::string left(const std::string& s, std::size_t width) {
  return s.size() >= width ? s : s + std::string(width - s.size(), ' ');
}

}  // namespace

void list_bvh_builders(std::ostream& out) {
  for (const bvh::BuilderInfo& b : bvh::builders())
    out << left(std::string(b.name), 22) << "  " << b.description << "\n";
  out << left("top-down:axis=A,split=P,cost=C", 22)
      << "  any top-down combination: A = longest | distant | pca | best, P = median | mean | extent | binned,\n"
      << std::string(24, ' ') << "C = sah | volume | largest | overlap | separation | sah-guarded\n"
      << std::string(24, ' ') << "insertion builders take a +rotations suffix (e.g. insertion-bnb+rotations)\n";
}

int bvh_command(const BvhOptions& o, std::ostream& out, std::ostream& err) {
  return guarded(err, [&]() -> int {
    if (o.leaf_size == 0) throw InputError("--leaf-size must be at least 1");
    if (o.repeats == 0) throw InputError("--repeats must be at least 1");
    std::vector<std::pair<std::string, bool>> names;  // (builder, from "all")
    for (const std::string& name : o.builders) {
      if (name == "all") {
        for (const bvh::BuilderInfo& b : bvh::builders()) names.emplace_back(std::string(b.name), true);
      } else {
        names.emplace_back(name, false);
      }
    }
    if (names.empty()) throw InputError("--builder: no builder named");
    for (const auto& [name, from_all] : names) check_builder_name(name);  // before any work

    LoadedScene loaded = load_scene_source(o);
    const std::vector<Aabb> boxes = world_aabbs(loaded.scene, loaded.aabb_update);
    const std::size_t n = boxes.size();
    for (const auto& [name, from_all] : names)
      if (!from_all && n > builder_size_limit(name))
        throw InputError("--builder " + name + " is an exact oracle for at most " +
                         std::to_string(builder_size_limit(name)) + " objects; this scene has " + std::to_string(n));
    ThreadPool pool(o.threads);
    out << "cullpipe bvh: " << (loaded.scene.name.empty() ? loaded.source : loaded.scene.name) << " (" << loaded.source
        << "), " << n << " objects, leaves of <= " << o.leaf_size
        << (o.sah_leaves ? " where the SAH says (top-down builders, object cost " + format_cost(o.object_cost) + ")"
                         : std::string())
        << ", median of " << o.repeats << (o.repeats == 1 ? " build" : " builds")
        << "; binned-sah and agglomerative-local on " << pool.size()
        << (pool.size() == 1 ? " thread\n\n" : " threads\n\n");
    out << "  " << left("builder", 26)
        << "  build ms  Mobj/s   SAH cost     nodes    leaves  depth  leaf depth  balance  volume  overlap\n";

    nlohmann::json report = nlohmann::json::array();
    bvh::BuildOptions options;
    options.max_leaf_size = o.leaf_size;
    options.sah_leaves = o.sah_leaves;
    options.object_cost = o.object_cost;
    options.pool = &pool;
    for (const auto& [name, from_all] : names) {
      if (n > builder_size_limit(name)) {  // only from "all": named ones were checked above
        out << "  " << left(name, 26) << "  skipped: an exact oracle, for at most " << builder_size_limit(name)
            << " objects\n";
        continue;
      }
      std::vector<double> times;
      bvh::Tree tree;
      for (std::size_t k = 0; k < o.repeats; ++k) {
        const auto start = std::chrono::steady_clock::now();
        try {
          tree = bvh::build(name, boxes, options);
        } catch (const std::invalid_argument& e) {
          throw InputError(std::string("--builder: ") + e.what());
        }
        times.push_back(double(
            std::chrono::duration_cast<std::chrono::nanoseconds>(std::chrono::steady_clock::now() - start).count()));
      }
      std::nth_element(times.begin(), times.begin() + times.size() / 2, times.end());
      const double build_ns = times[times.size() / 2];
      if (const std::string why = bvh::check_tree(tree, boxes); !why.empty())
        throw std::logic_error("builder " + name + " made an invalid tree: " + why);
      const bvh::DetailedMetrics m = bvh::detailed_metrics(tree);
      const double rate = build_ns > 0 ? double(n) / build_ns * 1e3 : 0.0;  // million objects per second
      out << "  " << left(name, 26) << right(fixed(build_ns / 1e6, 2), 10) << right(fixed(rate, 2), 8)
          << right(fixed(m.basic.sah_cost, 2), 11) << right(std::to_string(m.basic.nodes), 10)
          << right(std::to_string(m.basic.leaves), 10) << right(std::to_string(m.basic.depth), 7)
          << right(fixed(m.mean_leaf_depth, 1), 12) << right(fixed(m.balance, 2), 9)
          << right(fixed(m.total_volume, 1), 8) << right(fixed(m.overlap_volume, 2), 9) << "\n";
      nlohmann::json histogram = nlohmann::json::object();
      for (std::size_t k = 0; k < m.leaf_sizes.size(); ++k)
        if (m.leaf_sizes[k]) histogram[std::to_string(k)] = m.leaf_sizes[k];
      report.push_back({{"builder", name},
                        {"build_ns", build_ns},
                        {"sah_cost", m.basic.sah_cost},
                        {"nodes", m.basic.nodes},
                        {"leaves", m.basic.leaves},
                        {"depth", m.basic.depth},
                        {"max_leaf_size", m.basic.max_leaf_size},
                        {"mean_leaf_depth", m.mean_leaf_depth},
                        {"balance", m.balance},
                        {"total_volume", m.total_volume},
                        {"overlap_volume", m.overlap_volume},
                        {"leaf_sizes", histogram}});
    }
    out << "\n  SAH cost: traversal 1 per inner node + 1 per object in a leaf, weighted by area / root area.\n"
        << "  volume, overlap: sums of node volumes and of sibling overlaps, / root volume. balance: depth / (log2 "
           "leaves + 1).\n";
    if (!o.json_path.empty()) {
      nlohmann::json j;
      j["scene"] = loaded.scene.name;
      j["source"] = loaded.source;
      j["objects"] = n;
      j["leaf_size"] = o.leaf_size;
      j["sah_leaves"] = o.sah_leaves;
      j["object_cost"] = o.object_cost;
      j["repeats"] = o.repeats;
      j["builders"] = report;
      json_util::write_file_atomic(o.json_path, j.dump(2) + "\n");
    }
    return kExitOk;
  });
}

}  // namespace cullpipe::app
