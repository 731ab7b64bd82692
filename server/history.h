#pragma once
/// @file
/// The server's side of the lab's score history (`--history FILE --trainee
/// NAME`, common/record): a finished session's score appended for its
/// trainee. The history never stops a session: every failure is logged
/// naming the file, and the score still goes to the summary and the session
/// report.

#include <optional>
#include <string>

#include "common/record/score_history.h"
#include "common/sim/incision_score.h"
#include "common/sim/simulation.h"

namespace cutsim::server {

/// The history entry of a finished session scored as `score`.
[[nodiscard]] record::SessionEntry MakeHistoryEntry(const sim::IncisionScore& score, const std::string& trainee,
                                                    const std::string& session, const std::string& scene,
                                                    int64_t cuts, int64_t finished_unix_s);

/// At start: opens the history so that a bad file is reported now, not at
/// the end of the session. Logs what is wrong; never throws. True when the
/// history is usable.
bool CheckHistory(const std::string& path);

/// At the end: appends the session's score for `trainee` (a session
/// without a score, its scene having no planned incision, appends nothing
/// and says so). Logs a failure naming the file; never throws. True when
/// appended.
bool AppendToHistory(const std::string& path, const std::string& trainee, const std::string& session,
                     const std::string& scene, const sim::Simulation& simulation);

}  // namespace cutsim::server
