#version 460
// Flat frustum culling; gl_GlobalInvocationID.y is the view. One dispatch covers all views
// (and a chunk of at most maxComputeWorkGroupCount[0] groups of objects). Classifies each
// object (and writes its class: always in object order, with WRITE_CLASSES in arrival order) and
// counts visible / inside / intersecting objects. Then, by specialization:
// - ORDERED == 0: OBJECTS_PER_INVOCATION objects per invocation; appends visible ids (and, with
//   WRITE_DRAWS, draw commands) to the view's lists in arrival order, one global atomic per
//   subgroup (several objects per invocation: the planes are loaded once for all of them, and
//   the counter's cache line bounces once per subgroup's objects, not per object);
// - ORDERED == 1: the same objects per invocation; writes the classes and each workgroup's
//   visible and INSIDE counts; compact_scan.comp and compact_scatter.comp then write the lists
//   in object order.
// With OCCLUSION, the objects the frustum keeps are tested against the depth pyramid
// (shared/occlusion.glsl) and the hidden ones are OCCLUDED: counted, neither listed nor drawn.
//
// The plane tests, and their bit-exact contract with the CPU reference, are in
// shared/classify.glsl.
#extension GL_GOOGLE_include_directive : require
#extension GL_KHR_shader_subgroup_basic : require
#extension GL_KHR_shader_subgroup_ballot : require
#extension GL_KHR_shader_subgroup_arithmetic : require
#extension GL_KHR_shader_subgroup_shuffle : require
#extension GL_EXT_control_flow_attributes : require

#include "cullpipe/gpu/cull_types.h"

layout(local_size_x_id = 1) in;                 // = FLAT_CULL_GROUP_SIZE, set by the host
layout(constant_id = 0) const uint BV_KIND = BV_KIND_AABB;
layout(constant_id = 2) const uint ORDERED = 0;      // 1: object-order compaction by later passes
layout(constant_id = 3) const uint WRITE_DRAWS = 0;  // 1: also write draw commands (arrival order)
// Objects per invocation in both passes: the planes are loaded once for all of them and the
// visible list takes one atomic per subgroup for all of its objects.
// Object j of an invocation is at block + j * group size, so each step of the loop reads one
// contiguous run of objects per workgroup, and a workgroup covers one contiguous run of
// group size x OBJECTS_PER_INVOCATION objects (the ordered passes' unit).
layout(constant_id = 4) const uint OBJECTS_PER_INVOCATION = 1;
// Arrival order: 1 writes each object's class, 0 (classes not asked for) leaves them out of the
// pipeline. A specialization constant, not a push constant behind an `if`: lavapipe runs both
// sides of every branch under a lane mask, and its storage-buffer store is a loop over the
// lanes either way, so a class store switched off at run time would still cost its loop on
// every pass. The ordered passes always write them.
layout(constant_id = 5) const uint WRITE_CLASSES = 1;
layout(constant_id = 6) const uint OCCLUSION = 0;  // 1: test the kept objects against the pyramid

// The volumes' vec4 words, fetched as integer texels (exact bits) from a uniform texel buffer.
layout(set = 0, binding = BINDING_BOUNDS) uniform usamplerBuffer bounds;
layout(std430, set = 0, binding = BINDING_CLASSES) writeonly buffer Classes { uint classes[]; };
layout(std430, set = 0, binding = BINDING_VISIBLE) writeonly buffer Visible { uint visible_ids[]; };
layout(std430, set = 0, binding = BINDING_COUNTERS) buffer Counters { ViewCounters counters[]; };
layout(set = 0, binding = BINDING_VIEWS) uniform usamplerBuffer views;  // GpuFrustum, FRUSTUM_TEXELS texels each
// AABBs: per object xyz = centre, w = bound (src/cullpipe/geom/plane_bounds.hpp), as integer texels.
layout(set = 0, binding = BINDING_CENTRES) uniform usamplerBuffer centres;
layout(std430, set = 0, binding = BINDING_DRAW_TEMPLATES) readonly buffer DrawTemplates { DrawCommand templates[]; };
layout(std430, set = 0, binding = BINDING_DRAWS) writeonly buffer Draws { DrawCommand draws[]; };
// Ordered: per workgroup, [view][group] visible counts, then [view][group] INSIDE counts.
layout(std430, set = 0, binding = BINDING_GROUP_COUNTS) buffer GroupCounts { uint group_counts[]; };
layout(std430, set = 0, binding = BINDING_PYRAMID) readonly buffer Pyramid { float pyramid[]; };
layout(set = 0, binding = BINDING_OCCLUSION_VIEWS) uniform usamplerBuffer occlusion_views;  // GpuOcclusionView per view

layout(push_constant, std430) uniform Push { FlatCullParams params; };

