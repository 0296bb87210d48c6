// The only translation unit of terramap that includes PCL headers (they pull in Boost, VTK
// configuration and take seconds to parse); every public header stays PCL-free.
#include <terramap/io/readers.hpp>

#include "reader_detail.hpp"

#include <terramap/core/memory_budget.hpp>

#include <pcl/PCLPointCloud2.h>
#include <pcl/io/pcd_io.h>
#include <pcl/io/ply_io.h>

#include <algorithm>
#include <cctype>
#include <charconv>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>
#include <map>
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
  // In 64 bits: PCL keeps width, height and row_step in 32 (a PLY's obj_info num_cols / num_rows
  // set them directly), so row_step may have wrapped round below width x point_step.
  const std::uint64_t width = c.width, height = c.height, step = c.point_step, row = c.row_step;
  const std::uint64_t n = saturatingProduct({width, height});
  const std::uint64_t last_row = n > 0 ? saturatingProduct({height - 1, row}) : 0, row_bytes = width * step;
  const std::uint64_t needed = last_row > UINT64_MAX - row_bytes ? UINT64_MAX : last_row + row_bytes;
  if (n > 0 && (row_bytes > row || needed > c.data.size())) {
    throw InputError(std::string(format) + " file '" + path + "': " + std::to_string(n) + " points declared but only " +
                     std::to_string(c.data.size()) + " bytes of point data were read");
  }
  requireInputBudget(saturatingProduct({n, sizeof(PointXYZI)}), std::string(format) + " file '" + path + "'",
                     std::to_string(n) + " points x 16 bytes");
  std::vector<PointXYZI> out(static_cast<std::size_t>(n));
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

/// The whitespace-separated tokens of rest[i, eol) parsed as numbers, as PCL's ASCII readers
/// would (a leading '+' allowed, out-of-range values accepted): how many parse, up to the first
/// that does not (`bad` = its offset in `rest`, npos if none).
struct AsciiLine {
  std::uint64_t values = 0;
  std::size_t bad = std::string::npos, bad_len = 0;
  /// "'<token, at most 32 chars>' is not a number", for the error message.
  std::string badText(const std::vector<char>& rest) const {
    return "'" + std::string(rest.data() + bad, std::min<std::size_t>(bad_len, 32)) + "' is not a number";
  }
};

AsciiLine scanAsciiNumbers(const std::vector<char>& rest, std::size_t i, std::size_t eol) {
  AsciiLine out;
  for (std::size_t j = i; j < eol;) {
    while (j < eol && std::isspace(static_cast<unsigned char>(rest[j]))) ++j;
    if (j >= eol) break;
    std::size_t k = j;
    while (k < eol && !std::isspace(static_cast<unsigned char>(rest[k]))) ++k;
    const char* b = rest.data() + j;
    const char* e = rest.data() + k;
    if (*b == '+') ++b;
    double v;
    const auto [ptr, ec] = std::from_chars(b, e, v);
    if ((ec != std::errc() && ec != std::errc::result_out_of_range) || ptr != e) {
      out.bad = j;
      out.bad_len = k - j;
      return out;
    }
    ++out.values;
    j = k;
  }
  return out;
}

/// The header of a PLY file: its text up to "end_header" and the offset of the body.
/// One header line as PCL's PLY parser sees it, and its first word.
struct PlyLine {
  std::uint64_t at = 0;
  std::string text, keyword;
};

/// The header of a PLY file, split into lines the way PCL 1.13's ply_parser does, so that what
/// terramap checks is what PCL acts on: the magic is the first four bytes whatever the fourth
/// is ("plyX" passes, and the rest of that line is a header line); a '\r' there makes '\r' the
/// line delimiter, with the byte after each one skipped. The header ends at the first line
/// whose first word is end_header, wherever else that text occurs.
struct PlyHeader {
  std::string text;             // the first MiB of the file at most
  std::vector<PlyLine> lines;   // after the magic, up to but excluding end_header
  std::uint64_t body = 0;       // where the body starts
};

