// The AVX-512 kernels: 16 lanes. Built with -mavx512f; called only when the CPU reports
// AVX-512F.
#define CULLPIPE_SIMD_NS avx512
#define CULLPIPE_SIMD_LANES 16
#include "cullpipe/cull/simd_kernels.inl"

namespace cullpipe::fast::detail {
KernelTable avx512_kernels() {
  return {avx512::cull_aabb,
          avx512::cull_obb,
          avx512::cull_sphere,
          avx512::touch,
          avx512::touch_columns,
          avx512::walk_aabb,
          avx512::walk_obb,
          avx512::walk_sphere,
          avx512::expand_ids,
          avx512::list_marked,
          16};
}
}  // namespace cullpipe::fast::detail
