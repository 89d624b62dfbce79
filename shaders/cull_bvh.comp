#version 460
// Hierarchical frustum culling of a depth-first BVH in one dispatch. The host cuts the tree
// into subtrees of at most BvhCuller::subtree_objects() objects and BVH_CUT_MAX_HEIGHT levels
// below their root (the highest nodes that fit, and leaves), and one invocation takes one
// such cut subtree of one view:
//   1. it descends from the root to its cut node, testing each node on the path on the planes
//      its parent straddles (plane masking, Assarsson & Moller 2000); an OUTSIDE node ends the
//      work, an INSIDE one accepts the cut subtree's whole object range. Invocations whose cut
//      nodes share an ancestor all test it (same answer); only the one whose cut node is its
//      first-child descendant counts the test, so every node test is counted once;
//   2. it walks its cut subtree depth first (skip indices, a 6-bit plane mask per level):
//      OUTSIDE skips a subtree, INSIDE records its object range (adjacent ranges merged), and
//      the objects of an INTERSECTING leaf are tested there, on the planes the leaf straddles,
//      the visible ones recorded with their class;
//   3. the subgroup reserves the list slots of all its visible objects with one atomic per
//      counter;
//   4. the subgroup writes every lane's records together, lane after lane, one object per
//      lane: no atomics, and no lane idles through another's long accepted range.
// Records go to the invocation's own slice of a scratch buffer (its cut subtree's object
// range: one record per accepted range or visible tested object, so they fit), so the walk
// needs no atomics and no work queues. (On lavapipe every branch runs under a mask and only
// loops skip work: the walk loop holds the tests and record stores alone, and nothing in it
// waits on other lanes. The design before this one, an indirect dispatch per five tree
// levels over node queues with appends at every walk step, took 9 dispatches and 2.7-4x as
// long at 10-50% visible.)
// The result equals host/bvh cull_hierarchical bit for bit: same p/n-vertex test, distances as
// ((n.x*p.x + n.y*p.y) + n.z*p.z) + d marked `precise`, same masks, and the same counts of
// node and object tests.
#extension GL_GOOGLE_include_directive : require
#extension GL_KHR_shader_subgroup_basic : require
#extension GL_KHR_shader_subgroup_ballot : require
#extension GL_KHR_shader_subgroup_arithmetic : require
#extension GL_KHR_shader_subgroup_shuffle : require
#extension GL_EXT_control_flow_attributes : require

#include "shared/cull_types.h"

layout(local_size_x_id = 1) in;  // = BVH_CULL_GROUP_SIZE, set by the host
layout(constant_id = 2) const uint BV_KIND = BV_KIND_AABB;  // the node margin and the object test
layout(constant_id = 3) const uint WRITE_DRAWS = 0;  // also write draw commands

// The object volumes (GpuAabb, GpuObb or GpuSphere by BV_KIND, in tree order) and the nodes
// (GpuBvhNode) are read as integer texels (exact bits) from uniform texel buffers: on lavapipe
// a texel fetch loads 16 bytes per lane, a storage-buffer load branches per lane and component.
layout(set = 0, binding = BINDING_BOUNDS) uniform usamplerBuffer boxes;
layout(std430, set = 0, binding = BINDING_CLASSES) writeonly buffer Classes { uint classes[]; };
layout(std430, set = 0, binding = BINDING_VISIBLE) writeonly buffer Visible { uint visible_ids[]; };
layout(std430, set = 0, binding = BINDING_COUNTERS) buffer Counters { ViewCounters counters[]; };
layout(set = 0, binding = BINDING_VIEWS) uniform usamplerBuffer views;  // GpuFrustum, FRUSTUM_TEXELS texels each
layout(std430, set = 0, binding = BINDING_DRAW_TEMPLATES) readonly buffer DrawTemplates { DrawCommand templates[]; };
layout(std430, set = 0, binding = BINDING_DRAWS) writeonly buffer Draws { DrawCommand draws[]; };
layout(set = 0, binding = BVH_BINDING_NODES) uniform usamplerBuffer nodes;
layout(set = 0, binding = BVH_BINDING_OBJECTS) uniform usamplerBuffer object_order;  // four ids per texel
layout(std430, set = 0, binding = BVH_BINDING_CUTS) readonly buffer Cuts { uint cuts[]; };
// Written by each invocation in its walk, read by the other lanes of its subgroup after
// subgroupMemoryBarrierBuffer() and subgroupBarrier().
layout(std430, set = 0, binding = BVH_BINDING_RECORDS) coherent buffer Records { uvec2 records[]; };

