// Drives `terramap serve` in headless Chromium (playwright-core, Debian's chromium): loads the
// page, waits for frames until the source has finished, checks that the surface spans the
// map's extent, switches the colour layer and pauses through the page's own controls, checks
// the canvas shows a surface, and keeps a screenshot.
// Usage: node live_view.cjs TERRAMAP PIPELINE SCREENSHOT XMIN XMAX YMIN YMAX
// Env: PLAYWRIGHT_CORE (module path), CHROMIUM (executable).
const { spawn } = require('child_process');
const { chromium } = require(process.env.PLAYWRIGHT_CORE);

const [terramap, pipeline, screenshot, ...ext] = process.argv.slice(2);
const expected = ext.map(Number);
const fail = (msg) => { console.error('FAIL: ' + msg); process.exitCode = 1; };
const near = (a, b, tol) => Math.abs(a - b) <= tol;

(async () => {
  // Paced at 2x real time and held until the page connects, so the page sees the run play.
  const server = spawn(terramap, ['serve', pipeline, '--port', '0', '--speed', '2', '--wait-for-viewer', '--exit-after', '120'],
                       { stdio: ['ignore', 'pipe', 'inherit'] });
  const url = await new Promise((resolve, reject) => {
    let out = '';
    server.stdout.on('data', (d) => {
      out += d;
      const m = out.match(/serving (http:\/\/127\.0\.0\.1:\d+\/)/);
      if (m) resolve(m[1]);
    });
    server.on('exit', (code) => reject(new Error('terramap serve exited with ' + code + ':\n' + out)));
    setTimeout(() => reject(new Error('no "serving" line in 30 s:\n' + out)), 30000).unref();
  });
  console.log('server at', url);
  const browser = await chromium.launch({
    executablePath: process.env.CHROMIUM || '/usr/bin/chromium',
    args: ['--no-sandbox', '--use-angle=swiftshader', '--enable-unsafe-swiftshader', '--ignore-gpu-blocklist'],
  });
  try {
    const page = await browser.newPage({ viewport: { width: 1000, height: 700 } });
    const external = [];
    page.on('request', (r) => { if (!r.url().startsWith(url) && !r.url().startsWith(url.replace('http', 'ws'))) external.push(r.url()); });
    page.on('pageerror', (e) => fail('page error: ' + e.message));
    await page.goto(url);
    await page.waitForFunction(() => window.__terramap && window.__terramap.frames >= 1, null, { timeout: 60000 });
    console.log('first frame');
    await page.waitForFunction(() => window.__terramap.done, null, { timeout: 120000 });
    let s = await page.evaluate(() => window.__terramap);
    const h = s.header;
    console.log(`done: ${s.frames} frames, ${h.events} events, grid ${h.rows}x${h.cols} (stride ${h.stride})`);
    if (s.frames < 5) fail('expected frames while the source played, got ' + s.frames);
    h.map_extent.forEach((v, k) => { if (!near(v, expected[k], 1e-9)) fail(`map extent [${h.map_extent}] != [${expected}]`); });
    // The surface spans the centres of the sampled cells: the first is half a cell inside the
    // map's west/north edge, the last (cols - 1) * stride cells further (worked out here from the
    // map's own extent, not from what the server says).
    const res = h.resolution, st = h.stride;
    const want = [expected[0] + 0.5 * res, expected[0] + (0.5 + (h.cols - 1) * st) * res,
                  expected[3] - (0.5 + (h.rows - 1) * st) * res, expected[3] - 0.5 * res];
    if (h.cols !== Math.ceil(Math.round((expected[1] - expected[0]) / res) / st) ||
        h.rows !== Math.ceil(Math.round((expected[3] - expected[2]) / res) / st))
      fail(`grid ${h.rows}x${h.cols} (stride ${st}) does not sample the map's extent [${expected}]`);
    s.meshExtent.forEach((v, k) => {
      if (!near(v, want[k], 1e-4)) fail(`mesh extent [${s.meshExtent}] != the sampled cell centres [${want}]`);
      if (!near(v, h.extent[k], 1e-4)) fail(`mesh extent [${s.meshExtent}] != frame extent [${h.extent}]`);
    });
    if (!h.layers.includes('variance')) fail('no variance layer offered: ' + h.layers);
    // The page's own controls: colour by variance, then pause.
    await page.selectOption('#layer', 'variance');
    await page.waitForFunction(() => window.__terramap.header.color_layer === 'variance', null, { timeout: 20000 });
    await page.click('#play');
    await page.waitForFunction(() => window.__terramap.header.playing === false, null, { timeout: 20000 });
    // A surface, not an empty scene: many distinct colours on the canvas.
    const colours = await page.evaluate(() => {
      const src = document.querySelector('#view canvas');
      const c = document.createElement('canvas');
      c.width = src.width; c.height = src.height;
      const g = c.getContext('2d');
      g.drawImage(src, 0, 0);
      const d = g.getImageData(0, 0, c.width, c.height).data, seen = new Set();
      for (let k = 0; k < d.length; k += 4 * 97) seen.add((d[k] << 16) | (d[k + 1] << 8) | d[k + 2]);
      return seen.size;
    });
    console.log('distinct colours on the canvas:', colours);
    if (colours < 50) fail('the canvas shows no surface (' + colours + ' colours)');
    if (external.length) fail('the page fetched from elsewhere: ' + external.join(', '));
    await page.screenshot({ path: screenshot });
    console.log('screenshot', screenshot);
  } catch (e) {
    fail(e.stack || String(e));
  } finally {
    await browser.close();
    server.kill('SIGTERM');
  }
  if (!process.exitCode) console.log('live view ok');
})().catch((e) => { fail(e.stack || String(e)); process.exit(1); });
