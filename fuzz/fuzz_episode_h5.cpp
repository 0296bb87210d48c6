// libFuzzer target: HDF5 episodes through terramap::sim::readEpisodeDataset (the seal of
// io/file_seal.hpp, the budget check on a dataset's declared size, then HDF5's read and
// conversion to double). The seeds are sealed, so the unchanged seeds reach libhdf5 and nearly
// every mutation is refused by the seal (its length, checksum or text), which is the point.
#include "fuzz_support.hpp"

#include <terramap/sim/episode.hpp>

#include <hdf5.h>

extern "C" int LLVMFuzzerInitialize(int*, char***) {
  terramap::fuzz::setUp();
  // HDF5 prints an error stack for every failed call; readEpisodeDataset turns them off too,
  // but only once it is first called.
  H5Eset_auto2(H5E_DEFAULT, nullptr, nullptr);
  // HDF5 keeps freed blocks on free lists for reuse. libFuzzer takes more mallocs than frees
  // in a run for a possible leak and runs LeakSanitizer over the whole heap after it, which
  // made every input ~20x slower; with no free lists, blocks go back to malloc at once.
  H5set_free_list_limits(0, 0, 0, 0, 0, 0);
  return 0;
}

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  static terramap::fuzz::ScratchFile file("episode", ".h5");
  const std::string& path = file.write(data, size);
  using namespace terramap;
  // Two datasets the evaluation tools read (docs/sim.md): float32 3-D written whole, and float64
  // rows appended over time (unlimited first dimension); the seeds carry them, chunked and
  // gzipped in one (fuzz/seeds/make_seeds.cpp). Two, not more: each is a separate H5Fopen, and
  // HDF5 1.10.8 allocates and clears up to 256 MiB while opening a damaged file, ~1 s each
  // under ASan (docs/reliability.md, "Fuzzing").
  static const char* const kDatasets[] = {"/terrain/height", "/machines/ctl1/T_map_base"};
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
