#pragma once
/// @file
/// The server application: command line, then a headless batch run (or, with
/// the haptic link, a real-time session). Thin: the work is in common/.

#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <string_view>

#include "common/transport/journal_auth.h"
#include "common/transport/server_presence.h"
#include "common/transport/tool_auth.h"

namespace cutsim::sim {
class PeriodicCheckpointer;
}  // namespace cutsim::sim
namespace cutsim::v1 {
class JournalStats;
}  // namespace cutsim::v1

namespace cutsim::server {

struct ServerOptions {
  std::string scene;
  bool headless = false;
  std::optional<double> duration;  ///< s of simulated time
  bool until_rest = false;
  double max_time = 600.0;         ///< s, cap on simulated time for --until-rest
  std::string out;                 ///< .vtu of the final state
  int threads = 0;
  std::string precision;
  std::string integrator;          ///< "", "explicit", "implicit", "auto": overrides the scene's
  std::string log_level = "info";
  bool progress = true;
  /// The session's name: its LCM channels and DDS key in real time, and in
  /// every run the name its report and score-history row carry.
  std::string session = "default";
  bool session_given = false;      ///< --session was on the command line
  // Real-time session (not --headless).
  std::string lcm_url = "udpm://239.255.76.67:7667?ttl=0";
  uint32_t dds_domain = 0;
  std::string dds_config;          ///< file; empty: CYCLONEDDS_URI, else loopback
  double viewer_fps = 30.0;        ///< mesh frames to viewers (and trainee pages) per second
  bool realtime_priority = true;   ///< SCHED_FIFO for physics and LCM threads when permitted (--no-rt: off)
  double frame_rate = 0.0;         ///< physics frames per second; 0: the scene's frame_dt
  /// Wall-clock budget of a frame's dynamics as a fraction of the frame
  /// (--frame-budget): Newton and PCG stop there and carry the residual.
  /// Negative: the default (kDefaultFrameBudget in real time, none headless).
  double frame_budget = -1.0;
  double client_timeout = 1.0;     ///< s without tool poses: the haptic client is gone
  std::string stats_json;          ///< write the exit statistics here too
  std::string session_report;      ///< --session-report: JSON + SVG plot of the measures and score at the end
  std::string history;             ///< --history: the lab's score history (SQLite), appended at the end
  std::string trainee;             ///< --trainee: whose session this is, in --history
  // Record, replay and access control.
  std::string record;              ///< --record: LCM log of the session's inputs (real-time mode)
  std::string replay;              ///< --replay: with --headless, re-run a recording and check it
  /// --live (with --replay): play the recording to observers at real pace,
  /// with play, pause, seek, cut steps and speed (a debrief).
  bool live = false;
  std::string key_file;            ///< --key-file: hex session key; "" = $CUTSIM_SESSION_KEY, else open
  double auth_window = 2.0;        ///< s, accepted |clock difference| of signed tool messages
  // Checkpoints (common/sim/checkpoint.h).
  std::string checkpoint;          ///< --checkpoint: file saved periodically and at a clean exit
  double checkpoint_every = 5.0;   ///< s of wall time between saves; 0: only at exit
  /// With --replay --live: recorded seconds between the debrief's in-memory
  /// checkpoints (a seek simulates at most this much); --checkpoint-every.
  double debrief_checkpoint_every = 0.25;
  bool resume = false;             ///< --resume: restore --checkpoint at start if it exists
};

/// The tool-message authenticator for a session: from `--key-file`, else
/// `$CUTSIM_SESSION_KEY`, else null (an open session, logged as a warning).
/// Throws `InputError` for an unreadable or malformed key.
[[nodiscard]] std::unique_ptr<transport::HmacToolAuthenticator> MakeToolAuthenticator(
    const ServerOptions& options);

/// The event journal's signer: the session key's (`--key-file`, else
/// `$CUTSIM_SESSION_KEY`) when there is a key and a `--checkpoint`, else
/// null (an unsigned journal). Throws `InputError` for a bad key.
[[nodiscard]] std::unique_ptr<transport::HmacJournalSigner> MakeJournalSigner(const ServerOptions& options);

/// Exit status when the run itself succeeded but an output (recording,
/// checkpoint, statistics, final state) could not be written completely.
inline constexpr int kExitOutputFailed = 5;
/// Exit status of a headless run that finished with every output written,
/// but whose implicit steps did not all reach their force tolerance (the
/// summary's status "unconverged"): its numbers are not the answer to the
/// stated tolerance. (3: stepping stopped; 2: bad input; 6 is a duplicate server.)
inline constexpr int kExitUnconverged = 7;
/// The real-time default of --frame-budget: the implicit step gets 60 % of
/// the frame, the rest is for the cut step, the local model's stiffness,
/// the viewers' frame and the pacing's margin.
inline constexpr double kDefaultFrameBudget = 0.6;

/// One server per session: when another server already serves `session`,
/// logs that (naming it, then `advice`) and returns false; else starts
/// announcing this one and returns true.
bool ClaimSession(transport::ServerPresence& presence, const std::string& session, std::string_view advice);

/// Runs `write`; logs and returns false if it throws.
bool WriteOutput(const std::function<void()>& write);

/// The event journal's counters into `out` (nothing when checkpoints are off).
void FillJournalStats(const sim::PeriodicCheckpointer& checkpointer, v1::JournalStats* out);

/// At exit: writes what the event journal holds queued; false (logged with
/// the file) when any journal write failed, which makes the exit status
/// kExitOutputFailed as for any lost output.
bool FinishJournal(sim::PeriodicCheckpointer& checkpointer);

class ServerApp {
 public:
  /// Returns -1 to continue, or an exit code (help, version, bad flags).
  int ParseArgs(int argc, char** argv);
  /// Runs what the flags ask; returns the process exit code.
  int Run();

 private:
  int RunHeadless();
  int RunRealtime();
  int RunReplay();
  int RunDebrief();

  ServerOptions options_;
};

}  // namespace cutsim::server
