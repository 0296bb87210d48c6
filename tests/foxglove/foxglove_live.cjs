// `terramap serve` as Foxglove sees it, checked with Foxglove's own client (@foxglove/ws-protocol's
// FoxgloveClient over the `ws` package), not with terramap's code: connects to ws://127.0.0.1:PORT
// with the subprotocol foxglove.websocket.v1, checks serverInfo and the advertised channels,
// waits for the source to finish, subscribes to the map and decodes the foxglove.Grid (JSON, the
// cells base64) and compares every cell, bit for bit, with `terramap run` of the same pipeline
// exported to GeoTIFF and read by GDAL (gdal_translate to raw float32). The latest cloud
// (foxglove.PointCloud) must lie on that map: its points, moved by its pose into the map frame,
// fall on the mapped elevation. Unsubscribing stops the messages of that subscription. A second
// server with --foxglove-max-grid 64 sends the 200 x 120 map sampled every 4th cell: checked
// against the same reference.
// Usage: node foxglove_live.cjs TERRAMAP PIPELINE WORKDIR
// Env: NODE_PATH holding @foxglove/ws-protocol and ws (tests/ros2/package.json, installed by tests/ros2).
const { spawn, execFileSync } = require('child_process');
const fs = require('fs');
const path = require('path');
const { FoxgloveClient } = require('@foxglove/ws-protocol');
const { WebSocket } = require('ws');

const [terramap, pipeline, work] = process.argv.slice(2);
const LAYERS = ['elevation', 'variance'];
let failures = 0;
const fail = (msg) => { console.error('FAIL: ' + msg); failures += 1; };
const env = { ...process.env, TERRAMAP_PLUGIN_PATH: '' };

/// The reference: the same pipeline run to a .tmap, exported, read by GDAL.
function reference() {
  fs.rmSync(work, { recursive: true, force: true });
  fs.mkdirSync(work, { recursive: true });
  const out = path.join(work, 'run');
  execFileSync(terramap, ['run', pipeline, '--out', out, '-q'], { env, stdio: 'inherit' });
  const tif = path.join(work, 'map.tif'), raw = path.join(work, 'map.bin');
  const layerArgs = LAYERS.flatMap((l) => ['-l', l]);
  execFileSync(terramap, ['export', path.join(out, 'map.tmap'), ...layerArgs, '-o', tif, '--no-compress'], { env, stdio: 'inherit' });
  execFileSync('gdal_translate', ['-q', '-of', 'ENVI', tif, raw], { stdio: 'inherit' });
  const info = JSON.parse(execFileSync('gdalinfo', ['-json', tif], { stdio: ['ignore', 'pipe', 'ignore'] }).toString());
  const [width, height] = info.size;
  const buf = fs.readFileSync(raw);
  // ENVI, interleave bsq, byte order 0: band after band of little-endian float32, north row first.
  const bands = LAYERS.map((_, b) => new Float32Array(buf.buffer.slice(buf.byteOffset + b * width * height * 4,
                                                                      buf.byteOffset + (b + 1) * width * height * 4)));
  return { width, height, gt: info.geoTransform, bands };
}

function startServer(extra = []) {
  const server = spawn(terramap, ['serve', pipeline, '--port', '0', '--speed', '0', '--wait-for-viewer', '--exit-after', '60',
                                  '--foxglove-layers', LAYERS.join(','), ...extra],
                       { env, stdio: ['ignore', 'pipe', 'inherit'] });
  const port = new Promise((resolve, reject) => {
    let out = '';
    server.stdout.on('data', (d) => {
      out += d;
      const m = out.match(/Foxglove: ws:\/\/127\.0\.0\.1:(\d+)/);
      if (m) resolve(Number(m[1]));
    });
    server.on('exit', (code) => reject(new Error('terramap serve exited with ' + code + ':\n' + out)));
    setTimeout(() => reject(new Error('no "serving" line in 30 s:\n' + out)), 30000).unref();
  });
  return { server, port };
}

