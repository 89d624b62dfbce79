#version 460
// One level of a depth pyramid from the level below it: each texel the farthest depth of the
// texels it covers, 2 x 2, and at a level's last column or row also the one an odd size leaves
// over (up to 3 x 3). Level 0 is the depth image, copied in by the host (exact bits). The
// texels are compared in row-major order and replaced only by a strictly farther one, as
// occlusion::build_depth_pyramid does, so both give the same bits (docs/numerics.md, Depth
// pyramids).
#extension GL_GOOGLE_include_directive : require

#include "shared/cull_types.h"

layout(local_size_x = PYRAMID_GROUP_SIDE, local_size_y = PYRAMID_GROUP_SIDE) in;
layout(std430, set = 0, binding = 0) buffer Texels { float texels[]; };
layout(push_constant, std430) uniform Push { PyramidReduceParams params; };

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
  float farthest = texels[params.source_offset + y0 * params.source_width + x0];
  for (uint y = y0; y <= y1; ++y) {
    for (uint x = x0; x <= x1; ++x) {
      float d = texels[params.source_offset + y * params.source_width + x];
      if (params.reversed_z != 0u ? d < farthest : d > farthest) farthest = d;
    }
  }
  texels[params.offset + t.y * params.width + t.x] = farthest;
}
