// The ROS 2 interoperability tests (CMakeLists.txt here, README.md):
//   node run_bag_test.mjs kitti   TERRAMAP WORKDIR            KITTI frames -> rosbag2 (tf, zstd)
//   node run_bag_test.mjs ply     TERRAMAP WORKDIR DATA_DIR   data/gicp_pair -> rosbag2 (odometry, lz4)
//   node run_bag_test.mjs gridmap TERRAMAP WORKDIR DATA_DIR   terramap's GridMap recording, read back
// kitti/ply: the bag is written with @mcap/core + @foxglove/rosmsg2-serialization, mapped by
// `terramap run` with a `type: rosbag` source, and the .tmap compared with the one of the
// equivalent `type: sequence` pipeline (configs/kitti.yaml for KITTI). gridmap (and kitti, whose
// pipeline writes one too): terramap's `outputs.mcap` file read by @mcap/core's indexed and
// stream readers, decoded with the schemas it carries, checked against the .tmap.
// Exit 77 (CTest: skipped) with "SKIP: ..." when the KITTI frames are absent.
import fs from "node:fs";
import path from "node:path";
import { fileURLToPath } from "node:url";
import {
  fail, openBag, stampOf, matmul, rigidInverse, orthonormalize, transformMsg, poseMsg, runTerramap, readTmap, readMcap,
} from "./ros2lib.mjs";

const [mode, terramap, work, dataDir] = process.argv.slice(2);
const here = path.dirname(fileURLToPath(import.meta.url));
const source = path.resolve(here, "../..");
fs.rmSync(work, { recursive: true, force: true });
fs.mkdirSync(work, { recursive: true });

const I4 = [1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1];
function yawTranslation(yawDeg, x, y, z) {
  const a = (yawDeg * Math.PI) / 180, c = Math.cos(a), s = Math.sin(a);
  return [c, -s, 0, x, s, c, 0, y, 0, 0, 1, z, 0, 0, 0, 1];
}
const FLOAT32 = 7, FLOAT64 = 8, UINT16 = 4;

// ---- comparing two snapshots ------------------------------------------------------------------
/** Same geometry and layers; every cell the same bits, or both NaN, or within `tol` (m). */
function compareTmaps(a, b, tol) {
  if (a.bytes.equals(b.bytes)) return { identical: true, maxDiff: 0, differing: 0, cells: a.rows * a.cols * a.layers.size };
  for (const k of ["resolution", "rows", "cols"]) if (a[k] !== b[k]) fail(`${k} ${a[k]} vs ${b[k]}`);
  if (a.center[0] !== b.center[0] || a.center[1] !== b.center[1]) fail(`centre ${a.center} vs ${b.center}`);
  const names = [...a.layers.keys()];
  if (names.join() !== [...b.layers.keys()].join()) fail(`layers ${names} vs ${[...b.layers.keys()]}`);
  let maxDiff = 0, differing = 0, cells = 0;
  const perLayer = {};
  for (const n of names) {
    const x = a.layers.get(n), y = b.layers.get(n);
    let layerMax = 0, layerDiff = 0;
    for (let i = 0; i < x.length; ++i) {
      ++cells;
      if (Number.isNaN(x[i]) !== Number.isNaN(y[i]))
        fail(`layer ${n} cell ${i}: known in one map, unknown in the other (${x[i]} vs ${y[i]})`);
      if (Number.isNaN(x[i]) || x[i] === y[i]) continue;
      ++differing; ++layerDiff;
      layerMax = Math.max(layerMax, Math.abs(x[i] - y[i]));
    }
    perLayer[n] = { differing: layerDiff, max: layerMax };
    maxDiff = Math.max(maxDiff, layerMax);
  }
  if (!(maxDiff <= tol)) fail(`cells differ by up to ${maxDiff} (> ${tol}): ${JSON.stringify(perLayer)}`);
  return { identical: false, maxDiff, differing, cells, perLayer };
}

