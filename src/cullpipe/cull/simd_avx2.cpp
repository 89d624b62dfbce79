// The AVX2 kernels: 8 lanes. Built with -mavx2 -mfma (fused only where mul_add asks for it:
// -ffp-contract=off holds here too); called only when the CPU reports AVX2 and FMA.
#define CULLPIPE_SIMD_NS avx2
#define CULLPIPE_SIMD_LANES 8
#include "cullpipe/cull/simd_kernels.inl"

namespace cullpipe::fast::detail {
KernelTable avx2_kernels() {
  return {avx2::cull_aabb,
          avx2::cull_obb,
          avx2::cull_sphere,
          avx2::touch,
          avx2::touch_columns,
          avx2::walk_aabb,
          avx2::walk_obb,
          avx2::walk_sphere,
          avx2::expand_ids,
          avx2::list_marked,
          8};
}
}  // namespace cullpipe::fast::detail
