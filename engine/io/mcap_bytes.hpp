#pragma once
// Private to engine/io: little-endian field reading with bounds checks (each overrun an
// InputError naming the record and the field) and writing, shared by the MCAP container and
// the ROS 2 CDR messages.
#include <terramap/core/error.hpp>
#include <terramap/io/mcap.hpp>

#include "reader_detail.hpp"

#include <cstdint>
#include <cstring>
#include <string>
#include <vector>

namespace terramap::io::mcap {

/// Reads fields from [p, p + n); `where` prefixes every error.
class ByteReader {
 public:
  ByteReader(const std::uint8_t* p, std::uint64_t n, std::string where) : p_(p), n_(n), where_(std::move(where)) {}
  std::uint64_t remaining() const { return n_ - pos_; }
  std::uint64_t position() const { return pos_; }
  bool atEnd() const { return pos_ == n_; }
  const std::uint8_t* bytes(std::uint64_t len, const char* field) {
    if (len > n_ - pos_)
      throw InputError(where_ + ": field '" + field + "' at byte " + std::to_string(pos_) + " of the record needs " +
                       std::to_string(len) + " bytes, " + std::to_string(n_ - pos_) + " are left");
    const std::uint8_t* q = p_ + pos_;
    pos_ += len;
    return q;
  }
  std::uint8_t u8(const char* f) { return *bytes(1, f); }
  std::uint16_t u16(const char* f) { return detail::loadU16(bytes(2, f)); }
  std::uint32_t u32(const char* f) { return detail::loadU32(bytes(4, f)); }
  std::uint64_t u64(const char* f) { return detail::loadU64(bytes(8, f)); }
  std::string str(const char* f) {
    const std::uint32_t len = u32(f);
    const std::uint8_t* q = bytes(len, f);
    return std::string(reinterpret_cast<const char*>(q), len);
  }

 private:
  const std::uint8_t* p_;
  std::uint64_t n_;
  std::uint64_t pos_ = 0;
  std::string where_;
};

class ByteWriter {
 public:
  void u8(std::uint8_t v) { b_.push_back(v); }
  void u16(std::uint16_t v) { le(v, 2); }
  void u32(std::uint32_t v) { le(v, 4); }
  void u64(std::uint64_t v) { le(v, 8); }
  void str(const std::string& s) {
    u32(static_cast<std::uint32_t>(s.size()));
    b_.insert(b_.end(), s.begin(), s.end());
  }
  void raw(const std::uint8_t* p, std::size_t n) { b_.insert(b_.end(), p, p + n); }
  const std::vector<std::uint8_t>& bytes() const { return b_; }

 private:
  void le(std::uint64_t v, int n) {
    for (int i = 0; i < n; ++i) b_.push_back(static_cast<std::uint8_t>(v >> (8 * i)));
  }
  std::vector<std::uint8_t> b_;
};

inline void appendRecord(std::vector<std::uint8_t>& out, std::uint8_t op, const std::vector<std::uint8_t>& content) {
  out.push_back(op);
  const std::uint64_t n = content.size();
  for (int i = 0; i < 8; ++i) out.push_back(static_cast<std::uint8_t>(n >> (8 * i)));
  out.insert(out.end(), content.begin(), content.end());
}

inline std::vector<std::uint8_t> encodeSchema(const Schema& s) {
  ByteWriter w;
  w.u16(s.id);
  w.str(s.name);
  w.str(s.encoding);
  w.u32(static_cast<std::uint32_t>(s.data.size()));
  w.raw(s.data.data(), s.data.size());
  return w.bytes();
}

inline std::vector<std::uint8_t> encodeChannel(const Channel& c) {
  ByteWriter w;
  w.u16(c.id);
  w.u16(c.schema_id);
  w.str(c.topic);
  w.str(c.message_encoding);
  ByteWriter md;
  for (const auto& [k, v] : c.metadata) {
    md.str(k);
    md.str(v);
  }
  w.u32(static_cast<std::uint32_t>(md.bytes().size()));
  w.raw(md.bytes().data(), md.bytes().size());
  return w.bytes();
}

}  // namespace terramap::io::mcap
