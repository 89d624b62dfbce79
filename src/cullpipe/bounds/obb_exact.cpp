// Minimum-volume oriented bounding box: the hull-face candidates (one box face flush with a
// hull face, rectangle by rotating calipers) plus a sweep over every one-parameter family of
// boxes with two adjacent faces flush with hull edges (O'Rourke 1985: a minimal box has a face
// flush with a hull face, or two adjacent faces flush with hull edges).
//
// Family for edges (e1, e2): n1 runs along e1's arc on the Gauss sphere (the outward directions
// whose supporting plane contains e1), n2 = normalise(e2 x n1) (so e2 lies in a face normal to
// n2 when the plane through e2 supports the hull), n3 = n1 x n2. Along the family the support
// vertices in the six box directions change only at events, where the direction crosses the
// arc of an edge at the current support vertex; each event time is a root of a linear (n1, n2)
// or quadratic (n3) trigonometric equation. Between events the volume is a smooth function of
// the parameter, minimised by golden-section search; the events themselves are the edge
// triplets Jylanki (2015) enumerates, and the pieces' interiors cover O'Rourke's remaining
// case, so the search does not rely on Jylanki's conjecture.
#include <algorithm>
#include <array>
#include <cmath>
#include <glm/geometric.hpp>
#include <limits>
#include <vector>

#include "cullpipe/bounds/convex_hull.hpp"
#include "cullpipe/bounds/obb_fit.hpp"
#include "cullpipe/bounds/points.hpp"

namespace cullpipe::bounds {
namespace {

using dvec3 = glm::dvec3;
constexpr double kPi = 3.14159265358979323846;

struct Edge {
  std::uint32_t a, b;  // vertex indices
  dvec3 fa, fb;        // unit normals of the two adjacent faces: the ends of the edge's arc
};

// A few roots, without allocation.
struct Roots {
  double t[24];
  int n = 0;
  void push(double v) {
    if (n < 24) t[n++] = v;
  }
};

// Roots of A cos t + B sin t = C in (lo, hi] (the interval spans less than 4 pi).
void trig_roots(double A, double B, double C, double lo, double hi, Roots& out) {
  const double R = std::hypot(A, B);
  if (R < 1e-300 || std::abs(C) > R) return;
  const double phi = std::atan2(B, A), delta = std::acos(std::clamp(C / R, -1.0, 1.0));
  for (double base : {phi + delta, phi - delta})
    for (int k = -2; k <= 2; ++k) {
      const double t = base + 2.0 * kPi * k;
      if (t > lo && t <= hi) out.push(t);
    }
}

class Sweeper {
 public:
  Sweeper(const ConvexHull& hull) : hull_(hull) {
    for (const glm::vec3& v : hull.vertices) p_.push_back(dvec3(v));
    dvec3 lo(1e300), hi(-1e300);
    for (const dvec3& v : p_) lo = glm::min(lo, v), hi = glm::max(hi, v);
    diameter_ = glm::length(hi - lo);  // bounds every |p - q|
    build_support_table();
    for (std::size_t f = 0; f < hull.faces.size(); ++f) {
      const auto& t = hull.faces[f];
      const dvec3 n = glm::cross(p_[t[1]] - p_[t[0]], p_[t[2]] - p_[t[0]]);
      normals_.push_back(glm::length(n) > 0 ? glm::normalize(n) : dvec3(0.0));
      areas_.push_back(0.5 * n);
    }
    prune_ = hull.valid && hull.vertices.size() > 24;  // tiny hulls: the bounds cost more than they save
    {
      dvec3 c(0.0);
      for (const dvec3& v : p_) c += v;
      c /= double(p_.size());
      double rho = 1e300;
      for (std::size_t f = 0; f < hull.faces.size(); ++f)
        if (glm::length(normals_[f]) > 0) rho = std::min(rho, glm::dot(normals_[f], p_[hull.faces[f][0]] - c));
      min_width_ = std::max(0.0, 2.0 * rho * (1.0 - 1e-9));
    }
    for (std::size_t f = 0; f < hull.faces.size(); ++f)
      for (int k = 0; k < 3; ++k) {
        const std::uint32_t a = hull.faces[f][std::size_t(k)], b = hull.faces[f][std::size_t((k + 1) % 3)];
        if (a > b) continue;  // each edge once
        const std::uint32_t g = hull.face_neighbours[f][std::size_t(k)];
        const dvec3 fa = normals_[f], fb = normals_[g];
        if (glm::dot(fa, fb) > 1.0 - 1e-12 || glm::length(fa) == 0 || glm::length(fb) == 0)
          continue;  // flat edge: no arc
        edges_.push_back({a, b, fa, fb});
      }
  }

