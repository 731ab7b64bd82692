// The installed tree's folders are found relative to the executable, wherever
// the tree lies; without them the fallback (the source or build tree) holds.

#include "common/core/install_paths.h"

#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <string>

#include <gtest/gtest.h>

namespace cutsim {
namespace {
namespace fs = std::filesystem;

class InstallPathsTest : public ::testing::Test {
 protected:
  void SetUp() override {
    root_ = fs::temp_directory_path() /
            ("cutsim-install-paths-" + std::to_string(::getpid()) + "-" +
             ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::remove_all(root_);
    fs::create_directories(root_ / "usr" / "bin");
  }
  void TearDown() override { fs::remove_all(root_); }
  fs::path root_;
};

TEST_F(InstallPathsTest, InstalledDataFolderBesideBinWins) {
  fs::create_directories(root_ / "usr" / "share" / "cutsim");
  EXPECT_EQ(ResolveInstallDir(root_ / "usr" / "bin", "../share/cutsim", "/src/cutsim"),
            root_ / "usr" / "share" / "cutsim");
}

TEST_F(InstallPathsTest, MissingInstalledFolderFallsBack) {
  EXPECT_EQ(ResolveInstallDir(root_ / "usr" / "bin", "../share/cutsim", "/src/cutsim"), fs::path("/src/cutsim"));
}

TEST_F(InstallPathsTest, AFileInPlaceOfTheFolderFallsBack) {
  fs::create_directories(root_ / "usr" / "share");
  std::ofstream(root_ / "usr" / "share" / "cutsim") << "not a folder\n";
  EXPECT_EQ(ResolveInstallDir(root_ / "usr" / "bin", "../share/cutsim", "/src/cutsim"), fs::path("/src/cutsim"));
}

TEST_F(InstallPathsTest, PluginFolderUnderMultiarchLib) {
  const fs::path plugins = root_ / "usr" / "lib" / "x86_64-linux-gnu" / "cutsim" / "devices";
  fs::create_directories(plugins);
  EXPECT_EQ(ResolveInstallDir(root_ / "usr" / "bin", "../lib/x86_64-linux-gnu/cutsim/devices", root_ / "usr" / "bin"),
            plugins);
}

TEST(InstallPaths, ExecutableDirIsTheTestBinarysFolder) {
  const fs::path dir = ExecutableDir();
  EXPECT_TRUE(fs::is_directory(dir)) << dir;
  EXPECT_TRUE(fs::exists(dir / "core_test")) << dir;
}

TEST(InstallPaths, BuildTreeDataDirIsTheSourceTree) {
  // The test binary runs from the build tree, which has no share/cutsim
  // beside bin/: the data folder is the source tree, with the web pages.
  EXPECT_TRUE(fs::exists(DataDir() / "web" / "observer" / "index.html")) << DataDir();
  EXPECT_TRUE(fs::exists(DataDir() / "scenes" / "ligament.pbtxt")) << DataDir();
}

}  // namespace
}  // namespace cutsim
