#pragma once
/// @file
/// The session's measures for the instructor (SessionMetrics, the message
/// of cutsim/v1/metrics.proto),
/// computed from the physics as the session runs: the frame's last stage.
///
/// Per frame, from the tool's report: the force on the tool (peak, and the
/// time-mean over the time in contact), the travel of the blade tip and the
/// time in contact. Per sample, at a fixed period of simulated time, from
/// the whole mesh:
/// - the rest volume of the pieces cuts separated from the anchored body
///   (the pieces holding a fixed node; with none fixed, the largest piece);
/// - the rest area of the faces cuts opened;
/// - the largest von Mises stress outside the incision, over the anchored
///   body. The incision is the tets that share a node with an opened face,
///   with the facet the blade touches, or lie within a radius of the blade
///   in contact, grown by `incision_rings` rings of tets (tets sharing a
///   node). The stress concentrates at the blade's
///   edge and along the cut's walls by construction; what an instructor
///   reads is the load the trainee puts on the tissue around them.
///
/// The samples fall on frame ends where ⌊t / period⌋ changes, so a replay of
/// the same frames takes the same samples and reports the same numbers.

#include <array>
#include <cstdint>
#include <span>
#include <vector>

#include "common/cutting/cut_mesh.h"
#include "common/fem/model.h"
#include "common/mesh/tet_mesh.h"
#include "common/sim/types.h"
#include "cutsim/v1/metrics.pb.h"

namespace cutsim::sim {

/// What the whole-mesh sample needs to know of the cuts and the contact.
struct IncisionView {
  /// #≥N or empty: 1 where the node lies on a face a cut opened.
  std::span<const uint8_t> wall_nodes;
  /// Nodes of the facet the blade touches (−1: no contact).
  std::array<int32_t, 3> contact_nodes{-1, -1, -1};
  /// The blade while it touches the tissue: the nodes within `blade_radius`
  /// of the segment tip → tip + blade_length·blade_dir (world) are seeds
  /// too, since the blade's edge loads the tissue along its whole length.
  bool blade_touching = false;
  Eigen::Vector3d blade_tip = Eigen::Vector3d::Zero();  ///< m, world
  Eigen::Vector3d blade_dir = Eigen::Vector3d::UnitZ(); ///< unit, tip → handle
  double blade_length = 0.0;                            ///< m
  double blade_radius = 0.0;                            ///< m
  /// Live surface triangles by slot (#S×3, dead rows −1) and their opened
  /// flags (#S); null / empty without cutting.
  const mesh::Triangles* surface = nullptr;
  std::span<const uint8_t> opened;
  /// The cut complex, for its face-connected pieces (null: uncut scene).
  const cutting::CutMesh* cut = nullptr;
};

template <typename T>
class SessionMeter {
 public:
  /// At most this many force samples are kept (29 h at 10 Hz).
  static constexpr size_t kMaxForceSamples = size_t{1} << 20;

  struct Options {
    double sample_period = 0.1;   ///< s of simulated time between whole-mesh samples
    int incision_rings = 1;       ///< rings of tets added around the incision's own tets
    int threads = 1;
  };

  explicit SessionMeter(Options options);

  /// The frame's tool measures. `frame_time`: s; `tool`: the report at the
  /// frame's end.
  void AddFrame(double frame_time, const ToolReport& tool);

  /// Whether the frame that ended at `sim_time` s takes a whole-mesh sample.
  [[nodiscard]] bool SampleDue(double sim_time) const;

  /// The whole-mesh measures on the model's current positions `x` (#N·3).
  /// The pieces and the opened area are recomputed only when the topology
  /// version changed since the last sample.
  void Sample(const fem::Model<T>& model, const T* x, const IncisionView& incision, double sim_time);

  [[nodiscard]] const SessionMetrics& metrics() const { return metrics_; }
  /// The force on the tool at each sample, for the session report's plot.
  [[nodiscard]] const std::vector<ForceSample>& force_series() const { return series_; }
  /// What the meter carries from one frame to the next besides the
  /// measures: the tool's last tip (for the path length) and the last force.
  struct Running {
    bool have_tip = false;
    Eigen::Vector3d last_tip = Eigen::Vector3d::Zero();  ///< m
    double last_force = 0.0;                              ///< N
  };
  [[nodiscard]] Running running() const { return {have_tip_, last_tip_, last_force_}; }
  /// After a checkpoint restore: carries the session's measures, force
  /// series and running state on.
  void Restore(const SessionMetrics& metrics, std::span<const ForceSample> series, double sim_time,
               const Running& running);

 private:
  void UpdatePieces(const fem::Model<T>& model, const IncisionView& incision);
  void MarkIncision(const fem::Model<T>& model, const T* x, const IncisionView& incision);

  Options options_;
  SessionMetrics metrics_;
  bool have_tip_ = false;
  double last_force_ = 0.0;         // N, |f| at the last frame's end (0 out of contact)
  std::vector<ForceSample> series_;
  Eigen::Vector3d last_tip_ = Eigen::Vector3d::Zero();
  int64_t last_sample_slot_ = -1;
  uint64_t pieces_version_ = ~uint64_t{0};
  std::vector<uint8_t> cut_off_;    // #T: tet in a piece separated from the anchored body
  std::vector<uint8_t> node_mark_;  // #N scratch: node in the incision (grown ring by ring)
  std::vector<uint8_t> tet_mark_;   // #T scratch: tet in the incision
  std::vector<double> tet_volume_;     // #T scratch: a quarter of each tet's current volume, m³
  std::vector<double> node_pressure_;  // #N scratch: the nodal-pressure element's pressures, Pa
};

extern template class SessionMeter<float>;
extern template class SessionMeter<double>;

}  // namespace cutsim::sim
