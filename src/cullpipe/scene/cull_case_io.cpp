#include "cullpipe/scene/cull_case_io.hpp"

#include <stdexcept>

#include "cullpipe/geom/validate.hpp"
#include "cullpipe/scene/json_util.hpp"

namespace cullpipe {

using json_util::json;

namespace {

Frustum read_frustum(const json_util::Reader& r, const json& f, const std::string& path) {
  if (!f.is_object()) r.fail(path, "expected an object with \"planes\" or \"view_proj\"");
  try {
    if (f.contains("planes")) {
      const json& planes = f["planes"];
      if (!planes.is_array() || planes.empty() || planes.size() > 6) r.fail(path + ".planes", "expected 1 to 6 planes");
      std::vector<glm::vec4> v;
      for (std::size_t i = 0; i < planes.size(); ++i)
        v.push_back(r.vec4(planes[i], path + ".planes[" + std::to_string(i) + "]"));
      return Frustum::from_planes(v);
    }
    if (f.contains("view_proj")) return Frustum::from_view_proj(r.mat4(f["view_proj"], path + ".view_proj"));
  } catch (const std::invalid_argument& e) {
    r.fail(path, e.what());
  }
  r.fail(path, "expected \"planes\" or \"view_proj\"");
}

template <class V>
void check_volume(const json_util::Reader& r, const V& v, const std::string& path) {
  if (const std::string why = invalid_reason(v); !why.empty()) r.fail(path, why);
}

Volume read_volume(const json_util::Reader& r, const json& v, const std::string& path) {
  if (!v.is_object()) r.fail(path, "expected an object with \"aabb\", \"obb\" or \"sphere\"");
  if (int(v.contains("aabb")) + int(v.contains("obb")) + int(v.contains("sphere")) > 1)
    r.fail(path, "more than one of \"aabb\", \"obb\", \"sphere\" in one volume");
  if (v.contains("aabb")) {
    const json& a = v["aabb"];
    const std::string p = path + ".aabb";
    Aabb box;
    if (a.is_object() && a.contains("min")) {
      box.min = r.vec3(a["min"], p + ".min");
      box.max = r.vec3(r.member(a, p, "max"), p + ".max");
    } else if (a.is_object() && a.contains("center")) {
      const glm::vec3 c = r.vec3(a["center"], p + ".center");
      const glm::vec3 h = r.vec3(r.member(a, p, "half_extents"), p + ".half_extents");
      for (int k = 0; k < 3; ++k)
        if (h[k] < 0.0f) r.fail(p + ".half_extents", "negative extent");
      box = to_min_max(AabbCenterRadius{c, h});
    } else {
      r.fail(p, "expected {\"min\", \"max\"} or {\"center\", \"half_extents\"}");
    }
    check_volume(r, box, p);
    return box;
  }
  if (v.contains("sphere")) {
    const json& s = v["sphere"];
    const std::string p = path + ".sphere";
    Sphere sphere{r.vec3(r.member(s, p, "center"), p + ".center"), r.number(r.member(s, p, "radius"), p + ".radius")};
    check_volume(r, sphere, p);
    return sphere;
  }
  if (v.contains("obb")) {
    const json& o = v["obb"];
    const std::string p = path + ".obb";
    Obb box;
    box.center = r.vec3(r.member(o, p, "center"), p + ".center");
    box.half_extents = r.vec3(r.member(o, p, "half_extents"), p + ".half_extents");
    const json& axes = r.member(o, p, "axes");
    if (!axes.is_array() || axes.size() != 3) r.fail(p + ".axes", "expected three axis vectors");
    for (int k = 0; k < 3; ++k) box.basis[k] = r.vec3(axes[std::size_t(k)], p + ".axes[" + std::to_string(k) + "]");
    check_volume(r, box, p);
    return box;
  }
  r.fail(path, "expected \"aabb\", \"obb\" or \"sphere\"");
}

json volume_to_json(const Volume& v) {
  using json_util::to_json;
  if (const Aabb* a = std::get_if<Aabb>(&v)) return {{"aabb", {{"min", to_json(a->min)}, {"max", to_json(a->max)}}}};
  if (const Sphere* s = std::get_if<Sphere>(&v))
    return {{"sphere", {{"center", to_json(s->center)}, {"radius", s->radius}}}};
  const Obb& o = std::get<Obb>(v);
  return {{"obb",
           {{"center", to_json(o.center)},
            {"half_extents", to_json(o.half_extents)},
            {"axes", json::array({to_json(o.basis[0]), to_json(o.basis[1]), to_json(o.basis[2])})}}}};
}

json frustum_to_json(const Frustum& f) {
  json planes = json::array();
  for (const Plane& p : f.active()) planes.push_back(json_util::to_json(p.as_vec4()));
  return {{"planes", planes}};
}

}  // namespace

std::string volume_to_json_text(const Volume& v) { return volume_to_json(v).dump(); }

CullCase parse_cull_case(const std::string& text, const std::string& source) {
  const json root = json_util::parse(text, source);
  const json_util::Reader r{source};
  if (!root.is_object()) r.fail("(root)", "expected an object with \"frustum\" and \"volumes\"");
  CullCase c;
  if (root.contains("frusta") && root.contains("frustum")) r.fail("(root)", "give \"frustum\" or \"frusta\", not both");
  if (root.contains("frusta")) {
    const json& frusta = root["frusta"];
    if (!frusta.is_array() || frusta.empty()) r.fail("frusta", "expected a non-empty array of frusta");
    c.multi_view = true;
    for (std::size_t i = 0; i < frusta.size(); ++i)
      c.frusta.push_back(read_frustum(r, frusta[i], "frusta[" + std::to_string(i) + "]"));
  } else {
    c.frusta.push_back(read_frustum(r, r.member(root, "(root)", "frustum"), "frustum"));
  }
  const json& volumes = r.member(root, "(root)", "volumes");
  if (!volumes.is_array()) r.fail("volumes", "expected an array");
  c.volumes.reserve(volumes.size());
  for (std::size_t i = 0; i < volumes.size(); ++i)
    c.volumes.push_back(read_volume(r, volumes[i], "volumes[" + std::to_string(i) + "]"));
  return c;
}

std::string cull_case_to_json(const CullCase& c, const std::vector<std::vector<Classification>>* classes,
                              const std::vector<std::uint32_t>* ids) {
  json root;
  if (c.multi_view || c.frusta.size() != 1) {
    json frusta = json::array();
    for (const Frustum& f : c.frusta) frusta.push_back(frustum_to_json(f));
    root["frusta"] = frusta;
  } else {
    root["frustum"] = frustum_to_json(c.frusta.front());
  }
  json volumes = json::array();
  for (std::size_t i = 0; i < c.volumes.size(); ++i) {
    json v = volume_to_json(c.volumes[i]);
    if (ids) v["id"] = (*ids)[i];
    if (i < c.objects.size()) {
      const CullCase::Object& o = c.objects[i];
      json obj;
      obj["gltf"] = {{"node", o.origin.node},
                     {"mesh", o.origin.mesh},
                     {"primitive", o.origin.primitive},
                     {"instance", o.origin.instance}};
      for (const Volume& w : {Volume(o.aabb), Volume(o.obb), Volume(o.sphere)}) obj.update(volume_to_json(w));
      v["object"] = std::move(obj);
    }
    if (classes) {
      if (classes->size() == 1 && !c.multi_view) {
        v["class"] = std::string(to_string((*classes)[0][i]));
      } else {
        json per_view = json::array();
        for (const auto& view : *classes) per_view.push_back(std::string(to_string(view[i])));
        v["classes"] = per_view;
      }
    }
    volumes.push_back(std::move(v));
  }
  root["volumes"] = std::move(volumes);
  if (!c.tests.empty()) {
    json tests = json::array();
    for (std::size_t v = 0; v < c.tests.size(); ++v) {
      json t = {{"view", v},
                {"cull", c.tests[v].cull},
                {"node_tests", c.tests[v].node_tests},
                {"object_tests", c.tests[v].object_tests}};
      if (c.tests[v].cull == "bvh") t["range_objects"] = c.tests[v].range_objects;
      tests.push_back(std::move(t));
    }
    root["tests"] = std::move(tests);
  }
  return root.dump(1) + "\n";
}

}  // namespace cullpipe
