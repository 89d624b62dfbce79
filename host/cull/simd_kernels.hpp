#pragma once
// Internal interface between cpu_culler.cpp and the SIMD kernels. The kernels are compiled
// three times from simd_kernels.inl with different instruction sets (simd_portable.cpp,
// simd_avx2.cpp, simd_avx512.cpp), so this header holds plain data only: a kernel translation
// unit must not instantiate inline functions it shares with the rest of the program (the
// linker could keep its AVX-512 copy for everyone).
#include <cstddef>
#include <cstdint>

namespace cullpipe::fast::detail {

/// Up to six planes, one array per component (a copy of Frustum::active()).
struct PlaneSet {
  std::uint32_t count = 0;
  float nx[6]{}, ny[6]{}, nz[6]{}, d[6]{};
};

/// Structure-of-arrays bounds; every array holds at least `padded` floats (a multiple of 16),
/// the padding zeros, so a kernel may load whole vectors past the last object.
struct AabbArrays {
  const float *min_x, *min_y, *min_z, *max_x, *max_y, *max_z;
};
struct ObbArrays {
  const float *c_x, *c_y, *c_z;
  const float *u0_x, *u0_y, *u0_z, *u1_x, *u1_y, *u1_z, *u2_x, *u2_y, *u2_z;
  const float *h_x, *h_y, *h_z;
};
struct SphereArrays {
  const float *c_x, *c_y, *c_z, *radius;
};

/// Where one chunk's results go. `classes` (may be null) receives the class of objects
/// begin..end-1 at classes[0..]; `ids` (may be null) receives the ids of visible objects in
/// object order, at most end - begin of them, and may write up to 16 values beyond them.
struct ChunkOutput {
  std::uint8_t* classes = nullptr;
  std::uint32_t* ids = nullptr;
};

/// Visible (INSIDE + INTERSECTING) and INSIDE objects of one chunk.
struct ChunkCounts {
  std::uint32_t visible = 0;
  std::uint32_t inside = 0;
};

using AabbKernel = ChunkCounts (*)(const AabbArrays&, std::size_t begin, std::size_t end, const PlaneSet&, ChunkOutput);
using ObbKernel = ChunkCounts (*)(const ObbArrays&, std::size_t begin, std::size_t end, const PlaneSet&, ChunkOutput);
using SphereKernel = ChunkCounts (*)(const SphereArrays&, std::size_t begin, std::size_t end, const PlaneSet&, ChunkOutput);

/// Reads data[begin..end) (end - begin a multiple of 16 or data padded to one) and returns
/// the OR of its bits: the memory floor of a pass, with the same loads as the kernels.
using TouchKernel = std::uint32_t (*)(const float* data, std::size_t begin, std::size_t end);

struct KernelTable {
  AabbKernel aabb;
  ObbKernel obb;
  SphereKernel sphere;
  TouchKernel touch;
  unsigned lanes;
};

KernelTable portable_kernels();
#if defined(CULLPIPE_HAVE_X86_KERNELS)
KernelTable avx2_kernels();
KernelTable avx512_kernels();
#endif

}  // namespace cullpipe::fast::detail