  // Best volume found; `best_axes` holds its n1, n2.
  double run(double best_volume) {
    best_ = best_volume;
    const std::size_t E = edges_.size();
    std::vector<Arc> arcs(E);
    std::vector<std::vector<Span>> live(E);
    std::vector<std::uint32_t> live_edges;
    for (std::size_t i = 0; i < E; ++i) {
      const Edge& e = edges_[i];
      Arc& A = arcs[i];
      A.a = e.fa;
      A.b = glm::normalize(e.fb - glm::dot(e.fb, e.fa) * e.fa);
      A.theta = std::acos(std::clamp(glm::dot(e.fa, e.fb), -1.0, 1.0));
      A.fb = e.fb;
      if (prune_)
        collect_live(A, 0.0, A.theta, kDepth, live[i]);
      else
        live[i].push_back({0.0, A.theta, A.a, A.fb, 0.0});
      if (!live[i].empty()) live_edges.push_back(std::uint32_t(i));
    }
    for (std::size_t ii = 0; ii < live_edges.size(); ++ii) {
      const std::size_t i = live_edges[ii];
      const dvec3 a = arcs[i].a, b = arcs[i].b;
      const double theta = arcs[i].theta;
      // Over the arc, n1 stays within angle theta/2 of its midpoint, so within chord
      // 2 sin(theta/4) of it: a dot product with a unit vector changes by at most that much.
      const dvec3 mid = std::cos(0.5 * theta) * a + std::sin(0.5 * theta) * b;
      const double reach = 2.0 * std::sin(0.25 * theta) + 1e-9;
      // Unordered pairs suffice: the family of (e1, e2) and that of (e2, e1) are the same
      // boxes (e1 and e2 flush with adjacent faces), parameterised along either arc.
      for (std::size_t jj = ii + 1; jj < live_edges.size(); ++jj) {
        const std::size_t j = live_edges[jj];
        const Edge& e2 = edges_[j];
        const double ma = glm::dot(mid, e2.fa), mb = glm::dot(mid, e2.fb);
        if (ma * mb > 0.0 && std::abs(ma) > reach && std::abs(mb) > reach) continue;
        const dvec3 d2 = glm::normalize(p_[e2.b] - p_[e2.a]);
        for (const Span& s1 : live[i])
          for (const Span& s2 : live[j]) {
            // Every width is at least 2 rho (the hull holds a ball of radius rho).
            if (s1.w * s2.w * min_width_ > best_ * kPrune) continue;
            // n1(t) must be orthogonal to a point of the live part of e2's arc: n1.u0 and
            // n1.u1 of opposite sign.
            const double A1 = glm::dot(a, s2.u0), B1 = glm::dot(b, s2.u0), A2 = glm::dot(a, s2.u1),
                         B2 = glm::dot(b, s2.u1);
            auto g = [&](double t) {
              return (A1 * std::cos(t) + B1 * std::sin(t)) * (A2 * std::cos(t) + B2 * std::sin(t));
            };
            Roots cuts;
            cuts.push(s1.lo);
            trig_roots(A1, B1, 0.0, s1.lo, s1.hi, cuts);
            trig_roots(A2, B2, 0.0, s1.lo, s1.hi, cuts);
            cuts.push(s1.hi);
            std::sort(cuts.t, cuts.t + cuts.n);
            for (int k = 0; k + 1 < cuts.n; ++k) {
              const double lo = cuts.t[k], hi = cuts.t[k + 1];
              if (hi - lo < 1e-12 || g(0.5 * (lo + hi)) > 0.0) continue;
              bounded_sweep(a, b, d2, lo, hi);
            }
          }
      }
    }
    return best_;
  }

  dvec3 best_n1{1, 0, 0}, best_n2{0, 1, 0};
  // Every improving frame (n1, n2), in order: the caller measures the last few again.
  std::vector<std::array<dvec3, 2>> candidates;

