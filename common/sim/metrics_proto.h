#pragma once
/// @file
/// The session's measures (SessionMetrics, types.h) to and from their
/// message (cutsim/v1/metrics.proto), for the observer stream, the reports
/// and checkpoints.

#include <span>
#include <string>
#include <vector>

#include "common/sim/incision_score.h"
#include "common/sim/types.h"
#include "cutsim/v1/checkpoint.pb.h"
#include "cutsim/v1/metrics.pb.h"
#include "cutsim/v1/scene.pb.h"

namespace cutsim::sim {

void SessionMetricsToProto(const SessionMetrics& metrics, v1::SessionMetrics* out);

/// Checks that every field is finite and not negative and that the mean
/// does not exceed the peak; throws InputError naming `source` and the
/// field otherwise.
[[nodiscard]] SessionMetrics SessionMetricsFromProto(const v1::SessionMetrics& metrics, const std::string& source);

void IncisionScoreToProto(const IncisionScore& score, v1::IncisionScore* out);

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
