#version 460
// The pairs of the instances the object pass kept, listed in pair order, so that the cluster
// pass runs over them alone. One invocation per instance, in two stages (specialization
// constant 9) with compact_scan.comp between them: STAGE 0 adds each workgroup's kept instances'
// cluster counts into its group count; the scan turns those into offsets and writes the total
// (the list's header); STAGE 1 writes each kept instance's pairs at its offset (its workgroup's
// plus the counts before it in the workgroup), and the workgroup counts of the passes that
// follow (a VkDispatchIndirectCommand in the header). With OBJECT_CLASSES == 0 every instance is
// kept.
#extension GL_GOOGLE_include_directive : require
#extension GL_KHR_shader_subgroup_basic : require
#extension GL_KHR_shader_subgroup_arithmetic : require

#include "cullpipe/gpu/cull_types.h"

layout(local_size_x_id = 1) in;
layout(constant_id = 4) const uint OBJECTS_PER_INVOCATION = 1;  // one instance per invocation
layout(constant_id = 8) const uint OBJECT_CLASSES = 0;
layout(constant_id = 9) const uint STAGE = 0;
#include "shared/ordered_runs.glsl"

layout(set = 0, binding = BINDING_CENTRES) uniform usamplerBuffer instances;  // CLUSTER_INSTANCE_TEXELS each
layout(std430, set = 0, binding = BINDING_GROUP_COUNTS) buffer GroupCounts { uint group_counts[]; };
layout(std430, set = 0, binding = CLUSTER_BINDING_OBJECT_CLASSES) readonly buffer ObjectClasses { uint object_classes[]; };
layout(std430, set = 0, binding = CLUSTER_BINDING_ACTIVE) buffer Listed { uint listed_pairs[]; };
// pair_count = the instances, first_pair = the first instance of this dispatch.
layout(push_constant, std430) uniform Push { ClusterCullParams params; };

// Stage 1: the counts of the workgroup's instances, scanned in place (Hillis and Steele: log2 of
// the group size steps); a subgroup scan would not do, as invocations need not map to
// subgroups in order.
shared uint scan[2][MAX_CULL_GROUP_SIZE];

void main() {
  uint t = gl_LocalInvocationIndex;
  uint i = this_run_first_object(params.first_pair) + t;
  uint count = 0u, first = 0u;
  if (i < params.pair_count) {
    uvec4 info = texelFetch(instances, int(CLUSTER_INSTANCE_TEXELS * i + CLUSTER_INSTANCE_TEXELS - 1u));
    bool kept = true;
    if (OBJECT_CLASSES != 0u) kept = object_classes[i] == CLASS_INSIDE || object_classes[i] == CLASS_INTERSECTING;
    count = kept ? info.y : 0u;
    first = info.x;
  }
  if (STAGE == 0u) {
    uint total = subgroupAdd(count);
    if (subgroupElect() && total > 0u) atomicAdd(group_counts[this_run(params.first_pair)], total);
    return;
  }
  uint from = 0u;
  scan[0][t] = count;
  barrier();
  for (uint step = 1u; step < gl_WorkGroupSize.x; step *= 2u) {
    scan[1u - from][t] = scan[from][t] + (t >= step ? scan[from][t - step] : 0u);
    from = 1u - from;
    barrier();
  }
  uint at = group_counts[this_run(params.first_pair)] + scan[from][t] - count;  // exclusive
  for (uint j = 0u; j < count; ++j) listed_pairs[CLUSTER_ACTIVE_HEADER + at + j] = first + j;
  // The culling and draw passes' workgroups, for their indirect dispatch: as many as the list
  // needs (the scan wrote its length in the header).
  if (gl_GlobalInvocationID.x == 0u) {
    listed_pairs[CLUSTER_ACTIVE_DISPATCH] = (listed_pairs[0] + gl_WorkGroupSize.x - 1u) / gl_WorkGroupSize.x;
    listed_pairs[CLUSTER_ACTIVE_DISPATCH + 1u] = 1u;
    listed_pairs[CLUSTER_ACTIVE_DISPATCH + 2u] = 1u;
  }
}
