#include "cullpipe/bounds/obb_fit.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <glm/geometric.hpp>
#include <limits>
#include <vector>

#include "cullpipe/bounds/convex_hull.hpp"
#include "cullpipe/bounds/points.hpp"
#include "cullpipe/geom/rounding.hpp"

namespace cullpipe::bounds {
namespace {

using dvec3 = glm::dvec3;
using dmat3 = glm::dmat3;

// Right-handed orthonormal float basis from a double frame whose first column is kept.
glm::mat3 to_basis(dvec3 u, dvec3 v) {
  u = glm::normalize(u);
  v = glm::normalize(v - glm::dot(v, u) * u);
  const dvec3 w = glm::cross(u, v);
  return glm::mat3(glm::vec3(u), glm::vec3(v), glm::vec3(w));
}

// Any unit vector orthogonal to unit u.
dvec3 orthogonal(const dvec3& u) {
  const dvec3 helper = std::abs(u.x) < 0.6 ? dvec3(1, 0, 0) : std::abs(u.y) < 0.6 ? dvec3(0, 1, 0) : dvec3(0, 0, 1);
  return glm::normalize(glm::cross(u, helper));
}

// Eigenvectors of a symmetric 3x3 matrix by cyclic Jacobi rotations (columns of the result).
dmat3 eigenvectors(dmat3 a) {
  dmat3 v(1.0);
  for (int sweep = 0; sweep < 50; ++sweep) {
    const double off = a[0][1] * a[0][1] + a[0][2] * a[0][2] + a[1][2] * a[1][2];
    const double diag = a[0][0] * a[0][0] + a[1][1] * a[1][1] + a[2][2] * a[2][2];
    if (off <= 1e-30 * diag || off == 0.0) break;
    for (int p = 0; p < 2; ++p)
      for (int q = p + 1; q < 3; ++q) {
        if (a[p][q] == 0.0) continue;
        const double theta = (a[q][q] - a[p][p]) / (2.0 * a[p][q]);
        const double t = (theta >= 0 ? 1.0 : -1.0) / (std::abs(theta) + std::sqrt(theta * theta + 1.0));
        const double c = 1.0 / std::sqrt(t * t + 1.0), s = t * c;
        dmat3 j(1.0);
        j[p][p] = c;
        j[q][q] = c;
        j[q][p] = s;   // column q, row p
        j[p][q] = -s;  // column p, row q
        a = glm::transpose(j) * a * j;
        v = v * j;
      }
  }
  return v;
}

// The two extreme point indices along direction d.
std::pair<std::size_t, std::size_t> extremes(std::span<const glm::vec3> pts, const dvec3& d) {
  std::size_t lo = 0, hi = 0;
  double vlo = std::numeric_limits<double>::infinity(), vhi = -vlo;
  for (std::size_t i = 0; i < pts.size(); ++i) {
    const double v = glm::dot(dvec3(pts[i]), d);
    if (v < vlo) vlo = v, lo = i;
    if (v > vhi) vhi = v, hi = i;
  }
  return {lo, hi};
}

// Sum of the box's half-surface-area proxy along a frame for a small point set (DiTO's
// quality measure): (ex*ey + ey*ez + ez*ex) with e the extents.
double frame_quality(const std::vector<dvec3>& pts, const dvec3& u, const dvec3& v, const dvec3& w) {
  double lo[3] = {1e300, 1e300, 1e300}, hi[3] = {-1e300, -1e300, -1e300};
  for (const dvec3& p : pts) {
    const double c[3] = {glm::dot(p, u), glm::dot(p, v), glm::dot(p, w)};
    for (int k = 0; k < 3; ++k) lo[k] = std::min(lo[k], c[k]), hi[k] = std::max(hi[k], c[k]);
  }
  const double ex = hi[0] - lo[0], ey = hi[1] - lo[1], ez = hi[2] - lo[2];
  return ex * ey + ey * ez + ez * ex;
}

// Minimum-area enclosing rectangle of a convex polygon (counter-clockwise, 2D) by rotating
// calipers: one edge of the best rectangle lies on a polygon edge (Freeman & Shapira 1975).
// Returns the edge direction (unit, 2D) and the area.
struct Rect {
  double ux = 1, uy = 0;  // direction of the first side
  double area = std::numeric_limits<double>::infinity();
};

Rect min_area_rect(const std::vector<std::array<double, 2>>& poly) {
  const std::size_t m = poly.size();
  Rect best;
  if (m < 3) {
    if (m == 2) {
      const double dx = poly[1][0] - poly[0][0], dy = poly[1][1] - poly[0][1], len = std::hypot(dx, dy);
      if (len > 0) best = {dx / len, dy / len, 0.0};
    } else {
      best.area = 0.0;
    }
    return best;
  }
  auto dot = [&](std::size_t i, double x, double y) { return poly[i][0] * x + poly[i][1] * y; };
  std::size_t right = 0, top = 0, left = 0;  // caliper indices, advanced monotonically
  for (std::size_t i = 0; i < m; ++i) {
    const std::size_t j = (i + 1) % m;
    double ex = poly[j][0] - poly[i][0], ey = poly[j][1] - poly[i][1];
    const double len = std::hypot(ex, ey);
    if (len == 0) continue;
    ex /= len, ey /= len;
    const double nx = -ey, ny = ex;  // inward normal (polygon is counter-clockwise)
    if (i == 0) right = top = left = i;
    while (dot((right + 1) % m, ex, ey) >= dot(right, ex, ey) && (right + 1) % m != i) right = (right + 1) % m;
    if (i == 0) top = right;
    while (dot((top + 1) % m, nx, ny) >= dot(top, nx, ny) && (top + 1) % m != i) top = (top + 1) % m;
    if (i == 0) left = top;
    // The minimum along the edge may be the edge's own start vertex i, so left may reach i.
    while (left != i && dot((left + 1) % m, ex, ey) <= dot(left, ex, ey)) left = (left + 1) % m;
    const double width = dot(right, ex, ey) - dot(left, ex, ey);
    const double height = dot(top, nx, ny) - dot(i, nx, ny);
    if (width * height < best.area) best = {ex, ey, width * height};
  }
  return best;
}

// 2D convex hull (counter-clockwise) of projected points, by monotone chain.
std::vector<std::array<double, 2>> hull2d(std::vector<std::array<double, 2>> pts) {
  std::sort(pts.begin(), pts.end());
  pts.erase(std::unique(pts.begin(), pts.end()), pts.end());
  if (pts.size() < 3) return pts;
  auto cross = [](const std::array<double, 2>& o, const std::array<double, 2>& a, const std::array<double, 2>& b) {
    return (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0]);
  };
  std::vector<std::array<double, 2>> h(2 * pts.size());
  std::size_t k = 0;
  for (const auto& p : pts) {
    while (k >= 2 && cross(h[k - 2], h[k - 1], p) <= 0) --k;
    h[k++] = p;
  }
  for (std::size_t i = pts.size() - 1, lower = k + 1; i-- > 0;) {
    while (k >= lower && cross(h[k - 2], h[k - 1], pts[i]) <= 0) --k;
    h[k++] = pts[i];
  }
  h.resize(k - 1);
  return h;
}

}  // namespace

