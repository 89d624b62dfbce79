// classify.glsl: the plane tests of every culling shader, on the planes of the invocation's
// view selected by `mask` (bit k = plane k; the flat pass passes every bit). Included after
// the includer declares `uint view_plane_count` and `vec4 view_planes[MAX_FRUSTUM_PLANES]`.
//
// Bit-exact contract with src/cullpipe/cull/reference.cpp and src/cullpipe/bvh (classify_masked,
// classify_object): every distance is ((n.x*p.x + n.y*p.y) + n.z*p.z) + d, written out (not
// dot()) and marked `precise`, so no reassociation or fused multiply-add can change a result
// (docs/numerics.md, GPU and CPU agreement).
// Each test is branch-free over a fixed trip count (SIMD-friendly); the answer is the
// reference's: OUTSIDE if the volume is wholly behind any tested plane, else INTERSECTING if it
// is partly behind any, else INSIDE.
// Tests: p/n-vertex box test (Greene 1994; Assarsson & Moller 2000), the OBB test by projected
// radius r = sum |n.u_i| h_i (Ericson, Real-Time Collision Detection 5.2.3), the sphere test by
// signed distance.
#ifndef CULLPIPE_SHADERS_SHARED_CLASSIFY_GLSL
#define CULLPIPE_SHADERS_SHARED_CLASSIFY_GLSL

const uint ALL_PLANES = (1u << MAX_FRUSTUM_PLANES) - 1u;

float plane_distance(vec4 plane, vec3 p) {
  precise float s = plane.x * p.x + plane.y * p.y + plane.z * p.z + plane.w;
  return s;
}

bool plane_tested(uint k, uint mask) { return k < view_plane_count && (mask & (1u << k)) != 0u; }

// Whether x is finite, decided on its bits (without SignedZeroInfNanPreserve a comparison with
// a NaN need not be false on every device).
bool finite_bits(float x) { return (floatBitsToUint(x) & 0x7f800000u) != 0x7f800000u; }

// The p/n-vertex test; `straddled` receives the tested planes whose n-vertex is behind
// (meaningful unless OUTSIDE).
uint classify_aabb(vec3 lo, vec3 hi, uint mask, out uint straddled) {
  bool outside = false;
  straddled = 0u;
  [[unroll]] for (uint k = 0; k < MAX_FRUSTUM_PLANES; ++k) {
    vec4 plane = view_planes[k];
    vec3 p_vertex = vec3(plane.x >= 0.0 ? hi.x : lo.x, plane.y >= 0.0 ? hi.y : lo.y, plane.z >= 0.0 ? hi.z : lo.z);
    vec3 n_vertex = vec3(plane.x >= 0.0 ? lo.x : hi.x, plane.y >= 0.0 ? lo.y : hi.y, plane.z >= 0.0 ? lo.z : hi.z);
    bool tested = plane_tested(k, mask);
    outside = outside || (tested && plane_distance(plane, p_vertex) < 0.0);
    if (tested && plane_distance(plane, n_vertex) < 0.0) straddled |= 1u << k;
  }
  return outside ? CLASS_OUTSIDE : straddled != 0u ? CLASS_INTERSECTING : CLASS_INSIDE;
}

uint classify_obb(vec3 center, vec4 u0, vec4 u1, vec4 u2, uint mask) {
  bool outside = false, intersecting = false;
  [[unroll]] for (uint k = 0; k < MAX_FRUSTUM_PLANES; ++k) {
    vec4 plane = view_planes[k];
    bool tested = plane_tested(k, mask);
    float s = plane_distance(plane, center);
    precise float n_dot_u0 = plane.x * u0.x + plane.y * u0.y + plane.z * u0.z;
    precise float n_dot_u1 = plane.x * u1.x + plane.y * u1.y + plane.z * u1.z;
    precise float n_dot_u2 = plane.x * u2.x + plane.y * u2.y + plane.z * u2.z;
    precise float r = abs(n_dot_u0) * u0.w + abs(n_dot_u1) * u1.w + abs(n_dot_u2) * u2.w;
    outside = outside || (tested && s < -r);
    intersecting = intersecting || (tested && s < r);
  }
  return outside ? CLASS_OUTSIDE : intersecting ? CLASS_INTERSECTING : CLASS_INSIDE;
}

uint classify_sphere(vec4 center_radius, uint mask) {
  bool outside = false, intersecting = false;
  float radius = center_radius.w;
  [[unroll]] for (uint k = 0; k < MAX_FRUSTUM_PLANES; ++k) {
    bool tested = plane_tested(k, mask);
    float s = plane_distance(view_planes[k], center_radius.xyz);
    outside = outside || (tested && s < -radius);
    intersecting = intersecting || (tested && s < radius);
  }
  return outside ? CLASS_OUTSIDE : intersecting ? CLASS_INTERSECTING : CLASS_INSIDE;
}

#endif
