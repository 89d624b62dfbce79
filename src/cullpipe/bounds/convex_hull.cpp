#include "cullpipe/bounds/convex_hull.hpp"

#include <algorithm>
#include <cfloat>
#include <cmath>
#include <glm/geometric.hpp>
#include <tuple>

#include "cullpipe/bounds/points.hpp"

namespace cullpipe::bounds {
namespace {

using dvec3 = glm::dvec3;
constexpr std::uint32_t kNone = 0xFFFFFFFFu;

struct Face {
  std::uint32_t v[3];
  std::uint32_t nb[3];  // nb[i]: across edge v[i] -> v[(i+1)%3]
  dvec3 n;
  double d;
  bool alive = true;
  bool visited = false;
  std::vector<std::uint32_t> outside;
  double distance(const dvec3& p) const { return glm::dot(n, p) + d; }
};

class Quickhull {
 public:
  Quickhull(const std::vector<dvec3>& pts, double tol) : p_(pts), tol_(tol) {}

  // Builds the hull from a non-degenerate tetrahedron (a, b, c, d).
  void run(std::uint32_t a, std::uint32_t b, std::uint32_t c, std::uint32_t d) {
    // Orient so (a, b, c) faces away from d.
    if (glm::dot(glm::cross(p_[b] - p_[a], p_[c] - p_[a]), p_[d] - p_[a]) > 0) std::swap(b, c);
    const std::uint32_t f0 = add_face(a, b, c), f1 = add_face(a, d, b), f2 = add_face(b, d, c), f3 = add_face(c, d, a);
    link(f0, 0, f1, 2);  // a-b
    link(f0, 1, f2, 2);  // b-c
    link(f0, 2, f3, 2);  // c-a
    link(f1, 0, f3, 1);  // a-d
    link(f1, 1, f2, 0);  // d-b
    link(f2, 1, f3, 0);  // d-c
    const std::uint32_t initial[4] = {f0, f1, f2, f3};
    for (std::uint32_t i = 0; i < p_.size(); ++i) {
      if (i == a || i == b || i == c || i == d) continue;
      assign(i, initial, 4);
    }
    for (std::uint32_t f : initial) pending_.push_back(f);

    while (!pending_.empty()) {
      const std::uint32_t f = pending_.back();
      pending_.pop_back();
      if (!faces_[f].alive || faces_[f].outside.empty()) continue;
      add_point(f);
    }
  }

  std::vector<Face> faces_;

 private:
  std::uint32_t add_face(std::uint32_t a, std::uint32_t b, std::uint32_t c) {
    Face f;
    f.v[0] = a;
    f.v[1] = b;
    f.v[2] = c;
    f.nb[0] = f.nb[1] = f.nb[2] = kNone;
    const dvec3 n = glm::cross(p_[b] - p_[a], p_[c] - p_[a]);
    const double len = glm::length(n);
    f.n = len > 0 ? n / len : dvec3(0.0);
    f.d = -glm::dot(f.n, p_[a]);
    faces_.push_back(std::move(f));
    return std::uint32_t(faces_.size() - 1);
  }

  void link(std::uint32_t f, int ei, std::uint32_t g, int ej) {
    faces_[f].nb[ei] = g;
    faces_[g].nb[ej] = f;
  }

  // Gives point i to the first of `candidates` it is above; otherwise it is inside.
  void assign(std::uint32_t i, const std::uint32_t* candidates, std::size_t count) {
    std::uint32_t best = kNone;
    double best_d = tol_;
    for (std::size_t k = 0; k < count; ++k) {
      const double dist = faces_[candidates[k]].distance(p_[i]);
      if (dist > best_d) {
        best_d = dist;
        best = candidates[k];
      }
    }
    if (best != kNone) faces_[best].outside.push_back(i);
  }