PlyHeader readPlyHeader(std::FILE* f, const std::string& path, std::uint64_t size) {
  PlyHeader h;
  h.text.resize(static_cast<std::size_t>(std::min<std::uint64_t>(size, 1u << 20)));
  if (!h.text.empty() && std::fread(&h.text[0], 1, h.text.size(), f) != h.text.size()) {
    throw InputError("PLY file '" + path + "': read error in the header");
  }
  const std::string& t = h.text;
  if (t.compare(0, 3, "ply") != 0 || t.size() < 4) {
    throw InputError("PLY file '" + path + "' at byte offset 0: missing the 'ply' magic line");
  }
  const bool cr = t[3] == '\r';
  const char delim = cr ? '\r' : '\n';
  for (std::size_t at = cr ? 5 : 4; at < t.size();) {
    const std::size_t eol = t.find(delim, at);
    if (eol == std::string::npos) break;
    PlyLine line;
    line.at = at;
    line.text = t.substr(at, eol - at);
    std::istringstream ls(line.text);
    ls >> line.keyword;
    at = eol + 1 + (cr ? 1 : 0);
    if (line.keyword == "end_header") {
      h.body = at;
      return h;
    }
    h.lines.push_back(std::move(line));
  }
  throw InputError("PLY file '" + path + "' at byte offset " + std::to_string(t.size()) +
                   ": no terminated 'end_header' line" + (t.size() < size ? " within the first MiB" : ""));
}

struct PlyElement {
  std::string name;
  std::uint64_t count = 0;
  std::uint64_t stride = 0;
  bool fixed = true;  // no list property: every record has `stride` bytes
  std::string list;   // the first list property's name, if any
  std::uint64_t list_at = 0;  // byte offset of its header line
};

/// The declared elements, in order; `binary` tells whether the body is binary.
std::vector<PlyElement> plyElements(const PlyHeader& h, const std::string& path, bool& binary) {
  binary = false;
  std::vector<PlyElement> elements;
  for (const PlyLine& line : h.lines) {
    const std::uint64_t line_at = line.at;
    std::istringstream ls(line.text);
    std::string key;
    ls >> key;
    // PCL hands the whole line to a callback that asserts it starts with the word itself.
    if (key == "obj_info" && line.text.compare(0, 8, "obj_info") != 0) {
      throw InputError("PLY file '" + path + "' at byte offset " + std::to_string(line_at) +
                       ": 'obj_info' does not start its line (PCL aborts on that)");
    }
    if (key == "format") {
      std::string f;
      ls >> f;
      binary = f.rfind("binary", 0) == 0;
    } else if (key == "element") {
      PlyElement e;
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
        if (type == "list" && elements.back().list.empty()) {
          std::string count_type, item_type, name;
          ls >> count_type >> item_type >> name;
          elements.back().list = name;
          elements.back().list_at = line_at;
        }
      } else {
        elements.back().stride += sz;
      }
    }
  }
  return elements;
}

/// PCL's ASCII PLY parser turns a non-numeric vertex value into NaN without an error; refuse
/// instead (counts per line and per element PCL does check).
void checkPlyAsciiVertices(std::FILE* f, const std::string& path, std::uint64_t size, const PlyHeader& h,
                           const std::vector<PlyElement>& elements) {
  std::uint64_t skip = 0;
  const PlyElement* vertex = nullptr;
  for (const PlyElement& e : elements) {
    if (e.name == "vertex") {
      vertex = &e;
      break;
    }
    skip += e.count;
  }
  const std::uint64_t body = h.body;
  if (!vertex) return;
  if (std::fseek(f, static_cast<long>(body), SEEK_SET) != 0) return;
  std::vector<char> rest(static_cast<std::size_t>(size > body ? size - body : 0));
  if (!rest.empty() && std::fread(rest.data(), 1, rest.size(), f) != rest.size()) {
    throw InputError("PLY file '" + path + "': read error in the ASCII body");
  }
  const std::uint64_t header_lines = static_cast<std::uint64_t>(
      std::count(h.text.begin(), h.text.begin() + static_cast<std::ptrdiff_t>(std::min<std::uint64_t>(body, h.text.size())), '\n'));
  std::uint64_t row = 0;
  std::size_t i = 0;
  for (std::uint64_t line_no = header_lines + 1; i < rest.size() && row < skip + vertex->count; ++line_no) {
    std::size_t eol = i;
    while (eol < rest.size() && rest[eol] != '\n') ++eol;
    if (row >= skip) {
      const AsciiLine line = scanAsciiNumbers(rest, i, eol);
      if (line.bad != std::string::npos) {
        throw InputError("PLY file '" + path + "' at byte offset " + std::to_string(body + line.bad) + ": line " +
                         std::to_string(line_no) + ": " + line.badText(rest));
      }
    }
    ++row;
    i = eol + 1;
  }
  // PCL reports a short ASCII body only on stderr and may still return success.
  if (row < skip + vertex->count) {
    throw InputError("PLY file '" + path + "' at byte offset " + std::to_string(size) + ": the ASCII body ends after " +
                     std::to_string(row > skip ? row - skip : 0) + " vertex lines, the header declares " +
                     std::to_string(vertex->count) + " (checked before PCL)");
  }
}