 private:
  static constexpr double kPrune = 1.0 + 1e-7;
  static constexpr int kDepth = 3;

  struct Arc {
    dvec3 a, b;
    double theta;
    dvec3 fb;  // the exact normal at theta (at(theta) differs from it in the last bits)
    dvec3 at(double t) const { return std::cos(t) * a + std::sin(t) * b; }
    // At the arc's ends, its faces' exact normals: a sign test against them decides whether a
    // sliver piece next to the end exists, as the search without pruning decides it.
    dvec3 end_or_at(double t) const { return t == 0.0 ? a : t == theta ? fb : at(t); }
  };
  struct Span {  // a live sub-arc: its parameter range and its end directions
    double lo, hi;
    dvec3 u0, u1;
    double w;  // a lower bound on the hull's width along its directions
  };

  // A lower bound on the volume of every box one of whose axes n lies on the sub-arc
  // n(t), t in [t0, t1], of an edge's arc: such a box has width w(n) along n and a
  // cross-section that contains the hull's projection along n, of area A(n), so its volume
  // is at least w(n) A(n). With m the sub-arc's midpoint, p = support(m), q = support(-m):
  // w(n) >= n.(p - q); with c_f the faces' vector areas, A(n) = sum over front faces of
  // n.c_f >= n.V for V the sum of c_f over any set of faces, here those in front at m. Both
  // lower bounds are sinusoids in t; on an interval shorter than pi a sinusoid positive at
  // both ends is positive and concave in between, so its minimum is at an end.
  double arc_lower_bound(const Arc& arc, double t0, double t1, double* width = nullptr) const {
    if (width) *width = 0.0;
    const dvec3 m = arc.at(0.5 * (t0 + t1)), n0 = arc.at(t0), n1 = arc.at(t1);
    const dvec3 pq = p_[support(m)] - p_[support(-m)];
    const double w = std::min(glm::dot(n0, pq), glm::dot(n1, pq));
    if (!(w > 0.0)) return 0.0;
    if (width) *width = w * (1.0 - 1e-9);
    dvec3 V(0.0);
    for (const dvec3& c : areas_)
      if (glm::dot(m, c) > 0.0) V += c;
    const double A = std::min(glm::dot(n0, V), glm::dot(n1, V));
    if (!(A > 0.0)) return 0.0;
    return w * A * (1.0 - 1e-7);
  }

  // Appends the parts of [t0, t1] that the bound cannot exclude, merging neighbours.
  void collect_live(const Arc& arc, double t0, double t1, int depth, std::vector<Span>& out) const {
    double w = 0.0;
    if (arc_lower_bound(arc, t0, t1, &w) > best_ * kPrune) return;
    if (depth > 0 && t1 - t0 > 1e-6) {
      const double tm = 0.5 * (t0 + t1);
      collect_live(arc, t0, tm, depth - 1, out);
      collect_live(arc, tm, t1, depth - 1, out);
      return;
    }
    if (!out.empty() && out.back().hi == t0) {
      out.back().hi = t1;
      out.back().u1 = arc.end_or_at(t1);
      out.back().w = std::min(out.back().w, w);
    } else {
      out.push_back({t0, t1, arc.end_or_at(t0), arc.end_or_at(t1), w});
    }
  }

  bool prune_ = true;
  double min_width_ = 0.0;

  struct Frame {
    dvec3 n[3];
    bool ok;
  };

  static Frame frame(const dvec3& a, const dvec3& b, const dvec3& d2, double t) {
    Frame f;
    f.n[0] = std::cos(t) * a + std::sin(t) * b;
    const dvec3 m = glm::cross(d2, f.n[0]);
    const double len = glm::length(m);
    f.ok = len > 1e-9;
    f.n[1] = f.ok ? m / len : dvec3(0.0);
    f.n[2] = glm::cross(f.n[0], f.n[1]);
    return f;
  }

