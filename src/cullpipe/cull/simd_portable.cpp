// The portable kernels: 4-lane vectors in the baseline instruction set (SSE2 on x86-64).
#define CULLPIPE_SIMD_NS portable
#define CULLPIPE_SIMD_LANES 4
#include "cullpipe/cull/simd_kernels.inl"

namespace cullpipe::fast::detail {
KernelTable portable_kernels() {
  return {portable::cull_aabb,
          portable::cull_obb,
          portable::cull_sphere,
          portable::touch,
          portable::touch_columns,
          portable::walk_aabb,
          portable::walk_obb,
          portable::walk_sphere,
          portable::expand_ids,
          portable::list_marked,
          4};
}
}  // namespace cullpipe::fast::detail
