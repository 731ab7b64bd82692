#include "common/transport/dds.h"

#include <array>
#include <cstdlib>
#include <cstring>
#include <map>
#include <mutex>

#include <dds/dds.h>
#include <fmt/format.h>

#include "common/core/error.h"
#include "common/core/log.h"
#include "common/transport/channels.h"
#include "common/transport/codec.h"
#include "envelope.h"  // idlc output: cutsim_dds_Envelope, cutsim_dds_Envelope_desc

namespace cutsim::transport {

static_assert(std::is_same_v<DdsEntity, dds_entity_t>);
static_assert(static_cast<uint32_t>(EnvelopeKind::kSnapshot) == cutsim_dds_KIND_SNAPSHOT);
static_assert(static_cast<uint32_t>(EnvelopeKind::kDelta) == cutsim_dds_KIND_DELTA);
static_assert(static_cast<uint32_t>(EnvelopeKind::kStatus) == cutsim_dds_KIND_STATUS);
static_assert(static_cast<uint32_t>(EnvelopeKind::kControl) == cutsim_dds_KIND_CONTROL);
static_assert(sizeof(cutsim_dds_Envelope::session) > kMaxSessionLength);

namespace {

constexpr std::string_view kLoopbackXml =
#include "dds_loopback_config.inc"
    ;

// The one table of topic names and QoS (see TopicSpec).
constexpr std::array<TopicSpec, 4> kTopics = {{
    {.name = "cutsim_snapshot",
     .kind = EnvelopeKind::kSnapshot,
     .reliable = true,
     .transient_local = true,
     .history_depth = 1,
     .max_blocking_ms = 50},
    {.name = "cutsim_delta",
     .kind = EnvelopeKind::kDelta,
     .reliable = true,
     .transient_local = false,
     .history_depth = 64,
     .max_blocking_ms = 50},
    {.name = "cutsim_status",
     .kind = EnvelopeKind::kStatus,
     .reliable = false,
     .transient_local = false,
     .history_depth = 1,
     .max_blocking_ms = 0},
    {.name = "cutsim_control",
     .kind = EnvelopeKind::kControl,
     .reliable = true,
     .transient_local = false,
     .history_depth = 16,
     .max_blocking_ms = 10},
}};

size_t PayloadLimit(EnvelopeKind kind) {
  switch (kind) {
    case EnvelopeKind::kSnapshot:
      return MaxPayloadBytes<v1::MeshSnapshot>();
    case EnvelopeKind::kDelta:
      return MaxPayloadBytes<v1::MeshDelta>();
    case EnvelopeKind::kStatus:
      return MaxPayloadBytes<v1::SessionStatus>();
    case EnvelopeKind::kControl:
      return MaxPayloadBytes<v1::DebriefControl>();
  }
  return 0;
}

/// A dds_qos_t for a topic spec, freed on scope exit.
class Qos {
 public:
  explicit Qos(const TopicSpec& spec) : qos_(dds_create_qos()) {
    dds_qset_reliability(qos_, spec.reliable ? DDS_RELIABILITY_RELIABLE : DDS_RELIABILITY_BEST_EFFORT,
                         DDS_MSECS(spec.max_blocking_ms));
    dds_qset_durability(qos_, spec.transient_local ? DDS_DURABILITY_TRANSIENT_LOCAL
                                                   : DDS_DURABILITY_VOLATILE);
    dds_qset_history(qos_, DDS_HISTORY_KEEP_LAST, spec.history_depth);
  }
  ~Qos() { dds_delete_qos(qos_); }
  Qos(const Qos&) = delete;
  Qos& operator=(const Qos&) = delete;
  [[nodiscard]] const dds_qos_t* get() const { return qos_; }

