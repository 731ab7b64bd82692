#pragma once
/// @file
/// The observers' bus: RAII over Cyclone DDS 0.10's C API for the one IDL
/// type, `cutsim::dds::Envelope` (session key, sequence, kind, serialised
/// protobuf payload). Topic names and QoS live in `TopicSpecFor`, nowhere
/// else. Every entity is owned by exactly one object; none of these calls
/// throw after construction, and receiving waits on a WaitSet, never by
/// sleeping.
///
/// Configuration: a participant uses, in order, an explicit config string
/// (XML or file:// URI, e.g. from --dds-config), else $CYCLONEDDS_URI, else
/// the compiled-in deploy/cyclonedds-loopback.xml, which keeps all traffic on
/// 127.0.0.1 (unicast discovery, no multicast).

#include <chrono>
#include <cstddef>
#include <cstdint>
#include <span>
#include <string>
#include <string_view>
#include <type_traits>

namespace cutsim::transport {

/// A Cyclone entity handle (`dds_entity_t`); 0 means none.
using DdsEntity = int32_t;

/// What an envelope carries; the numbering mirrors `cutsim::dds::Kind`.
enum class EnvelopeKind : uint32_t {
  kSnapshot = 0,  ///< cutsim.v1.MeshSnapshot
  kDelta = 1,     ///< cutsim.v1.MeshDelta
  kStatus = 2,    ///< cutsim.v1.SessionStatus
  kControl = 3,   ///< cutsim.v1.DebriefControl (bridge → server)
};

/// Domain string of the signed trailer (stream_auth.h) of each observer
/// topic's payload, so a tag never moves from one topic to another.
[[nodiscard]] constexpr std::string_view ObserverStreamDomain(EnvelopeKind kind) {
  switch (kind) {
    case EnvelopeKind::kSnapshot:
      return "cutsim.v1.MeshSnapshot/hmac-sha256/1";
    case EnvelopeKind::kDelta:
      return "cutsim.v1.MeshDelta/hmac-sha256/1";
    case EnvelopeKind::kStatus:
      return "cutsim.v1.SessionStatus/hmac-sha256/1";
    case EnvelopeKind::kControl:
      return "cutsim.v1.DebriefControl/hmac-sha256/1";
  }
  return "";
}

/// Name and QoS of one topic. The one place where they are chosen:
///  - snapshot: RELIABLE, TRANSIENT_LOCAL, KEEP_LAST 1 per session (the key),
///    so a late joiner receives the current mesh on match;
///  - delta: RELIABLE, VOLATILE, KEEP_LAST 64 — a viewer that still misses
///    one sees a sequence gap and resynchronises from the next snapshot;
///  - status: BEST_EFFORT, VOLATILE, KEEP_LAST 1 — periodic, loss is harmless;
///  - control: RELIABLE, VOLATILE, KEEP_LAST 16 — a debrief's commands, from
///    the browser bridge to the server.
/// Reliable writers block at most `max_blocking_ms` when a slow reader has
/// not acknowledged enough data, then drop the sample (Publish reports it):
/// the physics loop never waits long for an observer.
struct TopicSpec {
  std::string_view name;
  EnvelopeKind kind;
  bool reliable;
  bool transient_local;
  int32_t history_depth;
  int32_t max_blocking_ms;
};

/// The spec of the topic carrying `kind`.
[[nodiscard]] const TopicSpec& TopicSpecFor(EnvelopeKind kind);

/// deploy/cyclonedds-loopback.xml as compiled in.
[[nodiscard]] std::string_view LoopbackDdsConfig();

/// The configuration a participant uses: `explicit_config` if non-empty,
/// else $CYCLONEDDS_URI if set and non-empty, else `LoopbackDdsConfig()`.
[[nodiscard]] std::string ResolveDdsConfig(std::string_view explicit_config = {});

/// Largest domain id whose ports fit (7400 + 250·id + offsets ≤ 65535).
inline constexpr uint32_t kMaxDdsDomainId = 232;

/// A domain participant. Creates the domain with the resolved configuration
/// unless this process already has it; the domain lives as long as any
/// participant of this process uses it.
class DdsParticipant {
 public:
  /// Throws `InputError` (field "--dds-domain" or "--dds-config") on an
  /// invalid domain id or a configuration Cyclone rejects.
  explicit DdsParticipant(uint32_t domain_id, std::string_view config = {});
  ~DdsParticipant();
  DdsParticipant(const DdsParticipant&) = delete;
  DdsParticipant& operator=(const DdsParticipant&) = delete;

  [[nodiscard]] DdsEntity handle() const { return participant_; }
  [[nodiscard]] uint32_t domain_id() const { return domain_id_; }

 private:
  uint32_t domain_id_;
  bool domain_lease_ = false;  // holds one reference on this process's domain entity
  DdsEntity participant_ = 0;
};

/// The Envelope topic for one kind, with its spec's QoS.
class DdsTopic {
 public:
  DdsTopic(const DdsParticipant& participant, EnvelopeKind kind);
  ~DdsTopic();
  DdsTopic(const DdsTopic&) = delete;
  DdsTopic& operator=(const DdsTopic&) = delete;

  [[nodiscard]] DdsEntity handle() const { return topic_; }
  [[nodiscard]] const TopicSpec& spec() const { return *spec_; }
  [[nodiscard]] DdsEntity participant() const { return participant_; }

