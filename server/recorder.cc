#include "server/recorder.h"

#include <algorithm>
#include <cmath>
#include <csignal>
#include <fstream>
#include <iterator>
#include <span>

#include <fmt/format.h>

#include "common/core/error.h"
#include "common/core/input_file.h"
#include "common/core/log.h"
#include "common/core/stop.h"
#include "common/sim/metrics_proto.h"
#include "common/sim/scene_loader.h"
#include "common/transport/codec.h"
#include "common/transport/proto_vec.h"
#include "server/session_report.h"

namespace cutsim::server {
namespace {

std::string Channel(const std::string& session, const char* kind) {
  return fmt::format("CUTSIM_{}_REC_{}", session, kind);
}

int64_t RealtimeUs() {
  timespec ts{};
  clock_gettime(CLOCK_REALTIME, &ts);
  return static_cast<int64_t>(ts.tv_sec) * 1'000'000 + ts.tv_nsec / 1000;
}

uint64_t FileHash(const std::filesystem::path& path) {
  const std::string text = ReadInputFile(path.string(), "scene file", sim::kMaxSceneFileBytes);
  uint64_t h = 0xcbf29ce484222325ULL;  // FNV-1a 64
  for (const char c : text) {
    h ^= static_cast<uint8_t>(c);
    h *= 0x100000001b3ULL;
  }
  return h;
}

/// The event as a field of an error: "event <n>".
std::string EventField(const transport::LcmLogEvent& e, std::string_view field = {}) {
  return field.empty() ? fmt::format("event {}", e.eventnum) : fmt::format("event {}: {}", e.eventnum, field);
}

uint64_t TopologyDigest(const sim::Simulation& simulation, sim::MeshView* view) {
  simulation.FillMeshView(*view);
  return transport::TopologyHash(simulation.topology_version(), view->tets, view->surface,
                                 view->opened);
}

template <class Msg>
Msg Parse(const transport::LcmLogEvent& e, const std::filesystem::path& path) {
  Msg msg;
  transport::DecodeError err;
  if (!transport::DecodeInto(std::span<const uint8_t>(e.data), msg, e.channel, &err)) {
    ThrowInputError({.file = path.string(), .field = EventField(e, e.channel)}, "recording: " + err.Message());
  }
  return msg;
}

bool EndsWith(const std::string& s, const std::string& suffix) {
  return s.size() >= suffix.size() && s.compare(s.size() - suffix.size(), suffix.size(), suffix) == 0;
}

}  // namespace

const char* BuildClass() {
#if defined(__FMA__) || defined(__AVX2__) || defined(__AVX__)
  return "native-fma";
#else
  return "portable";
#endif
}

uint64_t FinalMeshHash(const sim::Simulation& simulation, double quantum, sim::MeshView* view) {
  simulation.FillMeshView(*view);
  const auto quantise = [quantum](const mesh::Positions& p) {
    transport::QuantisedPositions q(p.rows(), 3);
    for (Eigen::Index i = 0; i < p.rows(); ++i) {
      for (int c = 0; c < 3; ++c) q(i, c) = transport::Quantise(p(i, c), quantum);
    }
    return q;
  };
  const uint64_t state = transport::MeshHash(simulation.topology_version(), quantise(view->world),
                                             view->tets, view->surface, view->opened);
  return transport::CombineHashes(state, transport::PositionsHash(quantise(view->rest)));
}

// ---- SessionRecorder ------------------------------------------------------------

SessionRecorder::SessionRecorder(const std::filesystem::path& path, const std::string& session,
                                 const std::string& scene_path, const sim::Simulation& simulation)
    : log_(path),
      frame_channel_(Channel(session, "FRAME")),
      end_channel_(Channel(session, "END")),
      last_version_(simulation.topology_version()) {
  const sim::SimulationSummary s = simulation.QuickSummary();
  v1::RecordHeader header;
  header.set_session(session);
  header.set_scene(scene_path);
  header.set_precision(s.precision);
  header.set_threads(s.threads);
  header.set_quantum(kRecordQuantum);
  header.set_build(BuildClass());
  header.set_scene_hash(FileHash(scene_path));
  header.set_frame_dt(simulation.frame_dt());
  Write(Channel(session, "HEADER"), header);
  log_.Flush();
}

void SessionRecorder::Write(const std::string& channel, const google::protobuf::MessageLite& msg) {
  buffer_.clear();
  msg.AppendToString(&buffer_);
  log_.Write(channel,
             std::span<const uint8_t>(reinterpret_cast<const uint8_t*>(buffer_.data()), buffer_.size()),
             RealtimeUs());
}

void SessionRecorder::Frame(double frame_time, const std::optional<sim::ToolPose>& applied,
                            const sim::Simulation& simulation) {
  if (!error_.empty()) return;
  frame_msg_.Clear();
  frame_msg_.set_frame(++frames_);
  frame_msg_.set_frame_time(frame_time);
  if (applied) {
    frame_msg_.set_has_tool(true);
    transport::SetVec3(applied->tip, frame_msg_.mutable_tip());
    transport::SetVec3(applied->blade_dir, frame_msg_.mutable_blade_dir());
  }
  const uint64_t version = simulation.topology_version();
  frame_msg_.set_topology_version(version);
  frame_msg_.set_cuts(simulation.has_tool() ? simulation.Tool().cuts : 0);
  if (version != last_version_) {
    frame_msg_.set_topology_hash(TopologyDigest(simulation, &view_));
    last_version_ = version;
  }
  if (frames_ % kRecordHashEveryFrames == 0) frame_msg_.set_mesh_hash(FinalMeshHash(simulation, kRecordQuantum, &view_));
  try {
    Write(frame_channel_, frame_msg_);
    // Through to the kernel each frame: a full disk shows at once, and a
    // crash loses at most this frame.
    log_.Flush();
  } catch (const InputError& e) {
    error_ = e.what();
    Log().error("recording stopped at frame {}: {}", frames_, error_);
  }
}

uint64_t SessionRecorder::Finish(const sim::Simulation& simulation) {
  v1::RecordEnd end;
  end.set_frames(frames_);
  end.set_topology_version(simulation.topology_version());
  end.set_cuts(simulation.has_tool() ? simulation.Tool().cuts : 0);
  end.set_mesh_hash(FinalMeshHash(simulation, kRecordQuantum, &view_));
  end.set_sim_time(simulation.sim_time());
  *end.mutable_metrics() = simulation.Metrics();
  if (const auto score = simulation.Score()) *end.mutable_score() = *score;
  if (!error_.empty()) ThrowInputError({.file = "", .field = "--record"}, "recording incomplete: " + error_);
  Write(end_channel_, end);
  log_.Close();
  return end.mesh_hash();
}

// ---- Replay ------------------------------------------------------------------------

namespace {

/// The recording's first event, its header. Throws naming the file when the
/// log is not a recording.
v1::RecordHeader ReadHeader(transport::LcmLogReader& reader, const std::filesystem::path& path) {
  auto first = reader.Next();
  if (!first || !EndsWith(first->channel, "_REC_HEADER")) {
    ThrowInputError({.file = path.string(), .field = "event 0"},
                    "not a cutsim recording: the first event must be on CUTSIM_<session>_REC_HEADER");
  }
  v1::RecordHeader header = Parse<v1::RecordHeader>(*first, path);
  sim::CheckThreads(header.threads(), {.file = path.string(), .field = "RecordHeader.threads"});
  if (header.frame_dt() != 0.0 && !(header.frame_dt() >= sim::kMinFrameDt && header.frame_dt() <= sim::kMaxFrameDt)) {
    ThrowInputError({.file = path.string(), .field = "RecordHeader.frame_dt"},
                    fmt::format("{:g} s is outside [{:g}, {:g}] s", header.frame_dt(), sim::kMinFrameDt,
                                sim::kMaxFrameDt));
  }
  if (!(header.quantum() >= 0.0 && header.quantum() < 1.0)) {
    ThrowInputError({.file = path.string(), .field = "RecordHeader.quantum"},
                    fmt::format("{:g} m is outside [0, 1) m", header.quantum()));
  }
  return header;
}

/// The scene to replay: the override, else as recorded, else a file of the
/// same name next to the recording. Throws when it is missing or is not the
/// recorded scene; warns when this build rounds differently from the
/// recorder's.
std::filesystem::path ReplayScene(const v1::RecordHeader& header, const std::filesystem::path& path,
                                  const std::string& scene_override) {
  const std::string file = path.string();
  std::filesystem::path scene = scene_override.empty() ? header.scene() : scene_override;
  if (scene_override.empty() && !std::filesystem::exists(scene)) {
    scene = path.parent_path() / std::filesystem::path(header.scene()).filename();
  }
  if (!std::filesystem::exists(scene)) {
    ThrowInputError({.file = file, .field = "RecordHeader.scene"},
                    fmt::format("scene \"{}\" not found (give --scene)", header.scene()));
  }
  if (FileHash(scene) != header.scene_hash()) {
    ThrowInputError({.file = file, .field = "RecordHeader.scene_hash"},
                    fmt::format("scene {} differs from the recorded one", scene.string()));
  }
  if (header.build() != BuildClass()) {
    Log().warn("{}: recorded by a {} build, replayed by a {} build: floating-point rounding differs "
               "and the replay may not match",
               file, header.build(), BuildClass());
  }
  return scene;
}

/// One RecordFrame event, checked: frame times within the scene limits (so
/// a hostile time cannot make one frame run forever), a finite tool pose,
/// frames numbered in order after `frames_so_far`. Throws naming the file
/// and event.
v1::RecordFrame ParseFrame(const transport::LcmLogEvent& e, const std::filesystem::path& path,
                           uint64_t frames_so_far) {
  auto f = Parse<v1::RecordFrame>(e, path);
  if (!(f.frame_time() >= sim::kMinFrameDt && f.frame_time() <= sim::kMaxFrameDt)) {
    ThrowInputError({.file = path.string(), .field = EventField(e, "RecordFrame.frame_time")},
                    fmt::format("frame {}: {:g} s is outside [{:g}, {:g}] s", f.frame(), f.frame_time(),
                                sim::kMinFrameDt, sim::kMaxFrameDt));
  }
  if (f.has_tool() && !(std::isfinite(f.tip().x()) && std::isfinite(f.tip().y()) && std::isfinite(f.tip().z()) &&
                        std::isfinite(f.blade_dir().x()) && std::isfinite(f.blade_dir().y()) &&
                        std::isfinite(f.blade_dir().z()))) {
    ThrowInputError({.file = path.string(), .field = EventField(e, "RecordFrame.tip/blade_dir")},
                    fmt::format("frame {}: the tool pose is NaN or infinite", f.frame()));
  }
  if (f.frame() != frames_so_far + 1) {
    ThrowInputError({.file = path.string(), .field = EventField(e, "RecordFrame.frame")},
                    fmt::format("frame {} follows frame {}: the recording is incomplete", f.frame(), frames_so_far));
  }
  return f;
}

/// Feeds a recording's frames to a simulation and compares its cut
/// decisions and final mesh with the recorded ones. The first difference is
/// the replay's mismatch; a malformed recording throws naming the file and
/// event.
class Replayer {
 public:
  Replayer(const std::filesystem::path& path, sim::Simulation& simulation, double quantum)
      : path_(path), simulation_(simulation), quantum_(quantum), last_version_(simulation.topology_version()) {}

