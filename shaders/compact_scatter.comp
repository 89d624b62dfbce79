#version 460
// Ordered compaction, pass 3 of 3: each visible object's slot is its workgroup's offset (from
// compact_scan.comp) plus its rank among the visible objects of the workgroup's run, in object
// order (a shared bitmask, independent of how invocations map to subgroups). The objects are
// the culling pass's: object j of an invocation at its block + j * group size.
// The visible ids, and with WRITE_DRAWS the draw commands, land in object order; slots at or
// past visible_capacity are dropped (the counters, from pass 2, report the overflow).
#extension GL_GOOGLE_include_directive : require
#extension GL_EXT_control_flow_attributes : require

#include "cullpipe/gpu/cull_types.h"

layout(local_size_x_id = 1) in;
layout(constant_id = 3) const uint WRITE_DRAWS = 0;
layout(constant_id = 4) const uint OBJECTS_PER_INVOCATION = 1;  // the culling pass's
#include "shared/ordered_runs.glsl"

layout(std430, set = 0, binding = BINDING_CLASSES) readonly buffer Classes { uint classes[]; };
layout(std430, set = 0, binding = BINDING_VISIBLE) writeonly buffer Visible { uint visible_ids[]; };
layout(std430, set = 0, binding = BINDING_DRAW_TEMPLATES) readonly buffer DrawTemplates { DrawCommand templates[]; };
layout(std430, set = 0, binding = BINDING_DRAWS) writeonly buffer Draws { DrawCommand draws[]; };
layout(std430, set = 0, binding = BINDING_GROUP_COUNTS) readonly buffer GroupCounts { uint group_offsets[]; };
layout(push_constant, std430) uniform Push { FlatCullParams params; };

// INSIDE or INTERSECTING: listed (OUTSIDE and OCCLUDED are not).
bool is_kept(uint c) { return c == CLASS_INSIDE || c == CLASS_INTERSECTING; }

// Bit p of the workgroup's run of objects: object group_first + p is visible; then, per word,
// the visible objects of the words before it.
shared uint flags[MAX_CULL_GROUP_SIZE * MAX_OBJECTS_PER_INVOCATION / 32];
shared uint word_base[MAX_CULL_GROUP_SIZE * MAX_OBJECTS_PER_INVOCATION / 32];

void main() {
  uint view = gl_WorkGroupID.y;  // = gl_GlobalInvocationID.y (local size 1 in y), visibly uniform
  uint t = gl_LocalInvocationIndex;
  uint group_size = gl_WorkGroupSize.x;
  uint run = run_objects();  // as the culling pass's
  uint group_first = this_run_first_object(params.first_object);
  bool view_ok = view < params.view_count;

  // The rank of each visible object among the workgroup's: the set bits before it. Three
  // workgroup barriers per run of objects (a scan over the invocations would take 17 per group
  // size; on lavapipe each barrier suspends and resumes every subgroup of the workgroup).
  uint words = (run + 31u) / 32u;
  for (uint w = t; w < words; w += group_size) flags[w] = 0u;
  barrier();
  uint visible_bits = 0u;
  [[unroll]] for (uint j = 0; j < OBJECTS_PER_INVOCATION; ++j) {
    uint p = j * group_size + t, i = group_first + p;
    if (view_ok && i < params.object_count && is_kept(classes[view * params.object_count + i])) {
      visible_bits |= 1u << j;
      atomicOr(flags[p / 32u], 1u << (p % 32u));
    }
  }
  barrier();
  for (uint w = t; w < words; w += group_size) {
    uint before = 0u;
    for (uint k = 0; k < w; ++k) before += bitCount(flags[k]);
    word_base[w] = before;
  }
  barrier();

  uint offset = view_ok ? group_offsets[view * run_count(params.object_count) + this_run(params.first_object)] : 0u;
  [[unroll]] for (uint j = 0; j < OBJECTS_PER_INVOCATION; ++j) {
    uint p = j * group_size + t, i = group_first + p;
    uint slot = offset + word_base[p / 32u] + bitCount(flags[p / 32u] & ((1u << (p % 32u)) - 1u));
    if ((visible_bits & 1u << j) != 0u && slot < params.visible_capacity) {
      visible_ids[view * params.visible_capacity + slot] = params.id_base + i;
      if (WRITE_DRAWS != 0) {
        DrawCommand d = templates[i];
        d.object_id = params.id_base + i;
        draws[view * params.visible_capacity + slot] = d;
      }
    }
  }
}
