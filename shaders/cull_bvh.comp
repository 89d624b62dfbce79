#version 460
// Hierarchical frustum culling of a depth-first BVH, in parallel: every
// BVH_LEVELS_PER_DISPATCH (5) levels of the tree are one indirect dispatch over a queue of
// (node, view, plane mask) work items; an invocation walks its item's subtree down those
// levels, depth first, and queues the INTERSECTING nodes' children below them. Each node box
// is tested once per view. (Two levels per dispatch, one node and its children per item, took
// 20% longer on lavapipe at 1-50% visible: each dispatch costs lavapipe thread wake-ups.)
//
//   SEED    one root item per view (all planes), queue state reset
//   LEVEL   test each node of the items' bands on the planes its parent straddles (plane
//           masking, Assarsson & Moller 2000): OUTSIDE drops the subtree; INSIDE queues its
//           object range as chunks to accept without tests; INTERSECTING descends with the
//           planes this node straddles (below the band: queues both children), or, at a
//           leaf, queues one test per object. The
//           last workgroup to finish (a counter, as in AMD FidelityFX SPD) writes the
//           indirect arguments of the next LEVEL dispatch
//   FINISH  indirect arguments for ACCEPT and TEST
//   ACCEPT  every object of an accepted chunk is INSIDE (list slots reserved by LEVEL)
//   TEST    each object of an INTERSECTING leaf is tested on the straddled planes
// An INSIDE subtree's object range is split so that no invocation idles on a small subtree:
// full chunks of the workgroup size go to ACCEPT (one workgroup each), the rest to the dense
// TEST list with an empty plane mask (accepted there without a test). (A variant with one
// range entry per subtree, ordered by a 64-bit atomic and searched per object, measured
// slower on lavapipe at every visible fraction.)
// The host records SEED, then LEVEL once per band of tree levels, then FINISH, ACCEPT and TEST,
// with barriers between. The result equals host/bvh cull_hierarchical bit for bit: same
// p/n-vertex test, distances as ((n.x*p.x + n.y*p.y) + n.z*p.z) + d marked `precise`, same
// masks, and the same counts of node and object tests.
#extension GL_GOOGLE_include_directive : require
#extension GL_KHR_shader_subgroup_basic : require
#extension GL_KHR_shader_subgroup_ballot : require
#extension GL_KHR_shader_subgroup_vote : require
#extension GL_KHR_shader_subgroup_arithmetic : require
#extension GL_KHR_shader_subgroup_shuffle : require
#extension GL_EXT_control_flow_attributes : require

#include "shared/cull_types.h"

layout(local_size_x_id = 1) in;  // = BVH_CULL_GROUP_SIZE, set by the host
layout(constant_id = 0) const uint PASS = BVH_PASS_LEVEL;
layout(constant_id = 2) const uint BV_KIND = BV_KIND_AABB;  // LEVEL: node margin; TEST: the object test
layout(constant_id = 3) const uint WRITE_DRAWS = 0;  // ACCEPT / TEST: also write draw commands

// The object volumes (GpuAabb, GpuObb or GpuSphere by BV_KIND, in tree order) and the nodes
// (GpuBvhNode) are read as integer
// texels (exact bits) from uniform texel buffers: on lavapipe a texel fetch loads 16 bytes per
// lane, a storage-buffer load branches per lane and component.
layout(set = 0, binding = BINDING_BOUNDS) uniform usamplerBuffer boxes;
layout(std430, set = 0, binding = BINDING_CLASSES) writeonly buffer Classes { uint classes[]; };
layout(std430, set = 0, binding = BINDING_VISIBLE) writeonly buffer Visible { uint visible_ids[]; };
layout(std430, set = 0, binding = BINDING_COUNTERS) buffer Counters { ViewCounters counters[]; };
layout(std430, set = 0, binding = BINDING_VIEWS) readonly buffer Views { GpuFrustum views[]; };
layout(std430, set = 0, binding = BINDING_DRAW_TEMPLATES) readonly buffer DrawTemplates { DrawCommand templates[]; };
layout(std430, set = 0, binding = BINDING_DRAWS) writeonly buffer Draws { DrawCommand draws[]; };
layout(set = 0, binding = BVH_BINDING_NODES) uniform usamplerBuffer nodes;
layout(std430, set = 0, binding = BVH_BINDING_OBJECTS) readonly buffer Objects { uint object_ids[]; };
layout(std430, set = 0, binding = BVH_BINDING_QUEUE) buffer Queue { BvhWorkItem queue[]; };
layout(std430, set = 0, binding = BVH_BINDING_RANGES) buffer Ranges { BvhRange ranges[]; };
layout(std430, set = 0, binding = BVH_BINDING_TESTS) buffer Tests { BvhWorkItem tests[]; };
layout(std430, set = 0, binding = BVH_BINDING_TRAVERSAL) buffer Traversal { BvhTraversal state; };

