#pragma once
/// @file
/// The session's measures (SessionMetrics, types.h) to and from their
/// message (cutsim/v1/metrics.proto), for the observer stream, the reports
/// and checkpoints.

#include <string>

#include "common/sim/types.h"
#include "cutsim/v1/metrics.pb.h"

namespace cutsim::sim {

void SessionMetricsToProto(const SessionMetrics& metrics, v1::SessionMetrics* out);

/// Checks that every field is finite and not negative and that the mean
/// does not exceed the peak; throws InputError naming `source` and the
/// field otherwise.
[[nodiscard]] SessionMetrics SessionMetricsFromProto(const v1::SessionMetrics& metrics, const std::string& source);

}  // namespace cutsim::sim
