#include "common/transport/mesh_stream.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstring>
#include <limits>

#include <dds/dds.h>

#include "common/core/clock.h"
#include "common/core/error.h"
#include "common/core/log.h"
#include "common/transport/channels.h"

namespace cutsim::transport {

// ---------------------------------------------------------------------------
// Quantisation, stress codes, hash

int32_t Quantise(double x, double quantum) {
  const double k = std::nearbyint(x / quantum);
  if (!(k == k)) return 0;  // NaN
  return static_cast<int32_t>(std::clamp(k, -static_cast<double>(kMaxQuantised),
                                         static_cast<double>(kMaxQuantised)));
}

namespace {
constexpr double kStressStepsPerOctave = 16.0;
constexpr int32_t kMaxStressCode = 65535;
}  // namespace

int32_t StressCode(double s) {
  if (!(s == s)) return 0;
  const double mag = std::min(kStressStepsPerOctave * std::log2(1.0 + std::fabs(s)),
                              static_cast<double>(kMaxStressCode));
  const auto c = static_cast<int32_t>(std::nearbyint(mag));
  return s < 0 ? -c : c;
}

double StressFromCode(int32_t code) {
  const double mag = std::exp2(std::abs(code) / kStressStepsPerOctave) - 1.0;
  return code < 0 ? -mag : mag;
}

namespace {

// A simple 64-bit streaming hash over integer words (multiply-xorshift per
// word, FNV offset basis as seed). Integrity against bugs and corruption, not
// an adversary. Works on values, not bytes, so it is endian-independent.
class Hasher {
 public:
  void Word(uint64_t w) {
    h_ ^= w;
    h_ *= 0x9E3779B97F4A7C15ULL;
    h_ ^= h_ >> 29;
  }
  void Ints(const int32_t* p, size_t n) {
    size_t i = 0;
    for (; i + 1 < n; i += 2) {
      Word(static_cast<uint64_t>(static_cast<uint32_t>(p[i])) |
           (static_cast<uint64_t>(static_cast<uint32_t>(p[i + 1])) << 32));
    }
    if (i < n) Word(static_cast<uint32_t>(p[i]));
  }
  [[nodiscard]] uint64_t Final() const {
    uint64_t h = h_;
    h ^= h >> 33;
    h *= 0xFF51AFD7ED558CCDULL;
    h ^= h >> 33;
    return h;
  }

