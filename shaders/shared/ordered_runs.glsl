// ordered_runs.glsl: the unit of the object-order passes (cull_flat.comp with ORDERED = 1,
// compact_scan.comp, compact_scatter.comp), in one place so the three agree: a culling
// workgroup's run of (group size x OBJECTS_PER_INVOCATION) consecutive objects, whose visible
// and INSIDE counts are entry [view][run] of the group-count buffer (BINDING_GROUP_COUNTS).
// A dispatch starts at a multiple of the run (the host chunks passes by whole workgroups).
// Included after the includer declares OBJECTS_PER_INVOCATION and its local size (the
// culling pass's: specialization constants 1 and 4).
#ifndef CULLPIPE_SHADERS_SHARED_ORDERED_RUNS_GLSL
#define CULLPIPE_SHADERS_SHARED_ORDERED_RUNS_GLSL

// Objects per run.
uint run_objects() { return gl_WorkGroupSize.x * OBJECTS_PER_INVOCATION; }

// Runs in a segment of object_count objects.
uint run_count(uint object_count) { return (object_count + run_objects() - 1u) / run_objects(); }

// This workgroup's run within the segment, in a dispatch that starts at object first_object.
uint this_run(uint first_object) { return first_object / run_objects() + gl_WorkGroupID.x; }

// The first object of this workgroup's run.
uint this_run_first_object(uint first_object) { return first_object + gl_WorkGroupID.x * run_objects(); }

#endif
