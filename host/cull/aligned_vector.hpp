#pragma once
// A std::vector whose storage starts on a cache line: records of 32 or 64 bytes then never
// straddle two lines, whatever address the allocator would have handed out (malloc gives 16).
// Large arrays (4 MiB and up) start on a 2 MiB boundary and ask Linux for transparent huge
// pages: a hierarchy's walk reads a few records from each of thousands of 4 KiB pages, and
// with cold caches the page-table walks miss as well (10^6 boxes, caches flushed before each
// pass: 0.267-0.288 -> 0.254-0.257 ms at 10% visible, 0.438-0.455 -> 0.415 at 50%).
// Internal to cullpipe.
#include <cstddef>
#include <new>
#include <vector>

#if defined(__linux__)
#include <sys/mman.h>
#endif

namespace cullpipe::fast::detail {

template <class T>
struct CacheLineAllocator {
  using value_type = T;
  static constexpr std::align_val_t kAlign{64};
  static constexpr std::size_t kHuge = std::size_t{2} << 20, kHugeFrom = std::size_t{4} << 20;
  CacheLineAllocator() = default;
  template <class U>
  CacheLineAllocator(const CacheLineAllocator<U>&) {}  // NOLINT: converting, as allocators are
  T* allocate(std::size_t n) {
    const std::size_t bytes = n * sizeof(T);
    if (bytes < kHugeFrom) return static_cast<T*>(::operator new(bytes, kAlign));
    const std::size_t rounded = (bytes + kHuge - 1) / kHuge * kHuge;
    void* p = ::operator new(rounded, std::align_val_t(kHuge));
#if defined(__linux__) && defined(MADV_HUGEPAGE)
    madvise(p, rounded, MADV_HUGEPAGE);  // a hint: without huge pages nothing changes
#endif
    return static_cast<T*>(p);
  }
  // (The unsized forms: clang before 19 declares the sized ones only with -fsized-deallocation.)
  void deallocate(T* p, std::size_t n) {
    if (n * sizeof(T) < kHugeFrom) return ::operator delete(p, kAlign);
    ::operator delete(p, std::align_val_t(kHuge));
  }
  template <class U>
  bool operator==(const CacheLineAllocator<U>&) const {
    return true;
  }
};

template <class T>
using CacheLineVector = std::vector<T, CacheLineAllocator<T>>;

}  // namespace cullpipe::fast::detail
