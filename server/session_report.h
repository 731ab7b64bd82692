#pragma once
/// @file
/// The session report (`--session-report FILE`): the session's measures,
/// the score against the scene's planned incision, and the series behind
/// them, as JSON (FILE, protobuf's JSON printer) plus a plot of the force
/// and of the cut's deviation from the plan over time (FILE with .svg).

#include <string>

#include "common/sim/simulation.h"
#include "cutsim/v1/report.pb.h"
#include "cutsim/v1/wire.pb.h"

namespace cutsim::server {

/// The session's measures, cut count and tool (pose, force, contact) into
/// an observer frame, as the live session and the debrief publish them.
void FillObservedSession(const sim::Simulation& simulation, v1::ObserverSession* observed);

[[nodiscard]] v1::SessionReport MakeSessionReport(const sim::Simulation& simulation, const std::string& session,
                                                  const std::string& scene);

/// The plot as an SVG document: |f| on the tool over time, and below it the
/// deviation of each scored cut step with the plan's tolerance band.
[[nodiscard]] std::string SessionPlotSvg(const v1::SessionReport& report);

/// The plot's path beside the report FILE: FILE with the extension .svg.
[[nodiscard]] std::string SessionPlotPath(const std::string& path);

/// Writes FILE and FILE's .svg sibling, each atomically
/// (common/core/input_file.h). Throws InputError naming the file on any
/// write error.
void WriteSessionReport(const std::string& path, const v1::SessionReport& report);

}  // namespace cutsim::server
