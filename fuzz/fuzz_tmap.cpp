// libFuzzer target: `.tmap` snapshots (terramap::io::loadSnapshot, readSnapshotInfo,
// decodeSnapshot).
//
// Random bytes almost never carry valid CRC-64s, so every input is tried twice: as it is (the
// magic, length and checksum checks) and with its length field and both checksums recomputed,
// which lets mutations reach the geometry, layer and tile decoding behind the checksums.
// A map that decodes must also survive a round trip: encode -> decode -> encode gives the same
// bytes.
#include "fuzz_support.hpp"

#include <terramap/io/snapshot.hpp>

#include <cstring>
#include <vector>

namespace {

void putU64(unsigned char* p, std::uint64_t v) {
  for (int i = 0; i < 8; ++i) p[i] = static_cast<unsigned char>(v >> (8 * i));
}

void checkRoundTrip(const terramap::LayeredMap& map) {
  using namespace terramap;
  const std::vector<unsigned char> once = io::encodeSnapshot(map);
  try {
    const LayeredMap again = io::decodeSnapshot(once.data(), once.size(), "round trip");
    if (io::encodeSnapshot(again) != once) __builtin_trap();
  } catch (const InputError&) {
    __builtin_trap();  // terramap refused a snapshot it wrote itself
  }
}

}  // namespace

extern "C" int LLVMFuzzerInitialize(int*, char***) {
  terramap::fuzz::setUp();
  return 0;
}

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  static terramap::fuzz::ScratchFile file("tmap", ".tmap");
  using namespace terramap;
  file.write(data, size);
  fuzz::expectInputErrorsOnly([&] { checkRoundTrip(io::loadSnapshot(file.path())); });

  const std::size_t header = io::kSnapshotHeaderBytes;
  if (size < header + 8 || std::memcmp(data, "TMAP", 4) != 0) return 0;
  std::vector<unsigned char> fixed(data, data + size);
  putU64(&fixed[8], size);
  putU64(&fixed[64], io::crc64(fixed.data(), 64));
  putU64(&fixed[size - 8], io::crc64(fixed.data(), size - 8));
  fuzz::expectInputErrorsOnly([&] { checkRoundTrip(io::decodeSnapshot(fixed.data(), fixed.size(), "fuzz.tmap")); });
  file.write(fixed.data(), fixed.size());
  fuzz::expectInputErrorsOnly([&] { io::readSnapshotInfo(file.path()); });
  return 0;
}
