#include "server/history.h"

#include <chrono>
#include <exception>

#include "common/core/log.h"

namespace cutsim::server {

record::SessionEntry MakeHistoryEntry(const sim::IncisionScore& score, const std::string& trainee,
                                      const std::string& session, const std::string& scene, int64_t cuts,
                                      int64_t finished_unix_s) {
  record::SessionEntry e;
  e.trainee = trainee;
  e.session = session;
  e.scene = scene;
  e.finished_unix_s = finished_unix_s;
  e.duration = score.duration();
  e.cuts = cuts;
  e.mean_deviation = score.mean_deviation();
  e.max_deviation = score.max_deviation();
  e.depth_error = score.depth_error();
  e.coverage = score.coverage();
  e.opened_area_outside = score.opened_area_outside();
  e.cut_off_volume = score.cut_off_volume();
  e.max_stress_outside = score.max_stress_outside();
  e.peak_force = score.peak_force();
  e.mean_force = score.mean_force();
  e.contact_time = score.contact_time();
  return e;
}

bool CheckHistory(const std::string& path) {
  try {
    const record::ScoreHistory history = record::ScoreHistory::Open(path);
    Log().info("score history {}: {} sessions recorded; this one is appended when it ends", path, history.size());
    return true;
  } catch (const std::exception& e) {
    Log().error("{} — the session runs, but its score will go only to its summary and report", e.what());
    return false;
  }
}

bool AppendToHistory(const std::string& path, const std::string& trainee, const std::string& session,
                     const std::string& scene, const sim::Simulation& simulation) {
  try {
    const std::optional<sim::IncisionScore> score = simulation.Score();
    if (!score) {
      Log().warn("score history {}: nothing appended: scene '{}' has no planned incision, so no score", path, scene);
      return false;
    }
    const int64_t now =
        std::chrono::duration_cast<std::chrono::seconds>(std::chrono::system_clock::now().time_since_epoch()).count();
    const auto cuts = static_cast<int64_t>(simulation.QuickSummary().cuts);
    record::ScoreHistory history = record::ScoreHistory::Open(path);
    history.Append(MakeHistoryEntry(*score, trainee, session, scene, cuts, now));
    Log().info("score history {}: appended session '{}' of trainee '{}' ({} sessions recorded for them)", path,
               session, trainee, history.ForTrainee(trainee).size());
    return true;
  } catch (const std::exception& e) {
    Log().error("{} — this session's score is NOT in the history (it is in the summary and the session report)",
                e.what());
    return false;
  }
}

}  // namespace cutsim::server
