// libFuzzer target: terramap::io::readRelativePoses and chaining what it read.
#include "fuzz_support.hpp"

#include <terramap/io/trajectory.hpp>

extern "C" int LLVMFuzzerInitialize(int*, char***) {
  terramap::fuzz::setUp();
  return 0;
}

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  static terramap::fuzz::ScratchFile file("relative", ".txt");
  const std::string& path = file.write(data, size);
  using namespace terramap;
  fuzz::expectInputErrorsOnly([&] {
    const auto rel = io::readRelativePoses(path);
    // The reader promises consecutive rows, which is all chaining needs.
    if (io::chainRelativePoses(rel).size() != rel.size() + 1) __builtin_trap();
  });
  return 0;
}
