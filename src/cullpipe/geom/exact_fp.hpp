#pragma once
// CULLPIPE_EXACT_FP_BEGIN / CULLPIPE_EXACT_FP_END bracket header-inline arithmetic whose
// rounding the CPU/GPU agreement depends on (Plane::distance, the OBB and sphere plane tests,
// Obb::corner): every product is rounded on its own, never contracted with a sum into a fused
// multiply-add, in whatever translation unit the code is inlined into. The library itself is
// built with -ffp-contract=off; a consumer sets no flag for this.
//  - GCC: the functions carry optimize("fp-contract=off"), whatever -ffp-contract says, and
//    are not inlined into callers built with other contraction settings.
//  - Clang: `#pragma clang fp contract(off)` holds under its default (-ffp-contract=on) and
//    -ffp-contract=fast-honor-pragmas; -ffp-contract=fast disregards every pragma, so a
//    consumer built with it and comparing its own inline calls with the GPU's answers uses
//    fast-honor-pragmas instead.
// The library's own answers (reference::classify, the fast CPU path, the GPU) do not depend on
// the consumer's flags at all: they are compiled inside the library.
#if defined(__clang__)
#define CULLPIPE_EXACT_FP_BEGIN _Pragma("float_control(push)") _Pragma("clang fp contract(off)")
#define CULLPIPE_EXACT_FP_END _Pragma("float_control(pop)")
#elif defined(__GNUC__)
#define CULLPIPE_EXACT_FP_BEGIN _Pragma("GCC push_options") _Pragma("GCC optimize(\"fp-contract=off\")")
#define CULLPIPE_EXACT_FP_END _Pragma("GCC pop_options")
#else
#define CULLPIPE_EXACT_FP_BEGIN
#define CULLPIPE_EXACT_FP_END
#endif
