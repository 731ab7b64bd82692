#pragma once
/// @file
/// The session's measures checked on their way in (checkpoints), and the
/// session report's series to and from their message.

#include <span>
#include <string>
#include <vector>

#include "common/sim/incision_score.h"
#include "common/sim/types.h"
#include "cutsim/v1/checkpoint.pb.h"
#include "cutsim/v1/metrics.pb.h"
#include "cutsim/v1/scene.pb.h"

namespace cutsim::sim {

/// The measures a checkpoint holds, checked: every field (the message's
/// fields are all doubles) finite and not negative, the mean force not above
/// the peak, the sample count whole; throws InputError naming `source` and
/// the field otherwise.
[[nodiscard]] SessionMetrics SessionMetricsFromProto(const v1::SessionMetrics& metrics, const std::string& source);

/// The run's summary into every field of `report` that bears the name of a
/// summary entry (the headless summary, the server's session statistics):
/// counts as uint32 (saturated), times and energies as doubles, status and
/// names as strings; `report`'s other fields are left as they are. The
/// summary's names are the ones SimulationSummary uses, with `nodes`,
/// `tets`, `free_nodes` for its counts and the implicit counters at top
/// level. Throws std::logic_error if a field of that name has another type.
void SummaryToReport(const SimulationSummary& summary, google::protobuf::Message* report);

/// The names SummaryToReport fills, for tests that hold a report message to
/// them.
[[nodiscard]] std::vector<std::string> SummaryFieldNames();

/// The scene's planned incision as checked by the scene loader.
[[nodiscard]] PlannedIncision PlanOf(const v1::PlannedIncision& plan);

/// The session report's series a checkpoint keeps.
struct SessionSeries {
  std::vector<ForceSample> force;
  std::vector<CutPoint> cut_points;
};
void SeriesToProto(std::span<const ForceSample> force, std::span<const CutPoint> cut_points, v1::CheckpointBody* out);
/// Checks the sizes (whole rows, within the kept caps) and that every value
/// is finite; throws InputError naming `source` and the field otherwise.
[[nodiscard]] SessionSeries SeriesFromProto(const v1::CheckpointBody& body, const std::string& source);

}  // namespace cutsim::sim
