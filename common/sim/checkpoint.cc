#include "common/sim/checkpoint.h"

#include <fcntl.h>
#include <unistd.h>

#include <cerrno>
#include <chrono>
#include <cmath>
#include <cstring>
#include <fstream>
#include <iterator>

#include <fmt/format.h>

#include "common/core/error.h"
#include "common/core/input_file.h"
#include "common/core/log.h"

namespace cutsim::sim {
namespace {

constexpr char kMagic[] = "cutsim-checkpoint";
// 2: each stage's part (FemStepPart, ToolPart, CutAttemptPart) besides the
// tissue; a version-1 file lacks them and is refused.
constexpr uint32_t kFormatVersion = 2;

/// A file descriptor closed on every path out.
class Fd {
 public:
  explicit Fd(int fd) : fd_(fd) {}
  ~Fd() {
    if (fd_ >= 0) ::close(fd_);
  }
  Fd(const Fd&) = delete;
  Fd& operator=(const Fd&) = delete;
  [[nodiscard]] int get() const { return fd_; }
  int Release() {
    const int fd = fd_;
    fd_ = -1;
    return fd;
  }

 private:
  int fd_;
};

Eigen::Vector3d Vec3FromProto(const google::protobuf::RepeatedField<double>& v, const std::string& source,
                              const std::string& field) {
  if (v.size() != 3) {
    ThrowInputError({.file = source, .field = field}, fmt::format("{} values, expected 3", v.size()));
  }
  const Eigen::Vector3d p(v[0], v[1], v[2]);
  if (!p.allFinite()) ThrowInputError({.file = source, .field = field}, "non-finite coordinate");
  return p;
}

}  // namespace

v1::CheckpointEvent EventToProto(const cutting::TopologyEvent& e) {
  v1::CheckpointEvent out;
  out.set_version(e.version);
  for (const cutting::Split& s : e.splits) {
    v1::CheckpointSplit* p = out.add_splits();
    p->set_node(s.node);
    p->set_new_node(s.new_node);
    p->mutable_tets()->Add(s.tets.begin(), s.tets.end());
  }
  for (const cutting::Move& m : e.moves) {
    v1::CheckpointMove* p = out.add_moves();
    p->set_node(m.node);
    p->mutable_rest()->Add(m.rest.data(), m.rest.data() + 3);
    p->mutable_world()->Add(m.world.data(), m.world.data() + 3);
  }
  out.mutable_touched_tets()->Add(e.touched_tets.begin(), e.touched_tets.end());
  out.mutable_touched_nodes()->Add(e.touched_nodes.begin(), e.touched_nodes.end());
  return out;
}

cutting::TopologyEvent EventFromProto(const v1::CheckpointEvent& p, const std::string& source,
                                      const std::string& field) {
  cutting::TopologyEvent e;
  e.version = p.version();
  e.splits.reserve(static_cast<size_t>(p.splits_size()));
  for (const v1::CheckpointSplit& s : p.splits()) {
    e.splits.push_back({s.node(), s.new_node(), {s.tets().begin(), s.tets().end()}});
  }
  e.moves.reserve(static_cast<size_t>(p.moves_size()));
  for (int i = 0; i < p.moves_size(); ++i) {
    const v1::CheckpointMove& m = p.moves(i);
    const std::string mf = fmt::format("{}.moves[{}]", field, i);
    e.moves.push_back({m.node(), Vec3FromProto(m.rest(), source, mf + ".rest"),
                       Vec3FromProto(m.world(), source, mf + ".world")});
  }
  e.touched_tets.assign(p.touched_tets().begin(), p.touched_tets().end());
  e.touched_nodes.assign(p.touched_nodes().begin(), p.touched_nodes().end());
  return e;
}

uint64_t SceneFingerprint(const std::string& scene_name, int32_t node_capacity, const mesh::TetMesh& mesh) {
  uint64_t h = Fnv1a64(scene_name.data(), scene_name.size());
  h = Fnv1a64(&node_capacity, sizeof(node_capacity), h);
  const mesh::Positions& p = mesh.nodes;
  h = Fnv1a64(p.data(), static_cast<size_t>(p.size()) * sizeof(double), h);
  const mesh::Tets& t = mesh.tets;
  return Fnv1a64(t.data(), static_cast<size_t>(t.size()) * sizeof(t(0, 0)), h);
}

v1::CheckpointBody MakeCheckpointBody(const CheckpointIdentity& identity, int64_t frames) {
  v1::CheckpointBody b;
  b.set_scene_name(identity.scene_name);
  b.set_scene_fingerprint(identity.fingerprint);
  b.set_precision(identity.precision);
  b.set_initial_nodes(identity.initial_nodes);
  b.set_initial_tets(identity.initial_tets);
  b.set_frames(frames);
  return b;
}

void ReplayEvent(cutting::CutMesh& cut, const cutting::TopologyEvent& event) {
  while (cut.version() + 1 < event.version) {
    cutting::TopologyEvent empty;
    empty.version = cut.version() + 1;
    cut.ApplyEvent(empty);
  }
  cut.ApplyEvent(event);
}

namespace {

[[noreturn]] void Fail(const std::string& source, const std::string& field, const std::string& why) {
  ThrowInputError({.file = source, .field = field}, why);
}

/// Scene, mesh, precision and counters of `b` against the target.
void CheckIdentity(const v1::CheckpointBody& b, const std::string& source, const RestoreTarget& target) {
  const CheckpointIdentity& id = target.identity;
  if (!target.fresh) Fail(source, "", "restore needs a freshly created simulation");
  if (b.scene_name() != id.scene_name) {
    Fail(source, "scene_name",
         fmt::format("checkpoint of scene '{}', this server runs '{}'", b.scene_name(), id.scene_name));
  }
  if (b.scene_fingerprint() != id.fingerprint || b.initial_nodes() != id.initial_nodes ||
      b.initial_tets() != id.initial_tets) {
    Fail(source, "scene_fingerprint",
         fmt::format("checkpoint of another mesh of scene '{}' ({} nodes, {} tets; "
                     "this one has {} nodes, {} tets, or its mesh/settings changed)",
                     b.scene_name(), b.initial_nodes(), b.initial_tets(), id.initial_nodes, id.initial_tets));
  }
  if (b.precision() != id.precision) {
    Fail(source, "precision",
         fmt::format("checkpoint written in {} precision, this server runs {} (use --precision {})", b.precision(),
                     id.precision, b.precision()));
  }
  if (!std::isfinite(b.sim_time()) || b.sim_time() < 0 || b.sim_time() > kMaxSimSeconds || b.steps() < 0 ||
      b.frames() < 0) {
    Fail(source, "sim_time", fmt::format("negative, non-finite or over {:g} s time, or negative counters", kMaxSimSeconds));
  }
  if (b.events_size() > 0 && target.cut == nullptr) {
    Fail(source, "events", "the scene has no cutting but the checkpoint has cuts");
  }
}

/// Checks and converts every event of `b` (CheckEvents); returns the events
/// and sets `num_nodes` to the replayed mesh's.
std::vector<cutting::TopologyEvent> DryRunEvents(const v1::CheckpointBody& b, const std::string& source,
                                                 const RestoreTarget& target, int32_t& num_nodes) {
  num_nodes = target.num_nodes;
  if (target.cut == nullptr) return {};
  std::vector<NamedEvent> named;
  named.reserve(static_cast<size_t>(b.events_size()));
  for (int i = 0; i < b.events_size(); ++i) named.push_back({&b.events(i), fmt::format("events[{}]", i)});
  std::vector<cutting::TopologyEvent> events =
      CheckEvents(named, source, *target.cut, target.num_tets, target.node_capacity, num_nodes);
  const uint64_t last = events.empty() ? target.cut->version() : events.back().version;
  if (b.topology_version() > kMaxTopologyVersion) {
    Fail(source, "topology_version", fmt::format("{} exceeds the limit {}", b.topology_version(), kMaxTopologyVersion));
  }
  if (b.topology_version() < last) {
    Fail(source, "topology_version",
         fmt::format("{} is below the last event's version {}", b.topology_version(), last));
  }
  return events;
}

/// Sizes and values of the positions and velocities for `num_nodes` nodes.
void CheckNodeValues(const v1::CheckpointBody& b, const std::string& source, int32_t num_nodes,
                     int32_t node_capacity) {
  if (num_nodes > node_capacity) {
    Fail(source, "events", fmt::format("{} nodes exceed the node capacity {}", num_nodes, node_capacity));
  }
  const int n3 = 3 * num_nodes;
  if (b.positions_size() != n3) {
    Fail(source, "positions",
         fmt::format("{} values, the replayed mesh needs {} (3 per node)", b.positions_size(), n3));
  }
  if (b.velocities_size() != n3) {
    Fail(source, "velocities",
         fmt::format("{} values, the replayed mesh needs {} (3 per node)", b.velocities_size(), n3));
  }
  for (int i = 0; i < n3; ++i) {
    if (!std::isfinite(b.positions(i))) Fail(source, fmt::format("positions[{}]", i), "non-finite");
    if (!std::isfinite(b.velocities(i))) Fail(source, fmt::format("velocities[{}]", i), "non-finite");
  }
}

}  // namespace

std::vector<cutting::TopologyEvent> CheckEvents(std::span<const NamedEvent> named, const std::string& source,
                                                const cutting::CutMesh& start, int32_t num_tets,
                                                int32_t node_capacity, int32_t& num_nodes) {
  std::vector<cutting::TopologyEvent> events;
  events.reserve(named.size());
  cutting::CutMesh trial = start;
  for (const NamedEvent& n : named) {
    const std::string& field = n.field;
    events.push_back(EventFromProto(*n.event, source, field));
    const cutting::TopologyEvent& e = events.back();
    if (e.version <= trial.version()) Fail(source, field + ".version", "versions must increase");
    // Versions between events are replayed as empty events: bounded, so a
    // forged version cannot make the restore loop for ever.
    if (e.version > kMaxTopologyVersion) {
      Fail(source, field + ".version", fmt::format("{} exceeds the limit {}", e.version, kMaxTopologyVersion));
    }
    try {
      ReplayEvent(trial, e);
    } catch (const InputError& err) {
      Fail(source, field + "." + err.source().field, err.message());
    }
    if (trial.num_nodes() > node_capacity) {
      Fail(source, field, fmt::format("{} nodes exceed the node capacity {}", trial.num_nodes(), node_capacity));
    }
    for (const int32_t t : e.touched_tets) {
      if (t < 0 || t >= num_tets) Fail(source, field + ".touched_tets", fmt::format("tet {} out of range", t));
    }
    for (const int32_t nd : e.touched_nodes) {
      if (nd < 0 || nd >= trial.num_nodes()) {
        Fail(source, field + ".touched_nodes", fmt::format("node {} out of range", nd));
      }
    }
  }
  num_nodes = trial.num_nodes();
  return events;
}

std::vector<cutting::TopologyEvent> CheckCheckpointBody(const v1::CheckpointBody& body, const std::string& source,
                                                        const RestoreTarget& target) {
  CheckIdentity(body, source, target);
  int32_t num_nodes = 0;
  std::vector<cutting::TopologyEvent> events = DryRunEvents(body, source, target, num_nodes);
  CheckNodeValues(body, source, num_nodes, target.node_capacity);
  return events;
}

void WriteCheckpointFile(const std::filesystem::path& path, const v1::CheckpointBody& body) {
  v1::CheckpointFile file;
  file.set_magic(kMagic);
  file.set_format_version(kFormatVersion);
  if (!body.SerializeToString(file.mutable_body())) ThrowFileError(path.string(), "cannot serialise the checkpoint");
  file.set_body_fnv1a64(Fnv1a64(file.body().data(), file.body().size()));
  std::string bytes;
  if (!file.SerializeToString(&bytes)) ThrowFileError(path.string(), "cannot serialise the checkpoint");

  CheckOutputPath(path.string(), "checkpoint");  // the rename below would replace a device or a pipe
  const std::filesystem::path tmp = path.string() + ".tmp";
  {
    Fd fd(::open(tmp.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644));
    if (fd.get() < 0) ThrowFileError(tmp.string(), fmt::format("cannot create: {}", std::strerror(errno)));
    size_t done = 0;
    while (done < bytes.size()) {
      const ssize_t n = ::write(fd.get(), bytes.data() + done, bytes.size() - done);
      if (n < 0 && errno == EINTR) continue;
      if (n <= 0) ThrowFileError(tmp.string(), fmt::format("write failed: {}", std::strerror(errno)));
      done += static_cast<size_t>(n);
    }
    // Data on disk before the rename makes it visible: a crash leaves either
    // the old or the new checkpoint, never a torn one.
    if (::fsync(fd.get()) != 0) ThrowFileError(tmp.string(), fmt::format("fsync failed: {}", std::strerror(errno)));
    if (::close(fd.Release()) != 0) ThrowFileError(tmp.string(), fmt::format("close failed: {}", std::strerror(errno)));
  }
  std::error_code ec;
  std::filesystem::rename(tmp, path, ec);
  if (ec) ThrowFileError(path.string(), fmt::format("cannot rename {} onto it: {}", tmp.string(), ec.message()));
  std::filesystem::path dir = path.parent_path();
  if (dir.empty()) dir = ".";
  Fd dir_fd(::open(dir.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC));
  if (dir_fd.get() < 0 || ::fsync(dir_fd.get()) != 0) {
    ThrowFileError(path.string(), fmt::format("cannot sync its directory {}: {}", dir.string(), std::strerror(errno)));
  }
}

v1::CheckpointBody ReadCheckpointFile(const std::filesystem::path& path) {
  const std::string source = path.string();
  const std::string bytes = ReadInputFile(source, "checkpoint", kMaxCheckpointBytes);
  v1::CheckpointFile file;
  if (bytes.empty() || !file.ParseFromString(bytes)) {
    ThrowInputError({.file = source}, "not a cutsim checkpoint (empty, truncated or not protobuf)");
  }
  if (file.magic() != kMagic) {
    ThrowInputError({.file = source, .field = "magic"},
                    fmt::format("'{}' is not '{}': not a cutsim checkpoint", file.magic(), kMagic));
  }
  if (file.format_version() != kFormatVersion) {
    ThrowInputError({.file = source, .field = "format_version"},
                    fmt::format("checkpoint format version {}, this build reads version {} only{}",
                                file.format_version(), kFormatVersion,
                                file.format_version() < kFormatVersion
                                    ? " (older checkpoints lack the tool's grip, the cut test's anchor and the "
                                      "step's state, so they cannot resume a run exactly): start from the scene"
                                    : ""));
  }
  if (Fnv1a64(file.body().data(), file.body().size()) != file.body_fnv1a64()) {
    ThrowInputError({.file = source, .field = "body_fnv1a64"}, "checksum mismatch: the file is corrupted");
  }
  v1::CheckpointBody body;
  if (!body.ParseFromString(file.body())) {
    ThrowInputError({.file = source, .field = "body"}, "the body does not parse");
  }
  return body;
}

uint64_t LastEventVersion(const v1::CheckpointBody& body) {
  return body.events().empty() ? 0 : body.events(body.events_size() - 1).version();
}

v1::CheckpointBody SaveCheckpoint(const Simulation& sim, const std::filesystem::path& path, uint64_t lineage) {
  v1::CheckpointBody body = sim.CheckpointState();
  body.set_lineage(lineage);
  body.set_wall_clock_unix_ns(std::chrono::duration_cast<std::chrono::nanoseconds>(
                                  std::chrono::system_clock::now().time_since_epoch())
                                  .count());
  WriteCheckpointFile(path, body);
  return body;
}

void RestoreCheckpoint(Simulation& sim, const std::filesystem::path& path) {
  const v1::CheckpointBody body = ReadCheckpointFile(path);
  sim.RestoreCheckpointState(body, path.string());
}

}  // namespace cutsim::sim
