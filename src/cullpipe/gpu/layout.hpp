#pragma once
// Conversions between the host volume types and the GPU structs of src/cullpipe/gpu/cull_types.h.
// Every conversion copies floats unchanged, so CPU and GPU see bit-identical inputs.
#include <limits>

#include "cullpipe/geom/aabb.hpp"
#include "cullpipe/geom/frustum.hpp"
#include "cullpipe/geom/obb.hpp"
#include "cullpipe/geom/sphere.hpp"
#include "cullpipe/gpu/cull_types.h"  // shaders/shared/, on the include path of cullpipe_gpu

namespace cullpipe::gpu {

inline GpuAabb pack(const Aabb& b) { return {vec4(b.min, 0.0f), vec4(b.max, 0.0f)}; }
inline GpuObb pack(const Obb& b) {
  return {vec4(b.center, 0.0f), vec4(b.basis[0], b.half_extents.x), vec4(b.basis[1], b.half_extents.y),
          vec4(b.basis[2], b.half_extents.z)};
}
inline GpuSphere pack(const Sphere& s) { return {vec4(s.center, s.radius)}; }
/// The planes past plane_count repeat the first: the tests read plane_count planes only, and the
/// flat pass's smallest centre distance over all of them is that of the planes in use.
inline GpuFrustum pack(const Frustum& f) {
  GpuFrustum g{};
  for (std::size_t i = 0; i < MAX_FRUSTUM_PLANES; ++i)
    if (f.plane_count > 0) g.planes[i] = f.planes[i < f.plane_count ? i : 0].as_vec4();
  g.plane_count = static_cast<uint>(f.plane_count);
  g.settle_margin = std::numeric_limits<float>::quiet_NaN();  // settles nothing until the flat culler sets it
  return g;
}

}  // namespace cullpipe::gpu
