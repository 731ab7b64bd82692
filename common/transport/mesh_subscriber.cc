#include "common/transport/mesh_subscriber.h"

#include <cmath>
#include <stdexcept>
#include <utility>

#include <dds/dds.h>

#include "common/core/clock.h"
#include "common/core/log.h"
#include "common/transport/channels.h"
#include "common/transport/codec.h"

namespace cutsim::transport {
namespace {

const std::string& ValidatedSession(const std::string& s) {
  ValidateSessionName(s, "--session");
  return s;
}

}  // namespace

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

MeshStreamSubscriber::MeshStreamSubscriber(DdsParticipant& participant, std::string session,
                                           std::optional<SessionKey> key)
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
                                           status_reader_.handle()})) {
  stats_.authenticated = key.has_value();
  if (key) {
    for (const EnvelopeKind kind :
         {EnvelopeKind::kSnapshot, EnvelopeKind::kDelta, EnvelopeKind::kStatus}) {
      verifiers_[static_cast<size_t>(kind)] = std::make_unique<PayloadAuthenticator>(
          *key, std::string(ObserverStreamDomain(kind)), session_);
    }
  }
}

MeshStreamSubscriber::~MeshStreamSubscriber() = default;

bool MeshStreamSubscriber::Authentic(EnvelopeKind kind, std::span<const uint8_t> payload,
                                     std::span<const uint8_t>* body) {
  PayloadAuthenticator* verifier = verifiers_[static_cast<size_t>(kind)].get();
  if (verifier == nullptr) {
    *body = payload;
    return true;
  }
  switch (verifier->Check(payload, body)) {
    case AuthVerdict::kOk:
      return true;
    case AuthVerdict::kUnsigned:
      ++stats_.unsigned_samples;
      return false;
    default:
      ++stats_.forged;
      return false;
  }
}

bool MeshStreamSubscriber::Admit(EnvelopeKind kind, uint64_t epoch, uint64_t seq, int64_t wall_ns) {
  const int64_t now = MonotonicNs();
  const AuthVerdict verdict =
      gate_.Judge(epoch, seq, wall_ns, RealtimeNowNs(), now, static_cast<size_t>(kind));
  switch (verdict) {
    case AuthVerdict::kOk:
      return true;
    case AuthVerdict::kNewEpoch:
      if (server_epoch_ != 0 && epoch != server_epoch_) {
        // Another server epoch: a restarted server (newer), or the old one
        // back after the newer went quiet. Its state starts with its snapshot.
        ++stats_.server_changes;
        Log().info("mesh stream {}: following server epoch {} (was {})", session_, epoch,
                   server_epoch_);
        LoseSync();
        pending_.clear();
      }
      server_epoch_ = epoch;
      return true;
    case AuthVerdict::kOtherSender:
      ++stats_.other_server;
      if (now - last_other_server_log_ns_ > 5'000'000'000) {
        last_other_server_log_ns_ = now;
        Log().warn("mesh stream {}: two servers publish this session (epochs {} and {}); "
                   "following {}, the newer",
                   session_, gate_.epoch(), epoch, gate_.epoch());
      }
      return false;
    case AuthVerdict::kReplayed:
      ++stats_.replayed;
      return false;
    default:
      ++stats_.invalid_epoch;
      return false;
  }
}

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
    case EnvelopeKind::kControl:  // not an observer topic: never read here
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
    CountForeign();
    return;
  }
  ++stats_.samples;
  stats_.bytes_received += payload.size();
  last_sample_ns_ = MonotonicNs();
  std::span<const uint8_t> body;
  if (!Authentic(kind, payload, &body)) return;
  switch (kind) {
    case EnvelopeKind::kSnapshot:
      OnSnapshot(body, seq);
      break;
    case EnvelopeKind::kDelta:
      OnDelta(body, seq);
      break;
    case EnvelopeKind::kStatus:
      OnStatus(body, seq);
      break;
    case EnvelopeKind::kControl:  // not an observer topic: never read here
      break;
  }
}

void MeshStreamSubscriber::CountForeign() {
  ++process_foreign_;
  stats_.foreign_session = process_foreign_ + reader_foreign_;
}

void MeshStreamSubscriber::LoseSync() {
  replica_.Desync();
  confirmed_ = false;
}