  // A coarse table of support vertices (cube map, kCells x kCells per face): climbs start
  // from the entry for their direction, so each takes a few steps wherever the last one was.
  static constexpr int kCells = 16;
  std::size_t cell(const dvec3& d) const {
    const dvec3 a = glm::abs(d);
    const int axis = a.x >= a.y && a.x >= a.z ? 0 : a.y >= a.z ? 1 : 2;
    const double m = a[axis] > 0 ? a[axis] : 1.0;
    const int face = 2 * axis + (d[axis] < 0 ? 1 : 0);
    const double u = d[(axis + 1) % 3] / m, v = d[(axis + 2) % 3] / m;  // in [-1, 1]
    const int iu = std::clamp(int((u + 1.0) * 0.5 * kCells), 0, kCells - 1);
    const int iv = std::clamp(int((v + 1.0) * 0.5 * kCells), 0, kCells - 1);
    return std::size_t((face * kCells + iu) * kCells + iv);
  }

  void build_support_table() {
    table_.assign(6 * kCells * kCells, 0);
    std::uint32_t v = 0;
    for (int face = 0; face < 6; ++face)
      for (int iu = 0; iu < kCells; ++iu)
        for (int iv = 0; iv < kCells; ++iv) {
          dvec3 d(0.0);
          const int axis = face / 2;
          d[axis] = face % 2 ? -1.0 : 1.0;
          d[(axis + 1) % 3] = (iu + 0.5) / kCells * 2.0 - 1.0;
          d[(axis + 2) % 3] = (iv + 0.5) / kCells * 2.0 - 1.0;
          v = climb(v, d);
          table_[std::size_t((face * kCells + iu) * kCells + iv)] = v;
        }
  }

  std::uint32_t support(const dvec3& d) const { return climb(table_[cell(d)], d); }

  std::uint32_t climb(std::uint32_t v, const dvec3& d) const {
    double best = glm::dot(d, p_[v]);
    for (bool moved = true; moved;) {
      moved = false;
      for (std::uint32_t w : hull_.vertex_neighbours[v]) {
        const double val = glm::dot(d, p_[w]);
        if (val > best) best = val, v = w, moved = true;
      }
    }
    return v;
  }

  // Volume with fixed supports sup[axis][side] (side 0: max along n, side 1: max along -n).
  double volume(const Frame& f, const std::array<std::array<std::uint32_t, 2>, 3>& sup) const {
    double v = 1.0;
    for (int k = 0; k < 3; ++k) v *= glm::dot(f.n[k], p_[sup[std::size_t(k)][0]] - p_[sup[std::size_t(k)][1]]);
    return v;
  }

  void consider(const Frame& f, double vol) {
    if (vol < best_) {
      best_ = vol;
      best_n1 = f.n[0];
      best_n2 = f.n[1];
      candidates.push_back({f.n[0], f.n[1]});
    }
  }

  // Earliest t in (t0, hi] at which the support vertex v of direction sign * n_axis(t) stops
  // being the support (a neighbour w catches up), or hi.
  double next_event(const dvec3& a, const dvec3& b, const dvec3& d2, int axis, int side, std::uint32_t v, double t0,
                    double hi, const Frame& at_hi) const {
    double best = hi;
    const dvec3 dir_hi = side ? -at_hi.n[axis] : at_hi.n[axis];
    for (std::uint32_t w : hull_.vertex_neighbours[v]) {
      const dvec3 u = p_[w] - p_[v];
      // For n1 and n2 the interval is shorter than pi, so d(t).u has at most one root in it,
      // and it is there only if w is ahead of v at the end of the interval.
      if (axis < 2 && glm::dot(dir_hi, u) <= 0.0) continue;
      // For n3, d2.u - (n1.d2)(n1.u) has derivative at most 2|u|: if it is that far below
      // zero at the end of the interval, it was below zero all along.
      if (axis == 2) {
        const double f_hi = glm::dot(d2, u) - glm::dot(at_hi.n[0], d2) * glm::dot(at_hi.n[0], u);
        if ((side ? -f_hi : f_hi) < -2.0 * glm::length(u) * (hi - t0)) continue;
      }
      Roots roots;
      if (axis == 0) {  // n1 . u = 0
        trig_roots(glm::dot(a, u), glm::dot(b, u), 0.0, t0, hi, roots);
      } else if (axis == 1) {  // (d2 x n1) . u = n1 . (u x d2) = 0
        const dvec3 c = glm::cross(u, d2);
        trig_roots(glm::dot(a, c), glm::dot(b, c), 0.0, t0, hi, roots);
      } else {  // n3 . u ∝ d2.u - (n1.d2)(n1.u) = 0, a quadratic in cos t, sin t
        const double p0 = glm::dot(a, d2), p1 = glm::dot(b, d2), q0 = glm::dot(a, u), q1 = glm::dot(b, u);
        const double C = glm::dot(d2, u) - 0.5 * (p0 * q0 + p1 * q1);
        Roots doubled;
        trig_roots(0.5 * (p0 * q0 - p1 * q1), 0.5 * (p0 * q1 + p1 * q0), C, 2.0 * t0, 2.0 * hi, doubled);
        for (int k = 0; k < doubled.n; ++k) roots.push(0.5 * doubled.t[k]);
      }
      for (int k = 0; k < roots.n; ++k)
        if (roots.t[k] > t0 + 1e-13 && roots.t[k] < best) best = roots.t[k];
    }
    return best;
  }

