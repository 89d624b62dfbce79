#version 460
// Hierarchical frustum culling of a depth-first BVH in one dispatch. The host cuts the tree
// into subtrees of at most BvhCuller::subtree_objects() objects and BVH_CUT_MAX_HEIGHT levels
// below their root (the highest nodes that fit, and leaves); a workgroup is one subgroup and
// takes consecutive cut subtrees of one view, one per invocation:
//   1. each invocation descends from the root to its cut node, testing each node on the path
//      on the planes its parent straddles (plane masking, Assarsson & Moller 2000); an OUTSIDE
//      node ends its work, an INSIDE one accepts the cut subtree's whole object range.
//      Invocations whose cut nodes share an ancestor all test it (same answer); only the one
//      whose cut node is its first-child descendant counts the test, so every node test is
//      counted once;
//   2. the subgroup walks its cut subtrees together: their nodes go on one stack (in shared
//      memory, or with STACK_IN_RECORDS in the records image), and each round every
//      invocation takes one (the subgroup's lanes stay busy however unevenly the work is
//      spread over its subtrees, where walking one subtree per invocation would leave the
//      lanes of the small ones idle). OUTSIDE drops a node, INSIDE records its object range,
//      an INTERSECTING inner node pushes its two children with the planes it straddles, an
//      INTERSECTING leaf lists its objects in chunks of at most BVH_CHUNK_OBJECTS, one record
//      each;
//   3. each lane takes a listed chunk and tests its objects, one per round, on the planes the
//      leaf straddles (boxes first by their centre bound, then in full those it leaves open),
//      and rewrites the chunk's record with a bit per visible and per INSIDE object;
//   4. the subgroup reserves the list slots of all its visible objects with one atomic per
//      counter and writes them: the accepted ranges, one object per lane, then each lane a
//      chunk's visible objects.
// Records go to the workgroup's own slice of a scratch image (its cut subtrees' object
// ranges, which are adjacent: one record per accepted range or listed chunk, so they fit), so
// the walk needs no global atomics and no work queues. (On lavapipe every branch runs under a
// mask and only loops skip work, so a lane's work in a round is the whole round's; every
// load or store of a storage buffer or shared memory is a loop over the lanes, and a load or a
// scan builds its result lane by lane through the stack (see exclusive_count), which is why a
// leaf is listed as chunks, not objects: a record per chunk, not one per object.)
// With OCCLUSION, every node the frustum keeps is also tested against the depth pyramid
// (shared/occlusion.glsl, with a node's wider margins): below an occluded node nothing more is
// tested for occlusion, and what the frustum keeps there is OCCLUDED (an INSIDE node's range
// as one record, flagged); an INSIDE node that is not occluded is walked on with no planes, so
// that its objects get their own occlusion test, as do the kept objects of listed chunks.
// The result equals src/cullpipe/bvh cull_hierarchical bit for bit (with OCCLUSION,
// occlusion::cull_hierarchical): same p/n-vertex test, distances as
// ((n.x*p.x + n.y*p.y) + n.z*p.z) + d marked `precise`, same masks, the same occlusion tests,
// and the same counts of node and object tests.
#extension GL_GOOGLE_include_directive : require
#extension GL_KHR_shader_subgroup_basic : require
#extension GL_KHR_shader_subgroup_ballot : require
#extension GL_KHR_shader_subgroup_arithmetic : require
#extension GL_KHR_shader_subgroup_shuffle : require
#extension GL_EXT_control_flow_attributes : require

#include "cullpipe/gpu/cull_types.h"

layout(local_size_x_id = 1) in;  // the device's subgroup size, at most BVH_CULL_GROUP_SIZE, set by the host

