// libFuzzer target: terramap::io::readKittiBin, and readPointCloud's dispatch on the extension.
#include "fuzz_support.hpp"

#include <terramap/io/readers.hpp>

extern "C" int LLVMFuzzerInitialize(int*, char***) {
  terramap::fuzz::setUp();
  return 0;
}

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  static terramap::fuzz::ScratchFile file("kitti", ".bin");
  const std::string& path = file.write(data, size);
  terramap::fuzz::expectInputErrorsOnly([&] {
    const auto points = terramap::io::readKittiBin(path);
    // Every whole record is a point: the reader may neither drop nor invent one.
    if (points.size() != size / 16) __builtin_trap();
  });
  return 0;
}
