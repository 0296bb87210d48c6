#include <terramap/io/readers.hpp>

#include "reader_detail.hpp"

#include <terramap/core/memory_budget.hpp>

#include <cstring>
#include <type_traits>

namespace terramap::io {

namespace {
constexpr std::uint64_t kKittiRecordBytes = 16;
static_assert(sizeof(PointXYZI) == kKittiRecordBytes && std::is_trivially_copyable_v<PointXYZI>,
              "PointXYZI must be four packed floats: the KITTI reader reads records straight into it");
}  // namespace

std::vector<PointXYZI> readKittiBin(const std::string& path) {
  detail::FileCloser fc{detail::openForRead(path, "KITTI scan")};
  const std::uint64_t size = detail::fileSize(fc.f, path);
  if (size % kKittiRecordBytes != 0) {
    const std::uint64_t partial = size - size % kKittiRecordBytes;
    throw InputError("KITTI scan '" + path + "': size " + std::to_string(size) +
                     " bytes is not a multiple of 16 (float32 x, y, z, reflectance): partial record at byte offset " +
                     std::to_string(partial) + " (" + std::to_string(size - partial) + " bytes)");
  }
  requireInputBudget(size, "KITTI scan '" + path + "'", std::to_string(size / kKittiRecordBytes) + " points x 16 bytes");
  std::vector<PointXYZI> points(size / kKittiRecordBytes);
  if (size != 0 && std::fread(points.data(), 1, size, fc.f) != size) {
    throw InputError("KITTI scan '" + path + "': read error (expected " + std::to_string(size) + " bytes)");
  }
#if defined(__BYTE_ORDER__) && __BYTE_ORDER__ == __ORDER_BIG_ENDIAN__
  // The format is little-endian; swap each float on big-endian hosts.
  for (auto& p : points) {
    for (float* v : {&p.x, &p.y, &p.z, &p.intensity}) {
      unsigned char b[4];
      std::memcpy(b, v, 4);
      *v = detail::loadF32(b);
    }
  }
#endif
  return points;
}

}  // namespace terramap::io