// A listed leaf's objects go to records in chunks of at most BVH_CHUNK_OBJECTS (16): (first
// slot, planes to test | CHUNK_HIDDEN if an ancestor is occluded | (objects - 1) <<
// CHUNK_SIZE_SHIFT), then, once tested, (first slot, visible bits | (INSIDE or OCCLUDED) bits <<
// BVH_CHUNK_OBJECTS: an OCCLUDED object has its second bit without its first). A chunk's record
// is read and rewritten by one lane only (the same lane in steps 3 and 4), so no lane reads
// another's record there. An accepted range's record is (first slot, count | RANGE_HIDDEN for a
// range of OCCLUDED objects).
const uint BVH_CHUNK_OBJECTS = 16u, CHUNK_SIZE_SHIFT = 8u, CHUNK_BITS = (1u << BVH_CHUNK_OBJECTS) - 1u;
const uint CHUNK_HIDDEN = 1u << 6u, RANGE_HIDDEN = 1u << 31u;
layout(constant_id = 2) const uint BV_KIND = BV_KIND_AABB;  // the node margin and the object test
layout(constant_id = 3) const uint WRITE_DRAWS = 0;  // also write draw commands
// 1: write each visible object's class. A specialization constant, since on lavapipe a store
// behind an `if` that is false on every lane still runs its loop over the lanes: switched off
// by a push constant, the class store would still cost its loop on every pass.
layout(constant_id = 4) const uint WRITE_CLASSES = 1;
// 1 (CPU devices): the walk stacks live in the records image, past the objects' records, a
// slice per workgroup, instead of in shared memory: lavapipe inserts each lane's shared-memory
// word through the stack (a stall per lane), where an image load gathers. GPUs keep shared
// memory.
layout(constant_id = 5) const uint STACK_IN_RECORDS = 0;
layout(constant_id = 6) const uint OCCLUSION = 0;  // 1: test the kept nodes and objects against the pyramid

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
// subgroupMemoryBarrierImage() and subgroupBarrier(). A storage texel buffer, not a storage
// buffer: lavapipe gathers an image load's lanes into a vector, where it inserts each lane's
// storage-buffer words through the stack (a failed store forwarding per lane and word).
layout(set = 0, binding = BVH_BINDING_RECORDS, rg32ui) uniform coherent uimageBuffer records;
uvec2 record_at(uint at) { return imageLoad(records, int(at)).xy; }
void set_record(uint at, uvec2 record) { imageStore(records, int(at), uvec4(record, 0u, 0u)); }
// AABBs: per object in tree order xyz = centre, w = bound (src/cullpipe/geom/plane_bounds.hpp), as the
// flat pass's BINDING_CENTRES.
layout(set = 0, binding = BVH_BINDING_CENTRES) uniform usamplerBuffer centres;
layout(std430, set = 0, binding = BVH_BINDING_PYRAMID) readonly buffer Pyramid { float pyramid[]; };
layout(set = 0, binding = BVH_BINDING_OCCLUSION_VIEWS) uniform usamplerBuffer occlusion_views;  // GpuOcclusionView per view

layout(push_constant, std430) uniform Push { BvhCullParams params; };

// Prefix sums over the subgroup from ballots: lavapipe builds an exclusive scan's result lane by
// lane through the stack (a vector stored, one lane written, the vector reloaded: a failed
// store-to-load forwarding per lane), where a ballot and a bit count only read lanes.
// The number of lower lanes where p holds, and (total) of all lanes.
uint exclusive_count(bool p, out uint total) {
  uvec4 bits = subgroupBallot(p);
  total = subgroupBallotBitCount(bits);
  return subgroupBallotExclusiveBitCount(bits);
}
// The sum of x over the lower lanes, and (total) over all: a ballot per bit of the largest x.
uint exclusive_sum(uint x, out uint total) {
  uint below = 0u, b = 0u;
  total = 0u;
  for (uint largest = subgroupMax(x); largest != 0u; largest >>= 1u, ++b) {
    uvec4 bits = subgroupBallot(((x >> b) & 1u) != 0u);
    below += subgroupBallotExclusiveBitCount(bits) << b;
    total += subgroupBallotBitCount(bits) << b;
  }
  return below;
}

GpuBvhNode load_node(uint index) {
  uvec4 a = texelFetch(nodes, int(3u * index)), b = texelFetch(nodes, int(3u * index + 1u)), c = texelFetch(nodes, int(3u * index + 2u));
  return GpuBvhNode(uintBitsToFloat(a.xyz), a.w, uintBitsToFloat(b.xyz), b.w, c.x, c.y, c.z, c.w);
}