 private:
  uint64_t h_ = 0xCBF29CE484222325ULL;
};

}  // namespace

uint64_t TopologyHash(uint64_t topology_version, const mesh::Tets& tets,
                      const mesh::Triangles& surface, std::span<const uint8_t> opened) {
  Hasher h;
  h.Word(0x544F504FULL);  // "TOPO"
  h.Word(topology_version);
  h.Word(static_cast<uint64_t>(tets.rows()));
  h.Ints(tets.data(), static_cast<size_t>(tets.size()));
  h.Word(static_cast<uint64_t>(surface.rows()));
  h.Ints(surface.data(), static_cast<size_t>(surface.size()));
  // Opened flags as bits, 64 per word; empty hashes like all zeros.
  const auto faces = static_cast<size_t>(surface.rows());
  for (size_t base = 0; base < faces; base += 64) {
    uint64_t bits = 0;
    if (!opened.empty()) {
      for (size_t i = base; i < std::min(faces, base + 64); ++i) {
        if (i < opened.size() && opened[i] != 0) bits |= uint64_t{1} << (i - base);
      }
    }
    h.Word(bits);
  }
  return h.Final();
}

uint64_t PositionsHash(const QuantisedPositions& world_q) {
  Hasher h;
  h.Word(0x504F53ULL);  // "POS"
  h.Word(static_cast<uint64_t>(world_q.rows()));
  h.Ints(world_q.data(), static_cast<size_t>(world_q.size()));
  return h.Final();
}

uint64_t CombineHashes(uint64_t topology_hash, uint64_t positions_hash) {
  Hasher h;
  h.Word(topology_hash);
  h.Word(positions_hash);
  return h.Final();
}

uint64_t MeshHash(uint64_t topology_version, const QuantisedPositions& world_q,
                  const mesh::Tets& tets, const mesh::Triangles& surface,
                  std::span<const uint8_t> opened) {
  return CombineHashes(TopologyHash(topology_version, tets, surface, opened),
                       PositionsHash(world_q));
}

// ---------------------------------------------------------------------------
// Publisher

namespace {

const MeshStreamOptions& ValidatedOptions(const MeshStreamOptions& o) {
  if (!(std::isfinite(o.quantum_m) && o.quantum_m > 0.0 && o.quantum_m <= 1.0)) {
    ThrowInputError({.field = "mesh_stream.quantum_m"}, "must be in (0, 1] m");
  }
  if (o.move_tolerance_m && !(std::isfinite(*o.move_tolerance_m) && *o.move_tolerance_m >= 0.0)) {
    ThrowInputError({.field = "mesh_stream.move_tolerance_m"}, "must be finite and ≥ 0");
  }
  if (!std::isfinite(o.keyframe_interval_s)) {
    ThrowInputError({.field = "mesh_stream.keyframe_interval_s"}, "must be finite");
  }
  return o;
}

const std::string& ValidatedSession(const std::string& s) {
  ValidateSessionName(s, "--session");
  return s;
}

/// Appends the sorted `index` as a delta from `prev` (first: from 0).
template <class Field>
void AddDeltaCoded(Field* field, uint32_t index, uint32_t& prev, bool& first) {
  field->Add(first ? index : index - prev);
  prev = index;
  first = false;
}

}  // namespace

MeshStreamPublisher::MeshStreamPublisher(DdsParticipant& participant, std::string session,
                                         MeshStreamOptions opts)
    : session_(ValidatedSession(session)),
      opts_(ValidatedOptions(opts)),
      tolerance2_(std::pow(opts.move_tolerance_m.value_or(opts.quantum_m), 2)),
      snapshot_topic_(participant, EnvelopeKind::kSnapshot),
      delta_topic_(participant, EnvelopeKind::kDelta),
      status_topic_(participant, EnvelopeKind::kStatus),
      snapshot_writer_(snapshot_topic_),
      delta_writer_(delta_topic_),
      status_writer_(status_topic_) {
  // A restarted server must continue above the sequence numbers of the one
  // it replaces, or viewers holding a newer replica ignore its snapshots as
  // stale: start at the wall clock in ms (frames go out at ≤ 240 Hz, so a
  // later start is always ahead). (ops, issue 7: server restart.)
  seq_ = static_cast<uint64_t>(std::chrono::duration_cast<std::chrono::milliseconds>(
                                   std::chrono::system_clock::now().time_since_epoch())
                                   .count());
}

MeshStreamPublisher::~MeshStreamPublisher() = default;

bool MeshStreamPublisher::HasReaders() const {
  return snapshot_writer_.matched_readers() > 0 || delta_writer_.matched_readers() > 0;
}

bool MeshStreamPublisher::ValidFrame() const {
  const MeshFrame& f = frame_;
  const Eigen::Index n = f.world.rows();
  if (f.rest.rows() != n) return false;
  if (n > std::numeric_limits<int32_t>::max() / 4) return false;
  if (f.tets.size() > 0 && (f.tets.minCoeff() < 0 || f.tets.maxCoeff() >= n)) return false;
  if (f.surface.size() > 0 && (f.surface.minCoeff() < 0 || f.surface.maxCoeff() >= n)) return false;
  if (!f.opened.empty() && f.opened.size() != static_cast<size_t>(f.surface.rows())) return false;
  if (!f.stress.empty() && f.stress.size() != static_cast<size_t>(n)) return false;
  return true;
}

void MeshStreamPublisher::PublishFrame(const std::function<void(MeshFrame&)>& fill) {
  ++stats_.frames;
  const DdsMatch ms = snapshot_writer_.match();
  const DdsMatch md = delta_writer_.match();
  if (ms.current == 0 && md.current == 0) {
    ++stats_.skipped_no_reader;
    return;
  }
  fill(frame_);
  const int64_t t0 = MonotonicNs();
  if (!ValidFrame()) {
    Log().error("mesh stream {}: inconsistent frame {} (sizes or indices), not published",
                session_, frame_.frame);
    ++stats_.publish_failures;
    return;
  }
  const MeshFrame& f = frame_;
  const double q = opts_.quantum_m;
  const auto n = static_cast<Eigen::Index>(f.world.rows());
  const uint32_t readers_total = ms.total + md.total;
  const bool new_reader = readers_total > seen_readers_total_;
  seen_readers_total_ = readers_total;
  const bool keyframe_due = opts_.keyframe_interval_s > 0 &&
                            1e-9 * static_cast<double>(t0 - last_snapshot_ns_) >= opts_.keyframe_interval_s;
  // What a delta cannot carry: fewer nodes, or a different tet count.
  const bool delta_possible = have_sent_ && n >= sent_world_.rows() && f.tets.rows() == sent_tets_.rows();
  const uint64_t seq = ++seq_;

  delta_.Clear();
  bool publish_delta = false;
  if (delta_possible) {
    publish_delta = true;
    const uint64_t base_version = sent_version_;
    const Eigen::Index old_n = sent_world_.rows();
    if (n > old_n) {  // new nodes start at 0 (their "previous sent" value)
      sent_world_.conservativeResize(n, 3);
      sent_rest_.conservativeResize(n, 3);
      sent_world_.bottomRows(n - old_n).setZero();
      sent_rest_.bottomRows(n - old_n).setZero();
    }
    // Tets: rows that differ from the last sent ones.
    changed_tets_.clear();
    if (std::memcmp(f.tets.data(), sent_tets_.data(), sizeof(int32_t) * static_cast<size_t>(f.tets.size())) != 0) {
      for (Eigen::Index t = 0; t < f.tets.rows(); ++t) {
        if (f.tets.row(t) != sent_tets_.row(t)) changed_tets_.push_back(static_cast<int32_t>(t));
      }
    }
    // Surface and opened flags: replaced as a whole when they changed.
    bool surface_changed = f.surface.rows() != sent_surface_.rows() ||
                           std::memcmp(f.surface.data(), sent_surface_.data(),
                                       sizeof(int32_t) * static_cast<size_t>(f.surface.size())) != 0;
    if (!surface_changed) {
      for (size_t i = 0; i < sent_opened_.size(); ++i) {
        const uint8_t now = (!f.opened.empty() && f.opened[i] != 0) ? 1 : 0;
        if (now != sent_opened_[i]) {
          surface_changed = true;
          break;
        }
      }
    }
    const bool topology_changed = !changed_tets_.empty() || surface_changed || n != old_n ||
                                  f.topology_version != sent_version_;
    delta_.set_base_topology_version(base_version);
    delta_.set_topology_version(f.topology_version);
    delta_.set_num_nodes(static_cast<uint32_t>(n));
    delta_.set_num_tets(static_cast<uint32_t>(f.tets.rows()));
    if (!changed_tets_.empty()) {
      uint32_t prev = 0;
      bool first = true;
      for (const int32_t t : changed_tets_) {
        AddDeltaCoded(delta_.mutable_changed_tets(), static_cast<uint32_t>(t), prev, first);
        for (int c = 0; c < 4; ++c) delta_.add_changed_tet_nodes(static_cast<uint32_t>(f.tets(t, c)));
        sent_tets_.row(t) = f.tets.row(t);
      }
    }
    // Rest positions: exact quantised change (cuts move v0, v1 in rest too).
    {
      uint32_t prev = 0;
      bool first = true;
      for (Eigen::Index i = 0; i < n; ++i) {
        const int32_t k0 = Quantise(f.rest(i, 0), q), k1 = Quantise(f.rest(i, 1), q),
                      k2 = Quantise(f.rest(i, 2), q);
        if (k0 != sent_rest_(i, 0) || k1 != sent_rest_(i, 1) || k2 != sent_rest_(i, 2) || i >= old_n) {
          AddDeltaCoded(delta_.mutable_rest_nodes(), static_cast<uint32_t>(i), prev, first);
          delta_.add_rest_dq(k0 - sent_rest_(i, 0));
          delta_.add_rest_dq(k1 - sent_rest_(i, 1));
          delta_.add_rest_dq(k2 - sent_rest_(i, 2));
          sent_rest_.row(i) << k0, k1, k2;
        }
      }
    }
    // Moved nodes: farther than the tolerance from the value last sent.
    {
      uint32_t prev = 0;
      bool first = true;
      for (Eigen::Index i = 0; i < n; ++i) {
        const double dx = f.world(i, 0) - q * sent_world_(i, 0);
        const double dy = f.world(i, 1) - q * sent_world_(i, 1);
        const double dz = f.world(i, 2) - q * sent_world_(i, 2);
        const double d2 = dx * dx + dy * dy + dz * dz;
        if (d2 > tolerance2_ || i >= old_n || !(d2 == d2)) {
          const int32_t k0 = Quantise(f.world(i, 0), q), k1 = Quantise(f.world(i, 1), q),
                        k2 = Quantise(f.world(i, 2), q);
          if (i < old_n && k0 == sent_world_(i, 0) && k1 == sent_world_(i, 1) && k2 == sent_world_(i, 2)) {
            continue;  // a tolerance below the quantum: nothing new to send
          }
          AddDeltaCoded(delta_.mutable_moved_nodes(), static_cast<uint32_t>(i), prev, first);
          delta_.add_moved_dq(k0 - sent_world_(i, 0));
          delta_.add_moved_dq(k1 - sent_world_(i, 1));
          delta_.add_moved_dq(k2 - sent_world_(i, 2));
          sent_world_.row(i) << k0, k1, k2;
        }
      }
    }
    delta_.set_quantum(q);
    if (surface_changed) {
      delta_.set_surface_changed(true);
      sent_surface_ = f.surface;
      sent_opened_.assign(static_cast<size_t>(f.surface.rows()), 0);
      for (Eigen::Index i = 0; i < f.surface.rows(); ++i) {
        for (int c = 0; c < 3; ++c) delta_.add_surface(static_cast<uint32_t>(f.surface(i, c)));
        const bool open = !f.opened.empty() && f.opened[static_cast<size_t>(i)] != 0;
        sent_opened_[static_cast<size_t>(i)] = open ? 1 : 0;
        if (!f.opened.empty()) delta_.add_opened(open);
      }
    }
    // Stress codes that changed.
    delta_.set_has_stress(!f.stress.empty());
    if (f.stress.empty()) {
      sent_stress_.clear();
    } else {
      sent_stress_.resize(static_cast<size_t>(n), 0);
      uint32_t prev = 0;
      bool first = true;
      for (size_t i = 0; i < static_cast<size_t>(n); ++i) {
        const int32_t c = StressCode(f.stress[i]);
        if (c != sent_stress_[i]) {
          AddDeltaCoded(delta_.mutable_stress_nodes(), static_cast<uint32_t>(i), prev, first);
          delta_.add_stress_code(c);
          sent_stress_[i] = c;
        }
      }
    }
    sent_version_ = f.topology_version;
    if (topology_changed) {
      topology_hash_ = TopologyHash(sent_version_, sent_tets_, sent_surface_, sent_opened_);
    }
  } else {
    // Take the whole frame as the state sent.
    sent_world_.resize(n, 3);
    sent_rest_.resize(n, 3);
    for (Eigen::Index i = 0; i < n; ++i) {
      for (int c = 0; c < 3; ++c) {
        sent_world_(i, c) = Quantise(f.world(i, c), q);
        sent_rest_(i, c) = Quantise(f.rest(i, c), q);
      }
    }
    sent_tets_ = f.tets;
    sent_surface_ = f.surface;
    sent_opened_.assign(static_cast<size_t>(f.surface.rows()), 0);
    for (size_t i = 0; i < f.opened.size(); ++i) sent_opened_[i] = f.opened[i] != 0 ? 1 : 0;
    sent_stress_.clear();
    for (const double s : f.stress) sent_stress_.push_back(StressCode(s));
    sent_version_ = f.topology_version;
    topology_hash_ = TopologyHash(sent_version_, sent_tets_, sent_surface_, sent_opened_);
    have_sent_ = true;
  }
  const uint64_t hash = CombineHashes(topology_hash_, PositionsHash(sent_world_));
  const bool publish_snapshot = !publish_delta || new_reader || keyframe_due;
  // Snapshot first: a viewer that joins on this frame then finds this
  // frame's delta stale, and one in sync applies the delta and ignores the
  // snapshot (same seq, same hash).
  if (publish_snapshot) {
    EncodeSnapshot(seq, hash);
    last_snapshot_ns_ = t0;
  }
  if (publish_delta) {
    delta_.set_session(session_);
    delta_.set_seq(seq);
    delta_.set_frame(f.frame);
    delta_.set_sim_time(f.sim_time);
    delta_.set_hash(hash);
    size_t size = 0;
    const auto bytes = encoder_.Encode(delta_, &size);
    if (bytes && delta_writer_.Publish(EnvelopeKind::kDelta, seq, session_, *bytes) == DdsPublishStatus::kOk) {
      ++stats_.deltas;
      stats_.delta_bytes += size;
      stats_.last_delta_bytes = size;
    } else {
      ++stats_.publish_failures;
    }
  }
  stats_.last_seq = seq;
  stats_.last_hash = hash;
  stats_.last_encode_ns = MonotonicNs() - t0;
  stats_.encode_ns += stats_.last_encode_ns;
}

void MeshStreamPublisher::EncodeSnapshot(uint64_t seq, uint64_t hash) {
  const MeshFrame& f = frame_;
  const double q = opts_.quantum_m;
  snapshot_.Clear();
  snapshot_.set_session(session_);
  snapshot_.set_seq(seq);
  snapshot_.set_frame(f.frame);
  snapshot_.set_sim_time(f.sim_time);
  snapshot_.set_topology_version(sent_version_);
  snapshot_.set_quantum(q);
  const auto n = static_cast<int>(sent_world_.rows());
  snapshot_.mutable_rest()->Reserve(3 * n);
  snapshot_.mutable_world()->Reserve(3 * n);
  for (Eigen::Index i = 0; i < sent_world_.rows(); ++i) {
    for (int c = 0; c < 3; ++c) {
      snapshot_.add_rest(static_cast<float>(q * sent_rest_(i, c)));
      snapshot_.add_world(static_cast<float>(q * sent_world_(i, c)));
    }
  }
  snapshot_.mutable_tets()->Reserve(static_cast<int>(sent_tets_.size()));
  for (Eigen::Index i = 0; i < sent_tets_.size(); ++i) {
    snapshot_.add_tets(static_cast<uint32_t>(sent_tets_.data()[i]));
  }
  for (Eigen::Index i = 0; i < sent_surface_.size(); ++i) {
    snapshot_.add_surface(static_cast<uint32_t>(sent_surface_.data()[i]));
  }
  for (const uint8_t o : sent_opened_) snapshot_.add_opened(o != 0);
  for (const int32_t c : sent_stress_) snapshot_.add_stress_code(c);
  snapshot_.set_hash(hash);
  size_t size = 0;
  const auto bytes = encoder_.Encode(snapshot_, &size);
  if (bytes && snapshot_writer_.Publish(EnvelopeKind::kSnapshot, seq, session_, *bytes) ==
                   DdsPublishStatus::kOk) {
    ++stats_.snapshots;
    stats_.snapshot_bytes += size;
    stats_.last_snapshot_bytes = size;
  } else {
    ++stats_.publish_failures;
    if (!bytes) Log().error("mesh stream {}: snapshot of {} bytes above the limit", session_, size);
  }
}

void MeshStreamPublisher::PublishStatus(const cutsim::v1::SessionStatus& status) {
  status_ = status;
  status_.set_session(session_);
  const auto bytes = encoder_.Encode(status_);
  if (bytes && status_writer_.Publish(EnvelopeKind::kStatus, ++status_seq_, session_, *bytes) ==
                   DdsPublishStatus::kOk) {
    ++stats_.status_published;
  } else {
    ++stats_.publish_failures;
  }
}

// ---------------------------------------------------------------------------
// Replica

namespace {

/// Decodes sorted delta-coded indices into `out`; false if not strictly
/// increasing, out of [0, limit) or overflowing.
template <class Field>
bool DecodeIndices(const Field& coded, uint32_t limit, std::vector<uint32_t>& out) {
  out.clear();
  out.reserve(static_cast<size_t>(coded.size()));
  uint64_t cur = 0;
  for (int i = 0; i < coded.size(); ++i) {
    const uint64_t d = coded.Get(i);
    if (i > 0 && d == 0) return false;
    cur = (i == 0) ? d : cur + d;
    if (cur >= limit) return false;
    out.push_back(static_cast<uint32_t>(cur));
  }
  return true;
}

bool InQuantisedRange(int64_t k) { return k >= -kMaxQuantised && k <= kMaxQuantised; }

// Largest mesh a replica accepts (consistent with MaxPayloadBytes).
constexpr uint64_t kMaxNodes = uint64_t{1} << 26;
constexpr uint64_t kMaxTets = uint64_t{1} << 27;

}  // namespace

mesh::Positions MeshReplica::Rest() const { return rest_q_.cast<double>() * quantum_; }

uint64_t MeshReplica::ComputeHash() const {
  return MeshHash(version_, world_q_, tets_, surface_, opened_);
}

MeshReplica::SnapshotResult MeshReplica::ApplySnapshot(const v1::MeshSnapshot& s) {
  const double q = s.quantum();
  if (!(std::isfinite(q) && q > 0.0 && q <= 1.0)) return SnapshotResult::kMalformed;
  if (s.world_size() != s.rest_size() || s.world_size() % 3 != 0) return SnapshotResult::kMalformed;
  const uint64_t n = static_cast<uint64_t>(s.world_size()) / 3;
  if (n > kMaxNodes || s.tets_size() % 4 != 0 || static_cast<uint64_t>(s.tets_size()) / 4 > kMaxTets ||
      s.surface_size() % 3 != 0) {
    return SnapshotResult::kMalformed;
  }
  const int f = s.surface_size() / 3;
  if (s.opened_size() != 0 && s.opened_size() != f) return SnapshotResult::kMalformed;
  if (s.stress_code_size() != 0 && static_cast<uint64_t>(s.stress_code_size()) != n) {
    return SnapshotResult::kMalformed;
  }
  for (const uint32_t i : s.tets()) {
    if (i >= n) return SnapshotResult::kMalformed;
  }
  for (const uint32_t i : s.surface()) {
    if (i >= n) return SnapshotResult::kMalformed;
  }
  QuantisedPositions world_q(static_cast<Eigen::Index>(n), 3);
  QuantisedPositions rest_q(static_cast<Eigen::Index>(n), 3);
  for (int i = 0; i < s.world_size(); ++i) {
    const double kw = std::nearbyint(static_cast<double>(s.world(i)) / q);
    const double kr = std::nearbyint(static_cast<double>(s.rest(i)) / q);
    if (!(std::fabs(kw) <= kMaxQuantised) || !(std::fabs(kr) <= kMaxQuantised)) {
      return SnapshotResult::kMalformed;
    }
    world_q.data()[i] = static_cast<int32_t>(kw);
    rest_q.data()[i] = static_cast<int32_t>(kr);
  }
  mesh::Tets tets(s.tets_size() / 4, 4);
  for (int i = 0; i < s.tets_size(); ++i) tets.data()[i] = static_cast<int32_t>(s.tets(i));
  mesh::Triangles surface(f, 3);
  for (int i = 0; i < s.surface_size(); ++i) surface.data()[i] = static_cast<int32_t>(s.surface(i));
  std::vector<uint8_t> opened(static_cast<size_t>(f), 0);
  for (int i = 0; i < s.opened_size(); ++i) opened[static_cast<size_t>(i)] = s.opened(i) ? 1 : 0;
  const uint64_t topo = TopologyHash(s.topology_version(), tets, surface, opened);
  const uint64_t hash = CombineHashes(topo, PositionsHash(world_q));
  if (hash != s.hash()) return SnapshotResult::kHashMismatch;

  quantum_ = q;
  world_q_ = std::move(world_q);
  rest_q_ = std::move(rest_q);
  world_ = world_q_.cast<double>() * q;
  tets_ = std::move(tets);
  surface_ = std::move(surface);
  opened_ = std::move(opened);
  stress_code_.assign(s.stress_code().begin(), s.stress_code().end());
  stress_.resize(stress_code_.size());
  for (size_t i = 0; i < stress_code_.size(); ++i) stress_[i] = StressFromCode(stress_code_[i]);
  version_ = s.topology_version();
  topology_hash_ = topo;
  hash_ = hash;
  seq_ = s.seq();
  frame_ = s.frame();
  sim_time_ = s.sim_time();
  synced_ = true;
  return SnapshotResult::kApplied;
}

MeshReplica::DeltaResult MeshReplica::ApplyDelta(const v1::MeshDelta& d) {
  if (!synced_) return DeltaResult::kNotSynced;
  if (d.seq() <= seq_) return DeltaResult::kStale;
  if (d.seq() != seq_ + 1) {
    synced_ = false;
    return DeltaResult::kGap;
  }
  if (d.base_topology_version() != version_) return DeltaResult::kUnknownTopology;
  // Validate everything before touching the state.
  if (d.quantum() != quantum_) return DeltaResult::kMalformed;
  const auto old_n = static_cast<uint64_t>(world_q_.rows());
  const uint64_t n = d.num_nodes();
  if (n < old_n || n > kMaxNodes || d.num_tets() != static_cast<uint64_t>(tets_.rows())) {
    return DeltaResult::kMalformed;
  }
  const auto limit = static_cast<uint32_t>(n);
  thread_local std::vector<uint32_t> tet_idx, rest_idx, moved_idx, stress_idx;
  if (!DecodeIndices(d.changed_tets(), static_cast<uint32_t>(tets_.rows()), tet_idx) ||
      static_cast<size_t>(d.changed_tet_nodes_size()) != 4 * tet_idx.size() ||
      !DecodeIndices(d.rest_nodes(), limit, rest_idx) ||
      static_cast<size_t>(d.rest_dq_size()) != 3 * rest_idx.size() ||
      !DecodeIndices(d.moved_nodes(), limit, moved_idx) ||
      static_cast<size_t>(d.moved_dq_size()) != 3 * moved_idx.size() ||
      !DecodeIndices(d.stress_nodes(), limit, stress_idx) ||
      d.stress_code_size() != static_cast<int>(stress_idx.size()) ||
      (!d.has_stress() && d.stress_code_size() != 0)) {
    return DeltaResult::kMalformed;
  }
  for (const uint32_t v : d.changed_tet_nodes()) {
    if (v >= n) return DeltaResult::kMalformed;
  }
  if (d.surface_changed()) {
    if (d.surface_size() % 3 != 0) return DeltaResult::kMalformed;
    if (d.opened_size() != 0 && d.opened_size() != d.surface_size() / 3) return DeltaResult::kMalformed;
    for (const uint32_t v : d.surface()) {
      if (v >= n) return DeltaResult::kMalformed;
    }
  } else if (d.surface_size() != 0 || d.opened_size() != 0) {
    return DeltaResult::kMalformed;
  }
  // Surface indices that stay must remain valid: they were < old_n ≤ n.
  auto old_value = [&](const QuantisedPositions& m, uint32_t i, int c) -> int64_t {
    return i < old_n ? m(i, c) : 0;
  };
  for (size_t j = 0; j < rest_idx.size(); ++j) {
    for (int c = 0; c < 3; ++c) {
      if (!InQuantisedRange(old_value(rest_q_, rest_idx[j], c) + d.rest_dq(static_cast<int>(3 * j) + c))) {
        return DeltaResult::kMalformed;
      }
    }
  }
  for (size_t j = 0; j < moved_idx.size(); ++j) {
    for (int c = 0; c < 3; ++c) {
      if (!InQuantisedRange(old_value(world_q_, moved_idx[j], c) + d.moved_dq(static_cast<int>(3 * j) + c))) {
        return DeltaResult::kMalformed;
      }
    }
  }
  // Apply.
  const bool topology_changed = !tet_idx.empty() || d.surface_changed() ||
                                d.topology_version() != version_;
  if (n > old_n) {
    const auto rows = static_cast<Eigen::Index>(n);
    const auto old_rows = static_cast<Eigen::Index>(old_n);
    world_q_.conservativeResize(rows, 3);
    rest_q_.conservativeResize(rows, 3);
    world_.conservativeResize(rows, 3);
    world_q_.bottomRows(rows - old_rows).setZero();
    rest_q_.bottomRows(rows - old_rows).setZero();
    world_.bottomRows(rows - old_rows).setZero();
  }
  for (size_t j = 0; j < tet_idx.size(); ++j) {
    for (int c = 0; c < 4; ++c) {
      tets_(tet_idx[j], c) = static_cast<int32_t>(d.changed_tet_nodes(static_cast<int>(4 * j) + c));
    }
  }
  for (size_t j = 0; j < rest_idx.size(); ++j) {
    for (int c = 0; c < 3; ++c) rest_q_(rest_idx[j], c) += d.rest_dq(static_cast<int>(3 * j) + c);
  }
  for (size_t j = 0; j < moved_idx.size(); ++j) {
    const uint32_t i = moved_idx[j];
    for (int c = 0; c < 3; ++c) {
      world_q_(i, c) += d.moved_dq(static_cast<int>(3 * j) + c);
      world_(i, c) = quantum_ * world_q_(i, c);
    }
  }
  if (d.surface_changed()) {
    surface_.resize(d.surface_size() / 3, 3);
    for (int i = 0; i < d.surface_size(); ++i) surface_.data()[i] = static_cast<int32_t>(d.surface(i));
    opened_.assign(static_cast<size_t>(surface_.rows()), 0);
    for (int i = 0; i < d.opened_size(); ++i) opened_[static_cast<size_t>(i)] = d.opened(i) ? 1 : 0;
  }
  if (d.has_stress()) {
    stress_code_.resize(n, 0);
    stress_.resize(n, 0.0);
    for (size_t j = 0; j < stress_idx.size(); ++j) {
      stress_code_[stress_idx[j]] = d.stress_code(static_cast<int>(j));
      stress_[stress_idx[j]] = StressFromCode(stress_code_[stress_idx[j]]);
    }
  } else {
    stress_code_.clear();
    stress_.clear();
  }
  version_ = d.topology_version();
  if (topology_changed) topology_hash_ = TopologyHash(version_, tets_, surface_, opened_);
  hash_ = CombineHashes(topology_hash_, PositionsHash(world_q_));
  seq_ = d.seq();
  frame_ = d.frame();
  sim_time_ = d.sim_time();
  if (hash_ != d.hash()) {
    synced_ = false;
    return DeltaResult::kHashMismatch;
  }
  return DeltaResult::kApplied;
}

// ---------------------------------------------------------------------------
// Subscriber

struct MeshStreamSubscriber::WaitSet {
  dds_entity_t waitset = 0;
  WaitSet(DdsEntity participant, std::initializer_list<DdsEntity> readers) {
    waitset = dds_create_waitset(participant);
    if (waitset < 0) throw std::runtime_error("dds_create_waitset failed");
    for (const DdsEntity r : readers) {
      const dds_entity_t cond = dds_create_readcondition(r, DDS_ANY_STATE);
      if (cond < 0 || dds_waitset_attach(waitset, cond, 0) != DDS_RETCODE_OK) {
        dds_delete(waitset);
        throw std::runtime_error("dds_create_readcondition / dds_waitset_attach failed");
      }
    }
  }
  ~WaitSet() { dds_delete(waitset); }  // read conditions go with their readers
  WaitSet(const WaitSet&) = delete;
  WaitSet& operator=(const WaitSet&) = delete;
};

MeshStreamSubscriber::MeshStreamSubscriber(DdsParticipant& participant, std::string session)
    : session_(ValidatedSession(session)),
      snapshot_topic_(participant, EnvelopeKind::kSnapshot),
      delta_topic_(participant, EnvelopeKind::kDelta),
      status_topic_(participant, EnvelopeKind::kStatus),
      snapshot_reader_(snapshot_topic_, session_),
      delta_reader_(delta_topic_, session_),
      status_reader_(status_topic_, session_),
      waitset_(std::make_unique<WaitSet>(
          participant.handle(),
          std::initializer_list<DdsEntity>{snapshot_reader_.handle(), delta_reader_.handle(),
                                           status_reader_.handle()})) {}

MeshStreamSubscriber::~MeshStreamSubscriber() = default;

size_t MeshStreamSubscriber::Poll(std::chrono::nanoseconds timeout) {
  if (timeout.count() > 0) {
    dds_waitset_wait(waitset_->waitset, nullptr, 0, static_cast<dds_duration_t>(timeout.count()));
  }
  size_t n = 0;
  auto on = [this](const EnvelopeView& e) { Process(e.kind, e.session, e.seq, e.payload); };
  // Snapshots before deltas: a delta that follows a snapshot of the same
  // batch then applies at once (the pending buffer covers other orders).
  n += snapshot_reader_.Take(std::chrono::nanoseconds{0}, on);
  n += delta_reader_.Take(std::chrono::nanoseconds{0}, on);
  n += status_reader_.Take(std::chrono::nanoseconds{0}, on);
  reader_foreign_ = snapshot_reader_.stats().foreign_session + delta_reader_.stats().foreign_session +
                    status_reader_.stats().foreign_session;
  stats_.foreign_session = process_foreign_ + reader_foreign_;
  return n;
}

bool MeshStreamSubscriber::current() const {
  if (!replica_.synced()) return false;
  if (confirmed_) return true;
  return MonotonicNs() - snapshot_applied_ns_ >=
         std::chrono::duration_cast<std::chrono::nanoseconds>(confirm_timeout_).count();
}

bool MeshStreamSubscriber::Decodable(std::span<const uint8_t> payload,
                                     google::protobuf::MessageLite& msg, EnvelopeKind kind) {
  DecodeError err;
  bool ok = false;
  const std::string_view topic = TopicSpecFor(kind).name;
  switch (kind) {
    case EnvelopeKind::kSnapshot:
      ok = DecodeInto(payload, static_cast<v1::MeshSnapshot&>(msg), topic, &err);
      break;
    case EnvelopeKind::kDelta:
      ok = DecodeInto(payload, static_cast<v1::MeshDelta&>(msg), topic, &err);
      break;
    case EnvelopeKind::kStatus:
      ok = DecodeInto(payload, static_cast<v1::SessionStatus&>(msg), topic, &err);
      break;
  }
  if (!ok) {
    if (err.status == DecodeStatus::kTooLarge) {
      ++stats_.oversized;
    } else {
      ++stats_.malformed;
    }
    Log().debug("{}", err.Message());
  }
  return ok;
}

void MeshStreamSubscriber::Process(EnvelopeKind kind, std::string_view session, uint64_t seq,
                                   std::span<const uint8_t> payload) {
  if (session != session_) {
    ++process_foreign_;
    stats_.foreign_session = process_foreign_ + reader_foreign_;
    return;
  }
  ++stats_.samples;
  stats_.bytes_received += payload.size();
  last_sample_ns_ = MonotonicNs();
  switch (kind) {
    case EnvelopeKind::kSnapshot:
      OnSnapshot(payload, seq);
      break;
    case EnvelopeKind::kDelta:
      OnDelta(payload, seq);
      break;
    case EnvelopeKind::kStatus:
      OnStatus(payload);
      break;
  }
}

void MeshStreamSubscriber::LoseSync() {
  replica_.Desync();
  confirmed_ = false;
}

void MeshStreamSubscriber::OnSnapshot(std::span<const uint8_t> payload, uint64_t seq) {
  if (!Decodable(payload, snapshot_msg_, EnvelopeKind::kSnapshot)) return;
  if (snapshot_msg_.session() != session_) {
    ++process_foreign_;
    stats_.foreign_session = process_foreign_ + reader_foreign_;
    return;
  }
  if (snapshot_msg_.seq() != seq) {
    ++stats_.malformed;
    return;
  }
  if (replica_.synced() && (seq < replica_.seq() ||
                            (seq == replica_.seq() && snapshot_msg_.hash() == replica_.hash()))) {
    ++stats_.ignored;  // we are already there or past it
    return;
  }
  const bool keep_confirmed = replica_.synced() && confirmed_;
  if (replica_.synced() && !confirmed_) ++stats_.stale_snapshots;
  switch (replica_.ApplySnapshot(snapshot_msg_)) {
    case MeshReplica::SnapshotResult::kApplied:
      ++stats_.snapshots;
      ++stats_.hash_checks;
      ++state_version_;
      confirmed_ = keep_confirmed;
      snapshot_applied_ns_ = MonotonicNs();
      ApplyPending();
      break;
    case MeshReplica::SnapshotResult::kHashMismatch:
      ++stats_.hash_checks;
      ++stats_.hash_mismatches;
      break;
    case MeshReplica::SnapshotResult::kMalformed:
      ++stats_.malformed;
      break;
  }
}

void MeshStreamSubscriber::Stash(const v1::MeshDelta& delta) {
  if (pending_.size() >= kMaxPending) pending_.erase(pending_.begin());
  pending_[delta.seq()] = delta;
}

void MeshStreamSubscriber::HandleDelta(const v1::MeshDelta& delta) {
  if (!replica_.synced()) {
    Stash(delta);  // may follow a snapshot still on its way
    return;
  }
  switch (replica_.ApplyDelta(delta)) {
    case MeshReplica::DeltaResult::kApplied:
      ++stats_.deltas;
      ++stats_.hash_checks;
      ++state_version_;
      confirmed_ = true;
      break;
    case MeshReplica::DeltaResult::kStale:
      // The delta of the frame our snapshot came from proves the snapshot
      // is current (not an old keyframe replayed on joining).
      if (delta.seq() == replica_.seq() && delta.hash() == replica_.hash()) confirmed_ = true;
      ++stats_.ignored;
      break;
    case MeshReplica::DeltaResult::kNotSynced:
      ++stats_.ignored;
      break;
    case MeshReplica::DeltaResult::kGap:
      if (confirmed_) {
        ++stats_.gaps;
        ++stats_.resyncs;
        Log().warn("mesh stream {}: gap at seq {}, waiting for the next snapshot", session_,
                   delta.seq());
      } else {
        ++stats_.stale_snapshots;  // the snapshot we held was an old keyframe
      }
      LoseSync();
      Stash(delta);
      break;
    case MeshReplica::DeltaResult::kHashMismatch:
      ++stats_.hash_checks;
      ++stats_.hash_mismatches;
      ++stats_.resyncs;
      Log().warn("mesh stream {}: hash mismatch at seq {}, waiting for the next snapshot",
                 session_, delta.seq());
      LoseSync();
      break;
    case MeshReplica::DeltaResult::kUnknownTopology:
      ++stats_.unknown_topology;
      break;
    case MeshReplica::DeltaResult::kMalformed:
      ++stats_.malformed;
      break;
  }
}

void MeshStreamSubscriber::OnDelta(std::span<const uint8_t> payload, uint64_t seq) {
  if (!Decodable(payload, delta_msg_, EnvelopeKind::kDelta)) return;
  if (delta_msg_.session() != session_) {
    ++process_foreign_;
    stats_.foreign_session = process_foreign_ + reader_foreign_;
    return;
  }
  if (delta_msg_.seq() != seq) {
    ++stats_.malformed;
    return;
  }
  HandleDelta(delta_msg_);
}

void MeshStreamSubscriber::ApplyPending() {
  while (!pending_.empty() && replica_.synced()) {
    auto it = pending_.begin();
    if (it->first <= replica_.seq()) {
      pending_.erase(it);
      continue;
    }
    if (it->first != replica_.seq() + 1) break;  // a hole: the live stream will tell
    const v1::MeshDelta delta = std::move(it->second);
    pending_.erase(it);
    HandleDelta(delta);
  }
}

void MeshStreamSubscriber::OnStatus(std::span<const uint8_t> payload) {
  v1::SessionStatus msg;
  if (!Decodable(payload, msg, EnvelopeKind::kStatus)) return;
  if (msg.session() != session_) {
    ++process_foreign_;
    stats_.foreign_session = process_foreign_ + reader_foreign_;
    return;
  }
  ++stats_.status;
  status_ = std::move(msg);
}

}  // namespace cutsim::transport
