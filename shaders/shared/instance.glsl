// instance.glsl: a mesh's local volume placed in the world by an instance's transform.
// Bit-exact contract with src/cullpipe/geom/instance.cpp (instance_volume): the same float
// operations in the same order, each marked `precise` (no fused multiply-add, no reassociation),
// selects written as the C++ writes them (b < a ? b : a), and overflow decided on the bits.
// Proof that the results enclose the exact placement: docs/numerics.md, Instance volumes.
#ifndef CULLPIPE_SHADERS_SHARED_INSTANCE_GLSL
#define CULLPIPE_SHADERS_SHARED_INSTANCE_GLSL

const float INSTANCE_RELATIVE_WIDENING = 1.0 / 1048576.0;  // 2^-20
float instance_absolute_widening() { return uintBitsToFloat(0x03800000u); }  // 2^-120

bool instance_finite_bits(float x) { return (floatBitsToUint(x) & 0x7f800000u) != 0x7f800000u; }
float instance_min(float a, float b) { return b < a ? b : a; }
float instance_max(float a, float b) { return a < b ? b : a; }

// The world box of local box [lmin, lmax] under `rows`: per axis Arvo's least and greatest
// values, widened by 2^-20 of the axis's sum of magnitudes plus 2^-120; (-inf, +inf) where the
// magnitudes overflow.
void instance_aabb(vec4 rows[3], vec3 lmin, vec3 lmax, out vec3 wmin, out vec3 wmax) {
  float inf = uintBitsToFloat(0x7f800000u);
  for (int i = 0; i < 3; ++i) {
    vec4 row = rows[i];
    precise float a0 = row.x * lmin.x, b0 = row.x * lmax.x;
    precise float a1 = row.y * lmin.y, b1 = row.y * lmax.y;
    precise float a2 = row.z * lmin.z, b2 = row.z * lmax.z;
    precise float low = ((instance_min(a0, b0) + instance_min(a1, b1)) + instance_min(a2, b2)) + row.w;
    precise float high = ((instance_max(a0, b0) + instance_max(a1, b1)) + instance_max(a2, b2)) + row.w;
    precise float sum = ((instance_max(abs(a0), abs(b0)) + instance_max(abs(a1), abs(b1))) +
                         instance_max(abs(a2), abs(b2))) + abs(row.w);
    precise float widening = sum * INSTANCE_RELATIVE_WIDENING + instance_absolute_widening();
    precise float lo = low - widening;
    precise float hi = high + widening;
    bool finite = instance_finite_bits(sum);
    wmin[i] = finite ? lo : -inf;
    wmax[i] = finite ? hi : inf;
  }
}

// The world sphere of local sphere (centre, radius) under `rows`, with scale = max_scale.
vec4 instance_sphere(vec4 rows[3], vec3 centre, float radius, float scale) {
  vec3 c;
  float magnitude[3];
  for (int i = 0; i < 3; ++i) {
    vec4 row = rows[i];
    precise float x = row.x * centre.x, y = row.y * centre.y, z = row.z * centre.z;
    precise float ci = ((x + y) + z) + row.w;
    precise float mi = ((abs(x) + abs(y)) + abs(z)) + abs(row.w);
    c[i] = ci;
    magnitude[i] = mi;
  }
  precise float scaled = radius * scale;
  precise float widening = (scaled + ((magnitude[0] + magnitude[1]) + magnitude[2])) * INSTANCE_RELATIVE_WIDENING;
  precise float r = (scaled + widening) + instance_absolute_widening();
  return instance_finite_bits(r) ? vec4(c, r) : vec4(0.0, 0.0, 0.0, uintBitsToFloat(0x7f800000u));
}

#endif