double volume(const Obb& b) {
  return 8.0 * double(b.half_extents.x) * double(b.half_extents.y) * double(b.half_extents.z);
}

namespace {

template <class Point>
Obb fit_box_impl(std::span<const Point> points, const glm::mat3& basis) {
  const dvec3 axes[3] = {dvec3(basis[0]), dvec3(basis[1]), dvec3(basis[2])};
  dvec3 lo(std::numeric_limits<double>::infinity()), hi(-std::numeric_limits<double>::infinity());
  for (const Point& p : points)
    for (int k = 0; k < 3; ++k) {
      const double c = glm::dot(dvec3(p), axes[k]);
      lo[k] = std::min(lo[k], c);
      hi[k] = std::max(hi[k], c);
    }
  Obb b;
  b.basis = basis;
  const dvec3 mid = (lo + hi) * 0.5;
  b.center = glm::vec3(axes[0] * mid.x + axes[1] * mid.y + axes[2] * mid.z);
  // Extents about the float centre actually stored, from p - c (a second pass: subtracting
  // projections instead would cancel for small objects far from the origin), rounded up.
  const dvec3 c(b.center);
  dvec3 ext(0.0);
  for (const Point& p : points) {
    const dvec3 d = dvec3(p) - c;
    for (int k = 0; k < 3; ++k) ext[k] = std::max(ext[k], std::abs(glm::dot(d, axes[k])));
  }
  for (int k = 0; k < 3; ++k) b.half_extents[k] = round_up(ext[k]);
  return b;
}

}  // namespace

Obb fit_box(std::span<const glm::vec3> points, const glm::mat3& basis) {
  check_points(points);
  return fit_box_impl(points, basis);
}