/// A binary body must hold every declared vertex. Only elements with fixed-size (non-list)
/// properties up to and including "vertex" can be checked; an earlier element with list
/// properties makes the vertex offset data dependent.
void checkPlyBinaryVertices(const std::string& path, std::uint64_t size, std::uint64_t body,
                            const std::vector<PlyElement>& elements) {
  std::uint64_t at = body;
  for (const PlyElement& e : elements) {
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
    at = std::min<std::uint64_t>(size, at + std::min<std::uint64_t>(size, saturatingProduct({e.count, e.stride})));
  }
}

// Checks a binary PLY's declared elements against the file size before PCL reads the body,
// and the numbers of an ASCII PLY's vertex lines.
/// `obj_info num_cols C` / `num_rows R` make PCL size its buffer C x R x the record, not by the
/// vertex count, and write vertex k at k x the record, asserting when that is past the end. The
/// dimensions are followed in header order as PCL does (a vertex element sets cols = its count,
/// rows = 1 unless both were given before it); they must multiply to the vertex count.
void checkPlyOrganisedDims(const PlyHeader& h, const std::string& path) {
  std::uint64_t cols = 0, rows = 0, vertices = 0;
  bool have_vertex = false, have_dims = false;
  std::uint64_t dims_at = 0;
  for (const PlyLine& line : h.lines) {
    std::istringstream ls(line.text);
    std::string key, what, value;
    ls >> key >> what >> value;
    if (key == "element" && what == "vertex") {
      std::uint64_t n = 0;
      std::from_chars(value.data(), value.data() + value.size(), n);
      vertices = n;
      have_vertex = true;
      if (cols == 0 || rows == 0) {
        cols = n;
        rows = 1;
      }
    } else if (key == "obj_info" && (what == "num_cols" || what == "num_rows")) {
      std::uint32_t v = 0;
      const auto [ptr, ec] = std::from_chars(value.data(), value.data() + value.size(), v);
      if (ec != std::errc() || ptr != value.data() + value.size() || v > static_cast<std::uint32_t>(INT32_MAX)) {
        throw InputError("PLY file '" + path + "' at byte offset " + std::to_string(line.at) + ": obj_info " + what +
                         " '" + value.substr(0, 32) + "' is not a whole number of points");
      }
      (what == "num_cols" ? cols : rows) = v;
      have_dims = true;
      dims_at = line.at;
    }
  }
  if (have_vertex && have_dims && saturatingProduct({cols, rows}) != vertices) {
    throw InputError("PLY file '" + path + "' at byte offset " + std::to_string(dims_at) + ": obj_info num_cols x num_rows = " +
                     std::to_string(cols) + " x " + std::to_string(rows) + " differs from the " + std::to_string(vertices) +
                     " vertices of the header");
  }
}

