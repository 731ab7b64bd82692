#pragma once
/// @file
/// The OpenMP thread count a solver option asks for.

#include <omp.h>

namespace cutsim::fem {

/// `requested` threads, or all OpenMP's threads when it is 0 or less.
inline int Threads(int requested) { return requested > 0 ? requested : omp_get_max_threads(); }

}  // namespace cutsim::fem