Obb pca_obb(std::span<const glm::vec3> points) {
  check_points(points);
  const ConvexHull hull = convex_hull(points);
  dmat3 cov(0.0);
  if (hull.dimension == ConvexHull::Dimension::Polyhedron) {
    // Covariance of the hull surface: triangles weighted by area (Gottschalk 1996).
    double total = 0.0;
    dvec3 mean(0.0);
    dmat3 second(0.0);
    for (const auto& f : hull.faces) {
      const dvec3 a(hull.vertices[f[0]]), b(hull.vertices[f[1]]), c(hull.vertices[f[2]]);
      const double area = 0.5 * glm::length(glm::cross(b - a, c - a));
      const dvec3 m = (a + b + c) / 3.0;
      total += area;
      mean += area * m;
      for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j)
          second[j][i] += area / 12.0 * (9.0 * m[i] * m[j] + a[i] * a[j] + b[i] * b[j] + c[i] * c[j]);
    }
    if (total > 0) {
      mean /= total;
      for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j) cov[j][i] = second[j][i] / total - mean[i] * mean[j];
    }
  } else {
    dvec3 mean(0.0);
    for (const glm::vec3& p : points) mean += dvec3(p);
    mean /= double(points.size());
    for (const glm::vec3& p : points) {
      const dvec3 d = dvec3(p) - mean;
      for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j) cov[j][i] += d[i] * d[j];
    }
  }
  const dmat3 v = eigenvectors(cov);
  return fit_box(points, to_basis(v[0], v[1]));
}

Obb dito_obb(std::span<const glm::vec3> points) {
  check_points(points);
  // 7 directions: the axes and the 4 cube diagonals.
  static const dvec3 dirs[7] = {{1, 0, 0}, {0, 1, 0}, {0, 0, 1}, {1, 1, 1}, {1, 1, -1}, {1, -1, 1}, {1, -1, -1}};
  std::vector<dvec3> ext;
  for (const dvec3& d : dirs) {
    const auto [lo, hi] = extremes(points, d);
    ext.push_back(dvec3(points[lo]));
    ext.push_back(dvec3(points[hi]));
  }
  const Obb aabb_box = fit_box(points, glm::mat3(1.0f));
  // Base triangle: the farthest pair of extremal points, then the extremal point farthest
  // from their line.
  std::size_t i0 = 0, i1 = 1;
  double far = -1;
  for (std::size_t i = 0; i < ext.size(); i += 2)
    if (const double d = glm::length(ext[i + 1] - ext[i]); d > far) far = d, i0 = i, i1 = i + 1;
  if (far <= 0) return aabb_box;  // all points coincide
  const dvec3 p0 = ext[i0], p1 = ext[i1];
  const dvec3 e0 = glm::normalize(p1 - p0);
  std::size_t i2 = 0;
  far = -1;
  for (std::size_t i = 0; i < ext.size(); ++i)
    if (const double d = glm::length(glm::cross(ext[i] - p0, e0)); d > far) far = d, i2 = i;
  std::vector<std::array<dvec3, 3>> frames;
  auto add_triangle_frames = [&](const dvec3& a, const dvec3& b, const dvec3& c) {
    const dvec3 n = glm::cross(b - a, c - a);
    if (glm::length(n) <= 1e-300) return;
    const dvec3 nn = glm::normalize(n);
    for (const dvec3& edge : {b - a, c - b, a - c}) {
      if (glm::length(edge) <= 1e-300) continue;
      const dvec3 u = glm::normalize(edge);
      frames.push_back({u, nn, glm::cross(u, nn)});
    }
  };
  if (far <= 1e-12 * glm::length(p1 - p0)) {
    // Collinear extremal points: the line and any two directions orthogonal to it.
    const dvec3 v = orthogonal(e0);
    frames.push_back({e0, v, glm::cross(e0, v)});
  } else {
    const dvec3 p2 = ext[i2];
    add_triangle_frames(p0, p1, p2);
    // Apex points: extreme along the base triangle's normal, on both sides.
    const dvec3 n = glm::normalize(glm::cross(p1 - p0, p2 - p0));
    const auto [lo, hi] = extremes(points, n);
    for (const dvec3 q : {dvec3(points[lo]), dvec3(points[hi])}) {
      if (std::abs(glm::dot(q - p0, n)) <= 1e-12 * glm::length(p1 - p0)) continue;
      add_triangle_frames(p0, p1, q);
      add_triangle_frames(p1, p2, q);
      add_triangle_frames(p2, p0, q);
    }
  }
  double best_q = std::numeric_limits<double>::infinity();
  std::array<dvec3, 3> best = frames.front();
  for (const auto& f : frames)
    if (const double q = frame_quality(ext, f[0], f[1], f[2]); q < best_q) best_q = q, best = f;
  const Obb box = fit_box(points, to_basis(best[0], best[1]));
  return volume(box) < volume(aabb_box) ? box : aabb_box;
}

Obb hull_face_obb(std::span<const glm::vec3> points) { return hull_face_obb(points, convex_hull(points)); }

