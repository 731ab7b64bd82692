// The event journal beside a checkpoint: records round-trip, a torn tail is
// left out with the valid prefix kept, a corrupt record with records after
// it is refused naming the file and byte offset, a checkpoint restarts the
// journal, and a resume from checkpoint + journal is the tissue the
// uninterrupted session had (topology, rest shape, surface, cut count).
#include "common/sim/event_journal.h"

#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <iterator>
#include <string>
#include <vector>

#include <fmt/format.h>
#include <gtest/gtest.h>

#include "common/core/error.h"
#include "common/sim/checkpoint.h"
#include "common/sim/checkpointer.h"
#include "common/sim/scene_loader.h"
#include "common/sim/simulation.h"
#include "common/transport/journal_auth.h"
#include "tests/support/block_scene.h"

namespace cutsim::sim {
namespace {

namespace fs = std::filesystem;

std::unique_ptr<Simulation> MakeBlock() {
  return Simulation::Create(
      ParseScene(support::BlockScene("journal-block"), "journal-test.pbtxt", fs::temp_directory_path()));
}

std::string ReadBytes(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

void WriteBytes(const fs::path& p, const std::string& bytes) {
  std::ofstream(p, std::ios::binary | std::ios::trunc) << bytes;
}

/// The error of `fn`, or "" if it did not throw InputError.
template <typename Fn>
std::string ErrorOf(Fn&& fn) {
  try {
    fn();
  } catch (const InputError& e) {
    return e.what();
  }
  return "";
}

class JournalTest : public ::testing::Test {
 protected:
  /// The session, run once for the suite: journal from the start, a
  /// checkpoint after the first cut (the journal's compaction), more cuts
  /// journaled after it, then "killed" (no final checkpoint).
  static void SetUpTestSuite() {
    suite_dir_ = fs::temp_directory_path() / ("cutsim-journal-test-" + std::to_string(::getpid()));
    fs::create_directories(suite_dir_);
    session_ = MakeBlock();
    Simulation& sim = *session_;
    PeriodicCheckpointer cp(suite_dir_ / "block.ckpt", 0.0);
    ASSERT_FALSE(cp.Begin(sim, /*resume=*/false));
    auto run_until = [&](uint64_t cuts) {
      while (sim.QuickSummary().cuts < cuts && sim.sim_time() < 0.8) {
        ASSERT_EQ(sim.AdvanceFrame(), SimStatus::kOk);
        cp.JournalNewEvents(sim);
      }
    };
    run_until(1);
    ASSERT_TRUE(cp.Save(sim));
    checkpoint_events_ = sim.TopologyEvents().size();
    run_until(3);
    cp.DrainJournal();
    counters_ = cp.journal_counters();
  }
  static void TearDownTestSuite() {
    session_.reset();
    fs::remove_all(suite_dir_);
  }

  void SetUp() override {
    dir_ = suite_dir_ / ::testing::UnitTest::GetInstance()->current_test_info()->name();
    fs::create_directories(dir_);
  }

  /// A journal of every event of the session, written by EventJournal.
  fs::path WriteWholeJournal() {
    const fs::path path = dir_ / "all.journal";
    EventJournal journal(path);
    v1::JournalHeader header;
    header.set_scene_name("journal-block");
    header.set_lineage(7);
    journal.Start(header, {});
    for (const cutting::TopologyEvent& e : session_->TopologyEvents()) journal.Append(e, 1, 0.5);
    journal.Drain();
    EXPECT_EQ(journal.counters().records, session_->TopologyEvents().size());
    EXPECT_EQ(journal.counters().failures, 0u);
    return path;
  }

  static inline fs::path suite_dir_;
  static inline std::unique_ptr<Simulation> session_;
  static inline size_t checkpoint_events_ = 0;
  static inline JournalCounters counters_;
  fs::path dir_;
};

TEST_F(JournalTest, RecordsRoundTrip) {
  const auto events = session_->TopologyEvents();
  ASSERT_GE(events.size(), 2u) << "the scalpel should have cut by now";
  const fs::path path = WriteWholeJournal();
  const JournalContents j = ReadJournalFile(path);
  EXPECT_FALSE(j.torn);
  EXPECT_EQ(j.valid_bytes, fs::file_size(path));
  EXPECT_EQ(j.header.scene_name(), "journal-block");
  EXPECT_EQ(j.header.lineage(), 7u);
  ASSERT_EQ(j.entries.size(), events.size());
  for (size_t i = 0; i < events.size(); ++i) {
    EXPECT_EQ(j.entries[i].record.event().SerializeAsString(), EventToProto(events[i]).SerializeAsString())
        << "record " << i;
    EXPECT_EQ(j.entries[i].record.cuts(), 1u);
  }
}

TEST_F(JournalTest, TornTailKeepsTheValidPrefix) {
  const fs::path path = WriteWholeJournal();
  const std::string whole = ReadBytes(path);
  const JournalContents all = ReadJournalFile(path);
  ASSERT_GE(all.entries.size(), 2u);
  const uint64_t last = all.entries.back().offset;
  // Cut inside the last record's payload, inside its frame, and a tail of
  // zeros (a file extended but not written): each keeps every whole record.
  for (const size_t keep : {whole.size() - 3, static_cast<size_t>(last) + 5}) {
    WriteBytes(path, whole.substr(0, keep));
    const JournalContents j = ReadJournalFile(path);
    EXPECT_TRUE(j.torn) << keep;
    EXPECT_EQ(j.entries.size(), all.entries.size() - 1) << keep;
    EXPECT_EQ(j.valid_bytes, last) << keep;
  }
  WriteBytes(path, whole + std::string(100, '\0'));
  const JournalContents zeros = ReadJournalFile(path);
  EXPECT_TRUE(zeros.torn);
  EXPECT_EQ(zeros.entries.size(), all.entries.size());
  // The last record's payload garbled in place (its checksum fails, nothing
  // after it): torn too.
  std::string garbled = whole;
  garbled[garbled.size() - 2] ^= 0x5a;
  WriteBytes(path, garbled);
  EXPECT_EQ(ReadJournalFile(path).entries.size(), all.entries.size() - 1);
}

TEST_F(JournalTest, StrayBytesAfterTheLastRecordAreATornTail) {
  const fs::path path = WriteWholeJournal();
  const std::string whole = ReadBytes(path);
  const JournalContents all = ReadJournalFile(path);
  // 300 random bytes appended, several seeds: they hold no whole record, so
  // every record before them is kept with the torn-tail warning.
  for (uint32_t seed = 1; seed <= 20; ++seed) {
    std::string tail(300, '\0');
    uint32_t x = seed * 2654435761u;
    for (char& c : tail) {
      x ^= x << 13;
      x ^= x >> 17;
      x ^= x << 5;
      c = static_cast<char>(x & 0xff);
    }
    WriteBytes(path, whole + tail);
    const JournalContents j = ReadJournalFile(path);
    EXPECT_TRUE(j.torn) << seed;
    EXPECT_EQ(j.entries.size(), all.entries.size()) << seed;
    EXPECT_EQ(j.valid_bytes, whole.size()) << seed;
  }
  // Stray bytes with a whole record after them are not a tail: refused.
  const uint64_t first = all.entries.front().offset;
  std::string bytes = whole;
  bytes.insert(first, std::string(7, '\x42'));
  WriteBytes(path, bytes);
  EXPECT_NE(ErrorOf([&] { (void)ReadJournalFile(path); }).find("corrupted"), std::string::npos);
}

TEST_F(JournalTest, CorruptRecordInTheMiddleIsRefusedNamingFileAndOffset) {
  const fs::path path = WriteWholeJournal();
  std::string bytes = ReadBytes(path);
  const JournalContents all = ReadJournalFile(path);
  ASSERT_GE(all.entries.size(), 2u);
  const uint64_t first = all.entries.front().offset;
  bytes[first + kJournalFrameBytes + 1] ^= 0x5a;
  WriteBytes(path, bytes);
  const std::string err = ErrorOf([&] { (void)ReadJournalFile(path); });
  EXPECT_NE(err.find(path.string()), std::string::npos) << err;
  EXPECT_NE(err.find("record at byte " + std::to_string(first)), std::string::npos) << err;
  EXPECT_NE(err.find("corrupted"), std::string::npos) << err;
  // A bad header is refused, torn or not.
  WriteBytes(path, bytes.substr(0, 5));
  EXPECT_NE(ErrorOf([&] { (void)ReadJournalFile(path); }).find("header"), std::string::npos);
  WriteBytes(path, "");
  EXPECT_NE(ErrorOf([&] { (void)ReadJournalFile(path); }), "");
}

transport::SessionKey KeyOf(uint8_t fill) {
  transport::SessionKey key;
  key.size = 32;
  for (size_t i = 0; i < key.size; ++i) key.bytes[i] = static_cast<uint8_t>(fill + i);
  return key;
}

// With the session key every record carries its HMAC: a record edited and
// re-framed with a correct checksum is refused, naming it; so is the
// journal without the key, with another key, and an unsigned journal read
// with a key.
TEST_F(JournalTest, SignedJournalRefusesAnEditedRecordWhoseChecksumWasFixed) {
  transport::HmacJournalSigner signer(KeyOf(0x11));
  transport::HmacJournalSigner other(KeyOf(0x22));
  const fs::path path = dir_ / "signed.journal";
  {
    EventJournal journal(path, &signer);
    v1::JournalHeader header;
    header.set_scene_name("journal-block");
    header.set_lineage(7);
    journal.Start(header, {});
    for (const cutting::TopologyEvent& e : session_->TopologyEvents()) journal.Append(e, 1, 0.5);
    journal.Drain();
    ASSERT_EQ(journal.counters().failures, 0u);
  }
  const JournalContents good = ReadJournalFile(path, &signer);
  EXPECT_TRUE(good.header.authenticated());
  ASSERT_EQ(good.entries.size(), session_->TopologyEvents().size());
  ASSERT_GE(good.entries.size(), 2u);
  EXPECT_EQ(good.entries[1].record.cuts(), 1u);

  // The second record says 99 cuts; its old tag is kept, the frame's
  // length and checksum are made right.
  const JournalEntry& victim = good.entries[1];
  v1::JournalRecord edited = victim.record;
  edited.set_cuts(99);
  const std::string old_tag = victim.payload.substr(victim.payload.size() - transport::kTrailerBytes);
  const std::string whole = ReadBytes(path);
  std::string bytes = whole;
  bytes.replace(victim.offset, kJournalFrameBytes + victim.payload.size(),
                FrameJournalRecord(edited.SerializeAsString() + old_tag));
  WriteBytes(path, bytes);
  const std::string err = ErrorOf([&] { (void)ReadJournalFile(path, &signer); });
  EXPECT_NE(err.find(path.string()), std::string::npos) << err;
  EXPECT_NE(err.find("record at byte " + std::to_string(victim.offset)), std::string::npos) << err;
  EXPECT_NE(err.find("HMAC does not match"), std::string::npos) << err;

  WriteBytes(path, whole);
  EXPECT_NE(ErrorOf([&] { (void)ReadJournalFile(path, &other); }).find("HMAC does not match"), std::string::npos);
  EXPECT_NE(ErrorOf([&] { (void)ReadJournalFile(path); }).find("signed with a session key"), std::string::npos);
  EXPECT_NE(ErrorOf([&] { (void)ReadJournalFile(WriteWholeJournal(), &signer); }).find("not signed"),
            std::string::npos);
  EXPECT_EQ(ErrorOf([&] { (void)ReadJournalFile(path, &signer); }), "");
}

TEST_F(JournalTest, CheckpointRestartsTheJournalAfterItsLastEvent) {
  const auto events = session_->TopologyEvents();
  ASSERT_GT(events.size(), checkpoint_events_) << "the session should cut after its checkpoint";
  const v1::CheckpointBody ckpt = ReadCheckpointFile(suite_dir_ / "block.ckpt");
  ASSERT_EQ(static_cast<size_t>(ckpt.events_size()), checkpoint_events_);
  const JournalContents j = ReadJournalFile(JournalPathFor(suite_dir_ / "block.ckpt"));
  EXPECT_EQ(j.header.base_topology_version(), LastEventVersion(ckpt));
  EXPECT_EQ(j.header.lineage(), ckpt.lineage());
  EXPECT_NE(ckpt.lineage(), 0u);
  // Only the events after the checkpoint, in order.
  ASSERT_EQ(j.entries.size(), events.size() - checkpoint_events_);
  for (size_t i = 0; i < j.entries.size(); ++i) {
    EXPECT_EQ(j.entries[i].record.event().version(), events[checkpoint_events_ + i].version);
  }
  EXPECT_EQ(counters_.failures, 0u);
  EXPECT_EQ(counters_.restarts, 2u);  // at start and after the checkpoint
  EXPECT_EQ(counters_.durable_version, events.back().version);
}

/// The topology of two simulations: version, counts, rest shape, tets,
/// surface and its opened faces, cuts.
void ExpectSameTopology(const Simulation& a, const Simulation& b) {
  MeshView va, vb;
  a.FillMeshView(va);
  b.FillMeshView(vb);
  EXPECT_EQ(a.topology_version(), b.topology_version());
  ASSERT_EQ(va.rest.rows(), vb.rest.rows()) << "node counts differ";
  ASSERT_EQ(va.tets.rows(), vb.tets.rows());
  EXPECT_TRUE(va.rest == vb.rest) << "rest positions differ";
  EXPECT_TRUE(va.tets == vb.tets) << "tets differ";
  ASSERT_EQ(va.surface.rows(), vb.surface.rows());
  EXPECT_TRUE(va.surface == vb.surface) << "surface differs";
  EXPECT_EQ(va.opened, vb.opened);
  EXPECT_EQ(a.QuickSummary().cuts, b.QuickSummary().cuts);
  EXPECT_EQ(a.Summary().opened_faces, b.Summary().opened_faces);
}

TEST_F(JournalTest, ResumeIsTheUninterruptedTopology) {
  for (const char* f : {"block.ckpt", "block.ckpt.journal"}) fs::copy_file(suite_dir_ / f, dir_ / f);
  auto resumed = MakeBlock();
  PeriodicCheckpointer cp(dir_ / "block.ckpt", 0.0);
  ASSERT_TRUE(cp.Begin(*resumed, /*resume=*/true));
  ExpectSameTopology(*session_, *resumed);
  // The positions are the checkpoint's: older than the session's.
  EXPECT_LT(resumed->sim_time(), session_->sim_time());

  // The control: the checkpoint alone is behind the session.
  fs::copy_file(suite_dir_ / "block.ckpt", dir_ / "alone.ckpt");
  auto alone = MakeBlock();
  PeriodicCheckpointer cp_alone(dir_ / "alone.ckpt", 0.0);
  ASSERT_TRUE(cp_alone.Begin(*alone, true));
  EXPECT_LT(alone->topology_version(), session_->topology_version());

  // The new journal carries the replayed events over: killed again before
  // any checkpoint, the next resume has them still.
  cp.DrainJournal();
  auto again = MakeBlock();
  PeriodicCheckpointer cp_again(dir_ / "block.ckpt", 0.0);
  ASSERT_TRUE(cp_again.Begin(*again, true));
  ExpectSameTopology(*session_, *again);
}

TEST_F(JournalTest, JournalAloneResumesOnTheUncutScene) {
  fs::copy_file(suite_dir_ / "block.ckpt.journal", dir_ / "block.ckpt.journal");
  // The suite's journal continues its checkpoint: without it, refused.
  auto sim = MakeBlock();
  PeriodicCheckpointer cp(dir_ / "block.ckpt", 0.0);
  const std::string err = ErrorOf([&] { (void)cp.Begin(*sim, true); });
  EXPECT_NE(err.find("base_topology_version"), std::string::npos) << err;
  EXPECT_NE(err.find("does not exist"), std::string::npos) << err;

  // A session journaled from the start and killed before any checkpoint.
  const fs::path whole = dir_ / "fresh.ckpt";
  {
    EventJournal journal(JournalPathFor(whole));
    v1::JournalHeader header;
    const v1::CheckpointBody self = session_->CheckpointState();
    header.set_scene_name(self.scene_name());
    header.set_scene_fingerprint(self.scene_fingerprint());
    header.set_precision(self.precision());
    header.set_lineage(99);
    journal.Start(header, {});
    for (const cutting::TopologyEvent& e : session_->TopologyEvents()) {
      journal.Append(e, session_->QuickSummary().cuts, 0.5);
    }
  }
  auto fresh = MakeBlock();
  PeriodicCheckpointer cp_fresh(whole, 0.0);
  ASSERT_TRUE(cp_fresh.Begin(*fresh, true));
  ExpectSameTopology(*session_, *fresh);
  EXPECT_EQ(fresh->sim_time(), 0.0);
}

TEST_F(JournalTest, AnotherSessionsJournalBesideACheckpointIsRefusedNamingBoth) {
  // The suite's checkpoint, and beside it the journal of a session started
  // from the scene (another lineage, continuing version 0).
  const fs::path ckpt = dir_ / "block.ckpt";
  fs::copy_file(suite_dir_ / "block.ckpt", ckpt);
  const std::string before = ReadBytes(ckpt);
  const v1::CheckpointBody self = session_->CheckpointState();
  {
    EventJournal journal(JournalPathFor(ckpt));
    v1::JournalHeader header;
    header.set_scene_name(self.scene_name());
    header.set_scene_fingerprint(self.scene_fingerprint());
    header.set_precision(self.precision());
    header.set_lineage(0x99);
    journal.Start(header, {});
  }
  auto sim = MakeBlock();
  PeriodicCheckpointer cp(ckpt, 0.0);
  const std::string err = ErrorOf([&] { (void)cp.Begin(*sim, true); });
  EXPECT_NE(err.find("lineage 0000000000000099"), std::string::npos) << err;
  EXPECT_NE(err.find(fmt::format("lineage {:016x}", ReadCheckpointFile(ckpt).lineage())), std::string::npos) << err;
  EXPECT_NE(err.find(ckpt.string()), std::string::npos) << err;
  EXPECT_EQ(ReadBytes(ckpt), before) << "the checkpoint is untouched";
  EXPECT_EQ(sim->topology_version(), 0u) << "nothing applied";
}

TEST_F(JournalTest, BadEventsAreRefusedNamingTheRecordsOffset) {
  const v1::CheckpointBody self = session_->CheckpointState();
  v1::JournalHeader header;
  header.set_scene_name(self.scene_name());
  header.set_scene_fingerprint(self.scene_fingerprint());
  header.set_precision(self.precision());
  header.set_lineage(5);
  // A checksummed record whose event splits a node the mesh lacks.
  v1::JournalRecord bad;
  *bad.mutable_event() = EventToProto(session_->TopologyEvents().front());
  bad.mutable_event()->mutable_splits(0)->set_node(1 << 30);
  const std::string payload = bad.SerializeAsString();
  const fs::path ckpt = dir_ / "bad.ckpt";
  {
    EventJournal journal(JournalPathFor(ckpt));
    journal.Start(header, std::vector<std::string>{payload});
  }
  auto sim = MakeBlock();
  PeriodicCheckpointer cp(ckpt, 0.0);
  const std::string err = ErrorOf([&] { (void)cp.Begin(*sim, true); });
  EXPECT_NE(err.find(JournalPathFor(ckpt).string()), std::string::npos) << err;
  EXPECT_NE(err.find("record at byte "), std::string::npos) << err;
  EXPECT_NE(err.find("splits"), std::string::npos) << err;
  EXPECT_EQ(sim->topology_version(), 0u) << "nothing applied";

  // A journal of another scene is refused.
  header.set_scene_name("another");
  {
    EventJournal journal(JournalPathFor(ckpt));
    journal.Start(header, {});
  }
  auto sim2 = MakeBlock();
  PeriodicCheckpointer cp2(ckpt, 0.0);
  EXPECT_NE(ErrorOf([&] { (void)cp2.Begin(*sim2, true); }).find("scene_name"), std::string::npos);
}

}  // namespace
}  // namespace cutsim::sim