  // n.(p - q) bounds the width along n from below for any vertices p, q, so the closed-form
  // piece bound with the supports at the interval's midpoint bounds every box of the
  // interval from below: skip the sweep (its event tracking) when that exceeds the best.
  void bounded_sweep(const dvec3& a, const dvec3& b, const dvec3& d2, double lo, double hi) {
    const Frame fm = frame(a, b, d2, 0.5 * (lo + hi));
    if (fm.ok) {
      std::array<std::array<std::uint32_t, 2>, 3> sup;
      for (int k = 0; k < 3; ++k) {
        sup[std::size_t(k)][0] = support(fm.n[k]);
        sup[std::size_t(k)][1] = support(-fm.n[k]);
      }
      if (piece_lower_bound(a, b, d2, sup, lo, hi) > best_ * (1.0 + 1e-9)) return;
    }
    sweep(a, b, d2, lo, hi);
  }

  void sweep(const dvec3& a, const dvec3& b, const dvec3& d2, double lo, double hi) {
    // Support k (axis k/2, side k%2) and the time its current vertex stops being the support.
    std::array<std::array<std::uint32_t, 2>, 3> sup;
    std::array<double, 6> event;
    const Frame at_hi = frame(a, b, d2, hi);
    Frame fp;  // the frame just after the current time: it decides ties at an event
    auto refresh = [&](int k, double t) {
      const int axis = k / 2, side = k % 2;
      const dvec3 dir = side ? -fp.n[axis] : fp.n[axis];
      const std::uint32_t v = support(dir);
      sup[std::size_t(axis)][std::size_t(side)] = v;
      event[std::size_t(k)] = next_event(a, b, d2, axis, side, v, t, hi, at_hi);
    };
    if (!frame(a, b, d2, lo).ok || !at_hi.ok) return;  // e2 parallel to n1 somewhere
    fp = frame(a, b, d2, std::min(hi, lo + 1e-9));
    for (int k = 0; k < 6; ++k) refresh(k, lo);
    double t = lo;
    for (int guard = 0; guard < 100000; ++guard) {
      const double t_next = *std::min_element(event.begin(), event.end());
      minimise_piece(a, b, d2, sup, t, t_next);
      if (t_next >= hi) return;
      t = t_next;
      fp = frame(a, b, d2, std::min(hi, t + 1e-9));
      for (int k = 0; k < 6; ++k)  // only the supports whose event this was change
        if (event[std::size_t(k)] <= t) refresh(k, t);
    }
  }

  // Minimum of A cos t + B sin t over [lo, hi].
  static double min_sinusoid(double A, double B, double lo, double hi) {
    double m = std::min(A * std::cos(lo) + B * std::sin(lo), A * std::cos(hi) + B * std::sin(hi));
    const double tmin = std::atan2(B, A) + kPi;  // where it equals -hypot(A, B)
    const double k = std::ceil((lo - tmin) / (2.0 * kPi));
    if (tmin + 2.0 * kPi * k <= hi) m = -std::hypot(A, B);
    return m;
  }