layout(push_constant, std430) uniform Push { BvhCullParams params; };

const uint MASK = (1u << BVH_MASK_BITS) - 1u;

GpuBvhNode load_node(uint index) {
  uvec4 a = texelFetch(nodes, int(3u * index)), b = texelFetch(nodes, int(3u * index + 1u)), c = texelFetch(nodes, int(3u * index + 2u));
  return GpuBvhNode(uintBitsToFloat(a.xyz), a.w, uintBitsToFloat(b.xyz), b.w, c.x, c.y, c.z, c.w);
}

vec4 volume_word(uint word) { return uintBitsToFloat(texelFetch(boxes, int(word))); }

// This invocation's view: its planes, loaded once (load_view) into registers.
uint view_plane_count;
vec4 view_planes[MAX_FRUSTUM_PLANES];

#include "shared/classify.glsl"

// Loads the planes of `view`. Called in uniform control flow: when the whole subgroup is on
// one view (the usual case) the loads use a subgroup-uniform index (one load, not a gather
// per lane).
void load_view(uint view) {
  if (subgroupAllEqual(view)) {
    uint v = subgroupBroadcastFirst(view);  // uniform: plain loads
    view_plane_count = min(views[v].plane_count, MAX_FRUSTUM_PLANES);
    [[unroll]] for (uint k = 0; k < MAX_FRUSTUM_PLANES; ++k) view_planes[k] = views[v].planes[k];
  } else {
    view_plane_count = min(views[view].plane_count, MAX_FRUSTUM_PLANES);
    [[unroll]] for (uint k = 0; k < MAX_FRUSTUM_PLANES; ++k) view_planes[k] = views[view].planes[k];
  }
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

// Dispatches larger than max_groups_x workgroups fold into y.
uint flat_group() { return gl_WorkGroupID.y * gl_NumWorkGroups.x + gl_WorkGroupID.x; }

BvhDispatch dispatch_for(uint groups, uint items) {
  uint x = min(groups, params.max_groups_x);
  uint y = x == 0u ? 1u : (groups + x - 1u) / x;
  return BvhDispatch(x, y, 1u, items);
}

void note_overflow() { atomicOr(state.overflow, 1u); }

// Writes a visible object's outputs: class, list slot, draw.
void emit_visible(uint view, uint object, uint slot, uint c) {
  if (params.write_classes != 0u) classes[view * params.object_count + object] = c;
  if (slot < params.visible_capacity) {
    visible_ids[view * params.visible_capacity + slot] = object;
    if (WRITE_DRAWS != 0) {
      DrawCommand d = templates[object];
      d.object_id = object;
      draws[view * params.visible_capacity + slot] = d;
    }
  }
}

void seed() {
  // One workgroup: item v = the root of view v with all its planes.
  uint roots = params.node_count == 0u ? 0u : params.view_count;
  for (uint v = gl_LocalInvocationIndex; v < roots; v += gl_WorkGroupSize.x) {
    uint plane_count = min(views[v].plane_count, MAX_FRUSTUM_PLANES);
    queue[v] = BvhWorkItem(0u, (v << BVH_MASK_BITS) | ((1u << plane_count) - 1u));
  }
  if (gl_LocalInvocationIndex == 0u) {
    state.queue_count[0] = roots;
    state.queue_count[1] = 0u;
    state.range_count = 0u;
    state.test_count = 0u;
    state.level = dispatch_for((roots + gl_WorkGroupSize.x - 1u) / gl_WorkGroupSize.x, roots);
    state.accept = BvhDispatch(0u, 1u, 1u, 0u);
    state.test = BvhDispatch(0u, 1u, 1u, 0u);
    state.overflow = 0u;
    state.groups_done = 0u;
  }
}

// Reserves `n` consecutive entries per invocation with one atomic per subgroup on COUNTER;
// returns this invocation's first entry. Called in uniform control flow.
#define SUBGROUP_APPEND(COUNTER, n, result)                                      \
  {                                                                             \
    uint n_ = (n), total_ = subgroupAdd(n_), base_ = 0u;                        \
    if (subgroupElect() && total_ > 0u) base_ = atomicAdd(COUNTER, total_);     \
    result = subgroupBroadcastFirst(base_) + subgroupExclusiveAdd(n_);          \
  }

// Adds `n` to a per-view counter: one atomic per subgroup when the subgroup is on one view.
#define VIEW_COUNTER_ADD(FIELD, view, n)                                         \
  {                                                                             \
    uint n_ = (n);                                                              \
    if (subgroupAllEqual(view)) {                                               \
      uint total_ = subgroupAdd(n_);                                            \
      if (subgroupElect() && total_ > 0u) atomicAdd(counters[view].FIELD, total_); \
    } else if (n_ > 0u) {                                                       \
      atomicAdd(counters[view].FIELD, n_);                                      \
    }                                                                           \
  }

// The plane masks of a band walk: 6 bits per level of the band (MAX_FRUSTUM_PLANES planes).
uint band_mask(uvec2 masks, uint level) {
  return level < 5u ? (masks.x >> (6u * level)) & 63u : (masks.y >> (6u * (level - 5u))) & 63u;
}
uvec2 with_band_mask(uvec2 masks, uint level, uint mask) {
  if (level < 5u) masks.x = (masks.x & ~(63u << (6u * level))) | (mask << (6u * level));
  else masks.y = (masks.y & ~(63u << (6u * (level - 5u)))) | (mask << (6u * (level - 5u)));
  return masks;
}

// Tests one node per invocation (when `has_node`) on the planes in `mask`, adds its node and
// object tests to `tests_made`, and appends what the node asks for except its children: INTERSECTING leaf: a test of each
// object on the planes it straddles; INSIDE: its object range, as full chunks for ACCEPT (one
// full workgroup each) and the remainder in the dense TEST list with an empty plane mask
// (accepted there without a test), so no workgroup runs mostly idle on a small subtree.
// Returns whether the node is an INTERSECTING inner node (its children must be visited, with
// `straddled`), and its second child. Called in uniform control flow.
bool test_node(bool has_node, uint index, uint view, uvec2 masks, uint band_top, out uint straddled, out uint second_child,
               out uint skip, out uint band_level, inout uvec2 tests_made) {
  uint c = CLASS_OUTSIDE;
  straddled = 0u;
  GpuBvhNode node;
  node.first = 0u;
  node.count = 0u;
  node.leaf = 1u;
  node.second_child = 0u;
  node.skip = 0u;
  node.depth = band_top;
  if (has_node) {
    node = load_node(index);
    c = classify_node(node.box_min, node.box_max, band_mask(masks, node.depth - band_top), straddled);
  }
  second_child = node.second_child;
  skip = node.skip;
  band_level = node.depth - band_top;
  uint tests_wanted = 0u, full = 0u, object_tests = 0u;
  if (c == CLASS_INTERSECTING && node.leaf != 0u) {
    tests_wanted = object_tests = node.count;
  } else if (c == CLASS_INSIDE) {
    full = node.count / gl_WorkGroupSize.x;
    tests_wanted = node.count - full * gl_WorkGroupSize.x;
  }
  tests_made += uvec2(has_node ? 1u : 0u, object_tests);
  uint test_base, range_base;
  SUBGROUP_APPEND(state.test_count, tests_wanted, test_base)
  SUBGROUP_APPEND(state.range_count, full, range_base)
  if (test_base + tests_wanted > params.test_capacity || range_base + full > params.range_capacity) {
    note_overflow();  // writes nothing (stays in uniform control flow)
    tests_wanted = full = 0u;
  }
  // The accepted chunks' objects are visible and INSIDE: their list slots are reserved now, so
  // ACCEPT writes them without atomics.
  uint accepted = full * gl_WorkGroupSize.x, slot_base = 0u;
  if (subgroupAllEqual(view)) {
    uint total = subgroupAdd(accepted), base = 0u;
    if (subgroupElect() && total > 0u) {
      base = atomicAdd(counters[view].visible_count, total);
      atomicAdd(counters[view].inside_count, total);
    }
    slot_base = subgroupBroadcastFirst(base) + subgroupExclusiveAdd(accepted);
  } else if (accepted > 0u) {
    slot_base = atomicAdd(counters[view].visible_count, accepted);
    atomicAdd(counters[view].inside_count, accepted);
  }
  // Test entries and chunks are written by the whole subgroup, lane by lane: a lane with many
  // (an INSIDE subtree's remainder, a large accepted range) does not keep the others idle.
  uint view_mask = (view << BVH_MASK_BITS) | (c == CLASS_INSIDE ? 0u : straddled);
  uint first_test = node.first + full * gl_WorkGroupSize.x;
  uvec4 writers = subgroupBallot(tests_wanted + full != 0u);
  for (uint w = subgroupBallotBitCount(writers); w > 0u; --w) {
    uint lane = subgroupBallotFindLSB(writers);
    writers[lane / 32u] &= ~(1u << (lane % 32u));
    uint n_tests = subgroupShuffle(tests_wanted, lane), n_full = subgroupShuffle(full, lane);
    uint lane_test_base = subgroupShuffle(test_base, lane), lane_first_test = subgroupShuffle(first_test, lane);
    uint lane_view_mask = subgroupShuffle(view_mask, lane);
    for (uint k = gl_SubgroupInvocationID; k < n_tests; k += gl_SubgroupSize)
      tests[lane_test_base + k] = BvhWorkItem(lane_first_test + k, lane_view_mask);
    uint lane_range_base = subgroupShuffle(range_base, lane), lane_first = subgroupShuffle(node.first, lane);
    uint lane_slot = subgroupShuffle(slot_base, lane);
    for (uint k = gl_SubgroupInvocationID; k < n_full; k += gl_SubgroupSize)
      ranges[lane_range_base + k] = BvhRange(lane_first + k * gl_WorkGroupSize.x, gl_WorkGroupSize.x, lane_view_mask >> BVH_MASK_BITS,
                                             lane_slot + k * gl_WorkGroupSize.x);
  }
  return c == CLASS_INTERSECTING && node.leaf == 0u;
}

// Queues the children of the nodes that asked (`pair` holds their first child and second
// child; both get `mask`), one atomic per subgroup.
void push_children(bool wanted, uvec2 pair, uint view, uint mask, uint half_out) {
  uint base;
  SUBGROUP_APPEND(state.queue_count[half_out], wanted ? 2u : 0u, base)
  if (!wanted) return;
  if (base + 2u > params.queue_capacity) {
    note_overflow();
    return;
  }
  uint view_mask = (view << BVH_MASK_BITS) | mask;
  queue[half_out * params.queue_capacity + base] = BvhWorkItem(pair.x, view_mask);
  queue[half_out * params.queue_capacity + base + 1u] = BvhWorkItem(pair.y, view_mask);
}

// BVH_LEVELS_PER_DISPATCH tree levels per dispatch: each invocation walks its item's node's
// subtree that many levels deep; the next level's nodes are queued.
void visit(bool has_item, uint i, uint half_out) {
  uint view = 0u, index = 0u, mask = 0u;
  if (has_item) {
    BvhWorkItem item = queue[(half_out ^ 1u) * params.queue_capacity + i];
    view = item.view_mask >> BVH_MASK_BITS;
    index = item.index;
    mask = item.view_mask & MASK;
  }
  load_view(view);
  // The walk: depth first through the item's subtree, one node per lane per step, in
  // subgroup-uniform steps (test_node and push_children use subgroup operations). A node in
  // the band's last level that is INTERSECTING queues its children; a node above it descends
  // with its straddled planes as its children's mask.
  uint end = 0u, band_top = 0u;
  if (has_item) {
    uvec4 links = texelFetch(nodes, int(3u * index + 2u));  // skip, second child, leaf, depth
    end = links.x;
    band_top = links.w;
  }
  uvec2 masks = uvec2(mask & 63u, 0u);
  uint node = index;
  bool walking = has_item;
  uvec2 tests_made = uvec2(0u);  // node tests, object tests
  while (subgroupAny(walking)) {
    uint straddled, second, skip, level;
    bool descend = test_node(walking, node, view, masks, band_top, straddled, second, skip, level, tests_made);
    bool deeper = descend && level + 1u < BVH_LEVELS_PER_DISPATCH;
    push_children(descend && !deeper, uvec2(node + 1u, second), view, straddled, half_out);
    if (walking) {
      masks = deeper ? with_band_mask(masks, level + 1u, straddled) : masks;
      node = deeper ? node + 1u : skip;
      walking = node != end;
    }
  }
  VIEW_COUNTER_ADD(node_tests, view, tests_made.x)
  VIEW_COUNTER_ADD(object_tests, view, tests_made.y)
}

shared bool last_group;

void level() {
  uint i = flat_group() * gl_WorkGroupSize.x + gl_LocalInvocationIndex;
  uint half_in = params.level & 1u, half_out = half_in ^ 1u;
  visit(i < state.level.items, i, half_out);
  // The last workgroup to finish prepares the next level: every workgroup's queue updates are
  // made visible before it counts itself done.
  memoryBarrierBuffer();
  barrier();
  if (gl_LocalInvocationIndex == 0u)
    last_group = atomicAdd(state.groups_done, 1u) == gl_NumWorkGroups.x * gl_NumWorkGroups.y - 1u;
  barrier();
  if (last_group && gl_LocalInvocationIndex == 0u) {
    memoryBarrierBuffer();
    // This level's output half becomes the next input; its input half is emptied for the
    // next level's output.
    uint items = min(atomicOr(state.queue_count[half_out], 0u), params.queue_capacity);
    if (atomicOr(state.overflow, 0u) != 0u) items = 0u;  // after an overflow, stop: queues may have holes
    state.level = dispatch_for((items + gl_WorkGroupSize.x - 1u) / gl_WorkGroupSize.x, items);
    state.queue_count[half_in] = 0u;
    state.groups_done = 0u;
  }
}

void finish() {
  if (gl_LocalInvocationIndex != 0u) return;
  // A level queue left non-empty means the tree is deeper than the levels recorded.
  if (state.level.items != 0u) note_overflow();
  // After an overflow the lists may have holes: run nothing more (the host reports it).
  bool ok = state.overflow == 0u;
  uint chunks = ok ? min(state.range_count, params.range_capacity) : 0u;
  state.accept = dispatch_for(min(chunks, BVH_ACCEPT_MAX_GROUPS), chunks);
  uint objects = ok ? min(state.test_count, params.test_capacity) : 0u;
  state.test = dispatch_for((objects + gl_WorkGroupSize.x - 1u) / gl_WorkGroupSize.x, objects);
}

void accept() {
  // Every chunk is full (one object per invocation) and its slots are reserved: no atomics.
  uint groups = gl_NumWorkGroups.x * gl_NumWorkGroups.y;
  for (uint chunk = flat_group(); chunk < state.accept.items; chunk += groups) {  // uniform across the workgroup
    BvhRange range = ranges[chunk];
    if (gl_LocalInvocationIndex < range.count)
      emit_visible(range.view, object_ids[range.first + gl_LocalInvocationIndex], range.slot + gl_LocalInvocationIndex, CLASS_INSIDE);
  }
}

void test() {
  uint i = flat_group() * gl_WorkGroupSize.x + gl_LocalInvocationIndex;
  bool in_list = i < state.test.items;
  BvhWorkItem item = BvhWorkItem(0u, 0u);
  if (in_list) item = tests[i];
  uint view = item.view_mask >> BVH_MASK_BITS, object = 0u, c = CLASS_OUTSIDE;
  load_view(view);
  if (in_list) {
    object = object_ids[item.index];
    uint mask = item.view_mask & MASK;
    // An empty mask: an object of an INSIDE subtree, accepted without a test.
    c = mask == 0u ? CLASS_INSIDE : classify_object(item.index, mask);
  }
  // emit_visible writes the visible objects' classes; the others stay OUTSIDE, as the host
  // filled the buffer.
  bool visible = c != CLASS_OUTSIDE;
  if (subgroupAllEqual(view)) {  // the usual case: one atomic per subgroup
    uvec4 ballot = subgroupBallot(visible);
    uint total = subgroupBallotBitCount(ballot);
    uint inside_total = subgroupBallotBitCount(subgroupBallot(c == CLASS_INSIDE));
    uint base = 0u;
    if (subgroupElect() && total > 0u) {
      base = atomicAdd(counters[view].visible_count, total);
      atomicAdd(counters[view].inside_count, inside_total);
    }
    base = subgroupBroadcastFirst(base);
    if (visible) emit_visible(view, object, base + subgroupBallotExclusiveBitCount(ballot), c);
  } else if (visible) {
    uint slot = atomicAdd(counters[view].visible_count, 1u);
    if (c == CLASS_INSIDE) atomicAdd(counters[view].inside_count, 1u);
    emit_visible(view, object, slot, c);
  }
}

void main() {
  if (PASS == BVH_PASS_SEED) seed();
  else if (PASS == BVH_PASS_LEVEL) level();
  else if (PASS == BVH_PASS_FINISH) finish();
  else if (PASS == BVH_PASS_ACCEPT) accept();
  else test();
}
