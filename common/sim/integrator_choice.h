#pragma once
/// @file
/// Which integrator steps a scene's frames: the scene's explicit symplectic
/// Euler (substeps under the stable limit), backward Euler (one implicit
/// step per frame, fem::ImplicitIntegrator), or AUTO: the cheaper of the two
/// by a cost estimate made once, at load time.
///
/// Cost of one frame of frame_dt seconds (s of one core):
///   explicit ≈ ⌈frame_dt / dt_stable⌉ · tets · kExplicitTetStepSeconds
///   implicit ≈ kNewtonIterations · (kNewtonOverheadSeconds
///                + tets · kAssemblyTetSeconds
///                + kPcgIterations · nnz · kPcgNnzSeconds)
///              + nnz · kFactorNnzSeconds / kFramesPerFactor
/// with dt_stable the explicit step the scene would take (safety factor
/// included) and nnz the scalar nonzeros of the 3N×3N stiffness pattern
/// (9 per node pair sharing an edge, both orders, plus 9 per node). The
/// constants are single-core release-build timings of the kernels
/// (bench/implicit_bench and cutsim-server's tet-steps/s); the choice is
/// only as sharp as they are, so AUTO favours explicit near the break-even
/// point (kImplicitMargin): explicit is bit-reproducible and cheaper per
/// cut.

#include <cstdint>
#include <string>

#include "common/mesh/tet_mesh.h"
#include "cutsim/v1/scene.pb.h"

namespace cutsim::sim {

/// How the tissue steps a frame.
enum class IntegratorKind : uint8_t {
  kExplicit,  ///< symplectic Euler in stable substeps
  kImplicit,  ///< one backward Euler step per frame
};

/// "explicit" or "implicit".
[[nodiscard]] const char* IntegratorName(IntegratorKind kind);

/// Single-core cost constants of the estimate (file comment), s.
inline constexpr double kExplicitTetStepSeconds = 30e-9;
inline constexpr double kNewtonIterations = 3.0;
inline constexpr double kNewtonOverheadSeconds = 50e-6;
inline constexpr double kAssemblyTetSeconds = 400e-9;
inline constexpr double kPcgIterations = 10.0;
inline constexpr double kPcgNnzSeconds = 2e-9;
inline constexpr double kFactorNnzSeconds = 100e-9;
inline constexpr double kFramesPerFactor = 20.0;
/// AUTO picks implicit only when it is estimated this many times cheaper.
inline constexpr double kImplicitMargin = 1.5;

/// The estimate's inputs and result for one frame.
struct IntegratorCost {
  int64_t tets = 0;
  int64_t nnz = 0;                ///< scalar nonzeros of the 3N×3N pattern
  double frame_dt = 0;            ///< s
  double stable_dt = 0;           ///< s, the explicit step (safety included)
  double explicit_seconds = 0;    ///< s per frame
  double implicit_seconds = 0;    ///< s per frame
};

/// Scalar nonzeros of the stiffness pattern of `tets` over `num_nodes`
/// nodes: 9 per node plus 18 per distinct edge.  // tets: #T×4
[[nodiscard]] int64_t StiffnessNonzeros(const mesh::Tets& tets, int32_t num_nodes);

/// The scene's policy, or the command line's override `option` ("" keeps
/// the scene's; "explicit", "implicit", "auto"). Throws InputError (field
/// "integrator") for another word.
[[nodiscard]] v1::TimeStepPolicy::Integrator IntegratorPolicy(v1::TimeStepPolicy::Integrator scene,
                                                              const std::string& option);

/// The estimate of the file comment.
[[nodiscard]] IntegratorCost EstimateFrameCost(int64_t tets, int64_t nnz, double frame_dt, double stable_dt);

/// The integrator for a scene: the policy's own choice, or for AUTO the
/// cheaper by `cost`. `double_precision` false: AUTO stays explicit (the
/// implicit step is double only) and IMPLICIT is an InputError naming
/// `source` and the field time_step.integrator.
[[nodiscard]] IntegratorKind ChooseIntegrator(v1::TimeStepPolicy::Integrator policy, const IntegratorCost& cost,
                                              bool double_precision, const std::string& source);

}  // namespace cutsim::sim
