#pragma once
// Volume sets at the edge of the plane bounds that let the fast CPU kernels and the GPU flat
// pass settle most objects without the reference's full test (src/cullpipe/geom/plane_bounds.hpp):
// each set comes with views of one plane each, and the answers must still be the reference's.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdlib>
#include <initializer_list>
#include <limits>
#include <vector>

#include "cullpipe/cull/simd_kernels.hpp"
#include "cullpipe/geom/pn_vertex.hpp"
#include "test_util.hpp"

namespace cullpipe::test {

template <class Volume>
struct EdgeSet {
  std::vector<Volume> volumes;
  std::vector<Frustum> views;  // one plane each, or two or six (add_mirrored_views)
};

// Appends views on which no bound may settle anything: the same planes with normals of length
// 2, built by hand, and planes at |d| = 2^121 (past the margin's range).
inline void add_unbounded_views(std::vector<Frustum>& views) {
  for (std::size_t v = 0, count = views.size(); v < count; ++v) {
    Frustum scaled = views[v];
    scaled.planes[0].normal *= 2.0f;
    scaled.planes[0].d *= 2.0f;
    views.push_back(scaled);
  }
  for (float d : {0x1p121f, -0x1p121f}) {
    const glm::vec4 plane(views[0].planes[0].normal, d);
    views.push_back(Frustum::from_planes({&plane, 1}));
  }
}

// Appends, for each of the first `count` views (one plane n.x + d each), views of two planes,
// that plane and one mirroring it: normal -n off by kMirrorSlack in every component (the most
// PlaneSet::mirrored allows; built by hand), offset -d (a slab around the plane: the plane's
// distance taken as a difference from the mirror's, and the other way round) or 4*10^6 (every
// volume deep inside the mirror). The bounds allow for the difference (docs/numerics.md,
// Mirrored planes).
// Then the slab among two more mirrored pairs, across it, at 4*10^6 (an orthographic
// frustum's shape: three pairs), in both roles and as the first, second and third pair (the
// kernels take the first pair's mirrored distance as a difference, the others' in full).
inline void add_mirrored_views(std::vector<Frustum>& views, std::size_t count) {
  const float slack = fast::detail::kMirrorSlack;
  for (std::size_t v = 0; v < count; ++v) {
    const Plane plane = views[v].planes[0];
    Plane mirror;
    mirror.normal = -plane.normal + slack * glm::vec3(1.0f, -1.0f, v % 2 ? 1.0f : -1.0f);
    for (float offset : {-plane.d, 4e6f}) {
      mirror.d = offset;
      Frustum pair;
      pair.plane_count = 2;
      pair.planes[0] = mirror;  // the base: `plane` is the one taken as a difference
      pair.planes[1] = plane;
      views.push_back(pair);
      if (offset != 4e6f) {
        std::swap(pair.planes[0], pair.planes[1]);
        views.push_back(pair);
      }
    }
    mirror.d = -plane.d;
    const glm::vec3 n = plane.normal;
    const glm::vec3 axis = std::abs(n.x) < 0.5f ? glm::vec3(1, 0, 0) : glm::vec3(0, 1, 0);
    const glm::vec3 u = glm::normalize(glm::cross(n, axis)), w = glm::normalize(glm::cross(n, u));
    const Plane across[4] = {{u, 4e6f},
                             {w, 4e6f},
                             {-u - slack * glm::vec3(1.0f, 1.0f, -1.0f), 4e6f},
                             {-w + slack * glm::vec3(-1.0f, 1.0f, 1.0f), 4e6f}};
    for (int role = 0; role < 2; ++role)
      for (int slot = 0; slot < 3; ++slot) {
        // The bases in planes 0-2, each mirrored three planes on; the slab's pair in `slot`.
        Frustum ortho;
        ortho.plane_count = 6;
        for (int k = 0, other = 0; k < 3; ++k) {
          if (k == slot) {
            ortho.planes[k] = role ? plane : mirror;
            ortho.planes[k + 3] = role ? mirror : plane;
          } else {
            ortho.planes[k] = across[other];
            ortho.planes[k + 3] = across[other + 2];
            ++other;
          }
        }
        views.push_back(ortho);
      }
  }
}

// One view of one slanted plane (a random normal) per offset d.
inline std::vector<Frustum> slanted_views(Rng& rng, std::initializer_list<float> offsets) {
  std::vector<Frustum> views;
  for (float d : offsets) {
    const glm::vec4 plane(glm::normalize(rng.vec3(-1, 1) + glm::vec3(0.1f)), d);
    views.push_back(Frustum::from_planes({&plane, 1}));
  }
  return views;
}

// The OBB kernel settles most objects with a bound b >= |r| on the projected radius and tests
// the rest in full. OBBs whose centre distance is within float steps of +-r, with an axis along
// the normal (where the float r can exceed |u| h), axes that are not unit or orthogonal,
// negative and zero extents; axes so long that n.u overflows (r is NaN: no bound is safe);
// across more than two runs of the kernel (4096 objects each).
inline EdgeSet<Obb> obb_edge_set() {
  Rng rng(11);
  // Slanted planes, one view each; through the origin for the first six: a centre t n has
  // coordinates no larger than t, so its distance can be set to within a float step of r.
  std::vector<Frustum> views = slanted_views(rng, {0.0f, 0.0f, 0.0f, 0.0f, 0.0f, 0.0f, 900.0f, -3000.0f, 1e6f});
  std::vector<Obb> obbs;
  for (const Frustum& view : views) {
    const glm::vec3 n = view.planes[0].normal;
    const glm::vec3 on_plane = -view.planes[0].d * n;
    for (int shape = 0; shape < 6; ++shape)
      for (int side = -1; side <= 1; side += 2)
        for (int step = -64; step <= 64; ++step) {
          Obb o;
          if (shape == 0) {  // one axis along the normal, the others empty
            o.basis = glm::mat3(n, glm::vec3(0), glm::vec3(0));
            o.half_extents = {rng.uniform(0.5f, 2.0f), 0, 0};
          } else if (shape == 1) {  // a rotated box
            o.basis = rng.rotation();
            o.half_extents = rng.vec3(0.0f, 2.0f);
          } else if (shape == 2) {  // skewed, scaled axes and a negative extent
            o.basis = glm::mat3(rng.vec3(-3, 3), rng.vec3(-3, 3), 0.001f * rng.vec3(-1, 1));
            o.half_extents = {rng.uniform(0.0f, 2.0f), -rng.uniform(0.0f, 2.0f), 1e3f};
          } else if (shape == 3) {  // a scaled axis along the normal
            o.basis = glm::mat3(7.0f * n, 0.5f * rng.vec3(-1, 1), glm::vec3(0));
            o.half_extents = {rng.uniform(0.1f, 1.0f), rng.uniform(0.0f, 0.01f), 3};
          } else if (shape == 4) {  // a rotated box at its widest along the normal: r = |h|_2,
            // the bound's Gram-matrix term at its edge
            const glm::mat3 rotation = rng.rotation();
            const float k = rng.uniform(0.5f, 2.0f);
            for (int i = 0; i < 3; ++i) {
              const float c = glm::dot(rotation[i], n);
              o.basis[i] = c < 0.0f ? -rotation[i] : rotation[i];
              o.half_extents[i] = k * std::fabs(c);
            }
          } else {  // axes bunched around the normal, far from orthogonal: r near sum |u_i| h_i
            for (int i = 0; i < 3; ++i) o.basis[i] = n + 0.2f * rng.vec3(-1, 1);
            o.half_extents = rng.vec3(0.2f, 2.0f);
          }
          // r as the reference computes it for this plane; the centre at distance side * r,
          // moved by `step` steps of 2^-26 of r (below a float step of the distance).
          float r = 0;
          for (int i = 0; i < 3; ++i) {
            const glm::vec3 u = o.basis[i];
            const float a = (n.x * u.x + n.y * u.y) + n.z * u.z;
            r = i == 0 ? std::fabs(a) * o.half_extents[i] : r + std::fabs(a) * o.half_extents[i];
          }
          o.center = on_plane + (float(side) * r * (1.0f + float(step) * 0x1p-26f)) * n;
          obbs.push_back(o);
        }
    // Behind this plane by 1 and by 10^-3, with an axis along which n.u overflows (r = inf x 0 =
    // NaN: the reference finds nothing behind this plane).
    for (float behind : {1.0f, 1e-3f}) {
      Obb o;
      o.basis = glm::mat3(3e38f * glm::sign(n), glm::vec3(0, 1, 0), glm::vec3(0, 0, 1));
      o.half_extents = {0, 1e-4f, 1e-4f};
      o.center = on_plane - behind * n;
      obbs.push_back(o);
    }
  }
  // Centres 10^5 away along the planes through the origin, within float steps of distance
  // +-r: a step of the distance is far larger than r, so only the bound's share for the centre
  // (2^-18 |c|_1) covers the fused centre distance rounding differently from the reference's.
  for (std::size_t v = 0; v < 6; ++v) {
    const glm::vec3 n = views[v].planes[0].normal;
    for (int i = 0; i < 300; ++i) {
      Obb o;
      o.basis = rng.rotation();
      o.half_extents = rng.vec3(0.0f, 1e-2f);
      const glm::vec3 along = rng.vec3(-1e5f, 1e5f);
      float r = 0;
      for (int k = 0; k < 3; ++k) {
        const glm::vec3 u = o.basis[k];
        r += std::fabs((n.x * u.x + n.y * u.y) + n.z * u.z) * o.half_extents[k];
      }
      o.center = (along - glm::dot(along, n) * n) + (i % 2 ? r : -r) * n;
      const int step = i % 9 - 4;
      for (int k = 0; k < 3; ++k)
        for (int t = 0; t < std::abs(step); ++t)
          o.center[k] = std::nextafter(o.center[k], (step > 0) == (n[k] > 0) ? 1e30f : -1e30f);
      obbs.push_back(o);
    }
  }
  // Where rounding makes the float r exceed the exact |u| h (which the bound's slack covers), a
  // centre at a distance s strictly between them, on each side: s < r is INTERSECTING, while a
  // bound of just |u| h would call it INSIDE (or OUTSIDE at -s).
  std::size_t between = 0;
  for (int trial = 0; trial < 4000 && between < 200; ++trial) {
    const Frustum& view = views[static_cast<std::size_t>(trial) % 6];  // d = 0
    const glm::vec3 n = view.planes[0].normal;
    Obb o;
    o.basis = glm::mat3(rng.uniform(0.5f, 8.0f) * n, glm::vec3(0), glm::vec3(0));
    o.half_extents = {rng.uniform(0.5f, 2.0f), 0, 0};
    const glm::vec3 u = o.basis[0];
    const float r = std::fabs((n.x * u.x + n.y * u.y) + n.z * u.z) * o.half_extents.x;
    const double exact = std::sqrt(double(u.x) * u.x + double(u.y) * u.y + double(u.z) * u.z) * o.half_extents.x;
    if (!(r > exact)) continue;
    for (float t = std::nextafter(r, 0.0f), stop = r * (1 - 0x1p-20f); t > stop; t = std::nextafter(t, 0.0f)) {
      const glm::vec3 c = t * n;
      const float s = (n.x * c.x + n.y * c.y) + n.z * c.z;  // the plane's d is 0
      if (s > exact && s < r) {
        o.center = c;
        obbs.push_back(o);
        o.center = -c;
        obbs.push_back(o);
        ++between;
        break;
      }
    }
  }
  EXPECT_GT(between, 50u);
  // Subnormal extents on huge axes and the reverse: under DAZ they would read as 0.
  for (const Frustum& view : views) {
    const glm::vec3 n = view.planes[0].normal;
    Obb o;
    o.basis = glm::mat3(0x1p124f * n, glm::vec3(0), glm::vec3(0));
    o.half_extents = {0x1p-127f, 0, 0};  // r = 0.125
    o.center = -view.planes[0].d * n + 0.01f * n;
    obbs.push_back(o);
    o.basis = glm::mat3(0x1p-127f * n, glm::vec3(0), glm::vec3(0));
    o.half_extents = {0x1p100f, 0, 0};  // r = 2^-27
    o.center = -view.planes[0].d * n + 0x1p-30f * n;
    obbs.push_back(o);
  }
  const std::size_t sharp = obbs.size();
  while (obbs.size() < 9000) obbs.push_back(obbs[rng.next() % sharp]);  // more than two runs
  add_mirrored_views(views, views.size());
  add_unbounded_views(views);
  return {obbs, views};
}

// The AABB kernel settles most boxes by their centre distance against a bound on the half
// diagonal plus margins for every rounding; the rest get the p/n-vertex test. Boxes whose
// extents follow the normal (so the half diagonal is exactly the projected radius and only the
// margins separate the bound from the answer), with a vertex within float steps of slanted
// planes far from the origin; inverted, flat and point boxes; huge and non-finite coordinates.
inline EdgeSet<Aabb> aabb_edge_set() {
  Rng rng(23);
  std::vector<Frustum> views = slanted_views(rng, {0.0f, 900.0f, -3000.0f, 1e6f});
  std::vector<Aabb> boxes;
  for (const Frustum& view : views) {
    const Plane& plane = view.planes[0];
    const glm::vec3 n = plane.normal;
    const glm::vec3 on_plane = -plane.d * n;
    for (int i = 0; i < 600; ++i) {
      const float lambda = i % 10 == 0 ? 0.0f : rng.uniform(0.01f, 3.0f);  // some point boxes
      const glm::vec3 e = lambda * glm::abs(n) + (i % 3 == 0 ? rng.vec3(0.0f, 0.5f) : glm::vec3(0.0f));
      const glm::vec3 c = on_plane + rng.vec3(-50, 50) - glm::dot(rng.vec3(-50, 50), n) * n;
      Aabb b{c - e, c + e};
      // Move the box along n so the p-vertex (or the n-vertex) lies on the plane, then nudge
      // every coordinate by the same few float steps.
      const PnVertices v = pn_vertices(n, b);
      const glm::vec3 shift = -plane.distance(i % 2 ? v.p : v.n) * n;
      const int steps = i % 13 - 6;
      for (int k = 0; k < 3; ++k) {
        b.min[k] += shift[k];
        b.max[k] += shift[k];
        for (int s = 0; s < std::abs(steps); ++s) {
          b.min[k] = std::nextafter(b.min[k], steps > 0 ? 1e30f : -1e30f);
          b.max[k] = std::nextafter(b.max[k], steps > 0 ? 1e30f : -1e30f);
        }
      }
      if (i % 50 == 7) std::swap(b.min, b.max);  // inverted
      boxes.push_back(b);
    }
  }
  const float inf = std::numeric_limits<float>::infinity(), nan = std::numeric_limits<float>::quiet_NaN();
  for (float v : {inf, -inf, nan, 3e38f, -3e38f, 1e36f, 1e-40f, -1e-40f}) {
    boxes.push_back({{v, 0, 0}, {1, 1, 1}});
    boxes.push_back({{-1, -1, -1}, {1, v, 1}});
    boxes.push_back({{v, v, v}, {v, v, v}});
  }
  const std::size_t sharp = boxes.size();
  while (boxes.size() < 9000) boxes.push_back(boxes[rng.next() % sharp]);  // more than two runs
  add_mirrored_views(views, views.size());
  add_unbounded_views(views);
  return {boxes, views};
}

// The sphere kernel settles most spheres by their centre distance, computed fused, against a
// bound of |radius| plus margins for the rounding of that distance and the reference's; the rest
// get the reference's test. Centres within float steps of distance +-r from slanted planes, some
// far along the plane (so a step of the distance is larger than the radius: only the margins
// tell the two distances apart); zero, negative, subnormal and huge radii; huge and non-finite
// centres.
inline EdgeSet<Sphere> sphere_edge_set() {
  Rng rng(31);
  std::vector<Frustum> views = slanted_views(rng, {0.0f, 900.0f, -3000.0f, 1e6f});
  std::vector<Sphere> spheres;
  for (const Frustum& view : views) {
    const Plane& plane = view.planes[0];
    const glm::vec3 n = plane.normal;
    for (int i = 0; i < 700; ++i) {
      // A point on the plane, near the origin or 10^5 away along the plane.
      const float reach = i % 4 == 0 ? 1e5f : 50.0f;
      const glm::vec3 along = rng.vec3(-reach, reach);
      const glm::vec3 on_plane = -plane.d * n + (along - glm::dot(along, n) * n);
      float r = i % 7 == 0 ? 0.0f : i % 3 == 0 ? rng.uniform(1e-4f, 1e-2f) : rng.uniform(0.1f, 3.0f);
      if (i % 11 == 5) r = -r;
      const int side = i % 2 ? 1 : -1, step = i % 17 - 8;
      Sphere sp{on_plane + (float(side) * std::fabs(r)) * n, r};
      // Then move the centre along the normal until the reference's distance is within a few
      // float steps of +-r.
      for (int k = 0; k < 3; ++k)
        for (int s = 0; s < std::abs(step); ++s)
          sp.center[k] = std::nextafter(sp.center[k], (step > 0) == (n[k] > 0) ? 1e30f : -1e30f);
      spheres.push_back(sp);
    }
  }
  const float inf = std::numeric_limits<float>::infinity(), nan = std::numeric_limits<float>::quiet_NaN();
  for (float v : {inf, -inf, nan, 3e38f, -3e38f, 1e36f, 1e-40f, -1e-40f}) {
    spheres.push_back({{v, 0, 0}, 1.0f});
    spheres.push_back({{0, 0, 0}, v});
    spheres.push_back({{v, v, v}, v});
  }
  const std::size_t sharp = spheres.size();
  while (spheres.size() < 9000) spheres.push_back(spheres[rng.next() % sharp]);  // more than two runs
  add_mirrored_views(views, views.size());
  add_unbounded_views(views);
  return {spheres, views};
}

// The kernels also settle a straddling object without its full test when its fused centre
// distance is nearer every plane than a lower bound on its reach (the smallest half extent
// or the radius) less every rounding (plane_bounds::pack_lower). Objects where that lower
// bound is exact or nearly so, within float steps of a straddling threshold (the n-vertex or
// the p-vertex on the plane, the centre at +-r), along planes through the origin (10 to 10^6
// away, so the centre's rounding share decides) and near planes farther out:
// - boxes: cubes (their reach along n is the half extent times |n|_1);
// - OBBs: cubes with an axis along the normal (reach = the half extent), and boxes whose two
//   axes make 20 degrees, placed on the normal so that n.u0 = -n.u1 (reach 0.35 of the
//   extent, far below the extent the axes would give if they were orthogonal);
// - spheres: centres at +-r.
// Remove a rounding term from any of the lower bounds, or the Gershgorin term from the OBBs',
// and these disagree with the reference. Each set also gets the views of add_unbounded_views
// and the same planes with normals of length 0.75 and 0.4 (the lower bounds scale with the
// shortest; below 1/2 the OBBs' settle nothing by them), and volumes past 2^119 whose packed
// lower bound would overflow the kernels' product if it were kept.
inline std::vector<Frustum> lower_edge_views(Rng& rng) {
  return slanted_views(rng, {0.0f, 0.0f, 0.0f, 0.0f, 0.0f, 0.0f, 900.0f, -3000.0f});
}

// The views above plus: each of the first six with its plane scaled by 0.75 and by 0.4 (built
// by hand: from_planes would normalise them), planes x = 0 and x = -+2^120 (for the huge
// volumes), and add_unbounded_views.
inline void add_lower_edge_views(std::vector<Frustum>& views) {
  for (std::size_t v = 0; v < 6; ++v)
    for (float scale : {0.75f, 0.4f}) {
      Frustum scaled = views[v];
      scaled.planes[0].normal *= scale;
      scaled.planes[0].d *= scale;
      views.push_back(scaled);
    }
  for (float d : {0.0f, 0x1p120f, -0x1p120f}) {
    const glm::vec4 plane(1, 0, 0, d);
    views.push_back(Frustum::from_planes({&plane, 1}));
  }
  add_unbounded_views(views);
}

inline glm::vec3 far_along(Rng& rng, const Plane& plane, int i) {
  // (At 10^6 the centre's share, 3.8, exceeds every extent: nothing settles by the lower bound,
  // but a lower bound without that share would settle many.)
  const float reach = i % 5 == 0 ? 1e6f : i % 5 == 1 ? 1e5f : i % 5 == 2 ? 1e4f : i % 5 == 3 ? 1e3f : 10.0f;
  const glm::vec3 along = rng.vec3(-reach, reach), n = plane.normal;
  return -plane.d * n + (along - glm::dot(along, n) * n);
}

// Moves every coordinate of `p` by |steps| float steps along +-n (the sign of `steps`).
inline void nudge(glm::vec3& p, const glm::vec3& n, int steps) {
  for (int k = 0; k < 3; ++k)
    for (int t = 0; t < std::abs(steps); ++t) p[k] = std::nextafter(p[k], (steps > 0) == (n[k] > 0) ? 1e30f : -1e30f);
}

// Per view of lower_edge_views, 1200 volumes make(rng, plane, i), then `extra`, then copies of
// them up to 12,000 (more than two runs of the kernel); the views of add_lower_edge_views.
template <class Volume, class Make>
EdgeSet<Volume> lower_edge_set(std::uint64_t seed, Make make, std::initializer_list<Volume> extra) {
  Rng rng(seed);
  std::vector<Frustum> views = lower_edge_views(rng);
  std::vector<Volume> volumes;
  for (const Frustum& view : views)
    for (int i = 0; i < 1200; ++i) volumes.push_back(make(rng, view.planes[0], i));
  volumes.insert(volumes.end(), extra);
  while (volumes.size() < 12000) volumes.push_back(volumes[rng.next() % volumes.size()]);
  const std::size_t unit = views.size();
  add_lower_edge_views(views);
  add_mirrored_views(views,
                     unit + 12);  // these and the twelve scaled by 0.75 and 0.4 (the first of add_lower_edge_views)
  return {volumes, views};
}

inline EdgeSet<Aabb> aabb_lower_edge_set() {
  return lower_edge_set<Aabb>(41,
                              [](Rng& rng, const Plane& plane, int i) {
                                const glm::vec3 e(rng.uniform(0.05f, 3.0f));
                                const glm::vec3 c = far_along(rng, plane, i);
                                Aabb b{c - e, c + e};
                                const PnVertices v = pn_vertices(plane.normal, b);
                                const glm::vec3 shift = -plane.distance(i % 2 ? v.p : v.n) * plane.normal;
                                b.min += shift;
                                b.max += shift;
                                const int steps = i % 17 - 8;
                                nudge(b.min, plane.normal, steps);
                                nudge(b.max, plane.normal, steps);
                                return b;
                              },
                              {Aabb{{0x1p120f, -1, -1}, {0x1p121f, 1, 1}},
                               Aabb{{-0x1p119f, -0x1p119f, -0x1p119f}, {0x1p119f, 0x1p119f, 0x1p119f}}});
}

inline EdgeSet<Obb> obb_lower_edge_set() {
  return lower_edge_set<Obb>(
      43,
      [](Rng& rng, const Plane& plane, int i) {
        const glm::vec3 n = plane.normal;
        const glm::vec3 a = glm::normalize(glm::cross(n, glm::normalize(rng.vec3(-1, 1) + glm::vec3(0.01f)))),
                        w = glm::cross(n, a);
        Obb o;
        o.half_extents = glm::vec3(rng.uniform(0.05f, 3.0f));
        if (i % 3 == 0) {
          const float phi = 10.0f * 3.14159265f / 180.0f;  // u0 and u1 20 degrees apart, n between their normals
          o.basis = glm::mat3(std::cos(phi) * a - std::sin(phi) * n, std::cos(phi) * a + std::sin(phi) * n, w);
        } else {
          o.basis = glm::mat3(n, a, w);
        }
        float r = 0;  // the reference's projected radius, its operations in its order
        for (int k = 0; k < 3; ++k) {
          const glm::vec3 u = o.basis[k];
          const float term = std::fabs((n.x * u.x + n.y * u.y) + n.z * u.z) * o.half_extents[k];
          r = k == 0 ? term : r + term;
        }
        o.center = far_along(rng, plane, i) + (i % 2 ? r : -r) * n;
        nudge(o.center, n, i % 17 - 8);
        return o;
      },
      {// Past 2^119: bound about 2^122.6, q would be 85 and q bound overflow (INSIDE at x = 2^120).
       Obb{{0x1p120f, 0, 0}, glm::mat3(0x1p100f), glm::vec3(0x1p21f)},
       Obb{{-0x1p120f, 0, 0}, glm::mat3(0x1p100f), glm::vec3(0x1p21f)},
       // Subnormal extents on long axes: DAZ reads them as 0 (INSIDE at x = 0), so no lower bound.
       Obb{{0, 0, 0}, glm::mat3(0x1p40f), glm::vec3(0x1p-127f)},
       Obb{{0x1p-100f, 0, 0}, glm::mat3(0x1p60f), glm::vec3(0x1p-130f)}});
}

inline EdgeSet<Sphere> sphere_lower_edge_set() {
  return lower_edge_set<Sphere>(
      47,
      [](Rng& rng, const Plane& plane, int i) {
        const float r = rng.uniform(0.05f, 3.0f);
        Sphere sp{far_along(rng, plane, i) + (i % 2 ? r : -r) * plane.normal, r};
        nudge(sp.center, plane.normal, i % 17 - 8);
        return sp;
      },
      {// Past 2^119 (q bound would overflow): OUTSIDE, INSIDE and OUTSIDE of x = 0, x = -2^120, x = 2^120.
       Sphere{{-1.01f * 0x1p120f - 0x1p100f, 0, 0}, 1.01f * 0x1p120f}, Sphere{{0x1p120f, 0, 0}, 1.01f * 0x1p120f},
       Sphere{{-0x1p120f, 0, 0}, 1.01f * 0x1p120f}, Sphere{{0, 0, 0}, 0x1p-127f}});
}

}  // namespace cullpipe::test
