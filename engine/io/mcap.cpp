// MCAP reading and writing (include/terramap/io/mcap.hpp); record layouts from the public
// specification, https://mcap.dev/spec.
#include <terramap/io/mcap.hpp>

#include <terramap/core/error.hpp>
#include <terramap/core/memory_budget.hpp>
#include <terramap/core/text.hpp>

#include "mcap_bytes.hpp"
#include "reader_detail.hpp"

#include <libdeflate.h>
#include <lz4frame.h>
#include <zstd.h>

#include <algorithm>
#include <cstring>

namespace terramap::io::mcap {

namespace {

constexpr std::uint8_t kMagic[8] = {0x89, 'M', 'C', 'A', 'P', '0', '\r', '\n'};
enum Op : std::uint8_t {
  kHeader = 0x01, kFooter = 0x02, kSchema = 0x03, kChannel = 0x04, kMessage = 0x05, kChunk = 0x06,
  kMessageIndex = 0x07, kChunkIndex = 0x08, kStatistics = 0x0B, kSummaryOffset = 0x0E, kDataEnd = 0x0F,
};
constexpr std::uint64_t kRecordPrefix = 9;  // opcode + u64 length
constexpr std::uint64_t kFooterRecord = kRecordPrefix + 20;

std::uint32_t crc32(const void* p, std::size_t n, std::uint32_t crc = 0) {
  return static_cast<std::uint32_t>(libdeflate_crc32(crc, p, n));
}

std::string hexBytes(const std::uint8_t* p, std::size_t n) {
  static const char* d = "0123456789abcdef";
  std::string s;
  for (std::size_t i = 0; i < n; ++i) {
    if (i) s += ' ';
    s += d[p[i] >> 4];
    s += d[p[i] & 15];
  }
  return s;
}

/// Decompresses a chunk's records into exactly `size` bytes.
std::vector<std::uint8_t> decompress(const std::string& compression, const std::uint8_t* p, std::uint64_t n,
                                     std::uint64_t size, const std::string& where) {
  std::vector<std::uint8_t> out;
  if (compression.empty()) {
    if (n != size)
      throw InputError(where + ": uncompressed chunk holds " + std::to_string(n) + " bytes, its uncompressed_size says " +
                       std::to_string(size));
    out.assign(p, p + n);
    return out;
  }
  out.resize(size);
  if (compression == "zstd") {
    const std::size_t r = ZSTD_decompress(out.data(), out.size(), p, n);
    if (ZSTD_isError(r))
      throw InputError(where + ": zstd chunk does not decompress: " + ZSTD_getErrorName(r));
    if (r != size)
      throw InputError(where + ": zstd chunk decompresses to " + std::to_string(r) + " bytes, its uncompressed_size says " +
                       std::to_string(size));
    return out;
  }
  if (compression == "lz4") {
    LZ4F_dctx* ctx = nullptr;
    if (LZ4F_isError(LZ4F_createDecompressionContext(&ctx, LZ4F_VERSION))) throw InternalError("LZ4F context");
    std::size_t done_out = 0, done_in = 0;
    std::size_t hint = 1;
    while (hint != 0 && done_in < n) {
      std::size_t dst = out.size() - done_out, src = n - done_in;
      hint = LZ4F_decompress(ctx, out.data() + done_out, &dst, p + done_in, &src, nullptr);
      if (LZ4F_isError(hint)) {
        const std::string e = LZ4F_getErrorName(hint);
        LZ4F_freeDecompressionContext(ctx);
        throw InputError(where + ": lz4 chunk does not decompress: " + e);
      }
      done_out += dst;
      done_in += src;
      if (dst == 0 && src == 0) break;  // no progress: the output is full but the frame goes on
    }
    LZ4F_freeDecompressionContext(ctx);
    if (hint != 0 || done_out != size)
      throw InputError(where + ": lz4 chunk decompresses to " + std::string(hint != 0 ? "more or less than " : "") +
                       std::to_string(done_out) + " bytes, its uncompressed_size says " + std::to_string(size));
    return out;
  }
  throw InputError(where + ": chunk compression '" + compression + "' is not supported (zstd, lz4 or none)");
}

}  // namespace

// ---- Reader -----------------------------------------------------------------------------------

Reader::Reader(std::string path) : path_(std::move(path)) {
  file_.reset(detail::openForRead(path_, "MCAP file"));
  std::FILE* f = file_.get();
  size_ = detail::fileSize(f, path_);
  const std::uint64_t least = 8 + kRecordPrefix + 8 + kFooterRecord + 8;
  if (size_ < least)
    throw InputError(path_ + ": " + std::to_string(size_) + " bytes, too short for an MCAP file (at least " +
                     std::to_string(least) + ": magic, header, footer, magic)");
  std::uint8_t head[8 + kRecordPrefix], tail[8];
  const bool ok = std::fread(head, 1, sizeof head, f) == sizeof head &&
                  std::fseek(f, static_cast<long>(size_ - 8), SEEK_SET) == 0 && std::fread(tail, 1, 8, f) == 8;
  if (!ok) throw InputError(path_ + ": cannot read the file's first and last bytes");
  if (std::memcmp(head, kMagic, 8) != 0)
    throw InputError(path_ + ": byte 0: not an MCAP file (magic " + hexBytes(head, 8) + ", expected " + hexBytes(kMagic, 8) + ")");
  if (std::memcmp(tail, kMagic, 8) != 0)
    throw InputError(path_ + ": byte " + std::to_string(size_ - 8) + ": the file does not end with the MCAP magic (found " +
                     hexBytes(tail, 8) + "): cut short, or still being recorded");
  if (head[8] != kHeader)
    throw InputError(path_ + ": byte 8: the first record is opcode 0x" + hexBytes(head + 8, 1) + ", not a Header (0x01)");
  const std::uint64_t len = detail::loadU64(head + 9);
  if (len > size_ - 8 - kRecordPrefix)
    throw InputError(path_ + ": byte 8: the Header record's length " + std::to_string(len) + " runs past the file's end");
  requireInputBudget(len, path_ + ": byte 8: the Header record's length", std::to_string(len) + " bytes");
  std::vector<std::uint8_t> content(len);
  if (std::fseek(f, 8 + kRecordPrefix, SEEK_SET) != 0 || (len && std::fread(content.data(), 1, len, f) != len))
    throw InputError(path_ + ": byte 8: cannot read the Header record");
  ByteReader r(content.data(), content.size(), path_ + ": byte 8: Header record");
  profile_ = r.str("profile");
  data_start_ = pos_ = 8 + kRecordPrefix + len;
}

Reader::~Reader() = default;

const Schema* Reader::schemaOf(const Channel& c) const {
  if (c.schema_id == 0) return nullptr;
  auto it = schemas_.find(c.schema_id);
  return it == schemas_.end() ? nullptr : &it->second;
}

double Reader::progress() const {
  if (done_ || size_ <= data_start_) return 1.0;
  return std::min(1.0, static_cast<double>(pos_ - data_start_) / static_cast<double>(size_ - data_start_));
}

void Reader::rewind() {
  pos_ = data_start_;
  done_ = false;
  chunk_.clear();
  chunk_pos_ = 0;
}

bool Reader::handleRecord(std::uint8_t op, const std::uint8_t* p, std::uint64_t n, const std::string& where, Message& m) {
  ByteReader r(p, n, where);
  if (op == kSchema) {
    Schema s;
    s.id = r.u16("id");
    s.name = r.str("name");
    s.encoding = r.str("encoding");
    const std::uint32_t len = r.u32("data length");
    const std::uint8_t* d = r.bytes(len, "data");
    s.data.assign(d, d + len);
    if (s.id == 0) throw InputError(where + ": Schema record with id 0 (reserved for 'no schema')");
    auto it = schemas_.find(s.id);
    if (it != schemas_.end() && (it->second.name != s.name || it->second.data != s.data))
      throw InputError(where + ": Schema " + std::to_string(s.id) + " defined again differently ('" + it->second.name +
                       "', then '" + s.name + "')");
    schemas_[s.id] = std::move(s);
    return false;
  }
  if (op == kChannel) {
    Channel c;
    c.id = r.u16("id");
    c.schema_id = r.u16("schema_id");
    c.topic = r.str("topic");
    c.message_encoding = r.str("message_encoding");
    const std::uint32_t len = r.u32("metadata length");
    ByteReader md(r.bytes(len, "metadata"), len, where + " metadata");
    while (!md.atEnd()) {
      std::string k = md.str("metadata key");
      c.metadata[k] = md.str("metadata value");
    }
    if (c.schema_id != 0 && !schemas_.count(c.schema_id))
      throw InputError(where + ": Channel " + std::to_string(c.id) + " ('" + c.topic + "') names schema " +
                       std::to_string(c.schema_id) + ", which no Schema record before it defines");
    channels_[c.id] = std::move(c);
    return false;
  }
  if (op == kMessage) {
    m.channel_id = r.u16("channel_id");
    m.sequence = r.u32("sequence");
    m.log_time = r.u64("log_time");
    m.publish_time = r.u64("publish_time");
    if (!channels_.count(m.channel_id))
      throw InputError(where + ": Message on channel " + std::to_string(m.channel_id) +
                       ", which no Channel record before it defines");
    const std::uint64_t len = r.remaining();
    const std::uint8_t* d = r.bytes(len, "data");
    m.data.assign(d, d + len);
    m.where = where;
    return true;
  }
  return false;  // indexes, attachments, metadata: not needed to read the messages
}

void Reader::readChunk(std::uint64_t record_offset, std::vector<std::uint8_t>&& content) {
  const std::string where = path_ + ": Chunk record at byte " + std::to_string(record_offset);
  ByteReader r(content.data(), content.size(), where);
  r.u64("message_start_time");
  r.u64("message_end_time");
  const std::uint64_t usize = r.u64("uncompressed_size");
  const std::uint32_t ucrc = r.u32("uncompressed_crc");
  const std::string compression = r.str("compression");
  const std::uint64_t len = r.u64("records length");
  const std::uint8_t* records = r.bytes(len, "records");
  if (compression.empty() ? usize != len : false)
    throw InputError(where + ": uncompressed chunk holds " + std::to_string(len) + " bytes, its uncompressed_size says " +
                     std::to_string(usize));
  // An lz4/zstd chunk expands at most ~255x; a larger claim is damage, caught before allocating.
  if (!compression.empty() && usize / 255 > len + 64)
    throw InputError(where + ": uncompressed_size " + std::to_string(usize) + " for " + std::to_string(len) +
                     " compressed bytes is more than " + compression + " can expand to");
  requireInputBudget(usize, where + ": uncompressed_size", std::to_string(usize) + " bytes of chunk records");
  chunk_ = decompress(compression, records, len, usize, where);
  if (ucrc != 0) {
    const std::uint32_t c = crc32(chunk_.data(), chunk_.size());
    if (c != ucrc)
      throw InputError(where + ": CRC-32 of the uncompressed records is " + std::to_string(c) + ", the chunk says " +
                       std::to_string(ucrc) + " (damaged file)");
  }
  chunk_offset_ = record_offset;
  chunk_pos_ = 0;
}

bool Reader::nextInChunk(Message& m) {
  while (chunk_pos_ < chunk_.size()) {
    const std::string where = path_ + ": chunk at byte " + std::to_string(chunk_offset_) + ", record at uncompressed byte " +
                              std::to_string(chunk_pos_);
    if (chunk_.size() - chunk_pos_ < kRecordPrefix) throw InputError(where + ": a record prefix cut off by the chunk's end");
    const std::uint8_t op = chunk_[chunk_pos_];
    const std::uint64_t len = detail::loadU64(chunk_.data() + chunk_pos_ + 1);
    if (len > chunk_.size() - chunk_pos_ - kRecordPrefix)
      throw InputError(where + ": record length " + std::to_string(len) + " runs past the chunk's end");
    const std::uint8_t* p = chunk_.data() + chunk_pos_ + kRecordPrefix;
    chunk_pos_ += kRecordPrefix + len;
    if (op != kSchema && op != kChannel && op != kMessage)
      throw InputError(where + ": opcode 0x" + hexBytes(&op, 1) + " inside a chunk (only Schema, Channel and Message may be)");
    if (handleRecord(op, p, len, where, m)) return true;
  }
  chunk_.clear();
  chunk_pos_ = 0;
  return false;
}

bool Reader::next(Message& m) {
  if (nextInChunk(m)) return true;
  while (!done_) {
    const std::string where = path_ + ": byte " + std::to_string(pos_);
    const std::uint64_t end = size_ - 8;  // the trailing magic
    if (end - pos_ < kRecordPrefix) throw InputError(where + ": a record prefix cut off by the trailing magic");
    std::uint8_t prefix[kRecordPrefix];
    if (std::fseek(file_.get(), static_cast<long>(pos_), SEEK_SET) != 0 ||
        std::fread(prefix, 1, kRecordPrefix, file_.get()) != kRecordPrefix)
      throw InputError(where + ": cannot read");
    const std::uint8_t op = prefix[0];
    const std::uint64_t len = detail::loadU64(prefix + 1);
    if (len > end - pos_ - kRecordPrefix)
      throw InputError(where + ": record (opcode 0x" + hexBytes(&op, 1) + ") of length " + std::to_string(len) +
                       " runs past the file's end at byte " + std::to_string(end));
    const std::uint64_t record = pos_;
    pos_ += kRecordPrefix + len;
    if (op == kDataEnd || op == kFooter) {
      done_ = true;
      return false;
    }
    if (op == kHeader) throw InputError(where + ": a second Header record");
    if (op != kSchema && op != kChannel && op != kMessage && op != kChunk) continue;  // skipped unread
    requireInputBudget(len, where + ": record length", std::to_string(len) + " bytes of one record");
    std::vector<std::uint8_t> content(len);
    if (len && std::fread(content.data(), 1, len, file_.get()) != len) throw InputError(where + ": cannot read the record");
    if (op == kChunk) {
      readChunk(record, std::move(content));
      if (nextInChunk(m)) return true;
      continue;
    }
    if (handleRecord(op, content.data(), len, where, m)) return true;
  }
  return false;
}

Compression parseCompression(const std::string& name, const std::string& where) {
  if (name == "zstd") return Compression::Zstd;
  if (name == "lz4") return Compression::Lz4;
  if (name == "none" || name.empty()) return Compression::None;
  const std::vector<std::string> known = {"zstd", "lz4", "none"};
  throw ConfigError(where + ": unknown MCAP chunk compression '" + name + "'" + didYouMean(name, known) + "; known: " +
                    joinStrings(known));
}

// ---- Writer -----------------------------------------------------------------------------------

Writer::Writer(const std::string& target, const std::string& profile, Compression compression, std::uint64_t chunk_bytes)
    : file_(target), compression_(compression), chunk_bytes_(std::max<std::uint64_t>(chunk_bytes, 1024)) {
  std::vector<std::uint8_t> b(kMagic, kMagic + 8);
  ByteWriter h;
  h.str(profile);
  h.str("terramap");
  appendRecord(b, kHeader, h.bytes());
  put(b);
}

Writer::~Writer() = default;  // AtomicFile removes the temporary unless committed

// Everything before the Data End record is the data section its CRC covers (magic and header
// included, as @mcap/core's writer and validator count it).
void Writer::put(const std::vector<std::uint8_t>& bytes) {
  data_crc_ = crc32(bytes.data(), bytes.size(), data_crc_);
  file_.write(bytes.data(), bytes.size());
}

std::uint16_t Writer::addSchema(const std::string& name, const std::string& encoding, const std::string& data) {
  if (schemas_.size() >= 65535) throw OutputError(file_.target().string() + ": more than 65535 schemas");
  flushChunk();
  Schema s;
  s.id = static_cast<std::uint16_t>(schemas_.size() + 1);
  s.name = name;
  s.encoding = encoding;
  s.data.assign(data.begin(), data.end());
  std::vector<std::uint8_t> rec;
  appendRecord(rec, kSchema, encodeSchema(s));
  put(rec);
  schemas_.push_back(std::move(s));
  return schemas_.back().id;
}

std::uint16_t Writer::addChannel(const std::string& topic, std::uint16_t schema_id, const std::string& message_encoding,
                                 const std::map<std::string, std::string>& metadata) {
  if (channels_.size() >= 65535) throw OutputError(file_.target().string() + ": more than 65535 channels");
  if (schema_id > schemas_.size()) throw InternalError("MCAP writer: channel '" + topic + "' names an unknown schema");
  flushChunk();
  Channel c;
  c.id = static_cast<std::uint16_t>(channels_.size() + 1);
  c.schema_id = schema_id;
  c.topic = topic;
  c.message_encoding = message_encoding;
  c.metadata = metadata;
  std::vector<std::uint8_t> rec;
  appendRecord(rec, kChannel, encodeChannel(c));
  put(rec);
  channels_.push_back(std::move(c));
  return channels_.back().id;
}

void Writer::write(std::uint16_t channel_id, std::uint64_t log_time, std::uint64_t publish_time, const std::uint8_t* data,
                   std::size_t n) {
  if (channel_id == 0 || channel_id > channels_.size())
    throw InternalError("MCAP writer: message on unknown channel " + std::to_string(channel_id));
  ByteWriter w;
  w.u16(channel_id);
  w.u32(sequence_[channel_id]++);
  w.u64(log_time);
  w.u64(publish_time);
  w.raw(data, n);
  chunk_index_[channel_id].emplace_back(log_time, chunk_.size());
  appendRecord(chunk_, kMessage, w.bytes());
  chunk_start_ = std::min(chunk_start_, log_time);
  chunk_end_ = std::max(chunk_end_, log_time);
  first_time_ = std::min(first_time_, log_time);
  last_time_ = std::max(last_time_, log_time);
  ++channel_counts_[channel_id];
  ++message_count_;
  if (chunk_.size() >= chunk_bytes_) flushChunk();
}

void Writer::flushChunk() {
  if (chunk_.empty()) return;
  const std::string name = compression_ == Compression::Zstd ? "zstd" : compression_ == Compression::Lz4 ? "lz4" : "";
  std::vector<std::uint8_t> packed;
  if (compression_ == Compression::Zstd) {
    packed.resize(ZSTD_compressBound(chunk_.size()));
    const std::size_t r = ZSTD_compress(packed.data(), packed.size(), chunk_.data(), chunk_.size(), 3);
    if (ZSTD_isError(r)) throw InternalError(std::string("zstd: ") + ZSTD_getErrorName(r));
    packed.resize(r);
  } else if (compression_ == Compression::Lz4) {
    packed.resize(LZ4F_compressFrameBound(chunk_.size(), nullptr));
    const std::size_t r = LZ4F_compressFrame(packed.data(), packed.size(), chunk_.data(), chunk_.size(), nullptr);
    if (LZ4F_isError(r)) throw InternalError(std::string("lz4: ") + LZ4F_getErrorName(r));
    packed.resize(r);
  } else {
    packed = chunk_;
  }
  ByteWriter c;
  c.u64(chunk_start_);
  c.u64(chunk_end_);
  c.u64(chunk_.size());
  c.u32(crc32(chunk_.data(), chunk_.size()));
  c.str(name);
  c.u64(packed.size());
  c.raw(packed.data(), packed.size());
  std::vector<std::uint8_t> rec;
  appendRecord(rec, kChunk, c.bytes());
  const std::uint64_t chunk_offset = file_.size();
  const std::uint64_t chunk_length = rec.size();
  // The message indexes follow the chunk, one per channel in it.
  std::map<std::uint16_t, std::uint64_t> index_offsets;
  std::uint64_t at = chunk_offset + chunk_length;
  for (const auto& [channel, entries] : chunk_index_) {
    ByteWriter mi;
    mi.u16(channel);
    mi.u32(static_cast<std::uint32_t>(entries.size() * 16));
    for (const auto& [t, off] : entries) {
      mi.u64(t);
      mi.u64(off);
    }
    index_offsets[channel] = at;
    const std::size_t before = rec.size();
    appendRecord(rec, kMessageIndex, mi.bytes());
    at += rec.size() - before;
  }
  ByteWriter ci;
  ci.u64(chunk_start_);
  ci.u64(chunk_end_);
  ci.u64(chunk_offset);
  ci.u64(chunk_length);
  ci.u32(static_cast<std::uint32_t>(index_offsets.size() * 10));
  for (const auto& [channel, off] : index_offsets) {
    ci.u16(channel);
    ci.u64(off);
  }
  ci.u64(rec.size() - chunk_length);
  ci.str(name);
  ci.u64(packed.size());
  ci.u64(chunk_.size());
  chunk_indexes_.push_back(ci.bytes());
  put(rec);
  ++chunk_count_;
  chunk_.clear();
  chunk_index_.clear();
  chunk_start_ = UINT64_MAX;
  chunk_end_ = 0;
}

void Writer::close() {
  if (closed_) return;
  flushChunk();
  std::vector<std::uint8_t> tail;
  {
    ByteWriter de;
    de.u32(data_crc_);
    appendRecord(tail, kDataEnd, de.bytes());
  }
  const std::uint64_t summary_start = file_.size() + tail.size();
  // Summary: schemas, channels, statistics, chunk indexes, each group noted for the offsets.
  std::vector<std::uint8_t> summary;
  struct Group {
    std::uint8_t op;
    std::uint64_t start, length;
  };
  std::vector<Group> groups;
  auto group = [&](std::uint8_t op, const std::vector<std::vector<std::uint8_t>>& contents) {
    if (contents.empty()) return;
    const std::uint64_t start = summary_start + summary.size();
    for (const auto& c : contents) appendRecord(summary, op, c);
    groups.push_back({op, start, summary_start + summary.size() - start});
  };
  std::vector<std::vector<std::uint8_t>> s, ch;
  for (const auto& x : schemas_) s.push_back(encodeSchema(x));
  for (const auto& x : channels_) ch.push_back(encodeChannel(x));
  group(kSchema, s);
  group(kChannel, ch);
  ByteWriter st;
  st.u64(message_count_);
  st.u16(static_cast<std::uint16_t>(schemas_.size()));
  st.u32(static_cast<std::uint32_t>(channels_.size()));
  st.u32(0);  // attachments
  st.u32(0);  // metadata
  st.u32(chunk_count_);
  st.u64(message_count_ ? first_time_ : 0);
  st.u64(message_count_ ? last_time_ : 0);
  st.u32(static_cast<std::uint32_t>(channel_counts_.size() * 10));
  for (const auto& [c, k] : channel_counts_) {
    st.u16(c);
    st.u64(k);
  }
  group(kStatistics, {st.bytes()});
  group(kChunkIndex, chunk_indexes_);
  const std::uint64_t offsets_start = summary_start + summary.size();
  for (const auto& g : groups) {
    ByteWriter so;
    so.u8(g.op);
    so.u64(g.start);
    so.u64(g.length);
    appendRecord(summary, kSummaryOffset, so.bytes());
  }
  // The footer's CRC covers the summary sections and the footer up to its own CRC field.
  std::vector<std::uint8_t> footer;
  footer.push_back(kFooter);
  ByteWriter f;
  f.u64(20);
  f.u64(summary_start);
  f.u64(offsets_start);
  footer.insert(footer.end(), f.bytes().begin(), f.bytes().end());
  std::uint32_t crc = crc32(summary.data(), summary.size());
  crc = crc32(footer.data(), footer.size(), crc);
  ByteWriter fc;
  fc.u32(crc);
  footer.insert(footer.end(), fc.bytes().begin(), fc.bytes().end());
  tail.insert(tail.end(), summary.begin(), summary.end());
  tail.insert(tail.end(), footer.begin(), footer.end());
  tail.insert(tail.end(), kMagic, kMagic + 8);
  put(tail);
  file_.commit();
  closed_ = true;
}

}  // namespace terramap::io::mcap