  /// Replays one RecordFrame event; false when the replay must stop.
  bool Frame(const transport::LcmLogEvent& e) {
    if (ended_) ThrowInputError({.file = path_.string(), .field = EventField(e)}, "frame after the end event");
    const auto f = ParseFrame(e, path_, result_.frames);
    if (f.has_tool()) {
      simulation_.SetToolPose({{f.tip().x(), f.tip().y(), f.tip().z()},
                               {f.blade_dir().x(), f.blade_dir().y(), f.blade_dir().z()}});
    }
    if (simulation_.AdvanceFrame(f.frame_time()) != sim::SimStatus::kOk) {
      Fail(fmt::format("frame {}: the simulation stopped: {}", f.frame(), simulation_.Summary().diagnosis));
      return false;
    }
    ++result_.frames;
    if (!SameTopology(f)) return false;
    // The state at the recorded frames that carry its hash.
    if (f.mesh_hash() != 0) {
      const uint64_t hash = FinalMeshHash(simulation_, quantum_, &view_);
      if (hash != f.mesh_hash()) {
        Fail(fmt::format("frame {}: mesh hash {:016x}, recorded {:016x}", f.frame(), hash, f.mesh_hash()));
        return false;
      }
      ++result_.hashed_frames;
    }
    return true;
  }

