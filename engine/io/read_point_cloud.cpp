#include <terramap/io/readers.hpp>

#include <terramap/core/text.hpp>

#include "reader_detail.hpp"

namespace terramap::io {

const std::vector<std::string>& supportedCloudExtensions() {
  static const std::vector<std::string> kExtensions = {".pcd", ".ply", ".bin", ".las"};
  return kExtensions;
}

CloudFile readPointCloud(const std::string& path) {
  const std::string ext = detail::lowerExtension(path);
  CloudFile out;
  out.path = path;
  if (ext == ".pcd") {
    out.format = "pcd";
    out.points = readPcd(path);
  } else if (ext == ".ply") {
    out.format = "ply";
    out.points = readPly(path);
  } else if (ext == ".bin") {
    out.format = "kitti_bin";
    out.points = readKittiBin(path);
  } else if (ext == ".las") {
    out.format = "las";
    LasCloud las = readLas(path);
    out.origin = las.origin;
    out.points = std::move(las.points);
  } else {
    throw InputError("point cloud '" + path + "': unknown extension '" + ext + "'" +
                     didYouMean(ext, supportedCloudExtensions()) + "; supported: " +
                     joinStrings(supportedCloudExtensions()));
  }
  return out;
}

}  // namespace terramap::io