  // Depth-first walk over the faces visible from `eye`, starting at f, collecting the horizon
  // edges in counter-clockwise order (iterative: the visible region can be large).
  void horizon(const dvec3& eye, std::uint32_t start) {
    struct Frame {
      std::uint32_t face;
      int entered;  // edge through which the walk entered, -1 for the start face
      int next;     // how many of the face's other edges were handled
    };
    std::vector<Frame> stack = {{start, -1, 0}};
    faces_[start].visited = true;
    visible_.push_back(start);
    while (!stack.empty()) {
      Frame& fr = stack.back();
      const int edges = fr.entered < 0 ? 3 : 2;
      if (fr.next == edges) {
        stack.pop_back();
        continue;
      }
      const int e = fr.entered < 0 ? fr.next : (fr.entered + 1 + fr.next) % 3;
      ++fr.next;
      const std::uint32_t f = fr.face, g = faces_[f].nb[e];
      if (faces_[g].visited) continue;
      // A neighbour counts as visible when the eye is above it, or in its plane (within the
      // tolerance): keeping such a face would pair its edge with an eye lying on the same
      // plane (often on the edge's own line, in CAD models), making a flat or zero-area face
      // with no usable normal. Replacing it fans the coplanar region to the eye instead.
      if (faces_[g].distance(eye) > -tol_) {
        faces_[g].visited = true;
        visible_.push_back(g);
        stack.push_back({g, edge_of(g, faces_[f].v[(e + 1) % 3], faces_[f].v[e]), 0});
      } else {
        horizon_.push_back({f, e});
      }
    }
  }

  // The edge index i of face g that runs from vertex a to vertex b.
  int edge_of(std::uint32_t g, std::uint32_t a, std::uint32_t b) const {
    for (int i = 0; i < 3; ++i)
      if (faces_[g].v[i] == a && faces_[g].v[(i + 1) % 3] == b) return i;
    return 0;  // unreachable on a consistent mesh
  }

  void add_point(std::uint32_t f) {
    // The farthest outside point of f.
    Face& face = faces_[f];
    std::uint32_t eye_index = face.outside[0];
    double far = -1.0;
    for (std::uint32_t i : face.outside) {
      const double dist = face.distance(p_[i]);
      if (dist > far) {
        far = dist;
        eye_index = i;
      }
    }
    const dvec3 eye = p_[eye_index];
    visible_.clear();
    horizon_.clear();
    horizon(eye, f);

    // New faces: one per horizon edge, joined to the eye.
    const std::size_t first_new = faces_.size();
    for (const auto& [hf, e] : horizon_) {
      const std::uint32_t a = faces_[hf].v[e], b = faces_[hf].v[(e + 1) % 3];
      const std::uint32_t across = faces_[hf].nb[e];
      const std::uint32_t nf = add_face(a, b, eye_index);
      faces_[across].nb[edge_of(across, b, a)] = nf;
      faces_[nf].nb[0] = across;
    }
    const std::size_t count = faces_.size() - first_new;
    for (std::size_t k = 0; k < count; ++k) {
      const std::uint32_t cur = std::uint32_t(first_new + k);
      const std::uint32_t next = std::uint32_t(first_new + (k + 1) % count);
      faces_[cur].nb[1] = next;  // b -> eye is shared with the next face's eye -> a
      faces_[next].nb[2] = cur;
    }

    // Retire the visible faces and hand their points to the new faces.
    std::vector<std::uint32_t> new_faces(count);
    for (std::size_t k = 0; k < count; ++k) new_faces[k] = std::uint32_t(first_new + k);
    for (std::uint32_t v : visible_) {
      faces_[v].alive = false;
      std::vector<std::uint32_t> orphans;
      orphans.swap(faces_[v].outside);
      for (std::uint32_t i : orphans)
        if (i != eye_index) assign(i, new_faces.data(), count);
    }
    for (std::uint32_t nf : new_faces)
      if (!faces_[nf].outside.empty()) pending_.push_back(nf);
  }

