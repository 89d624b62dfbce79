// Part of the SIMD kernels (simd_kernels.inl includes it once per instruction set). The flat pass per
// volume kind: the reference's full test for the objects the bounds leave open.
#include <cstddef>
#include <cstdint>

namespace cullpipe::fast::detail {
namespace CULLPIPE_SIMD_NS {
namespace {

// AABBs: the open boxes get the reference's p/n-vertex test.
ChunkCounts cull_aabb(const AabbArrays& a, std::size_t begin, std::size_t end, const PlaneSet& planes,
                      ChunkOutput out) {
  auto resolve = [&](const std::uint32_t* objects, unsigned count, std::uint32_t& outside_bits,
                     std::uint32_t& crossing_bits) {
    vf box[kAabbRecordFloats];  // min x y z, max x y z, two spare
    gather_columns(a.records, objects, count, box);
    const vf zero = {};
    vi outside = {}, crossing = {};
    for (std::uint32_t k = 0; k < planes.count; ++k) {
      const float nx = planes.nx[k], ny = planes.ny[k], nz = planes.nz[k], d = planes.d[k];
      // The p-vertex (farthest along the normal) and n-vertex, as pn_vertices (-0 as positive).
      const bool sx = nx >= 0.0f, sy = ny >= 0.0f, sz = nz >= 0.0f;
      const vf dp = ((nx * box[sx ? 3 : 0] + ny * box[sy ? 4 : 1]) + nz * box[sz ? 5 : 2]) + d;
      const vf dn = ((nx * box[sx ? 0 : 3] + ny * box[sy ? 1 : 4]) + nz * box[sz ? 2 : 5]) + d;
      outside |= dp < zero;
      crossing |= dn < zero;
    }
    outside_bits = lane_bits(outside);
    crossing_bits = lane_bits(crossing);
  };
  auto prefetch = [&](std::uint32_t o) { __builtin_prefetch(a.records + std::size_t(o) * kAabbRecordFloats); };
  return cull_settled({a.c_x, a.c_y, a.c_z, a.bound}, begin, end, planes, planes.lower_scale_l1, prefetch, resolve,
                      out);
}

// OBBs: the open ones get the reference's projected-radius test.
ChunkCounts cull_obb(const ObbArrays& a, std::size_t begin, std::size_t end, const PlaneSet& planes, ChunkOutput out) {
  auto resolve = [&](const std::uint32_t* objects, unsigned count, std::uint32_t& outside_bits,
                     std::uint32_t& crossing_bits) {
    vf col[kObbRecordFloats];  // centre, axes u0 u1 u2, half extents, a spare
    gather_columns(a.records, objects, count, col);
    vi outside = {}, crossing = {};
    for (std::uint32_t k = 0; k < planes.count; ++k) {
      const float nx = planes.nx[k], ny = planes.ny[k], nz = planes.nz[k];
      const vf s = ((nx * col[0] + ny * col[1]) + nz * col[2]) + planes.d[k];
      const vf a0 = (nx * col[3] + ny * col[4]) + nz * col[5];
      const vf a1 = (nx * col[6] + ny * col[7]) + nz * col[8];
      const vf a2 = (nx * col[9] + ny * col[10]) + nz * col[11];
      const vf r = (abs(a0) * col[12] + abs(a1) * col[13]) + abs(a2) * col[14];
      outside |= s < -r;
      crossing |= s < r;
    }
    outside_bits = lane_bits(outside);
    crossing_bits = lane_bits(crossing);
  };
  auto prefetch = [&](std::uint32_t o) { __builtin_prefetch(a.records + std::size_t(o) * kObbRecordFloats); };
  return cull_settled({a.c_x, a.c_y, a.c_z, a.bound}, begin, end, planes, planes.lower_scale_l2, prefetch, resolve,
                      out);
}

/// The reference's sphere test of W spheres (centre, radius) on every plane.
inline void test_spheres_all(vf cx, vf cy, vf cz, vf radius, const PlaneSet& planes, vi& outside, vi& crossing) {
  outside = crossing = vi{};
  for (std::uint32_t k = 0; k < planes.count; ++k) {
    const vf s = ((planes.nx[k] * cx + planes.ny[k] * cy) + planes.nz[k] * cz) + planes.d[k];
    outside |= s < -radius;
    crossing |= s < radius;
  }
}

// Spheres: the open ones get the reference's signed-distance test, their centres and radii
// read from the columns (16 bytes of records per sphere would double what an upload writes).
// Without unit normals every sphere is tested that way, a vector at a time.
ChunkCounts cull_sphere(const SphereArrays& a, std::size_t begin, std::size_t end, const PlaneSet& planes,
                        ChunkOutput out) {
  if (!planes.unit_normals) {
    ChunkCounts counts;
    for (std::size_t run = begin, r = 0; run < end; run += kRunObjects, ++r) {
      const std::uint32_t* const ids_before = out.ids;
      for (std::size_t i = run; i < smaller(end, run + kRunObjects); i += W) {
        vi outside, crossing;
        test_spheres_all(load(a.c_x + i), load(a.c_y + i), load(a.c_z + i), load(a.radius + i), planes, outside,
                         crossing);
        emit(i, begin, static_cast<unsigned>(smaller(W, end - i)), lane_bits(outside), lane_bits(crossing), out,
             counts);
      }
      if (out.runs) out.runs[r] = static_cast<std::uint32_t>(out.ids - ids_before);  // (every run's ids listed)
    }
    return counts;
  }
  auto resolve = [&](const std::uint32_t* objects, unsigned count, std::uint32_t& outside_bits,
                     std::uint32_t& crossing_bits) {
    alignas(64) float col[4][W];
    for (unsigned l = 0; l < W; ++l) {
      const std::uint32_t o = objects[l < count ? l : 0];
      col[0][l] = a.c_x[o], col[1][l] = a.c_y[o], col[2][l] = a.c_z[o], col[3][l] = a.radius[o];
    }
    vi outside, crossing;
    test_spheres_all(load(col[0]), load(col[1]), load(col[2]), load(col[3]), planes, outside, crossing);
    outside_bits = lane_bits(outside);
    crossing_bits = lane_bits(crossing);
  };
  auto prefetch = [&](std::uint32_t o) {
    __builtin_prefetch(a.c_x + o);
    __builtin_prefetch(a.c_y + o);
    __builtin_prefetch(a.c_z + o);
    __builtin_prefetch(a.radius + o);
  };
  return cull_settled({a.c_x, a.c_y, a.c_z, a.bound}, begin, end, planes, 0x1p-8f * (1.0f - 0x1p-12f), prefetch,
                      resolve, out);
}

}  // namespace
}  // namespace CULLPIPE_SIMD_NS
}  // namespace cullpipe::fast::detail
