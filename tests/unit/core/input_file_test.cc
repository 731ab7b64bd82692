// The one gate every reader passes: regular files only, a size cap, counts
// against the bytes present, outputs checked at start, checked writes.

#include "common/core/input_file.h"

#include <sys/stat.h>
#include <unistd.h>

#include <cmath>
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <string>
#include <utility>

#include <gtest/gtest.h>

#include "common/core/error.h"
#include "common/core/finite.h"

namespace cutsim {
namespace {

class InputFileTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = std::filesystem::temp_directory_path() / ("cutsim_input_file_" + std::to_string(::getpid()));
    std::filesystem::create_directories(dir_);
  }
  void TearDown() override { std::filesystem::remove_all(dir_); }
  std::string Write(const std::string& name, const std::string& text) {
    const std::string path = (dir_ / name).string();
    std::ofstream(path, std::ios::binary) << text;
    return path;
  }
  std::filesystem::path dir_;
};

/// The message of the InputError `fn` throws ("" if none).
template <typename Fn>
std::string ErrorOf(Fn&& fn) {
  try {
    fn();
  } catch (const InputError& e) {
    return e.what();
  }
  return "";
}

TEST_F(InputFileTest, ReadsARegularFile) {
  const std::string path = Write("a.txt", "hello\n");
  EXPECT_EQ(ReadInputFile(path, "test file"), "hello\n");
  EXPECT_EQ(CheckInputFile(path, "test file"), 6u);
}

TEST_F(InputFileTest, RefusesDevicesDirectoriesAndMissingFilesNamingThem) {
  for (const auto& [path, kind] : {std::pair{std::string("/dev/zero"), "character device"},
                                   std::pair{dir_.string(), "directory"},
                                   std::pair{(dir_ / "missing").string(), "No such file"}}) {
    const std::string what = ErrorOf([&, &path = path] { (void)ReadInputFile(path, "scene file"); });
    EXPECT_NE(what.find(path), std::string::npos) << what;
    EXPECT_NE(what.find("scene file"), std::string::npos) << what;
    EXPECT_NE(what.find(kind), std::string::npos) << what;
  }
  EXPECT_NE(ErrorOf([] { (void)ReadInputFile("", "key file"); }).find("key file"), std::string::npos);
}

TEST_F(InputFileTest, RefusesAFileOverTheCap) {
  const std::string path = Write("big", std::string(100, 'x'));
  const std::string what = ErrorOf([&] { (void)ReadInputFile(path, "mesh file", 99); });
  EXPECT_NE(what.find("limit of 99 bytes"), std::string::npos) << what;
  EXPECT_EQ(ReadInputFile(path, "mesh file", 100).size(), 100u);
}

TEST(RequireCountFits, RefusesCountsTheFileCannotHold) {
  const SourceRef where{.file = "m.node", .line = 1};
  EXPECT_NO_THROW(RequireCountFits(10, 8, 80, where, "node count"));
  EXPECT_THROW(RequireCountFits(11, 8, 80, where, "node count"), InputError);
  EXPECT_THROW(RequireCountFits(100'000'000, 8, 20, where, "node count"), InputError);
  EXPECT_THROW(RequireCountFits(-1, 8, 80, where, "node count"), InputError);
  EXPECT_THROW(RequireCountFits(INT64_MAX, 8, UINT64_MAX / 16, where, "node count"), InputError);
}

TEST_F(InputFileTest, OutputPathsAreCheckedBeforeTheWork) {
  EXPECT_NO_THROW(CheckOutputPath((dir_ / "new.vtu").string(), "final state"));
  // A device, a pipe or a directory would be replaced by the rename that
  // puts an output in place: refused, naming what it is.
  for (const auto& [path, kind] : {std::pair{std::string("/dev/null"), "character device"},
                                   std::pair{std::string("/dev/full"), "character device"},
                                   std::pair{dir_.string(), "directory"}}) {
    const std::string e = ErrorOf([&, &path = path] { CheckOutputPath(path, "final state (--out)"); });
    EXPECT_NE(e.find(kind), std::string::npos) << e;
    EXPECT_NE(e.find("--out"), std::string::npos) << e;
    EXPECT_NE(e.find(path), std::string::npos) << e;
  }
  const std::string fifo = (dir_ / "fifo").string();
  ASSERT_EQ(::mkfifo(fifo.c_str(), 0600), 0);
  EXPECT_NE(ErrorOf([&] { CheckOutputPath(fifo, "checkpoint (--checkpoint)"); }).find("pipe"), std::string::npos);
  EXPECT_NE(ErrorOf([&] { WriteFileAtomically(fifo, "{}"); }).find("pipe"), std::string::npos);
  EXPECT_TRUE(std::filesystem::is_fifo(fifo)) << "the pipe was replaced";
  const std::string missing_dir = ErrorOf([&] { CheckOutputPath((dir_ / "no/such/dir.ckpt").string(), "checkpoint"); });
  EXPECT_NE(missing_dir.find("does not exist"), std::string::npos) << missing_dir;
  EXPECT_NE(ErrorOf([&] { CheckOutputPath(dir_.string(), "checkpoint"); }).find("directory"), std::string::npos);
  if (::geteuid() != 0) {  // root writes anywhere
    std::filesystem::permissions(dir_, std::filesystem::perms::owner_read | std::filesystem::perms::owner_exec);
    EXPECT_THROW(CheckOutputPath((dir_ / "x.ckpt").string(), "checkpoint"), InputError);
    std::filesystem::permissions(dir_, std::filesystem::perms::owner_all);
  }
}

TEST_F(InputFileTest, AtomicWriteChecksEveryStep) {
  const std::string path = (dir_ / "out.json").string();
  WriteFileAtomically(path, "{}\n");
  EXPECT_EQ(ReadInputFile(path, "out"), "{}\n");
  EXPECT_FALSE(std::filesystem::exists(path + ".tmp"));
  EXPECT_THROW(WriteFileAtomically((dir_ / "missing/out.json").string(), "{}"), InputError);
}

TEST(Finite, RequireIndexRefusesNonIntegralNonFiniteAndOutOfRange) {
  const SourceRef where{.file = "m.vtu", .field = "cell 1"};
  EXPECT_EQ(RequireIndex(3.0, 0, 3, where), 3);
  for (const double bad : {-1.0, 4.0, 1.5, 1e20, -1e20, std::nan(""), HUGE_VAL}) {
    EXPECT_THROW((void)RequireIndex(bad, 0, 3, where), InputError) << bad;
  }
  EXPECT_THROW(RequireFinite(std::nan(""), where, "x"), InputError);
  EXPECT_NO_THROW(RequireFinite(1e300, where, "x"));
}

}  // namespace
}  // namespace cutsim