  // A lower bound on the volume over [lo, hi] with the supports fixed, from closed forms:
  // w1 = n1.u1 (a sinusoid); with s = n1.d2 and L = |d2 x n1| = sqrt(1 - s^2),
  // w2 = n1.(u2 x d2) / L and w3 = (d2.u3 - s (n1.u3)) / L, whose numerators are a sinusoid
  // in t and a constant plus a sinusoid in 2t. Each numerator's exact minimum over the
  // interval, divided by the largest L there (|s| is concave where s keeps its sign, so
  // its smallest value is at an end), bounds the width from below when positive.
  double piece_lower_bound(const dvec3& a, const dvec3& b, const dvec3& d2,
                           const std::array<std::array<std::uint32_t, 2>, 3>& sup, double lo, double hi) const {
    dvec3 u[3];
    for (int k = 0; k < 3; ++k) u[k] = p_[sup[std::size_t(k)][0]] - p_[sup[std::size_t(k)][1]];
    const double w1 = min_sinusoid(glm::dot(a, u[0]), glm::dot(b, u[0]), lo, hi);
    if (!(w1 > 0.0)) return 0.0;
    const double p0 = glm::dot(a, d2), p1 = glm::dot(b, d2);
    const double s_lo = p0 * std::cos(lo) + p1 * std::sin(lo), s_hi = p0 * std::cos(hi) + p1 * std::sin(hi);
    const double s_min = s_lo * s_hi > 0.0 ? std::min(std::abs(s_lo), std::abs(s_hi)) : 0.0;
    const double L_max = std::sqrt(std::max(0.0, 1.0 - s_min * s_min));
    const dvec3 c2 = glm::cross(u[1], d2);
    const double n2 = min_sinusoid(glm::dot(a, c2), glm::dot(b, c2), lo, hi);
    if (!(n2 > 0.0)) return 0.0;
    const double q0 = glm::dot(a, u[2]), q1 = glm::dot(b, u[2]);
    const double K = glm::dot(d2, u[2]) - 0.5 * (p0 * q0 + p1 * q1);
    const double n3 = K + min_sinusoid(-0.5 * (p0 * q0 - p1 * q1), -0.5 * (p0 * q1 + p1 * q0), 2.0 * lo, 2.0 * hi);
    if (!(n3 > 0.0)) return 0.0;
    return w1 * (n2 / L_max) * (n3 / L_max) * (1.0 - 1e-12);
  }

  // With the supports fixed, V(t) = w1 w2 w3, w_k = n_k(t).u_k, is smooth on the piece, and
  // V >= min(V(lo), V(hi)) - M2 (hi - lo)^2 / 8 for M2 >= |V''| (linear interpolation error).
  // Along the family |n1'| = |n1''| = 1; m = d2 x n1 has |m'|, |m''| <= 1, so n2 = m / L,
  // L = |m| >= Lmin, has |n2'| <= 1/L and |n2''| <= 2/L + 3/L^2, and n3 = n1 x n2 has
  // |n3'| <= 1 + 1/L and |n3''| <= 1 + 4/L + 3/L^2; |w_k^(i)| <= |n_k^(i)| |u_k|, and |w_k| is at
  // most its larger end value plus |n_k'| |u_k| (hi - lo).
  double interp_bound(const dvec3& a, const dvec3& b, const dvec3& d2,
                      const std::array<std::array<std::uint32_t, 2>, 3>& sup, const Frame& f_lo, const Frame& f_hi,
                      double v_lo, double v_hi, double lo, double hi) const {
    const double len = hi - lo, M2 = curvature_bound(a, b, d2, sup, f_lo, f_hi, lo, hi);
    if (!(M2 < std::numeric_limits<double>::infinity())) return 0.0;
    return (std::min(v_lo, v_hi) - M2 * len * len * 0.125) * (1.0 - 1e-12);
  }

  // dV/dt at t with the supports fixed (f: the frame at t).
  static double volume_derivative(const dvec3& a, const dvec3& b, const dvec3& d2, const Frame& f, const dvec3 u[3],
                                  double t) {
    const dvec3 n1d = -std::sin(t) * a + std::cos(t) * b;
    const dvec3 m = glm::cross(d2, f.n[0]), md = glm::cross(d2, n1d);
    const double L = glm::length(m);
    const dvec3 n2d = (md - f.n[1] * glm::dot(f.n[1], md)) / L;
    const dvec3 n3d = glm::cross(n1d, f.n[1]) + glm::cross(f.n[0], n2d);
    const double w1 = glm::dot(f.n[0], u[0]), w2 = glm::dot(f.n[1], u[1]), w3 = glm::dot(f.n[2], u[2]);
    return glm::dot(n1d, u[0]) * w2 * w3 + w1 * glm::dot(n2d, u[1]) * w3 + w1 * w2 * glm::dot(n3d, u[2]);
  }

