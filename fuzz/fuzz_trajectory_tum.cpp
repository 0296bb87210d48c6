// libFuzzer target: terramap::io::readTumTrajectory, then interpolation inside what was read.
#include "fuzz_support.hpp"

#include <terramap/io/trajectory.hpp>

extern "C" int LLVMFuzzerInitialize(int*, char***) {
  terramap::fuzz::setUp();
  return 0;
}

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  static terramap::fuzz::ScratchFile file("tum", ".txt");
  const std::string& path = file.write(data, size);
  using namespace terramap;
  fuzz::expectInputErrorsOnly([&] {
    const io::Trajectory t = io::readTumTrajectory(path);
    if (t.empty()) return;
    // A trajectory that loads must answer inside its own range.
    const double mid = t.startStamp() + 0.5 * (t.endStamp() - t.startStamp());
    for (double s : {t.startStamp(), mid, t.endStamp()}) {
      if (!t.at(s).matrix().allFinite()) __builtin_trap();
    }
  });
  return 0;
}