void checkPlyBody(const std::string& path) {
  detail::FileCloser fc{detail::openForRead(path, "PLY file")};
  const std::uint64_t size = detail::fileSize(fc.f, path);
  const PlyHeader h = readPlyHeader(fc.f, path, size);
  bool binary = false;
  const std::vector<PlyElement> elements = plyElements(h, path, binary);
  checkPlyOrganisedDims(h, path);
  for (const PlyElement& e : elements) {
    if (e.name != "vertex") continue;
    // PCL sizes a vertex list field by the first vertex's list and asserts (or, built without
    // assertions, writes past the cloud) on a longer one; terramap reads only scalars anyway.
    if (!e.list.empty()) {
      throw InputError("PLY file '" + path + "' at byte offset " + std::to_string(e.list_at) + ": vertex property '" +
                       e.list + "' is a list; vertex lists are not supported (only scalar x, y, z, intensity are read)");
    }
    // PCL holds the vertex records (>= 4 bytes per property; lists make them longer) and the
    // conversion 16 bytes per point.
    const std::uint64_t record = std::max<std::uint64_t>(e.stride, 4);
    requireInputBudget(saturatingProduct({e.count, record + sizeof(PointXYZI)}),
                       "PLY file '" + path + "': 'element vertex " + std::to_string(e.count) + "'",
                       std::to_string(e.count) + " vertices x (" + std::to_string(record) + " + 16) bytes");
  }
  if (binary) checkPlyBinaryVertices(path, size, h.body, elements);
  else checkPlyAsciiVertices(fc.f, path, size, h, elements);
}

[[noreturn]] void pcdFail(const std::string& path, std::uint64_t offset, const std::string& msg) {
  throw InputError("PCD file '" + path + "' at byte offset " + std::to_string(offset) + ": " + msg);
}

/// A PCD header as declared, with the byte offset of each line an error may point at.
struct PcdHeader {
  std::vector<std::string> fields, sizes, types, counts;
  std::uint64_t width = 0, height = 1, points = 0;
  bool have_width = false, have_points = false;
  std::string data;  // ascii, binary or binary_compressed; empty until the DATA line
  std::uint64_t sizes_at = 0, types_at = 0, counts_at = 0, points_at = 0, data_at = 0, body = 0;
  std::size_t end = 0;  // where reading stopped
};

/// Reads the header lines up to and including DATA, refusing unknown keywords and bad counts.
PcdHeader parsePcdHeader(const std::string& path, const std::string& text) {
  PcdHeader h;
  std::map<std::string, std::size_t> seen;  // keyword -> offset of its line
  std::size_t at = 0;
  while (at < text.size() && h.data.empty()) {
    const std::size_t eol = text.find('\n', at);
    if (eol == std::string::npos) pcdFail(path, at, "header line is not terminated (no DATA line within the first 64 KiB)");
    std::string line = text.substr(at, eol - at);
    const bool empty = line.empty();
    if (!line.empty() && line.back() == '\r') line.pop_back();
    std::istringstream ls(line);
    std::string key;
    ls >> key;
    // PCL skips only truly empty lines; one holding nothing but whitespace (a lone "\r" of a
    // CRLF file too) ends its header, so it reads no fields (PCL 1.13 then dereferences null
    // when it is the first line) or silently drops the rest of the header.
    if (key.empty() && !empty)
      pcdFail(path, at, "header line holds only whitespace (PCL ends the header there); remove it");
    // PCL acts on every occurrence (each POINTS line resizes its buffer), terramap would check
    // only the last: a repeated keyword is refused.
    if (!key.empty() && key[0] != '#') {
      const std::string canonical = key == "COLUMNS" ? "FIELDS" : key;
      const auto [it, first] = seen.emplace(canonical, at);
      if (!first)
        pcdFail(path, at, "header keyword '" + key.substr(0, 32) + "' appears again (first at byte offset " +
                              std::to_string(it->second) + ")");
    }
    std::vector<std::string> vals;
    for (std::string v; ls >> v;) vals.push_back(v);
    auto integer = [&](const std::string& what) {
      std::uint64_t v = 0;
      if (vals.size() != 1) pcdFail(path, at, what + " needs one value");
      const auto [ptr, ec] = std::from_chars(vals[0].data(), vals[0].data() + vals[0].size(), v);
      if (ec != std::errc() || ptr != vals[0].data() + vals[0].size())
        pcdFail(path, at, what + " value '" + vals[0] + "' is not a count");
      return v;
    };
    if (key.empty() || key[0] == '#') {
    } else if (key == "VERSION" || key == "VIEWPOINT") {
    } else if (key == "FIELDS" || key == "COLUMNS") {
      h.fields = vals;
    } else if (key == "SIZE") {
      h.sizes = vals;
      h.sizes_at = at;
    } else if (key == "TYPE") {
      h.types = vals;
      h.types_at = at;
    } else if (key == "COUNT") {
      h.counts = vals;
      h.counts_at = at;
    } else if (key == "WIDTH") {
      h.width = integer("WIDTH");
      h.have_width = true;
    } else if (key == "HEIGHT") {
      h.height = integer("HEIGHT");
    } else if (key == "POINTS") {
      h.points = integer("POINTS");
      h.points_at = at;
      h.have_points = true;
    } else if (key == "DATA") {
      if (vals.size() != 1 || (vals[0] != "ascii" && vals[0] != "binary" && vals[0] != "binary_compressed")) {
        pcdFail(path, at, "DATA must be ascii, binary or binary_compressed");
      }
      h.data = vals[0];
      h.data_at = at;
      h.body = eol + 1;
    } else {
      pcdFail(path, at, "unknown header keyword '" + key.substr(0, 32) + "' (not a PCD file?)");
    }
    at = eol + 1;
  }
  h.end = at;
  return h;
}