  // Whether no interior point of the piece can beat the best (which the ends have already
  // been compared with, so best_ <= V(lo), V(hi)): from each end, V(end + s) >= V(end) +
  // D s - M2 s^2 / 2 with D the inward derivative, which stays >= best_ for s up to the
  // larger root; excluded when the two reaches cover the piece.
  bool ends_exclude(const dvec3& a, const dvec3& b, const dvec3& d2,
                    const std::array<std::array<std::uint32_t, 2>, 3>& sup, const Frame& f_lo, const Frame& f_hi,
                    double v_lo, double v_hi, double lo, double hi) const {
    const double M2 = curvature_bound(a, b, d2, sup, f_lo, f_hi, lo, hi);
    if (!(M2 > 0.0 && M2 < std::numeric_limits<double>::infinity())) return false;
    dvec3 u[3];
    for (int k = 0; k < 3; ++k) u[k] = p_[sup[std::size_t(k)][0]] - p_[sup[std::size_t(k)][1]];
    const double target = best_ * (1.0 - 1e-12);
    auto reach = [&](double v, double D) {
      const double gap = v - target;
      if (gap < 0.0) return 0.0;
      const double disc = D * D + 2.0 * M2 * gap;
      return (D + std::sqrt(disc)) / M2 * (1.0 - 1e-9);
    };
    const double r_lo = reach(v_lo, volume_derivative(a, b, d2, f_lo, u, lo));
    const double r_hi = reach(v_hi, -volume_derivative(a, b, d2, f_hi, u, hi));
    return r_lo + r_hi >= hi - lo;
  }

  // A bound on |V''| over the piece with the supports fixed (infinity when n1 comes near d2).
  double curvature_bound(const dvec3& a, const dvec3& b, const dvec3& d2,
                         const std::array<std::array<std::uint32_t, 2>, 3>& sup, const Frame& f_lo, const Frame& f_hi,
                         double lo, double hi) const {
    const double len = hi - lo;
    const double p0 = glm::dot(a, d2), p1 = glm::dot(b, d2);
    const double s_abs = std::max(-min_sinusoid(p0, p1, lo, hi), -min_sinusoid(-p0, -p1, lo, hi));
    const double L = std::sqrt(std::max(0.0, 1.0 - s_abs * s_abs));
    if (L < 1e-3) return std::numeric_limits<double>::infinity();
    const double il = 1.0 / L;
    const double d1[3] = {1.0, il, 1.0 + il}, d2n[3] = {1.0, 2.0 * il + 3.0 * il * il, 1.0 + 4.0 * il + 3.0 * il * il};
    double U[3], W[3];
    for (int k = 0; k < 3; ++k) {
      const dvec3 u = p_[sup[std::size_t(k)][0]] - p_[sup[std::size_t(k)][1]];
      U[k] = glm::length(u);
      W[k] = std::min(U[k], std::max(glm::dot(f_lo.n[k], u), glm::dot(f_hi.n[k], u)) + d1[k] * U[k] * len);
    }
    const double M2 = d2n[0] * U[0] * W[1] * W[2] + W[0] * d2n[1] * U[1] * W[2] + W[0] * W[1] * d2n[2] * U[2] +
                      2.0 * (d1[0] * U[0] * d1[1] * U[1] * W[2] + d1[0] * U[0] * W[1] * d1[2] * U[2] +
                             W[0] * d1[1] * U[1] * d1[2] * U[2]);
    return M2;
  }

