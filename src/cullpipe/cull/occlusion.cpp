#include "cullpipe/cull/occlusion.hpp"

#include <algorithm>
#include <bit>
#include <cfloat>
#include <cmath>
#include <stdexcept>
#include <string>

#include "cullpipe/bvh/bvh.hpp"
#include "cullpipe/cull/reference.hpp"

namespace cullpipe::occlusion {

namespace {

// Margins, each proved in docs/numerics.md, "Occlusion footprints".
constexpr float kClipError = 0x1p-18f;      // of a clip row's magnitude bound: ours and the vertex pipeline's error
constexpr float kTiny = 0x1p-100f;          // subnormal roundings
constexpr float kPixelMargin = 0.0625f;     // pixels: the rasteriser's snapping, our roundings
constexpr float kPixelRelative = 0x1p-20f;  // of a pixel coordinate's magnitude
constexpr float kDepthMargin = 0x1p-20f;    // depth: the rasteriser's interpolation, our roundings
constexpr float kMinW = 0x1p-126f, kMaxW = 0x1p126f;  // w range of a projected corner

/// The margins of one footprint: an object's, or a hierarchy node's, each kNodeMarginScale
/// times as wide (products of constants by a power of two, exact; the shader takes the same).
/// `limit` bounds the magnitude of its ndc bounds: past it the volume is not projected (an
/// object's: any finite value; a node's: 2^120, so that the bounds of the volumes inside it,
/// a few roundings larger, stay finite).
struct Margins {
  float clip, tiny, pixel, pixel_relative, depth, limit;
};
constexpr Margins kObjectMargins{.clip = kClipError,
                                 .tiny = kTiny,
                                 .pixel = kPixelMargin,
                                 .pixel_relative = kPixelRelative,
                                 .depth = kDepthMargin,
                                 .limit = FLT_MAX};
constexpr Margins kNodeMargins{.clip = kClipError * kNodeMarginScale,
                               .tiny = kTiny * kNodeMarginScale,
                               .pixel = kPixelMargin * kNodeMarginScale,
                               .pixel_relative = kPixelRelative * kNodeMarginScale,
                               .depth = kDepthMargin * kNodeMarginScale,
                               .limit = 0x1p120f};

/// A volume as the footprint sees it: its corners, and per world axis a bound on the magnitude
/// of any of its points' coordinates (and of the error in the corners as computed).
struct Corners {
  glm::vec3 p[8];
  glm::vec3 magnitude;
};

/// The bounds of x / w over x in [x_lo, x_hi] and w in [w_lo, w_hi], 0 < w_lo.
float quotient_lo(float x_lo, float w_lo, float w_hi) { return x_lo >= 0.0f ? x_lo / w_hi : x_lo / w_lo; }
float quotient_hi(float x_hi, float w_lo, float w_hi) { return x_hi >= 0.0f ? x_hi / w_lo : x_hi / w_hi; }

/// Widens [lo, hi] to hold x / w for x in [x_lo, x_hi] and w in [w_lo, w_hi], 0 < w_lo.
void widen(float& lo, float& hi, float x_lo, float x_hi, float w_lo, float w_hi) {
  lo = std::min(lo, quotient_lo(x_lo, w_lo, w_hi));
  hi = std::max(hi, quotient_hi(x_hi, w_lo, w_hi));
}

/// The pixel range [first, last] of ndc range [lo, hi] on a viewport side of `size` pixels.
void pixel_range(float lo, float hi, std::uint32_t size, const Margins& margins, std::uint32_t& first,
                 std::uint32_t& last) {
  const float half = 0.5f * float(size);
  const float from = (lo + 1.0f) * half, to = (hi + 1.0f) * half;
  const float a = std::floor(from - (margins.pixel + std::fabs(from) * margins.pixel_relative));
  const float b = std::floor(to + (margins.pixel + std::fabs(to) * margins.pixel_relative));
  const float top = float(size - 1);
  // (As the shader clamps: a NaN from an overflowed bound becomes 0, never a conversion of NaN.)
  const float a0 = a > 0.0f ? a : 0.0f, b0 = b > 0.0f ? b : 0.0f;
  first = std::uint32_t(top < a0 ? top : a0);
  last = std::uint32_t(top < b0 ? top : b0);
}

Footprint project(const Corners& c, const OcclusionView& view, const Margins& margins = kObjectMargins) {
  const glm::mat4& m = view.view_proj;
  // Per clip row r, the error allowed in any point's clip coordinate: kClipError times a bound
  // on sum_j |m[j][r]| |p_j| + |m[3][r]| over the volume's points.
  float e[4];
  for (int r = 0; r < 4; ++r) {
    const float a = ((std::fabs(m[0][r]) * c.magnitude.x + std::fabs(m[1][r]) * c.magnitude.y) +
                     std::fabs(m[2][r]) * c.magnitude.z) +
                    std::fabs(m[3][r]);
    e[r] = a * margins.clip + margins.tiny;
  }
  float x_lo = INFINITY, x_hi = -INFINITY, y_lo = INFINITY, y_hi = -INFINITY, z_lo = INFINITY, z_hi = -INFINITY;
  Footprint f;
  for (const glm::vec3& p : c.p) {
    float v[4];
    for (int r = 0; r < 4; ++r) v[r] = ((m[0][r] * p.x + m[1][r] * p.y) + m[2][r] * p.z) + m[3][r];
    const float w_lo = v[3] - e[3], w_hi = v[3] + e[3];
    // At or behind the eye (or NaN): not projected; nor where w leaves the range in which GLSL
    // bounds the division's error (2^-126 to 2^126).
    if (!(w_lo >= kMinW) || !(w_hi < kMaxW)) return f;
    widen(x_lo, x_hi, v[0] - e[0], v[0] + e[0], w_lo, w_hi);
    widen(y_lo, y_hi, v[1] - e[1], v[1] + e[1], w_lo, w_hi);
    widen(z_lo, z_hi, v[2] - e[2], v[2] + e[2], w_lo, w_hi);
  }
  // (NaN compares false: not projected.)
  const float limit = margins.limit;
  if (!(std::fabs(x_lo) <= limit) || !(std::fabs(x_hi) <= limit) || !(std::fabs(y_lo) <= limit) ||
      !(std::fabs(y_hi) <= limit) || !(std::fabs(z_lo) <= limit) || !(std::fabs(z_hi) <= limit))
    return f;
  pixel_range(x_lo, x_hi, view.width, margins, f.x0, f.x1);
  pixel_range(y_lo, y_hi, view.height, margins, f.y0, f.y1);
  f.nearest = view.reversed_z ? z_hi + (margins.depth + std::fabs(z_hi) * margins.depth)
                              : z_lo - (margins.depth + std::fabs(z_lo) * margins.depth);
  f.projected = true;
  return f;
}

/// Corners of a box given by centre, three axes scaled by their half extents, computed in float
/// as ((c + s0 a0) + s1 a1) + s2 a2; magnitude_j = ((|c_j| + |a0_j|) + |a1_j|) + |a2_j| bounds
/// every point's coordinate and, times 2^-21, the corners' rounding.
Corners box_corners(const glm::vec3& c, const glm::vec3& a0, const glm::vec3& a1, const glm::vec3& a2) {
  Corners k;
  for (int i = 0; i < 8; ++i) {
    const glm::vec3 s0 = (i & 1) ? a0 : -a0, s1 = (i & 2) ? a1 : -a1, s2 = (i & 4) ? a2 : -a2;
    k.p[i] = ((c + s0) + s1) + s2;
  }
  k.magnitude = ((glm::abs(c) + glm::abs(a0)) + glm::abs(a1)) + glm::abs(a2);
  return k;
}

Corners aabb_corners(const Aabb& box) {
  Corners k;
  for (int i = 0; i < 8; ++i) k.p[i] = box.corner(i);  // exact
  k.magnitude = glm::max(glm::abs(box.min), glm::abs(box.max));
  return k;
}

template <class Volume>
Classification classify_volume(const Volume& v, const Frustum& frustum, const OcclusionView& view,
                               const DepthPyramid& pyramid, const OcclusionOptions& options) {
  check_view(view, pyramid, options);
  const Classification c = reference::classify(v, frustum);
  if (c == Classification::Outside) return c;
  return occluded(footprint(v, view), pyramid, options) ? Classification::Occluded : c;
}

template <class Volume>
reference::CullCounts classify_all_volumes(std::span<const Volume> volumes, const Frustum& frustum,
                                           const OcclusionView& view, const DepthPyramid& pyramid,
                                           const OcclusionOptions& options, std::span<Classification> out) {
  if (out.size() != volumes.size())
    throw std::invalid_argument("occlusion::classify_all: " + std::to_string(out.size()) + " classes for " +
                                std::to_string(volumes.size()) + " volumes");
  check_view(view, pyramid, options);
  for (std::size_t i = 0; i < volumes.size(); ++i) {
    Classification c = reference::classify(volumes[i], frustum);
    if (c != Classification::Outside && occluded(footprint(volumes[i], view), pyramid, options))
      c = Classification::Occluded;
    out[i] = c;
  }
  return reference::count_classes(out);
}

template <class Volume>
bvh::HierarchicalResult cull_hierarchical_volumes(const bvh::FlatTree& tree, std::span<const Volume> volumes,
                                                  const Frustum& frustum, const OcclusionView& view,
                                                  const DepthPyramid& pyramid, const OcclusionOptions& options,
                                                  const bvh::TraversalOptions& traversal) {
  if constexpr (!std::is_same_v<Volume, Aabb>) bvh::require_unit_normals(frustum, "occlusion::cull_hierarchical");
  check_view(view, pyramid, options);
  bvh::HierarchicalResult r;
  r.classes.assign(volumes.size(), Classification::Outside);
  if (tree.nodes.empty()) return r;
  struct Entry {
    std::uint32_t node, mask;
    bool hidden;  // an ancestor is occluded: what the frustum keeps below is OCCLUDED, untested
  };
  const std::uint32_t all = (1u << frustum.active().size()) - 1u;
  std::vector<Entry> stack{{0, all, false}};
  while (!stack.empty()) {
    const Entry e = stack.back();
    stack.pop_back();
    const bvh::FlatNode& node = tree.nodes[e.node];
    ++r.node_tests;
    std::uint32_t straddled = 0;
    const Classification c = bvh::classify_node<Volume>(node.box, frustum, e.mask, straddled);
    if (c == Classification::Outside) continue;
    r.occlusion_tests += !e.hidden;
    const bool hidden = e.hidden || node_occluded(node.box, view, pyramid, options);
    if (c == Classification::Inside && hidden) {  // the whole range, no further tests
      for (std::uint32_t k = node.first; k < node.first + node.count; ++k)
        r.classes[tree.objects[k]] = Classification::Occluded;
      continue;
    }
    // INTERSECTING, or INSIDE and not hidden (straddled is empty): the objects need their own
    // occlusion test, so the walk goes on below an INSIDE node.
    if (traversal.tests_objects_of(node)) {
      for (std::uint32_t k = node.first; k < node.first + node.count; ++k) {
        const std::uint32_t id = tree.objects[k];
        Classification oc = bvh::classify_object(volumes[id], frustum, straddled);
        ++r.object_tests;
        const bool tests = oc != Classification::Outside && !hidden;
        r.occlusion_tests += tests;
        if (oc != Classification::Outside &&
            (hidden || (tests && occluded(footprint(volumes[id], view), pyramid, options))))
          oc = Classification::Occluded;
        r.classes[id] = oc;
      }
      continue;
    }
    stack.push_back({tree.nodes[e.node + 1].skip, straddled, hidden});
    stack.push_back({e.node + 1, straddled, hidden});
  }
  const reference::CullCounts counts = reference::count_classes(r.classes);
  r.visible = counts.visible;
  r.inside = counts.inside;
  r.occluded = counts.occluded;
  return r;
}

}  // namespace

Footprint footprint(const Aabb& box, const OcclusionView& view) { return project(aabb_corners(box), view); }

Footprint node_footprint(const Aabb& node, const OcclusionView& view) {
  return project(aabb_corners(node), view, kNodeMargins);
}

Footprint footprint(const Obb& box, const OcclusionView& view) {
  return project(box_corners(box.center, box.basis[0] * box.half_extents.x, box.basis[1] * box.half_extents.y,
                             box.basis[2] * box.half_extents.z),
                 view);
}

Footprint footprint(const Sphere& s, const OcclusionView& view) {
  const float r = std::fabs(s.radius);
  return project(box_corners(s.center, glm::vec3(r, 0.0f, 0.0f), glm::vec3(0.0f, r, 0.0f), glm::vec3(0.0f, 0.0f, r)),
                 view);
}

bool node_occluded(const Aabb& node, const OcclusionView& view, const DepthPyramid& pyramid,
                   const OcclusionOptions& options) {
  return occluded(node_footprint(node, view), pyramid, {std::min(options.texels_per_axis, kNodeTexelsPerAxis), 0});
}

unsigned test_level(const Footprint& f, const DepthPyramid& pyramid, std::uint32_t texels_per_axis) {
  unsigned k = 0;
  while (k + 1 < pyramid.levels.size() &&
         ((f.x1 >> k) - (f.x0 >> k) >= texels_per_axis || (f.y1 >> k) - (f.y0 >> k) >= texels_per_axis))
    ++k;
  return k;
}

namespace {

// Whether every texel over the footprint, at the finest level where it spans at most `texels`
// texels per axis, is strictly nearer than the volume's nearest fragment.
bool hidden_at(const Footprint& f, const DepthPyramid& pyramid, std::uint32_t texels) {
  const unsigned k = test_level(f, pyramid, texels);
  const PyramidLevel& level = pyramid.levels[k];
  const std::uint32_t tx0 = texel_of(f.x0, k, level.width), tx1 = texel_of(f.x1, k, level.width);
  const std::uint32_t ty0 = texel_of(f.y0, k, level.height), ty1 = texel_of(f.y1, k, level.height);
  for (std::uint32_t y = ty0; y <= ty1; ++y)
    for (std::uint32_t x = tx0; x <= tx1; ++x) {
      const float farthest = pyramid.at(k, x, y);
      // Hidden only behind a depth strictly nearer than the volume's nearest (NaN: not hidden).
      if (!(pyramid.reversed_z ? f.nearest < farthest : f.nearest > farthest)) return false;
    }
  return true;
}

}  // namespace

bool occluded(const Footprint& f, const DepthPyramid& pyramid, const OcclusionOptions& options) {
  if (!f.projected) return false;
  if (hidden_at(f, pyramid, options.texels_per_axis)) return true;
  return options.refine_texels_per_axis > options.texels_per_axis &&
         hidden_at(f, pyramid, options.refine_texels_per_axis);
}

void check_view(const OcclusionView& view, const DepthPyramid& pyramid, const OcclusionOptions& options) {
  check_view(view, pyramid.width, pyramid.height, pyramid.reversed_z, options);
}

void check_view(const OcclusionView& view, std::uint32_t width, std::uint32_t height, bool reversed_z,
                const OcclusionOptions& options) {
  const auto size = [](std::uint32_t w, std::uint32_t h) { return std::to_string(w) + "x" + std::to_string(h); };
  if (view.width != width || view.height != height)
    throw std::invalid_argument("occlusion: a " + size(view.width, view.height) + " view does not match a " +
                                size(width, height) + " depth pyramid");
  if (view.width == 0 || view.height == 0 || view.width > kMaxViewportSide || view.height > kMaxViewportSide)
    throw std::invalid_argument("occlusion: a " + size(view.width, view.height) + " viewport (each side 1 to " +
                                std::to_string(kMaxViewportSide) + ")");
  if (view.reversed_z != reversed_z)
    throw std::invalid_argument(std::string("occlusion: a ") + (view.reversed_z ? "reversed-Z" : "standard-depth") +
                                " view against a " + (reversed_z ? "reversed-Z" : "standard-depth") + " pyramid");
  for (int c = 0; c < 4; ++c)
    for (int r = 0; r < 4; ++r)
      if (!std::isfinite(view.view_proj[c][r]))
        throw std::invalid_argument("occlusion: the view-projection matrix has a non-finite entry");
  const std::uint32_t t = options.texels_per_axis, r = options.refine_texels_per_axis;
  if (t != 2 && t != 4 && t != 8 && t != 16)
    throw std::invalid_argument("occlusion: texels_per_axis " + std::to_string(t) + " (2, 4, 8 or 16)");
  if (r != 0 && r != 2 && r != 4 && r != 8 && r != 16)
    throw std::invalid_argument("occlusion: refine_texels_per_axis " + std::to_string(r) + " (0, 2, 4, 8 or 16)");
}

Classification classify(const Aabb& box, const Frustum& frustum, const OcclusionView& view, const DepthPyramid& pyramid,
                        const OcclusionOptions& options) {
  return classify_volume(box, frustum, view, pyramid, options);
}
Classification classify(const Obb& box, const Frustum& frustum, const OcclusionView& view, const DepthPyramid& pyramid,
                        const OcclusionOptions& options) {
  return classify_volume(box, frustum, view, pyramid, options);
}
Classification classify(const Sphere& sphere, const Frustum& frustum, const OcclusionView& view,
                        const DepthPyramid& pyramid, const OcclusionOptions& options) {
  return classify_volume(sphere, frustum, view, pyramid, options);
}

reference::CullCounts classify_all(std::span<const Aabb> volumes, const Frustum& frustum, const OcclusionView& view,
                                   const DepthPyramid& pyramid, const OcclusionOptions& options,
                                   std::span<Classification> out) {
  return classify_all_volumes(volumes, frustum, view, pyramid, options, out);
}
reference::CullCounts classify_all(std::span<const Obb> volumes, const Frustum& frustum, const OcclusionView& view,
                                   const DepthPyramid& pyramid, const OcclusionOptions& options,
                                   std::span<Classification> out) {
  return classify_all_volumes(volumes, frustum, view, pyramid, options, out);
}
reference::CullCounts classify_all(std::span<const Sphere> volumes, const Frustum& frustum, const OcclusionView& view,
                                   const DepthPyramid& pyramid, const OcclusionOptions& options,
                                   std::span<Classification> out) {
  return classify_all_volumes(volumes, frustum, view, pyramid, options, out);
}

bvh::HierarchicalResult cull_hierarchical(const bvh::FlatTree& tree, std::span<const Aabb> volumes,
                                          const Frustum& frustum, const OcclusionView& view,
                                          const DepthPyramid& pyramid, const OcclusionOptions& options,
                                          const bvh::TraversalOptions& traversal) {
  return cull_hierarchical_volumes(tree, volumes, frustum, view, pyramid, options, traversal);
}
bvh::HierarchicalResult cull_hierarchical(const bvh::FlatTree& tree, std::span<const Obb> volumes,
                                          const Frustum& frustum, const OcclusionView& view,
                                          const DepthPyramid& pyramid, const OcclusionOptions& options,
                                          const bvh::TraversalOptions& traversal) {
  return cull_hierarchical_volumes(tree, volumes, frustum, view, pyramid, options, traversal);
}
bvh::HierarchicalResult cull_hierarchical(const bvh::FlatTree& tree, std::span<const Sphere> volumes,
                                          const Frustum& frustum, const OcclusionView& view,
                                          const DepthPyramid& pyramid, const OcclusionOptions& options,
                                          const bvh::TraversalOptions& traversal) {
  return cull_hierarchical_volumes(tree, volumes, frustum, view, pyramid, options, traversal);
}

}  // namespace cullpipe::occlusion
