#include <iostream>
#include <iterator>
#include <nlohmann/json.hpp>

#include "cullpipe/app/backends.hpp"
#include "cullpipe/app/commands.hpp"
#include "cullpipe/app/guard.hpp"
#include "cullpipe/scene/cull_case_io.hpp"
#include "cullpipe/scene/json_util.hpp"

namespace cullpipe::app {
namespace {

// Classifies the volumes of one kind (positions `where` in the case) and scatters the
// results into cpu/gpu [view][volume] tables.
template <class Volume>
std::size_t classify_kind(const CullCase& c, Backend backend, GpuBackend& gpu_backend,
                          std::vector<std::vector<Classification>>& cpu, std::vector<std::vector<Classification>>& gpu,
                          std::vector<std::string>& reports) {
  std::vector<Volume> volumes;
  std::vector<std::size_t> where;
  for (std::size_t i = 0; i < c.volumes.size(); ++i)
    if (const Volume* v = std::get_if<Volume>(&c.volumes[i])) {
      volumes.push_back(*v);
      where.push_back(i);
    }
  if (volumes.empty()) return 0;
  // No warm-up: classify reports no timings. Reports name volumes by their index in the file.
  BackendResults r = cull_on_backends<Volume>(volumes, c.frusta, backend, gpu_backend, /*warm_up=*/false, where);
  for (std::size_t v = 0; v < c.frusta.size(); ++v)
    for (std::size_t k = 0; k < volumes.size(); ++k) {
      if (!r.cpu.empty()) cpu[v][where[k]] = r.cpu[v][k];
      if (!r.gpu.empty()) gpu[v][where[k]] = r.gpu[v][k];
    }
  for (std::string& m : r.mismatch_reports) reports.push_back(std::move(m));
  return r.mismatches;
}

nlohmann::json names(const std::vector<Classification>& classes) {
  nlohmann::json a = nlohmann::json::array();
  for (Classification c : classes) a.push_back(std::string(to_string(c)));
  return a;
}

}  // namespace

int classify_command(const ClassifyOptions& o, std::ostream& out, std::ostream& err) {
  return guarded(err, [&]() -> int {
    std::string text, source = o.input_path;
    if (o.input_path == "-") {
      source = "<stdin>";
      text.assign(std::istreambuf_iterator<char>(std::cin), std::istreambuf_iterator<char>());
    } else {
      text = json_util::read_file(o.input_path);
    }
    const CullCase c = parse_cull_case(text, source);

    const std::size_t views = c.frusta.size(), n = c.volumes.size();
    std::vector<std::vector<Classification>> cpu, gpu;
    if (o.backend != Backend::Gpu) cpu.assign(views, std::vector<Classification>(n));
    if (o.backend != Backend::Cpu) gpu.assign(views, std::vector<Classification>(n));
    GpuBackend gpu_backend{o.device, nullptr, nullptr};
    std::vector<std::string> reports;
    std::size_t mismatches = 0;
    mismatches += classify_kind<Aabb>(c, o.backend, gpu_backend, cpu, gpu, reports);
    mismatches += classify_kind<Obb>(c, o.backend, gpu_backend, cpu, gpu, reports);
    mismatches += classify_kind<Sphere>(c, o.backend, gpu_backend, cpu, gpu, reports);

    auto view_json = [&](std::size_t v) {
      nlohmann::json j = nlohmann::json::object();
      if (!cpu.empty()) j["cpu"] = names(cpu[v]);
      if (!gpu.empty()) j["gpu"] = names(gpu[v]);
      return j;
    };
    nlohmann::json result;
    if (c.multi_view) {
      result["views"] = nlohmann::json::array();
      for (std::size_t v = 0; v < views; ++v) result["views"].push_back(view_json(v));
    } else {
      result = view_json(0);
    }
    if (mismatches) {
      result["mismatches"] = mismatches;
      out << result.dump(2) << "\n";
      err << "error: " << source << ": GPU and CPU disagree (" << mismatches << " differences):\n";
      for (const std::string& m : reports) err << "  " << m << "\n";
      return kExitMismatch;
    }
    out << result.dump(2) << "\n";
    return kExitOk;
  });
}

}  // namespace cullpipe::app