layout(push_constant, std430) uniform Push { BvhCullParams params; };

GpuBvhNode load_node(uint index) {
  uvec4 a = texelFetch(nodes, int(3u * index)), b = texelFetch(nodes, int(3u * index + 1u)), c = texelFetch(nodes, int(3u * index + 2u));
  return GpuBvhNode(uintBitsToFloat(a.xyz), a.w, uintBitsToFloat(b.xyz), b.w, c.x, c.y, c.z, c.w);
}

vec4 volume_word(uint word) { return uintBitsToFloat(texelFetch(boxes, int(word))); }

// The id of the object at tree-order slot `slot`.
uint object_at(uint slot) {
  uvec4 t = texelFetch(object_order, int(slot >> 2u));
  uint c = slot & 3u;
  return c == 0u ? t.x : c == 1u ? t.y : c == 2u ? t.z : t.w;
}

// The workgroup's view: its planes, loaded once into registers (the view is uniform across
// the workgroup: plain loads).
uint view_plane_count;
vec4 view_planes[MAX_FRUSTUM_PLANES];

#include "shared/classify.glsl"

void load_view(uint view) {
  int first = int(FRUSTUM_TEXELS * view);
  view_plane_count = min(texelFetch(views, first + int(MAX_FRUSTUM_PLANES)).x, MAX_FRUSTUM_PLANES);
  [[unroll]] for (uint k = 0; k < MAX_FRUSTUM_PLANES; ++k) view_planes[k] = uintBitsToFloat(texelFetch(views, first + int(k)));
}

// The node test of hierarchies over OBBs and spheres (bvh::classify_masked_margin): a plane
// decides a node only beyond a margin of 2^-16 x (reach + |d|) + 2^-120, reach = the sum over
// axes of the box's largest |coordinate|; past reach + |d| = 2^120 it decides nothing.
uint classify_masked_margin(vec3 lo, vec3 hi, uint mask, out uint straddled) {
  bool outside = false;
  straddled = 0u;
  precise float reach = max(abs(lo.x), abs(hi.x)) + max(abs(lo.y), abs(hi.y)) + max(abs(lo.z), abs(hi.z));
  [[unroll]] for (uint k = 0; k < MAX_FRUSTUM_PLANES; ++k) {
    vec4 plane = view_planes[k];
    precise float size = reach + abs(plane.w);
    bool certain = size <= uintBitsToFloat(BVH_MARGIN_LIMIT_BITS);  // false for NaN too
    precise float margin = uintBitsToFloat(BVH_MARGIN_SCALE_BITS) * size + uintBitsToFloat(BVH_MARGIN_FLOOR_BITS);
    vec3 p_vertex = vec3(plane.x >= 0.0 ? hi.x : lo.x, plane.y >= 0.0 ? hi.y : lo.y, plane.z >= 0.0 ? hi.z : lo.z);
    vec3 n_vertex = vec3(plane.x >= 0.0 ? lo.x : hi.x, plane.y >= 0.0 ? lo.y : hi.y, plane.z >= 0.0 ? lo.z : hi.z);
    bool tested = plane_tested(k, mask);
    outside = outside || (tested && certain && plane_distance(plane, p_vertex) < -margin);
    if (tested && (!certain || plane_distance(plane, n_vertex) < margin)) straddled |= 1u << k;
  }
  return outside ? CLASS_OUTSIDE : straddled != 0u ? CLASS_INTERSECTING : CLASS_INSIDE;
}

uint classify_node(vec3 lo, vec3 hi, uint mask, out uint straddled) {
  if (BV_KIND == BV_KIND_AABB) return classify_aabb(lo, hi, mask, straddled);
  return classify_masked_margin(lo, hi, mask, straddled);
}

// The object test of slot `slot` (tree order) on the planes in `mask` (bvh::classify_object).
uint classify_object(uint slot, uint mask) {
  if (BV_KIND == BV_KIND_AABB) {
    uint unused;
    return classify_aabb(volume_word(AABB_VEC4S * slot).xyz, volume_word(AABB_VEC4S * slot + 1u).xyz, mask, unused);
  }
  if (BV_KIND == BV_KIND_OBB) {
    uint b = OBB_VEC4S * slot;
    return classify_obb(volume_word(b).xyz, volume_word(b + 1u), volume_word(b + 2u), volume_word(b + 3u), mask);
  }
  return classify_sphere(volume_word(SPHERE_VEC4S * slot), mask);
}