const sameBits = (a, b) => (Number.isNaN(a) && Number.isNaN(b)) || Object.is(a, b) || a === b;

/// The Grid against the reference; with stride k, Grid cell (c, r) is the map's cell (k c, k r)
/// counted from the south-west corner, and a Grid cell is k map cells wide.
function checkGrid(grid, ref, k = 1) {
  const res = ref.gt[1];
  const cols = Math.ceil(ref.width / k), rowsWant = Math.ceil(ref.height / k);
  const xmin = ref.gt[0], ymin = ref.gt[3] + ref.gt[5] * ref.height;
  if (grid.frame_id !== 'map') fail(`frame_id ${grid.frame_id}`);
  if (grid.column_count !== cols) fail(`column_count ${grid.column_count} != ${cols}`);
  if (Math.abs(grid.cell_size.x - k * res) > 1e-12 || Math.abs(grid.cell_size.y - k * res) > 1e-12)
    fail(`cell_size ${JSON.stringify(grid.cell_size)} != ${k} x ${res}`);
  const p = grid.pose.position, q = grid.pose.orientation;
  if (Math.abs(p.x - xmin) > 1e-9 || Math.abs(p.y - ymin) > 1e-9 || p.z !== 0)
    fail(`pose ${JSON.stringify(p)} is not the map's south-west corner (${xmin}, ${ymin})`);
  if (q.x !== 0 || q.y !== 0 || q.z !== 0 || q.w !== 1) fail(`orientation ${JSON.stringify(q)} is not the identity`);
  const names = grid.fields.map((f) => f.name);
  if (JSON.stringify(names) !== JSON.stringify(LAYERS)) fail(`fields [${names}] != [${LAYERS}]`);
  grid.fields.forEach((f) => { if (f.type !== 7) fail(`field ${f.name} type ${f.type} is not FLOAT32 (7)`); });
  if (grid.cell_stride !== 4 * LAYERS.length || grid.row_stride !== grid.cell_stride * grid.column_count)
    fail(`strides ${grid.cell_stride}/${grid.row_stride}`);
  const data = Buffer.from(grid.data, 'base64');
  const rows = data.length / grid.row_stride;
  if (rows !== rowsWant) fail(`${rows} rows != ${rowsWant}`);
  let compared = 0, known = 0, differing = 0;
  for (let r = 0; r < Math.min(rows, rowsWant); ++r)
    for (let c = 0; c < cols; ++c)
      grid.fields.forEach((f, b) => {
        const v = data.readFloatLE(r * grid.row_stride + c * grid.cell_stride + f.offset);
        // Grid rows go north from the pose (y-major); the GeoTIFF's first row is the northmost.
        const want = ref.bands[b][(ref.height - 1 - r * k) * ref.width + c * k];
        compared += 1;
        if (!Number.isNaN(want)) known += 1;
        if (!sameBits(v, want)) {
          if (differing < 5) fail(`${f.name} at grid row ${r} column ${c}: ${v} != ${want} (terramap run + export)`);
          differing += 1;
        }
      });
  console.log(`grid (stride ${k}): ${cols}x${rows} cells x ${LAYERS.length} layers, ${compared} values compared, ` +
              `${known} known, ${differing} differ`);
  if (known < compared / 10) fail(`only ${known} of ${compared} values are known: the run mapped too little to compare`);
  if (differing > 0) fail(`${differing} values differ from the exported map`);
  return { xmin, ymin, res, data, rowStride: grid.row_stride, cellStride: grid.cell_stride };
}

