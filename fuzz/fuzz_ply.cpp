// libFuzzer target: terramap::io::readPly (terramap's header/body checks, then PCL's parser).
#include "fuzz_support.hpp"

#include <terramap/io/readers.hpp>

#include <pcl/console/print.h>

extern "C" int LLVMFuzzerInitialize(int*, char***) {
  terramap::fuzz::setUp();
  // PCL prints a warning for most malformed inputs; at millions of runs that is all one sees.
  pcl::console::setVerbosityLevel(pcl::console::L_ALWAYS);
  return 0;
}

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  static terramap::fuzz::ScratchFile file("ply", ".ply");
  const std::string& path = file.write(data, size);
  terramap::fuzz::expectInputErrorsOnly([&] { terramap::io::readPly(path); });
  return 0;
}