/// PCL's header loop does not stop at DATA: it goes on reading lines as long as they are
/// empty, comments or start with a header keyword (prefixes count: "POINTSX" is POINTS to it),
/// so a body whose first line looks like one is read as more header (a later POINTS resizes
/// PCL's buffer to whatever it says, a later DATA moves the body). Refused, at that line.
void checkBodyDoesNotContinueHeader(const std::string& path, const std::string& text, const PcdHeader& h) {
  static const char* const kKeywords[] = {"VERSION", "FIELDS", "COLUMNS", "SIZE",   "TYPE", "COUNT",
                                          "WIDTH",   "HEIGHT", "VIEWPOINT", "POINTS", "DATA"};
  if (h.data.empty()) return;  // no DATA line: refused by checkPcdFields
  for (std::size_t at = h.body; at < text.size();) {
    std::size_t eol = text.find('\n', at);
    if (eol == std::string::npos) eol = text.size();
    std::istringstream ls(text.substr(at, eol - at));
    std::string word;
    ls >> word;
    if (eol == at || (!word.empty() && word[0] == '#')) {  // PCL skips these and reads on
      at = eol + 1;
      continue;
    }
    for (const char* k : kKeywords) {
      if (word.compare(0, std::strlen(k), k) == 0)
        pcdFail(path, at, std::string("the body after DATA starts with '") + k +
                              "...', which PCL reads as another header line");
    }
    return;
  }
}