uint view;             // this invocation's view (gl_WorkGroupID.y)
uint view_plane_count;
float view_settle_margin;  // GpuFrustum::settle_margin
vec4 view_planes[MAX_FRUSTUM_PLANES];
vec4 bound(uint word) { return uintBitsToFloat(texelFetch(bounds, int(word))); }
vec4 occ_volume_word(uint word) { return bound(word); }

#include "shared/classify.glsl"
#include "shared/occlusion.glsl"
#include "shared/ordered_runs.glsl"

uint classify_object(uint i) {
  uint unused;
  if (BV_KIND == BV_KIND_AABB) return classify_aabb(bound(AABB_VEC4S * i).xyz, bound(AABB_VEC4S * i + 1).xyz, ALL_PLANES, unused);
  if (BV_KIND == BV_KIND_OBB) {
    uint b = OBB_VEC4S * i;
    return classify_obb(bound(b).xyz, bound(b + 1), bound(b + 2), bound(b + 3), ALL_PLANES);
  }
  return classify_sphere(bound(SPHERE_VEC4S * i), ALL_PLANES);
}

void load_view() {
  int first = int(FRUSTUM_TEXELS * view);
  uvec4 tail = texelFetch(views, first + int(MAX_FRUSTUM_PLANES));
  view_plane_count = min(tail.x, MAX_FRUSTUM_PLANES);
  view_settle_margin = uintBitsToFloat(tail.y);
  [[unroll]] for (uint k = 0; k < MAX_FRUSTUM_PLANES; ++k) view_planes[k] = uintBitsToFloat(texelFetch(views, first + int(k)));
  if (OCCLUSION != 0u) occ_load_view(view);
}

// Whether object i, which the frustum keeps, is hidden behind the pyramid (occlusion::footprint).
bool occluded_object(uint i) {
  return occ_volume_occluded(BV_KIND == BV_KIND_AABB ? AABB_VEC4S * i : BV_KIND == BV_KIND_OBB ? OBB_VEC4S * i : SPHERE_VEC4S * i);
}

// An AABB's or OBB's class from its centre and bound alone where they settle it, as the fast CPU
// kernels do: with reach = bound + the view's margin, the smallest centre distance s over the
// planes below -reach is the reference's OUTSIDE, at least reach its INSIDE, else CLASS_OPEN (the
// reference's own test). Proof: docs/numerics.md, Settling bounds. pack() repeats the first plane
// past the last (no planes: everything INSIDE). A NaN or infinite bound or margin settles nothing,
// decided on the bits (docs/numerics.md, GPU and CPU agreement). Spheres are tested in full at
// once (one texel either way).
const uint CLASS_OPEN = 4u;  // (not a class any pass writes)
uint settle_object(uint i) {
  if (BV_KIND == BV_KIND_SPHERE) return classify_object(i);
  vec4 centre_bound = BV_KIND == BV_KIND_AABB ? uintBitsToFloat(texelFetch(centres, int(i))) : bound(OBB_VEC4S * i);
  bool usable = finite_bits(centre_bound.w) && finite_bits(view_settle_margin);
  float reach = centre_bound.w + view_settle_margin;
  float m = plane_distance(view_planes[0], centre_bound.xyz);
  [[unroll]] for (uint k = 1; k < MAX_FRUSTUM_PLANES; ++k) m = min(m, plane_distance(view_planes[k], centre_bound.xyz));
  bool planes = view_plane_count != 0u;
  bool beyond = planes && m < -reach, within = !planes || m >= reach;
  return !usable ? CLASS_OPEN : beyond ? CLASS_OUTSIDE : within ? CLASS_INSIDE : CLASS_OPEN;
}

// Classifies this invocation's objects block + j * group size (j < OBJECTS_PER_INVOCATION):
// bit j of outside_bits / inside_bits / occluded_bits is set for OUTSIDE / INSIDE / OCCLUDED
// (none: INTERSECTING); objects past object_count (or of no view) are OUTSIDE.
void classify_objects(uint block, bool view_ok, uint object_count, out uint outside_bits, out uint inside_bits,
                      out uint occluded_bits) {
  uint open = 0u;
  outside_bits = 0u;
  inside_bits = 0u;
  // Bit j of open: object j is still open after its centre bound (boxes).
  [[unroll]] for (uint j = 0; j < OBJECTS_PER_INVOCATION; ++j) {
    uint i = block + j * gl_WorkGroupSize.x;
    uint c = CLASS_OUTSIDE;
    if (view_ok && i < object_count) c = settle_object(i);
    outside_bits |= c == CLASS_OUTSIDE ? 1u << j : 0u;
    inside_bits |= c == CLASS_INSIDE ? 1u << j : 0u;
    open |= c == CLASS_OPEN ? 1u << j : 0u;
  }
  // The open boxes (few: those near a plane), one per invocation per round. On lavapipe a loop
  // runs while any lane has work, where both sides of an `if` always run: 8 one-texel bound
  // tests and one or two full tests cost less than 8 full tests.
  if (BV_KIND != BV_KIND_SPHERE) {
    while (open != 0u) {
      uint j = findLSB(open);
      open &= open - 1u;
      uint c = classify_object(block + j * gl_WorkGroupSize.x);
      outside_bits |= c == CLASS_OUTSIDE ? 1u << j : 0u;
      inside_bits |= c == CLASS_INSIDE ? 1u << j : 0u;
    }
  }
  // The kept objects against the pyramid, one per invocation per round (few are kept).
  occluded_bits = 0u;
  if (OCCLUSION != 0u) {
    uint all = OBJECTS_PER_INVOCATION >= 32u ? 0xffffffffu : (1u << OBJECTS_PER_INVOCATION) - 1u;
    uint kept = ~outside_bits & all;
    while (kept != 0u) {
      uint j = findLSB(kept);
      kept &= kept - 1u;
      if (occluded_object(block + j * gl_WorkGroupSize.x)) occluded_bits |= 1u << j;
    }
    inside_bits &= ~occluded_bits;
  }
}

