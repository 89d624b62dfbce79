#version 460
// One level of a depth pyramid from the level below it: each texel the farthest depth of the
// texels it covers, 2 x 2, and at a level's last column or row also the one an odd size leaves
// over (up to 3 x 3). Level 0 is the depth image, copied in by the host (exact bits). The
// texels are compared in row-major order and replaced only by a strictly farther one, as
// occlusion::build_depth_pyramid does, so both give the same bits (docs/numerics.md, Depth
// pyramids).
#extension GL_GOOGLE_include_directive : require
#extension GL_EXT_control_flow_attributes : require

#include "cullpipe/gpu/cull_types.h"

layout(local_size_x = PYRAMID_GROUP_SIDE, local_size_y = PYRAMID_GROUP_SIDE) in;
layout(std430, set = 0, binding = 0) writeonly buffer Texels { float texels[]; };
// The same buffer read as integer texels of four floats (exact bits): on lavapipe a texel fetch
// gathers the lanes' loads, where a storage-buffer load inserts each lane's word through the
// stack.
layout(set = 0, binding = 1) uniform usamplerBuffer source_texels;
layout(push_constant, std430) uniform Push { PyramidReduceParams params; };

// From the bits: without SignedZeroInfNanPreserve a device need not keep isnan() exact.
bool is_nan(float x) { return (floatBitsToUint(x) & 0x7fffffffu) > 0x7f800000u; }

float source_at(uint i) {
  uvec4 t = texelFetch(source_texels, int(i >> 2u));
  uint c = i & 3u;
  return uintBitsToFloat(c == 0u ? t.x : c == 1u ? t.y : c == 2u ? t.z : t.w);
}

// The source range [first, last] of texel t of a level of `size` texels over `source` texels.
void source_range(uint t, uint size, uint source, out uint first, out uint last) {
  first = source > 1u ? 2u * t : 0u;
  last = t + 1u == size ? source - 1u : 2u * t + 1u;
}

void main() {
  uvec2 t = gl_GlobalInvocationID.xy;
  if (t.x >= params.width || t.y >= params.height) return;
  uint x0, x1, y0, y1;
  source_range(t.x, params.width, params.source_width, x0, x1);
  source_range(t.y, params.height, params.source_height, y0, y1);
  // At most 3 x 3 texels (a last column or row takes the one an odd size leaves over), read
  // unrolled in row-major order.
  uint row = params.source_offset + y0 * params.source_width + x0;
  float farthest = source_at(row);
  [[unroll]] for (uint dy = 0u; dy < 3u; ++dy) {
    [[unroll]] for (uint dx = 0u; dx < 3u; ++dx) {
      if (x0 + dx <= x1 && y0 + dy <= y1) {
        float d = source_at(row + dy * params.source_width + dx);
        // A NaN wins and stays: it occludes nothing, nor may any texel above it.
        if (!is_nan(farthest) && (is_nan(d) || (params.reversed_z != 0u ? d < farthest : d > farthest))) farthest = d;
      }
    }
  }
  texels[params.offset + t.y * params.width + t.x] = farthest;
}