 private:
  dds_qos_t* qos_;
};

void DeleteEntity(dds_entity_t& e) noexcept {
  // ALREADY_DELETED is fine: deleting a parent deletes its children.
  if (e > 0) static_cast<void>(dds_delete(e));
  e = 0;
}

// ---- Per-process domain registry -----------------------------------------------
// A domain created with dds_create_domain stays until deleted, and deleting it
// deletes every participant in it, so it is reference counted across all
// DdsParticipants of this process.

struct DomainEntry {
  dds_entity_t domain = 0;  // 0: the domain existed before us; not ours to delete
  int refs = 0;
  std::string config;
};

std::mutex& DomainMutex() {
  static std::mutex mu;
  return mu;
}

std::map<uint32_t, DomainEntry>& Domains() {
  static std::map<uint32_t, DomainEntry> domains;
  return domains;
}

void AcquireDomain(uint32_t id, const std::string& config) {
  std::lock_guard lock(DomainMutex());
  DomainEntry& entry = Domains()[id];
  if (entry.refs > 0) {
    if (entry.config != config) {
      Log().warn("DDS domain {} already exists in this process with another configuration; "
                 "using the existing one",
                 id);
    }
    ++entry.refs;
    return;
  }
  const dds_entity_t domain = dds_create_domain(id, config.c_str());
  if (domain == DDS_RETCODE_PRECONDITION_NOT_MET) {
    // Created implicitly elsewhere (a plain dds_create_participant): share it.
    entry = DomainEntry{.domain = 0, .refs = 1, .config = config};
    return;
  }
  if (domain < 0) {
    Domains().erase(id);
    const bool xml = !config.empty() && config.front() == '<';
    ThrowInputError(
        SourceRef{.field = "--dds-config"},
        fmt::format("Cyclone DDS rejected the configuration for domain {} ({}): {}", id,
                    dds_strretcode(domain),
                    xml ? std::string("inline XML; set Tracing/Verbosity to see why")
                        : config));
  }
  entry = DomainEntry{.domain = domain, .refs = 1, .config = config};
}

void ReleaseDomain(uint32_t id) noexcept {
  std::lock_guard lock(DomainMutex());
  auto it = Domains().find(id);
  if (it == Domains().end()) return;
  if (--it->second.refs > 0) return;
  DeleteEntity(it->second.domain);
  Domains().erase(it);
}

}  // namespace

const TopicSpec& TopicSpecFor(EnvelopeKind kind) {
  for (const TopicSpec& spec : kTopics) {
    if (spec.kind == kind) return spec;
  }
  CUTSIM_CHECK(false, "unknown EnvelopeKind");
}

std::string_view LoopbackDdsConfig() { return kLoopbackXml; }

std::string ResolveDdsConfig(std::string_view explicit_config) {
  if (!explicit_config.empty()) return std::string(explicit_config);
  const char* env = std::getenv("CYCLONEDDS_URI");
  if (env != nullptr && env[0] != '\0') return env;
  return std::string(kLoopbackXml);
}

// ---- DdsParticipant ------------------------------------------------------------------

DdsParticipant::DdsParticipant(uint32_t domain_id, std::string_view config)
    : domain_id_(domain_id) {
  if (domain_id > kMaxDdsDomainId) {
    ThrowInputError(SourceRef{.field = "--dds-domain"},
                    fmt::format("DDS domain id {} out of range 0..{}", domain_id, kMaxDdsDomainId));
  }
  AcquireDomain(domain_id, ResolveDdsConfig(config));
  domain_lease_ = true;
  participant_ = dds_create_participant(domain_id, nullptr, nullptr);
  if (participant_ < 0) {
    const dds_return_t rc = participant_;
    participant_ = 0;
    ReleaseDomain(domain_id_);
    domain_lease_ = false;
    ThrowInputError(SourceRef{.field = "--dds-domain"},
                    fmt::format("cannot create a DDS participant in domain {}: {}", domain_id,
                                dds_strretcode(rc)));
  }
}

DdsParticipant::~DdsParticipant() {
  DeleteEntity(participant_);
  if (domain_lease_) ReleaseDomain(domain_id_);
}

// ---- DdsTopic ----------------------------------------------------------------------------

DdsTopic::DdsTopic(const DdsParticipant& participant, EnvelopeKind kind)
    : spec_(&TopicSpecFor(kind)), participant_(participant.handle()) {
  const Qos qos(*spec_);
  const std::string name(spec_->name);
  topic_ = dds_create_topic(participant_, &cutsim_dds_Envelope_desc, name.c_str(), qos.get(),
                            nullptr);
  // Only a bug (or a foreign type registered under our name) fails here.
  CUTSIM_CHECK(topic_ > 0, fmt::format("dds_create_topic({}): {}", name,
                                       dds_strretcode(topic_)));
}

DdsTopic::~DdsTopic() { DeleteEntity(topic_); }

// ---- DdsWriter ---------------------------------------------------------------------------

DdsWriter::DdsWriter(const DdsTopic& topic)
    : spec_(&topic.spec()), participant_(topic.participant()) {
  const Qos qos(*spec_);
  writer_ = dds_create_writer(participant_, topic.handle(), qos.get(), nullptr);
  CUTSIM_CHECK(writer_ > 0, fmt::format("dds_create_writer({}): {}", spec_->name,
                                        dds_strretcode(writer_)));
}

DdsWriter::~DdsWriter() { DeleteEntity(writer_); }

DdsPublishStatus DdsWriter::Publish(EnvelopeKind kind, uint64_t seq, std::string_view session,
                                    std::span<const uint8_t> payload) noexcept {
  auto fail = [this](DdsPublishStatus status) {
    ++failed_;
    return status;
  };
  if (!IsValidSessionName(session)) return fail(DdsPublishStatus::kBadSession);
  if (kind != spec_->kind) return fail(DdsPublishStatus::kWrongKind);
  if (payload.size() > PayloadLimit(kind)) return fail(DdsPublishStatus::kTooLarge);

  cutsim_dds_Envelope sample{};
  std::memcpy(sample.session, session.data(), session.size());
  sample.session[session.size()] = '\0';
  sample.seq = seq;
  sample.kind = static_cast<cutsim_dds_Kind>(kind);
  // Borrowed: dds_write serialises the sample before returning.
  sample.payload._buffer = const_cast<uint8_t*>(payload.data());
  sample.payload._length = static_cast<uint32_t>(payload.size());
  sample.payload._maximum = static_cast<uint32_t>(payload.size());
  sample.payload._release = false;
  const dds_return_t rc = dds_write(writer_, &sample);
  if (rc != DDS_RETCODE_OK) return fail(DdsPublishStatus::kFailed);
  ++published_;
  return DdsPublishStatus::kOk;
}

DdsMatch DdsWriter::match() const {
  dds_publication_matched_status_t status{};
  if (dds_get_publication_matched_status(writer_, &status) != DDS_RETCODE_OK) return {};
  return DdsMatch{.current = status.current_count, .total = status.total_count};
}

uint32_t DdsWriter::matched_readers() const { return match().current; }

template <class Pred>
bool DdsWriter::WaitForMatch(Pred done, std::chrono::milliseconds timeout) const {
  const dds_time_t deadline = dds_time() + DDS_MSECS(timeout.count());
  if (dds_set_status_mask(writer_, DDS_PUBLICATION_MATCHED_STATUS) != DDS_RETCODE_OK) return false;
  dds_entity_t ws = dds_create_waitset(participant_);
  if (ws < 0) return false;
  bool ok = false;
  if (dds_waitset_attach(ws, writer_, writer_) == DDS_RETCODE_OK) {
    while (true) {
      // Reading the status resets its trigger, so the wait below sleeps
      // until the next match change.
      if (done(matched_readers())) {
        ok = true;
        break;
      }
      if (dds_waitset_wait_until(ws, nullptr, 0, deadline) <= 0) {
        ok = done(matched_readers());
        break;
      }
    }
  }
  DeleteEntity(ws);
  return ok;
}

bool DdsWriter::WaitForReaders(uint32_t readers, std::chrono::milliseconds timeout) const {
  return WaitForMatch([readers](uint32_t n) { return n >= readers; }, timeout);
}

bool DdsWriter::WaitForNoReaders(std::chrono::milliseconds timeout) const {
  return WaitForMatch([](uint32_t n) { return n == 0; }, timeout);
}

bool DdsWriter::WaitForAcks(std::chrono::milliseconds timeout) const {
  return dds_wait_for_acks(writer_, DDS_MSECS(timeout.count())) == DDS_RETCODE_OK;
}

// ---- DdsReader ---------------------------------------------------------------------------

DdsReader::DdsReader(const DdsTopic& topic, std::string session)
    : DdsReader(topic, AnySession{}) {
  ValidateSessionName(session);
  session_ = std::move(session);
  any_session_ = false;
}

DdsReader::DdsReader(const DdsTopic& topic, AnySession) : spec_(&topic.spec()), any_session_(true) {
  const Qos qos(*spec_);
  reader_ = dds_create_reader(topic.participant(), topic.handle(), qos.get(), nullptr);
  CUTSIM_CHECK(reader_ > 0, fmt::format("dds_create_reader({}): {}", spec_->name,
                                        dds_strretcode(reader_)));
  read_condition_ = dds_create_readcondition(reader_, DDS_ANY_STATE);
  CUTSIM_CHECK(read_condition_ > 0, "dds_create_readcondition failed");
  waitset_ = dds_create_waitset(topic.participant());
  CUTSIM_CHECK(waitset_ > 0, "dds_create_waitset failed");
  CUTSIM_CHECK(dds_waitset_attach(waitset_, read_condition_, reader_) == DDS_RETCODE_OK,
               "dds_waitset_attach failed");
}

DdsReader::~DdsReader() {
  DeleteEntity(waitset_);
  DeleteEntity(read_condition_);
  DeleteEntity(reader_);
}

uint32_t DdsReader::matched_writers() const {
  dds_subscription_matched_status_t status{};
  if (dds_get_subscription_matched_status(reader_, &status) != DDS_RETCODE_OK) return 0;
  return status.current_count;
}

size_t DdsReader::TakeImpl(std::chrono::nanoseconds timeout, Callback cb, void* ctx) {
  if (timeout.count() > 0) {
    const dds_return_t rc = dds_waitset_wait(waitset_, nullptr, 0, timeout.count());
    if (rc < 0) {
      ++stats_.errors;
      return 0;
    }
    if (rc == 0) return 0;  // timed out, nothing available
  }
  constexpr uint32_t kBatch = 16;
  size_t delivered = 0;
  while (true) {
    std::array<void*, kBatch> samples{};  // null: Cyclone lends its own buffers
    std::array<dds_sample_info_t, kBatch> infos{};
    const dds_return_t n = dds_take_wl(reader_, samples.data(), infos.data(), kBatch);
    if (n < 0) {
      ++stats_.errors;
      break;
    }
    if (n == 0) break;
    // Return the loan even if the callback throws.
    struct LoanGuard {
      dds_entity_t reader;
      void** buf;
      int32_t n;
      ~LoanGuard() { static_cast<void>(dds_return_loan(reader, buf, n)); }
    } guard{reader_, samples.data(), n};
    for (int32_t i = 0; i < n; ++i) {
      if (!infos[static_cast<size_t>(i)].valid_data) {
        ++stats_.no_data;
        continue;
      }
      const auto* e = static_cast<const cutsim_dds_Envelope*>(samples[static_cast<size_t>(i)]);
      const std::string_view key(e->session, strnlen(e->session, sizeof(e->session)));
      if (any_session_ ? !IsValidSessionName(key) : key != session_) {
        ++stats_.foreign_session;
        continue;
      }
      if (static_cast<uint32_t>(e->kind) != static_cast<uint32_t>(spec_->kind)) {
        ++stats_.bad_kind;
        continue;
      }
      const EnvelopeView view{
          .session = key,
          .seq = e->seq,
          .kind = spec_->kind,
          .payload = std::span<const uint8_t>(e->payload._buffer, e->payload._length),
          .topic = spec_->name};
      ++stats_.delivered;
      ++delivered;
      cb(ctx, view);
    }
    if (n < static_cast<dds_return_t>(kBatch)) break;
  }
  return delivered;
}

}  // namespace cutsim::transport
