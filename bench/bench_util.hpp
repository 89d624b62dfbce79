#pragma once
// Helpers shared by the benchmark programs: timing, medians, argument lists, the machine banner.
#include <CLI/CLI.hpp>
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <sstream>
#include <string>
#include <vector>

#include "cullpipe/geom/frustum.hpp"
#include "cullpipe/scene/camera.hpp"

namespace cullpipe::bench {

using Clock = std::chrono::steady_clock;

inline double since(Clock::time_point t0) {
  return double(std::chrono::duration_cast<std::chrono::nanoseconds>(Clock::now() - t0).count());
}

inline double median(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  const std::size_t n = v.size();
  return n == 0 ? 0.0 : n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
}

/// "a,b,,c" -> {"a", "b", "c"}.
inline std::vector<std::string> split(const std::string& s) {
  std::vector<std::string> out;
  std::stringstream in(s);
  for (std::string item; std::getline(in, item, ',');)
    if (!item.empty()) out.push_back(item);
  return out;
}

/// "1000,1e6,4e6" -> counts; throws CLI::ValidationError naming `option` on anything else.
inline std::vector<std::size_t> parse_counts(const std::string& list, const std::string& option) {
  std::vector<std::size_t> counts;
  for (const std::string& s : split(list)) {
    char* end = nullptr;
    const double n = std::strtod(s.c_str(), &end);
    if (*end != '\0' || !(n >= 0) || n > 1e9) throw CLI::ValidationError(option, "'" + s + "' is not a count");
    counts.push_back(std::size_t(n));
  }
  if (counts.empty()) throw CLI::ValidationError(option, "needs at least one count");
  return counts;
}

/// "0.01,0.1" -> fractions in (0, 1]; throws CLI::ValidationError naming `option` otherwise.
inline std::vector<double> parse_fractions(const std::string& list, const std::string& option) {
  std::vector<double> out;
  for (const std::string& s : split(list)) {
    char* end = nullptr;
    const double f = std::strtod(s.c_str(), &end);
    if (*end != '\0' || !(f > 0.0 && f <= 1.0))
      throw CLI::ValidationError(option, "'" + s + "' is not a fraction in (0, 1]");
    out.push_back(f);
  }
  if (out.empty()) throw CLI::ValidationError(option, "needs at least one fraction");
  return out;
}

/// "a,b" -> items, each one of `known`; throws CLI::ValidationError naming `option` otherwise.
inline std::vector<std::string> parse_names(const std::string& list, const std::string& option,
                                            const std::vector<std::string>& known) {
  std::vector<std::string> items = split(list);
  for (const std::string& item : items)
    if (std::find(known.begin(), known.end(), item) == known.end())
      throw CLI::ValidationError(option, "unknown '" + item + "'");
  if (items.empty()) throw CLI::ValidationError(option, "needs at least one value");
  return items;
}

/// An option taking a comma-separated list of counts ("1e3,1e6") into `out`.
inline CLI::Option* add_counts_option(CLI::App& app, const std::string& name, std::vector<std::size_t>& out,
                                      const std::string& help) {
  return app
      .add_option_function<std::string>(
          name, [&out, name](const std::string& v) { out = parse_counts(v, name); }, help)
      ->type_name("N,..");
}
/// An option taking a comma-separated list of fractions in (0, 1] into `out`.
inline CLI::Option* add_fractions_option(CLI::App& app, const std::string& name, std::vector<double>& out,
                                         const std::string& help) {
  return app
      .add_option_function<std::string>(
          name, [&out, name](const std::string& v) { out = parse_fractions(v, name); }, help)
      ->type_name("F,..");
}
/// An option taking a comma-separated list of names, each one of `known`, into `out`.
inline CLI::Option* add_names_option(CLI::App& app, const std::string& name, std::vector<std::string>& out,
                                     const std::vector<std::string>& known, const std::string& help) {
  return app
      .add_option_function<std::string>(
          name, [&out, name, known](const std::string& v) { out = parse_names(v, name, known); }, help)
      ->type_name("NAME,..");
}

/// Parses the command line as the cullpipe tool does: --help prints the options and exits 0, a
/// bad argument prints what is wrong and exits 2.
inline void parse_command_line(CLI::App& app, int argc, char** argv) {
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    const int code = app.exit(e);
    std::exit(code == 0 ? 0 : 2);
  }
}

inline std::string cpu_model() {
  std::ifstream in("/proc/cpuinfo");
  for (std::string line; std::getline(in, line);)
    if (line.rfind("model name", 0) == 0) return line.substr(line.find(':') + 2);
  return "unknown CPU";
}

/// A camera looking at the centre of `bounds` from outside (framing_camera), its field of view
/// (orthographic: its height) chosen by bisection so that about `fraction` of the objects are
/// visible; count_visible(f) counts them for a frustum. `achieved` gets the fraction reached,
/// `chosen` (if given) the camera.
template <class CountVisible>
Frustum frustum_for_fraction(const Aabb& bounds, std::size_t objects, double fraction, CountVisible count_visible,
                             double& achieved, Camera* chosen = nullptr, bool orthographic = false) {
  Camera cam = framing_camera(bounds);
  cam.aspect = 1.0f;
  cam.orthographic = orthographic;
  // Degrees, or (orthographic) half heights up to the scene's diagonal.
  double lo = 0.001, hi = orthographic ? double(glm::length(bounds.max - bounds.min)) + 1e-3 : 179.0;
  Frustum best = Frustum::from_view_proj(cam.view_proj());
  if (chosen) *chosen = cam;
  double best_error = 1e300;
  achieved = 0.0;
  for (int step = 0; step < 40 && objects > 0; ++step) {
    const double mid = 0.5 * (lo + hi);
    if (orthographic)
      cam.ortho_half_height = float(mid);
    else
      cam.fov_y_degrees = float(mid);
    const Frustum f = Frustum::from_view_proj(cam.view_proj());
    const double visible = double(count_visible(f)) / double(objects);
    if (std::abs(visible - fraction) < best_error) {
      best_error = std::abs(visible - fraction), best = f, achieved = visible;
      if (chosen) *chosen = cam;
    }
    if (visible < fraction)
      lo = mid;
    else
      hi = mid;
    if (best_error < fraction * 0.02) break;
  }
  return best;
}

}  // namespace cullpipe::bench