 private:
  const TopicSpec* spec_;
  DdsEntity participant_;
  DdsEntity topic_ = 0;
};

/// Result of `DdsWriter::Publish`.
enum class DdsPublishStatus : uint8_t {
  kOk = 0,
  kBadSession,  ///< Not a valid session name; nothing sent.
  kWrongKind,   ///< Kind does not belong to this writer's topic; nothing sent.
  kTooLarge,    ///< Payload above the type's limit; nothing sent.
  kFailed,      ///< dds_write failed (e.g. timed out on a slow reliable reader).
};

/// Matched-reader counts of a writer (publication-matched status).
struct DdsMatch {
  uint32_t current = 0;  ///< Readers matched now.
  uint32_t total = 0;    ///< Readers ever matched; a rise means a new reader joined.
};

/// Writes envelopes on one topic.
class DdsWriter {
 public:
  explicit DdsWriter(const DdsTopic& topic);
  ~DdsWriter();
  DdsWriter(const DdsWriter&) = delete;
  DdsWriter& operator=(const DdsWriter&) = delete;

  /// Wraps `payload` in an envelope and writes it (no copy of the payload).
  /// Never throws.
  DdsPublishStatus Publish(EnvelopeKind kind, uint64_t seq, std::string_view session,
                           std::span<const uint8_t> payload) noexcept;

  /// Readers matched now; the server encodes nothing while this is zero.
  [[nodiscard]] uint32_t matched_readers() const;
  /// Current and cumulative matched readers.
  [[nodiscard]] DdsMatch match() const;
  /// Waits (WaitSet on the publication-matched status) until at least
  /// `readers` readers are matched or `timeout` passes; returns whether they are.
  bool WaitForReaders(uint32_t readers, std::chrono::milliseconds timeout) const;
  /// Waits until no reader is matched or `timeout` passes; returns whether none is.
  bool WaitForNoReaders(std::chrono::milliseconds timeout) const;
  /// Waits until every matched reliable reader acknowledged all written
  /// samples (dds_wait_for_acks), e.g. before a clean shutdown. Note: in
  /// Cyclone 0.10 a reader that matches after a write counts as having
  /// acknowledged it, so this does not cover a late joiner's replay.
  bool WaitForAcks(std::chrono::milliseconds timeout) const;

  [[nodiscard]] DdsEntity handle() const { return writer_; }
  [[nodiscard]] uint64_t published() const { return published_; }
  [[nodiscard]] uint64_t failed() const { return failed_; }

 private:
  template <class Pred>
  bool WaitForMatch(Pred done, std::chrono::milliseconds timeout) const;

  const TopicSpec* spec_;
  DdsEntity participant_;
  DdsEntity writer_ = 0;
  uint64_t published_ = 0;
  uint64_t failed_ = 0;
};

/// One received envelope, valid only inside the `Take` callback.
struct EnvelopeView {
  std::string_view session;
  uint64_t seq = 0;
  EnvelopeKind kind = EnvelopeKind::kSnapshot;
  std::span<const uint8_t> payload;
  std::string_view topic;  ///< Topic name, for decode error messages.
};

/// Counters of a reader.
struct DdsReaderStats {
  uint64_t delivered = 0;        ///< Envelopes passed to the callback.
  uint64_t foreign_session = 0;  ///< Envelopes of another session, ignored.
  uint64_t bad_kind = 0;         ///< Kind not matching the topic, ignored.
  uint64_t no_data = 0;          ///< Samples without data (dispose/unregister), ignored.
  uint64_t errors = 0;           ///< dds_take / dds_waitset_wait failures.
};

/// Selects a reader of every session (DdsReader's second constructor).
struct AnySession {};

/// Reads envelopes of one session, or of every session, from one topic.
class DdsReader {
 public:
  /// Only envelopes whose key equals `session` are delivered. Throws
  /// `InputError` (field "--session") on an invalid session name.
  DdsReader(const DdsTopic& topic, std::string session);
  /// Envelopes of every session whose key is a valid session name are
  /// delivered (EnvelopeView::session names each one's); others count as
  /// foreign. For discovering the sessions on a domain.
  DdsReader(const DdsTopic& topic, AnySession);
  ~DdsReader();
  DdsReader(const DdsReader&) = delete;
  DdsReader& operator=(const DdsReader&) = delete;

  /// Waits up to `timeout` for data (WaitSet on a read condition; zero does
  /// not wait), then takes every available sample, calling `fn(const
  /// EnvelopeView&)` for each valid one of this session (of any session for
  /// an AnySession reader). Returns how many
  /// were delivered. Exceptions from `fn` propagate after the samples are
  /// returned to Cyclone; nothing else throws.
  template <class Fn>
  size_t Take(std::chrono::nanoseconds timeout, Fn&& fn) {
    return TakeImpl(
        timeout,
        [](void* ctx, const EnvelopeView& e) { (*static_cast<std::remove_reference_t<Fn>*>(ctx))(e); },
        &fn);
  }

  [[nodiscard]] const DdsReaderStats& stats() const { return stats_; }
  [[nodiscard]] const std::string& session() const { return session_; }
  [[nodiscard]] DdsEntity handle() const { return reader_; }
  /// Writers matched now (subscription-matched status).
  [[nodiscard]] uint32_t matched_writers() const;

 private:
  using Callback = void (*)(void*, const EnvelopeView&);
  size_t TakeImpl(std::chrono::nanoseconds timeout, Callback cb, void* ctx);

  const TopicSpec* spec_;
  std::string session_;  // empty when any_session_
  bool any_session_ = false;
  DdsEntity reader_ = 0;
  DdsEntity read_condition_ = 0;
  DdsEntity waitset_ = 0;
  DdsReaderStats stats_;
};

}  // namespace cutsim::transport
