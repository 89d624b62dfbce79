#pragma once
// Strict readers for JSON input: every failure throws InputError naming the source and the
// JSON path of the bad element ("file.json: volumes[2].sphere.radius: expected a number").
#include <cmath>
#include <fstream>
#include <glm/vec3.hpp>
#include <glm/vec4.hpp>
#include <nlohmann/json.hpp>
#include <sstream>
#include <string>

#include "cullpipe/scene/scene.hpp"

namespace cullpipe::json_util {

using json = nlohmann::json;

struct Reader {
  std::string source;  // file name, or "<stdin>"

  [[noreturn]] void fail(const std::string& path, const std::string& what) const {
    throw InputError(source + ": " + path + ": " + what);
  }

  const json& member(const json& obj, const std::string& path, const char* key) const {
    if (!obj.is_object()) fail(path, "expected an object");
    auto it = obj.find(key);
    if (it == obj.end()) fail(path, std::string("missing \"") + key + "\"");
    return *it;
  }

  float number(const json& v, const std::string& path) const {
    if (!v.is_number()) fail(path, "expected a number, got " + std::string(v.type_name()));
    const double d = v.get<double>();
    const float f = static_cast<float>(d);
    if (!std::isfinite(f)) fail(path, std::isfinite(d) ? "number out of float range" : "number is not finite");
    return f;
  }

  bool boolean(const json& v, const std::string& path) const {
    if (!v.is_boolean()) fail(path, "expected true or false, got " + std::string(v.type_name()));
    return v.get<bool>();
  }

  const json& array(const json& v, const std::string& path, std::size_t size) const {
    if (!v.is_array()) fail(path, "expected an array of " + std::to_string(size) + " numbers");
    if (v.size() != size) fail(path, "expected " + std::to_string(size) + " numbers, got " + std::to_string(v.size()));
    return v;
  }

  glm::vec3 vec3(const json& v, const std::string& path) const {
    array(v, path, 3);
    return {number(v[0], path + "[0]"), number(v[1], path + "[1]"), number(v[2], path + "[2]")};
  }

  glm::vec4 vec4(const json& v, const std::string& path) const {
    array(v, path, 4);
    return {number(v[0], path + "[0]"), number(v[1], path + "[1]"), number(v[2], path + "[2]"),
            number(v[3], path + "[3]")};
  }

  glm::mat4 mat4(const json& v, const std::string& path) const {  // 16 numbers, column-major
    array(v, path, 16);
    glm::mat4 m;
    for (int c = 0; c < 4; ++c)
      for (int r = 0; r < 4; ++r)
        m[c][r] = number(v[std::size_t(c * 4 + r)], path + "[" + std::to_string(c * 4 + r) + "]");
    return m;
  }
};

/// Parses JSON text; a syntax error becomes InputError naming the source and byte offset.
inline json parse(const std::string& text, const std::string& source) {
  try {
    return json::parse(text);
  } catch (const json::exception& e) {  // syntax errors, and numbers beyond double range
    throw InputError(source + ": invalid JSON: " + e.what());
  }
}

/// Reads a whole file; throws InputError when it cannot be read.
inline std::string read_file(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw InputError(path + ": cannot open file");
  std::ostringstream s;
  s << in.rdbuf();
  if (in.bad()) throw InputError(path + ": read error");
  return s.str();
}

inline json to_json(const glm::vec3& v) { return json::array({v.x, v.y, v.z}); }
inline json to_json(const glm::vec4& v) { return json::array({v.x, v.y, v.z, v.w}); }
inline json to_json(const glm::mat4& m) {
  json a = json::array();
  for (int c = 0; c < 4; ++c)
    for (int r = 0; r < 4; ++r) a.push_back(m[c][r]);
  return a;
}

using cullpipe::write_file_atomic;  // scene/scene.hpp

}  // namespace cullpipe::json_util
