#pragma once
// HDF5 write helpers shared by the episode writer (sim) and the soil dataset (eval). Internal:
// not installed; each library that includes it gets its own (inline, hidden) copy.
#include <terramap/core/error.hpp>

#include <hdf5.h>

#include <algorithm>
#include <cstdint>
#include <string>
#include <vector>

namespace terramap::h5detail {

// Objects are created without HDF5's modification/creation times (on by default), so the same
// content gives the same file, byte for byte: an episode's sha1 is then a reproducibility check.
inline hid_t makeGroup(hid_t parent, const std::string& name, const std::string& path) {
  const hid_t gcpl = H5Pcreate(H5P_GROUP_CREATE);
  H5Pset_obj_track_times(gcpl, 0);
  const hid_t g = H5Gcreate2(parent, name.c_str(), H5P_DEFAULT, gcpl, H5P_DEFAULT);
  H5Pclose(gcpl);
  if (g < 0) throw OutputError(path + ": cannot create group '" + name + "'");
  return g;
}

inline void attrDouble(hid_t obj, const char* name, double v) {
  const hid_t s = H5Screate(H5S_SCALAR);
  const hid_t a = H5Acreate2(obj, name, H5T_NATIVE_DOUBLE, s, H5P_DEFAULT, H5P_DEFAULT);
  H5Awrite(a, H5T_NATIVE_DOUBLE, &v);
  H5Aclose(a);
  H5Sclose(s);
}
inline void attrDoubles(hid_t obj, const char* name, const double* v, std::size_t n) {
  const hsize_t dims[1] = {n};
  const hid_t s = H5Screate_simple(1, dims, nullptr);
  const hid_t a = H5Acreate2(obj, name, H5T_NATIVE_DOUBLE, s, H5P_DEFAULT, H5P_DEFAULT);
  H5Awrite(a, H5T_NATIVE_DOUBLE, v);
  H5Aclose(a);
  H5Sclose(s);
}
inline void attrU64(hid_t obj, const char* name, std::uint64_t v) {
  const hid_t s = H5Screate(H5S_SCALAR);
  const hid_t a = H5Acreate2(obj, name, H5T_NATIVE_UINT64, s, H5P_DEFAULT, H5P_DEFAULT);
  H5Awrite(a, H5T_NATIVE_UINT64, &v);
  H5Aclose(a);
  H5Sclose(s);
}
inline void attrString(hid_t obj, const char* name, const std::string& v) {
  const hid_t t = H5Tcopy(H5T_C_S1);
  H5Tset_size(t, std::max<std::size_t>(1, v.size()));
  H5Tset_strpad(t, H5T_STR_NULLPAD);
  const hid_t s = H5Screate(H5S_SCALAR);
  const hid_t a = H5Acreate2(obj, name, t, s, H5P_DEFAULT, H5P_DEFAULT);
  H5Awrite(a, t, v.empty() ? " " : v.c_str());
  H5Aclose(a);
  H5Sclose(s);
  H5Tclose(t);
}


/// Writes a whole n-dimensional dataset (chunked by up to 4096 leading rows, gzip level `gzip`
/// with shuffle when > 0). `memtype` is the type of `data` (H5T_NATIVE_FLOAT, ...), stored as is.
inline void writeArray(hid_t parent, const std::string& name, hid_t memtype, const void* data,
                       const std::vector<hsize_t>& dims, int gzip, const std::string& path) {
  const hid_t space = H5Screate_simple(static_cast<int>(dims.size()), dims.data(), nullptr);
  const hid_t dcpl = H5Pcreate(H5P_DATASET_CREATE);
  H5Pset_obj_track_times(dcpl, 0);
  bool empty = false;
  for (hsize_t d : dims) empty = empty || d == 0;
  if (!empty && gzip > 0) {
    std::vector<hsize_t> chunk = dims;
    chunk[0] = std::min<hsize_t>(dims[0], 4096);
    H5Pset_chunk(dcpl, static_cast<int>(chunk.size()), chunk.data());
    H5Pset_shuffle(dcpl);
    H5Pset_deflate(dcpl, static_cast<unsigned>(gzip));
  }
  const hid_t ds = H5Dcreate2(parent, name.c_str(), memtype, space, H5P_DEFAULT, dcpl, H5P_DEFAULT);
  H5Pclose(dcpl);
  H5Sclose(space);
  if (ds < 0 || (!empty && H5Dwrite(ds, memtype, H5S_ALL, H5S_ALL, H5P_DEFAULT, data) < 0)) {
    if (ds >= 0) H5Dclose(ds);
    throw OutputError(path + ": cannot write dataset '" + name + "'");
  }
  H5Dclose(ds);
}

}  // namespace terramap::h5detail
