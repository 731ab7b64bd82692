#pragma once
/// @file
/// Counts heap allocations in a test executable: glibc lets the executable
/// interpose malloc and friends and forward to __libc_*, which catches
/// operator new, Eigen's aligned_malloc and anything else in one place.
/// Include this header in exactly ONE source file of a test executable (it
/// defines malloc). Under a sanitizer, which owns malloc itself, counting is
/// unavailable: `kMallocCounting` is false and tests skip.
#include <atomic>
#include <cstddef>

// GCC names AddressSanitizer with a macro, clang with a feature test.
#if defined(__SANITIZE_ADDRESS__)
#define CUTSIM_MALLOC_SANITIZED 1
#elif defined(__has_feature)
#if __has_feature(address_sanitizer)
#define CUTSIM_MALLOC_SANITIZED 1
#endif
#endif
#if !defined(CUTSIM_MALLOC_SANITIZED) && defined(__GLIBC__)
#define CUTSIM_COUNT_MALLOC 1
#endif

namespace cutsim::support {

#ifdef CUTSIM_COUNT_MALLOC
inline constexpr bool kMallocCounting = true;
#else
inline constexpr bool kMallocCounting = false;
#endif

namespace malloc_counter {
inline std::atomic<bool> counting{false};
inline std::atomic<long> allocations{0};
}  // namespace malloc_counter

/// Starts counting the allocations of every thread.
inline void StartCountingAllocations() {
  malloc_counter::allocations = 0;
  malloc_counter::counting = true;
}

/// Stops counting; returns the allocations since StartCountingAllocations().
inline long StopCountingAllocations() {
  malloc_counter::counting = false;
  return malloc_counter::allocations.load();
}

}  // namespace cutsim::support

#ifdef CUTSIM_COUNT_MALLOC
extern "C" {
void* __libc_malloc(size_t);
void* __libc_calloc(size_t, size_t);
void* __libc_realloc(void*, size_t);
void* __libc_memalign(size_t, size_t);
inline void CutsimCountAllocation() {
  if (cutsim::support::malloc_counter::counting.load(std::memory_order_relaxed)) {
    cutsim::support::malloc_counter::allocations.fetch_add(1);
  }
}
void* malloc(size_t n) {
  CutsimCountAllocation();
  return __libc_malloc(n);
}
void* calloc(size_t a, size_t b) {
  CutsimCountAllocation();
  return __libc_calloc(a, b);
}
void* realloc(void* p, size_t n) {
  CutsimCountAllocation();
  return __libc_realloc(p, n);
}
void* aligned_alloc(size_t a, size_t n) {
  CutsimCountAllocation();
  return __libc_memalign(a, n);
}
int posix_memalign(void** out, size_t a, size_t n) {
  CutsimCountAllocation();
  *out = __libc_memalign(a, n);
  return *out != nullptr ? 0 : 12;  // ENOMEM
}
}
#endif