// The parameters, read once (lavapipe reads a push constant like a uniform buffer at each use:
// a bounds-checked gather).
uint object_count, visible_capacity;
bool write_classes;

// Writes a visible object's outputs: class, list slot, draw.
void emit_visible(uint view, uint object, uint slot, uint c) {
  if (write_classes) classes[view * object_count + object] = c;
  if (slot < visible_capacity) {
    visible_ids[view * visible_capacity + slot] = object;
    if (WRITE_DRAWS != 0) {
      DrawCommand d = templates[object];
      d.object_id = object;
      draws[view * visible_capacity + slot] = d;
    }
  }
}

// The plane mask of tree level `level` below the cut node: 6 bits (MAX_FRUSTUM_PLANES) per
// level, five levels per word, BVH_CUT_MAX_HEIGHT + 1 <= 20 levels.
uint level_mask(uvec4 masks, uint level) {
  uint word = level < 5u ? masks.x : level < 10u ? masks.y : level < 15u ? masks.z : masks.w;
  return (word >> (6u * (level % 5u))) & 63u;
}
uvec4 with_level_mask(uvec4 masks, uint level, uint mask) {
  uint shift = 6u * (level % 5u), keep = ~(63u << shift), put = mask << shift;
  if (level < 5u) masks.x = (masks.x & keep) | put;
  else if (level < 10u) masks.y = (masks.y & keep) | put;
  else if (level < 15u) masks.z = (masks.z & keep) | put;
  else masks.w = (masks.w & keep) | put;
  return masks;
}


