#pragma once
#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <span>
#include <string>
#include <vector>

#include "cullpipe/cull/reference.hpp"
#include "cullpipe/geom/aabb.hpp"
#include "cullpipe/geom/classification.hpp"
#include "cullpipe/geom/frustum.hpp"
#include "cullpipe/geom/obb.hpp"
#include "cullpipe/geom/sphere.hpp"

namespace cullpipe {

/// Human-readable forms with every float printed to round-trip precision (%.9g), so a
/// reported case can be reproduced exactly.
std::string describe(const Aabb& b);
std::string describe(const Obb& b);
std::string describe(const Sphere& s);
std::string describe(const Frustum& f);

/// Index of the first position where `expected` and `actual` differ, or `npos` when equal
/// (sizes differing counts as a difference at the shorter size).
std::size_t first_mismatch(std::span<const Classification> expected, std::span<const Classification> actual);
inline constexpr std::size_t npos = static_cast<std::size_t>(-1);

/// Counts positions where the two differ (positions beyond the shorter span count too).
std::size_t count_mismatches(std::span<const Classification> expected, std::span<const Classification> actual);

/// "object 17: aabb min (..) max (..); planes [...]; cpu says inside, gpu says intersecting".
template <class Volume>
std::string describe_mismatch(std::size_t object, const Volume& v, const Frustum& f, Classification cpu,
                              Classification gpu) {
  return "object " + std::to_string(object) + ": " + describe(v) + "; frustum " + describe(f) + "; cpu says " +
         std::string(to_string(cpu)) + ", gpu says " + std::string(to_string(gpu));
}

/// The outcome of checking one view of a GPU pass against the CPU reference.
struct Agreement {
  std::size_t mismatches = 0;        ///< differing classes, plus 1 per wrong counter or list
  std::vector<std::string> reports;  ///< the first few differences, described in full
  bool ok() const { return mismatches == 0; }
};

/// Checks one view: the classes object by object, the counters, and the compacted list (each
/// visible object exactly once; with overflow, `capacity` distinct visible objects). Reports
/// name objects by `object_ids[i]` when given (e.g. their index in an input file), else by i.
template <class Volume>
Agreement check_agreement(std::span<const Volume> volumes, const Frustum& frustum, std::span<const Classification> cpu,
                          const reference::CullCounts& cpu_counts, std::span<const Classification> gpu,
                          const reference::CullCounts& gpu_counts, std::span<const std::uint32_t> gpu_visible_ids,
                          std::size_t capacity, std::size_t max_reports = 10,
                          std::span<const std::size_t> object_ids = {}) {
  Agreement a;
  auto report = [&](std::string text) {
    if (a.reports.size() < max_reports) a.reports.push_back(std::move(text));
  };
  a.mismatches = count_mismatches(cpu, gpu);
  for (std::size_t i = 0; i < volumes.size() && i < cpu.size() && i < gpu.size() && a.reports.size() < max_reports; ++i)
    if (cpu[i] != gpu[i])
      report(describe_mismatch(object_ids.empty() ? i : object_ids[i], volumes[i], frustum, cpu[i], gpu[i]));
  if (cpu.size() != gpu.size())
    report("the GPU returned " + std::to_string(gpu.size()) + " classes for " + std::to_string(cpu.size()) +
           " objects");
  if (!(cpu_counts == gpu_counts)) {
    ++a.mismatches;
    report("GPU counters (visible " + std::to_string(gpu_counts.visible) + ", inside " +
           std::to_string(gpu_counts.inside) + ", occluded " + std::to_string(gpu_counts.occluded) +
           ") differ from the CPU's (visible " + std::to_string(cpu_counts.visible) + ", inside " +
           std::to_string(cpu_counts.inside) + ", occluded " + std::to_string(cpu_counts.occluded) + ")");
  }
  std::vector<std::uint32_t> ids(gpu_visible_ids.begin(), gpu_visible_ids.end());
  std::sort(ids.begin(), ids.end());
  std::vector<std::uint32_t> expected;
  for (std::size_t i = 0; i < cpu.size(); ++i)
    if (is_visible(cpu[i])) expected.push_back(static_cast<std::uint32_t>(i));
  bool list_ok = std::adjacent_find(ids.begin(), ids.end()) == ids.end();
  if (expected.size() <= capacity)
    list_ok = list_ok && ids == expected;
  else
    list_ok =
        list_ok && ids.size() == capacity && std::includes(expected.begin(), expected.end(), ids.begin(), ids.end());
  if (!list_ok) {
    ++a.mismatches;
    report("the GPU's visible-id list (" + std::to_string(ids.size()) + " ids) is not the CPU's visible set (" +
           std::to_string(expected.size()) + " objects, list capacity " + std::to_string(capacity) + ")");
  }
  return a;
}

}  // namespace cullpipe
