#include <chrono>
#include <cstdio>
#include <functional>
#include <nlohmann/json.hpp>
#include <ostream>

#include "cullpipe/app/commands.hpp"
#include "cullpipe/app/guard.hpp"
#include "cullpipe/bounds/convex_hull.hpp"
#include "cullpipe/bounds/obb_fit.hpp"
#include "cullpipe/bounds/sphere_fit.hpp"
#include "cullpipe/geom/validate.hpp"
#include "cullpipe/scene/cull_case_io.hpp"
#include "cullpipe/scene/gltf_points.hpp"
#include "cullpipe/scene/json_util.hpp"
#include "cullpipe/scene/point_io.hpp"

namespace cullpipe::app {
namespace {

struct Built {
  std::string builder;
  Volume volume;
  double size = 0;  // volume of a box, radius of a sphere
  double ms = 0;
};

template <class F>
Built timed(const std::string& name, F&& build) {
  const auto t0 = std::chrono::steady_clock::now();
  Volume v = build();
  const double ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
  double size = 0;
  if (const Aabb* a = std::get_if<Aabb>(&v)) size = double(a->extent().x) * a->extent().y * a->extent().z;
  if (const Obb* o = std::get_if<Obb>(&v)) size = bounds::volume(*o);
  if (const Sphere* s = std::get_if<Sphere>(&v)) size = s->radius;
  return {name, v, size, ms};
}

const char* dimension_name(bounds::ConvexHull::Dimension d) {
  switch (d) {
    case bounds::ConvexHull::Dimension::Point:
      return "a point";
    case bounds::ConvexHull::Dimension::Segment:
      return "a segment";
    case bounds::ConvexHull::Dimension::Polygon:
      return "a polygon";
    case bounds::ConvexHull::Dimension::Polyhedron:
      return "a polyhedron";
  }
  return "?";
}

// Builds every volume of one point set, prints the table and returns the JSON record.
nlohmann::json report(const std::string& title, const std::vector<glm::vec3>& pts, std::ostream& out) {
  const auto t0 = std::chrono::steady_clock::now();
  const bounds::ConvexHull hull = bounds::convex_hull(pts);
  const double hull_ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();

  std::vector<Built> boxes, spheres;
  boxes.push_back(timed("aabb", [&] { return Volume(bounds::aabb_of_points(pts)); }));
  boxes.push_back(timed("obb-pca", [&] { return Volume(bounds::pca_obb(pts)); }));
  boxes.push_back(timed("obb-dito", [&] { return Volume(bounds::dito_obb(pts)); }));
  boxes.push_back(timed("obb-hull-face", [&] { return Volume(bounds::hull_face_obb(pts)); }));
  boxes.push_back(timed("obb-exact", [&] { return Volume(bounds::exact_obb(pts)); }));
  spheres.push_back(timed("sphere-ritter", [&] { return Volume(bounds::ritter_sphere(pts)); }));
  spheres.push_back(timed("sphere-refined", [&] { return Volume(bounds::refined_sphere(pts)); }));
  spheres.push_back(timed("sphere-exact", [&] { return Volume(bounds::exact_sphere(pts)); }));

  // Coordinates near the float limit can overflow a volume (e.g. a radius beyond 3.4e38):
  // report that rather than print or write non-finite numbers.
  for (const auto* list : {&boxes, &spheres})
    for (const Built& b : *list) {
      const std::string why = std::visit([](const auto& v) { return invalid_reason(v); }, b.volume);
      if (!why.empty())
        throw InputError(title + ": " + b.builder + " gives no finite volume (" + why + "); coordinates too large");
    }
  const double exact_box = boxes.back().size, exact_radius = spheres.back().size;

  char hull_ms_text[32];
  std::snprintf(hull_ms_text, sizeof hull_ms_text, "%.3f", hull_ms);
  out << title << ": " << pts.size() << " points; convex hull: " << dimension_name(hull.dimension) << " with "
      << hull.vertices.size() << " vertices and " << hull.faces.size() << " faces (" << hull_ms_text << " ms)\n";
  out << "  builder            size            relative   time ms\n";
  auto row = [&](const Built& b, double reference, const char* unit) {
    char line[160];
    std::snprintf(line, sizeof line, "  %-17s %12.6g %-7s %8.4f %9.3f\n", b.builder.c_str(), b.size, unit,
                  reference > 0 ? b.size / reference : 1.0, b.ms);
    out << line;
  };
  for (const Built& b : boxes) row(b, exact_box, "volume");
  for (const Built& s : spheres) row(s, exact_radius, "radius");
  out << "\n";

  nlohmann::json j;
  j["name"] = title;
  j["points"] = pts.size();
  j["hull_vertices"] = hull.vertices.size();
  j["hull_faces"] = hull.faces.size();
  j["volumes"] = nlohmann::json::array();
  for (const auto* list : {&boxes, &spheres})
    for (const Built& b : *list) {
      nlohmann::json v = nlohmann::json::parse(volume_to_json_text(b.volume));
      v["builder"] = b.builder;
      v["time_ms"] = b.ms;
      j["volumes"].push_back(v);
    }
  return j;
}

}  // namespace

int bounds_command(const BoundsOptions& o, std::ostream& out, std::ostream& err) {
  return guarded(err, [&]() -> int {
    if (o.points_path.empty() == o.model_path.empty())
      throw InputError("bounds: give a glTF file (.gltf, .glb) or --points FILE (.txt, .off, .obj)");
    nlohmann::json sets = nlohmann::json::array();
    out << "Sizes relative to the exact minimum: box volumes to the exact OBB's, sphere radii to the exact "
           "sphere's.\n\n";
    if (!o.points_path.empty()) {
      sets.push_back(report(o.points_path, load_points(o.points_path), out));
    } else {
      for (const GltfMeshPoints& mesh : load_gltf_mesh_points(o.model_path)) {
        const std::string title = o.model_path + " mesh " + std::to_string(mesh.mesh) + " (" + mesh.name + ")";
        if (mesh.positions.empty()) {
          out << title << ": no vertices, skipped\n\n";
          continue;
        }
        sets.push_back(report(title, mesh.positions, out));
      }
    }
    if (!o.json_path.empty()) json_util::write_file_atomic(o.json_path, nlohmann::json{{"sets", sets}}.dump(2) + "\n");
    return kExitOk;
  });
}

}  // namespace cullpipe::app
