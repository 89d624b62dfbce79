#pragma once
#include <cstddef>

namespace cullpipe {

/// How far ahead a gather in a tree's object order (volumes[order[k]], an object per cache
/// miss) asks for its objects: uploads of hierarchies read a million volumes in that order.
inline constexpr std::size_t kGatherAhead = 16;

/// Asks for the cache lines of *p (a hint; nothing where the compiler has no prefetch).
template <class T>
inline void prefetch_object(const T* p) {
  static_assert(sizeof(T) <= 64, "two prefetches cover at most 64 bytes");
#if defined(__GNUC__)
  __builtin_prefetch(p);
  if constexpr (sizeof(T) > 1) __builtin_prefetch(reinterpret_cast<const char*>(p) + sizeof(T) - 1);
#else
  (void)p;
#endif
}

}  // namespace cullpipe