/// Checks that the header lines agree with each other; returns the point size in bytes and,
/// in `step_values`, the number of values per point.
std::uint64_t checkPcdFields(const std::string& path, PcdHeader& h, std::uint64_t& step_values) {
  const auto& fields = h.fields;
  if (h.data.empty()) pcdFail(path, h.end, "no DATA line in the header");
  if (fields.empty()) pcdFail(path, h.data_at, "no FIELDS line before DATA");
  if (h.sizes.size() != fields.size())
    pcdFail(path, h.sizes_at, std::to_string(h.sizes.size()) + " SIZE values for " + std::to_string(fields.size()) + " FIELDS");
  if (h.types.size() != fields.size())
    pcdFail(path, h.types_at, std::to_string(h.types.size()) + " TYPE values for " + std::to_string(fields.size()) + " FIELDS");
  if (!h.counts.empty() && h.counts.size() != fields.size()) {
    pcdFail(path, h.counts_at, std::to_string(h.counts.size()) + " COUNT values for " + std::to_string(fields.size()) + " FIELDS");
  }
  if (!h.have_width) pcdFail(path, h.data_at, "no WIDTH line before DATA");
  // Saturating: WIDTH x HEIGHT must not wrap round to a small POINTS.
  const std::uint64_t wh = saturatingProduct({h.width, h.height});
  if (!h.have_points) h.points = wh;
  if (h.points != wh) {
    pcdFail(path, h.points_at, "POINTS " + std::to_string(h.points) + " differs from WIDTH x HEIGHT = " +
                                   (wh == UINT64_MAX ? std::string("more than 2^64") : std::to_string(wh)));
  }
  std::uint64_t step = 0;
  step_values = 0;
  for (std::size_t k = 0; k < fields.size(); ++k) {
    const std::string& t = h.types[k];
    const std::string& z = h.sizes[k];
    if ((t != "F" && t != "I" && t != "U") || (z != "1" && z != "2" && z != "4" && z != "8") ||
        (t == "F" && z != "4" && z != "8")) {
      pcdFail(path, h.types_at, "field '" + fields[k] + "' has TYPE " + t + " SIZE " + z +
                                    " (need I/U of 1, 2, 4, 8 bytes or F of 4, 8)");
    }
    std::uint64_t count = 1;
    if (!h.counts.empty()) {
      const std::string& c = h.counts[k];
      const auto [ptr, ec] = std::from_chars(c.data(), c.data() + c.size(), count);
      if (ec != std::errc() || ptr != c.data() + c.size() || count == 0) {
        pcdFail(path, h.counts_at, "COUNT '" + c + "' of field '" + fields[k] + "' is not a positive count");
      }
    }
    step = std::min<std::uint64_t>(UINT64_MAX / 2, step + saturatingProduct({count, static_cast<std::uint64_t>(z[0] - '0')}));
    step_values = std::min<std::uint64_t>(UINT64_MAX / 2, step_values + count);
  }
  return step;
}

/// PCL accepts short lines and non-numbers with a warning and zero-fills; refuse instead.
void checkPcdAsciiBody(std::FILE* f, const std::string& path, std::uint64_t size, const std::string& text,
                       const PcdHeader& h, std::uint64_t step_values) {
  const std::uint64_t body = h.body;
  std::vector<char> rest(static_cast<std::size_t>(size - std::min<std::uint64_t>(size, body)));
  if (!rest.empty() && (std::fseek(f, static_cast<long>(body), SEEK_SET) != 0 ||
                        std::fread(rest.data(), 1, rest.size(), f) != rest.size())) {
    pcdFail(path, body, "read error in the ASCII body");
  }
  std::uint64_t header_lines =
      static_cast<std::uint64_t>(std::count(text.begin(), text.begin() + static_cast<std::ptrdiff_t>(body), '\n'));
  std::uint64_t rows = 0, line_no = header_lines;
  std::size_t i = 0;
  while (i < rest.size()) {
    std::size_t eol = i;
    while (eol < rest.size() && rest[eol] != '\n') ++eol;
    ++line_no;
    const AsciiLine line = scanAsciiNumbers(rest, i, eol);
    if (line.bad != std::string::npos)
      pcdFail(path, body + line.bad, "line " + std::to_string(line_no) + ": " + line.badText(rest));
    const std::uint64_t values = line.values;
    if (values != 0) {
      if (values != step_values) {
        pcdFail(path, body + i, "line " + std::to_string(line_no) + " has " + std::to_string(values) +
                                    " values, expected " + std::to_string(step_values) + " (one per FIELDS x COUNT)");
      }
      ++rows;
    }
    i = eol + 1;
  }
  if (rows != h.points) {
    pcdFail(path, size, "ASCII body has " + std::to_string(rows) + " points, the header declares POINTS " +
                            std::to_string(h.points));
  }
}

void checkPcdBinaryBody(const std::string& path, std::uint64_t size, const PcdHeader& h, std::uint64_t step) {
  const std::uint64_t body = h.body, points = h.points;
  const std::uint64_t avail = size > body ? size - body : 0;
  if (points > avail / step) {
    pcdFail(path, body + (avail / step) * step,
            "POINTS " + std::to_string(points) + " of " + std::to_string(step) + " bytes need the body to end at byte " +
                std::to_string(body + points * step) + " but the file has " + std::to_string(size) + " bytes (point " +
                std::to_string(avail / step) + " is incomplete or missing)");
  }
}