  /// Takes the RecordEnd event: the recorded frame count and final hash.
  void End(const transport::LcmLogEvent& e) {
    const auto end = Parse<v1::RecordEnd>(e, path_);
    ended_ = true;
    result_.recorded_mesh_hash = end.mesh_hash();
    if (end.frames() != result_.frames) {
      Fail(fmt::format("{} frames replayed, {} recorded", result_.frames, end.frames()));
    }
    if (end.has_metrics()) SameMeasures("metrics", end.metrics(), simulation_.Metrics());
    if (end.has_score()) {
      const auto score = simulation_.Score();
      if (!score) {
        Fail("the recording has a score; the re-run's scene has no planned incision");
      } else {
        SameMeasures("score", end.score(), *score);
      }
    }
  }

  /// The re-run's measures (or score) against the recorded ones, field by
  /// field (every field is a double). The replay is deterministic on the
  /// recording's build class, so they agree to rounding. A field with
  /// presence (`optional`: a measure added after recordings existed) is
  /// compared only where the recording holds it.
  void SameMeasures(const char* what, const google::protobuf::Message& recorded, const google::protobuf::Message& now) {
    const auto* descriptor = recorded.GetDescriptor();
    const auto* reflection = recorded.GetReflection();
    for (int i = 0; i < descriptor->field_count(); ++i) {
      const auto* field = descriptor->field(i);
      if (field->has_presence() && !reflection->HasField(recorded, field)) continue;
      const double a = reflection->GetDouble(now, field);
      const double b = reflection->GetDouble(recorded, field);
      if (!(std::abs(a - b) <= 1e-12 * std::max(std::abs(a), std::abs(b)))) {
        Fail(fmt::format("{}.{}: {:.17g} replayed, {:.17g} recorded", what, field->name(), a, b));
      }
    }
  }