Obb hull_face_obb(std::span<const glm::vec3> points, const ConvexHull& hull) {
  check_points(points);
  if (hull.dimension != ConvexHull::Dimension::Polyhedron) {
    // Flat or lower: the best rectangle in the plane (or along the line), zero thickness.
    dvec3 n = hull.dimension == ConvexHull::Dimension::Polygon ? dvec3(hull.normal) : dvec3(0, 0, 1);
    if (hull.dimension == ConvexHull::Dimension::Segment)
      n = orthogonal(glm::normalize(dvec3(hull.vertices[1]) - dvec3(hull.vertices[0])));  // double: no float overflow
    if (hull.dimension == ConvexHull::Dimension::Point) return fit_box(points, glm::mat3(1.0f));
    const dvec3 u = orthogonal(n), v = glm::cross(n, u);
    std::vector<std::array<double, 2>> proj;
    for (const glm::vec3& p : hull.vertices) proj.push_back({glm::dot(dvec3(p), u), glm::dot(dvec3(p), v)});
    const Rect r = min_area_rect(hull2d(proj));
    return fit_box(points, to_basis(u * r.ux + v * r.uy, n));
  }
  const std::vector<glm::vec3>& hv = hull.vertices;
  const std::size_t nf = hull.faces.size();
  std::vector<dvec3> normal(nf, dvec3(0.0));
  for (std::size_t f = 0; f < nf; ++f) {
    const auto& t = hull.faces[f];
    const dvec3 raw = glm::cross(dvec3(hv[t[1]]) - dvec3(hv[t[0]]), dvec3(hv[t[2]]) - dvec3(hv[t[0]]));
    if (glm::length(raw) > 0) normal[f] = glm::normalize(raw);
  }
  // Coplanar neighbouring triangles form one hull face and give the same box: label each
  // group once (flood fill over neighbours with the same normal).
  std::vector<std::uint32_t> group(nf, ~0u);
  std::vector<std::size_t> representatives;
  for (std::size_t f = 0; f < nf; ++f) {
    if (group[f] != ~0u || glm::length(normal[f]) == 0) continue;
    group[f] = std::uint32_t(representatives.size());
    representatives.push_back(f);
    std::vector<std::size_t> stack = {f};
    while (!stack.empty()) {
      const std::size_t g = stack.back();
      stack.pop_back();
      for (std::uint32_t h : hull.face_neighbours[g])
        if (group[h] == ~0u && glm::dot(normal[h], normal[f]) > 1 - 1e-12) {
          group[h] = group[f];
          stack.push_back(h);
        }
    }
  }
  // Faces around each vertex, to find the outline of the hull seen along a direction.
  std::vector<std::vector<std::uint32_t>> vertex_faces(hv.size());
  for (std::size_t f = 0; f < nf; ++f)
    for (std::uint32_t v : hull.faces[f]) vertex_faces[v].push_back(std::uint32_t(f));

  double best_volume = std::numeric_limits<double>::infinity();
  glm::mat3 best_basis(1.0f);
  std::vector<std::array<double, 2>> proj;
  for (std::size_t f : representatives) {
    const dvec3 n = normal[f];
    const dvec3 a(hv[hull.faces[f][0]]), b(hv[hull.faces[f][1]]);
    const dvec3 u = glm::normalize(b - a), v = glm::cross(n, u);
    // Only outline vertices (with faces turned towards and away from n around them) can be
    // corners of the projection's 2D hull.
    proj.clear();
    double depth = 0;
    const double top = glm::dot(n, a);
    for (std::size_t i = 0; i < hv.size(); ++i) {
      const dvec3 q(hv[i]);
      depth = std::max(depth, top - glm::dot(q, n));
      bool towards = false, away = false;
      for (std::uint32_t g : vertex_faces[i]) {
        const double s = glm::dot(normal[g], n);
        towards |= s >= -1e-12;
        away |= s <= 1e-12;
      }
      if (towards && away) proj.push_back({glm::dot(q, u), glm::dot(q, v)});
    }
    const Rect r = min_area_rect(hull2d(proj));
    const double vol = r.area * depth;
    if (vol < best_volume) {
      best_volume = vol;
      best_basis = to_basis(u * r.ux + v * r.uy, n);
    }
  }
  return fit_box(points, best_basis);
}

Obb transform_obb(const Obb& b, const glm::mat4& m) {
  // The box is the cube [-h, h] in its own frame: compose frame and transform in double.
  glm::dmat4 frame(1.0);
  for (int k = 0; k < 3; ++k) frame[k] = glm::dvec4(dvec3(b.basis[k]), 0.0);
  frame[3] = glm::dvec4(dvec3(b.center), 1.0);
  return Obb::from_transformed_aabb(Aabb{-b.half_extents, b.half_extents}, glm::dmat4(m) * frame);
}

}  // namespace cullpipe::bounds
