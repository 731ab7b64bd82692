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

#include "common/core/clock.h"
#include "common/core/error.h"
#include "common/core/log.h"

namespace cutsim::sim {
namespace {

constexpr char kMagic[] = "cutsim-checkpoint";
constexpr uint32_t kFormatVersion = 1;

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

void WriteCheckpointFile(const std::filesystem::path& path, const v1::CheckpointBody& body) {
  v1::CheckpointFile file;
  file.set_magic(kMagic);
  file.set_format_version(kFormatVersion);
  if (!body.SerializeToString(file.mutable_body())) ThrowFileError(path.string(), "cannot serialise the checkpoint");
  file.set_body_fnv1a64(Fnv1a64(file.body().data(), file.body().size()));
  std::string bytes;
  if (!file.SerializeToString(&bytes)) ThrowFileError(path.string(), "cannot serialise the checkpoint");

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
}

v1::CheckpointBody ReadCheckpointFile(const std::filesystem::path& path) {
  const std::string source = path.string();
  std::ifstream in(path, std::ios::binary);
  if (!in) ThrowFileError(source, "cannot open the checkpoint");
  const std::string bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
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
                    fmt::format("version {}, this build reads {}", file.format_version(), kFormatVersion));
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

void SaveCheckpoint(const Simulation& sim, const std::filesystem::path& path) {
  v1::CheckpointBody body = sim.CheckpointState();
  body.set_wall_clock_unix_ns(std::chrono::duration_cast<std::chrono::nanoseconds>(
                                  std::chrono::system_clock::now().time_since_epoch())
                                  .count());
  WriteCheckpointFile(path, body);
}

void RestoreCheckpoint(Simulation& sim, const std::filesystem::path& path) {
  const v1::CheckpointBody body = ReadCheckpointFile(path);
  sim.RestoreCheckpointState(body, path.string());
}

PeriodicCheckpointer::PeriodicCheckpointer(std::filesystem::path path, double every)
    : path_(std::move(path)),
      period_ns_(every > 0 ? static_cast<int64_t>(std::llround(every * 1e9)) : 0),
      next_ns_(MonotonicNs() + period_ns_) {}

bool PeriodicCheckpointer::Resume(Simulation& sim) {
  if (!enabled()) return false;
  if (!std::filesystem::exists(path_)) {
    Log().info("checkpoint {} does not exist yet: starting from the uncut scene", path_.string());
    return false;
  }
  RestoreCheckpoint(sim, path_);
  const SimulationSummary s = sim.QuickSummary();
  Log().info("resumed from checkpoint {}: t = {:.4g} s, {} cuts, topology version {}", path_.string(),
             s.sim_time, s.cuts, s.topology_version);
  return true;
}

void PeriodicCheckpointer::MaybeSave(const Simulation& sim) {
  if (!enabled() || period_ns_ <= 0) return;
  const int64_t now = MonotonicNs();
  if (now < next_ns_) return;
  next_ns_ = now + period_ns_;
  (void)Save(sim);
}

bool PeriodicCheckpointer::Save(const Simulation& sim) {
  if (!enabled()) return false;
  try {
    SaveCheckpoint(sim, path_);
    ++saves_;
    Log().debug("checkpoint {} written (t = {:.4g} s, topology version {})", path_.string(), sim.sim_time(),
                sim.topology_version());
    return true;
  } catch (const std::exception& e) {
    ++failures_;
    Log().error("checkpoint not written: {}", e.what());
    return false;
  }
}

}  // namespace cutsim::sim
