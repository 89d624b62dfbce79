#version 460
// Flat frustum culling: one invocation per object and view; gl_GlobalInvocationID.y is the
// view. One dispatch covers all views (and a chunk of at most maxComputeWorkGroupCount[0]
// groups of objects). Writes each object's classification and counts visible / inside /
// intersecting objects. Then, by specialization:
// - ORDERED == 0: appends visible ids (and, with WRITE_DRAWS, draw commands) to the view's
//   lists in arrival order, one atomic per subgroup;
// - ORDERED == 1: writes only each workgroup's visible count; compact_scan.comp and
//   compact_scatter.comp then write the lists in object order.
//
// Bit-exact contract with host/cull/reference.cpp: every distance is computed as
// ((n.x*p.x + n.y*p.y) + n.z*p.z) + d, written out (not dot()) and marked `precise`, so no
// reassociation or fused multiply-add can change a result.
// Tests: p/n-vertex box test (Greene 1994; Assarsson & Moller 2000), the OBB test by
// projected radius r = sum |n.u_i| h_i (Ericson, Real-Time Collision Detection 5.2.3), the
// sphere test by signed distance.
#extension GL_GOOGLE_include_directive : require
#extension GL_KHR_shader_subgroup_basic : require
#extension GL_KHR_shader_subgroup_ballot : require
#extension GL_EXT_control_flow_attributes : require

#include "shared/cull_types.h"

layout(local_size_x_id = 1) in;                 // = FLAT_CULL_GROUP_SIZE, set by the host
layout(constant_id = 0) const uint BV_KIND = BV_KIND_AABB;
layout(constant_id = 2) const uint ORDERED = 0;      // 1: object-order compaction by later passes
layout(constant_id = 3) const uint WRITE_DRAWS = 0;  // 1: also write draw commands (arrival order)

layout(std430, set = 0, binding = BINDING_BOUNDS) readonly buffer Bounds { vec4 bounds[]; };
layout(std430, set = 0, binding = BINDING_CLASSES) writeonly buffer Classes { uint classes[]; };
layout(std430, set = 0, binding = BINDING_VISIBLE) writeonly buffer Visible { uint visible_ids[]; };
layout(std430, set = 0, binding = BINDING_COUNTERS) buffer Counters { ViewCounters counters[]; };
layout(std430, set = 0, binding = BINDING_VIEWS) readonly buffer Views { GpuFrustum views[]; };
layout(std430, set = 0, binding = BINDING_DRAW_TEMPLATES) readonly buffer DrawTemplates { DrawCommand templates[]; };
layout(std430, set = 0, binding = BINDING_DRAWS) writeonly buffer Draws { DrawCommand draws[]; };
layout(std430, set = 0, binding = BINDING_GROUP_COUNTS) writeonly buffer GroupCounts { uint group_counts[]; };

shared uint group_visible;  // ORDERED: this workgroup's visible and inside counts
shared uint group_inside;

layout(push_constant, std430) uniform Push { FlatCullParams params; };

uint view;             // this invocation's view (gl_GlobalInvocationID.y)
uint view_plane_count;
vec4 view_planes[MAX_FRUSTUM_PLANES];

float plane_distance(vec4 plane, vec3 p) {
  precise float s = plane.x * p.x + plane.y * p.y + plane.z * p.z + plane.w;
  return s;
}

uint classify_aabb(vec3 lo, vec3 hi) {
  // Branch-free over a fixed trip count (SIMD-friendly); the answer is the reference's:
  // OUTSIDE if any p-vertex is behind, else INTERSECTING if any n-vertex is behind.
  bool outside = false, intersecting = false;
  [[unroll]] for (uint k = 0; k < MAX_FRUSTUM_PLANES; ++k) {
    if (k < view_plane_count) {
      vec4 plane = view_planes[k];
      vec3 p_vertex = vec3(plane.x >= 0.0 ? hi.x : lo.x, plane.y >= 0.0 ? hi.y : lo.y, plane.z >= 0.0 ? hi.z : lo.z);
      vec3 n_vertex = vec3(plane.x >= 0.0 ? lo.x : hi.x, plane.y >= 0.0 ? lo.y : hi.y, plane.z >= 0.0 ? lo.z : hi.z);
      bool p_behind = plane_distance(plane, p_vertex) < 0.0;
      bool n_behind = plane_distance(plane, n_vertex) < 0.0;
      outside = outside || p_behind;
      intersecting = intersecting || n_behind;
    }
  }
  return outside ? CLASS_OUTSIDE : intersecting ? CLASS_INTERSECTING : CLASS_INSIDE;
}