  /// Keeps the first mismatch.
  void Fail(std::string what) {
    if (result_.mismatch.empty()) result_.mismatch = std::move(what);
  }

  /// The simulation's final state against the recorded one (hashed at
  /// `quantum`, m).
  [[nodiscard]] ReplayResult Finish(double quantum) {
    result_.topology_version = simulation_.topology_version();
    result_.cuts = simulation_.has_tool() ? simulation_.Tool().cuts : 0;
    result_.sim_time = simulation_.sim_time();
    result_.metrics = simulation_.Metrics();
    result_.report = MakeSessionReport(simulation_, result_.session, result_.scene);
    result_.mesh_hash = FinalMeshHash(simulation_, quantum, &view_);
    if (result_.mismatch.empty() && result_.mesh_hash != result_.recorded_mesh_hash) {
      Fail(fmt::format("final mesh hash {:016x}, recorded {:016x}", result_.mesh_hash,
                       result_.recorded_mesh_hash));
    }
    result_.match = result_.mismatch.empty();
    return result_;
  }

  [[nodiscard]] bool ended() const { return ended_; }
  [[nodiscard]] bool failed() const { return !result_.mismatch.empty(); }
  [[nodiscard]] uint64_t frames() const { return result_.frames; }

 private:
  /// The frame's topology version, and on a frame that cut its digest, as
  /// recorded; false (a mismatch) otherwise.
  bool SameTopology(const v1::RecordFrame& f) {
    const uint64_t version = simulation_.topology_version();
    if (version != f.topology_version()) {
      Fail(fmt::format("frame {}: topology version {}, recorded {} (a cut decision differs)", f.frame(),
                       version, f.topology_version()));
      return false;
    }
    if (version == last_version_) return true;
    ++result_.cut_frames;
    last_version_ = version;
    const uint64_t digest = TopologyDigest(simulation_, &view_);
    if (f.topology_hash() != 0 && digest != f.topology_hash()) {
      // The digest covers the tets and the surface in slot order: a build
      // that splits the same nodes but fills other free surface slots
      // differs too.
      Fail(fmt::format("frame {}: topology digest {:016x}, recorded {:016x} (the cut left other tets or "
                       "other surface slots than recorded)",
                       f.frame(), digest, f.topology_hash()));
      return false;
    }
    return true;
  }

