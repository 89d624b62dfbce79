// cone.glsl: the back-face cone test, the same float operations in the same order as
// facing_away() in src/cullpipe/geom/cone.cpp, every product and sum `precise`, the finiteness
// decided on the bits. Proof that it culls only clusters whose every triangle faces away:
// docs/numerics.md, Back-face cones.
#ifndef CULLPIPE_SHADERS_SHARED_CONE_GLSL
#define CULLPIPE_SHADERS_SHARED_CONE_GLSL

const float CONE_EYE_MARGIN = 1.0 / 131072.0;        // 2^-17
const float CONE_COORDINATE_MARGIN = 1.0 / 524288.0;   // 2^-19
const float CONE_SQUARE_MARGIN = 1.0 + 1.0 / 65536.0;  // 1 + 2^-16
const float CONE_TINY = 7.88860905221011805411728565283e-31;  // 2^-100 (exactly, as a float)

bool cone_finite_bits(float x) { return (floatBitsToUint(x) & 0x7f800000u) != 0x7f800000u; }

// Whether the cluster whose cone is (apex, cutoff, axis) faces away from `eye` (world space),
// under the instance whose inverse rows are `inverse` and translation magnitudes `translation`.
bool cone_facing_away(vec3 apex, float cutoff, vec3 axis, vec4 inverse[3], vec3 translation, vec3 eye) {
  if (!(cutoff < 1.0)) return false;
  vec3 local, magnitude;
  [[unroll]] for (int i = 0; i < 3; ++i) {
    vec4 row = inverse[i];
    precise float x = row.x * eye.x, y = row.y * eye.y, z = row.z * eye.z;
    precise float l = ((x + y) + z) + row.w;
    precise float m = (((abs(x) + abs(y)) + abs(z)) + abs(row.w)) + translation[i];
    local[i] = l;
    magnitude[i] = m;
  }
  precise float d0 = apex.x - local.x, d1 = apex.y - local.y, d2 = apex.z - local.z;
  precise float along = (d0 * axis.x + d1 * axis.y) + d2 * axis.z;
  precise float squared = (d0 * d0 + d1 * d1) + d2 * d2;
  precise float coordinates = ((abs(apex.x) + abs(apex.y)) + abs(apex.z)) + ((abs(local.x) + abs(local.y)) + abs(local.z));
  precise float margin =
      (((magnitude.x + magnitude.y) + magnitude.z) * CONE_EYE_MARGIN + coordinates * CONE_COORDINATE_MARGIN) + CONE_TINY;
  precise float x = along - margin;
  precise float x2 = x * x;
  precise float bound = (((cutoff * cutoff) * squared) * CONE_SQUARE_MARGIN) + CONE_TINY;
  return x > 0.0 && cone_finite_bits(margin) && cone_finite_bits(squared) && cone_finite_bits(x2) && x2 >= bound;
}

#endif
