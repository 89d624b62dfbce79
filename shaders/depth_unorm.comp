#version 460
// Level 0 of a depth pyramid from unsigned normalised depth (D16 or D24, copied in by the host as
// integers): each texel the float occlusion::unorm_depth_float gives for its stored value, the
// farthest depth a fragment it lets through can have, rounded outward, by the same float
// operations (docs/numerics.md, Depth pyramids).
#extension GL_GOOGLE_include_directive : require

#include "cullpipe/gpu/cull_types.h"

layout(local_size_x = 64) in;
layout(std430, set = 0, binding = 0) writeonly buffer Texels { float texels[]; };
layout(std430, set = 0, binding = 1) readonly buffer Raw { uint raw[]; };
layout(push_constant, std430) uniform Push { PyramidUnormParams params; };

void main() {
  uint i = gl_GlobalInvocationID.x;
  if (i >= params.count) return;
  uint n = (1u << params.bits) - 1u;
  // 16-bit values two to a word (the first in the low half), 24-bit ones one to a word.
  uint q = params.bits == 16u ? (raw[i >> 1u] >> (16u * (i & 1u))) & n : raw[i] & n;
  float step = uintBitsToFloat(params.step_bits);
  float f;
  if (params.reversed_z == 0u) {
    precise float p = float(q + 1u) * step;
    f = uintBitsToFloat(floatBitsToUint(p) + 3u);
  } else if (q == 0u) {
    f = -uintBitsToFloat(params.step_bits + 3u);
  } else if (q == 1u) {
    f = 0.0;
  } else {
    precise float p = float(q - 1u) * step;
    f = uintBitsToFloat(floatBitsToUint(p) - 3u);
  }
  texels[i] = f;
}
