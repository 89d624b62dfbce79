#pragma once
// The per-object bounds that settle most boxes with one centre distance per plane (see
// aabb_plane_bound and obb_plane_bound in cpu_culler.cpp for why they agree with the
// reference's tests), shared by the fast CPU kernels and the GPU flat pass. Internal to cullpipe.
#include <span>

#include <glm/vec4.hpp>

#include "geom/aabb.hpp"
#include "geom/frustum.hpp"
#include "geom/obb.hpp"
#include "geom/sphere.hpp"

namespace cullpipe::fast::detail {

/// Per box: xyz = its centre (min + max) / 2 rounded to a float, w = the bound (NaN where no
/// bound is safe: non-finite or huge coordinates). Computed in round-to-nearest without
/// flushing, whatever the caller's floating-point mode. out.size() == boxes.size().
void aabb_centre_bounds(std::span<const Aabb> boxes, std::span<glm::vec4> out);

/// Per OBB: a bound b >= |r| on the reference's projected radius r for every plane normal of
/// length <= 1 + 2^-20, NaN where none is safe; computed like aabb_centre_bounds.
void obb_plane_bounds(std::span<const Obb> boxes, std::span<float> out);

/// The lower bounds a CpuCuller packs into the bounds it stores (proofs in cpu_culler.cpp):
/// per object X, with the straddling threshold less every rounding at least c_k X - m on every
/// unit-normal plane k (c_k: |n_k|_1 for boxes, |n_k|_2 for OBBs, 1 for spheres; m the view's
/// margin); 0 or negative where none is known.
double aabb_lower(const Aabb& b);
double obb_lower(const Obb& b);
double sphere_lower(const Sphere& s);
/// `bound` rounded up to a multiple of 2^8 float steps, its lowest 8 bits q = floor(256 lower /
/// bound), 0 to 255 (0 for lower <= 0 and bounds past 2^119); NaN, infinite and zero bounds
/// unchanged, one that rounds up past the float range infinite. What a CpuCuller stores:
/// pack_lower(bound, aabb_lower(box)) and so on.
float pack_lower(float bound, double lower);

/// The margin m a view adds to every bound: a centre distance s < -(bound + m) on a plane
/// settles OUTSIDE, s >= bound + m on every plane INSIDE. NaN (settles nothing) unless every
/// plane normal has length <= 1 + 2^-20 and every |d| <= 2^120.
float settle_margin(const Frustum& frustum);

}  // namespace cullpipe::fast::detail
