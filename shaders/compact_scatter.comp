#version 460
// Ordered compaction, pass 3 of 3: each visible object's slot is its workgroup's offset (from
// compact_scan.comp) plus its rank among the visible invocations of its workgroup, in
// invocation order (a shared bitmask, independent of how invocations map to subgroups).
// The visible ids, and with WRITE_DRAWS the draw commands, land in object order; slots at or
// past visible_capacity are dropped (the counters, from pass 2, report the overflow).
#extension GL_GOOGLE_include_directive : require

#include "shared/cull_types.h"

layout(local_size_x_id = 1) in;
layout(constant_id = 3) const uint WRITE_DRAWS = 0;

layout(std430, set = 0, binding = BINDING_CLASSES) readonly buffer Classes { uint classes[]; };
layout(std430, set = 0, binding = BINDING_VISIBLE) writeonly buffer Visible { uint visible_ids[]; };
layout(std430, set = 0, binding = BINDING_DRAW_TEMPLATES) readonly buffer DrawTemplates { DrawCommand templates[]; };
layout(std430, set = 0, binding = BINDING_DRAWS) writeonly buffer Draws { DrawCommand draws[]; };
layout(std430, set = 0, binding = BINDING_GROUP_COUNTS) readonly buffer GroupCounts { uint group_offsets[]; };
layout(push_constant, std430) uniform Push { FlatCullParams params; };

// Bit t of the workgroup: invocation t's object is visible.
shared uint flags[(MAX_CULL_GROUP_SIZE + 31) / 32];

void main() {
  uint i = params.first_object + gl_GlobalInvocationID.x;
  uint view = gl_WorkGroupID.y;  // = gl_GlobalInvocationID.y (local size 1 in y), visibly uniform
  uint t = gl_LocalInvocationIndex;
  bool visible = i < params.object_count && view < params.view_count &&
                 classes[view * params.object_count + i] != CLASS_OUTSIDE;

  // The rank among the workgroup's visible objects: the set bits below t. Two workgroup
  // barriers (a scan over the invocations took 17; on lavapipe each barrier suspends and
  // resumes every subgroup of the workgroup).
  if (t < (gl_WorkGroupSize.x + 31u) / 32u) flags[t] = 0u;
  barrier();
  if (visible) atomicOr(flags[t / 32u], 1u << (t % 32u));
  barrier();
  if (!visible) return;
  uint rank = bitCount(flags[t / 32u] & ((1u << (t % 32u)) - 1u));
  for (uint w = 0; w < t / 32u; ++w) rank += bitCount(flags[w]);

  uint groups = (params.object_count + gl_WorkGroupSize.x - 1) / gl_WorkGroupSize.x;
  uint g = params.first_object / gl_WorkGroupSize.x + gl_WorkGroupID.x;
  uint slot = group_offsets[view * groups + g] + rank;
  if (slot < params.visible_capacity) {
    visible_ids[view * params.visible_capacity + slot] = params.id_base + i;
    if (WRITE_DRAWS != 0) {
      DrawCommand d = templates[i];
      d.object_id = params.id_base + i;
      draws[view * params.visible_capacity + slot] = d;
    }
  }
}
