// ROS 2 CDR messages (include/terramap/io/ros2_messages.hpp). Field orders from the messages'
// .msg definitions (common_interfaces, geometry2, grid_map_msgs), which are also the text of
// messageDefinition().
#include <terramap/io/ros2_messages.hpp>

#include <terramap/core/error.hpp>
#include <terramap/core/memory_budget.hpp>

#include "reader_detail.hpp"

#include <array>
#include <cmath>
#include <cstring>
#include <map>

namespace terramap::io::ros2 {

namespace {

/// CDR reading: alignment counts from the byte after the encapsulation header.
class CdrReader {
 public:
  CdrReader(const std::uint8_t* p, std::size_t n, const std::string& where) : p_(p), n_(n), where_(where) {
    if (n < 4) throw InputError(where + ": " + std::to_string(n) + " bytes, too short for a CDR message");
    if (p[0] != 0x00 || (p[1] != 0x01 && p[1] != 0x00))
      throw InputError(where + ": CDR encapsulation " + std::to_string(p[0]) + " " + std::to_string(p[1]) +
                       " is not plain CDR");
    if (p[1] == 0x00)
      throw InputError(where + ": big-endian CDR (encapsulation 00 00) is not supported, only little-endian (00 01)");
    pos_ = 4;
  }
  const std::uint8_t* take(std::size_t size, std::size_t align, const char* field) {
    const std::size_t rel = pos_ - 4;
    const std::size_t pad = align > 1 ? (align - rel % align) % align : 0;
    if (pad > n_ - pos_ || size > n_ - pos_ - pad)
      throw InputError(where_ + ": field '" + field + "' at byte " + std::to_string(pos_ + pad) + " runs past the message's " +
                       std::to_string(n_) + " bytes");
    pos_ += pad;
    const std::uint8_t* q = p_ + pos_;
    pos_ += size;
    return q;
  }
  std::uint8_t u8(const char* f) { return *take(1, 1, f); }
  bool boolean(const char* f) { return u8(f) != 0; }
  std::uint16_t u16(const char* f) { return detail::loadU16(take(2, 2, f)); }
  std::uint32_t u32(const char* f) { return detail::loadU32(take(4, 4, f)); }
  std::int32_t i32(const char* f) { return detail::loadI32(take(4, 4, f)); }
  float f32(const char* f) { return detail::loadF32(take(4, 4, f)); }
  double f64(const char* f) { return detail::loadF64(take(8, 8, f)); }
  std::string str(const char* f) {
    const std::uint32_t len = u32(f);
    if (len == 0) return {};  // some writers send an empty string as length 0
    const std::uint8_t* q = take(len, 1, f);
    if (q[len - 1] != 0) throw InputError(where_ + ": string '" + f + "' does not end with its NUL");
    return std::string(reinterpret_cast<const char*>(q), len - 1);
  }
  /// A sequence's count, checked against the bytes left (each element at least `min_size`).
  std::uint32_t count(const char* f, std::size_t min_size) {
    const std::uint32_t c = u32(f);
    if (min_size && c > (n_ - pos_) / min_size)
      throw InputError(where_ + ": sequence '" + f + "' claims " + std::to_string(c) + " elements, more than the " +
                       std::to_string(n_ - pos_) + " bytes left can hold");
    return c;
  }
  const std::string& where() const { return where_; }

 private:
  const std::uint8_t* p_;
  std::size_t n_;
  std::size_t pos_ = 0;
  const std::string& where_;
};

class CdrWriter {
 public:
  CdrWriter() { b_ = {0x00, 0x01, 0x00, 0x00}; }
  void align(std::size_t a) {
    while ((b_.size() - 4) % a) b_.push_back(0);
  }
  void u8(std::uint8_t v) { b_.push_back(v); }
  void u16(std::uint16_t v) { put(&v, 2); }
  void u32(std::uint32_t v) { put(&v, 4); }
  void i32(std::int32_t v) { put(&v, 4); }
  void f32(float v) { put(&v, 4); }
  void f64(double v) { put(&v, 8); }
  void str(const std::string& s) {
    u32(static_cast<std::uint32_t>(s.size() + 1));
    b_.insert(b_.end(), s.begin(), s.end());
    b_.push_back(0);
  }
  void raw(const void* p, std::size_t n) {
    const auto* q = static_cast<const std::uint8_t*>(p);
    b_.insert(b_.end(), q, q + n);
  }
  std::vector<std::uint8_t> take() { return std::move(b_); }

