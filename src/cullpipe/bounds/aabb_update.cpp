#include "cullpipe/bounds/aabb_update.hpp"

#include <cfloat>
#include <cmath>
#include <glm/geometric.hpp>
#include <limits>

#include "cullpipe/bounds/sphere_fit.hpp"
#include "cullpipe/geom/rounding.hpp"

namespace cullpipe::bounds {
namespace {

using dvec3 = glm::dvec3;

Aabb round_outward(const dvec3& lo, const dvec3& hi) {
  return {{round_down(lo.x), round_down(lo.y), round_down(lo.z)}, {round_up(hi.x), round_up(hi.y), round_up(hi.z)}};
}

// Row i of the linear part of m, as the local direction whose dot product gives world axis i.
dvec3 row(const glm::mat4& m, int i) { return {m[0][i], m[1][i], m[2][i]}; }

template <class Points>
Aabb transform_points(const Points& pts, const glm::mat4& m, double pad) {
  const glm::dmat4 dm(m);
  dvec3 lo(std::numeric_limits<double>::infinity()), hi(-std::numeric_limits<double>::infinity());
  for (const glm::vec3& p : pts) {
    const dvec3 q = dvec3(dm * glm::dvec4(dvec3(p), 1.0));
    lo = glm::min(lo, q);
    hi = glm::max(hi, q);
  }
  dvec3 pads;
  for (int i = 0; i < 3; ++i) pads[i] = pad * glm::length(row(m, i));
  return round_outward(lo - pads, hi + pads);
}

}  // namespace

std::string_view to_string(AabbUpdate method) {
  switch (method) {
    case AabbUpdate::Recompute:
      return "recompute";
    case AabbUpdate::HullRecompute:
      return "hull";
    case AabbUpdate::TransformBox:
      return "transform-box";
    case AabbUpdate::HillClimb:
      return "hill-climb";
  }
  return "?";
}

std::optional<AabbUpdate> parse_aabb_update(std::string_view name) {
  for (AabbUpdate m :
       {AabbUpdate::Recompute, AabbUpdate::HullRecompute, AabbUpdate::TransformBox, AabbUpdate::HillClimb})
    if (to_string(m) == name) return m;
  return std::nullopt;
}

AabbTracker::AabbTracker(std::span<const glm::vec3> local_points)
    : points_(local_points.begin(), local_points.end()),
      hull_(convex_hull(local_points)),
      local_(aabb_of_points(local_points)) {
  // Climb over the hull vertices; for a linear hull, over their projections onto its line; for
  // a flat one, over its ring in the ring's own plane coordinates (U, V along plane_u and
  // plane_v), where it is convex exactly, with the plane's normal n = plane_u x plane_v, the
  // one the hull's tolerance is measured from. A point is U u + V v + N n (to rounding far
  // inside the hull's margin), so dir . p is du U + dv V + dn N, and N lies within the
  // tolerance of the plane's N. Both the walk and the value it reports use that form: 3D
  // projections round by about the magnitude's ulp, which scrambles the order of ring
  // vertices far closer together than that (a tiny cluster beside large points), where a walk
  // stopped inside the cluster, far from the maximum. Off-plane scatter is covered by the
  // tolerance padding; climbing over the raw points could stop at a local maximum it creates.
  const dvec3 origin(hull_.vertices[0]);
  if (hull_.dimension == ConvexHull::Dimension::Polygon) {
    plane_n_ = glm::cross(hull_.plane_u, hull_.plane_v);
    plane_c_ = glm::dot(origin, plane_n_);
  }
  for (const glm::vec3& v : hull_.vertices) {
    dvec3 q(v);
    if (hull_.dimension == ConvexHull::Dimension::Segment) {
      const dvec3 line = glm::normalize(dvec3(hull_.vertices[1]) - origin);
      q = origin + glm::dot(q - origin, line) * line;
    }
    climb_points_.push_back(q);
    if (hull_.dimension == ConvexHull::Dimension::Polygon)
      ring_uv_.push_back({glm::dot(dvec3(v), hull_.plane_u), glm::dot(dvec3(v), hull_.plane_v)});
  }
  // Start every climb at the vertex extreme along the local axes.
  for (int axis = 0; axis < 3; ++axis)
    for (std::uint32_t v = 0; v < hull_.vertices.size(); ++v) {
      if (hull_.vertices[v][axis] < hull_.vertices[extreme_[std::size_t(2 * axis)]][axis])
        extreme_[std::size_t(2 * axis)] = v;
      if (hull_.vertices[v][axis] > hull_.vertices[extreme_[std::size_t(2 * axis + 1)]][axis])
        extreme_[std::size_t(2 * axis + 1)] = v;
    }
  initial_extreme_ = extreme_;
  // A walk finds the maximum only where the surface is convex: a hull that passed validation
  // may still fold inward by up to its tolerance at an edge, and along a direction nearly
  // tangent to a long face such a fold can hold a walk far below the maximum. Walk only a
  // hull with no edge certainly concave: for each edge, the far vertex of the face across it
  // is not above this face's plane beyond the rounding of the orientation determinant
  // (8 DBL_EPSILON times its permanent, above Shewchuk's orient3d bound); otherwise hill
  // climbing transforms the hull vertices instead. (Folds at the rounding level pass this
  // test and remain: see aabb_update.hpp.)
  if (hull_.dimension == ConvexHull::Dimension::Polyhedron && hull_.valid) {
    const std::vector<glm::vec3>& hv = hull_.vertices;
    for (std::size_t f = 0; f < hull_.faces.size() && climb_safe_; ++f) {
      const auto& t = hull_.faces[f];
      const dvec3 a(hv[t[0]]), u = dvec3(hv[t[1]]) - a, v = dvec3(hv[t[2]]) - a;
      for (std::uint32_t g : hull_.face_neighbours[f])
        for (std::uint32_t corner : hull_.faces[g]) {
          const dvec3 w = dvec3(hv[corner]) - a;
          const double det =
              u.x * (v.y * w.z - v.z * w.y) + u.y * (v.z * w.x - v.x * w.z) + u.z * (v.x * w.y - v.y * w.x);
          const double permanent = std::abs(u.x) * (std::abs(v.y * w.z) + std::abs(v.z * w.y)) +
                                   std::abs(u.y) * (std::abs(v.z * w.x) + std::abs(v.x * w.z)) +
                                   std::abs(u.z) * (std::abs(v.x * w.y) + std::abs(v.y * w.x));
          if (det > 8.0 * DBL_EPSILON * permanent) climb_safe_ = false;
        }
    }
  }
}

Aabb AabbTracker::update(const glm::mat4& world, AabbUpdate method) {
  return update(world, method, extreme_, &climb_steps_);
}

Aabb AabbTracker::update(const glm::mat4& world, AabbUpdate method, Extremes& extremes, std::size_t* steps) const {
  // A hull that failed validation may not contain the points: use every point instead.
  if (!hull_.valid && (method == AabbUpdate::HullRecompute || method == AabbUpdate::HillClimb))
    method = AabbUpdate::Recompute;
  // A hull with an edge certainly folded inward is not walked (see the constructor).
  if (method == AabbUpdate::HillClimb && !climb_safe_) {
    if (steps) *steps = 0;  // no walk
    method = AabbUpdate::HullRecompute;
  }
  switch (method) {
    case AabbUpdate::Recompute:
      return transform_points(points_, world, 0.0);
    case AabbUpdate::HullRecompute: {
      // A flat or linear hull's vertices lie up to the tolerance off its plane or line, and a
      // point up to the tolerance off it on the other side: twice the tolerance from the
      // vertices' polygon. A polyhedron's points lie within the tolerance of its faces.
      const bool flat =
          hull_.dimension == ConvexHull::Dimension::Segment || hull_.dimension == ConvexHull::Dimension::Polygon;
      return transform_points(hull_.vertices, world, flat ? 2.0 * hull_.tolerance : hull_.tolerance);
    }
    case AabbUpdate::TransformBox:
      return local_.transformed(world);
    case AabbUpdate::HillClimb:
      break;
  }
  // Hill climbing: for world axis i, maximise (and minimise) row_i(M) . p over hull vertices by
  // moving to a better neighbour until none is better. On a convex polytope a local maximum of
  // a linear function is the global one.
  std::size_t climb_steps = 0;
  const glm::dmat4 dm(world);
  dvec3 lo, hi;
  for (int axis = 0; axis < 3; ++axis) {
    const dvec3 r = row(world, axis);
    for (int side = 0; side < 2; ++side) {
      const dvec3 dir = side ? r : -r;
      std::uint32_t& v = extremes[std::size_t(2 * axis + side)];
      // A flat hull's ring is walked in its plane coordinates (see the constructor).
      const glm::dvec2 in_plane =
          ring_uv_.empty() ? glm::dvec2(0.0) : glm::dvec2(glm::dot(dir, hull_.plane_u), glm::dot(dir, hull_.plane_v));
      const auto key = [&](std::uint32_t w) {
        return ring_uv_.empty() ? glm::dot(dir, climb_points_[w]) : glm::dot(in_plane, ring_uv_[w]);
      };
      double best = key(v);
      for (bool moved = true; moved;) {
        moved = false;
        for (std::uint32_t w : hull_.vertex_neighbours[v]) {
          const double value = key(w);
          if (value > best) {
            best = value;
            v = w;
            moved = true;
          }
        }
        ++climb_steps;
      }
      const double world_value =
          (ring_uv_.empty()
               ? glm::dot(r, climb_points_[v])
               : glm::dot(glm::dvec2(glm::dot(r, hull_.plane_u), glm::dot(r, hull_.plane_v)), ring_uv_[v]) +
                     glm::dot(r, plane_n_) * plane_c_) +
          dm[3][axis];
      (side ? hi : lo)[axis] = world_value;
    }
  }
  if (steps) *steps = climb_steps;
  dvec3 pads;
  for (int i = 0; i < 3; ++i) pads[i] = hull_.tolerance * glm::length(row(world, i));
  return round_outward(lo - pads, hi + pads);
}

}  // namespace cullpipe::bounds