void main() {
  // Workgroups are view-major and never straddle views (groups_per_view per view); larger
  // dispatches fold into y, and the groups past the last view return.
  uint group = gl_WorkGroupID.y * gl_NumWorkGroups.x + gl_WorkGroupID.x;
  uint view = group / params.groups_per_view;
  if (view >= params.view_count) return;
  object_count = params.object_count;
  visible_capacity = params.visible_capacity;
  write_classes = params.write_classes != 0u;
  uint i = (group - view * params.groups_per_view) * gl_WorkGroupSize.x + gl_LocalInvocationIndex;
  bool has_cut = i < params.cut_count;
  load_view(view);

  uint cut = has_cut ? cuts[i] : 0u;
  uvec4 cut_lo = texelFetch(nodes, int(3u * cut)), cut_hi = texelFetch(nodes, int(3u * cut + 1u));
  uvec4 cut_links = texelFetch(nodes, int(3u * cut + 2u));  // skip, second child, leaf, depth
  uint cut_first = cut_lo.w, cut_count = has_cut ? cut_hi.w : 0u, cut_end = cut_links.x, cut_depth = cut_links.w;
  uint mask = (1u << view_plane_count) - 1u;
  uvec2 tests = uvec2(0u);  // node tests, object tests (counted as host/bvh counts them)

  // 1. From the root down to the cut node.
  bool walk = has_cut, accept_all = false, descending = has_cut && cut != 0u;
  uint node = 0u;
  while (descending) {
    GpuBvhNode n = load_node(node);
    uint straddled;
    uint c = classify_node(n.box_min, n.box_max, mask, straddled);
    if (cut - node == cut_depth - n.depth) tests.x += 1u;  // the cut node is its first-child descendant
    if (c != CLASS_INTERSECTING) {
      walk = false;
      accept_all = c == CLASS_INSIDE;
      descending = false;
    } else {
      mask = straddled;
      node = cut >= n.second_child ? n.second_child : node + 1u;
      descending = node != cut;
    }
  }

  // 2. The cut subtree, depth first, recording into this invocation's slice of the scratch
  // (cut_count records; one per accepted range or visible tested object, so they fit):
  // accepted ranges from its front, the visible objects of INTERSECTING leaves, tested here,
  // from its back.
  uint base = view * object_count + cut_first, back = base + cut_count - 1u;
  uint accept_records = 0u, tested_visible = 0u, accepted = 0u, tested_inside = 0u;
  uint open_first = cut_first, open_count = accept_all ? cut_count : 0u;  // the accepted range being grown
  uvec4 masks = uvec4(mask, 0u, 0u, 0u);
  node = cut;
  while (walk) {
    GpuBvhNode n = load_node(node);
    uint level = n.depth - cut_depth, straddled;
    uint c = classify_node(n.box_min, n.box_max, level_mask(masks, level), straddled);
    tests.x += 1u;
    bool leaf_test = c == CLASS_INTERSECTING && n.leaf != 0u;
    uint to_test = leaf_test ? n.count : 0u;
    tests.y += to_test;
    for (uint k = 0u; k < to_test; ++k) {
      uint object_class = classify_object(n.first + k, straddled);
      if (object_class != CLASS_OUTSIDE) {
        records[back - tested_visible] = uvec2(n.first + k, object_class);
        tested_visible += 1u;
        tested_inside += object_class == CLASS_INSIDE ? 1u : 0u;
      }
    }
    // An INSIDE node continues the accepted range being grown, or closes it and starts one.
    bool extend = c == CLASS_INSIDE && open_count != 0u && open_first + open_count == n.first;
    if (c == CLASS_INSIDE && !extend && open_count != 0u) {
      records[base + accept_records] = uvec2(open_first, open_count);
      accept_records += 1u;
      accepted += open_count;
    }
    if (c == CLASS_INSIDE) {
      open_first = extend ? open_first : n.first;
      open_count = extend ? open_count + n.count : n.count;
    }
    bool descend = c == CLASS_INTERSECTING && n.leaf == 0u;
    if (descend) masks = with_level_mask(masks, level + 1u, straddled);
    node = descend ? node + 1u : n.skip;
    walk = node != cut_end;
  }
  if (open_count != 0u) {
    records[base + accept_records] = uvec2(open_first, open_count);
    accept_records += 1u;
    accepted += open_count;
  }

  // 3. The list slots and the counts: one global atomic per subgroup and counter, no
  // workgroup barrier (as the flat pass: on lavapipe each barrier suspends and resumes every
  // subgroup's coroutine).
  uint visible = accepted + tested_visible, inside = accepted + tested_inside;
  subgroupMemoryBarrierBuffer();  // the records, for step 4 (read by this subgroup only)
  subgroupBarrier();
  uint subgroup_visible = subgroupAdd(visible), subgroup_inside = subgroupAdd(inside);
  uint node_tests = subgroupAdd(tests.x), object_tests = subgroupAdd(tests.y);
  uint subgroup_base = 0u;
  if (subgroupElect()) {
    if (subgroup_visible != 0u) {
      subgroup_base = atomicAdd(counters[view].visible_count, subgroup_visible);
      atomicAdd(counters[view].inside_count, subgroup_inside);
    }
    if (node_tests != 0u) atomicAdd(counters[view].node_tests, node_tests);
    if (object_tests != 0u) atomicAdd(counters[view].object_tests, object_tests);
  }
  uint slot = subgroupBroadcastFirst(subgroup_base) + subgroupExclusiveAdd(visible);

  // 4. Every lane's records, lane after lane, by the whole subgroup: its accepted ranges (every
  // object INSIDE), then its tested visible objects.
  uvec4 todo = subgroupBallot(visible != 0u);
  for (uint left = subgroupBallotBitCount(todo); left > 0u; --left) {
    uint lane = subgroupBallotFindLSB(todo);
    todo[lane / 32u] &= ~(1u << (lane % 32u));
    uint lane_base = subgroupShuffle(base, lane), lane_records = subgroupShuffle(accept_records, lane);
    uint lane_slot = subgroupShuffle(slot, lane);
    for (uint r = 0u; r < lane_records; ++r) {
      uvec2 range = records[lane_base + r];
      for (uint k = gl_SubgroupInvocationID; k < range.y; k += gl_SubgroupSize)
        emit_visible(view, object_at(range.x + k), lane_slot + k, CLASS_INSIDE);
      lane_slot += range.y;
    }
    uint lane_back = subgroupShuffle(back, lane), lane_tested = subgroupShuffle(tested_visible, lane);
    for (uint k = gl_SubgroupInvocationID; k < lane_tested; k += gl_SubgroupSize) {
      uvec2 tested = records[lane_back - k];
      emit_visible(view, object_at(tested.x), lane_slot + k, tested.y);
    }
  }
}