/// Points of the cloud in the map frame against the Grid's elevation: the median distance of
/// the points that land on known cells.
function checkCloud(cloud, g) {
  if (cloud.frame_id !== 'map') fail(`cloud frame_id ${cloud.frame_id}`);
  const f = Object.fromEntries(cloud.fields.map((x) => [x.name, x]));
  ['x', 'y', 'z'].forEach((n) => { if (!f[n] || f[n].type !== 7) fail(`cloud field ${n} missing or not FLOAT32`); });
  const data = Buffer.from(cloud.data, 'base64');
  const n = data.length / cloud.point_stride;
  if (!Number.isInteger(n) || n < 100) { fail(`cloud of ${n} points`); return; }
  const { x: qx, y: qy, z: qz, w: qw } = cloud.pose.orientation, t = cloud.pose.position;
  const R = [[1 - 2 * (qy * qy + qz * qz), 2 * (qx * qy - qz * qw), 2 * (qx * qz + qy * qw)],
             [2 * (qx * qy + qz * qw), 1 - 2 * (qx * qx + qz * qz), 2 * (qy * qz - qx * qw)],
             [2 * (qx * qz - qy * qw), 2 * (qy * qz + qx * qw), 1 - 2 * (qx * qx + qy * qy)]];
  const rot = (v) => R.map((row) => row[0] * v[0] + row[1] * v[1] + row[2] * v[2]);
  const d = [];
  for (let i = 0; i < n; ++i) {
    const o = i * cloud.point_stride;
    const p = rot([data.readFloatLE(o + f.x.offset), data.readFloatLE(o + f.y.offset), data.readFloatLE(o + f.z.offset)]);
    const mx = p[0] + t.x, my = p[1] + t.y, mz = p[2] + t.z;
    const c = Math.floor((mx - g.xmin) / g.res), r = Math.floor((my - g.ymin) / g.res);
    if (c < 0 || r < 0 || c * g.cellStride >= g.rowStride || r * g.rowStride >= g.data.length) continue;
    const h = g.data.readFloatLE(r * g.rowStride + c * g.cellStride);
    if (!Number.isNaN(h)) d.push(Math.abs(mz - h));
  }
  d.sort((a, b) => a - b);
  const median = d[Math.floor(d.length / 2)];
  console.log(`cloud: ${n} points, ${d.length} on known cells, median |z - elevation| ${median.toFixed(4)} m`);
  if (d.length < n / 10) fail(`only ${d.length} of ${n} cloud points land on known cells`);
  if (!(median < 0.05)) fail(`the cloud does not lie on the map: median |z - elevation| ${median} m`);
}

