// occlusion.glsl: the occlusion test of the flat pass, the same float operations in the same
// order as host/cull/occlusion.cpp (the reference), every sum and product `precise`. A volume's
// footprint from its eight corners (a pixel rectangle and a bound on its nearest fragment depth),
// read against the depth pyramid at the finest level spanning at most texels_per_axis texels.
// Proof that it is conservative: docs/numerics.md, Occlusion footprints.
// Included after the includer declares `float pyramid[]` (BINDING_PYRAMID), `mat4 occ_view_proj`,
// `uint occ_width, occ_height, occ_reversed, occ_texels, occ_level_count` and
// `uvec4 occ_levels[PYRAMID_MAX_LEVELS]` (x = offset, y = width, z = height).
#ifndef CULLPIPE_SHADERS_SHARED_OCCLUSION_GLSL
#define CULLPIPE_SHADERS_SHARED_OCCLUSION_GLSL

const float OCC_CLIP_ERROR = 1.0 / 262144.0;         // 2^-18
const float OCC_TINY = 7.88860905221011805411728565283e-31;  // 2^-100 (exactly, as a float)
const float OCC_PIXEL_MARGIN = 0.0625;
const float OCC_PIXEL_RELATIVE = 1.0 / 1048576.0;  // 2^-20
const float OCC_MIN_W = 1.17549435082228750796873653722e-38;  // 2^-126
const float OCC_MAX_W = 8.50705917302346158658436518579e37;   // 2^126
const float OCC_DEPTH_MARGIN = 1.0 / 1048576.0;    // 2^-20

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
void occ_pixel_range(float lo, float hi, uint size, out uint first, out uint last) {
  precise float half_size = 0.5 * float(size);
  precise float from = (lo + 1.0) * half_size;
  precise float to = (hi + 1.0) * half_size;
  precise float a = floor(from - (OCC_PIXEL_MARGIN + abs(from) * OCC_PIXEL_RELATIVE));
  precise float b = floor(to + (OCC_PIXEL_MARGIN + abs(to) * OCC_PIXEL_RELATIVE));
  float top = float(size - 1u);
  a = a > 0.0 ? a : 0.0;
  b = b > 0.0 ? b : 0.0;
  first = uint(top < a ? top : a);
  last = uint(top < b ? top : b);
}

// Whether the volume with corners p[8], every point's coordinates bounded by `magnitude`, is
// hidden: every pyramid texel over its footprint strictly nearer than its nearest fragment.
bool occ_occluded(vec3 p[8], vec3 magnitude) {
  mat4 m = occ_view_proj;
  float e[4];
  [[unroll]] for (uint r = 0; r < 4; ++r) {
    precise float a = ((abs(m[0][r]) * magnitude.x + abs(m[1][r]) * magnitude.y) + abs(m[2][r]) * magnitude.z) + abs(m[3][r]);
    precise float er = a * OCC_CLIP_ERROR + OCC_TINY;
    e[r] = er;
  }
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
    // division's error (2^-126 to 2^126).
    if (!(w_lo >= OCC_MIN_W) || !(w_hi < OCC_MAX_W)) return false;
    precise float x0 = v[0] - e[0], x1 = v[0] + e[0], y0 = v[1] - e[1], y1 = v[1] + e[1], z0 = v[2] - e[2], z1 = v[2] + e[2];
    occ_widen(x_lo, x_hi, x0, x1, w_lo, w_hi);
    occ_widen(y_lo, y_hi, y0, y1, w_lo, w_hi);
    occ_widen(z_lo, z_hi, z0, z1, w_lo, w_hi);
  }
  if (!finite_bits(x_lo) || !finite_bits(x_hi) || !finite_bits(y_lo) || !finite_bits(y_hi) || !finite_bits(z_lo) ||
      !finite_bits(z_hi))
    return false;
  uint px0, px1, py0, py1;
  occ_pixel_range(x_lo, x_hi, occ_width, px0, px1);
  occ_pixel_range(y_lo, y_hi, occ_height, py0, py1);
  precise float nearest = occ_reversed != 0u ? z_hi + (OCC_DEPTH_MARGIN + abs(z_hi) * OCC_DEPTH_MARGIN)
                                             : z_lo - (OCC_DEPTH_MARGIN + abs(z_lo) * OCC_DEPTH_MARGIN);
  // The finest level at which the rectangle spans at most occ_texels texels per axis.
  uint k = 0;
  while (k + 1u < occ_level_count && ((px1 >> k) - (px0 >> k) >= occ_texels || (py1 >> k) - (py0 >> k) >= occ_texels)) ++k;
  uvec4 level = occ_levels[k];
  uint tx0 = min(px0 >> k, level.y - 1u), tx1 = min(px1 >> k, level.y - 1u);
  uint ty0 = min(py0 >> k, level.z - 1u), ty1 = min(py1 >> k, level.z - 1u);
  bool hidden = true;
  for (uint y = ty0; y <= ty1; ++y) {
    for (uint x = tx0; x <= tx1; ++x) {
      float farthest = pyramid[level.x + y * level.y + x];
      hidden = hidden && (occ_reversed != 0u ? nearest < farthest : nearest > farthest);
    }
  }
  return hidden;
}

#endif
