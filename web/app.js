// The live view of `terramap serve`: the elevation as a shaded surface coloured by any layer,
// the machine and its blade, play/pause and a layer picker, fed by the server's WebSocket.
// Frame = [u32 header length][header JSON][pad to 4][f32 height rows*cols][f32 colour rows*cols],
// grids north-up (row 0 = largest y, column 0 = smallest x), NaN = unknown.
import * as THREE from 'three';
import { OrbitControls } from 'three/addons/controls/OrbitControls.js';

const state = { frames: 0, header: null, meshExtent: null, playing: true, done: false, error: null,
                // Colour range per layer: the layer's first frame, then fixed (the server scales each
                // frame to itself, so a colour would mean another value every frame) until the user
                // types another one or fits it to the frame shown.
                ranges: {}, firstRanges: {}, appliedRange: null, gridSpacing: null };
window.__terramap = state;  // read by the headless test

const view = document.getElementById('view');
const renderer = new THREE.WebGLRenderer({ antialias: true, preserveDrawingBuffer: true });
renderer.setPixelRatio(window.devicePixelRatio);
view.appendChild(renderer.domElement);
const scene = new THREE.Scene();
scene.background = new THREE.Color(0x1e2227);
const camera = new THREE.PerspectiveCamera(45, 1, 0.05, 5000);
camera.up.set(0, 0, 1);  // the map frame is z up
const controls = new OrbitControls(camera, renderer.domElement);
scene.add(new THREE.HemisphereLight(0xffffff, 0x404040, 1.2));
const sun = new THREE.DirectionalLight(0xffffff, 1.6);
sun.position.set(-1, 1, 2);  // from the north-west, as the PNGs' hillshade
scene.add(sun);

let mesh = null, grid = null;
const machine = new THREE.Group();
const body = new THREE.Mesh(new THREE.BoxGeometry(2.6, 1.6, 1.2), new THREE.MeshStandardMaterial({ color: 0xf2b01e }));
body.position.set(-1.2, 0, 0.9);
machine.add(body);
scene.add(machine);
const blade = new THREE.Mesh(new THREE.BoxGeometry(0.06, 1, 1), new THREE.MeshStandardMaterial({ color: 0xd04030 }));
scene.add(blade);
machine.visible = blade.visible = false;

function resize() {
  const w = view.clientWidth, h = view.clientHeight;
  renderer.setSize(w, h);
  camera.aspect = w / h;
  camera.updateProjectionMatrix();
}
window.addEventListener('resize', resize);
resize();

// Viridis control points (the PNGs' default ramp), interpolated in sRGB.
const VIRIDIS = [[0, 68, 1, 84], [0.25, 59, 82, 139], [0.5, 33, 145, 140], [0.75, 94, 201, 98], [1, 253, 231, 37]];
const RDBU = [[0, 103, 0, 31], [0.25, 214, 96, 77], [0.5, 247, 247, 247], [0.75, 67, 147, 195], [1, 5, 48, 97]];
function ramp(stops, t) {
  t = Math.min(1, Math.max(0, t));
  for (let k = 1; k < stops.length; ++k) {
    if (t <= stops[k][0]) {
      const a = stops[k - 1], b = stops[k], u = (t - a[0]) / (b[0] - a[0]);
      return [0, 1, 2].map(i => (a[i + 1] + u * (b[i + 1] - a[i + 1])) / 255);
    }
  }
  return stops[stops.length - 1].slice(1).map(v => v / 255);
}

/// A "nice" step (1, 2 or 5 times a power of ten) giving about `n` intervals over `span`.
function niceStep(span, n) {
  const raw = span / n, p = Math.pow(10, Math.floor(Math.log10(raw))), f = raw / p;
  return (f <= 1 ? 1 : f <= 2 ? 2 : f <= 5 ? 5 : 10) * p;
}

