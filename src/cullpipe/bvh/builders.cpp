// The builder registry: names to builders, and the "top-down:axis=..,split=..,cost=.." grammar.
#include "cullpipe/bvh/builders.hpp"

#include <array>
#include <stdexcept>
#include <string>
#include <utility>

namespace cullpipe::bvh {
namespace {

using BuildFunction = Tree (*)(std::span<const Aabb>, const BuildOptions&);

struct Entry {
  BuilderInfo info;
  BuildFunction function = nullptr;  ///< nullptr: build_top_down with the split below
  SplitAxis axis = SplitAxis::Best;
  SplitPosition position = SplitPosition::Binned;
  SplitCost cost = SplitCost::Sah;
  bool insertion = false;  ///< accepts "+rotations"
};

constexpr Entry top_down(std::string_view name, std::string_view description, SplitAxis axis, SplitPosition position,
                         SplitCost cost) {
  return {{name, description}, nullptr, axis, position, cost, false};
}

constexpr Entry other(std::string_view name, std::string_view description, BuildFunction function,
                      bool insertion = false) {
  return {{name, description}, function, SplitAxis::Best, SplitPosition::Binned, SplitCost::Sah, insertion};
}

using enum SplitAxis;
using enum SplitPosition;
using enum SplitCost;

const std::array kEntries = {
    top_down("binned-sah", "top-down, best of `bins` binned SAH splits on x, y, z (the default)", Best, Binned, Sah),
    top_down("median", "top-down, median of the centroids on the longest axis", Longest, Median, Sah),
    top_down("mean", "top-down, mean of the centroids on the longest axis", Longest, Mean, Sah),
    top_down("extent-median", "top-down, middle of the centroids' extent on the longest axis", Longest, ExtentMedian,
             Sah),
    top_down("pca-median", "top-down, median of the centroids along their principal axis", Pca, Median, Sah),
    top_down("distant-median", "top-down, median along the line through two most distant centroids", DistantCentroids,
             Median, Sah),
    top_down("volume", "top-down, binned on x, y, z, least sum of the children's volumes", Best, Binned, VolumeSum),
    top_down("largest-volume", "top-down, binned on x, y, z, least volume of the larger child", Best, Binned,
             LargestVolume),
    top_down("overlap", "top-down, binned on x, y, z, least overlap volume of the children", Best, Binned, Overlap),
    top_down("separation", "top-down, binned on x, y, z, widest gap (least overlap) between the children", Best, Binned,
             Separation),
    top_down("sah-guarded", "top-down, binned SAH, passing over splits whose children overlap in > 1/4 of the node",
             Best, Binned, SahOverlapGuarded),
    other("agglomerative-brute", "bottom-up clustering, all pairs searched each step (O(n^3), small n)",
          build_agglomerative_brute),
    other("agglomerative-pq", "bottom-up clustering with a priority queue of best partners (O(n^2))",
          build_agglomerative_pq),
    other("agglomerative-local", "bottom-up clustering among Morton-order neighbours (PLOC)",
          build_agglomerative_local),
    other("insertion-greedy", "insertion (fixed shuffle), descending to the cheaper child (+rotations)",
          build_insertion_greedy, true),
    other("insertion-bnb", "insertion (fixed shuffle), best sibling by branch and bound (+rotations)",
          build_insertion_bnb, true),
};

const std::array<BuilderInfo, kEntries.size()>& infos() {
  static const std::array<BuilderInfo, kEntries.size()> table = [] {
    std::array<BuilderInfo, kEntries.size()> t{};
    for (std::size_t i = 0; i < kEntries.size(); ++i) t[i] = kEntries[i].info;
    return t;
  }();
  return table;
}

constexpr std::string_view kTopDown = "top-down";
constexpr std::string_view kRotations = "+rotations";

[[noreturn]] void fail(std::string_view name, const std::string& what) {
  std::string known;
  for (const Entry& e : kEntries) known += (known.empty() ? "" : ", ") + std::string(e.info.name);
  throw std::invalid_argument("BVH builder '" + std::string(name) + "': " + what + "; known builders: " + known +
                              "; or top-down:axis=longest|distant|pca|best,split=median|mean|extent|binned,"
                              "cost=sah|volume|largest|overlap|separation|sah-guarded (any part may be left out); "
                              "insertion builders take a trailing +rotations");
}

template <typename T, std::size_t N>
bool lookup(const std::array<std::pair<std::string_view, T>, N>& table, std::string_view key, T& out) {
  for (const auto& [name, value] : table)
    if (name == key) {
      out = value;
      return true;
    }
  return false;
}

constexpr std::array<std::pair<std::string_view, SplitAxis>, 4> kAxes = {
    {{"longest", Longest}, {"distant", DistantCentroids}, {"pca", Pca}, {"best", Best}}};
constexpr std::array<std::pair<std::string_view, SplitPosition>, 4> kPositions = {
    {{"median", Median}, {"mean", Mean}, {"extent", ExtentMedian}, {"binned", Binned}}};
constexpr std::array<std::pair<std::string_view, SplitCost>, 6> kCosts = {{{"sah", Sah},
                                                                           {"volume", VolumeSum},
                                                                           {"largest", LargestVolume},
                                                                           {"overlap", Overlap},
                                                                           {"separation", Separation},
                                                                           {"sah-guarded", SahOverlapGuarded}}};

// "axis=A,split=P,cost=C" (each optional, each at most once) into options.
void parse_top_down(std::string_view name, std::string_view params, BuildOptions& options) {
  bool seen_axis = false, seen_split = false, seen_cost = false;
  while (!params.empty()) {
    const std::size_t comma = params.find(',');
    const std::string_view item = params.substr(0, comma);
    params = comma == std::string_view::npos ? std::string_view{} : params.substr(comma + 1);
    if (comma != std::string_view::npos && params.empty()) fail(name, "empty parameter after ','");
    const std::size_t eq = item.find('=');
    if (eq == std::string_view::npos) fail(name, "parameter '" + std::string(item) + "' is not key=value");
    const std::string_view key = item.substr(0, eq), value = item.substr(eq + 1);
    const auto bad_value = [&](const char* choices) {
      fail(name, "unknown " + std::string(key) + " '" + std::string(value) + "' (" + choices + ")");
    };
    const auto once = [&](bool& seen) {
      if (seen) fail(name, "parameter '" + std::string(key) + "' given twice");
      seen = true;
    };
    if (key == "axis") {
      once(seen_axis);
      if (!lookup(kAxes, value, options.axis)) bad_value("longest|distant|pca|best");
    } else if (key == "split") {
      once(seen_split);
      if (!lookup(kPositions, value, options.position)) bad_value("median|mean|extent|binned");
    } else if (key == "cost") {
      once(seen_cost);
      if (!lookup(kCosts, value, options.cost)) bad_value("sah|volume|largest|overlap|separation|sah-guarded");
    } else {
      fail(name, "unknown parameter '" + std::string(key) + "' (axis, split, cost)");
    }
  }
}

}  // namespace

std::span<const BuilderInfo> builders() { return infos(); }

Tree build(std::string_view name, std::span<const Aabb> boxes, BuildOptions options) {
  if (name == kTopDown || name.starts_with(std::string(kTopDown) + ":")) {
    parse_top_down(name, name.substr(std::min(name.size(), kTopDown.size() + 1)), options);
    return build_top_down(boxes, options);
  }
  std::string_view base = name;
  const bool rotations = base.ends_with(kRotations);
  if (rotations) base.remove_suffix(kRotations.size());
  for (const Entry& e : kEntries) {
    if (e.info.name != base) continue;
    if (rotations && !e.insertion) fail(name, "'+rotations' applies only to the insertion builders");
    if (rotations) options.rotations = true;
    if (e.function) return e.function(boxes, options);
    options.axis = e.axis;
    options.position = e.position;
    options.cost = e.cost;
    return build_top_down(boxes, options);
  }
  fail(name, "unknown name");
}

}  // namespace cullpipe::bvh
