#include "common/sim/frame_times.h"

#include "common/fem/implicit.h"

namespace cutsim::sim {

static_assert(kNumDynamicsPhases == fem::kNumImplicitPhases);

const char* DynamicsPhaseName(int i) { return fem::ImplicitPhaseName(static_cast<fem::ImplicitPhase>(i)); }

}  // namespace cutsim::sim