vec4 volume_word(uint word) { return uintBitsToFloat(texelFetch(boxes, int(word))); }
vec4 occ_volume_word(uint word) { return volume_word(word); }
// The first word of the volume at tree-order slot `slot`.
uint volume_first_word(uint slot) {
  return BV_KIND == BV_KIND_AABB ? AABB_VEC4S * slot : BV_KIND == BV_KIND_OBB ? OBB_VEC4S * slot : SPHERE_VEC4S * slot;
}

// The id of the object at tree-order slot `slot`.
uint object_at(uint slot) {
  uvec4 t = texelFetch(object_order, int(slot >> 2u));
  uint c = slot & 3u;
  return c == 0u ? t.x : c == 1u ? t.y : c == 2u ? t.z : t.w;
}

// The workgroup's view: its planes, loaded once into registers (the view is uniform across
// the workgroup: plain loads).
uint view_plane_count;
float view_settle_margin;  // GpuFrustum::settle_margin
vec4 view_planes[MAX_FRUSTUM_PLANES];

#include "shared/classify.glsl"
#include "shared/occlusion.glsl"

void load_view(uint view) {
  int first = int(FRUSTUM_TEXELS * view);
  uvec4 tail = texelFetch(views, first + int(MAX_FRUSTUM_PLANES));
  view_plane_count = min(tail.x, MAX_FRUSTUM_PLANES);
  view_settle_margin = uintBitsToFloat(tail.y);
  [[unroll]] for (uint k = 0; k < MAX_FRUSTUM_PLANES; ++k) view_planes[k] = uintBitsToFloat(texelFetch(views, first + int(k)));
  if (OCCLUSION != 0u) occ_load_view(view);
}

// A box's class on the planes in `mask` from its centre and bound alone where they settle it
// (the flat pass's settle_object, on a leaf's straddled planes): with reach = bound + the view's
// margin, the smallest centre distance s over the tested planes below -reach is OUTSIDE, at least
// reach INSIDE on them, else CLASS_OPEN (the full test). Proof: docs/numerics.md, Settling bounds.
// A NaN or infinite bound or margin settles nothing (decided on the bits).
const uint CLASS_OPEN = 4u;  // (not a class any pass writes)
uint settle_box(uint slot, uint mask) {
  vec4 centre_bound = uintBitsToFloat(texelFetch(centres, int(slot)));
  bool usable = finite_bits(centre_bound.w) && finite_bits(view_settle_margin);
  float reach = centre_bound.w + view_settle_margin;
  float m = uintBitsToFloat(0x7f7fffffu);  // the largest float: no tested plane (a leaf listed only for occlusion)
  [[unroll]] for (uint k = 0; k < MAX_FRUSTUM_PLANES; ++k)
    m = plane_tested(k, mask) ? min(m, plane_distance(view_planes[k], centre_bound.xyz)) : m;
  return !usable ? CLASS_OPEN : m < -reach ? CLASS_OUTSIDE : m >= reach ? CLASS_INSIDE : CLASS_OPEN;
}

// The node test of hierarchies over OBBs and spheres (bvh::classify_masked_margin): a plane
// decides a node only beyond a margin of 2^-16 x (reach + |d|) + 2^-120, reach = the sum over
// axes of the box's largest |coordinate|; past reach + |d| = 2^120 it decides nothing. Evaluated
// in the host's order. Proof: docs/numerics.md, BVH node margins.
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

// Writes a visible object's outputs: class, list slot, draw.
void emit_visible(uint view, uint object, uint slot, uint c) {
  if (WRITE_CLASSES != 0) classes[view * object_count + object] = c;
  if (slot < visible_capacity) {
    visible_ids[view * visible_capacity + slot] = object;
    if (WRITE_DRAWS != 0) {
      DrawCommand d = templates[object];
      d.object_id = object;
      draws[view * visible_capacity + slot] = d;
    }
  }
}

