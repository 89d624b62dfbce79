#pragma once
// A std::vector whose storage starts on a cache line: records of 32 or 64 bytes then never
// straddle two lines, whatever address the allocator would have handed out (malloc gives 16).
// Internal to cullpipe.
#include <cstddef>
#include <new>
#include <vector>

namespace cullpipe::fast::detail {

template <class T>
struct CacheLineAllocator {
  using value_type = T;
  static constexpr std::align_val_t kAlign{64};
  CacheLineAllocator() = default;
  template <class U>
  CacheLineAllocator(const CacheLineAllocator<U>&) {}  // NOLINT: converting, as allocators are
  T* allocate(std::size_t n) { return static_cast<T*>(::operator new(n * sizeof(T), kAlign)); }
  void deallocate(T* p, std::size_t n) { ::operator delete(p, n * sizeof(T), kAlign); }
  template <class U>
  bool operator==(const CacheLineAllocator<U>&) const {
    return true;
  }
};

template <class T>
using CacheLineVector = std::vector<T, CacheLineAllocator<T>>;

}  // namespace cullpipe::fast::detail