void MeshStreamSubscriber::OnSnapshot(std::span<const uint8_t> payload, uint64_t seq) {
  if (!Decodable(payload, snapshot_msg_, EnvelopeKind::kSnapshot)) return;
  if (snapshot_msg_.session() != session_) {
    CountForeign();
    return;
  }
  if (snapshot_msg_.seq() != seq) {
    ++stats_.malformed;
    return;
  }
  if (!Admit(EnvelopeKind::kSnapshot, snapshot_msg_.epoch(), seq, snapshot_msg_.wall_ns())) return;
  // Only a sample whose content proved valid is remembered by the gate, so a
  // malformed one cannot use up the sequence number of the genuine one.
  const auto taken = [&] {
    gate_.Record(snapshot_msg_.epoch(), seq, MonotonicNs(), static_cast<size_t>(EnvelopeKind::kSnapshot));
  };
  if (replica_.synced() && (seq < replica_.seq() ||
                            (seq == replica_.seq() && snapshot_msg_.hash() == replica_.hash()))) {
    ++stats_.ignored;  // we are already there or past it
    taken();
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
      taken();
      TakeObserved(snapshot_msg_.observed());
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

namespace {

bool FiniteVec(const v1::Vec3& v) { return std::isfinite(v.x()) && std::isfinite(v.y()) && std::isfinite(v.z()); }

/// Every measure is a finite, non-negative double.
bool ValidMetrics(const v1::SessionMetrics& m) {
  const auto* descriptor = v1::SessionMetrics::descriptor();
  const auto* reflection = v1::SessionMetrics::GetReflection();
  for (int i = 0; i < descriptor->field_count(); ++i) {
    const double v = reflection->GetDouble(m, descriptor->field(i));
    if (!std::isfinite(v) || v < 0.0) return false;
  }
  return true;
}

/// Longest list of a debrief's timeline a viewer takes (wire.proto).
constexpr int kMaxTimelineSamples = 4096;

bool FiniteList(const google::protobuf::RepeatedField<float>& list) {
  if (list.size() > kMaxTimelineSamples) return false;
  for (const float v : list) {
    if (!std::isfinite(v)) return false;
  }
  return true;
}

/// A debrief's state: finite times and speed, short lists of finite values
/// in pairs where they pair, a command line of at most 64 bytes.
bool ValidDebrief(const v1::DebriefState& d) {
  bool ok = std::isfinite(d.position()) && std::isfinite(d.duration()) && d.duration() >= 0 &&
            std::isfinite(d.speed()) && d.speed() >= 0 && d.last_command().size() <= 64;
  if (!d.has_timeline()) return ok;
  const v1::DebriefTimeline& t = d.timeline();
  return ok && std::isfinite(t.duration()) && std::isfinite(t.tolerance()) && FiniteList(t.force_t()) &&
         FiniteList(t.force_n()) && t.force_t_size() == t.force_n_size() && FiniteList(t.cut_t()) &&
         FiniteList(t.cut_deviation()) && t.cut_t_size() == t.cut_deviation_size() && FiniteList(t.step_t());
}

/// Points of a planned line a page is given at most.
constexpr int kMaxPlanPoints = 64;

bool ValidPlan(const v1::PlannedLine& p) {
  bool ok = p.points_size() <= kMaxPlanPoints && std::isfinite(p.tolerance()) && p.tolerance() >= 0;
  for (const v1::Vec3& v : p.points()) ok = ok && FiniteVec(v);
  return ok;
}

}  // namespace

void MeshStreamSubscriber::TakeObserved(const v1::ObserverSession& o) {
  bool ok = o.tools_size() <= kMaxObservedTools && std::isfinite(o.sim_time()) && std::isfinite(o.wall_time()) &&
            ValidMetrics(o.metrics()) && (!o.has_debrief() || ValidDebrief(o.debrief())) &&
            (!o.has_plan() || ValidPlan(o.plan()));
  for (const v1::ToolView& t : o.tools()) {
    ok = ok && FiniteVec(t.tip()) && FiniteVec(t.blade_dir()) && FiniteVec(t.force()) &&
         t.blade_length() >= 0 && t.blade_length() <= kMaxObservedBladeLength;
  }
  if (!ok) {
    ++stats_.malformed_observed;  // the mesh stands; the previous session view stays
    return;
  }
  observed_ = o;
}

void MeshStreamSubscriber::Stash(const v1::MeshDelta& delta) {
  if (pending_.size() >= kMaxPending) pending_.erase(pending_.begin());
  pending_[delta.seq()] = delta;
}

bool MeshStreamSubscriber::HandleDelta(const v1::MeshDelta& delta) {
  if (!replica_.synced()) {
    Stash(delta);  // may follow a snapshot still on its way
    return true;
  }
  switch (replica_.ApplyDelta(delta)) {
    case MeshReplica::DeltaResult::kApplied:
      ++stats_.deltas;
      ++stats_.hash_checks;
      ++state_version_;
      confirmed_ = true;
      TakeObserved(delta.observed());
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
      return false;
    case MeshReplica::DeltaResult::kUnknownTopology:
      ++stats_.unknown_topology;
      return false;
    case MeshReplica::DeltaResult::kMalformed:
      ++stats_.malformed;
      return false;
  }
  return true;
}

void MeshStreamSubscriber::OnDelta(std::span<const uint8_t> payload, uint64_t seq) {
  if (!Decodable(payload, delta_msg_, EnvelopeKind::kDelta)) return;
  if (delta_msg_.session() != session_) {
    CountForeign();
    return;
  }
  if (delta_msg_.seq() != seq) {
    ++stats_.malformed;
    return;
  }
  if (!Admit(EnvelopeKind::kDelta, delta_msg_.epoch(), seq, delta_msg_.wall_ns())) return;
  if (HandleDelta(delta_msg_)) {
    gate_.Record(delta_msg_.epoch(), seq, MonotonicNs(), static_cast<size_t>(EnvelopeKind::kDelta));
  }
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

void MeshStreamSubscriber::OnStatus(std::span<const uint8_t> payload, uint64_t seq) {
  v1::SessionStatus msg;
  if (!Decodable(payload, msg, EnvelopeKind::kStatus)) return;
  if (msg.session() != session_) {
    CountForeign();
    return;
  }
  if (!Admit(EnvelopeKind::kStatus, msg.epoch(), seq, msg.wall_ns())) return;
  gate_.Record(msg.epoch(), seq, MonotonicNs(), static_cast<size_t>(EnvelopeKind::kStatus));
  ++stats_.status;
  status_ = std::move(msg);
}

}  // namespace cutsim::transport