uint class_of(uint j, uint outside_bits, uint inside_bits, uint occluded_bits) {
  return (outside_bits & 1u << j) != 0u    ? CLASS_OUTSIDE
         : (occluded_bits & 1u << j) != 0u ? CLASS_OCCLUDED
         : (inside_bits & 1u << j) != 0u   ? CLASS_INSIDE
                                           : CLASS_INTERSECTING;
}

bool is_kept(uint c) { return c == CLASS_INSIDE || c == CLASS_INTERSECTING; }

// Adds the subgroup's occluded objects to the view's count (OCCLUSION).
void count_occluded(bool view_ok, uint occluded_bits) {
  if (OCCLUSION == 0u) return;
  uint total = subgroupAdd(bitCount(occluded_bits));
  if (subgroupElect() && view_ok && total > 0u) atomicAdd(counters[view].occluded_count, total);
}

// Object order: OBJECTS_PER_INVOCATION objects per invocation, each workgroup's contiguous run
// of objects counted (visible and INSIDE) with one global atomic per subgroup on the
// workgroup's own two counts (zeroed before the pass; a workgroup runs on one core, so no cache
// line bounces, and no workgroup barrier); compact_scan sums them into the view's counters and
// offsets, and compact_scatter writes the lists.
void main_ordered() {
  uint object_count = params.object_count;
  bool view_ok = view < params.view_count;
  if (view_ok) load_view();
  uint block = this_run_first_object(params.first_object) + gl_LocalInvocationIndex;
  uint outside_bits, inside_bits, occluded_bits;
  classify_objects(block, view_ok, object_count, outside_bits, inside_bits, occluded_bits);
  uint visible = 0u;
  [[unroll]] for (uint j = 0; j < OBJECTS_PER_INVOCATION; ++j) {
    uint i = block + j * gl_WorkGroupSize.x;
    if (view_ok && i < object_count) {
      uint c = class_of(j, outside_bits, inside_bits, occluded_bits);
      classes[view * object_count + i] = c;
      visible += is_kept(c) ? 1u : 0u;
    }
  }
  count_occluded(view_ok, occluded_bits);
  uint vis_total = subgroupAdd(visible);
  uint inside_total = subgroupAdd(bitCount(inside_bits));
  if (subgroupElect() && view_ok) {
    uint groups = run_count(object_count), g = this_run(params.first_object);
    if (vis_total > 0) atomicAdd(group_counts[view * groups + g], vis_total);
    if (inside_total > 0) atomicAdd(group_counts[(params.view_count + view) * groups + g], inside_total);
  }
}

// Position of the k-th (from 0) set bit of x; x has more than k set bits. Straight-line halving
// steps (a loop here stayed a loop on lavapipe, with its iteration limiter and spills).
uint nth_set_bit(uint x, uint k) {
  uint pos = 0;
#define CP_HALVE(w)                                  \
  if (gl_SubgroupSize > (w)) {                       \
    uint low = bitCount(x & ((1u << (w)) - 1u));     \
    bool up = k >= low;                              \
    k = up ? k - low : k;                            \
    x = up ? x >> (w) : x;                           \
    pos = up ? pos + (w) : pos;                      \
  }
  CP_HALVE(16u) CP_HALVE(8u) CP_HALVE(4u) CP_HALVE(2u) CP_HALVE(1u)
#undef CP_HALVE
  return pos;
}

