#version 460
// Cluster draws, the last of the cluster pass's passes (after cull_clusters.comp and
// compact_scan.comp): the drawn pairs of each workgroup's run of listed pairs, in pair order, as draws, where a
// drawn pair that continues the one before it (its index range follows on from it, same
// instance and vertex offset: the pair texel's w) joins that pair's draw. A draw starts at a
// drawn pair whose predecessor in the run is not drawn or not continued; it ends before the
// first pair after it that is not drawn or not continued (or at the run's end): one draw then
// covers the whole run of clusters, whose index count is the span from its first cluster's first
// index to its last cluster's end. Fewer draws, the same triangles in the same order.
// Slots at or past visible_capacity are dropped (the counters report the overflow).
#extension GL_GOOGLE_include_directive : require

#include "cullpipe/gpu/cull_types.h"

layout(local_size_x_id = 1) in;
layout(constant_id = 4) const uint OBJECTS_PER_INVOCATION = 1;  // one pair per invocation
#include "shared/ordered_runs.glsl"

layout(std430, set = 0, binding = BINDING_CLASSES) readonly buffer Classes { uint classes[]; };
layout(std430, set = 0, binding = BINDING_VISIBLE) writeonly buffer Visible { uint visible_ids[]; };
layout(std430, set = 0, binding = BINDING_DRAW_TEMPLATES) readonly buffer DrawTemplates { DrawCommand templates[]; };
layout(std430, set = 0, binding = BINDING_DRAWS) writeonly buffer Draws { DrawCommand draws[]; };
layout(std430, set = 0, binding = BINDING_GROUP_COUNTS) readonly buffer GroupCounts { uint group_offsets[]; };
layout(set = 0, binding = CLUSTER_BINDING_PAIRS) uniform usamplerBuffer pairs;
layout(std430, set = 0, binding = CLUSTER_BINDING_ACTIVE) readonly buffer Listed { uint listed_pairs[]; };
layout(push_constant, std430) uniform Push { ClusterCullParams params; };

// Per pair of the run: drawn; joining the draw of the pair before (drawn, continuing it, and
// that pair drawn); starting a draw (drawn, not joining); then, per word, the starts before it.
shared uint drawn_bits[MAX_CULL_GROUP_SIZE / 32];
shared uint join_bits[MAX_CULL_GROUP_SIZE / 32];
shared uint start_bits[MAX_CULL_GROUP_SIZE / 32];
shared uint word_base[MAX_CULL_GROUP_SIZE / 32];

// The first pair after t (local) that does not join the draw before it, or `limit`.
uint draw_end(uint t, uint limit) {
  uint q = t + 1u;
  while (q < limit) {
    uint w = q / 32u;
    uint breaks = ~join_bits[w] & (0xffffffffu << (q % 32u));
    if (breaks != 0u) return min(w * 32u + findLSB(breaks), limit);
    q = (w + 1u) * 32u;
  }
  return limit;
}

// Invocation k takes the k-th listed pair (cluster_expand.comp), as the culling pass did.
void main() {
  uint t = gl_LocalInvocationIndex;
  uint group_size = gl_WorkGroupSize.x;
  uint listed = listed_pairs[0];
  uint first = this_run_first_object(params.first_pair);
  if (first >= listed) return;  // the whole workgroup
  uint k = first + t;
  uint limit = min(group_size, listed - first);
  uint words = (group_size + 31u) / 32u;
  if (t < words) {
    drawn_bits[t] = 0u;
    join_bits[t] = 0u;
    start_bits[t] = 0u;
  }
  barrier();
  uint p = k < listed ? listed_pairs[CLUSTER_ACTIVE_HEADER + k] : 0u;
  bool drawn = k < listed && classes[p] == CLUSTER_DRAWN;
  if (drawn) atomicOr(drawn_bits[t / 32u], 1u << (t % 32u));
  barrier();
  bool continues = drawn && texelFetch(pairs, int(p)).w != 0u;
  bool joins = continues && t > 0u && (drawn_bits[(t - 1u) / 32u] & (1u << ((t - 1u) % 32u))) != 0u;
  bool start = drawn && !joins;
  if (joins) atomicOr(join_bits[t / 32u], 1u << (t % 32u));
  if (start) atomicOr(start_bits[t / 32u], 1u << (t % 32u));
  barrier();
  if (t < words) {
    uint before = 0u;
    for (uint w = 0u; w < t; ++w) before += bitCount(start_bits[w]);
    word_base[t] = before;
  }
  barrier();
  if (!start) return;
  uint slot = group_offsets[this_run(params.first_pair)] + word_base[t / 32u] +
              bitCount(start_bits[t / 32u] & ((1u << (t % 32u)) - 1u));
  if (slot >= params.visible_capacity) return;
  uint last = listed_pairs[CLUSTER_ACTIVE_HEADER + first + draw_end(t, limit) - 1u];
  DrawCommand d = templates[p];
  DrawCommand e = templates[last];
  d.index_count = e.first_index + e.index_count - d.first_index;
  d.object_id = p;
  draws[slot] = d;
  visible_ids[slot] = p;
}
