#version 460
// Refits a flattened tree to its objects' placed boxes: each invocation recomputes one node's
// box, as the union of its objects' boxes (a leaf) or of its two children's (an inner node).
// One dispatch per height, leaves first, so every child is done before its parent reads it.
// Bit for bit bvh::refit(FlatTree&, boxes): a box starts empty and takes the componentwise
// minima and maxima in the same order (objects in tree order; first child, then second),
// written as glm writes them (b < a ? b : a), which decides between +0 and -0 the same way.
// Minima and maxima round nothing, so the node boxes enclose the placed boxes exactly.
//
// Shaped for lavapipe, where both sides of an `if` run and a storage-buffer store is a loop over
// the lanes: leaves and inner nodes are separate pipelines (LEAVES), each node's entry in the
// order gives all it needs besides the boxes, everything is read through texel buffers (a
// gather per texel), and only the box words are stored.
#extension GL_GOOGLE_include_directive : require

#include "cullpipe/gpu/cull_types.h"

layout(local_size_x = REFIT_GROUP_SIZE) in;
layout(constant_id = 0) const bool LEAVES = true;  // the leaves' dispatch, else an inner height's

layout(set = 0, binding = REFIT_BINDING_NODES) uniform usamplerBuffer nodes;  // three texels per node
layout(std430, set = 0, binding = REFIT_BINDING_NODE_WORDS) writeonly buffer NodeWords { uvec4 node_words[]; };
layout(set = 0, binding = REFIT_BINDING_BOUNDS) uniform usamplerBuffer bounds;
layout(set = 0, binding = REFIT_BINDING_ORDER) uniform usamplerBuffer order;  // GpuRefitEntry per node
layout(push_constant) uniform Push { RefitParams params; };

vec3 grow_min(vec3 a, vec3 b) { return vec3(b.x < a.x ? b.x : a.x, b.y < a.y ? b.y : a.y, b.z < a.z ? b.z : a.z); }
vec3 grow_max(vec3 a, vec3 b) { return vec3(a.x < b.x ? b.x : a.x, a.y < b.y ? b.y : a.y, a.z < b.z ? b.z : a.z); }
vec3 box_word(usamplerBuffer b, uint texel) { return uintBitsToFloat(texelFetch(b, int(texel)).xyz); }

void main() {
  if (gl_GlobalInvocationID.x >= params.count) return;
  uvec4 entry = texelFetch(order, int(params.first + gl_GlobalInvocationID.x));  // node, first, count
  float inf = uintBitsToFloat(0x7f800000u);
  vec3 lo = vec3(inf), hi = vec3(-inf);
  if (LEAVES) {
    for (uint j = entry.y, end = entry.y + entry.z; j < end; ++j) {
      lo = grow_min(lo, box_word(bounds, 2u * j));
      hi = grow_max(hi, box_word(bounds, 2u * j + 1u));
    }
  } else {
    lo = grow_min(lo, box_word(nodes, 3u * entry.y));
    hi = grow_max(hi, box_word(nodes, 3u * entry.y + 1u));
    lo = grow_min(lo, box_word(nodes, 3u * entry.z));
    hi = grow_max(hi, box_word(nodes, 3u * entry.z + 1u));
  }
  node_words[3u * entry.x].xyz = floatBitsToUint(lo);
  node_words[3u * entry.x + 1u].xyz = floatBitsToUint(hi);
}
