#version 460
// Cluster culling: one invocation per listed (instance, cluster) pair, the pairs of the
// instances the object pass kept (cluster_expand.comp; the others' classes are filled with
// CLUSTER_OBJECT_CULLED before). A listed pair is culled when the cluster's box placed by the
// instance's transform (or its placed OBB, where it has one) is outside the frustum, when every
// triangle of the cluster faces away from the eye (its back-face cone, shared/cone.glsl), or
// when the placed box (or OBB) is hidden behind the depth pyramid (OCCLUSION): the first test
// that culls names its class (CLUSTER_*), as
// clusters::classify in src/cullpipe/cull/clusters.cpp decides it, bit for bit. Each pair's
// class and its workgroup's count of draws are written as the ordered flat pass writes its
// classes and counts; compact_scan.comp turns the counts into offsets and cluster_scatter.comp
// writes the draws in pair order, a run of drawn clusters whose index ranges follow on from
// each other in one draw.
#extension GL_GOOGLE_include_directive : require
#extension GL_KHR_shader_subgroup_basic : require
#extension GL_KHR_shader_subgroup_arithmetic : require
#extension GL_EXT_control_flow_attributes : require

#include "cullpipe/gpu/cull_types.h"

layout(local_size_x_id = 1) in;  // = FLAT_CULL_GROUP_SIZE
layout(constant_id = 4) const uint OBJECTS_PER_INVOCATION = 1;  // one pair per invocation (ordered_runs.glsl)
layout(constant_id = 6) const uint OCCLUSION = 0;       // 1: test the kept pairs against the pyramid
const uint BV_KIND = BV_KIND_AABB;

layout(set = 0, binding = BINDING_BOUNDS) uniform usamplerBuffer clusters;  // CLUSTER_TEXELS each
layout(std430, set = 0, binding = BINDING_CLASSES) writeonly buffer Classes { uint classes[]; };
layout(std430, set = 0, binding = BINDING_COUNTERS) buffer Counters { ViewCounters counters[]; };
layout(set = 0, binding = BINDING_VIEWS) uniform usamplerBuffer views;          // GpuFrustum
layout(set = 0, binding = BINDING_CENTRES) uniform usamplerBuffer instances;    // CLUSTER_INSTANCE_TEXELS each
layout(std430, set = 0, binding = BINDING_GROUP_COUNTS) buffer GroupCounts { uint group_counts[]; };
layout(std430, set = 0, binding = BINDING_PYRAMID) readonly buffer Pyramid { float pyramid[]; };
layout(set = 0, binding = BINDING_OCCLUSION_VIEWS) uniform usamplerBuffer occlusion_views;
layout(set = 0, binding = CLUSTER_BINDING_PAIRS) uniform usamplerBuffer pairs;
layout(std430, set = 0, binding = CLUSTER_BINDING_ACTIVE) readonly buffer Listed { uint listed_pairs[]; };
layout(set = 0, binding = CLUSTER_BINDING_OBBS) uniform usamplerBuffer pair_obbs;  // GpuObb each

layout(push_constant, std430) uniform Push { ClusterCullParams params; };

uint view_plane_count;
vec4 view_planes[MAX_FRUSTUM_PLANES];
vec4 occ_volume_word(uint word) { return vec4(0.0); }  // (boxes are tested from their corners directly)

#include "shared/classify.glsl"
#include "shared/cone.glsl"
#include "shared/instance.glsl"
#include "shared/occlusion.glsl"
#include "shared/ordered_runs.glsl"

vec4 word(usamplerBuffer b, int i) { return uintBitsToFloat(texelFetch(b, i)); }

void load_view() {
  uvec4 tail = texelFetch(views, int(MAX_FRUSTUM_PLANES));
  view_plane_count = min(tail.x, MAX_FRUSTUM_PLANES);
  [[unroll]] for (uint k = 0; k < MAX_FRUSTUM_PLANES; ++k) view_planes[k] = word(views, int(k));
  if (OCCLUSION != 0u) occ_load_view(0u);
}