function report(what, r) {
  if (r.identical) console.log(`${what}: the .tmap files are byte-identical`);
  else console.log(`${what}: the .tmap files differ in ${r.differing} of ${r.cells} cells, by at most ${r.maxDiff.toExponential(3)}` +
    ` (NaN pattern identical): ${JSON.stringify(r.perLayer)}`);
}

// ---- terramap's GridMap recording against its snapshot ----------------------------------------
async function checkGridMap(mcapPath, tmap, opts) {
  const { header, messages, statistics } = await readMcap(mcapPath);
  if (header.profile !== "ros2") fail(`profile '${header.profile}', not ros2`);
  const maps = messages.filter((m) => m.topic === opts.topic);
  if (maps.length !== opts.expectedMaps) fail(`${maps.length} GridMap messages, expected ${opts.expectedMaps}`);
  if (maps.some((m) => m.type !== "grid_map_msgs/msg/GridMap")) fail(`GridMap schema name ${maps[0].type}`);
  if (statistics && Number(statistics.messageCount) !== messages.length) fail("statistics.messageCount disagrees");
  const last = maps[maps.length - 1].msg;
  const { rows, cols, resolution } = tmap;
  if (last.header.frame_id !== "map") fail(`frame_id ${last.header.frame_id}`);
  if (last.info.resolution !== resolution) fail(`resolution ${last.info.resolution}`);
  if (last.info.length_x !== rows * resolution || last.info.length_y !== cols * resolution)
    fail(`length ${last.info.length_x} x ${last.info.length_y}, map ${rows} x ${cols} x ${resolution}`);
  const p = last.info.pose;
  if (p.position.x !== tmap.center[0] || p.position.y !== tmap.center[1] || p.position.z !== 0) fail(`pose ${JSON.stringify(p.position)}`);
  if (p.orientation.w !== 1 || p.orientation.x || p.orientation.y || p.orientation.z) fail("orientation not identity");
  if (last.layers.join() !== opts.layers.join()) fail(`layers ${last.layers} vs ${opts.layers}`);
  if (last.outer_start_index !== 0 || last.inner_start_index !== 0) fail("start indices not 0");
  if (last.data.length !== opts.layers.length) fail(`${last.data.length} data arrays`);
  let unknown = 0, known = 0;
  last.data.forEach((d, k) => {
    const dim = d.layout.dim;
    if (dim.length !== 2 || dim[0].label !== "column_index" || dim[1].label !== "row_index") fail(`layer ${k} labels ${JSON.stringify(dim)}`);
    if (dim[0].size !== cols || dim[0].stride !== rows * cols || dim[1].size !== rows || dim[1].stride !== rows)
      fail(`layer ${k} layout ${JSON.stringify(dim)} for ${rows} rows x ${cols} cols`);
    if (d.layout.data_offset !== 0) fail("data_offset");
    if (d.data.length !== rows * cols) fail(`layer ${k}: ${d.data.length} values`);
    const t = tmap.layers.get(opts.layers[k]);
    const bits = new Uint32Array(new Float32Array(d.data).buffer), tbits = new Uint32Array(t.buffer);
    for (let i = 0; i < rows; ++i)
      for (let j = 0; j < cols; ++j) {
        const v = d.data[i + j * rows];
        if (Number.isNaN(v)) { ++unknown; if (!Number.isNaN(t[i * cols + j])) fail(`layer ${opts.layers[k]} (${i}, ${j}) NaN in the message`); continue; }
        ++known;
        if (bits[i + j * rows] !== tbits[i * cols + j]) fail(`layer ${opts.layers[k]} (${i}, ${j}): ${v} vs ${t[i * cols + j]}`);
      }
  });
  if (!known || !unknown) fail(`${known} known and ${unknown} unknown cells: the check would be vacuous`);
  // On-finish layers are unknown in the updates before the end, and the first update knows less.
  if (opts.finishLayer) {
    const k = opts.layers.indexOf(opts.finishLayer);
    if (!maps[0].msg.data[k].data.every(Number.isNaN)) fail(`${opts.finishLayer} known before the run's finish`);
  }
  const knownIn = (m) => m.data[0].data.filter((v) => !Number.isNaN(v)).length;
  if (!(knownIn(maps[0].msg) < knownIn(last))) fail("the first update knows as much as the finished map");
  const stamps = maps.map((m) => m.msg.header.stamp.sec + m.msg.header.stamp.nanosec / 1e9);
  if (stamps.join() !== opts.stamps.join()) fail(`GridMap stamps ${stamps} vs ${opts.stamps}`);
  if (opts.clouds) {
    const clouds = messages.filter((m) => m.topic === "/terramap/points");
    const tfs = messages.filter((m) => m.topic === "/tf");
    if (clouds.length !== opts.clouds.length || tfs.length !== opts.clouds.length) fail(`${clouds.length} clouds, ${tfs.length} tf`);
    clouds.forEach((c, k) => {
      const m = c.msg, want = opts.clouds[k];
      if (m.width * m.height !== want.count || m.point_step !== 16) fail(`cloud ${k}: ${m.width} x ${m.height} points`);
      const dv = new DataView(m.data.buffer, m.data.byteOffset, m.data.byteLength);
      const first = [0, 4, 8, 12].map((o) => dv.getFloat32(o, true));
      if (first.join() !== want.first.join()) fail(`cloud ${k} first point ${first} vs ${want.first}`);
      const t = tfs[k].msg.transforms[0];
      if (t.header.frame_id !== "map" || t.child_frame_id !== m.header.frame_id) fail(`tf ${k} frames`);
      const d = Math.hypot(t.transform.translation.x - want.T[3], t.transform.translation.y - want.T[7], t.transform.translation.z - want.T[11]);
      if (!(d < 1e-6)) fail(`tf ${k} translation off by ${d} m`);
    });
  }
  console.log(`gridmap: ${maps.length} GridMap messages read by @mcap/core (indexed and stream readers, CRCs checked), ` +
    `decoded with the file's ros2msg schemas; the last one equals the .tmap cell for cell (${known} known, ${unknown} unknown)`);
}

