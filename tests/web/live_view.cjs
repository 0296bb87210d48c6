// Drives `terramap serve` in headless Chromium (playwright-core, Debian's chromium): loads the
// page, waits for frames until the source has finished, checks that the surface spans the
// map's extent, switches the colour layer and pauses through the page's own controls, checks
// the canvas shows a surface, checks that colour ranges stay fixed per layer (first frame, or as
// typed) and that a ground grid with its spacing is shown, and keeps a screenshot.
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
    // Colours hold still over the run: the layer's range stays the one of its first frame with
    // data, whatever later frames span (the server sends each frame's own range).
    const layer0 = h.color_layer, first = s.firstRanges && s.firstRanges[layer0];
    if (!first) fail('no colour range kept for ' + layer0);
    else {
      if (JSON.stringify(s.appliedRange) !== JSON.stringify(first))
        fail(`the last frame was coloured over [${s.appliedRange}], not the first frame's [${first}]`);
      console.log(`colour range of ${layer0}: first frame [${first}], last frame's own [${h.color_range}], used [${s.appliedRange}]`);
      if (JSON.stringify(h.color_range) === JSON.stringify(first)) fail('the run never changed the range: the check above proves nothing');
      if (JSON.stringify(first) === '[0,1]') fail('the range was fixed before the map held data (the empty map\'s [0, 1])');
    }
    // A ground grid with round spacing, its spacing written in the legend.
    const spacing = s.gridSpacing;
    if (!(spacing > 0) || ![1, 2, 5].some((m) => near(spacing / Math.pow(10, Math.floor(Math.log10(spacing) + 1e-9)), m, 1e-9)))
      fail('no ground grid with a round spacing: ' + spacing);
    const gridText = await page.textContent('#grid-label');
    if (!gridText.includes(`${spacing} m`)) fail(`the legend does not give the grid spacing (${spacing} m): "${gridText}"`);
    console.log(gridText);
    if (!h.layers.includes('variance')) fail('no variance layer offered: ' + h.layers);
    // The page's own controls: colour by variance, then pause.
    await page.selectOption('#layer', 'variance');
    await page.waitForFunction(() => window.__terramap.header.color_layer === 'variance', null, { timeout: 20000 });
    await page.click('#play');
    await page.waitForFunction(() => window.__terramap.header.playing === false, null, { timeout: 20000 });
    // The user sets the range: it is used at once (paused, no new frame comes) and values above
    // it are flagged in the legend.
    await page.$eval('#lo', (e) => { e.value = '0'; e.dispatchEvent(new Event('change')); });
    await page.$eval('#hi', (e) => { e.value = '1e-6'; e.dispatchEvent(new Event('change')); });
    s = await page.evaluate(() => window.__terramap);
    if (JSON.stringify(s.appliedRange) !== JSON.stringify([0, 1e-6]) || JSON.stringify(s.ranges.variance) !== JSON.stringify([0, 1e-6]))
      fail(`the typed range [0, 1e-6] is not used: applied [${s.appliedRange}], kept [${s.ranges.variance}]`);
    const more = await page.$eval('#hi-more', (e) => getComputedStyle(e).visibility);
    if (more !== 'visible') fail('values above the typed range are not flagged in the legend');
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
