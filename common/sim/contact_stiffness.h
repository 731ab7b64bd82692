#pragma once
/// @file
/// The tissue's stiffness at the tool contact, for the haptic side's local
/// model: free functions of the FEM model and positions, no state of their
/// own beyond reusable scratch.
///
/// The tissue's point stiffness along a unit direction u for a load spread
/// as wᵢ·u over a facet's nodes is k_t = 1/(fᵀK⁻¹f), f = w ⊗ u, K = −∂f/∂x
/// the tangent (StVK, or the nodal-pressure element's deviatoric and
/// volumetric parts) at the current positions of the free nodes within
/// kStiffnessRings rings of the facet, with every element touching them;
/// nodes beyond are held. The facet nodes' diagonal blocks alone (every
/// other node held) overestimate it several times; they remain the fallback
/// when the patch cannot be factored.

#include <array>
#include <cstdint>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Sparse>

#include "common/fem/model.h"

namespace cutsim::sim {

/// Rings of neighbours around the loaded facet that PatchStiffness frees.
inline constexpr int kStiffnessRings = 2;

/// Scratch of PatchStiffness, reused across calls (no allocation once
/// warm). `column` maps a node id to its unknown index and stays −1
/// between calls.
struct PatchScratch {
  std::vector<int32_t> column;    ///< #node_capacity: node → unknown index, −1 if none
  std::vector<int32_t> unknown;   ///< node ids of the patch, in discovery order
  std::vector<int32_t> tets;      ///< elements touching an unknown, once each
  std::vector<Eigen::Triplet<double>> entries;  ///< lower triangle of the patch K
};

/// StVK tangent K = −∂f/∂x of element `t` at positions `x` (#N·3, m),
/// with the element's own λ: with the nodal-pressure element the
/// deviatoric part only (its volumetric tangent couples whole node patches
/// and enters the patch solve and NodeNormalStiffness separately).  // 12×12
template <typename T>
[[nodiscard]] Eigen::Matrix<double, 12, 12> ElementStiffness(const fem::Model<T>& model, const T* x, int32_t t);

/// nᵀKᵢᵢn for one node: its diagonal block of the incident element tangents
/// along unit `n`, N/m.
template <typename T>
[[nodiscard]] double NodeNormalStiffness(const fem::Model<T>& model, const T* x, int32_t node,
                                         const Eigen::Vector3d& n);

/// The patch solve: 1/(fᵀK⁻¹f) over the unknowns already in
/// `scratch.unknown` (mapped by `scratch.column`), f = wᵢ·u on `nodes`; 0 if
/// the patch matrix cannot be factored or the compliance is not positive.
template <typename T>
[[nodiscard]] double SolvePatchCompliance(const fem::Model<T>& model, const T* x,
                                          const std::array<int32_t, 3>& nodes, const Eigen::Vector3d& w,
                                          const Eigen::Vector3d& u, PatchScratch& scratch);

/// Point stiffness of the tissue (N/m) along unit `u` for the load wᵢ·u on
/// `nodes` (file comment): the patch of free nodes within kStiffnessRings
/// rings, solved by SolvePatchCompliance; the diagonal estimate
/// Σ wᵢ·NodeNormalStiffness if that fails.
template <typename T>
[[nodiscard]] double PatchStiffness(const fem::Model<T>& model, const T* x, const std::array<int32_t, 3>& nodes,
                                    const Eigen::Vector3d& w, const Eigen::Vector3d& u, PatchScratch& scratch);

/// The contact spring `k_contact` in series with the tissue's `k_tissue`
/// (N/m): k·k_t/(k + k_t), 0 when both are 0.
[[nodiscard]] double SeriesStiffness(double k_contact, double k_tissue);

}  // namespace cutsim::sim
