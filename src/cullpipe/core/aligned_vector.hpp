#pragma once
// A std::vector whose storage starts on a cache line, so that records of 32 or 64 bytes never
// straddle two lines (malloc aligns to 16). Arrays of 4 MiB and up start on a 2 MiB boundary
// with transparent huge pages asked for: a hierarchy's walk reads a few records from each of
// thousands of pages, and with 4 KiB pages the page-table walks miss too. Internal.
#include <cstddef>
#include <new>
#include <vector>

#include "cullpipe/core/huge_pages.hpp"

namespace cullpipe::detail {

template <class T>
struct CacheLineAllocator {
  using value_type = T;
  static constexpr std::align_val_t kAlign{64};
  static constexpr std::size_t kHugeFrom = std::size_t{4} << 20;
  CacheLineAllocator() = default;
  template <class U>
  CacheLineAllocator(const CacheLineAllocator<U>&) {}  // NOLINT: converting, as allocators are
  T* allocate(std::size_t n) {
    const std::size_t bytes = n * sizeof(T);
    if (bytes < kHugeFrom) return static_cast<T*>(::operator new(bytes, kAlign));
    const std::size_t rounded = (bytes + kHugePageSize - 1) / kHugePageSize * kHugePageSize;
    void* p = ::operator new(rounded, std::align_val_t(kHugePageSize));
    advise_huge_pages(p, rounded);
    return static_cast<T*>(p);
  }
  // (The unsized forms: clang before 19 declares the sized ones only with -fsized-deallocation.)
  void deallocate(T* p, std::size_t n) {
    if (n * sizeof(T) < kHugeFrom) return ::operator delete(p, kAlign);
    ::operator delete(p, std::align_val_t(kHugePageSize));
  }
  template <class U>
  bool operator==(const CacheLineAllocator<U>&) const {
    return true;
  }
};

template <class T>
using CacheLineVector = std::vector<T, CacheLineAllocator<T>>;

}  // namespace cullpipe::detail
