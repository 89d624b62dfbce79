#include "cullpipe/cull/software_depth.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <glm/mat4x4.hpp>
#include <glm/vec2.hpp>
#include <glm/vec3.hpp>
#include <glm/vec4.hpp>
#include <limits>
#include <stdexcept>
#include <string>

#include "cullpipe/core/thread_pool.hpp"

namespace cullpipe::occlusion {

namespace {

using glm::dvec2;
using glm::dvec3;
using glm::dvec4;

// Margins, proved in docs/numerics.md, "Software depth": four times the model's vertex error
// (2^-19 of a clip row's magnitude bound), the rasteriser's snapping (1/128 pixel) and depth
// interpolation (2^-21 (1 + |z|)), and slack for this file's own double roundings.
constexpr double kVertexError = 0x1p-17;
constexpr double kSnap = 1.0 / 128.0;
constexpr double kInterpolation = 0x1p-21;
constexpr double kSlack = 1e-9;
constexpr std::uint32_t kMaxRow = 256;  // pixels of a row evaluated at once

/// One occluder box, ready to rasterise: its silhouette (the convex hull of its projected
/// corners, counter-clockwise in pixel coordinates), its front planes' depths as affine
/// functions a x + b y + c of the full-resolution pixel position (unused planes never win),
/// and its margins in pixels and depth.
struct Shape {
  std::array<dvec2, 17> hull{};  // (8 points; room for what near-collinear roundings may add)
  int hull_size = 0;
  std::array<dvec3, 6> planes{};
  int plane_count = 0;
  double e = 0, eps = 0;
  double x_lo = 0, x_hi = 0, y_lo = 0, y_hi = 0;  // the silhouette's bounding box
};

double cross(const dvec2& o, const dvec2& a, const dvec2& b) {
  return (a.x - o.x) * (b.y - o.y) - (a.y - o.y) * (b.x - o.x);
}

/// Andrew's monotone chain: the convex hull of `p`, counter-clockwise (in a y-down frame:
/// every cross product of consecutive edges positive), collinear points dropped.
int convex_hull(std::array<dvec2, 8> p, std::array<dvec2, 17>& hull) {
  std::sort(p.begin(), p.end(), [](const dvec2& a, const dvec2& b) { return a.x < b.x || (a.x == b.x && a.y < b.y); });
  int k = 0;
  for (int i = 0; i < 8; ++i) {
    while (k >= 2 && cross(hull[k - 2], hull[k - 1], p[i]) <= 0) --k;
    hull[std::size_t(k++)] = p[i];
  }
  for (int i = 6, t = k + 1; i >= 0; --i) {
    while (k >= t && cross(hull[k - 2], hull[k - 1], p[i]) <= 0) --k;
    hull[std::size_t(k++)] = p[i];  // (at most 16: each point pushed once per chain)
  }
  return k - 1;  // the last point repeats the first
}

/// Prepares `box` for a viewport of width x height pixels whose buffer pixels are cell_x x cell_y
/// of them; false when the box occludes nothing here (also when it cannot cover a whole pixel).
bool prepare(const OccluderBox& box, const glm::dmat4& m, double width, double height, double cell_x, double cell_y,
             bool reversed, Shape& s) {
  const dvec3 c(box.center);
  dvec3 a[3];
  for (int k = 0; k < 3; ++k) a[k] = dvec3(box.half_axes[k]);
  const dvec3 magnitude = glm::abs(c) + glm::abs(a[0]) + glm::abs(a[1]) + glm::abs(a[2]);
  double delta[4];
  for (int r = 0; r < 4; ++r)
    delta[r] = kVertexError * (std::abs(m[0][r]) * magnitude.x + std::abs(m[1][r]) * magnitude.y +
                               std::abs(m[2][r]) * magnitude.z + std::abs(m[3][r])) +
               0x1p-100;
  std::array<dvec2, 8> screen;
  std::array<double, 8> depth;
  double e = 0, eps = 0, largest = 0, largest_depth = 0;
  for (int i = 0; i < 8; ++i) {
    const dvec3 p = c + ((i & 1) ? a[0] : -a[0]) + ((i & 2) ? a[1] : -a[1]) + ((i & 4) ? a[2] : -a[2]);
    const dvec4 v = m * dvec4(p, 1.0);
    const double w_lo = v.w - delta[3];
    if (!(w_lo > 0x1p-100) || !std::isfinite(v.w)) return false;  // at or behind the eye, or NaN
    const double x = v.x / v.w, y = v.y / v.w, z = v.z / v.w;
    screen[i] = dvec2((x + 1.0) * 0.5 * width, (y + 1.0) * 0.5 * height);
    depth[i] = z;
    e = std::max({e, 0.5 * width * (delta[0] + std::abs(x) * delta[3]) / w_lo,
                  0.5 * height * (delta[1] + std::abs(y) * delta[3]) / w_lo});
    const double corner_eps = (delta[2] + std::abs(z) * delta[3]) / w_lo;
    eps = std::max(eps, corner_eps);
    // The GPU clips what lies nearer than the near plane (depth 0; reversed, 1) and shows what is
    // behind it there: a box reaching past it occludes nothing here.
    if (!(reversed ? z + 2.0 * corner_eps < 1.0 : z - 2.0 * corner_eps > 0.0)) return false;
    largest = std::max({largest, std::abs(screen[i].x), std::abs(screen[i].y)});
    largest_depth = std::max(largest_depth, std::abs(z));
  }
  s.e = e * (1.0 + kSlack) + kSnap + kSlack * (1.0 + largest);
  s.eps = eps * (1.0 + kSlack) + kInterpolation * (1.0 + largest_depth) + kSlack * (1.0 + largest_depth);
  if (!std::isfinite(s.e) || !std::isfinite(s.eps) || !std::isfinite(largest)) return false;
  // Too small to hold a whole buffer pixel widened by e: nothing to write (most distant boxes).
  double x_lo = screen[0].x, x_hi = x_lo, y_lo = screen[0].y, y_hi = y_lo;
  for (const dvec2& p : screen)
    x_lo = std::min(x_lo, p.x), x_hi = std::max(x_hi, p.x), y_lo = std::min(y_lo, p.y), y_hi = std::max(y_hi, p.y);
  if (x_hi - x_lo < cell_x + 2.0 * s.e || y_hi - y_lo < cell_y + 2.0 * s.e) return false;
  if (x_hi < 0.0 || y_hi < 0.0 || x_lo > width || y_lo > height) return false;  // off screen
  s.hull_size = convex_hull(screen, s.hull);
  if (s.hull_size < 3) return false;  // seen edge on: covers no pixel whole
  s.x_lo = s.x_hi = s.hull[0].x;
  s.y_lo = s.y_hi = s.hull[0].y;
  for (int i = 1; i < s.hull_size; ++i) {
    s.x_lo = std::min(s.x_lo, s.hull[i].x), s.x_hi = std::max(s.x_hi, s.hull[i].x);
    s.y_lo = std::min(s.y_lo, s.hull[i].y), s.y_hi = std::max(s.y_hi, s.hull[i].y);
  }
  // The centre's screen position and depth: a face plane crossing its ray before the centre
  // faces the eye. A plane not clearly behind it is kept: an extra plane only moves the
  // bound farther.
  const dvec4 vc = m * dvec4(c, 1.0);
  const dvec2 qc((vc.x / vc.w + 1.0) * 0.5 * width, (vc.y / vc.w + 1.0) * 0.5 * height);
  const double zc = vc.z / vc.w;
  s.plane_count = 0;
  for (int axis = 0; axis < 3; ++axis)
    for (int side = 0; side < 2; ++side) {
      // Three corners of the face: the one with the others' bits clear, and one step along each.
      const int base = side << axis, u = 1 << ((axis + 1) % 3), v = 1 << ((axis + 2) % 3);
      const dvec2 p0 = screen[base], p1 = screen[base | u], p2 = screen[base | v];
      const double z0 = depth[base], z1 = depth[base | u], z2 = depth[base | v];
      const double det = (p1.x - p0.x) * (p2.y - p0.y) - (p2.x - p0.x) * (p1.y - p0.y);
      const double pa = ((z1 - z0) * (p2.y - p0.y) - (z2 - z0) * (p1.y - p0.y)) / det;
      const double pb = ((p1.x - p0.x) * (z2 - z0) - (p2.x - p0.x) * (z1 - z0)) / det;
      const double pc = z0 - pa * p0.x - pb * p0.y;
      if (!std::isfinite(pa) || !std::isfinite(pb) || !std::isfinite(pc)) return false;  // edge on
      const double at_centre = pa * qc.x + pb * qc.y + pc;
      // Dropped only when clearly beyond the centre (the comparison's roundings are far below
      // 2^-40 of its terms); a plane kept needlessly only moves the bound farther.
      const double clear = 0x1p-40 * (std::abs(pa * qc.x) + std::abs(pb * qc.y) + std::abs(pc) + std::abs(zc));
      const bool behind = reversed ? at_centre < zc - clear : at_centre > zc + clear;
      if (behind) continue;
      // A kept face seen (nearly) edge on: its plane's coefficients come from a near-singular
      // solve, so the box is left out (occluding nothing is always safe).
      const double e1 = std::abs(p1.x - p0.x) + std::abs(p1.y - p0.y),
                   e2 = std::abs(p2.x - p0.x) + std::abs(p2.y - p0.y);
      if (!(std::abs(det) > 0x1p-20 * e1 * e2)) return false;
      s.planes[std::size_t(s.plane_count++)] = dvec3(pa, pb, pc);
    }
  return s.plane_count > 0 && std::isfinite(zc) && std::isfinite(qc.x) && std::isfinite(qc.y);
}

/// Whether `q` lies inside the silhouette (on the inner side of every edge, with slack for
/// the double roundings of the test).
bool inside(const Shape& s, const dvec2& q) {
  for (int i = 0; i < s.hull_size; ++i) {
    const dvec2 &a = s.hull[std::size_t(i)], &b = s.hull[std::size_t(i + 1)];
    const double slack = kSlack * (std::abs(a.x) + std::abs(a.y) + std::abs(b.x) + std::abs(b.y) + 1.0) *
                         (std::abs(b.x - a.x) + std::abs(b.y - a.y) + std::abs(q.x) + std::abs(q.y) + 1.0);
    if (!(cross(a, b, q) > slack)) return false;
  }
  return true;
}

}  // namespace

OccluderBox occluder_box(const Aabb& local, const glm::mat4& world) {
  const glm::vec3 centre = 0.5f * (local.min + local.max), half = 0.5f * (local.max - local.min);
  OccluderBox b;
  b.center = glm::vec3(world * glm::vec4(centre, 1.0f));
  for (int k = 0; k < 3; ++k) b.half_axes[k] = glm::vec3(world[k]) * half[k];
  return b;
}

OccluderBox occluder_box(const Obb& box) {
  OccluderBox b;
  b.center = box.center;
  for (int k = 0; k < 3; ++k) b.half_axes[k] = box.basis[k] * box.half_extents[k];
  return b;
}

SoftwareDepth rasterise_occluders(std::span<const OccluderBox> occluders, const OcclusionView& view,
                                  std::uint32_t width, std::uint32_t height, ThreadPool* pool) {
  check_view(view, view.width, view.height, view.reversed_z);
  if (width == 0 || height == 0 || width > view.width || height > view.height)
    throw std::invalid_argument("software depth: a " + std::to_string(width) + "x" + std::to_string(height) +
                                " buffer for a " + std::to_string(view.width) + "x" + std::to_string(view.height) +
                                " viewport (each side 1 to the viewport's)");
  const bool reversed = view.reversed_z;
  SoftwareDepth out;
  out.width = width;
  out.height = height;
  out.reversed_z = reversed;
  out.depth.assign(std::size_t(width) * height, reversed ? 0.0f : 1.0f);
  const glm::dmat4 m(view.view_proj);
  const double full_w = view.width, full_h = view.height;
  // A buffer pixel (px, py) covers full-resolution pixels [px sx, (px + 1) sx) x [py sy, (py + 1) sy).
  const double sx = full_w / width, sy = full_h / height;
  // The boxes prepared in parallel, each task keeping the few that can cover a pixel (order does
  // not matter: a pixel keeps the nearest value).
  constexpr std::size_t kBoxesPerTask = 2048;
  const std::size_t box_tasks = (occluders.size() + kBoxesPerTask - 1) / kBoxesPerTask;
  std::vector<std::vector<Shape>> prepared(box_tasks);
  auto prepare_boxes = [&](std::size_t task) {
    const std::size_t first = task * kBoxesPerTask, end = std::min(occluders.size(), first + kBoxesPerTask);
    Shape s;
    for (std::size_t i = first; i < end; ++i)
      if (prepare(occluders[i], m, full_w, full_h, sx, sy, reversed, s)) prepared[task].push_back(s);
  };
  if (pool)
    pool->parallel_for(box_tasks, prepare_boxes);
  else
    for (std::size_t t = 0; t < box_tasks; ++t) prepare_boxes(t);
  std::vector<Shape> shapes;
  for (const std::vector<Shape>& part : prepared) shapes.insert(shapes.end(), part.begin(), part.end());
  // Each band of rows gets the boxes that reach it.
  constexpr std::uint32_t kRowsPerTask = 8;
  const std::size_t tasks = (height + kRowsPerTask - 1) / kRowsPerTask;
  std::vector<std::vector<std::uint32_t>> in_band(tasks);
  for (std::size_t i = 0; i < shapes.size(); ++i) {
    const double top = std::clamp(std::floor(shapes[i].y_lo / sy), 0.0, double(height));
    const double bottom = std::clamp(std::ceil(shapes[i].y_hi / sy), 0.0, double(height));
    for (std::size_t b = std::size_t(top) / kRowsPerTask; b < tasks && double(b * kRowsPerTask) < bottom; ++b)
      in_band[b].push_back(std::uint32_t(i));
  }
  auto band = [&](std::size_t task) {
    const std::uint32_t row_first = std::uint32_t(task) * kRowsPerTask,
                        row_end = std::min(height, row_first + kRowsPerTask);
    for (const std::uint32_t index : in_band[task]) {
      const Shape& s = shapes[index];
      // Pixels whose rectangle, widened by e, may lie inside the silhouette.
      const double first_y = std::ceil((s.y_lo + s.e) / sy), last_y = std::floor((s.y_hi - s.e) / sy) - 1.0;
      const double first_x = std::ceil((s.x_lo + s.e) / sx), last_x = std::floor((s.x_hi - s.e) / sx) - 1.0;
      const std::uint32_t y0 = std::uint32_t(std::clamp(first_y, double(row_first), double(row_end)));
      const std::uint32_t y1 = std::uint32_t(std::clamp(last_y + 1.0, double(row_first), double(row_end)));
      const std::uint32_t x0 = std::uint32_t(std::clamp(first_x, 0.0, double(width)));
      const std::uint32_t x1 = std::uint32_t(std::clamp(last_x + 1.0, 0.0, double(width)));
      // Each plane's depth at the rectangle's extreme corner is a x + (b y + c) with x = px sx +
      // offset: the row part and the offset once per row, the rest per pixel in a loop the
      // compiler vectorises. `bound` covers the evaluation's roundings (the terms may be much
      // larger than the depth).
      const double x_reach = std::max(std::abs(s.x_lo), std::abs(s.x_hi)) + s.e + sx,
                   y_reach = std::max(std::abs(s.y_lo), std::abs(s.y_hi)) + s.e + sy;
      for (std::uint32_t py = y0; py < y1; ++py) {
        const double ya = py * sy - s.e, yb = (py + 1) * sy + s.e;
        auto covered = [&](std::uint32_t px) {
          const double xa = px * sx - s.e, xb = (px + 1) * sx + s.e;
          return inside(s, {xa, ya}) && inside(s, {xb, ya}) && inside(s, {xa, yb}) && inside(s, {xb, yb});
        };
        // The covered pixels of a row are an interval (the silhouette is convex): its ends.
        std::uint32_t first = x0, last = x1;
        while (first < x1 && !covered(first)) ++first;
        if (first == x1) continue;
        while (last > first + 1 && !covered(last - 1)) --last;
        double row[kMaxRow];
        for (std::uint32_t block = first; block < last; block += kMaxRow) {
          const std::uint32_t n = std::min<std::uint32_t>(kMaxRow, last - block);
          for (std::uint32_t k = 0; k < n; ++k)
            row[k] = reversed ? std::numeric_limits<double>::infinity() : -std::numeric_limits<double>::infinity();
          for (int i = 0; i < s.plane_count; ++i) {
            const dvec3& p = s.planes[std::size_t(i)];
            const double bound = 0x1p-50 * (std::abs(p.x) * x_reach + std::abs(p.y) * y_reach + std::abs(p.z));
            // The corner where the plane is farthest (reversed: smallest): x at the right end if a > 0.
            const bool right = reversed ? p.x < 0.0 : p.x > 0.0;
            const double offset = right ? sx + s.e : -s.e;
            const double row_part = (reversed ? std::min(p.y * ya, p.y * yb) : std::max(p.y * ya, p.y * yb)) + p.z +
                                    (reversed ? -bound : bound);
            const double step = p.x * sx, start = p.x * (double(block) * sx + offset) + row_part;
            if (reversed)
              for (std::uint32_t k = 0; k < n; ++k) row[k] = std::min(row[k], start + step * double(k));
            else
              for (std::uint32_t k = 0; k < n; ++k) row[k] = std::max(row[k], start + step * double(k));
          }
          float* stored = out.depth.data() + std::size_t(py) * width + block;
          for (std::uint32_t k = 0; k < n; ++k) {
            // Farther by eps, then rounded to a float no nearer (a step of 2^-23 |v| covers
            // round-to-nearest; 2^-126 the subnormals).
            const double v = reversed ? row[k] - s.eps - (std::abs(row[k]) * 0x1p-23 + 0x1p-126)
                                      : row[k] + s.eps + (std::abs(row[k]) * 0x1p-23 + 0x1p-126);
            const float f = float(v);
            stored[k] = reversed ? std::max(stored[k], f) : std::min(stored[k], f);  // the nearest occluder's
          }
        }
      }
    }
  };
  if (pool)
    pool->parallel_for(tasks, band);
  else
    for (std::size_t t = 0; t < tasks; ++t) band(t);
  return out;
}

template <class Volume>
reference::CullCounts cull_with_software_depth(std::span<const Volume> volumes, std::span<const OccluderBox> occluders,
                                               const Frustum& frustum, const OcclusionView& view, std::uint32_t width,
                                               std::uint32_t height, const OcclusionOptions& options,
                                               std::span<Classification> out, ThreadPool* pool) {
  if (out.size() != volumes.size())
    throw std::invalid_argument("occlusion::cull_with_software_depth: " + std::to_string(out.size()) + " classes for " +
                                std::to_string(volumes.size()) + " volumes");
  const SoftwareDepth depth = rasterise_occluders(occluders, view, width, height, pool);
  const DepthPyramid pyramid = build_depth_pyramid(depth.depth, width, height, depth.reversed_z);
  const OcclusionView small = software_view(view, depth);
  check_view(small, pyramid, options);
  constexpr std::size_t kChunk = 4096;
  const std::size_t chunks = (volumes.size() + kChunk - 1) / kChunk;
  auto classify_chunk = [&](std::size_t chunk) {
    const std::size_t first = chunk * kChunk, end = std::min(volumes.size(), first + kChunk);
    classify_all(volumes.subspan(first, end - first), frustum, small, pyramid, options,
                 out.subspan(first, end - first));
  };
  if (pool)
    pool->parallel_for(chunks, classify_chunk);
  else
    for (std::size_t c = 0; c < chunks; ++c) classify_chunk(c);
  return reference::count_classes(out);
}

template reference::CullCounts cull_with_software_depth<Aabb>(std::span<const Aabb>, std::span<const OccluderBox>,
                                                              const Frustum&, const OcclusionView&, std::uint32_t,
                                                              std::uint32_t, const OcclusionOptions&,
                                                              std::span<Classification>, ThreadPool*);
template reference::CullCounts cull_with_software_depth<Obb>(std::span<const Obb>, std::span<const OccluderBox>,
                                                             const Frustum&, const OcclusionView&, std::uint32_t,
                                                             std::uint32_t, const OcclusionOptions&,
                                                             std::span<Classification>, ThreadPool*);
template reference::CullCounts cull_with_software_depth<Sphere>(std::span<const Sphere>, std::span<const OccluderBox>,
                                                                const Frustum&, const OcclusionView&, std::uint32_t,
                                                                std::uint32_t, const OcclusionOptions&,
                                                                std::span<Classification>, ThreadPool*);

}  // namespace cullpipe::occlusion
