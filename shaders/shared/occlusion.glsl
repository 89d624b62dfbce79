// occlusion.glsl: the occlusion test of the flat pass, the same float operations in the same
// order as src/cullpipe/cull/occlusion.cpp (the reference), every sum and product `precise`. A volume's
// footprint from its eight corners (a pixel rectangle and a bound on its nearest fragment depth),
// read against the depth pyramid at the finest level spanning at most texels_per_axis texels.
// Proof that it is conservative: docs/numerics.md, Occlusion footprints.
// Hierarchy nodes take every margin OCC_NODE_MARGIN_SCALE times an object's (a power of two:
// the products are exact), so that an occluded node hides every volume inside it as the volume's
// own test finds it (docs/numerics.md, Hierarchical occlusion).
// Included after the includer declares `float pyramid[]` (the pyramid's floats), the uniform
// texel buffer `occlusion_views` (GpuOcclusionView per view), the volume kind BV_KIND, and
// `vec4 occ_volume_word(uint word)` (the vec4 words of the volumes, as the includer stores them).
#ifndef CULLPIPE_SHADERS_SHARED_OCCLUSION_GLSL
#define CULLPIPE_SHADERS_SHARED_OCCLUSION_GLSL

const float OCC_CLIP_ERROR = 1.0 / 262144.0;         // 2^-18
const float OCC_TINY = 7.88860905221011805411728565283e-31;  // 2^-100 (exactly, as a float)
const float OCC_PIXEL_MARGIN = 0.0625;
const float OCC_PIXEL_RELATIVE = 1.0 / 1048576.0;  // 2^-20
const float OCC_MIN_W = 1.17549435082228750796873653722e-38;  // 2^-126
const float OCC_MAX_W = 8.50705917302346158658436518579e37;   // 2^126
const float OCC_DEPTH_MARGIN = 1.0 / 1048576.0;    // 2^-20
const float OCC_NODE_MARGIN_SCALE = 4.0;           // occlusion::kNodeMarginScale

// OcclusionOptions::texels_per_axis, a specialization constant: a row of texels is read unrolled
// and only the rows loop. lavapipe ends every loop of an invocation once the loops of that
// invocation together have run 65535 iterations (gallivm's loop limiter, shared by all loops):
// a hierarchical walk that read every texel in a loop ran past it and stopped early.
layout(constant_id = 7) const uint OCC_TEXELS = 4;
// Hierarchy nodes read at most occlusion::kNodeTexelsPerAxis texels per axis.
const uint OCC_NODE_TEXELS = OCC_TEXELS < 4u ? OCC_TEXELS : 4u;
// OcclusionOptions::refine_texels_per_axis (0: none): a volume the OCC_TEXELS test keeps is
// read again at the finest level where it spans at most this many texels per axis.
layout(constant_id = 10) const uint OCC_REFINE_TEXELS = 0;

// The view's GpuOcclusionView, loaded by occ_load_view.
mat4 occ_view_proj;
uint occ_width, occ_height, occ_reversed, occ_level_count;
int occ_view_first;  // the view's first texel in occlusion_views

void occ_load_view(uint view) {
  int o = int(OCCLUSION_VIEW_TEXELS * view);
  [[unroll]] for (int c = 0; c < 4; ++c) occ_view_proj[c] = uintBitsToFloat(texelFetch(occlusion_views, o + c));
  uvec4 sizes = texelFetch(occlusion_views, o + 4);
  occ_width = sizes.x;
  occ_height = sizes.y;
  occ_reversed = sizes.z;
  occ_level_count = min(texelFetch(occlusion_views, o + 5).x, PYRAMID_MAX_LEVELS);
  occ_view_first = o;
}

float occ_quotient_lo(float x, float w_lo, float w_hi) {
  precise float q = x >= 0.0 ? x / w_hi : x / w_lo;
  return q;
}
float occ_quotient_hi(float x, float w_lo, float w_hi) {
  precise float q = x >= 0.0 ? x / w_lo : x / w_hi;
  return q;
}

// Widens [lo, hi] to hold x / w for x in [x_lo, x_hi] and w in [w_lo, w_hi], 0 < w_lo (as
// std::min and std::max do: the new bound replaces the old only when strictly beyond it).
void occ_widen(inout float lo, inout float hi, float x_lo, float x_hi, float w_lo, float w_hi) {
  float q = occ_quotient_lo(x_lo, w_lo, w_hi);
  lo = q < lo ? q : lo;
  q = occ_quotient_hi(x_hi, w_lo, w_hi);
  hi = hi < q ? q : hi;
}

