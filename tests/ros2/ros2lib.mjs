// Shared by the ROS 2 interoperability tests: rosbag2 MCAP files written with @mcap/core and
// @foxglove/rosmsg2-serialization (implementations that are not terramap's), zstd chunks by
// @foxglove/wasm-zstd and lz4 chunks by Debian's lz4 tool (the reference LZ4 frame encoder;
// @foxglove/wasm-lz4 only decompresses), message definitions written here from the ROS 2 .msg
// files; a reader of terramap's .tmap snapshots (the byte layout documented in
// include/terramap/io/snapshot.hpp) and small matrix helpers for the poses.
import { execFileSync, spawnSync } from "node:child_process";
import fs from "node:fs";
import { createRequire } from "node:module";
import path from "node:path";

// ES modules ignore NODE_PATH: the packages are required from the folder `npm ci` installed them
// in (TERRAMAP_ROS2_NPM_DIR, set by CTest; tests/ros2/CMakeLists.txt).
const npmDir = process.env.TERRAMAP_ROS2_NPM_DIR;
if (!npmDir) {
  console.log("FAIL: TERRAMAP_ROS2_NPM_DIR is not set (run through CTest, or point it at <build>/ros2_npm)");
  process.exit(1);
}
const require = createRequire(path.join(npmDir, "package.json"));
const { McapWriter, McapIndexedReader, McapStreamReader } = require("@mcap/core");
const { MessageWriter, MessageReader } = require("@foxglove/rosmsg2-serialization");
const { parse } = require("@foxglove/rosmsg");
const zstd = require("@foxglove/wasm-zstd");
const lz4decompress = require("@foxglove/wasm-lz4");

export function fail(msg) {
  console.log(`FAIL: ${msg}`);
  process.exit(1);
}

// ---- message definitions (ros2msg, as rosbag2 stores them) ------------------------------------
const SEP = "\n" + "=".repeat(80) + "\n";
const DEFS = {
  "builtin_interfaces/Time": "int32 sec\nuint32 nanosec\n",
  "std_msgs/Header": "builtin_interfaces/Time stamp\nstring frame_id\n",
  "sensor_msgs/PointField":
    "uint8 INT8=1\nuint8 UINT8=2\nuint8 INT16=3\nuint8 UINT16=4\nuint8 INT32=5\nuint8 UINT32=6\nuint8 FLOAT32=7\nuint8 FLOAT64=8\n" +
    "string name\nuint32 offset\nuint8 datatype\nuint32 count\n",
  "sensor_msgs/PointCloud2":
    "std_msgs/Header header\nuint32 height\nuint32 width\nsensor_msgs/PointField[] fields\nbool is_bigendian\n" +
    "uint32 point_step\nuint32 row_step\nuint8[] data\nbool is_dense\n",
  "geometry_msgs/Vector3": "float64 x\nfloat64 y\nfloat64 z\n",
  "geometry_msgs/Point": "float64 x\nfloat64 y\nfloat64 z\n",
  "geometry_msgs/Quaternion": "float64 x\nfloat64 y\nfloat64 z\nfloat64 w\n",
  "geometry_msgs/Pose": "geometry_msgs/Point position\ngeometry_msgs/Quaternion orientation\n",
  "geometry_msgs/Transform": "geometry_msgs/Vector3 translation\ngeometry_msgs/Quaternion rotation\n",
  "geometry_msgs/TransformStamped": "std_msgs/Header header\nstring child_frame_id\ngeometry_msgs/Transform transform\n",
  "geometry_msgs/Twist": "geometry_msgs/Vector3 linear\ngeometry_msgs/Vector3 angular\n",
  "geometry_msgs/PoseWithCovariance": "geometry_msgs/Pose pose\nfloat64[36] covariance\n",
  "geometry_msgs/TwistWithCovariance": "geometry_msgs/Twist twist\nfloat64[36] covariance\n",
  "tf2_msgs/TFMessage": "geometry_msgs/TransformStamped[] transforms\n",
  "nav_msgs/Odometry":
    "std_msgs/Header header\nstring child_frame_id\ngeometry_msgs/PoseWithCovariance pose\ngeometry_msgs/TwistWithCovariance twist\n",
};
const USES = {
  "sensor_msgs/PointCloud2": ["std_msgs/Header", "builtin_interfaces/Time", "sensor_msgs/PointField"],
  "tf2_msgs/TFMessage": ["geometry_msgs/TransformStamped", "std_msgs/Header", "builtin_interfaces/Time",
    "geometry_msgs/Transform", "geometry_msgs/Vector3", "geometry_msgs/Quaternion"],
  "nav_msgs/Odometry": ["std_msgs/Header", "builtin_interfaces/Time", "geometry_msgs/PoseWithCovariance",
    "geometry_msgs/Pose", "geometry_msgs/Point", "geometry_msgs/Quaternion", "geometry_msgs/TwistWithCovariance",
    "geometry_msgs/Twist", "geometry_msgs/Vector3"],
};
function definition(type) {
  return DEFS[type] + USES[type].map((d) => `${SEP}MSG: ${d}\n${DEFS[d]}`).join("");
}

