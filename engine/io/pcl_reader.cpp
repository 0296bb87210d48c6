// The only translation unit of terramap that includes PCL headers (they pull in Boost, VTK
// configuration and take seconds to parse); every public header stays PCL-free.
#include <terramap/io/readers.hpp>

#include "reader_detail.hpp"

#include <pcl/PCLPointCloud2.h>
#include <pcl/io/pcd_io.h>
#include <pcl/io/ply_io.h>

#include <cmath>
#include <limits>
#include <sstream>

namespace terramap::io {

namespace {

const char* const kIntensityNames[] = {"intensity", "scalar_intensity", "reflectance", "remission"};

const pcl::PCLPointField* findField(const pcl::PCLPointCloud2& c, const std::string& name) {
  for (const auto& f : c.fields) {
    if (f.name == name) return &f;
  }
  return nullptr;
}

std::size_t typeSize(std::uint8_t datatype) {
  switch (datatype) {
    case pcl::PCLPointField::INT8:
    case pcl::PCLPointField::UINT8:
      return 1;
    case pcl::PCLPointField::INT16:
    case pcl::PCLPointField::UINT16:
      return 2;
    case pcl::PCLPointField::INT32:
    case pcl::PCLPointField::UINT32:
    case pcl::PCLPointField::FLOAT32:
      return 4;
    case pcl::PCLPointField::FLOAT64:
      return 8;
    default:
      return 0;
  }
}

// Reads one scalar of any PCL datatype as float. PCL stores data in host byte order.
float loadAsFloat(const std::uint8_t* p, std::uint8_t datatype) {
  auto get = [p](auto v) {
    std::memcpy(&v, p, sizeof v);
    return static_cast<float>(v);
  };
  switch (datatype) {
    case pcl::PCLPointField::INT8: return get(std::int8_t{});
    case pcl::PCLPointField::UINT8: return get(std::uint8_t{});
    case pcl::PCLPointField::INT16: return get(std::int16_t{});
    case pcl::PCLPointField::UINT16: return get(std::uint16_t{});
    case pcl::PCLPointField::INT32: return get(std::int32_t{});
    case pcl::PCLPointField::UINT32: return get(std::uint32_t{});
    case pcl::PCLPointField::FLOAT32: return get(float{});
    case pcl::PCLPointField::FLOAT64: return get(double{});
    default: return std::numeric_limits<float>::quiet_NaN();
  }
}

std::vector<PointXYZI> convert(const pcl::PCLPointCloud2& c, const std::string& path, const char* format) {
  const pcl::PCLPointField* fx = findField(c, "x");
  const pcl::PCLPointField* fy = findField(c, "y");
  const pcl::PCLPointField* fz = findField(c, "z");
  std::string names;
  for (const auto& f : c.fields) names += (names.empty() ? "" : ", ") + f.name;
  if (!fx || !fy || !fz) {
    throw InputError(std::string(format) + " file '" + path + "' has no x, y and z fields (fields: " +
                     (names.empty() ? "none" : names) + ")");
  }
  const pcl::PCLPointField* fi = nullptr;
  for (const char* n : kIntensityNames) {
    if ((fi = findField(c, n))) break;
  }
  for (const pcl::PCLPointField* f : {fx, fy, fz, fi}) {
    if (!f) continue;
    const std::size_t sz = typeSize(f->datatype);
    if (sz == 0 || f->offset + sz > c.point_step) {
      throw InputError(std::string(format) + " file '" + path + "': field '" + f->name + "' has datatype " +
                       std::to_string(f->datatype) + " at offset " + std::to_string(f->offset) +
                       " which does not fit the " + std::to_string(c.point_step) + "-byte point");
    }
  }
  const std::size_t n = static_cast<std::size_t>(c.width) * c.height;
  if (c.height > 0 && static_cast<std::size_t>(c.row_step) * c.height > c.data.size()) {
    throw InputError(std::string(format) + " file '" + path + "': " + std::to_string(n) + " points declared but only " +
                     std::to_string(c.data.size()) + " bytes of point data were read");
  }
  std::vector<PointXYZI> out(n);
  const float nan = std::numeric_limits<float>::quiet_NaN();
  for (std::size_t r = 0; r < c.height; ++r) {
    for (std::size_t col = 0; col < c.width; ++col) {
      const std::uint8_t* p = c.data.data() + r * c.row_step + col * c.point_step;
      PointXYZI& q = out[r * c.width + col];
      q.x = loadAsFloat(p + fx->offset, fx->datatype);
      q.y = loadAsFloat(p + fy->offset, fy->datatype);
      q.z = loadAsFloat(p + fz->offset, fz->datatype);
      q.intensity = fi ? loadAsFloat(p + fi->offset, fi->datatype) : nan;
    }
  }
  return out;
}

// Checks a binary PLY's declared elements against the file size before PCL reads the body.
// Only elements with fixed-size (non-list) properties up to and including "vertex" can be
// checked; an earlier element with list properties makes the vertex offset data dependent.
void checkPlyBinarySize(const std::string& path) {
  detail::FileCloser fc{detail::openForRead(path, "PLY file")};
  const std::uint64_t size = detail::fileSize(fc.f, path);
  std::string header;
  std::vector<char> chunk(4096);
  std::size_t end = std::string::npos;
  while (end == std::string::npos && header.size() < (1u << 20)) {
    const std::size_t got = std::fread(chunk.data(), 1, chunk.size(), fc.f);
    if (got == 0) break;
    header.append(chunk.data(), got);
    end = header.find("end_header");
  }
  if (header.compare(0, 3, "ply") != 0) {
    throw InputError("PLY file '" + path + "' at byte offset 0: missing the 'ply' magic line");
  }
  if (end == std::string::npos) {
    throw InputError("PLY file '" + path + "' at byte offset " + std::to_string(header.size()) +
                     ": no 'end_header' line");
  }
  const std::size_t eol = header.find('\n', end);
  if (eol == std::string::npos) {
    throw InputError("PLY file '" + path + "' at byte offset " + std::to_string(header.size()) +
                     ": 'end_header' line is not terminated");
  }
  const std::uint64_t body = eol + 1;
  std::istringstream is(header.substr(0, end));
  std::string line;
  bool binary = false;
  struct Element {
    std::string name;
    std::uint64_t count = 0;
    std::uint64_t stride = 0;
    bool fixed = true;
  };
  std::vector<Element> elements;
  while (std::getline(is, line)) {
    std::istringstream ls(line);
    std::string key;
    ls >> key;
    if (key == "format") {
      std::string f;
      ls >> f;
      binary = f.rfind("binary", 0) == 0;
    } else if (key == "element") {
      Element e;
      ls >> e.name >> e.count;
      elements.push_back(e);
    } else if (key == "property" && !elements.empty()) {
      std::string type;
      ls >> type;
      static const std::pair<const char*, int> kSizes[] = {
          {"char", 1},  {"uchar", 1},  {"int8", 1},   {"uint8", 1},  {"short", 2},   {"ushort", 2},
          {"int16", 2}, {"uint16", 2}, {"int", 4},    {"uint", 4},   {"int32", 4},   {"uint32", 4},
          {"float", 4}, {"float32", 4}, {"double", 8}, {"float64", 8}};
      int sz = 0;
      for (const auto& [name, s] : kSizes) {
        if (type == name) sz = s;
      }
      if (type == "list" || sz == 0) {
        elements.back().fixed = false;
      } else {
        elements.back().stride += sz;
      }
    }
  }
  if (!binary) return;
  std::uint64_t at = body;
  for (const Element& e : elements) {
    if (!e.fixed) return;
    if (e.name == "vertex") {
      const std::uint64_t avail = size > at ? size - at : 0;
      if (e.stride > 0 && e.count > avail / e.stride) {
        const std::uint64_t first_incomplete = at + (avail / e.stride) * e.stride;
        throw InputError("PLY file '" + path + "' at byte offset " + std::to_string(first_incomplete) + ": header declares " +
                         std::to_string(e.count) + " vertices of " + std::to_string(e.stride) + " bytes from offset " +
                         std::to_string(at) + " but the file ends at byte " + std::to_string(size) + " (vertex " +
                         std::to_string(avail / e.stride) + " is incomplete or missing)");
      }
      return;
    }
    at += e.count * e.stride;
  }
}

}  // namespace

std::vector<PointXYZI> readPcd(const std::string& path) {
  { detail::FileCloser probe{detail::openForRead(path, "PCD file")}; }
  pcl::PCLPointCloud2 cloud;
  pcl::PCDReader reader;
  Eigen::Vector4f origin;
  Eigen::Quaternionf orientation;
  int version = 0;
  if (reader.read(path, cloud, origin, orientation, version) < 0) {
    throw InputError("PCD file '" + path + "' could not be parsed by PCL (see PCL's message on stderr for the cause)");
  }
  return convert(cloud, path, "PCD");
}

std::vector<PointXYZI> readPly(const std::string& path) {
  checkPlyBinarySize(path);
  pcl::PCLPointCloud2 cloud;
  pcl::PLYReader reader;
  Eigen::Vector4f origin;
  Eigen::Quaternionf orientation;
  int version = 0;
  if (reader.read(path, cloud, origin, orientation, version) < 0) {
    throw InputError("PLY file '" + path + "' could not be parsed by PCL (see PCL's message on stderr for the cause)");
  }
  return convert(cloud, path, "PLY");
}

}  // namespace terramap::io