// The pixel range [first, last] of ndc range [lo, hi] on a side of `size` pixels.
void occ_pixel_range(float lo, float hi, uint size, float scale, out uint first, out uint last) {
  precise float half_size = 0.5 * float(size);
  precise float from = (lo + 1.0) * half_size;
  precise float to = (hi + 1.0) * half_size;
  float margin = OCC_PIXEL_MARGIN * scale, relative = OCC_PIXEL_RELATIVE * scale;
  precise float a = floor(from - (margin + abs(from) * relative));
  precise float b = floor(to + (margin + abs(to) * relative));
  float top = float(size - 1u);
  a = a > 0.0 ? a : 0.0;
  b = b > 0.0 ? b : 0.0;
  first = uint(top < a ? top : a);
  last = uint(top < b ? top : b);
}

// Whether the pixel rectangle [px0, px1] x [py0, py1] is hidden behind the pyramid at the finest
// level where it spans at most `texels` texels per axis: every texel there strictly nearer than
// `nearest` (occlusion.cpp's hidden_at). Nothing is read unless `test`.
bool occ_hidden_at(bool test, uint px0, uint px1, uint py0, uint py1, float nearest, uint texels) {
  uint k = 0;
  [[unroll]] for (uint i = 0; i + 1u < PYRAMID_MAX_LEVELS; ++i)
    k += test && k == i && k + 1u < occ_level_count &&
                 ((px1 >> k) - (px0 >> k) >= texels || (py1 >> k) - (py0 >> k) >= texels)
             ? 1u
             : 0u;
  uvec4 level = texelFetch(occlusion_views, occ_view_first + 6 + int(k));  // x = offset, y = width, z = height
  uint tx0 = min(px0 >> k, level.y - 1u), tx1 = min(px1 >> k, level.y - 1u);
  uint ty0 = min(py0 >> k, level.z - 1u), ty1 = min(py1 >> k, level.z - 1u);
  // At most `texels` texels per axis from (tx0, ty0): hidden when every one is strictly nearer.
  bool hidden = test;
  ty1 = test ? ty1 : 0u;
  ty0 = test ? ty0 : 1u;  // (no rows)
  for (uint y = ty0; y <= ty1 && hidden; ++y) {  // (a row found nearer settles it)
    [[unroll]] for (uint dx = 0; dx < texels; ++dx) {
      uint x = tx0 + dx;
      bool read = x <= tx1;
      float farthest = 0.0;
      if (read) farthest = pyramid[level.x + y * level.y + x];
      hidden = hidden && (!read || (occ_reversed != 0u ? nearest < farthest : nearest > farthest));
    }
  }
  return hidden;
}

// Whether the volume with corners p[8], every point's coordinates bounded by `magnitude`, is
// hidden: every pyramid texel over its footprint strictly nearer than its nearest fragment.
// `scale`: 1 for an object, OCC_NODE_MARGIN_SCALE for a hierarchy node; `texels` its texels per
// axis (OCC_TEXELS or OCC_NODE_TEXELS).
bool occ_occluded(vec3 p[8], vec3 magnitude, float scale, uint texels) {
  mat4 m = occ_view_proj;
  float e[4];
  float clip_error = OCC_CLIP_ERROR * scale, tiny = OCC_TINY * scale;
  [[unroll]] for (uint r = 0; r < 4; ++r) {
    precise float a = ((abs(m[0][r]) * magnitude.x + abs(m[1][r]) * magnitude.y) + abs(m[2][r]) * magnitude.z) + abs(m[3][r]);
    precise float er = a * clip_error + tiny;
    e[r] = er;
  }
  // One exit, at the end: a lane that is not projected reads no texel.
  bool projected = true;
  float inf = uintBitsToFloat(0x7f800000u);
  float x_lo = inf, x_hi = -inf, y_lo = inf, y_hi = -inf, z_lo = inf, z_hi = -inf;
  [[unroll]] for (uint k = 0; k < 8; ++k) {
    float v[4];
    [[unroll]] for (uint r = 0; r < 4; ++r) {
      precise float vr = ((m[0][r] * p[k].x + m[1][r] * p[k].y) + m[2][r] * p[k].z) + m[3][r];
      v[r] = vr;
    }
    precise float w_lo = v[3] - e[3];
    precise float w_hi = v[3] + e[3];
    // At or behind the eye: not projected; nor where w leaves the range in which GLSL bounds the
    // division's error (2^-126 to 2^126). (The bounds below are then not used.)
    projected = projected && w_lo >= OCC_MIN_W && w_hi < OCC_MAX_W;
    precise float x0 = v[0] - e[0], x1 = v[0] + e[0], y0 = v[1] - e[1], y1 = v[1] + e[1], z0 = v[2] - e[2], z1 = v[2] + e[2];
    occ_widen(x_lo, x_hi, x0, x1, w_lo, w_hi);
    occ_widen(y_lo, y_hi, y0, y1, w_lo, w_hi);
    occ_widen(z_lo, z_hi, z0, z1, w_lo, w_hi);
  }
  // An object's bounds must be finite, a node's at most 2^120 in magnitude; compared on the bits
  // (a NaN's exceed both), as a device need not compare with NaN or infinity exactly.
  uint limit = scale == 1.0 ? 0x7f7fffffu : 0x7b800000u;
  projected = projected && (floatBitsToUint(x_lo) & 0x7fffffffu) <= limit &&
              (floatBitsToUint(x_hi) & 0x7fffffffu) <= limit && (floatBitsToUint(y_lo) & 0x7fffffffu) <= limit &&
              (floatBitsToUint(y_hi) & 0x7fffffffu) <= limit && (floatBitsToUint(z_lo) & 0x7fffffffu) <= limit &&
              (floatBitsToUint(z_hi) & 0x7fffffffu) <= limit;
  uint px0, px1, py0, py1;
  occ_pixel_range(x_lo, x_hi, occ_width, scale, px0, px1);
  occ_pixel_range(y_lo, y_hi, occ_height, scale, py0, py1);
  float depth_margin = OCC_DEPTH_MARGIN * scale;
  precise float nearest = occ_reversed != 0u ? z_hi + (depth_margin + abs(z_hi) * depth_margin)
                                             : z_lo - (depth_margin + abs(z_lo) * depth_margin);
  bool hidden = occ_hidden_at(projected, px0, px1, py0, py1, nearest, texels);
  if (OCC_REFINE_TEXELS > texels && scale == 1.0)  // (a volume, not a node: occlusion::occluded)
    hidden = hidden || occ_hidden_at(projected && !hidden, px0, px1, py0, py1, nearest, OCC_REFINE_TEXELS);
  return hidden;
}