(async () => {
  const ref = reference();
  const { server, port: portP } = startServer();
  try {
    const port = await portP;
    const ws = new WebSocket(`ws://127.0.0.1:${port}`, [FoxgloveClient.SUPPORTED_SUBPROTOCOL]);
    const client = new FoxgloveClient({ ws });
    const got = { channels: [], statuses: [], messages: [] };
    let wake = () => {};
    const changed = () => wake();
    client.on('serverInfo', (i) => { got.info = i; changed(); });
    client.on('advertise', (c) => { got.channels.push(...c); changed(); });
    client.on('status', (s) => { got.statuses.push(s); changed(); });
    client.on('message', (m) => { got.messages.push(m); changed(); });
    client.on('error', (e) => fail('client error: ' + e));
    const until = (pred, what, ms = 60000) => new Promise((resolve, reject) => {
      const timer = setTimeout(() => reject(new Error('timed out waiting for ' + what)), ms);
      wake = () => { if (pred()) { clearTimeout(timer); resolve(); } };
      wake();
    });
    await until(() => got.info && got.channels.length >= 2, 'serverInfo and advertise');
    if (ws.protocol !== 'foxglove.websocket.v1') fail(`negotiated subprotocol '${ws.protocol}'`);
    if (got.info.name !== 'terramap') fail(`server name ${got.info.name}`);
    const byTopic = Object.fromEntries(got.channels.map((c) => [c.topic, c]));
    const gridCh = byTopic['/terramap/map'], cloudCh = byTopic['/terramap/cloud'];
    for (const [ch, schemaName] of [[gridCh, 'foxglove.Grid'], [cloudCh, 'foxglove.PointCloud']]) {
      if (!ch) { fail(`no channel for ${schemaName}: ${JSON.stringify(got.channels.map((c) => c.topic))}`); return; }
      if (ch.schemaName !== schemaName || ch.encoding !== 'json' || ch.schemaEncoding !== 'jsonschema')
        fail(`channel ${ch.topic}: ${ch.schemaName} ${ch.encoding} ${ch.schemaEncoding}`);
      const schema = JSON.parse(ch.schema);
      if (schema.properties.data.contentEncoding !== 'base64') fail(`${schemaName} schema: data is not base64`);
    }
    await until(() => got.statuses.some((s) => /source finished/.test(s.message)), 'the "source finished" status');
    console.log('source finished:', got.statuses.find((s) => /source finished/.test(s.message)).message);
    const gridSub = client.subscribe(gridCh.id);
    const cloudSub = client.subscribe(cloudCh.id);
    const decode = (m) => JSON.parse(Buffer.from(m.data.buffer, m.data.byteOffset, m.data.byteLength).toString());
    await until(() => got.messages.some((m) => m.subscriptionId === gridSub) && got.messages.some((m) => m.subscriptionId === cloudSub),
                'a Grid and a PointCloud');
    const gridMsg = got.messages.find((m) => m.subscriptionId === gridSub);
    const grid = decode(gridMsg);
    const stampNs = BigInt(grid.timestamp.sec) * 1000000000n + BigInt(grid.timestamp.nsec);
    if (gridMsg.timestamp !== stampNs) fail(`message timestamp ${gridMsg.timestamp} != the Grid's ${stampNs}`);
    const g = checkGrid(grid, ref);
    checkCloud(decode(got.messages.find((m) => m.subscriptionId === cloudSub)), g);
    // An unknown channel is refused with an error status, the connection stays.
    client.subscribe(99);
    await until(() => got.statuses.some((s) => s.level === 2), 'an error status for channel 99', 10000);
    // After unsubscribing, a new subscriber's republish reaches only the new subscription.
    client.unsubscribe(gridSub);
    const before = got.messages.length;
    const again = client.subscribe(gridCh.id);
    await until(() => got.messages.slice(before).some((m) => m.subscriptionId === again), 'the Grid on a second subscription');
    if (got.messages.slice(before).some((m) => m.subscriptionId === gridSub)) fail('messages for an unsubscribed subscription');
    client.close();
  } catch (e) {
    fail(e.message);
  } finally {
    server.kill('SIGTERM');
  }
  const sampled = startServer(['--foxglove-max-grid', '64']);
  try {
    const port = await sampled.port;
    const ws = new WebSocket(`ws://127.0.0.1:${port}`, [FoxgloveClient.SUPPORTED_SUBPROTOCOL]);
    const client = new FoxgloveClient({ ws });
    const grid = await new Promise((resolve, reject) => {
      const timer = setTimeout(() => reject(new Error('timed out waiting for the sampled Grid')), 60000);
      let sub = -1, finished = false, gridId = -1;
      client.on('advertise', (channels) => { gridId = channels.find((c) => c.topic === '/terramap/map').id; });
      client.on('status', (s) => {
        if (/source finished/.test(s.message) && !finished) { finished = true; sub = client.subscribe(gridId); }
      });
      client.on('message', (m) => {
        if (m.subscriptionId !== sub) return;
        clearTimeout(timer);
        resolve(JSON.parse(Buffer.from(m.data.buffer, m.data.byteOffset, m.data.byteLength).toString()));
      });
    });
    checkGrid(grid, ref, 4);
    client.close();
  } catch (e) {
    fail(e.message);
  } finally {
    sampled.server.kill('SIGTERM');
  }
  if (failures === 0) console.log('foxglove live ok');
  process.exitCode = failures === 0 ? 0 : 1;
})();