// A ground grid under the surface with round spacing, its lines on multiples of the spacing in
// map coordinates, so distances and positions can be read off the view.
let ground = null;
function buildGround(h) {
  if (ground) { scene.remove(ground); ground.geometry.dispose(); }
  const [xmin, xmax, ymin, ymax] = h.map_extent || h.extent;
  const span = Math.max(xmax - xmin, ymax - ymin), step = niceStep(span, 12);
  const cx = Math.round((xmin + xmax) / 2 / step) * step, cy = Math.round((ymin + ymax) / 2 / step) * step;
  const n = 2 * Math.ceil((span / 2 + step) / step);  // even: a line through the (round) centre
  ground = new THREE.GridHelper(n * step, n, 0x8a939c, 0x50575f);
  ground.rotation.x = Math.PI / 2;  // the helper lies in x-z; the map's ground is x-y, z up
  ground.position.set(cx, cy, 0);
  scene.add(ground);
  state.gridSpacing = step;
  document.getElementById('grid-label').textContent = `grid: ${step} m squares`;
}

// Fixed at the first frame that holds a known value of the layer: before it the server's range
// is a placeholder ([0, 1] of an empty map).
function rangeOf(h) {
  if (!state.ranges[h.color_layer]) {
    if (!(state.valueMin <= state.valueMax)) return h.color_range;
    state.ranges[h.color_layer] = h.color_range.slice();
    state.firstRanges[h.color_layer] = h.color_range.slice();
  }
  return state.ranges[h.color_layer];
}

function drawLegend(h) {
  const stops = h.diverging ? RDBU : VIRIDIS;
  const c = document.getElementById('ramp').getContext('2d');
  for (let x = 0; x < 200; ++x) {
    const [r, g, b] = ramp(stops, x / 199);
    c.fillStyle = `rgb(${r * 255},${g * 255},${b * 255})`;
    c.fillRect(x, 0, 1, 12);
  }
  document.getElementById('legend-title').textContent = `${h.color_layer} [${h.color_unit}]`;
  const [lo, hi] = rangeOf(h), loIn = document.getElementById('lo'), hiIn = document.getElementById('hi');
  // Not while the user is typing into it.
  if (document.activeElement !== loIn) loIn.value = Number(lo.toPrecision(3));
  if (document.activeElement !== hiIn) hiIn.value = Number(hi.toPrecision(3));
  // Values beyond the fixed range are drawn in its end colours: say so, as the PNGs' arrows do.
  document.getElementById('lo-more').style.visibility = state.valueMin < lo ? 'visible' : 'hidden';
  document.getElementById('hi-more').style.visibility = state.valueMax > hi ? 'visible' : 'hidden';
}

function buildMesh(h) {
  if (mesh) { scene.remove(mesh); mesh.geometry.dispose(); }
  const [xmin, xmax, ymin, ymax] = h.extent;
  const geo = new THREE.PlaneGeometry(xmax - xmin, ymax - ymin, h.cols - 1, h.rows - 1);
  geo.translate((xmin + xmax) / 2, (ymin + ymax) / 2, 0);
  geo.setAttribute('color', new THREE.BufferAttribute(new Float32Array(h.rows * h.cols * 3), 3));
  mesh = new THREE.Mesh(geo, new THREE.MeshStandardMaterial({ vertexColors: true, side: THREE.DoubleSide, roughness: 0.9 }));
  scene.add(mesh);
  grid = `${h.rows}x${h.cols}@${h.extent.join(',')}`;
  const cx = (xmin + xmax) / 2, cy = (ymin + ymax) / 2, span = Math.max(xmax - xmin, ymax - ymin);
  camera.position.set(cx - 0.2 * span, cy - 0.9 * span, 0.7 * span);
  controls.target.set(cx, cy, 0);
  controls.update();
}