  const std::filesystem::path& path_;
  sim::Simulation& simulation_;
  double quantum_;
  ReplayResult result_;
  sim::MeshView view_;  // reused for digests
  uint64_t last_version_;
  bool ended_ = false;
};

}  // namespace

ReplayResult ReplayRecording(const std::filesystem::path& path, const std::string& scene_override) {
  transport::LcmLogReader reader(path);
  const v1::RecordHeader header = ReadHeader(reader, path);
  const std::filesystem::path scene = ReplayScene(header, path, scene_override);
  const sim::LoadedScene loaded = sim::LoadScene(scene);
  auto simulation = sim::Simulation::Create(
      loaded, {.threads = header.threads(), .precision = header.precision()});
  const double quantum = header.quantum() > 0 ? header.quantum() : kRecordQuantum;
  Replayer replayer(path, *simulation, quantum);
  while (auto e = reader.Next()) {
    if (StopRequested()) {
      replayer.Fail(fmt::format("interrupted after {} frames", replayer.frames()));
      break;
    }
    if (EndsWith(e->channel, "_REC_FRAME")) {
      if (!replayer.Frame(*e)) break;
    } else if (EndsWith(e->channel, "_REC_END")) {
      replayer.End(*e);
    }
    // Other channels (e.g. a tool stream logged alongside) are ignored.
  }
  if (!replayer.ended() && !replayer.failed() && !StopRequested()) {
    ThrowInputError({.file = path.string(), .field = "RecordEnd"},
                    "the recording has no end event (the server did not finish it)");
  }
  ReplayResult result = replayer.Finish(quantum);
  result.session = header.session();
  result.scene = scene.string();
  return result;
}

Recording ReadRecording(const std::filesystem::path& path, const std::string& scene_override) {
  transport::LcmLogReader reader(path);
  Recording r;
  r.header = ReadHeader(reader, path);
  r.scene = ReplayScene(r.header, path, scene_override);
  while (auto e = reader.Next()) {
    if (EndsWith(e->channel, "_REC_FRAME")) {
      if (r.end) ThrowInputError({.file = path.string(), .field = EventField(*e)}, "frame after the end event");
      if (r.frames.size() >= kMaxDebriefFrames) {
        ThrowInputError({.file = path.string(), .field = EventField(*e)},
                        fmt::format("more than {} frames: too long for a debrief", kMaxDebriefFrames));
      }
      const v1::RecordFrame f = ParseFrame(*e, path, r.frames.size());
      debrief::PlayerFrame frame{.frame_time = f.frame_time(), .tool = std::nullopt,
                                 .topology_version = f.topology_version()};
      if (f.has_tool()) {
        frame.tool = sim::ToolPose{{f.tip().x(), f.tip().y(), f.tip().z()},
                                   {f.blade_dir().x(), f.blade_dir().y(), f.blade_dir().z()}};
      }
      r.frames.push_back(frame);
      r.mesh_hashes.push_back(f.mesh_hash());
    } else if (EndsWith(e->channel, "_REC_END")) {
      r.end = Parse<v1::RecordEnd>(*e, path);
    }
  }
  if (r.frames.empty()) ThrowInputError({.file = path.string(), .field = "RecordFrame"}, "the recording has no frames");
  return r;
}

uint64_t RecordingHash(const Recording& recording, const sim::Simulation& simulation) {
  sim::MeshView view;
  return FinalMeshHash(simulation, recording.header.quantum() > 0 ? recording.header.quantum() : kRecordQuantum,
                       &view);
}

}  // namespace cutsim::server