// ---- writing a rosbag2 MCAP -------------------------------------------------------------------
/** compression: "zstd" or "lz4"; returns {add(topic, type, stampNs, message), end()}. */
export async function openBag(path, compression, chunkSize = 1 << 20) {
  await zstd.isLoaded;
  const fd = fs.openSync(path, "w");
  let pos = 0n;
  const writable = {
    position: () => pos,
    write: async (buf) => {
      fs.writeSync(fd, buf);
      pos += BigInt(buf.byteLength);
    },
  };
  const compressChunk = (data) => {
    if (compression === "zstd") return { compression: "zstd", compressedData: zstd.compress(data, 3) };
    const packed = execFileSync("lz4", ["-q", "-c", "-"], { input: data, maxBuffer: 1 << 30 });
    // The frame must be one an independent decoder reads back to the same bytes.
    const back = lz4decompress(packed, data.byteLength);
    if (Buffer.compare(Buffer.from(back), Buffer.from(data)) !== 0) fail("lz4 tool's frame does not round-trip");
    return { compression: "lz4", compressedData: new Uint8Array(packed) };
  };
  await lz4decompress.isLoaded;
  const writer = new McapWriter({ writable, useChunks: true, chunkSize, compressChunk });
  await writer.start({ profile: "ros2", library: "terramap tests/ros2 (@mcap/core)" });
  const channels = new Map();
  const sequence = new Map();
  return {
    async add(topic, type, stampNs, message) {
      let ch = channels.get(topic);
      if (!ch) {
        const full = type.replace("/", "/msg/");
        const schemaId = await writer.registerSchema({ name: full, encoding: "ros2msg",
          data: new TextEncoder().encode(definition(type)) });
        const id = await writer.registerChannel({ topic, schemaId, messageEncoding: "cdr",
          metadata: new Map([["offered_qos_profiles", ""]]) });
        ch = { id, msg: new MessageWriter(parse(definition(type), { ros2: true })) };
        channels.set(topic, ch);
      }
      const seq = sequence.get(topic) ?? 0;
      sequence.set(topic, seq + 1);
      await writer.addMessage({ channelId: ch.id, sequence: seq, logTime: stampNs, publishTime: stampNs,
        data: ch.msg.writeMessage(message) });
    },
    async end() {
      await writer.end();
      fs.closeSync(fd);
    },
  };
}

/** {sec, nanosec} of k-th frame at `period_ns`; and the same as BigInt nanoseconds. */
export function stampOf(ns) {
  return { sec: Number(ns / 1000000000n), nanosec: Number(ns % 1000000000n) };
}