// The lane of the k-th (from 0) set bit of a subgroup ballot with more than k bits set.
// Branch-free: on lavapipe divergent branches cost more than the few extra operations.
uint nth_set_lane(uvec4 ballot, uint k) {
  if (gl_SubgroupSize <= 32) return nth_set_bit(ballot.x, k);
  uint lane = 0;
  bool found = false;
  [[unroll]] for (uint w = 0; w < 4; ++w) {
    uint n = bitCount(ballot[w]);
    bool here = !found && k < n;
    lane = here ? 32 * w + nth_set_bit(ballot[w], k) : lane;
    k = found || here ? k : k - n;
    found = found || here;
  }
  return lane;
}

// Arrival order: OBJECTS_PER_INVOCATION objects each, one global atomic per subgroup for all
// of them (see below). The subgroup's visible objects are
// then written in rounds of one id per invocation, each invocation working out from the ballots
// which object is its one (object j of lane l comes after every visible object j' < j and every
// visible object j of a lower lane). Every invocation but some of the last round stores, so the
// stores are not masked per object: on lavapipe a store is a branch per lane on its mask, which
// random visibility makes the branch predictor miss.
void main_arrival() {
  // The parameters, read once: lavapipe reads push constants like a uniform buffer, one
  // bounds-checked gather per use, and cannot move a read past the stores to other buffers.
  uint object_count = params.object_count;
  uint visible_capacity = params.visible_capacity;
  uint id_base = params.id_base;
  bool view_ok = view < params.view_count;
  if (view_ok) load_view();
  uint group_first = this_run_first_object(params.first_object);  // (the same runs as the ordered passes')
  uint block = group_first + gl_LocalInvocationIndex;
  uint outside_bits, inside_bits, occluded_bits;
  classify_objects(block, view_ok, object_count, outside_bits, inside_bits, occluded_bits);
  count_occluded(view_ok, occluded_bits);
  uvec4 ballots[OBJECTS_PER_INVOCATION];
  uint prefix[OBJECTS_PER_INVOCATION + 1];
  uint inside = bitCount(inside_bits);
  prefix[0] = 0;
  [[unroll]] for (uint j = 0; j < OBJECTS_PER_INVOCATION; ++j) {
    uint i = block + j * gl_WorkGroupSize.x;
    bool in_range = view_ok && i < object_count;
    uint c = class_of(j, outside_bits, inside_bits, occluded_bits);
    if (WRITE_CLASSES != 0 && in_range) classes[view * object_count + i] = c;
    ballots[j] = subgroupBallot(in_range && is_kept(c));
    prefix[j + 1] = prefix[j] + subgroupBallotBitCount(ballots[j]);
  }
  uint vis_total = prefix[OBJECTS_PER_INVOCATION];
  uint inside_total = subgroupAdd(inside);
  // The subgroup's slots in the view's list: one global atomic per subgroup, no workgroup
  // barrier. On lavapipe each barrier suspends and resumes every subgroup of the workgroup (a
  // coroutine each); the three a workgroup-wide reservation needs cost more than the atomics
  // they save.
  uint base = 0;
  if (subgroupElect() && vis_total > 0) {
    base = atomicAdd(counters[view].visible_count, vis_total);
    atomicAdd(counters[view].inside_count, inside_total);
  }
  base = subgroupBroadcastFirst(base);
  // Rounds in subgroup-uniform control flow, so that every lane takes part in the shuffle (a
  // shuffle from an inactive lane is undefined): lanes past the last visible object work out
  // the last one again and store nothing.
  for (uint round = 0; round < vis_total; round += gl_SubgroupSize) {
    uint t = round + gl_SubgroupInvocationID;
    uint k = min(t, vis_total - 1u);
    // The object step j holding visible object k, then its lane within ballot j.
    uint j = 0;
    [[unroll]] for (uint q = 1; q < OBJECTS_PER_INVOCATION; ++q) j = k >= prefix[q] ? q : j;
    uvec4 ballot = ballots[0];
    uint before = 0;
    [[unroll]] for (uint q = 1; q < OBJECTS_PER_INVOCATION; ++q) {
      ballot = q == j ? ballots[q] : ballot;
      before = q == j ? prefix[q] : before;
    }
    // That lane's first object (no assumption on how lanes map to local invocations).
    uint lane_block = group_first + subgroupShuffle(gl_LocalInvocationIndex, nth_set_lane(ballot, k - before));
    uint i = lane_block + j * gl_WorkGroupSize.x;
    uint slot = base + t;
    if (t < vis_total && slot < visible_capacity) {
      visible_ids[view * visible_capacity + slot] = id_base + i;
      if (WRITE_DRAWS != 0) {
        DrawCommand d = templates[i];
        d.object_id = id_base + i;
        draws[view * visible_capacity + slot] = d;
      }
    }
  }
}

void main() {
  view = gl_WorkGroupID.y;  // = gl_GlobalInvocationID.y (local size 1 in y), and visibly uniform: lavapipe then loads the planes once, not per lane
  if (ORDERED != 0) main_ordered();
  else main_arrival();
}