// A listed pair's class (its instance was kept: the list holds no other); `obb` is 1 + the
// index of its placed OBB, 0 for none.
uint classify_pair(uint instance, uint cluster, uint obb) {
  int ib = int(CLUSTER_INSTANCE_TEXELS * instance), cb = int(CLUSTER_TEXELS * cluster);
  vec4 rows[3] = vec4[3](word(instances, ib), word(instances, ib + 1), word(instances, ib + 2));
  vec4 box_min = word(clusters, cb), box_max = word(clusters, cb + 1);
  vec3 lo, hi;
  instance_aabb(rows, box_min.xyz, box_max.xyz, lo, hi);
  uint straddled;
  if (classify_aabb(lo, hi, ALL_PLANES, straddled) == CLASS_OUTSIDE) return CLUSTER_OUTSIDE;
  vec4 o[4] = vec4[4](vec4(0.0), vec4(0.0), vec4(0.0), vec4(0.0));
  if (obb != 0u) {
    int ob = int(OBB_VEC4S * (obb - 1u));
    o = vec4[4](word(pair_obbs, ob), word(pair_obbs, ob + 1), word(pair_obbs, ob + 2), word(pair_obbs, ob + 3));
    if (classify_obb(o[0].xyz, o[1], o[2], o[3], ALL_PLANES) == CLASS_OUTSIDE) return CLUSTER_OUTSIDE;
  }
  if (params.backface != 0u) {
    vec4 frame = word(instances, ib + 6);
    if ((floatBitsToUint(frame.w) & 1u) != 0u) {
      vec4 inverse[3] = vec4[3](word(instances, ib + 3), word(instances, ib + 4), word(instances, ib + 5));
      if (cone_facing_away(word(clusters, cb + 2).xyz, box_min.w, word(clusters, cb + 3).xyz, inverse, frame.xyz,
                           params.eye.xyz))
        return CLUSTER_BACK_FACING;
    }
  }
  if (OCCLUSION != 0u) {
    vec3 p[8];
    vec3 magnitude;
    occ_box_corners(lo, hi, p, magnitude);
    if (occ_occluded(p, magnitude, 1.0, OCC_TEXELS)) return CLUSTER_OCCLUDED;
    if (obb != 0u) {
      occ_obb_corners(o[0].xyz, o[1], o[2], o[3], p, magnitude);
      if (occ_occluded(p, magnitude, 1.0, OCC_TEXELS)) return CLUSTER_OCCLUDED;
    }
  }
  return CLUSTER_DRAWN;
}

// The run's drawn pairs (for the draws' starts).
shared uint drawn_bits[MAX_CULL_GROUP_SIZE / 32];

// Invocation k takes the k-th listed pair (cluster_expand.comp); workgroups past the list end
// at once.
void main() {
  uint t = gl_LocalInvocationIndex;
  uint listed = listed_pairs[0];  // the header's visible_count
  uint k0 = this_run_first_object(params.first_pair);
  if (k0 >= listed) return;  // the whole workgroup
  if (t < (gl_WorkGroupSize.x + 31u) / 32u) drawn_bits[t] = 0u;
  load_view();
  uint k = k0 + t;
  bool drawn = false, continues = false;
  if (k < listed) {
    uint p = listed_pairs[CLUSTER_ACTIVE_HEADER + k];
    uvec4 pair = texelFetch(pairs, int(p));
    uint c = classify_pair(pair.x, pair.y, pair.z);
    classes[p] = c;
    drawn = c == CLUSTER_DRAWN;
    continues = pair.w != 0u;
  }
  barrier();
  if (drawn) atomicOr(drawn_bits[t / 32u], 1u << (t % 32u));
  barrier();
  // The workgroup's draws: its drawn pairs that do not join the draw of the pair before
  // (cluster_scatter.comp; a pair continuing another is of the same instance, so that pair is
  // listed just before it), counted with one atomic per subgroup on the workgroup's own count,
  // zeroed before the pass (its INSIDE count stays 0).
  bool joins = continues && t > 0u && (drawn_bits[(t - 1u) / 32u] & (1u << ((t - 1u) % 32u))) != 0u;
  uint total = subgroupAdd(drawn && !joins ? 1u : 0u);
  if (subgroupElect() && total > 0u) atomicAdd(group_counts[this_run(params.first_pair)], total);
}
