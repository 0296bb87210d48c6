// The seal of terramap's HDF5 files (io/file_seal.hpp): what it accepts, and that every kind of
// damage (a flipped byte anywhere after the block, truncation, bytes appended, a damaged seal,
// no seal) is an InputError saying which.
#include <terramap/core/error.hpp>
#include <terramap/io/file_seal.hpp>
#include <terramap/io/snapshot.hpp>

#include <gtest/gtest.h>

#include <cstdio>
#include <fstream>
#include <string>
#include <vector>

#include "scratch_dir.hpp"

using namespace terramap;
namespace fs = std::filesystem;

namespace {

class FileSeal : public ScratchDirTest {
 protected:
  FileSeal() : ScratchDirTest("seal_") {}

  /// A file laid out as a writer leaves it before sealing: an empty 512-byte block, then content.
  fs::path unsealed(const std::string& name, std::size_t content_bytes) {
    const fs::path p = dir_ / name;
    std::vector<char> bytes(io::kSealBytes + content_bytes, '\0');
    for (std::size_t i = 0; i < content_bytes; ++i) bytes[io::kSealBytes + i] = static_cast<char>(i * 7 + 3);
    std::ofstream(p, std::ios::binary).write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
    return p;
  }
  static void flipByte(const fs::path& p, std::uint64_t at) {
    std::fstream f(p, std::ios::in | std::ios::out | std::ios::binary);
    f.seekg(static_cast<std::streamoff>(at));
    char c = 0;
    f.read(&c, 1);
    c = static_cast<char>(c ^ 0x10);
    f.seekp(static_cast<std::streamoff>(at));
    f.write(&c, 1);
  }
  static std::string refusal(const fs::path& p) {
    try {
      io::verifySeal(p);
    } catch (const InputError& e) {
      return e.what();
    }
    return "(accepted)";
  }
};

bool has(const std::string& s, const std::string& part) { return s.find(part) != std::string::npos; }

TEST_F(FileSeal, ASealedFileVerifiesAndItsBlockSaysWhatItCovers) {
  // More than the 1 MiB the checksum reads at a time, so the pieces are joined.
  const fs::path p = unsealed("a.h5", (std::size_t{1} << 20) + 4321);
  io::sealFile(p);
  EXPECT_NO_THROW(io::verifySeal(p));
  std::ifstream f(p, std::ios::binary);
  std::string head(40, '\0');
  f.read(head.data(), 40);
  EXPECT_EQ(head.rfind("terramap-seal 1\nbytes 1053409\ncrc64 ", 0), 0u) << head;
}

TEST_F(FileSeal, ALargeFileCheckedInPiecesOnThreadsGivesTheOneCallChecksum) {
  // Past 64 MiB the checksum is read in pieces on their own threads (two or more where the
  // machine has the cores) and combined: the seal must still hold the CRC of the whole content,
  // and damage in the last piece must still show.
  const std::size_t n = (std::size_t{64} << 20) + 12345;
  const fs::path p = unsealed("large.h5", n);
  std::vector<char> bytes(n);
  {
    std::ifstream f(p, std::ios::binary);
    f.seekg(static_cast<std::streamoff>(io::kSealBytes));
    f.read(bytes.data(), static_cast<std::streamsize>(n));
  }
  char want[40];
  std::snprintf(want, sizeof want, "crc64 %016llx\n", static_cast<unsigned long long>(io::crc64(bytes.data(), n)));
  bytes = {};
  io::sealFile(p);
  std::ifstream f(p, std::ios::binary);
  std::string head(io::kSealBytes, '\0');
  f.read(head.data(), static_cast<std::streamsize>(head.size()));
  f.close();
  EXPECT_TRUE(has(head, want)) << head.substr(0, 60) << " vs " << want;
  EXPECT_NO_THROW(io::verifySeal(p));
  flipByte(p, io::kSealBytes + n - 77);
  EXPECT_TRUE(has(refusal(p), "damaged: checksum")) << refusal(p);
}

TEST_F(FileSeal, AFlippedByteAnywhereAfterTheBlockIsDamage) {
  const std::size_t n = 3000;
  const fs::path p = unsealed("b.h5", n);
  io::sealFile(p);
  for (std::uint64_t at : {std::uint64_t{io::kSealBytes}, io::kSealBytes + 1234, io::kSealBytes + n - 1}) {
    flipByte(p, at);
    const std::string why = refusal(p);
    EXPECT_TRUE(has(why, "damaged: checksum")) << at << ": " << why;
    EXPECT_TRUE(has(why, p.string())) << why;
    flipByte(p, at);  // back as it was
    EXPECT_NO_THROW(io::verifySeal(p)) << at;
  }
}

TEST_F(FileSeal, TruncatedOrExtendedFilesAreRefusedByLength) {
  const fs::path p = unsealed("c.h5", 2000);
  io::sealFile(p);
  fs::resize_file(p, io::kSealBytes + 1999);
  EXPECT_TRUE(has(refusal(p), "2511 bytes, but its seal says 2512 (truncated)")) << refusal(p);
  fs::resize_file(p, io::kSealBytes + 2001);
  EXPECT_TRUE(has(refusal(p), "(extended after it was written)")) << refusal(p);
}

TEST_F(FileSeal, NoSealOrADamagedSealIsRefused) {
  const fs::path p = unsealed("d.h5", 100);
  EXPECT_TRUE(has(refusal(p), "no terramap seal")) << refusal(p);
  std::ofstream(dir_ / "short.h5") << "tiny";
  EXPECT_TRUE(has(refusal(dir_ / "short.h5"), "no terramap seal"));
  io::sealFile(p);
  flipByte(p, 23);  // inside "bytes <N>"
  const std::string why = refusal(p);
  EXPECT_TRUE(has(why, "bytes, but its seal says") || has(why, "seal is damaged")) << why;
  EXPECT_TRUE(has(refusal(dir_ / "missing.h5"), "cannot open"));
}

TEST_F(FileSeal, SealingAFileWithoutAnEmptyBlockIsRefusedNotOverwritten) {
  // An HDF5 file created without the user block starts with its superblock's signature.
  const fs::path p = dir_ / "plain.h5";
  std::string bytes = "\x89HDF\r\n\x1a\n";
  bytes.resize(1024, 'x');
  std::ofstream(p, std::ios::binary) << bytes;
  EXPECT_THROW(io::sealFile(p), OutputError);
  std::ifstream f(p, std::ios::binary);
  std::string back((std::istreambuf_iterator<char>(f)), std::istreambuf_iterator<char>());
  EXPECT_EQ(back, bytes);
  // Sealing twice is refused the same way (the block is no longer empty).
  const fs::path q = unsealed("twice.h5", 10);
  io::sealFile(q);
  EXPECT_THROW(io::sealFile(q), OutputError);
  EXPECT_NO_THROW(io::verifySeal(q));
}

}  // namespace
