#include "scratch_dir.hpp"
#include <terramap/core/error.hpp>
#include <terramap/io/atomic_file.hpp>

#include <gtest/gtest.h>

#include <algorithm>
#include <cerrno>
#include <cstring>
#include <fstream>
#include <iterator>
#include <random>
#include <stdexcept>
#include <string>
#include <vector>

#include <unistd.h>

namespace fs = std::filesystem;
using terramap::OutputError;
namespace tio = terramap::io;

namespace {

/// A fresh folder per test so directory listings are meaningful.
class AtomicFileTest : public ScratchDirTest {
 protected:
  AtomicFileTest() : ScratchDirTest("atomic_") {}

  static std::string slurp(const fs::path& p) {
    std::ifstream in(p, std::ios::binary);
    return std::string(std::istreambuf_iterator<char>(in), {});
  }
};

TEST_F(AtomicFileTest, WritesAndReplacesWithoutLeavingTemporaries) {
  const fs::path target = dir_ / "out.bin";
  tio::writeFileAtomically(target, std::string("first"));
  EXPECT_EQ(slurp(target), "first");
  tio::writeFileAtomically(target, std::string("second, longer"));
  EXPECT_EQ(slurp(target), "second, longer");
  EXPECT_EQ(listing(), std::vector<std::string>{"out.bin"});
}

TEST_F(AtomicFileTest, TemporaryLivesNextToTargetAndCarriesPid) {
  const fs::path target = dir_ / "map.tmap";
  tio::AtomicFile f(target);
  EXPECT_EQ(f.tempPath().parent_path(), target.parent_path());
  const std::string name = f.tempPath().filename().string();
  const std::string prefix = "map.tmap.tmp." + std::to_string(::getpid()) + ".";
  ASSERT_EQ(name.rfind(prefix, 0), 0u) << name;
  EXPECT_EQ(name.size(), prefix.size() + 16);  // 64 random bits in hex
  EXPECT_TRUE(fs::exists(f.tempPath()));
  EXPECT_FALSE(fs::exists(target));  // nothing visible under the target name before commit
  f.write("abc", 3);
  f.commit();
  EXPECT_FALSE(fs::exists(f.tempPath()));
  EXPECT_EQ(slurp(target), "abc");
}

TEST_F(AtomicFileTest, TwoTemporariesForTheSameTargetDiffer) {
  const fs::path target = dir_ / "x";
  tio::AtomicFile a(target), b(target);
  EXPECT_NE(a.tempPath(), b.tempPath());
}

TEST_F(AtomicFileTest, LargeWritesCrossTheBufferIntact) {
  // 3.5 MiB in uneven pieces: crosses the 1 MiB internal buffer several times.
  std::vector<unsigned char> data(3 * 1024 * 1024 + 512 * 1024);
  std::mt19937 rng(7);
  for (auto& c : data) c = static_cast<unsigned char>(rng());
  const fs::path target = dir_ / "big.bin";
  tio::AtomicFile f(target);
  std::size_t off = 0, piece = 1;
  while (off < data.size()) {
    const std::size_t n = std::min(piece, data.size() - off);
    f.write(data.data() + off, n);
    off += n;
    piece = piece * 3 + 17;
  }
  EXPECT_EQ(f.size(), data.size());
  f.commit();
  const std::string back = slurp(target);
  ASSERT_EQ(back.size(), data.size());
  EXPECT_EQ(0, std::memcmp(back.data(), data.data(), data.size()));
}

TEST_F(AtomicFileTest, DroppedWithoutCommitKeepsOldContent) {
  const fs::path target = dir_ / "keep.txt";
  tio::writeFileAtomically(target, std::string("old"));
  {
    tio::AtomicFile f(target);
    f.write("new new new", 11);
  }  // destroyed: e.g. an exception while encoding
  EXPECT_EQ(slurp(target), "old");
  EXPECT_EQ(listing(), std::vector<std::string>{"keep.txt"});
}

TEST_F(AtomicFileTest, MissingFolderNamesPathAndErrno) {
  const fs::path target = dir_ / "no_such_dir" / "out.bin";
  try {
    tio::writeFileAtomically(target, std::string("x"));
    FAIL() << "expected OutputError";
  } catch (const OutputError& e) {
    const std::string msg = e.what();
    EXPECT_NE(msg.find(target.string()), std::string::npos) << msg;
    EXPECT_NE(msg.find("No such file or directory"), std::string::npos) << msg;
    // The folder is what the user must fix; the temporary file's name means nothing to them.
    EXPECT_NE(msg.find("folder '" + (dir_ / "no_such_dir").string() + "' does not exist"), std::string::npos) << msg;
    EXPECT_EQ(msg.find(".tmp."), std::string::npos) << msg;
  }
}

TEST_F(AtomicFileTest, RenameFailureRemovesTemporary) {
  // The target is a non-empty directory: rename(2) refuses to replace it.
  const fs::path target = dir_ / "occupied";
  fs::create_directories(target / "inner");
  try {
    tio::writeFileAtomically(target, std::string("data"));
    FAIL() << "expected OutputError";
  } catch (const OutputError& e) {
    const std::string msg = e.what();
    EXPECT_NE(msg.find(target.string()), std::string::npos) << msg;
    EXPECT_NE(msg.find("rename"), std::string::npos) << msg;
    EXPECT_NE(msg.find(std::strerror(EISDIR)), std::string::npos) << msg;
  }
  EXPECT_EQ(listing(), std::vector<std::string>{"occupied"});
  EXPECT_TRUE(fs::is_directory(target / "inner"));
}

TEST_F(AtomicFileTest, PathProducerFailureKeepsTargetAndCleansUp) {
  const fs::path target = dir_ / "image.png";
  tio::writeFileAtomically(target, std::string("old image"));
  EXPECT_THROW(tio::replaceFileAtomically(target,
                                          [](const fs::path& tmp) {
                                            std::ofstream(tmp) << "half written";
                                            std::ofstream(tmp.string() + ".aux.xml") << "<PAM/>";
                                            throw std::runtime_error("driver failed");
                                          }),
               std::runtime_error);
  EXPECT_EQ(slurp(target), "old image");
  EXPECT_EQ(listing(), std::vector<std::string>{"image.png"});
}

TEST_F(AtomicFileTest, PathProducerSuccessRenamesAndDropsSideCar) {
  const fs::path target = dir_ / "image.tif";
  fs::path seen;
  tio::replaceFileAtomically(target, [&](const fs::path& tmp) {
    seen = tmp;
    EXPECT_TRUE(fs::exists(tmp));  // reserved with O_EXCL before the producer runs
    std::ofstream(tmp, std::ios::trunc) << "tiff bytes";
    std::ofstream(tmp.string() + ".aux.xml") << "<PAM/>";
  });
  EXPECT_EQ(seen.parent_path(), target.parent_path());
  EXPECT_EQ(slurp(target), "tiff bytes");
  EXPECT_EQ(listing(), std::vector<std::string>{"image.tif"});
}

TEST_F(AtomicFileTest, ProducerThatDeletesItsFileIsAnOutputError) {
  const fs::path target = dir_ / "gone.tif";
  EXPECT_THROW(tio::replaceFileAtomically(target, [](const fs::path& tmp) { fs::remove(tmp); }), OutputError);
  EXPECT_TRUE(listing().empty());
}

TEST_F(AtomicFileTest, WriteAfterCommitThrows) {
  tio::AtomicFile f(dir_ / "a");
  f.commit();
  EXPECT_THROW(f.write("x", 1), OutputError);
  EXPECT_THROW(f.commit(), OutputError);
}

}  // namespace
