// libFuzzer target: KITTI poses (readKittiPoseRows) with a times file (readStampFile,
// readKittiTrajectory). One input holds both files: the poses, then a line "%%", then the
// times; without that line the poses are stamped at a fixed period instead.
#include "fuzz_support.hpp"

#include <terramap/io/trajectory.hpp>

#include <string_view>

extern "C" int LLVMFuzzerInitialize(int*, char***) {
  terramap::fuzz::setUp();
  return 0;
}

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  static terramap::fuzz::ScratchFile poses("kitti-poses", ".txt"), times("kitti-times", ".txt");
  using namespace terramap;
  const std::string_view all(reinterpret_cast<const char*>(data), size);
  const std::size_t cut = all.find("\n%%\n");
  const std::string_view p = all.substr(0, cut), t = cut == std::string_view::npos ? "" : all.substr(cut + 4);
  poses.write(reinterpret_cast<const std::uint8_t*>(p.data()), p.size());
  times.write(reinterpret_cast<const std::uint8_t*>(t.data()), t.size());
  fuzz::expectInputErrorsOnly([&] {
    const io::Trajectory tr = cut == std::string_view::npos ? io::readKittiTrajectory(poses.path(), 0.1)
                                                            : io::readKittiTrajectory(poses.path(), times.path());
    if (!tr.empty() && !tr.at(tr.endStamp()).matrix().allFinite()) __builtin_trap();
  });
  return 0;
}