  void minimise_piece(const dvec3& a, const dvec3& b, const dvec3& d2,
                      const std::array<std::array<std::uint32_t, 2>, 3>& sup, double lo, double hi) {
    auto vol = [&](double t, Frame& f) {
      f = frame(a, b, d2, t);
      return f.ok ? volume(f, sup) : std::numeric_limits<double>::infinity();
    };
    Frame f_lo, f_hi;
    // Ends of the piece, then a golden-section search for an interior minimum.
    const double v_lo = vol(lo, f_lo), v_hi = vol(hi, f_hi);
    consider(f_lo, v_lo);
    consider(f_hi, v_hi);
    if (hi - lo < 1e-10 || !f_lo.ok || !f_hi.ok) return;
    if (ends_exclude(a, b, d2, sup, f_lo, f_hi, v_lo, v_hi, lo, hi) ||
        interp_bound(a, b, d2, sup, f_lo, f_hi, v_lo, v_hi, lo, hi) > best_ * (1.0 + 1e-9) ||
        piece_lower_bound(a, b, d2, sup, lo, hi) > best_ * (1.0 + 1e-9))
      return;
    // Skip the search when no interior point can beat the best: each width is
    // n_k(t).(p - q) with |p - q| <= the hull diameter D, and n_k turns at most at speed 1 (n1),
    // 2/|m| (n2) and 1 + 2/|m| (n3), m = d2 x n1, |m| changing at speed <= 1.
    const double len = hi - lo;
    const double m_min =
        std::min(glm::length(glm::cross(d2, f_lo.n[0])), glm::length(glm::cross(d2, f_hi.n[0]))) - 0.5 * len;
    if (m_min > 0.0) {
      const double speed[3] = {1.0, 2.0 / m_min, 1.0 + 2.0 / m_min};
      double bound = 1.0;
      for (int k = 0; k < 3; ++k) {
        const dvec3 delta = p_[sup[std::size_t(k)][0]] - p_[sup[std::size_t(k)][1]];
        const double w =
            std::min(glm::dot(f_lo.n[k], delta), glm::dot(f_hi.n[k], delta)) - speed[k] * diameter_ * 0.5 * len;
        bound *= std::max(w, 0.0);
      }
      if (bound >= best_) return;
    }
    const double r = 0.6180339887498949;
    double x0 = lo, x3 = hi, x1 = x3 - r * (x3 - x0), x2 = x0 + r * (x3 - x0);
    Frame f1, f2;
    double v1 = vol(x1, f1), v2 = vol(x2, f2);
    for (int it = 0; it < 40 && x3 - x0 > 1e-12; ++it) {
      if (v1 < v2) {
        x3 = x2, x2 = x1, v2 = v1, f2 = f1;
        x1 = x3 - r * (x3 - x0);
        v1 = vol(x1, f1);
      } else {
        x0 = x1, x1 = x2, v1 = v2, f1 = f2;
        x2 = x0 + r * (x3 - x0);
        v2 = vol(x2, f2);
      }
    }
    consider(f1, v1);
    consider(f2, v2);
  }

  const ConvexHull& hull_;
  std::vector<dvec3> p_, normals_, areas_;
  std::vector<Edge> edges_;
  double diameter_ = 0.0;
  std::vector<std::uint32_t> table_;
  double best_ = std::numeric_limits<double>::infinity();
};

}  // namespace

constexpr std::size_t kRefits = 32;

Obb exact_obb(std::span<const glm::vec3> points) {
  const ConvexHull hull = convex_hull(points);   // checks the points
  const Obb face = hull_face_obb(points, hull);  // the face-flush candidates
  if (hull.dimension != ConvexHull::Dimension::Polyhedron) return face;
  Sweeper sweeper(hull);
  const double face_volume = volume(face);
  const double best = sweeper.run(face_volume);
  if (!(best < face_volume)) return face;
  // The sweep's volumes come from supports it tracks, which can lag behind near an event, so
  // the frame it found best need not be: the last kRefits improving frames are measured on the
  // hull's vertices, and the best of them is fitted to every point.
  const std::size_t count = sweeper.candidates.size(), first = count > kRefits ? count - kRefits : 0;
  std::size_t chosen = count;
  double chosen_volume = face_volume;
  const auto axes_of = [&](std::size_t c) {
    const dvec3 n1 = glm::normalize(sweeper.candidates[c][0]);
    const dvec3 n2 = glm::normalize(sweeper.candidates[c][1] - glm::dot(sweeper.candidates[c][1], n1) * n1);
    return glm::mat3(glm::vec3(n1), glm::vec3(n2), glm::vec3(glm::cross(n1, n2)));
  };
  for (std::size_t c = first; c < count; ++c) {
    const double v = volume(fit_box(hull.vertices, axes_of(c)));
    if (v < chosen_volume) chosen = c, chosen_volume = v;
  }
  if (chosen == count) return face;
  const Obb edge_box = fit_box(points, axes_of(chosen));
  return volume(edge_box) < face_volume ? edge_box : face;
}

}  // namespace cullpipe::bounds
