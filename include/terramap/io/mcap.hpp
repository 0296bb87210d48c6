#pragma once
/// \file
/// MCAP (https://mcap.dev/spec, major version 0), the container rosbag2 records into by default:
/// a streaming reader of its messages and an atomic, indexed writer. Hand-written (no Debian
/// package reads MCAP from C++); chunk compression through Debian's libzstd ("zstd") and
/// liblz4's frame format ("lz4"), CRC-32 through libdeflate.
///
/// The reader goes through the data section in file order, one record at a time, holding one
/// decompressed chunk: memory is the largest chunk plus the largest message, each checked
/// against the memory budget (memory_budget.hpp) before it is allocated. It needs neither the
/// summary nor the message indexes (a bag cut short by a crash still reads up to where it
/// ends, then says where it ends). Errors throw InputError naming the file and the byte offset
/// of the record (and, inside a chunk, the offset within the chunk's uncompressed records).
///
/// The writer puts messages in chunks of about `chunk_bytes` uncompressed, each followed by
/// its message indexes; then the summary (schemas, channels, statistics, chunk indexes), the
/// summary offsets and the footer, with every CRC filled in, so indexed readers (@mcap/core's
/// McapIndexedReader, Foxglove) seek by time. The file appears under its name only when
/// close() succeeds (AtomicFile).
///
/// Threading: one reader or writer object is used by one thread at a time; separate objects
/// are independent.
#include <terramap/io/atomic_file.hpp>

#include <cstdint>
#include <cstdio>
#include <map>
#include <memory>
#include <string>
#include <vector>

namespace terramap::io::mcap {

struct Schema {
  std::uint16_t id = 0;
  std::string name;      ///< e.g. "sensor_msgs/msg/PointCloud2"
  std::string encoding;  ///< e.g. "ros2msg"
  std::vector<std::uint8_t> data;  ///< the definition text for ros2msg
};

struct Channel {
  std::uint16_t id = 0;
  std::uint16_t schema_id = 0;  ///< 0 = no schema
  std::string topic;
  std::string message_encoding;  ///< "cdr" for rosbag2
  std::map<std::string, std::string> metadata;
};

struct Message {
  std::uint16_t channel_id = 0;
  std::uint32_t sequence = 0;
  std::uint64_t log_time = 0;      ///< nanoseconds
  std::uint64_t publish_time = 0;  ///< nanoseconds
  std::vector<std::uint8_t> data;
  /// Where the message record is, for messages: "file: byte N" or "file: chunk at byte N,
  /// record at uncompressed byte M".
  std::string where;
};

/// Reads the messages of an MCAP file in file order.
class Reader {
 public:
  /// Opens `path` and reads the magic and the header record.
  /// \throws InputError: cannot open, shorter than magic + header + footer + magic, either
  ///   magic wrong (naming what was found), a first record that is not a Header.
  explicit Reader(std::string path);
  ~Reader();
  Reader(const Reader&) = delete;
  Reader& operator=(const Reader&) = delete;

  /// The next message (schemas and channels met on the way are collected), or false at the
  /// Data End record / the footer. \throws InputError for a record running past the end of its
  /// file or chunk, a field running past its record, a message on a channel not defined before
  /// it, a channel naming an undefined schema, an unknown chunk compression, a chunk that does
  /// not decompress to its uncompressed_size or whose CRC-32 differs, sizes beyond the budget.
  bool next(Message& m);
  /// Back to the first record of the data section (channels and schemas are kept).
  void rewind();

  const std::string& path() const { return path_; }
  const std::string& profile() const { return profile_; }  ///< "ros2" for rosbag2
  const std::map<std::uint16_t, Schema>& schemas() const { return schemas_; }
  const std::map<std::uint16_t, Channel>& channels() const { return channels_; }
  /// The channel of a message read by next() (defined: next() refuses the others).
  const Channel& channelOf(const Message& m) const { return channels_.at(m.channel_id); }
  /// The schema of a channel, or nullptr when it has none (schema id 0).
  const Schema* schemaOf(const Channel& c) const;
  /// Fraction of the file's data section read, in [0, 1].
  double progress() const;

