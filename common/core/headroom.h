#pragma once
/// @file
/// Sizing of the buffers a topology change grows. A cut adds a few nodes
/// and blocks; buffers sized exactly would be reallocated at every cut,
/// and the frame that cuts would fault in megabytes of fresh pages. With
/// an eighth of headroom, the next cuts reuse the memory.

#include <cstddef>

namespace cutsim {

/// Resizes `v` to `n` elements (new ones value-initialised), reserving an
/// eighth more than `n` when it must grow.
template <typename V>
void ResizeWithHeadroom(V& v, size_t n) {
  if (n > v.capacity()) v.reserve(n + n / 8);
  v.resize(n);
}

/// Sets `v` to `n` copies of `value`, reserving an eighth more than `n`
/// when it must grow.
template <typename V>
void AssignWithHeadroom(V& v, size_t n, const typename V::value_type& value) {
  if (n > v.capacity()) v.reserve(n + n / 8);
  v.assign(n, value);
}

}  // namespace cutsim
