#pragma once
/// @file
/// Where a frame's wall time goes: the stages of Simulation::AdvanceFrame
/// and, inside its dynamics, the implicit step's phases (MuJoCo's mjTIMER
/// split, per frame). The real-time server aggregates them per session.

#include <array>
#include <cstddef>
#include <cstdint>

namespace cutsim::sim {

/// The stages of Simulation::AdvanceFrame, in the order it runs them.
enum class FrameStage : uint8_t {
  kPrescribe,  ///< prescribed motion of boundary nodes
  kContact,    ///< the tool's move and contact search
  kDynamics,   ///< the tissue's step (explicit substeps or one implicit step)
  kCut,        ///< the cut test and, when it cuts, the topology and FEM update
  kMeasure,    ///< the session's measures (whole-mesh samples at their period)
};
inline constexpr int kNumFrameStages = 5;

/// "prescribe", "contact", "dynamics", "cut", "measure".
[[nodiscard]] constexpr const char* FrameStageName(FrameStage stage) {
  constexpr std::array<const char*, kNumFrameStages> kNames{"prescribe", "contact", "dynamics", "cut", "measure"};
  return kNames[static_cast<size_t>(stage)];
}

/// The implicit step's phases inside kDynamics (fem::ImplicitPhase, in its
/// order; frame_times.cc checks the count).
inline constexpr int kNumDynamicsPhases = 5;
/// fem::ImplicitPhaseName of phase `i` (0 ≤ i < kNumDynamicsPhases).
[[nodiscard]] const char* DynamicsPhaseName(int i);

/// Wall time of one frame's stages, s.
struct FrameTimes {
  std::array<double, kNumFrameStages> stage_seconds{};
  /// The implicit step's phases inside kDynamics (fem::ImplicitPhase; zero
  /// for the explicit step), summed over a recovery's substeps.
  std::array<double, kNumDynamicsPhases> dynamics_seconds{};

  [[nodiscard]] double stage(FrameStage s) const { return stage_seconds[static_cast<size_t>(s)]; }
};

}  // namespace cutsim::sim