// The walk's stack (in shared memory, or with STACK_IN_RECORDS in the records image),
// BVH_STACK_PER_INVOCATION entries per invocation: (node - the workgroup's
// first cut node) << BVH_STACK_MASK_BITS | STACK_HIDDEN if an ancestor is occluded | planes to
// test, one word (the host checks that a workgroup's nodes span fewer than 2^25:
// BvhCuller::upload). One word, not a pair: lavapipe inserts each lane's loaded word into the
// result through the stack (a stall per lane and word), so a second word per entry would add a
// stall per lane.
const uint BVH_STACK_MASK_BITS = 7u, STACK_HIDDEN = 1u << 6u;
shared uint walk_stack[gl_WorkGroupSize.x * BVH_STACK_PER_INVOCATION];
uint stack_base;  // STACK_IN_RECORDS: this workgroup's stack in the records image
uint stack_load(uint i) { return STACK_IN_RECORDS != 0 ? imageLoad(records, int(stack_base + i)).x : walk_stack[i]; }
void stack_store(uint i, uint word) {
  if (STACK_IN_RECORDS != 0) imageStore(records, int(stack_base + i), uvec4(word, 0u, 0u, 0u));
  else walk_stack[i] = word;
}

void main() {
  // Workgroups are view-major and never straddle views (groups_per_view per view); larger
  // dispatches fold into y, and the groups past the last view return.
  uint group = gl_WorkGroupID.y * gl_NumWorkGroups.x + gl_WorkGroupID.x;
  uint view = group / params.groups_per_view;
  if (view >= params.view_count) return;
  object_count = params.object_count;
  visible_capacity = params.visible_capacity;
  uint i = (group - view * params.groups_per_view) * gl_WorkGroupSize.x + gl_LocalInvocationIndex;
  bool has_cut = i < params.cut_count;
  load_view(view);

  uint cut = has_cut ? cuts[params.cut_offset + i] : 0u;
  uvec4 cut_lo = texelFetch(nodes, int(3u * cut)), cut_hi = texelFetch(nodes, int(3u * cut + 1u));
  uvec4 cut_links = texelFetch(nodes, int(3u * cut + 2u));  // skip, second child, leaf, depth
  uint cut_first = cut_lo.w, cut_count = has_cut ? cut_hi.w : 0u, cut_depth = cut_links.w;
  uint mask = (1u << view_plane_count) - 1u;
  uvec2 tests = uvec2(0u);  // node tests, object tests (counted as src/cullpipe/bvh counts them)

  // 1. From the root down to the cut node.
  bool walk = has_cut, accept_all = false, descending = has_cut && cut != 0u;
  bool hidden = false;  // OCCLUSION: a node on the way down is occluded
  uint node = 0u;
  while (descending) {
    GpuBvhNode n = load_node(node);
    uint straddled;
    uint c = classify_node(n.box_min, n.box_max, mask, straddled);
    if (cut - node == cut_depth - n.depth) tests.x += 1u;  // the cut node is its first-child descendant
    if (OCCLUSION != 0u && c != CLASS_OUTSIDE && !hidden) hidden = occ_node_occluded(n.box_min, n.box_max);
    // OUTSIDE ends the walk, as does INSIDE unless its objects still need an occlusion test.
    if (c == CLASS_OUTSIDE || (c == CLASS_INSIDE && (OCCLUSION == 0u || hidden))) {
      walk = false;
      accept_all = c == CLASS_INSIDE;
      descending = false;
    } else {
      mask = straddled;
      node = cut >= n.second_child ? n.second_child : node + 1u;
      descending = node != cut;
    }
  }

  // 2. The cut subtrees, by the whole subgroup. The workgroup's slice of the scratch: its cut
  // subtrees' objects, adjacent in tree order; accepted ranges from its front, listed chunks
  // from its back (rewritten in place once tested).
  uint lanes;
  uint rank = exclusive_count(true, lanes);
  uint slice_first = subgroupMin(has_cut ? cut_first : 0xffffffffu), slice_end = subgroupMax(has_cut ? cut_first + cut_count : 0u);
  uint base = view * object_count + slice_first, back = view * object_count + slice_end - 1u;
  uint ranges = 0u, listed = 0u;  // records at the front and back, subgroup-wide
  uint accepted = 0u;             // objects in this invocation's accepted ranges
  uint hidden_accepted = 0u;      // objects in its ranges of OCCLUDED objects
  // A cut INSIDE by an ancestor is accepted whole (OCCLUDED when an ancestor is occluded).
  uint take_all = accept_all && cut_count != 0u ? 1u : 0u;
  uint take_all_count;
  uint take_all_at = exclusive_count(take_all != 0u, take_all_count);
  if (take_all != 0u) set_record(base + take_all_at, uvec2(cut_first, cut_count | (hidden ? RANGE_HIDDEN : 0u)));
  ranges += take_all_count;
  accepted += take_all != 0u && !hidden ? cut_count : 0u;
  hidden_accepted += take_all != 0u && hidden ? cut_count : 0u;
  // The walk. The stack holds at most BVH_STACK_PER_INVOCATION entries per lane: it stays
  // sorted by depth below the cut (each round takes its top entries, in order, and pushes their
  // children in that order, one level deeper than any entry left), and a round that takes an
  // entry of depth d - 1 has taken every entry of depth >= d, so the entries of depth d all come
  // from that one round: at most 2 x lanes of them, for depths 1..BVH_CUT_MAX_HEIGHT, and the
  // cut nodes (depth 0) at most one per lane.
  uint node_base = subgroupMin(has_cut ? cut : 0xffffffffu);  // (the first lane has a cut)
  uint top;
  uint push0_at = exclusive_count(walk, top);
  stack_base = params.object_count * params.view_count + group * gl_WorkGroupSize.x * BVH_STACK_PER_INVOCATION;
  if (walk) stack_store(push0_at, (cut - node_base) << BVH_STACK_MASK_BITS | (hidden ? STACK_HIDDEN : 0u) | mask);
  subgroupMemoryBarrierShared();
  subgroupMemoryBarrierImage();
  subgroupBarrier();
  while (top != 0u) {
    uint take = min(top, lanes);
    bool live = rank < take;
    uint word = stack_load(top - take + min(rank, take - 1u));
    uvec2 entry = uvec2(node_base + (word >> BVH_STACK_MASK_BITS), word & ALL_PLANES);
    bool entry_hidden = (word & STACK_HIDDEN) != 0u;
    top -= take;
    subgroupMemoryBarrierShared();  // every lane has read its entry before any lane pushes
    subgroupMemoryBarrierImage();
    subgroupBarrier();
    GpuBvhNode n = load_node(entry.x);
    uint straddled;
    uint c = classify_node(n.box_min, n.box_max, entry.y, straddled);
    c = live ? c : CLASS_OUTSIDE;
    tests.x += live ? 1u : 0u;
    bool node_hidden = entry_hidden;
    if (OCCLUSION != 0u && c != CLASS_OUTSIDE && !entry_hidden) node_hidden = occ_node_occluded(n.box_min, n.box_max);
    // INTERSECTING opens a node, and so does INSIDE when its objects still need an occlusion
    // test (then straddled is empty).
    bool open = c == CLASS_INTERSECTING || (OCCLUSION != 0u && c == CLASS_INSIDE && !node_hidden);
    uint carried = straddled | (node_hidden ? STACK_HIDDEN : 0u);  // (CHUNK_HIDDEN is the same bit)
    bool push = open && n.leaf == 0u;
    uint pushers;
    uint at = top + 2u * exclusive_count(push, pushers);
    if (push) {
      stack_store(at, (entry.x + 1u - node_base) << BVH_STACK_MASK_BITS | carried);
      stack_store(at + 1u, (n.second_child - node_base) << BVH_STACK_MASK_BITS | carried);
    }
    top += 2u * pushers;
    bool range = c == CLASS_INSIDE && !open && n.count != 0u;
    uint range_count;
    uint range_at = ranges + exclusive_count(range, range_count);
    if (range) set_record(base + range_at, uvec2(n.first, n.count | (node_hidden ? RANGE_HIDDEN : 0u)));
    ranges += range_count;
    accepted += range && !node_hidden ? n.count : 0u;
    hidden_accepted += range && node_hidden ? n.count : 0u;
    uint list = open && n.leaf != 0u ? n.count : 0u;
    uint chunks = (list + BVH_CHUNK_OBJECTS - 1u) / BVH_CHUNK_OBJECTS;
    uint chunk_total;
    uint chunk_at = listed + exclusive_sum(chunks, chunk_total);
    for (uint j = 0u; j < chunks; ++j) {
      uint size = min(BVH_CHUNK_OBJECTS, list - BVH_CHUNK_OBJECTS * j);
      set_record(back - (chunk_at + j), uvec2(n.first + BVH_CHUNK_OBJECTS * j, carried | (size - 1u) << CHUNK_SIZE_SHIFT));
    }
    listed += chunk_total;
    tests.y += list;
    subgroupMemoryBarrierShared();  // the pushes, for the next round
    subgroupMemoryBarrierImage();
    subgroupBarrier();
  }

  // 3. The listed chunks, a lane each: its objects tested one per round (as many rounds as
  // the largest of the subgroup's chunks has objects), and the chunk's record rewritten in
  // place with the objects found visible and INSIDE, a bit each. A lane without a chunk
  // tests the slice's first object, and the answer is dropped.
  subgroupMemoryBarrierImage();
  subgroupBarrier();
  uint tested_visible = 0u, tested_inside = 0u, tested_occluded = 0u;  // this lane's
  for (uint first = 0u; first < listed; first += lanes) {
    bool live = first + rank < listed;
    uint at = back - (first + rank);
    uvec2 chunk = uvec2(slice_first, 0u);
    if (live) chunk = record_at(at);
    uint size = live ? (chunk.y >> CHUNK_SIZE_SHIFT) + 1u : 0u, mask = chunk.y & ALL_PLANES;
    uint visible_bits = 0u, inside_bits = 0u;
    uint rounds = subgroupMax(size);
    if (BV_KIND == BV_KIND_AABB) {
      // Boxes: settled by their centre bound, one texel each, then the full test of those left
      // open (near a plane), one per lane per round: on lavapipe a round costs what its most
      // expensive lane does, and most of a straddling leaf's boxes settle.
      uint open = 0u;
      for (uint k = 0u; k < rounds; ++k) {
        uint object_class = settle_box(chunk.x + min(k, max(size, 1u) - 1u), mask);
        uint bit = k < size ? 1u << k : 0u;
        visible_bits |= object_class != CLASS_OUTSIDE ? bit : 0u;
        inside_bits |= object_class == CLASS_INSIDE ? bit : 0u;
        open |= object_class == CLASS_OPEN ? bit : 0u;
      }
      while (open != 0u) {
        uint k = uint(findLSB(open));
        open &= open - 1u;
        uint object_class = classify_object(chunk.x + k, mask);
        visible_bits &= object_class == CLASS_OUTSIDE ? ~(1u << k) : ~0u;
        inside_bits |= object_class == CLASS_INSIDE ? 1u << k : 0u;
      }
    } else {
      for (uint k = 0u; k < rounds; ++k) {
        uint object_class = classify_object(chunk.x + min(k, max(size, 1u) - 1u), mask);
        if (k < size && object_class != CLASS_OUTSIDE) visible_bits |= 1u << k;
        if (k < size && object_class == CLASS_INSIDE) inside_bits |= 1u << k;
      }
    }
    // The kept objects against the pyramid, one per lane per round; all of them OCCLUDED below
    // an occluded node.
    uint occluded_bits = 0u;
    if (OCCLUSION != 0u) {
      bool chunk_hidden = (chunk.y & CHUNK_HIDDEN) != 0u;
      occluded_bits = chunk_hidden ? visible_bits : 0u;
      uint pending = chunk_hidden ? 0u : visible_bits;
      while (pending != 0u) {
        uint k = uint(findLSB(pending));
        pending &= pending - 1u;
        if (occ_volume_occluded(volume_first_word(chunk.x + k))) occluded_bits |= 1u << k;
      }
      visible_bits &= ~occluded_bits;
      inside_bits &= ~occluded_bits;
    }
    tested_visible += bitCount(visible_bits);
    tested_inside += bitCount(inside_bits);
    tested_occluded += bitCount(occluded_bits);
    if (live) set_record(at, uvec2(chunk.x, visible_bits | (inside_bits | occluded_bits) << BVH_CHUNK_OBJECTS));
  }

  // 4. The list slots and the counts: one global atomic per subgroup and counter, no
  // workgroup barrier (as the flat pass: on lavapipe each barrier suspends and resumes every
  // subgroup's coroutine).
  uint subgroup_accepted = subgroupAdd(accepted);
  uint subgroup_visible = subgroup_accepted + subgroupAdd(tested_visible), subgroup_inside = subgroup_accepted + subgroupAdd(tested_inside);
  uint node_tests = subgroupAdd(tests.x), object_tests = subgroupAdd(tests.y);
  uint subgroup_occluded = OCCLUSION != 0u ? subgroupAdd(hidden_accepted + tested_occluded) : 0u;
  uint subgroup_base = 0u;
  if (subgroupElect()) {
    if (subgroup_visible != 0u) {
      subgroup_base = atomicAdd(counters[view].visible_count, subgroup_visible);
      atomicAdd(counters[view].inside_count, subgroup_inside);
    }
    if (node_tests != 0u) atomicAdd(counters[view].node_tests, node_tests);
    if (object_tests != 0u) atomicAdd(counters[view].object_tests, object_tests);
    if (subgroup_occluded != 0u) atomicAdd(counters[view].occluded_count, subgroup_occluded);
  }
  uint slot = subgroupBroadcastFirst(subgroup_base);
  // The accepted ranges (every object INSIDE, or OCCLUDED: a class each and no slot), then the
  // tested visible objects.
  for (uint r = 0u; r < ranges; ++r) {
    uvec2 range = record_at(base + r);
    if ((range.y & RANGE_HIDDEN) != 0u) {
      if (WRITE_CLASSES != 0u)
        for (uint k = rank; k < (range.y & ~RANGE_HIDDEN); k += lanes) classes[view * object_count + object_at(range.x + k)] = CLASS_OCCLUDED;
      continue;
    }
    for (uint k = rank; k < range.y; k += lanes) emit_visible(view, object_at(range.x + k), slot + k, CLASS_INSIDE);
    slot += range.y;
  }
  for (uint first = 0u; first < listed; first += lanes) {  // the chunks, a lane each (as in step 3)
    bool live = first + rank < listed;
    uvec2 chunk = uvec2(0u);
    if (live) chunk = record_at(back - (first + rank));
    uint bits = chunk.y & CHUNK_BITS;
    uint found = uint(bitCount(bits));
    uint found_total;
    uint lane_slot = slot + exclusive_sum(found, found_total);
    slot += found_total;
    uint rounds = subgroupMax(found);
    for (uint j = 0u; j < rounds; ++j) {
      if (bits != 0u) {
        uint k = uint(findLSB(bits));
        emit_visible(view, object_at(chunk.x + k), lane_slot, ((chunk.y >> (BVH_CHUNK_OBJECTS + k)) & 1u) != 0u ? CLASS_INSIDE : CLASS_INTERSECTING);
        lane_slot += 1u;
        bits &= bits - 1u;
      }
    }
    if (OCCLUSION != 0u && WRITE_CLASSES != 0u) {  // the chunk's OCCLUDED objects: their class
      uint occluded_bits = (chunk.y >> BVH_CHUNK_OBJECTS) & ~chunk.y & CHUNK_BITS;
      while (occluded_bits != 0u) {
        uint k = uint(findLSB(occluded_bits));
        occluded_bits &= occluded_bits - 1u;
        classes[view * object_count + object_at(chunk.x + k)] = CLASS_OCCLUDED;
      }
    }
  }
}
