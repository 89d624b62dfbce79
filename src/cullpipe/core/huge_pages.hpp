#pragma once
// Transparent huge pages for large fresh buffers. Internal.
#include <cstddef>
#include <cstdint>
#if defined(__linux__)
#include <sys/mman.h>
#endif

namespace cullpipe::detail {

/// The huge page size the hint below assumes (x86-64 and most Linux configurations).
inline constexpr std::size_t kHugePageSize = std::size_t{2} << 20;

/// Asks the kernel to back the kHugePageSize-aligned part of [p, p + bytes) with transparent
/// huge pages: a million-object build or cull touches ~100 MB of fresh memory, and with 4 KiB
/// pages the page faults and page-table walks take a noticeable share of it. A hint only: nothing
/// changes where THP is off or on other systems.
inline void advise_huge_pages(void* p, std::size_t bytes) {
#if defined(__linux__) && defined(MADV_HUGEPAGE)
  const std::uintptr_t begin = (reinterpret_cast<std::uintptr_t>(p) + kHugePageSize - 1) & ~(kHugePageSize - 1);
  const std::uintptr_t end = (reinterpret_cast<std::uintptr_t>(p) + bytes) & ~(kHugePageSize - 1);
  if (end > begin) madvise(reinterpret_cast<void*>(begin), end - begin, MADV_HUGEPAGE);
#else
  (void)p;
  (void)bytes;
#endif
}

}  // namespace cullpipe::detail
