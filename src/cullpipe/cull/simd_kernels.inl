// The SIMD culling kernels, written once with GCC/Clang vector extensions and compiled once per
// instruction set: the including file defines CULLPIPE_SIMD_NS (a namespace name) and
// CULLPIPE_SIMD_LANES (4, 8 or 16) and is built with the matching -m flags.
//
// Bit-exact with cullpipe::reference: every lane does the reference's float operations in the
// reference's order ((n.x*p.x + n.y*p.y) + n.z*p.z) + d, with contraction off (-ffp-contract=off
// is global), and the same comparisons. The reference's early exit at the first plane that
// rejects does not change its answer (OUTSIDE wins over everything found before or after), so
// the kernels OR the per-plane masks over all planes (early exits per vector, measured on
// AABBs and spheres, cost more in mispredictions than they saved).
// AABBs and OBBs are first settled by a bound (cull_settled): only the objects it leaves open
// get the reference's test, so no answer depends on the bound's own arithmetic.
//
// The kernels by role, in the order each builds on the last:
//   simd_lanes.inl    vectors of W lanes: loads, masks, compression, transposes, emit
//   simd_settle.inl   the flat pass: settle by bounds, resolve open objects, list per run
//   simd_list.inl     ids from bits and marks; the read-floor loops
//   simd_resolve.inl  the flat pass per volume kind (the reference's full tests)
//   simd_walk.inl     the hierarchy walk
// (In this order: each part uses the ones above it.)
// clang-format off
#include "cullpipe/cull/simd_lanes.inl"
#include "cullpipe/cull/simd_settle.inl"
#include "cullpipe/cull/simd_list.inl"
#include "cullpipe/cull/simd_resolve.inl"
#include "cullpipe/cull/simd_walk.inl"
// clang-format on
