#version 460
// Ordered compaction, pass 2 of 3: for each view (workgroup y), turns the per-workgroup
// visible counts written by cull_flat.comp (ORDERED = 1) into exclusive prefix sums in place,
// so each workgroup of the scatter pass knows where its visible objects start, and writes the
// view's visible and INSIDE totals into its counters (pass 1 counts per workgroup only). One
// workgroup per view; each invocation scans a contiguous run of counts. Integer sums:
// deterministic.
#extension GL_GOOGLE_include_directive : require

#include "cullpipe/gpu/cull_types.h"

layout(local_size_x_id = 1) in;  // the culling group size (the counts are per culling workgroup)
layout(constant_id = 4) const uint OBJECTS_PER_INVOCATION = 1;  // the culling pass's
#include "shared/ordered_runs.glsl"

layout(std430, set = 0, binding = BINDING_COUNTERS) buffer Counters { ViewCounters counters[]; };
// [view][group] visible counts, then [view][group] INSIDE counts (cull_flat.comp, ORDERED = 1).
layout(std430, set = 0, binding = BINDING_GROUP_COUNTS) buffer GroupCounts { uint group_counts[]; };
layout(push_constant, std430) uniform Push { FlatCullParams params; };

shared uint partial[MAX_CULL_GROUP_SIZE];
shared uint partial_inside[MAX_CULL_GROUP_SIZE];

void main() {
  uint view = gl_WorkGroupID.y;
  uint lanes = gl_WorkGroupSize.x;
  uint t = gl_LocalInvocationIndex;
  uint groups = run_count(params.object_count);  // the culling workgroups' runs
  uint per = (groups + lanes - 1) / lanes;
  uint begin = min(t * per, groups), end = min(begin + per, groups);
  uint base = view * groups, inside_base = (params.view_count + view) * groups;

  uint sum = 0, inside = 0;
  for (uint g = begin; g < end; ++g) {
    sum += group_counts[base + g];
    inside += group_counts[inside_base + g];
  }
  partial[t] = sum;
  partial_inside[t] = inside;
  barrier();
  if (t == 0) {
    uint running = 0, inside_total = 0;
    for (uint k = 0; k < lanes; ++k) {
      uint v = partial[k];
      partial[k] = running;
      running += v;
      inside_total += partial_inside[k];
    }
    counters[view].visible_count = running;
    counters[view].inside_count = inside_total;
  }
  barrier();
  uint running = partial[t];
  for (uint g = begin; g < end; ++g) {
    uint v = group_counts[base + g];
    group_counts[base + g] = running;
    running += v;
  }
}
