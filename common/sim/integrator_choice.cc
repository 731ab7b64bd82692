#include "common/sim/integrator_choice.h"

#include <algorithm>
#include <cmath>
#include <vector>

#include <fmt/format.h>

#include "common/core/error.h"

namespace cutsim::sim {

const char* IntegratorName(IntegratorKind kind) {
  return kind == IntegratorKind::kImplicit ? "implicit" : "explicit";
}

int64_t StiffnessNonzeros(const mesh::Tets& tets, int32_t num_nodes) {
  std::vector<uint64_t> edges;
  edges.reserve(static_cast<size_t>(tets.rows()) * 6);
  for (Eigen::Index t = 0; t < tets.rows(); ++t) {
    for (int a = 0; a < 4; ++a) {
      for (int b = a + 1; b < 4; ++b) {
        const auto lo = static_cast<uint64_t>(std::min(tets(t, a), tets(t, b)));
        const auto hi = static_cast<uint64_t>(std::max(tets(t, a), tets(t, b)));
        edges.push_back(lo << 32 | hi);
      }
    }
  }
  std::sort(edges.begin(), edges.end());
  const auto distinct = std::unique(edges.begin(), edges.end()) - edges.begin();
  return 9 * static_cast<int64_t>(num_nodes) + 18 * static_cast<int64_t>(distinct);
}

IntegratorCost EstimateFrameCost(int64_t tets, int64_t nnz, double frame_dt, double stable_dt) {
  IntegratorCost c{.tets = tets, .nnz = nnz, .frame_dt = frame_dt, .stable_dt = stable_dt};
  const double substeps = stable_dt > 0 ? std::ceil(frame_dt / stable_dt) : 1.0;
  const auto t = static_cast<double>(tets);
  const auto z = static_cast<double>(nnz);
  c.explicit_seconds = substeps * t * kExplicitTetStepSeconds;
  c.implicit_seconds =
      kNewtonIterations * (kNewtonOverheadSeconds + t * kAssemblyTetSeconds + kPcgIterations * z * kPcgNnzSeconds) +
      z * kFactorNnzSeconds / kFramesPerFactor;
  return c;
}

v1::TimeStepPolicy::Integrator IntegratorPolicy(v1::TimeStepPolicy::Integrator scene, const std::string& option) {
  if (option.empty()) return scene;
  if (option == "explicit") return v1::TimeStepPolicy::INTEGRATOR_SYMPLECTIC_EULER;
  if (option == "implicit") return v1::TimeStepPolicy::INTEGRATOR_IMPLICIT;
  if (option == "auto") return v1::TimeStepPolicy::INTEGRATOR_AUTO;
  ThrowInputError({.field = "integrator"}, fmt::format("unknown integrator '{}' (explicit, implicit, auto)", option));
}

IntegratorKind ChooseIntegrator(v1::TimeStepPolicy::Integrator policy, const IntegratorCost& cost,
                                bool double_precision, const std::string& source) {
  switch (policy) {
    case v1::TimeStepPolicy::INTEGRATOR_IMPLICIT:
      if (!double_precision) {
        ThrowInputError({.file = source, .field = "time_step.integrator"},
                        "INTEGRATOR_IMPLICIT needs double precision (time_step.precision / --precision)");
      }
      return IntegratorKind::kImplicit;
    case v1::TimeStepPolicy::INTEGRATOR_AUTO:
      if (!double_precision) return IntegratorKind::kExplicit;
      return cost.implicit_seconds * kImplicitMargin < cost.explicit_seconds ? IntegratorKind::kImplicit
                                                                             : IntegratorKind::kExplicit;
    default:
      return IntegratorKind::kExplicit;
  }
}

}  // namespace cutsim::sim