 private:
  // Little-endian hosts only write their bytes as they are (static_assert below).
  void put(const void* v, std::size_t n) {
    align(n);
    raw(v, n);
  }
  std::vector<std::uint8_t> b_;
};
static_assert(__BYTE_ORDER__ == __ORDER_LITTLE_ENDIAN__, "the CDR writer writes host bytes");

Header readHeader(CdrReader& r) {
  Header h;
  h.stamp.sec = r.i32("header.stamp.sec");
  h.stamp.nanosec = r.u32("header.stamp.nanosec");
  h.frame_id = r.str("header.frame_id");
  return h;
}
void writeHeader(CdrWriter& w, const Header& h) {
  w.i32(h.stamp.sec);
  w.u32(h.stamp.nanosec);
  w.str(h.frame_id);
}
Eigen::Vector3d readVec(CdrReader& r, const char* f) {
  Eigen::Vector3d v;
  v.x() = r.f64(f);
  v.y() = r.f64(f);
  v.z() = r.f64(f);
  return v;
}
Eigen::Quaterniond readQuat(CdrReader& r, const char* f) {
  const double x = r.f64(f), y = r.f64(f), z = r.f64(f), w = r.f64(f);
  return Eigen::Quaterniond(w, x, y, z);
}
void writeVec(CdrWriter& w, const Eigen::Vector3d& v) {
  w.f64(v.x());
  w.f64(v.y());
  w.f64(v.z());
}
void writeQuat(CdrWriter& w, const Eigen::Quaterniond& q) {
  w.f64(q.x());
  w.f64(q.y());
  w.f64(q.z());
  w.f64(q.w());
}

Eigen::Isometry3d isometry(const Eigen::Vector3d& t, const Eigen::Quaterniond& q) {
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.linear() = q.normalized().toRotationMatrix();
  T.translation() = t;
  return T;
}

std::size_t fieldSize(std::uint8_t t) {
  switch (t) {
    case kInt8: case kUint8: return 1;
    case kInt16: case kUint16: return 2;
    case kInt32: case kUint32: case kFloat32: return 4;
    case kFloat64: return 8;
    default: return 0;
  }
}
const char* typeName(std::uint8_t t) {
  static const char* names[] = {"?", "INT8", "UINT8", "INT16", "UINT16", "INT32", "UINT32", "FLOAT32", "FLOAT64"};
  return t <= 8 ? names[t] : "unknown";
}
double loadField(const std::uint8_t* q, std::uint8_t t) {
  switch (t) {
    case kInt8: return static_cast<std::int8_t>(q[0]);
    case kUint8: return q[0];
    case kInt16: return static_cast<std::int16_t>(detail::loadU16(q));
    case kUint16: return detail::loadU16(q);
    case kInt32: return detail::loadI32(q);
    case kUint32: return detail::loadU32(q);
    case kFloat32: return detail::loadF32(q);
    case kFloat64: return detail::loadF64(q);
    default: return std::nan("");
  }
}

}  // namespace

Time Time::fromSeconds(double s) {
  Time t;
  const double whole = std::floor(s);
  long long ns = std::llround((s - whole) * 1e9);
  long long sec = static_cast<long long>(whole);
  if (ns >= 1000000000) {
    ns -= 1000000000;
    ++sec;
  }
  t.sec = static_cast<std::int32_t>(sec);
  t.nanosec = static_cast<std::uint32_t>(ns);
  return t;
}

Eigen::Isometry3d TransformStamped::transform() const { return isometry(translation, rotation); }
Eigen::Isometry3d Odometry::pose() const { return isometry(position, orientation); }

PointCloud2 decodePointCloud2(const std::uint8_t* p, std::size_t n, const std::string& where) {
  CdrReader r(p, n, where);
  PointCloud2 m;
  m.header = readHeader(r);
  m.height = r.u32("height");
  m.width = r.u32("width");
  const std::uint32_t nf = r.count("fields", 13);
  m.fields.resize(nf);
  for (auto& f : m.fields) {
    f.name = r.str("fields.name");
    f.offset = r.u32("fields.offset");
    f.datatype = r.u8("fields.datatype");
    f.count = r.u32("fields.count");
  }
  m.is_bigendian = r.boolean("is_bigendian");
  m.point_step = r.u32("point_step");
  m.row_step = r.u32("row_step");
  const std::uint32_t nd = r.count("data", 1);
  const std::uint8_t* d = r.take(nd, 1, "data");
  m.data.assign(d, d + nd);
  m.is_dense = r.boolean("is_dense");
  return m;
}

std::vector<TransformStamped> decodeTFMessage(const std::uint8_t* p, std::size_t n, const std::string& where) {
  CdrReader r(p, n, where);
  const std::uint32_t c = r.count("transforms", 4 + 4 + 4 + 4 + 56);
  std::vector<TransformStamped> out(c);
  for (auto& t : out) {
    t.header = readHeader(r);
    t.child_frame_id = r.str("transforms.child_frame_id");
    t.translation = readVec(r, "transforms.transform.translation");
    t.rotation = readQuat(r, "transforms.transform.rotation");
  }
  return out;
}

Odometry decodeOdometry(const std::uint8_t* p, std::size_t n, const std::string& where) {
  CdrReader r(p, n, where);
  Odometry o;
  o.header = readHeader(r);
  o.child_frame_id = r.str("child_frame_id");
  o.position = readVec(r, "pose.pose.position");
  o.orientation = readQuat(r, "pose.pose.orientation");
  for (double& v : o.pose_covariance) v = r.f64("pose.covariance");
  o.linear = readVec(r, "twist.twist.linear");
  o.angular = readVec(r, "twist.twist.angular");
  for (double& v : o.twist_covariance) v = r.f64("twist.covariance");
  return o;
}

GridMapMsg decodeGridMap(const std::uint8_t* p, std::size_t n, const std::string& where) {
  CdrReader r(p, n, where);
  GridMapMsg m;
  m.header = readHeader(r);
  m.resolution = r.f64("info.resolution");
  m.length_x = r.f64("info.length_x");
  m.length_y = r.f64("info.length_y");
  m.position = readVec(r, "info.pose.position");
  m.orientation = readQuat(r, "info.pose.orientation");
  for (auto* names : {&m.layers, &m.basic_layers}) {
    names->resize(r.count("layers", 4));
    for (auto& s : *names) s = r.str("layers");
  }
  const std::uint32_t nd = r.count("data", 12);
  m.data.resize(nd);
  for (std::uint32_t k = 0; k < nd; ++k) {
    const std::uint32_t dims = r.count("data.layout.dim", 12);
    std::vector<std::pair<std::string, std::uint32_t>> dim(dims);
    for (auto& [label, size] : dim) {
      label = r.str("data.layout.dim.label");
      size = r.u32("data.layout.dim.size");
      r.u32("data.layout.dim.stride");
    }
    if (r.u32("data.layout.data_offset") != 0) throw InputError(where + ": data[" + std::to_string(k) + "] has a data_offset");
    if (dims != 2 || dim[0].first != "column_index" || dim[1].first != "row_index")
      throw InputError(where + ": data[" + std::to_string(k) + "] is not column-major (dim labels column_index, row_index)");
    m.cols = dim[0].second;
    m.rows = dim[1].second;
    const std::uint32_t values = r.count("data.data", 4);
    const std::uint8_t* q = r.take(static_cast<std::size_t>(values) * 4, 4, "data.data");
    m.data[k].resize(values);
    if (values) std::memcpy(m.data[k].data(), q, static_cast<std::size_t>(values) * 4);
  }
  m.outer_start_index = r.u16("outer_start_index");
  m.inner_start_index = r.u16("inner_start_index");
  return m;
}

std::vector<std::uint8_t> encodePointCloud2(const PointCloud2& m) {
  CdrWriter w;
  writeHeader(w, m.header);
  w.u32(m.height);
  w.u32(m.width);
  w.u32(static_cast<std::uint32_t>(m.fields.size()));
  for (const auto& f : m.fields) {
    w.str(f.name);
    w.u32(f.offset);
    w.u8(f.datatype);
    w.u32(f.count);
  }
  w.u8(m.is_bigendian);
  w.u32(m.point_step);
  w.u32(m.row_step);
  w.u32(static_cast<std::uint32_t>(m.data.size()));
  w.raw(m.data.data(), m.data.size());
  w.u8(m.is_dense);
  return w.take();
}

std::vector<std::uint8_t> encodeTFMessage(const std::vector<TransformStamped>& m) {
  CdrWriter w;
  w.u32(static_cast<std::uint32_t>(m.size()));
  for (const auto& t : m) {
    writeHeader(w, t.header);
    w.str(t.child_frame_id);
    writeVec(w, t.translation);
    writeQuat(w, t.rotation);
  }
  return w.take();
}

std::vector<std::uint8_t> encodeOdometry(const Odometry& o) {
  CdrWriter w;
  writeHeader(w, o.header);
  w.str(o.child_frame_id);
  writeVec(w, o.position);
  writeQuat(w, o.orientation);
  for (double v : o.pose_covariance) w.f64(v);
  writeVec(w, o.linear);
  writeVec(w, o.angular);
  for (double v : o.twist_covariance) w.f64(v);
  return w.take();
}

std::vector<std::uint8_t> encodeGridMap(const GridMapMsg& m) {
  CdrWriter w;
  writeHeader(w, m.header);
  w.f64(m.resolution);
  w.f64(m.length_x);
  w.f64(m.length_y);
  writeVec(w, m.position);
  writeQuat(w, m.orientation);
  for (const auto* names : {&m.layers, &m.basic_layers}) {
    w.u32(static_cast<std::uint32_t>(names->size()));
    for (const auto& s : *names) w.str(s);
  }
  w.u32(static_cast<std::uint32_t>(m.data.size()));
  for (const auto& d : m.data) {
    // grid_map's matrixEigenCopyToMultiArrayMessage for a column-major matrix.
    w.u32(2);
    w.str("column_index");
    w.u32(m.cols);
    w.u32(m.rows * m.cols);
    w.str("row_index");
    w.u32(m.rows);
    w.u32(m.rows);
    w.u32(0);  // data_offset
    w.u32(static_cast<std::uint32_t>(d.size()));
    w.align(4);
    w.raw(d.data(), d.size() * sizeof(float));
  }
  w.u16(m.outer_start_index);
  w.u16(m.inner_start_index);
  return w.take();
}

std::vector<PointXYZI> cloudPoints(const PointCloud2& c, const std::string& where) {
  if (c.is_bigendian) throw InputError(where + ": is_bigendian is true; only little-endian point data is read");
  const PointField* axis[3] = {nullptr, nullptr, nullptr};
  const PointField* intensity = nullptr;
  for (const auto& f : c.fields) {
    for (int k = 0; k < 3; ++k)
      if (f.name == std::string(1, static_cast<char>('x' + k)) && !axis[k]) axis[k] = &f;
    if (!intensity && (f.name == "intensity" || f.name == "reflectance" || f.name == "i")) intensity = &f;
  }
  for (int k = 0; k < 3; ++k) {
    const std::string name(1, static_cast<char>('x' + k));
    if (!axis[k]) throw InputError(where + ": no field '" + name + "' (fields x, y and z are needed)");
    const PointField& f = *axis[k];
    if ((f.datatype != kFloat32 && f.datatype != kFloat64) || f.count != 1)
      throw InputError(where + ": field '" + name + "' is " + std::to_string(f.count) + " x " + typeName(f.datatype) +
                       "; x, y and z must each be one FLOAT32 or FLOAT64");
  }
  if (intensity && (fieldSize(intensity->datatype) == 0 || intensity->count != 1))
    throw InputError(where + ": field '" + intensity->name + "' is " + std::to_string(intensity->count) + " x " +
                     typeName(intensity->datatype) + "; an intensity must be one number");
  for (const PointField* f : {axis[0], axis[1], axis[2], intensity}) {
    if (f && (f->offset > c.point_step || fieldSize(f->datatype) > c.point_step - f->offset))
      throw InputError(where + ": field '" + f->name + "' at offset " + std::to_string(f->offset) + " (" +
                       typeName(f->datatype) + ") does not fit in point_step " + std::to_string(c.point_step));
  }
  const std::uint64_t row_bytes = static_cast<std::uint64_t>(c.width) * c.point_step;
  if (row_bytes > c.row_step)
    throw InputError(where + ": width " + std::to_string(c.width) + " x point_step " + std::to_string(c.point_step) +
                     " is more than row_step " + std::to_string(c.row_step));
  const std::uint64_t need = static_cast<std::uint64_t>(c.row_step) * c.height;
  if (need > c.data.size())
    throw InputError(where + ": data holds " + std::to_string(c.data.size()) + " bytes, row_step " +
                     std::to_string(c.row_step) + " x height " + std::to_string(c.height) + " needs " + std::to_string(need));
  const std::uint64_t points = static_cast<std::uint64_t>(c.width) * c.height;
  requireInputBudget(saturatingProduct({points, sizeof(PointXYZI)}), where + ": the cloud's points",
                     std::to_string(c.width) + " x " + std::to_string(c.height) + " points");
  std::vector<PointXYZI> out;
  out.reserve(static_cast<std::size_t>(c.width) * c.height);
  for (std::uint32_t row = 0; row < c.height; ++row) {
    const std::uint8_t* base = c.data.data() + static_cast<std::size_t>(row) * c.row_step;
    for (std::uint32_t i = 0; i < c.width; ++i) {
      const std::uint8_t* q = base + static_cast<std::size_t>(i) * c.point_step;
      PointXYZI pt;
      float* xyz[3] = {&pt.x, &pt.y, &pt.z};
      for (int k = 0; k < 3; ++k) {
        const PointField& f = *axis[k];
        *xyz[k] = f.datatype == kFloat32 ? detail::loadF32(q + f.offset) : static_cast<float>(detail::loadF64(q + f.offset));
      }
      pt.intensity = intensity ? static_cast<float>(loadField(q + intensity->offset, intensity->datatype))
                               : std::numeric_limits<float>::quiet_NaN();
      out.push_back(pt);
    }
  }
  return out;
}

const std::string& messageDefinition(const std::string& type) {
  static const std::string sep = "\n" + std::string(80, '=') + "\n";
  static const std::map<std::string, std::string> base = {
      {"builtin_interfaces/Time", "int32 sec\nuint32 nanosec\n"},
      {"std_msgs/Header", "builtin_interfaces/Time stamp\nstring frame_id\n"},
      {"sensor_msgs/PointField",
       "uint8 INT8    = 1\nuint8 UINT8   = 2\nuint8 INT16   = 3\nuint8 UINT16  = 4\nuint8 INT32   = 5\n"
       "uint8 UINT32  = 6\nuint8 FLOAT32 = 7\nuint8 FLOAT64 = 8\n\nstring name\nuint32 offset\nuint8  datatype\nuint32 count\n"},
      {"sensor_msgs/PointCloud2",
       "std_msgs/Header header\n\nuint32 height\nuint32 width\n\nPointField[] fields\n\nbool    is_bigendian\n"
       "uint32  point_step\nuint32  row_step\nuint8[] data\n\nbool is_dense\n"},
      {"geometry_msgs/Vector3", "float64 x\nfloat64 y\nfloat64 z\n"},
      {"geometry_msgs/Point", "float64 x\nfloat64 y\nfloat64 z\n"},
      {"geometry_msgs/Quaternion", "float64 x 0\nfloat64 y 0\nfloat64 z 0\nfloat64 w 1\n"},
      {"geometry_msgs/Pose", "Point position\nQuaternion orientation\n"},
      {"geometry_msgs/Transform", "Vector3 translation\nQuaternion rotation\n"},
      {"geometry_msgs/TransformStamped", "std_msgs/Header header\nstring child_frame_id\nTransform transform\n"},
      {"geometry_msgs/Twist", "Vector3  linear\nVector3  angular\n"},
      {"geometry_msgs/PoseWithCovariance", "Pose pose\nfloat64[36] covariance\n"},
      {"geometry_msgs/TwistWithCovariance", "Twist twist\nfloat64[36] covariance\n"},
      {"tf2_msgs/TFMessage", "geometry_msgs/TransformStamped[] transforms\n"},
      {"nav_msgs/Odometry",
       "std_msgs/Header header\nstring child_frame_id\ngeometry_msgs/PoseWithCovariance pose\n"
       "geometry_msgs/TwistWithCovariance twist\n"},
      {"std_msgs/MultiArrayDimension", "string label\nuint32 size\nuint32 stride\n"},
      {"std_msgs/MultiArrayLayout", "MultiArrayDimension[] dim\nuint32 data_offset\n"},
      {"std_msgs/Float32MultiArray", "MultiArrayLayout layout\nfloat32[] data\n"},
      {"grid_map_msgs/GridMapInfo",
       "float64 resolution\nfloat64 length_x\nfloat64 length_y\ngeometry_msgs/Pose pose\n"},
      {"grid_map_msgs/GridMap",
       "std_msgs/Header header\nGridMapInfo info\nstring[] layers\nstring[] basic_layers\n"
       "std_msgs/Float32MultiArray[] data\nuint16 outer_start_index\nuint16 inner_start_index\n"},
  };
  // Each message with the types it uses, depth first, each once (rosbag2's order).
  static const std::map<std::string, std::vector<std::string>> uses = {
      {"sensor_msgs/PointCloud2", {"std_msgs/Header", "builtin_interfaces/Time", "sensor_msgs/PointField"}},
      {"tf2_msgs/TFMessage",
       {"geometry_msgs/TransformStamped", "std_msgs/Header", "builtin_interfaces/Time", "geometry_msgs/Transform",
        "geometry_msgs/Vector3", "geometry_msgs/Quaternion"}},
      {"nav_msgs/Odometry",
       {"std_msgs/Header", "builtin_interfaces/Time", "geometry_msgs/PoseWithCovariance", "geometry_msgs/Pose",
        "geometry_msgs/Point", "geometry_msgs/Quaternion", "geometry_msgs/TwistWithCovariance", "geometry_msgs/Twist",
        "geometry_msgs/Vector3"}},
      {"grid_map_msgs/GridMap",
       {"std_msgs/Header", "builtin_interfaces/Time", "grid_map_msgs/GridMapInfo", "geometry_msgs/Pose",
        "geometry_msgs/Point", "geometry_msgs/Quaternion", "std_msgs/Float32MultiArray", "std_msgs/MultiArrayLayout",
        "std_msgs/MultiArrayDimension"}},
  };
  static const std::map<std::string, std::string> full = [] {
    std::map<std::string, std::string> f;
    for (const auto& [name, deps] : uses) {
      std::string text = base.at(name);
      for (const auto& d : deps) text += sep + "MSG: " + d + "\n" + base.at(d);
      const std::size_t slash = name.find('/');
      f[name.substr(0, slash) + "/msg" + name.substr(slash)] = text;
    }
    return f;
  }();
  auto it = full.find(type);
  if (it == full.end()) throw InternalError("no ros2msg definition for '" + type + "'");
  return it->second;
}

}  // namespace terramap::io::ros2