// The corners of box [lo, hi] (exact) and its magnitude bound.
void occ_box_corners(vec3 lo, vec3 hi, out vec3 p[8], out vec3 magnitude) {
  [[unroll]] for (uint k = 0; k < 8; ++k)
    p[k] = vec3((k & 1u) != 0u ? hi.x : lo.x, (k & 2u) != 0u ? hi.y : lo.y, (k & 4u) != 0u ? hi.z : lo.z);
  magnitude = max(abs(lo), abs(hi));
}

// Whether a hierarchy node's box [lo, hi] is hidden (occlusion::node_footprint).
bool occ_node_occluded(vec3 lo, vec3 hi) {
  vec3 p[8];
  vec3 magnitude;
  occ_box_corners(lo, hi, p, magnitude);
  return occ_occluded(p, magnitude, OCC_NODE_MARGIN_SCALE, OCC_NODE_TEXELS);
}

// The corners c +- a0 +- a1 +- a2, summed in the order occlusion.cpp's box_corners sums them,
// and their magnitude bound.
void occ_corners(vec3 c, vec3 a0, vec3 a1, vec3 a2, out vec3 p[8], out vec3 magnitude) {
  [[unroll]] for (uint k = 0; k < 8; ++k) {
    precise vec3 q = ((c + ((k & 1u) != 0u ? a0 : -a0)) + ((k & 2u) != 0u ? a1 : -a1)) + ((k & 4u) != 0u ? a2 : -a2);
    p[k] = q;
  }
  precise vec3 m = ((abs(c) + abs(a0)) + abs(a1)) + abs(a2);
  magnitude = m;
}

// The corners of an OBB given as its GpuObb words (centre, then each unit axis with its half
// extent in w), from its half axes u_i * h_i.
void occ_obb_corners(vec3 c, vec4 u0, vec4 u1, vec4 u2, out vec3 p[8], out vec3 magnitude) {
  precise vec3 s0 = u0.xyz * u0.w, s1 = u1.xyz * u1.w, s2 = u2.xyz * u2.w;
  occ_corners(c, s0, s1, s2, p, magnitude);
}

// Whether the volume whose words start at occ_volume_word(first) is hidden: its corners as
// occlusion::footprint takes them (a sphere's by its box).
bool occ_volume_occluded(uint first) {
  vec3 p[8];
  vec3 magnitude;
  if (BV_KIND == BV_KIND_AABB) {
    occ_box_corners(occ_volume_word(first).xyz, occ_volume_word(first + 1u).xyz, p, magnitude);
  } else if (BV_KIND == BV_KIND_OBB) {
    occ_obb_corners(occ_volume_word(first).xyz, occ_volume_word(first + 1u), occ_volume_word(first + 2u),
                    occ_volume_word(first + 3u), p, magnitude);
  } else {
    vec4 s = occ_volume_word(first);
    float r = abs(s.w);
    occ_corners(s.xyz, vec3(r, 0.0, 0.0), vec3(0.0, r, 0.0), vec3(0.0, 0.0, r), p, magnitude);
  }
  return occ_occluded(p, magnitude, 1.0, OCC_TEXELS);
}

#endif