// ---- rigid transforms as 4x4 row-major arrays -------------------------------------------------
export function matmul(a, b) {
  const c = new Array(16).fill(0);
  for (let i = 0; i < 4; ++i) for (let j = 0; j < 4; ++j) for (let k = 0; k < 4; ++k) c[4 * i + j] += a[4 * i + k] * b[4 * k + j];
  return c;
}
export function rigidInverse(T) {
  const R = [T[0], T[1], T[2], T[4], T[5], T[6], T[8], T[9], T[10]];
  const t = [T[3], T[7], T[11]];
  const out = new Array(16).fill(0);
  for (let i = 0; i < 3; ++i) {
    for (let j = 0; j < 3; ++j) out[4 * i + j] = R[3 * j + i];
    out[4 * i + 3] = -(R[i] * t[0] + R[3 + i] * t[1] + R[6 + i] * t[2]);
  }
  out[15] = 1;
  return out;
}
/** The nearest rotation to the 3x3 block (polar factor by Newton's iteration R <- (R + R^-T) / 2). */
export function orthonormalize(T) {
  let R = [T[0], T[1], T[2], T[4], T[5], T[6], T[8], T[9], T[10]];
  for (let it = 0; it < 20; ++it) {
    const [a, b, c, d, e, f, g, h, i] = R;
    const det = a * (e * i - f * h) - b * (d * i - f * g) + c * (d * h - e * g);
    // inverse transpose = cofactor matrix / det
    const cof = [e * i - f * h, -(d * i - f * g), d * h - e * g, -(b * i - c * h), a * i - c * g, -(a * h - b * g),
      b * f - c * e, -(a * f - c * d), a * e - b * d];
    R = R.map((v, k) => 0.5 * (v + cof[k] / det));
  }
  const out = T.slice();
  for (let i = 0; i < 3; ++i) for (let j = 0; j < 3; ++j) out[4 * i + j] = R[3 * i + j];
  return out;
}
export function quaternionOf(T) {
  const [m00, m01, m02, , m10, m11, m12, , m20, m21, m22] = T;
  const tr = m00 + m11 + m22;
  let x, y, z, w;
  if (tr > 0) {
    const s = Math.sqrt(tr + 1) * 2;
    w = 0.25 * s; x = (m21 - m12) / s; y = (m02 - m20) / s; z = (m10 - m01) / s;
  } else if (m00 > m11 && m00 > m22) {
    const s = Math.sqrt(1 + m00 - m11 - m22) * 2;
    w = (m21 - m12) / s; x = 0.25 * s; y = (m01 + m10) / s; z = (m02 + m20) / s;
  } else if (m11 > m22) {
    const s = Math.sqrt(1 + m11 - m00 - m22) * 2;
    w = (m02 - m20) / s; x = (m01 + m10) / s; y = 0.25 * s; z = (m12 + m21) / s;
  } else {
    const s = Math.sqrt(1 + m22 - m00 - m11) * 2;
    w = (m10 - m01) / s; x = (m02 + m20) / s; y = (m12 + m21) / s; z = 0.25 * s;
  }
  return { x, y, z, w };
}
export function transformMsg(T) {
  return { translation: { x: T[3], y: T[7], z: T[11] }, rotation: quaternionOf(T) };
}
export function poseMsg(T) {
  return { position: { x: T[3], y: T[7], z: T[11] }, orientation: quaternionOf(T) };
}

// ---- terramap and its snapshots ---------------------------------------------------------------
export function runTerramap(terramap, args, env = {}) {
  const r = spawnSync(terramap, args, { encoding: "utf8", env: { ...process.env, ...env }, maxBuffer: 1 << 26 });
  if (r.status !== 0) fail(`terramap ${args.join(" ")} exited ${r.status}:\n${r.stdout}\n${r.stderr}`);
  return r.stdout + r.stderr;
}

