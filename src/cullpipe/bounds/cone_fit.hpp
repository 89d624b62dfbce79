#pragma once
#include <cstdint>
#include <glm/vec3.hpp>
#include <span>

#include "cullpipe/geom/cone.hpp"

namespace cullpipe::bounds {

/// The back-face cone of the triangles `indices` (three per triangle) into `positions`, in
/// double, about the direction of `axis_hint` (meshoptimizer's cone axis, say; the normals'
/// mean when the hint is zero or not finite). The widest angle between the float axis and a
/// triangle's normal is measured in double, widened by the angle whose sine is 2^-5 (so that a
/// viewer the cone passes is behind every triangle's plane by 2^-5 of its distance), and its
/// sine raised by 2^-20 before rounding up; a cluster with a sliver (a triangle whose smallest
/// altitude is below 2^-8 of the cluster's radius) gets no cone; the
/// apex is put behind every triangle's plane by 2^-12 of the cluster's radius, and found
/// behind each by 2^-21 of its distance (in double, from the float apex). Triangles with two equal corners are skipped
/// (they have no area wherever they are drawn). No cone (cutoff 1) when a triangle is so thin that its normal is
/// uncertain (|(b - a) x (c - a)| below 2^-30 of |b - a| |c - a|), when a normal is 84 degrees
/// or more from the axis (meshoptimizer's limit), or when nothing is finite. Indices must be in
/// range (not checked: build_clusters checks them). O(triangles).
BackfaceCone backface_cone(std::span<const glm::vec3> positions, std::span<const std::uint32_t> indices,
                           const glm::vec3& axis_hint);

}  // namespace cullpipe::bounds