  const std::vector<dvec3>& p_;
  double tol_;
  std::vector<std::uint32_t> pending_;
  std::vector<std::uint32_t> visible_;
  std::vector<std::pair<std::uint32_t, int>> horizon_;
};

// Andrew's monotone chain on points projected to the plane (u, v); counter-clockwise.
std::vector<std::uint32_t> hull_2d(const std::vector<dvec3>& p, const dvec3& u, const dvec3& v) {
  std::vector<std::uint32_t> idx(p.size());
  for (std::uint32_t i = 0; i < idx.size(); ++i) idx[i] = i;
  auto uv = [&](std::uint32_t i) { return std::pair<double, double>(glm::dot(p[i], u), glm::dot(p[i], v)); };
  std::sort(idx.begin(), idx.end(), [&](std::uint32_t a, std::uint32_t b) { return uv(a) < uv(b); });
  auto cross = [&](std::uint32_t o, std::uint32_t a, std::uint32_t b) {
    const auto [ox, oy] = uv(o);
    const auto [ax, ay] = uv(a);
    const auto [bx, by] = uv(b);
    // A certain left turn: larger than the double rounding of the determinant can reach
    // (8 DBL_EPSILON times the sum of its two products' magnitudes, above Shewchuk's 3u
    // filter), so the ring is convex in (u, v) exactly and a walk over it cannot stop at a
    // local maximum beyond the rounding of its own comparisons. A point dropped as uncertain
    // lies within that rounding of its chord: under 14 DBL_EPSILON times the larger (u, v)
    // distance, so under 28 DBL_EPSILON times the magnitude; the hull's margin (48) leaves
    // room for a dropped point's chord to have been dropped in turn once.
    const double left = (ax - ox) * (by - oy), right = (ay - oy) * (bx - ox);
    return left - right > 8.0 * DBL_EPSILON * (std::abs(left) + std::abs(right));
  };
  std::vector<std::uint32_t> h(2 * idx.size());
  std::size_t k = 0;
  for (std::uint32_t i : idx) {
    while (k >= 2 && !cross(h[k - 2], h[k - 1], i)) --k;
    h[k++] = i;
  }
  for (std::size_t t = idx.size() - 1, lower = k + 1; t-- > 0;) {
    const std::uint32_t i = idx[t];
    while (k >= lower && !cross(h[k - 2], h[k - 1], i)) --k;
    h[k++] = i;
  }
  h.resize(k > 1 ? k - 1 : k);
  return h;
}

}  // namespace

ConvexHull convex_hull(std::span<const glm::vec3> points) {
  check_points(points);
  // Exact duplicates are dropped first (they would only make zero-area faces); `unique_index`
  // maps the remaining points back to the input.
  std::vector<std::uint32_t> unique_index(points.size());
  for (std::uint32_t i = 0; i < unique_index.size(); ++i) unique_index[i] = i;
  auto key = [&](std::uint32_t i) { return std::tuple(points[i].x, points[i].y, points[i].z); };
  std::sort(unique_index.begin(), unique_index.end(),
            [&](std::uint32_t x, std::uint32_t y) { return key(x) < key(y); });
  unique_index.erase(std::unique(unique_index.begin(), unique_index.end(),
                                 [&](std::uint32_t x, std::uint32_t y) { return key(x) == key(y); }),
                     unique_index.end());
  std::vector<glm::vec3> unique_points;
  std::vector<dvec3> p;
  for (std::uint32_t i : unique_index) {
    unique_points.push_back(points[i]);
    p.push_back(dvec3(points[i]));
  }
  dvec3 max_abs(0.0);
  for (const dvec3& q : p) max_abs = glm::max(max_abs, glm::abs(q));
  ConvexHull hull;
  // Two tolerances: a float-precision one decides whether the set is degenerate (flat,
  // collinear or one point to float precision), a double-precision one (Lloyd's) decides
  // visibility inside Quickhull, where a larger value would let non-convex edges grow.
  const double magnitude = max_abs.x + max_abs.y + max_abs.z;
  const double tol = 3.0 * FLT_EPSILON * magnitude;
  const double hull_tol = 3.0 * DBL_EPSILON * magnitude;
  hull.tolerance = tol;

  auto finish = [&](std::vector<std::uint32_t> input) {
    for (std::uint32_t i : input) {
      hull.vertices.push_back(unique_points[i]);
      hull.input_index.push_back(unique_index[i]);
    }
    hull.vertex_neighbours.assign(input.size(), {});
  };

  // The most separated pair of axis-extreme points seeds the simplex.
  const auto [seed_a, seed_b] = most_separated_axis_extremes(unique_points);
  const std::uint32_t a = std::uint32_t(seed_a), b = std::uint32_t(seed_b);
  // For the lower-dimensional hulls the tolerance is measured: the largest distance of any
  // point from the point, line or plane of the result, plus the polyhedron's rounding margin
  // (16 x Lloyd's tolerance). The margin covers what the measure does not: a point the
  // in-line or in-plane hull dropped by rounding (its ends and ring are chosen on double
  // projections) may lie outside by a few ulps of the magnitude, which matters beside tiny
  // coordinates (subnormal points beside unit ones, say).
  const double rounding_margin = 16.0 * hull_tol;
  if (glm::length(p[b] - p[a]) <= tol) {
    hull.dimension = ConvexHull::Dimension::Point;
    finish({a});
    hull.tolerance = 0.0;
    for (const dvec3& q : p) hull.tolerance = std::max(hull.tolerance, glm::length(q - p[a]));
    hull.tolerance += rounding_margin;
    return hull;
  }

  // Farthest from the line ab.
  const dvec3 dir = glm::normalize(p[b] - p[a]);
  std::uint32_t c = a;
  double best = -1.0;
  for (std::uint32_t i = 0; i < p.size(); ++i) {
    const double dist = glm::length(glm::cross(p[i] - p[a], dir));
    if (dist > best) {
      best = dist;
      c = i;
    }
  }
  if (best <= tol) {
    hull.dimension = ConvexHull::Dimension::Segment;
    // The two ends along the line.
    std::uint32_t s0 = a, s1 = a;
    for (std::uint32_t i = 0; i < p.size(); ++i) {
      const double t = glm::dot(p[i] - p[a], dir);
      if (t < glm::dot(p[s0] - p[a], dir)) s0 = i;
      if (t > glm::dot(p[s1] - p[a], dir)) s1 = i;
    }
    finish({s0, s1});
    hull.vertex_neighbours = {{1}, {0}};
    const dvec3 line = glm::normalize(p[s1] - p[s0]);
    hull.tolerance = 0.0;
    for (const dvec3& q : p) hull.tolerance = std::max(hull.tolerance, glm::length(glm::cross(q - p[s0], line)));
    hull.tolerance += rounding_margin;
    return hull;
  }

  // Farthest from the plane abc.
  const dvec3 n = glm::normalize(glm::cross(p[b] - p[a], p[c] - p[a]));
  std::uint32_t d = a;
  best = -1.0;
  for (std::uint32_t i = 0; i < p.size(); ++i) {
    const double dist = std::abs(glm::dot(p[i] - p[a], n));
    if (dist > best) {
      best = dist;
      d = i;
    }
  }
  if (best <= tol) {
    hull.dimension = ConvexHull::Dimension::Polygon;
    hull.normal = glm::vec3(n);
    const dvec3 u = dir, v = glm::cross(n, dir);
    hull.plane_u = u;
    hull.plane_v = v;
    const std::vector<std::uint32_t> ring = hull_2d(p, u, v);
    finish(ring);
    hull.tolerance = 0.0;
    // Measured from the plane through vertices[0] with normal plane_u x plane_v, which users of
    // the hull can rebuild (AabbTracker walks the ring in that frame).
    const dvec3 plane_n = glm::cross(u, v), first(hull.vertices[0]);
    for (const dvec3& q : p)
      hull.tolerance = std::max(hull.tolerance, std::abs(glm::dot(q - first, plane_n)) / glm::length(plane_n));
    hull.tolerance += rounding_margin;
    const std::uint32_t m = std::uint32_t(ring.size());
    for (std::uint32_t i = 0; i < m; ++i) {
      hull.vertex_neighbours[i] = {(i + m - 1) % m, (i + 1) % m};
      std::sort(hull.vertex_neighbours[i].begin(), hull.vertex_neighbours[i].end());
      hull.vertex_neighbours[i].erase(std::unique(hull.vertex_neighbours[i].begin(), hull.vertex_neighbours[i].end()),
                                      hull.vertex_neighbours[i].end());
    }
    return hull;
  }

  hull.dimension = ConvexHull::Dimension::Polyhedron;
  hull.tolerance = 16.0 * hull_tol;  // margin for rounding accumulated over the build
  Quickhull qh(p, hull_tol);
  qh.run(a, b, c, d);

  // Compact: live faces, used vertices renumbered.
  std::vector<std::uint32_t> vertex_id(p.size(), kNone), face_id(qh.faces_.size(), kNone);
  std::vector<std::uint32_t> used;
  for (std::uint32_t f = 0; f < qh.faces_.size(); ++f) {
    if (!qh.faces_[f].alive) continue;
    face_id[f] = std::uint32_t(hull.faces.size());
    std::array<std::uint32_t, 3> tri;
    for (int k = 0; k < 3; ++k) {
      const std::uint32_t v = qh.faces_[f].v[k];
      if (vertex_id[v] == kNone) {
        vertex_id[v] = std::uint32_t(used.size());
        used.push_back(v);
      }
      tri[std::size_t(k)] = vertex_id[v];
    }
    hull.faces.push_back(tri);
  }
  finish(used);
  // A live face whose neighbour was retired (near-degenerate input can leave the horizon
  // inconsistent, and this Quickhull does not merge faces) has lost its adjacency across that
  // edge: the hull is flagged, and the face lists itself there, so every index in
  // face_neighbours stays a face of the hull for whoever walks it.
  for (std::uint32_t f = 0; f < qh.faces_.size(); ++f) {
    if (!qh.faces_[f].alive) continue;
    std::array<std::uint32_t, 3> nb;
    for (int k = 0; k < 3; ++k) {
      const std::uint32_t g = qh.faces_[f].nb[k];
      nb[std::size_t(k)] = g < face_id.size() && face_id[g] != kNone ? face_id[g] : face_id[f];
      if (nb[std::size_t(k)] == face_id[f]) hull.valid = false;
    }
    hull.face_neighbours.push_back(nb);
  }
  for (const auto& tri : hull.faces)
    for (int k = 0; k < 3; ++k) hull.vertex_neighbours[tri[std::size_t(k)]].push_back(tri[std::size_t((k + 1) % 3)]);
  // Every edge a->b of a closed triangle mesh also appears as b->a in the neighbouring face,
  // so the lists are symmetric; sort them for binary search and stable output.
  for (auto& list : hull.vertex_neighbours) std::sort(list.begin(), list.end());

  // Validation: adjacency reciprocal, no zero-area face, and every edge convex to within the
  // declared tolerance (the neighbour's far vertex not above the face). Near-degenerate
  // input (clusters of almost equal points, slivers) can defeat a Quickhull without face
  // merging; such a hull is flagged rather than trusted.
  const std::vector<glm::vec3>& hv = hull.vertices;
  for (std::size_t f = 0; f < hull.faces.size() && hull.valid; ++f) {
    const auto& t = hull.faces[f];
    const dvec3 raw = glm::cross(dvec3(hv[t[1]]) - dvec3(hv[t[0]]), dvec3(hv[t[2]]) - dvec3(hv[t[0]]));
    if (!(glm::length(raw) > 0.0)) {
      hull.valid = false;
      break;
    }
    const dvec3 fn = glm::normalize(raw);
    for (int k = 0; k < 3 && hull.valid; ++k) {
      const std::uint32_t g = hull.face_neighbours[f][std::size_t(k)];
      const auto& gt = hull.faces[g];
      bool back = false;
      for (int j = 0; j < 3; ++j) back |= hull.face_neighbours[g][std::size_t(j)] == f;
      double above = 0.0;
      for (std::uint32_t w : gt) above = std::max(above, glm::dot(fn, dvec3(hv[w]) - dvec3(hv[t[0]])));
      if (!back || above > hull.tolerance) hull.valid = false;
    }
  }
  return hull;
}

}  // namespace cullpipe::bounds