/** A .tmap as {resolution, rows, cols, center: [x, y], layers: Map(name -> Float32Array row-major)}. */
export function readTmap(path) {
  const b = fs.readFileSync(path);
  if (b.toString("latin1", 0, 4) !== "TMAP") fail(`${path}: not a .tmap`);
  const dv = new DataView(b.buffer, b.byteOffset, b.byteLength);
  const resolution = dv.getFloat64(16, true);
  const rows = dv.getInt32(24, true), cols = dv.getInt32(28, true);
  const center = [dv.getFloat64(32, true), dv.getFloat64(40, true)];
  const T = dv.getInt32(48, true);
  const nLayers = dv.getUint32(56, true);
  const tileCols = Math.ceil(cols / T);
  let p = 72;
  const layers = new Map();
  for (let l = 0; l < nLayers; ++l) {
    const nameLen = dv.getUint32(p, true); p += 4;
    const name = b.toString("utf8", p, p + nameLen); p += nameLen;
    const unitLen = dv.getUint32(p, true); p += 4 + unitLen;
    const fill = dv.getFloat32(p, true); p += 4;
    const K = dv.getUint32(p, true); p += 4;
    const v = new Float32Array(rows * cols).fill(fill);
    for (let k = 0; k < K; ++k) {
      const t = dv.getUint32(p, true); p += 4;
      const r0 = Math.floor(t / tileCols) * T, c0 = (t % tileCols) * T;
      const r1 = Math.min(rows, r0 + T), c1 = Math.min(cols, c0 + T);
      for (let r = r0; r < r1; ++r)
        for (let c = c0; c < c1; ++c) { v[r * cols + c] = dv.getFloat32(p, true); p += 4; }
    }
    layers.set(name, v);
  }
  return { resolution, rows, cols, center, layers, bytes: b };
}

// ---- reading an MCAP file back ----------------------------------------------------------------
export const decompressHandlers = {
  zstd: (buf, size) => zstd.decompress(buf, Number(size)),
  lz4: (buf, size) => lz4decompress(buf, Number(size)),
};

/** Every message of `path` through McapIndexedReader (summary, chunk indexes, message indexes),
 *  after a full pass of McapStreamReader with its CRC checks; decoded with the file's schemas. */
export async function readMcap(path) {
  await zstd.isLoaded;
  await lz4decompress.isLoaded;
  const bytes = fs.readFileSync(path);
  const stream = new McapStreamReader({ decompressHandlers, validateCrcs: true });
  stream.append(new Uint8Array(bytes.buffer, bytes.byteOffset, bytes.byteLength));
  let streamed = 0, header;
  for (let rec; (rec = stream.nextRecord());) {
    if (rec.type === "Message") ++streamed;
    if (rec.type === "Header") header = rec;
  }
  if (!stream.done()) fail(`${path}: McapStreamReader did not reach the end of the file`);
  const readable = {
    size: async () => BigInt(bytes.byteLength),
    read: async (offset, size) => new Uint8Array(bytes.buffer, bytes.byteOffset + Number(offset), Number(size)),
  };
  const reader = await McapIndexedReader.Initialize({ readable, decompressHandlers });
  const decoders = new Map();
  const out = [];
  for await (const m of reader.readMessages()) {
    const ch = reader.channelsById.get(m.channelId);
    const schema = reader.schemasById.get(ch.schemaId);
    if (!decoders.has(ch.id)) {
      if (schema.encoding !== "ros2msg" || ch.messageEncoding !== "cdr") fail(`${ch.topic}: ${schema.encoding}/${ch.messageEncoding}`);
      decoders.set(ch.id, new MessageReader(parse(new TextDecoder().decode(schema.data), { ros2: true })));
    }
    out.push({ topic: ch.topic, type: schema.name, logTime: m.logTime, msg: decoders.get(ch.id).readMessage(m.data) });
  }
  if (out.length !== streamed) fail(`${path}: indexed reader found ${out.length} messages, stream reader ${streamed}`);
  return { header, messages: out, statistics: reader.statistics, chunkIndexes: reader.chunkIndexes };
}
