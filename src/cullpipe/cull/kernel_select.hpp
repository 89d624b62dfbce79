#pragma once
// Internal to the CPU cullers: the kernel table of an instruction set and a frustum as the
// kernels read it (defined in cpu_culler.cpp, shared with cpu_bvh_culler.cpp).
#include "cullpipe/cull/cpu_culler.hpp"
#include "cullpipe/cull/simd_kernels.hpp"
#include "cullpipe/geom/frustum.hpp"

namespace cullpipe::fast::detail {

/// The kernels built for `isa` (the caller checks that the machine runs them).
KernelTable kernels(Isa isa);

/// Frustum::active() as a PlaneSet, with the flat kernels' unit_normals and max_margin.
PlaneSet plane_set(const Frustum& f);

}  // namespace cullpipe::fast::detail
