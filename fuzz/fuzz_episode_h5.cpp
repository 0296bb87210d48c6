// libFuzzer target: HDF5 episodes through terramap::sim::readEpisodeDataset (the budget check
// on a dataset's declared size, then HDF5's read and conversion to double).
#include "fuzz_support.hpp"

#include <terramap/sim/episode.hpp>

#include <hdf5.h>

extern "C" int LLVMFuzzerInitialize(int*, char***) {
  terramap::fuzz::setUp();
  // HDF5 prints an error stack for every failed call; readEpisodeDataset turns them off too,
  // but only once it is first called.
  H5Eset_auto2(H5E_DEFAULT, nullptr, nullptr);
  return 0;
}

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  static terramap::fuzz::ScratchFile file("episode", ".h5");
  const std::string& path = file.write(data, size);
  using namespace terramap;
  // Datasets the evaluation tools read (docs/sim.md), of different ranks and types; the seeds
  // carry them (fuzz/seeds/make_seeds.cpp).
  static const char* const kDatasets[] = {"/terrain/height", "/machines/ctl1/T_map_base", "/terrain/snapshot_stamp",
                                          "/machines/ctl1/truth/stalled"};
  for (const char* name : kDatasets) {
    fuzz::expectInputErrorsOnly([&] {
      std::vector<std::uint64_t> dims;
      const std::vector<double> v = sim::readEpisodeDataset(path, name, dims);
      std::uint64_t n = 1;
      for (std::uint64_t d : dims) n *= d;
      if (n != v.size()) __builtin_trap();
    });
  }
  return 0;
}
