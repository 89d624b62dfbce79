#include "cullpipe/scene/point_io.hpp"

#include <cmath>
#include <cstdlib>
#include <fstream>
#include <limits>
#include <sstream>

#include "cullpipe/scene/scene.hpp"

namespace cullpipe {
namespace {

bool ends_with(const std::string& s, const std::string& suffix) {
  if (s.size() < suffix.size()) return false;
  for (std::size_t i = 0; i < suffix.size(); ++i)
    if (std::tolower(static_cast<unsigned char>(s[s.size() - suffix.size() + i])) != suffix[i]) return false;
  return true;
}

struct LineReader {
  const std::string& path;
  std::size_t line = 0;

  [[noreturn]] void fail(const std::string& what) const {
    throw InputError(path + ":" + std::to_string(line) + ": " + what);
  }

  // Parses one float token; rejects garbage, NaN, infinities and out-of-range values.
  float number(const std::string& token) const {
    char* end = nullptr;
    const double v = std::strtod(token.c_str(), &end);
    if (token.empty() || *end != '\0') fail("'" + token + "' is not a number");
    if (!std::isfinite(v)) fail("'" + token + "' is not finite");
    if (std::abs(v) > double(std::numeric_limits<float>::max())) fail("'" + token + "' is out of float range");
    return static_cast<float>(v);
  }

  glm::vec3 point(std::istringstream& in) const {
    std::string t[3];
    for (std::string& s : t)
      if (!(in >> s)) fail("expected three coordinates");
    return {number(t[0]), number(t[1]), number(t[2])};
  }
};

}  // namespace

std::vector<glm::vec3> load_points(const std::string& path) {
  std::ifstream in(path);
  if (!in) throw InputError(path + ": cannot open file");
  LineReader r{path};
  std::vector<glm::vec3> points;
  std::string text;
  const bool off = ends_with(path, ".off"), obj = ends_with(path, ".obj");
  long long off_remaining = -1;  // vertices still to read in an OFF file; -1 before the header
  bool off_magic = false;
  while (std::getline(in, text)) {
    ++r.line;
    const auto hash = text.find('#');
    if (hash != std::string::npos) text.resize(hash);
    std::istringstream line(text);
    std::string first;
    if (!(line >> first)) continue;  // blank
    if (obj) {
      if (first == "v") points.push_back(r.point(line));
      continue;
    }
    if (off) {
      if (!off_magic) {
        if (first != "OFF") r.fail("expected the OFF header");
        off_magic = true;
        if (!(line >> first)) continue;  // counts on the next line
      }
      if (off_remaining < 0) {
        char* end = nullptr;
        const long long nv = std::strtoll(first.c_str(), &end, 10);
        if (*end != '\0' || nv < 0 || nv > 100'000'000) r.fail("bad vertex count '" + first + "'");
        off_remaining = nv;
        continue;
      }
      if (off_remaining == 0) break;  // faces follow
      std::istringstream whole(text);
      points.push_back(r.point(whole));
      --off_remaining;
      continue;
    }
    std::istringstream whole(text);
    points.push_back(r.point(whole));
    std::string extra;
    if (whole >> extra) r.fail("more than three numbers on a line");
  }
  if (in.bad()) throw InputError(path + ": read error");
  if (off && off_remaining > 0)
    throw InputError(path + ": file ends before all " + std::to_string(points.size() + std::size_t(off_remaining)) +
                     " vertices");
  if (points.empty()) throw InputError(path + ": no points");
  return points;
}

}  // namespace cullpipe