function applyFrame(h, height, colour) {
  if (`${h.rows}x${h.cols}@${h.extent.join(',')}` !== grid) buildMesh(h);
  const pos = mesh.geometry.attributes.position, col = mesh.geometry.attributes.color;
  let lo = Infinity;
  for (const v of height) if (Number.isFinite(v) && v < lo) lo = v;
  if (!Number.isFinite(lo)) lo = 0;
  if (!ground) buildGround(h);
  ground.position.z = lo - 0.01;  // just under the lowest ground, so it never cuts the surface
  state.valueMin = Infinity;
  state.valueMax = -Infinity;
  for (let k = 0; k < h.rows * h.cols; ++k) {
    const v = colour[k];
    if (Number.isFinite(height[k]) && Number.isFinite(v)) {
      state.valueMin = Math.min(state.valueMin, v);
      state.valueMax = Math.max(state.valueMax, v);
    }
  }
  const [c0, c1] = rangeOf(h);
  const stops = h.diverging ? RDBU : VIRIDIS, span = c1 > c0 ? c1 - c0 : 1;
  state.appliedRange = [c0, c1];
  for (let k = 0; k < h.rows * h.cols; ++k) {
    const z = height[k], v = colour[k];
    pos.setZ(k, Number.isFinite(z) ? z : lo);
    const rgb = Number.isFinite(z) && Number.isFinite(v) ? ramp(stops, (v - c0) / span) : [0.5, 0.5, 0.5];
    col.setXYZ(k, rgb[0], rgb[1], rgb[2]);
  }
  pos.needsUpdate = col.needsUpdate = true;
  mesh.geometry.computeVertexNormals();
  mesh.geometry.computeBoundingBox();
  const bb = mesh.geometry.boundingBox;
  state.meshExtent = [bb.min.x, bb.max.x, bb.min.y, bb.max.y];
  for (const [obj, key] of [[machine, 'T_map_base'], [blade, 'T_map_blade']]) {
    const T = h[key];
    obj.visible = Array.isArray(T);
    if (obj.visible) {
      obj.matrixAutoUpdate = false;
      obj.matrix.fromArray(T);  // column-major 4x4, as sent
      if (obj === blade) obj.matrix.multiply(new THREE.Matrix4().makeScale(1, h.blade_width_m, h.blade_height_m).premultiply(new THREE.Matrix4().makeTranslation(0, 0, h.blade_height_m / 2)));
    }
  }
}

function setLayers(h) {
  const sel = document.getElementById('layer');
  if (sel.options.length !== h.layers.length) {
    sel.innerHTML = '';
    for (const name of h.layers) sel.add(new Option(name, name));
  }
  sel.value = h.color_layer;
}

const ws = new WebSocket(`ws://${location.host}/live`);
ws.binaryType = 'arraybuffer';
ws.onopen = () => { document.getElementById('status').textContent = 'connected'; };
ws.onclose = () => { document.getElementById('status').textContent = 'disconnected'; };
ws.onerror = () => { state.error = 'websocket error'; };
ws.onmessage = (msg) => {
  // Text is the server refusing a command ({"error": ...}); frames are binary.
  if (typeof msg.data === 'string') { state.error = msg.data; console.warn('terramap serve:', msg.data); return; }
  const dv = new DataView(msg.data);
  const n = dv.getUint32(0, true);
  const h = JSON.parse(new TextDecoder().decode(new Uint8Array(msg.data, 4, n)));
  const off = 4 + n + ((4 - ((4 + n) % 4)) % 4), cells = h.rows * h.cols;
  const height = new Float32Array(msg.data, off, cells), colour = new Float32Array(msg.data, off + 4 * cells, cells);
  state.last = { h, height, colour };
  applyFrame(h, height, colour);
  setLayers(h);
  drawLegend(h);
  state.header = h;
  state.playing = h.playing;
  state.done = h.done;
  document.getElementById('play').textContent = h.playing ? 'pause' : 'play';
  document.getElementById('status').textContent =
    `t = ${h.stamp.toFixed(2)} s · ${h.events} events · ${h.rows}x${h.cols} of ${h.map_rows}x${h.map_cols} cells` +
    (h.done ? ' · source finished' : h.playing ? '' : ' · paused');
  state.frames += 1;
};
document.getElementById('play').onclick = () => ws.send(JSON.stringify({ cmd: state.playing ? 'pause' : 'play' }));
document.getElementById('layer').onchange = (e) => ws.send(JSON.stringify({ cmd: 'layer', name: e.target.value }));
// A range the user sets holds for that layer until changed; the frame shown is recoloured now
// (a paused or finished run sends no more frames).
function setRange(range) {
  if (!state.last) return;
  const { h, height, colour } = state.last;
  if (!(range[0] < range[1])) return;
  state.ranges[h.color_layer] = range;
  applyFrame(h, height, colour);
  drawLegend(h);
}
for (const id of ['lo', 'hi'])
  document.getElementById(id).onchange = () =>
    setRange([Number(document.getElementById('lo').value), Number(document.getElementById('hi').value)]);
document.getElementById('fit').onclick = () => state.last && setRange(state.last.h.color_range.slice());

renderer.setAnimationLoop(() => { controls.update(); renderer.render(scene, camera); });