void checkPcdCompressedBody(std::FILE* f, const std::string& path, std::uint64_t size, const PcdHeader& h,
                            std::uint64_t step) {
  const std::uint64_t body = h.body;
  unsigned char sz[8];
  if (size < body + 8 || std::fseek(f, static_cast<long>(body), SEEK_SET) != 0 || std::fread(sz, 1, 8, f) != 8) {
    pcdFail(path, body, "binary_compressed body lacks its 8-byte size prefix");
  }
  const std::uint64_t compressed = detail::loadU32(sz), uncompressed = detail::loadU32(sz + 4);
  if (body + 8 + compressed > size) {
    pcdFail(path, size, "compressed body of " + std::to_string(compressed) + " bytes from offset " +
                            std::to_string(body + 8) + " runs past the end of the file (" + std::to_string(size) +
                            " bytes)");
  }
  if (uncompressed != saturatingProduct({h.points, step})) {
    pcdFail(path, body + 4, "uncompressed size " + std::to_string(uncompressed) +
                                " differs from POINTS x point size = " + std::to_string(h.points * step));
  }
}

// Validates a PCD header (and, for binary data, the body size) before PCL sees the file:
// PCL 1.13 crashes on some headerless files and reads past a short binary body, and its own
// messages carry no byte offsets.
void checkPcdHeader(const std::string& path) {
  detail::FileCloser fc{detail::openForRead(path, "PCD file")};
  const std::uint64_t size = detail::fileSize(fc.f, path);
  std::string text(static_cast<std::size_t>(std::min<std::uint64_t>(size, 1u << 16)), '\0');
  if (!text.empty() && std::fread(&text[0], 1, text.size(), fc.f) != text.size()) {
    throw InputError("PCD file '" + path + "': read error in the header");
  }
  PcdHeader h = parsePcdHeader(path, text);
  checkBodyDoesNotContinueHeader(path, text, h);
  std::uint64_t step_values = 0;
  const std::uint64_t step = checkPcdFields(path, h, step_values);
  // PCL holds POINTS x point size, the conversion 16 bytes per point: refuse before either.
  requireInputBudget(saturatingProduct({h.points, step + sizeof(PointXYZI)}),
                     "PCD file '" + path + "': POINTS " + std::to_string(h.points),
                     std::to_string(h.points) + " points x (" + std::to_string(step) + " + 16) bytes");
  if (h.data == "ascii") checkPcdAsciiBody(fc.f, path, size, text, h, step_values);
  else if (h.data == "binary") checkPcdBinaryBody(path, size, h, step);
  else if (h.data == "binary_compressed") checkPcdCompressedBody(fc.f, path, size, h, step);
}

}  // namespace

namespace {
/// Runs a PCL reader (pcl::PCDReader or pcl::PLYReader, same read() signature) and turns every
/// way it can fail into an InputError naming the file.
template <class Reader>
std::vector<PointXYZI> readWithPcl(const std::string& path, const char* format) {
  pcl::PCLPointCloud2 cloud;
  Reader reader;
  Eigen::Vector4f origin;
  Eigen::Quaternionf orientation;
  int version = 0;
  int rc = -1;
  try {
    rc = reader.read(path, cloud, origin, orientation, version);
  } catch (const std::exception& e) {  // pcl::PCLException, std::bad_alloc from a bogus count
    throw InputError(std::string(format) + " file '" + path + "' could not be parsed by PCL: " + e.what());
  }
  if (rc < 0) {
    throw InputError(std::string(format) + " file '" + path +
                     "' could not be parsed by PCL (see PCL's message on stderr for the cause)");
  }
  return convert(cloud, path, format);
}
}  // namespace

std::vector<PointXYZI> readPcd(const std::string& path) {
  checkPcdHeader(path);
  return readWithPcl<pcl::PCDReader>(path, "PCD");
}

std::vector<PointXYZI> readPly(const std::string& path) {
  checkPlyBody(path);
  return readWithPcl<pcl::PLYReader>(path, "PLY");
}

}  // namespace terramap::io
