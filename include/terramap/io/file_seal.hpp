#pragma once
/// \file
/// The seal of terramap's HDF5 files (simulator episodes, soil-dataset episodes): a 512-byte
/// HDF5 *user block* at the start of the file, which libhdf5 and every HDF5 tool (h5py, h5dump)
/// skip, holding the file's length and the CRC-64/XZ of everything after the block.
///
/// Why: libhdf5 1.10.8 (Debian 12) crashes on some damaged files while it opens them
/// (docs/reliability.md, "Fuzzing"), before terramap can check anything. A reader that verifies
/// the seal first refuses a truncated, extended or damaged file with an input error and never
/// hands it to libhdf5. What it does not stop: a file built on purpose to crash libhdf5 and then
/// sealed; read HDF5 only from places you trust.
///
/// Layout of the block: the ASCII text `terramap-seal 1\nbytes <N>\ncrc64 <16 hex digits>\n`,
/// then zero bytes up to 512. N is the whole file's size in bytes, the CRC covers bytes
/// [512, N). A writer creates the HDF5 file with `H5Pset_userblock(fcpl, kSealBytes)`, closes it
/// and then calls sealFile() on it before renaming it into place.
///
/// Threading: both functions are reentrant (they share no state).
#include <cstdint>
#include <filesystem>

namespace terramap::io {

/// Size of the HDF5 user block the seal occupies (HDF5 wants a power of two ≥ 512).
inline constexpr std::uint64_t kSealBytes = 512;

/// Writes the seal into the first kSealBytes of `path` (which must already be reserved as an
/// HDF5 user block, i.e. zero). Reads the file once. \throws OutputError naming the path when
/// the file cannot be read or written, is shorter than the block, or its block is not empty.
void sealFile(const std::filesystem::path& path);

/// Checks that `path` carries a seal matching its length and contents. Reads the file once,
/// in 1 MiB pieces (no more memory than that). \throws InputError naming the path and what does
/// not match: no seal (not written by terramap, or by one older than the seal), a length that
/// differs (truncated or extended), a checksum that differs (damaged).
void verifySeal(const std::filesystem::path& path);

}  // namespace terramap::io