uint classify_obb(vec3 center, vec4 u0, vec4 u1, vec4 u2) {
  bool outside = false, intersecting = false;
  [[unroll]] for (uint k = 0; k < MAX_FRUSTUM_PLANES; ++k) {
    if (k < view_plane_count) {
      vec4 plane = view_planes[k];
      float s = plane_distance(plane, center);
      precise float n_dot_u0 = plane.x * u0.x + plane.y * u0.y + plane.z * u0.z;
      precise float n_dot_u1 = plane.x * u1.x + plane.y * u1.y + plane.z * u1.z;
      precise float n_dot_u2 = plane.x * u2.x + plane.y * u2.y + plane.z * u2.z;
      precise float r = abs(n_dot_u0) * u0.w + abs(n_dot_u1) * u1.w + abs(n_dot_u2) * u2.w;
      bool all_behind = s < -r;
      bool some_behind = s < r;
      outside = outside || all_behind;
      intersecting = intersecting || some_behind;
    }
  }
  return outside ? CLASS_OUTSIDE : intersecting ? CLASS_INTERSECTING : CLASS_INSIDE;
}

uint classify_sphere(vec4 center_radius) {
  bool outside = false, intersecting = false;
  float radius = center_radius.w;
  [[unroll]] for (uint k = 0; k < MAX_FRUSTUM_PLANES; ++k) {
    if (k < view_plane_count) {
      float s = plane_distance(view_planes[k], center_radius.xyz);
      bool all_behind = s < -radius;
      bool some_behind = s < radius;
      outside = outside || all_behind;
      intersecting = intersecting || some_behind;
    }
  }
  return outside ? CLASS_OUTSIDE : intersecting ? CLASS_INTERSECTING : CLASS_INSIDE;
}

void main() {
  uint i = params.first_object + gl_GlobalInvocationID.x;
  view = gl_GlobalInvocationID.y;
  // No early return: the ordered path has workgroup barriers, which every invocation must reach.
  bool in_range = i < params.object_count && view < params.view_count;
  uint c = CLASS_OUTSIDE;
  if (in_range) {
    view_plane_count = min(views[view].plane_count, MAX_FRUSTUM_PLANES);
    [[unroll]] for (uint k = 0; k < MAX_FRUSTUM_PLANES; ++k) view_planes[k] = views[view].planes[k];
    if (BV_KIND == BV_KIND_AABB) {
      c = classify_aabb(bounds[AABB_VEC4S * i].xyz, bounds[AABB_VEC4S * i + 1].xyz);
    } else if (BV_KIND == BV_KIND_OBB) {
      uint b = OBB_VEC4S * i;
      c = classify_obb(bounds[b].xyz, bounds[b + 1], bounds[b + 2], bounds[b + 3]);
    } else {
      c = classify_sphere(bounds[SPHERE_VEC4S * i]);
    }
    classes[view * params.object_count + i] = c;
  }

  bool visible = c != CLASS_OUTSIDE;  // inactive invocations count as OUTSIDE
  uvec4 vis_ballot = subgroupBallot(visible);
  uint vis_total = subgroupBallotBitCount(vis_ballot);
  uint inside_total = subgroupBallotBitCount(subgroupBallot(c == CLASS_INSIDE));

  if (ORDERED != 0) {
    // Count per workgroup; one global atomic per workgroup and view.
    if (gl_LocalInvocationIndex == 0) {
      group_visible = 0;
      group_inside = 0;
    }
    barrier();
    if (subgroupElect()) {
      atomicAdd(group_visible, vis_total);
      atomicAdd(group_inside, inside_total);
    }
    barrier();
    if (gl_LocalInvocationIndex == 0) {
      uint groups = (params.object_count + gl_WorkGroupSize.x - 1) / gl_WorkGroupSize.x;
      uint g = params.first_object / gl_WorkGroupSize.x + gl_WorkGroupID.x;
      group_counts[view * groups + g] = group_visible;
      if (group_visible > 0) {
        atomicAdd(counters[view].visible_count, group_visible);
        atomicAdd(counters[view].inside_count, group_inside);
      }
    }
    return;
  }

  // Arrival-order compaction: one atomic per subgroup for the visible list, then each visible
  // invocation writes its id at its rank within the subgroup.
  uint base = 0;
  if (subgroupElect() && vis_total > 0) {
    base = atomicAdd(counters[view].visible_count, vis_total);
    atomicAdd(counters[view].inside_count, inside_total);
  }
  base = subgroupBroadcastFirst(base);
  uint slot = base + subgroupBallotExclusiveBitCount(vis_ballot);
  if (visible && slot < params.visible_capacity) {
    visible_ids[view * params.visible_capacity + slot] = i;
    if (WRITE_DRAWS != 0) {
      DrawCommand d = templates[i];
      d.object_id = i;
      draws[view * params.visible_capacity + slot] = d;
    }
  }
}