// ---- KITTI -------------------------------------------------------------------------------------
async function kitti() {
  const env = process.env.TERRAMAP_KITTI_DIR;
  const dir = env ? path.resolve(env) : process.env.TERRAMAP_KITTI_DIR_DEFAULT;
  const files = [0, 1, 2, 3, 4, 5].map((k) => path.join(dir, `${String(k).padStart(6, "0")}.bin`));
  const posesFile = path.join(dir, "DERIVED_icp_relative_poses.txt");
  for (const f of [...files, posesFile])
    if (!fs.existsSync(f)) {
      console.log(`SKIP: KITTI frames not found: ${f} is missing (set TERRAMAP_KITTI_DIR to their folder; data/README.md)`);
      process.exit(77);
    }
  // T_0_k chained as configs/kitti.yaml's relative poses are (each product re-projected onto SO(3)).
  const poses = [I4];
  for (const line of fs.readFileSync(posesFile, "utf8").split("\n")) {
    const t = line.replace(/#.*/, "").trim().split(/\s+/);
    if (t.length < 17) continue;
    poses.push(orthonormalize(matmul(poses[poses.length - 1], t.slice(1, 17).map(Number))));
  }
  const T_base_velo = yawTranslation(1.5, 0.27, 0.0, 1.73);
  const bagPath = path.join(work, "kitti.mcap");
  const bag = await openBag(bagPath, "zstd");
  await bag.add("/tf_static", "tf2_msgs/TFMessage", 0n, { transforms: [{ header: { stamp: stampOf(0n), frame_id: "base_link" },
    child_frame_id: "velodyne", transform: transformMsg(T_base_velo) }] });
  for (let k = 0; k < 6; ++k) {
    const ns = BigInt(k) * 100000000n;
    const T_map_base = matmul(poses[k], rigidInverse(T_base_velo));
    await bag.add("/tf", "tf2_msgs/TFMessage", ns, { transforms: [{ header: { stamp: stampOf(ns), frame_id: "map" },
      child_frame_id: "base_link", transform: transformMsg(T_map_base) }] });
    const data = fs.readFileSync(files[k]);
    const n = data.length / 16;
    await bag.add("/velodyne_points", "sensor_msgs/PointCloud2", ns, {
      header: { stamp: stampOf(ns), frame_id: "velodyne" }, height: 1, width: n,
      fields: ["x", "y", "z", "intensity"].map((name, i) => ({ name, offset: 4 * i, datatype: FLOAT32, count: 1 })),
      is_bigendian: false, point_step: 16, row_step: 16 * n, data: new Uint8Array(data), is_dense: true });
  }
  await bag.end();
  runTerramap(terramap, ["run", path.join(source, "configs/kitti.yaml"), "--out", path.join(work, "sequence")]);
  runTerramap(terramap, ["run", path.join(source, "configs/kitti_rosbag.yaml"), "--out", path.join(work, "rosbag")],
    { TERRAMAP_ROSBAG: bagPath });
  const a = readTmap(path.join(work, "sequence/map.tmap")), b = readTmap(path.join(work, "rosbag/map.tmap"));
  report("kitti", compareTmaps(a, b, 1e-3));
  await checkGridMap(path.join(work, "rosbag/map.mcap"), b, { topic: "/terramap/grid_map", expectedMaps: 7,
    layers: ["elevation", "variance", "elevation_inpainted", "elevation_smooth"], finishLayer: "elevation_smooth",
    stamps: [0, 0.1, 0.2, 0.3, 0.4, 0.5, 0.5] });
}

// ---- the repository's PLY pair -------------------------------------------------------------------
function readPly(file) {
  const b = fs.readFileSync(file);
  const end = b.indexOf("end_header\n") + "end_header\n".length;
  const n = Number(/element vertex (\d+)/.exec(b.toString("latin1", 0, end))[1]);
  const dv = new DataView(b.buffer, b.byteOffset + end, n * 16);
  return { n, get: (i, k) => dv.getFloat32(16 * i + 4 * k, true) };
}

/** data/gicp_pair as a bag: Odometry + a static extrinsic, organised float64 clouds, lz4 chunks. */
async function plyBag(bagPath) {
  const rows = fs.readFileSync(path.join(dataDir, "T_target_source.txt"), "utf8").trim().split(/\s+/).map(Number);
  const frames = [{ ply: readPly(path.join(dataDir, "source.ply")), T: rows }, { ply: readPly(path.join(dataDir, "target.ply")), T: I4 }];
  const T_base_lidar = yawTranslation(0, 0.1, -0.05, 0.6);
  const bag = await openBag(bagPath, "lz4", 256 << 10);
  await bag.add("/tf_static", "tf2_msgs/TFMessage", 0n, { transforms: [{ header: { stamp: stampOf(0n), frame_id: "base_link" },
    child_frame_id: "lidar", transform: transformMsg(T_base_lidar) }] });
  const zero36 = new Array(36).fill(0);
  for (let k = 0; k < frames.length; ++k) {
    const ns = BigInt(k) * 100000000n;
    await bag.add("/odom", "nav_msgs/Odometry", ns, { header: { stamp: stampOf(ns), frame_id: "odom" }, child_frame_id: "base_link",
      pose: { pose: poseMsg(matmul(frames[k].T, rigidInverse(T_base_lidar))), covariance: zero36 },
      twist: { twist: { linear: { x: 0, y: 0, z: 0 }, angular: { x: 0, y: 0, z: 0 } }, covariance: zero36 } });
    // Organised (2 rows), x/y/z float64, intensity float32, a uint16 ring field, 8 bytes of row padding.
    const { ply } = frames[k];
    const width = ply.n / 2, step = 32, rowStep = width * step + 8;
    const data = new Uint8Array(rowStep * 2);
    const dv = new DataView(data.buffer);
    for (let i = 0; i < ply.n; ++i) {
      const o = Math.floor(i / width) * rowStep + (i % width) * step;
      for (let a = 0; a < 3; ++a) dv.setFloat64(o + 8 * a, ply.get(i, a), true);
      dv.setFloat32(o + 24, ply.get(i, 3), true);
      dv.setUint16(o + 28, i % 64, true);
    }
    await bag.add("/points", "sensor_msgs/PointCloud2", ns, { header: { stamp: stampOf(ns), frame_id: "lidar" }, height: 2, width,
      fields: [{ name: "x", offset: 0, datatype: FLOAT64, count: 1 }, { name: "y", offset: 8, datatype: FLOAT64, count: 1 },
        { name: "z", offset: 16, datatype: FLOAT64, count: 1 }, { name: "intensity", offset: 24, datatype: FLOAT32, count: 1 },
        { name: "ring", offset: 28, datatype: UINT16, count: 1 }],
      is_bigendian: false, point_step: step, row_step: rowStep, data, is_dense: false });
  }
  await bag.end();
  return frames;
}

const PLY_STAGES = `pipeline:
  - {name: lidar, type: lidar_fusion, params: {sensor_noise: range_based, max_range_m: 40, enable_visibility_cleanup: true}}
  - {name: fill, type: inpaint, params: {input_layer: elevation, output_layer: elevation_inpainted, max_distance_m: 1.0}}
  - {name: smooth, type: smooth_filter, params: {input_layer: elevation_inpainted, output_layer: elevation_smooth,
                                                 sigma_m: 0.15, radius_m: 0.45, run_on: [], on_finish: true}}
`;
const PLY_MAP = "version: 1\nmap: {resolution: 0.1, size: [400, 400], center: [0, 0], tile: 64}\nthreads: 2\n";
function rosbagYaml(bagPath, outputs) {
  return `${PLY_MAP}source: {type: rosbag, bag: ${bagPath}, cloud_topic: /points, pose_source: odometry, odometry_topic: /odom,
         map_frame: odom}
${PLY_STAGES}outputs: {png: [], ${outputs}}
`;
}

async function ply() {
  const bagPath = path.join(work, "pair.mcap");
  const frames = await plyBag(bagPath);
  // The same frames through the sequence source: KITTI pose rows (12 numbers, shortest exact text).
  fs.writeFileSync(path.join(work, "poses.txt"), frames.map((f) => f.T.slice(0, 12).join(" ")).join("\n") + "\n");
  fs.writeFileSync(path.join(work, "sequence.yaml"), `${PLY_MAP}source: {type: sequence, clouds: ${dataDir}, extensions: [.ply],
         poses: ${path.join(work, "poses.txt")}, pose_format: kitti, period_s: 0.1}
${PLY_STAGES}outputs: {png: [], snapshot: true}
`);
  fs.writeFileSync(path.join(work, "rosbag.yaml"), rosbagYaml(bagPath, "snapshot: true"));
  runTerramap(terramap, ["run", path.join(work, "sequence.yaml"), "--out", path.join(work, "sequence")]);
  runTerramap(terramap, ["run", path.join(work, "rosbag.yaml"), "--out", path.join(work, "rosbag")]);
  report("ply", compareTmaps(readTmap(path.join(work, "sequence/map.tmap")), readTmap(path.join(work, "rosbag/map.tmap")), 1e-3));
}

async function gridmap() {
  const bagPath = path.join(work, "pair.mcap");
  const frames = await plyBag(bagPath);
  const layers = ["elevation", "variance", "elevation_smooth"];
  fs.writeFileSync(path.join(work, "rosbag.yaml"), rosbagYaml(bagPath,
    `snapshot: true, mcap: {layers: [${layers}], copy_clouds: true, compression: lz4}`));
  runTerramap(terramap, ["run", path.join(work, "rosbag.yaml"), "--out", path.join(work, "out")]);
  const tmap = readTmap(path.join(work, "out/map.tmap"));
  await checkGridMap(path.join(work, "out/map.mcap"), tmap, { topic: "/terramap/grid_map", expectedMaps: 3, layers,
    finishLayer: "elevation_smooth", stamps: [0, 0.1, 0.1],
    clouds: frames.map((f) => ({ count: f.ply.n, first: [0, 1, 2, 3].map((a) => f.ply.get(0, a)), T: f.T })) });
}

const modes = { kitti, ply, gridmap };
if (!modes[mode]) fail(`unknown mode '${mode}' (kitti, ply, gridmap)`);
await modes[mode]();
console.log(`ros2 ${mode} ok`);