 private:
  bool nextInChunk(Message& m);
  void readChunk(std::uint64_t record_offset, std::vector<std::uint8_t>&& content);
  /// Schema/Channel/Message records from the file or a chunk; true when `m` was filled.
  bool handleRecord(std::uint8_t op, const std::uint8_t* p, std::uint64_t n, const std::string& where, Message& m);

  std::string path_;
  /// Owned from the first line of the constructor, so a constructor that throws closes it too.
  std::unique_ptr<std::FILE, int (*)(std::FILE*)> file_{nullptr, &std::fclose};
  std::uint64_t size_ = 0;
  std::uint64_t data_start_ = 0;
  std::uint64_t pos_ = 0;
  bool done_ = false;
  std::string profile_;
  std::map<std::uint16_t, Schema> schemas_;
  std::map<std::uint16_t, Channel> channels_;
  std::vector<std::uint8_t> chunk_;  ///< the current chunk's uncompressed records
  std::uint64_t chunk_offset_ = 0;   ///< file offset of its record
  std::uint64_t chunk_pos_ = 0;      ///< next record within chunk_
};

enum class Compression { None, Zstd, Lz4 };
/// "none"/"" , "zstd", "lz4"; ConfigError otherwise (naming `where`).
Compression parseCompression(const std::string& name, const std::string& where);

/// Writes an MCAP file atomically (see the file comment).
class Writer {
 public:
  /// Creates the temporary file next to `target` and writes the magic and the header.
  /// \throws OutputError.
  Writer(const std::string& target, const std::string& profile, Compression compression = Compression::Zstd,
         std::uint64_t chunk_bytes = 4u << 20);
  /// Abandons the temporary file unless close() succeeded.
  ~Writer();
  Writer(const Writer&) = delete;
  Writer& operator=(const Writer&) = delete;

  /// Ids count from 1. \throws OutputError for more than 65535 schemas or channels.
  std::uint16_t addSchema(const std::string& name, const std::string& encoding, const std::string& data);
  std::uint16_t addChannel(const std::string& topic, std::uint16_t schema_id, const std::string& message_encoding,
                           const std::map<std::string, std::string>& metadata = {});
  /// Appends a message (times in nanoseconds). \throws OutputError (write failure, unknown channel).
  void write(std::uint16_t channel_id, std::uint64_t log_time, std::uint64_t publish_time, const std::uint8_t* data,
             std::size_t n);
  /// Flushes the last chunk, writes the summary and footer and renames the file into place.
  void close();
  std::uint64_t messageCount() const { return message_count_; }

 private:
  void flushChunk();
  void put(const std::vector<std::uint8_t>& bytes);

  AtomicFile file_;
  Compression compression_;
  std::uint64_t chunk_bytes_;
  std::uint32_t data_crc_ = 0;
  std::vector<Schema> schemas_;
  std::vector<Channel> channels_;
  std::vector<std::uint8_t> chunk_;  ///< uncompressed records of the open chunk
  std::uint64_t chunk_start_ = UINT64_MAX, chunk_end_ = 0;
  std::map<std::uint16_t, std::vector<std::pair<std::uint64_t, std::uint64_t>>> chunk_index_;  ///< per channel
  std::vector<std::vector<std::uint8_t>> chunk_indexes_;  ///< encoded Chunk Index records
  std::map<std::uint16_t, std::uint64_t> channel_counts_;
  std::map<std::uint16_t, std::uint32_t> sequence_;
  std::uint64_t message_count_ = 0, first_time_ = UINT64_MAX, last_time_ = 0;
  std::uint32_t chunk_count_ = 0;
  bool closed_ = false;
};

}  // namespace terramap::io::mcap
