#pragma once
/// @file
/// An objective score of a cut against a planned incision (the scene's
/// `planned_incision`: a polyline on the tissue's surface and a depth).
///
/// Everything is measured in the rest frame, i.e. on the tissue as it was
/// meshed, so stretching the tissue while cutting does not count as
/// deviation:
/// - each cut step contributes the point where the blade met the surface
///   (the contact facet's barycentric point on the rest mesh); its
///   **deviation** is its distance from the planned line across the
///   surface, i.e. with the component along the plan's normal removed;
/// - the **depth reached** is the deepest node of an opened face within
///   the plan's tolerance band, measured below the nearest point of the
///   plan along its normal; the **depth error** is reached − planned;
/// - **coverage** is the fraction of the planned cut surface that is opened:
///   the plan swept from the surface to the planned depth along −normal is
///   a grid of cells (arc length × depth); the opened faces within the band
///   are projected onto it (arc of the nearest plan point, depth below it)
///   and cover the cells whose centres they contain. Only cells that lie in
///   the tissue count (SetTissue), so a complete transection on the line
///   scores 1 whatever the cross-section's shape, a cut to half the depth
///   ½, and a cut the blade crossed in one step counts the whole wall it
///   opened;
/// - **damage outside the incision**: the opened area outside the band, the
///   volume cut off and the largest stress outside the incision
///   (SessionMetrics), peak and mean force and time in contact.

#include <cstdint>
#include <optional>
#include <span>
#include <vector>

#include <Eigen/Core>

#include "common/mesh/tet_mesh.h"
#include "common/sim/types.h"
#include "cutsim/v1/metrics.pb.h"

namespace cutsim::sim {

/// A planned incision, in the rest frame.
struct PlannedIncision {
  std::vector<Eigen::Vector3d> points;                   ///< m, ≥ 2, on the surface, in cutting order
  Eigen::Vector3d normal = Eigen::Vector3d::UnitZ();     ///< unit, outward: depth is measured along −normal
  double depth = 0.0;                                    ///< m, planned depth below the surface
  double tolerance = 0.002;                              ///< m, half-width of the band counted as the incision
};

/// One cut step's point on the rest surface.
struct CutPoint {
  double t = 0.0;                                       ///< s, simulated time of the cut step
  Eigen::Vector3d rest = Eigen::Vector3d::Zero();       ///< m, rest frame
  double deviation = 0.0;                               ///< m, from the planned line across the surface
};

/// The cut against the plan: the message itself (cutsim/v1/metrics.proto),
/// which the scorer fills and the reports print.
using IncisionScore = v1::IncisionScore;

class IncisionScorer {
 public:
  /// At most this many cut points are kept (a cut step per physics frame for
  /// hours); later ones still count in the mean and maximum.
  static constexpr size_t kMaxKeptCutPoints = size_t{1} << 20;

  /// `plan` as checked by the scene loader (≥ 2 distinct points, unit
  /// normal, depth and tolerance > 0).
  explicit IncisionScorer(PlannedIncision plan);

  /// Cells of the planned cut surface along the plan and in depth.
  static constexpr int kArcCells = 128;
  static constexpr int kDepthCells = 32;

  [[nodiscard]] const PlannedIncision& plan() const { return plan_; }

  /// The tissue at rest: the cells of the planned cut surface whose centres
  /// lie in one of its tets are the ones coverage counts. Without it every
  /// cell counts. O(cells × tets) once, at load.
  void SetTissue(const mesh::TetMesh& rest);

  /// Distance from the planned line across the surface, m.
  [[nodiscard]] double Deviation(const Eigen::Vector3d& rest_point) const;

  /// A cut step at time `t` whose blade met the surface at `rest_point`.
  void AddCutPoint(double t, const Eigen::Vector3d& rest_point);

  /// The score now: the cut points so far, the opened faces of `surface`
  /// (#S×3 by slot, dead rows −1) flagged in `opened` (#S) on the rest
  /// positions `rest` (#N·3), and the session's measures.
  template <typename T>
  [[nodiscard]] IncisionScore Score(const T* rest, const mesh::Triangles& surface, std::span<const uint8_t> opened,
                                    const SessionMetrics& metrics, double sim_time) const;

  [[nodiscard]] const std::vector<CutPoint>& cut_points() const { return kept_; }
  /// After a checkpoint restore: the cut points up to the save.
  void Restore(std::span<const CutPoint> points);

 private:
  struct Nearest {
    Eigen::Vector3d point;  ///< on the plan, m
    double distance;        ///< across the surface, m
    double arc;             ///< arc length along the plan to `point`, m
  };
  /// The plan's point nearest to `p` across the surface.
  [[nodiscard]] Nearest NearestOnPlan(const Eigen::Vector3d& p) const;
  /// The plan's point at arc length `arc` (m) from its start.
  [[nodiscard]] Eigen::Vector3d PointAt(double arc) const;
  /// Marks in `covered` (#kArcCells·kDepthCells) the cells whose centres
  /// lie in the triangle a, b, c projected onto the planned cut surface.
  void CoverCells(const Eigen::Vector3d& a, const Eigen::Vector3d& b, const Eigen::Vector3d& c,
                  std::vector<uint8_t>& covered) const;

  PlannedIncision plan_;
  double length_ = 0.0;  // m, the plan's arc length
  std::vector<uint8_t> in_tissue_;  // #kArcCells·kDepthCells, cell (i, j) at i·kDepthCells + j
  int64_t cells_in_tissue_ = 0;
  std::vector<CutPoint> kept_;
  int64_t count_ = 0;
  double sum_deviation_ = 0.0;
  double max_deviation_ = 0.0;
};

}  // namespace cutsim::sim
