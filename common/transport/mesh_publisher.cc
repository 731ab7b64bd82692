#include "common/transport/mesh_publisher.h"

#include <chrono>
#include <cmath>
#include <cstring>
#include <limits>

#include "common/core/clock.h"
#include "common/core/error.h"
#include "common/core/log.h"
#include "common/transport/channels.h"

namespace cutsim::transport {
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

/// Appends sorted indices to a repeated field, each as its difference from
/// the previous one (the first as is).
template <class Field>
class DeltaCodedIndices {
 public:
  explicit DeltaCodedIndices(Field* field) : field_(field) {}
  void Add(uint32_t index) {
    field_->Add(first_ ? index : index - prev_);
    prev_ = index;
    first_ = false;
  }

 private:
  Field* field_;
  uint32_t prev_ = 0;
  bool first_ = true;
};

template <class Field>
DeltaCodedIndices<Field> DeltaCoded(Field* field) {
  return DeltaCodedIndices<Field>(field);
}

/// The flag of face `i` as sent (0/1); an empty `opened` means none opened.
uint8_t OpenedFlag(const std::vector<uint8_t>& opened, size_t i) {
  return (!opened.empty() && opened[i] != 0) ? 1 : 0;
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
  // later start is always ahead).
  seq_ = static_cast<uint64_t>(std::chrono::duration_cast<std::chrono::milliseconds>(
                                   std::chrono::system_clock::now().time_since_epoch())
                                   .count());
  epoch_ = static_cast<uint64_t>(RealtimeNowNs());
  if (opts_.key) {
    snapshot_signer_ = std::make_unique<PayloadAuthenticator>(
        *opts_.key, std::string(ObserverStreamDomain(EnvelopeKind::kSnapshot)), session_);
    delta_signer_ = std::make_unique<PayloadAuthenticator>(
        *opts_.key, std::string(ObserverStreamDomain(EnvelopeKind::kDelta)), session_);
    status_signer_ = std::make_unique<PayloadAuthenticator>(
        *opts_.key, std::string(ObserverStreamDomain(EnvelopeKind::kStatus)), session_);
  }
}

MeshStreamPublisher::~MeshStreamPublisher() = default;

bool MeshStreamPublisher::HasReaders() const {
  return snapshot_writer_.matched_readers() > 0 || delta_writer_.matched_readers() > 0;
}

bool MeshStreamPublisher::HasStatusReaders() const { return status_writer_.matched_readers() > 0; }

void MeshStreamPublisher::PublishFrame(const std::function<void(MeshFrame&)>& fill) {
  ++stats_.frames;
  const DdsMatch snapshot_match = snapshot_writer_.match();
  const DdsMatch delta_match = delta_writer_.match();
  if (snapshot_match.current == 0 && delta_match.current == 0) {
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
  const bool new_reader = NoteReaders(snapshot_match.total + delta_match.total);
  const bool keyframe_due = KeyframeDue(t0);
  const bool publish_delta = DeltaPossible();
  const uint64_t seq = ++seq_;
  if (publish_delta) {
    BuildDelta();
  } else {
    TakeFrameAsSent();
  }
  const uint64_t hash = CombineHashes(topology_hash_, PositionsHash(sent_world_));
  // Snapshot first: a viewer that joins on this frame then finds this
  // frame's delta stale, and one in sync applies the delta and ignores the
  // snapshot (same seq, same hash).
  if (!publish_delta || new_reader || keyframe_due) {
    EncodeSnapshot(seq, hash);
    last_snapshot_ns_ = t0;
  }
  if (publish_delta) PublishDelta(seq, hash);
  stats_.last_seq = seq;
  stats_.last_hash = hash;
  stats_.last_encode_ns = MonotonicNs() - t0;
  stats_.encode_ns += stats_.last_encode_ns;
}

// ---------------------------------------------------------------------------
// Frame checks

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

bool MeshStreamPublisher::NoteReaders(uint32_t readers_total) {
  // The cumulative match count rises for every reader that joins, even one
  // that replaced a reader gone in the meantime.
  const bool new_reader = readers_total > seen_readers_total_;
  seen_readers_total_ = readers_total;
  return new_reader;
}

bool MeshStreamPublisher::KeyframeDue(int64_t now_ns) const {
  return opts_.keyframe_interval_s > 0 &&
         1e-9 * static_cast<double>(now_ns - last_snapshot_ns_) >= opts_.keyframe_interval_s;
}

bool MeshStreamPublisher::DeltaPossible() const {
  // What a delta cannot carry: fewer nodes, or a different tet count.
  return have_sent_ && frame_.world.rows() >= sent_world_.rows() &&
         frame_.tets.rows() == sent_tets_.rows();
}

// ---------------------------------------------------------------------------
// The delta

void MeshStreamPublisher::BuildDelta() {
  const MeshFrame& f = frame_;
  const Eigen::Index old_n = sent_world_.rows();
  const Eigen::Index n = f.world.rows();
  delta_.Clear();
  delta_.set_base_topology_version(sent_version_);
  delta_.set_topology_version(f.topology_version);
  delta_.set_num_nodes(static_cast<uint32_t>(n));
  delta_.set_num_tets(static_cast<uint32_t>(f.tets.rows()));
  delta_.set_quantum(opts_.quantum_m);
  GrowSentNodes(n);
  FindChangedTets();
  const bool surface_changed = SurfaceChanged();
  const bool topology_changed = !changed_tets_.empty() || surface_changed || n != old_n ||
                                f.topology_version != sent_version_;
  AddChangedTets();
  AddRestChanges(old_n);
  AddMovedNodes(old_n);
  if (surface_changed) AddSurface();
  AddStressChanges();
  sent_version_ = f.topology_version;
  if (topology_changed) {
    topology_hash_ = TopologyHash(sent_version_, sent_tets_, sent_surface_, sent_opened_);
  }
}

void MeshStreamPublisher::GrowSentNodes(Eigen::Index n) {
  // New nodes start at 0, their "previous sent" value.
  const Eigen::Index old_n = sent_world_.rows();
  if (n <= old_n) return;
  sent_world_.conservativeResize(n, 3);
  sent_rest_.conservativeResize(n, 3);
  sent_world_.bottomRows(n - old_n).setZero();
  sent_rest_.bottomRows(n - old_n).setZero();
}

void MeshStreamPublisher::FindChangedTets() {
  const mesh::Tets& tets = frame_.tets;
  changed_tets_.clear();
  if (std::memcmp(tets.data(), sent_tets_.data(), sizeof(int32_t) * static_cast<size_t>(tets.size())) == 0) {
    return;
  }
  for (Eigen::Index t = 0; t < tets.rows(); ++t) {
    if (tets.row(t) != sent_tets_.row(t)) changed_tets_.push_back(static_cast<int32_t>(t));
  }
}

bool MeshStreamPublisher::SurfaceChanged() const {
  const MeshFrame& f = frame_;
  if (f.surface.rows() != sent_surface_.rows() ||
      std::memcmp(f.surface.data(), sent_surface_.data(),
                  sizeof(int32_t) * static_cast<size_t>(f.surface.size())) != 0) {
    return true;
  }
  for (size_t i = 0; i < sent_opened_.size(); ++i) {
    if (OpenedFlag(f.opened, i) != sent_opened_[i]) return true;
  }
  return false;
}

void MeshStreamPublisher::AddChangedTets() {
  auto indices = DeltaCoded(delta_.mutable_changed_tets());
  for (const int32_t t : changed_tets_) {
    indices.Add(static_cast<uint32_t>(t));
    for (int c = 0; c < 4; ++c) delta_.add_changed_tet_nodes(static_cast<uint32_t>(frame_.tets(t, c)));
    sent_tets_.row(t) = frame_.tets.row(t);
  }
}

void MeshStreamPublisher::AddRestChanges(Eigen::Index old_n) {
  // The exact quantised change: cuts move nodes in the rest configuration too.
  const double q = opts_.quantum_m;
  auto indices = DeltaCoded(delta_.mutable_rest_nodes());
  for (Eigen::Index i = 0; i < frame_.rest.rows(); ++i) {
    const int32_t k0 = Quantise(frame_.rest(i, 0), q), k1 = Quantise(frame_.rest(i, 1), q),
                  k2 = Quantise(frame_.rest(i, 2), q);
    if (k0 != sent_rest_(i, 0) || k1 != sent_rest_(i, 1) || k2 != sent_rest_(i, 2) || i >= old_n) {
      indices.Add(static_cast<uint32_t>(i));
      delta_.add_rest_dq(k0 - sent_rest_(i, 0));
      delta_.add_rest_dq(k1 - sent_rest_(i, 1));
      delta_.add_rest_dq(k2 - sent_rest_(i, 2));
      sent_rest_.row(i) << k0, k1, k2;
    }
  }
}

void MeshStreamPublisher::AddMovedNodes(Eigen::Index old_n) {
  // Nodes farther than the tolerance from the value last sent (new nodes and
  // non-finite positions always).
  const double q = opts_.quantum_m;
  const mesh::Positions& world = frame_.world;
  auto indices = DeltaCoded(delta_.mutable_moved_nodes());
  for (Eigen::Index i = 0; i < world.rows(); ++i) {
    const double dx = world(i, 0) - q * sent_world_(i, 0);
    const double dy = world(i, 1) - q * sent_world_(i, 1);
    const double dz = world(i, 2) - q * sent_world_(i, 2);
    const double d2 = dx * dx + dy * dy + dz * dz;
    if (!(d2 > tolerance2_ || i >= old_n || !(d2 == d2))) continue;
    const int32_t k0 = Quantise(world(i, 0), q), k1 = Quantise(world(i, 1), q),
                  k2 = Quantise(world(i, 2), q);
    if (i < old_n && k0 == sent_world_(i, 0) && k1 == sent_world_(i, 1) && k2 == sent_world_(i, 2)) {
      continue;  // a tolerance below the quantum: nothing new to send
    }
    indices.Add(static_cast<uint32_t>(i));
    delta_.add_moved_dq(k0 - sent_world_(i, 0));
    delta_.add_moved_dq(k1 - sent_world_(i, 1));
    delta_.add_moved_dq(k2 - sent_world_(i, 2));
    sent_world_.row(i) << k0, k1, k2;
  }
}

void MeshStreamPublisher::AddSurface() {
  // Surface and opened flags are replaced as a whole when either changed.
  const MeshFrame& f = frame_;
  delta_.set_surface_changed(true);
  sent_surface_ = f.surface;
  sent_opened_.assign(static_cast<size_t>(f.surface.rows()), 0);
  for (Eigen::Index i = 0; i < f.surface.rows(); ++i) {
    for (int c = 0; c < 3; ++c) delta_.add_surface(static_cast<uint32_t>(f.surface(i, c)));
    const uint8_t open = OpenedFlag(f.opened, static_cast<size_t>(i));
    sent_opened_[static_cast<size_t>(i)] = open;
    if (!f.opened.empty()) delta_.add_opened(open != 0);
  }
}

void MeshStreamPublisher::AddStressChanges() {
  const std::vector<double>& stress = frame_.stress;
  delta_.set_has_stress(!stress.empty());
  if (stress.empty()) {
    sent_stress_.clear();
    return;
  }
  sent_stress_.resize(stress.size(), 0);
  auto indices = DeltaCoded(delta_.mutable_stress_nodes());
  for (size_t i = 0; i < stress.size(); ++i) {
    const int32_t c = StressCode(stress[i]);
    if (c == sent_stress_[i]) continue;
    indices.Add(static_cast<uint32_t>(i));
    delta_.add_stress_code(c);
    sent_stress_[i] = c;
  }
}

void MeshStreamPublisher::TakeFrameAsSent() {
  const MeshFrame& f = frame_;
  const double q = opts_.quantum_m;
  const Eigen::Index n = f.world.rows();
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

// ---------------------------------------------------------------------------
// Encoding and writing

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
  *snapshot_.mutable_observed() = observed_;
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
  snapshot_.set_epoch(epoch_);
  snapshot_.set_wall_ns(RealtimeNowNs());
  size_t size = 0;
  const auto bytes = encoder_.Encode(snapshot_, &size, snapshot_signer_.get());
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

void MeshStreamPublisher::PublishDelta(uint64_t seq, uint64_t hash) {
  delta_.set_session(session_);
  delta_.set_seq(seq);
  delta_.set_frame(frame_.frame);
  delta_.set_sim_time(frame_.sim_time);
  delta_.set_hash(hash);
  *delta_.mutable_observed() = observed_;
  delta_.set_epoch(epoch_);
  delta_.set_wall_ns(RealtimeNowNs());
  size_t size = 0;
  const auto bytes = encoder_.Encode(delta_, &size, delta_signer_.get());
  if (bytes && delta_writer_.Publish(EnvelopeKind::kDelta, seq, session_, *bytes) == DdsPublishStatus::kOk) {
    ++stats_.deltas;
    stats_.delta_bytes += size;
    stats_.last_delta_bytes = size;
  } else {
    ++stats_.publish_failures;
  }
}

void MeshStreamPublisher::PublishStatus(const cutsim::v1::SessionStatus& status) {
  status_ = status;
  status_.set_session(session_);
  status_.set_epoch(epoch_);
  status_.set_wall_ns(RealtimeNowNs());
  const auto bytes = encoder_.Encode(status_, nullptr, status_signer_.get());
  if (bytes && status_writer_.Publish(EnvelopeKind::kStatus, ++status_seq_, session_, *bytes) ==
                   DdsPublishStatus::kOk) {
    ++stats_.status_published;
  } else {
    ++stats_.publish_failures;
  }
}

}  // namespace cutsim::transport
