#pragma once
// The per-object bounds that settle most boxes with one centre distance per plane (see
// aabb_plane_bound and obb_plane_bound in cpu_culler.cpp for why they agree with the
// reference's tests), shared by the fast CPU kernels and the GPU flat pass. Internal to cullpipe.
#include <span>

#include <glm/vec4.hpp>

#include "geom/aabb.hpp"
#include "geom/frustum.hpp"
#include "geom/obb.hpp"

namespace cullpipe::fast::detail {

/// Per box: xyz = its centre (min + max) / 2 rounded to a float, w = the bound (NaN where no
/// bound is safe: non-finite or huge coordinates). Computed in round-to-nearest without
/// flushing, whatever the caller's floating-point mode. out.size() == boxes.size().
void aabb_centre_bounds(std::span<const Aabb> boxes, std::span<glm::vec4> out);

/// Per OBB: a bound b >= |r| on the reference's projected radius r for every plane normal of
/// length <= 1 + 2^-20, NaN where none is safe; computed like aabb_centre_bounds.
void obb_plane_bounds(std::span<const Obb> boxes, std::span<float> out);

/// The margin m a view adds to every bound: a centre distance s < -(bound + m) on a plane
/// settles OUTSIDE, s >= bound + m on every plane INSIDE. NaN (settles nothing) unless every
/// plane normal has length <= 1 + 2^-20 and every |d| <= 2^120.
float settle_margin(const Frustum& frustum);

}  // namespace cullpipe::fast::detail
