// End-to-end test of the observer page against a running bridge
// (`cutsim-viewer --serve`) that streams a session in which a scripted
// scalpel cuts the tissue:
//
//   node web/observer/test/observer_test.mjs --url http://127.0.0.1:PORT/ [--token T] [--out DIR]
//        [--ready-file PATH] [--chromium PATH]
//
// Drives Debian's chromium (/usr/bin/chromium, WebGL through SwiftShader) with
// playwright-core, and plain WebSocket clients (ws) for the load and
// hostile-input checks. Prints `ok NAME` or `FAIL NAME: why` per check and a
// final JSON summary line (also written to DIR/summary.json with the
// screenshots); exits 0 when every check passes, 1 otherwise, 2 on bad usage.
//
// Checks: page-loads, canvas-shows-tissue-and-scalpel, planned-line-drawn,
// view-updates-as-tool-moves, view-updates-after-cut, late-joiner-catches-up,
// twenty-clients, hostile-input-refused, page-reports-no-errors.
//
// The session is short (seconds), so the checks that need it live run early
// and side by side: the page checks (screenshots, tool motion, the cut, the
// late joiner) in one sequence, the WebSocket checks in another, where the
// hostile clients come and go while the twenty clients are held open. The
// motion check needs the tool to move after the first page has connected;
// --ready-file PATH is created at that moment so that a driving script can
// start the scripted scalpel then.

import fs from 'node:fs';
import path from 'node:path';
import zlib from 'node:zlib';
import { chromium } from 'playwright-core';
import WebSocket from 'ws';

// ---------------------------------------------------------------------------
// Arguments

function parseArgs(argv) {
  const args = { url: null, token: null, out: null, readyFile: null, chromium: '/usr/bin/chromium' };
  for (let i = 0; i < argv.length; ++i) {
    const value = () => {
      if (i + 1 >= argv.length) usage(`${argv[i]} needs a value`);
      return argv[++i];
    };
    switch (argv[i]) {
      case '--url': args.url = value(); break;
      case '--token': args.token = value(); break;
      case '--out': args.out = value(); break;
      case '--ready-file': args.readyFile = value(); break;
      case '--chromium': args.chromium = value(); break;
      case '-h': case '--help': usage(null); break;
      default: usage(`unknown argument ${argv[i]}`);
    }
  }
  if (!args.url) usage('--url is required');
  return args;
}

function usage(problem) {
  if (problem) console.error(`observer_test: ${problem}`);
  console.error('usage: node observer_test.mjs --url http://HOST:PORT/ [--token T] [--out DIR] [--ready-file PATH] [--chromium PATH]');
  console.error('  --ready-file PATH: created once the first page shows the session, so that a driving script can');
  console.error('                     start the scripted scalpel only then (the motion check needs a moving tool)');
  process.exit(2);
}

const args = parseArgs(process.argv.slice(2));
const pageUrl = new URL(args.url);
if (args.token !== null && !pageUrl.searchParams.has('token')) pageUrl.searchParams.set('token', args.token);
const token = args.token ?? pageUrl.searchParams.get('token');

/** The bridge's WebSocket URL, with `tokenValue` as its token (null: none). */
function socketUrl(tokenValue = token) {
  const u = new URL('/ws', pageUrl);
  u.protocol = pageUrl.protocol === 'https:' ? 'wss:' : 'ws:';
  if (tokenValue !== null) u.searchParams.set('token', tokenValue);
  return u.toString();
}

if (args.out) fs.mkdirSync(args.out, { recursive: true });

function writeOut(name, data) {
  if (args.out) fs.writeFileSync(path.join(args.out, name), data);
}

// ---------------------------------------------------------------------------
// Reporting

const results = {};
const startedMs = Date.now();

function report(name, ok, why = '', details = {}) {
  results[name] = { ok, ...(ok ? {} : { why }), atMs: Date.now() - startedMs, ...details };
  console.log(ok ? `ok ${name}` : `FAIL ${name}: ${why}`);
}

/** Runs one check; an exception fails it with its message. */
async function check(name, body) {
  try {
    await body();
  } catch (error) {
    if (!(name in results)) report(name, false, String(error?.message ?? error).split('\n')[0]);
  }
}

const sleep = (ms) => new Promise((resolve) => setTimeout(resolve, ms));

// ---------------------------------------------------------------------------
// PNG decoding (8-bit RGB or RGBA, not interlaced: what chromium writes)

/** Decodes a PNG into {width, height, rgba: Uint8Array}. */
function decodePng(buffer) {
  const signature = Buffer.from([137, 80, 78, 71, 13, 10, 26, 10]);
  if (!buffer.subarray(0, 8).equals(signature)) throw new Error('not a PNG');
  let offset = 8;
  let width = 0, height = 0, colourType = 0;
  const idat = [];
  while (offset < buffer.length) {
    const length = buffer.readUInt32BE(offset);
    const type = buffer.toString('latin1', offset + 4, offset + 8);
    const data = buffer.subarray(offset + 8, offset + 8 + length);
    if (type === 'IHDR') {
      width = data.readUInt32BE(0);
      height = data.readUInt32BE(4);
      const bitDepth = data[8];
      colourType = data[9];
      if (bitDepth !== 8 || (colourType !== 2 && colourType !== 6) || data[12] !== 0) {
        throw new Error(`unsupported PNG (bit depth ${bitDepth}, colour type ${colourType}, interlace ${data[12]})`);
      }
    } else if (type === 'IDAT') {
      idat.push(data);
    } else if (type === 'IEND') {
      break;
    }
    offset += 12 + length;
  }
  const channels = colourType === 6 ? 4 : 3;
  const stride = width * channels;
  const raw = zlib.inflateSync(Buffer.concat(idat));
  const pixels = new Uint8Array(stride * height);
  for (let y = 0; y < height; ++y) {
    const filter = raw[y * (stride + 1)];
    const line = raw.subarray(y * (stride + 1) + 1, (y + 1) * (stride + 1));
    const out = pixels.subarray(y * stride, (y + 1) * stride);
    const prev = y > 0 ? pixels.subarray((y - 1) * stride, y * stride) : null;
    for (let x = 0; x < stride; ++x) {
      const a = x >= channels ? out[x - channels] : 0;
      const b = prev ? prev[x] : 0;
      const c = prev && x >= channels ? prev[x - channels] : 0;
      let predictor;
      switch (filter) {
        case 0: predictor = 0; break;
        case 1: predictor = a; break;
        case 2: predictor = b; break;
        case 3: predictor = (a + b) >> 1; break;
        case 4: {
          const p = a + b - c;
          const pa = Math.abs(p - a), pb = Math.abs(p - b), pc = Math.abs(p - c);
          predictor = pa <= pb && pa <= pc ? a : pb <= pc ? b : c;
          break;
        }
        default: throw new Error(`bad PNG filter ${filter}`);
      }
      out[x] = (line[x] + predictor) & 0xff;
    }
  }
  const rgba = new Uint8Array(width * height * 4);
  for (let i = 0; i < width * height; ++i) {
    rgba[4 * i] = pixels[channels * i];
    rgba[4 * i + 1] = pixels[channels * i + 1];
    rgba[4 * i + 2] = pixels[channels * i + 2];
    rgba[4 * i + 3] = channels === 4 ? pixels[channels * i + 3] : 255;
  }
  return { width, height, rgba };
}

// ---------------------------------------------------------------------------
// Pixel classes. Lighting scales a base colour's brightness but keeps its hue
// and saturation (the page lights as common/render/palette.h describes), so
// the classes test hue and saturation, with a floor on the largest channel.

/** HSV hue in degrees [0, 360) and saturation [0, 1]; hue 0 for greys. */
function hueSaturation(r, g, b) {
  const hi = Math.max(r, g, b), lo = Math.min(r, g, b);
  if (hi === 0 || hi === lo) return { hue: 0, saturation: 0 };
  const delta = hi - lo;
  let hue;
  if (hi === r) hue = (60 * (g - b)) / delta;
  else if (hi === g) hue = 60 * (2 + (b - r) / delta);
  else hue = 60 * (4 + (r - g) / delta);
  if (hue < 0) hue += 360;
  return { hue, saturation: delta / hi };
}

const CLASSES = {
  // #e4988e: hue ≈ 7°, saturation ≈ 0.38.
  tissue: (r, g, b, hs) => Math.max(r, g, b) >= 40 && (hs.hue >= 345 || hs.hue <= 20) &&
    hs.saturation >= 0.2 && hs.saturation <= 0.6,
  // #b4bcce: hue ≈ 222°, saturation ≈ 0.13 (the background #1e222c has 0.32).
  tool: (r, g, b, hs) => Math.max(r, g, b) >= 40 && hs.hue >= 195 && hs.hue <= 250 &&
    hs.saturation >= 0.04 && hs.saturation <= 0.22,
  // #ebb91e: hue ≈ 45°, saturation ≈ 0.87 (the C++ IsCutFaceColour rule).
  cut: (r, g, b, hs) => Math.max(r, g, b) >= 40 && hs.hue >= 30 && hs.hue <= 65 && hs.saturation >= 0.6,
  // #3cc85a: hue ≈ 133°, saturation ≈ 0.70 (the C++ IsForceColour rule).
  force: (r, g, b, hs) => Math.max(r, g, b) >= 40 && hs.hue >= 100 && hs.hue <= 165 && hs.saturation >= 0.5,
  // #4fc3f7 (web/common/plan_line.js): hue ≈ 199°, saturation ≈ 0.68.
  plan: (r, g, b, hs) => Math.max(r, g, b) >= 80 && hs.hue >= 185 && hs.hue <= 215 && hs.saturation >= 0.45,
};

/** Pixel counts per class of a decoded image. */
function classify(image) {
  const counts = { pixels: image.width * image.height, tissue: 0, tool: 0, cut: 0, force: 0, plan: 0 };
  const { rgba } = image;
  for (let i = 0; i < rgba.length; i += 4) {
    const r = rgba[i], g = rgba[i + 1], b = rgba[i + 2];
    const hs = hueSaturation(r, g, b);
    for (const [name, test] of Object.entries(CLASSES)) {
      if (test(r, g, b, hs)) counts[name] += 1;
    }
  }
  return counts;
}

// ---------------------------------------------------------------------------
// Page helpers

const state = (page) => page.evaluate(() => {
  const s = window.cutsimObserver?.state;
  return s ? JSON.parse(JSON.stringify(s)) : null;
});

/** Waits until `predicate(state)` (a page-side function source) holds. */
function waitState(page, predicateSource, timeoutMs, arg) {
  return page.waitForFunction(
    ([source, a]) => {
      const s = window.cutsimObserver?.state;
      return s ? new Function('s', 'arg', `return (${source})(s, arg);`)(s, a) : false;
    },
    [predicateSource, arg ?? null], { timeout: timeoutMs, polling: 50 });
}

/** The WebGL canvas as PNG bytes, its decoded pixels and their classes. */
async function canvasImage(page, name) {
  const dataUrl = await page.evaluate(() => document.getElementById('view').toDataURL('image/png'));
  const png = Buffer.from(dataUrl.slice(dataUrl.indexOf(',') + 1), 'base64');
  if (name) writeOut(`${name}.png`, png);
  const image = decodePng(png);
  return { png, image, counts: classify(image) };
}

async function screenshot(page, name) {
  const png = await page.screenshot({ type: 'png' });
  writeOut(`${name}.png`, png);
  return png;
}

/**
 * Makes the page sample itself every 100 ms from its first frame on (tool
 * tip, session clock and a hash of the canvas shrunk to 96×60) into
 * window.__observerSamples, for the motion check: the scripted tool moves for
 * a few seconds only, so sampling starts before the test looks.
 */
function installSampler(page) {
  return page.addInitScript(() => {
    const small = document.createElement('canvas');
    small.width = 96;
    small.height = 60;
    const ctx = small.getContext('2d', { willReadFrequently: true });
    window.__observerSamples = [];
    setInterval(() => {
      const s = window.cutsimObserver?.state;
      const view = document.getElementById('view');
      if (!s || !view || s.rendered === 0) return;
      ctx.drawImage(view, 0, 0, small.width, small.height);
      const data = ctx.getImageData(0, 0, small.width, small.height).data;
      let hash = 2166136261;
      for (let i = 0; i < data.length; ++i) hash = Math.imul(hash ^ data[i], 16777619) >>> 0;
      window.__observerSamples.push({
        t: performance.now(), tip: s.tool ? { ...s.tool.tip } : null, simTime: s.simTime, hash, rendered: s.rendered,
      });
      if (window.__observerSamples.length > 600) window.__observerSamples.shift();  // the last minute
    }, 100);
  });
}

/** Attaches listeners that collect the page's uncaught errors and console errors. */
function watchPage(page, label, sink) {
  page.on('pageerror', (error) => sink.push(`${label}: page error: ${error.message}`));
  page.on('console', (message) => {
    if (message.type() === 'error') sink.push(`${label}: console: ${message.text()}`);
  });
}

// ---------------------------------------------------------------------------
// WebSocket helpers

/**
 * Opens a WebSocket and records what happens to it: open, hello, snapshots,
 * session messages, close (code) and upgrade refusal (HTTP status).
 */
function openClient(url, options = {}) {
  const ws = new WebSocket(url, { handshakeTimeout: 5000, ...options });
  const c = {
    ws, opened: false, hello: false, snapshots: 0, updates: 0, sessions: 0,
    closed: false, closeCode: null, refused: null, error: null,
  };
  c.done = new Promise((resolve) => {
    ws.on('open', () => { c.opened = true; });
    ws.on('message', (data, isBinary) => {
      if (isBinary) {
        const bytes = Buffer.isBuffer(data) ? data : Buffer.concat(data);
        if (bytes[0] === 1) c.snapshots += 1;
        else if (bytes[0] === 2) c.updates += 1;
        return;
      }
      try {
        const m = JSON.parse(data.toString());
        if (m.type === 'hello') c.hello = true;
        if (m.type === 'session') c.sessions += 1;
      } catch { /* counted as neither */ }
    });
    ws.on('unexpected-response', (req, res) => {
      c.refused = res.statusCode;
      req.destroy();
      resolve();
    });
    ws.on('error', (error) => { c.error = error.message; if (!c.opened) resolve(); });
    ws.on('close', (code) => { c.closed = true; c.closeCode = code; resolve(); });
  });
  return c;
}

/** Waits until `condition()` holds or `timeoutMs` passes; returns whether it held. */
async function until(condition, timeoutMs, stepMs = 50) {
  const end = Date.now() + timeoutMs;
  while (Date.now() < end) {
    if (condition()) return true;
    await sleep(stepMs);
  }
  return condition();
}

const whenSettled = (c, timeoutMs) => Promise.race([c.done, sleep(timeoutMs)]);

// ---------------------------------------------------------------------------
// Checks

const CHROMIUM_ARGS = ['--headless=new', '--use-gl=swiftshader', '--enable-unsafe-swiftshader', '--no-sandbox'];
const VIEWPORT = { width: 1280, height: 720 };
const pageErrors = [];

async function main() {
  let browser = null;
  const clients = [];
  try {
    browser = await chromium.launch({ executablePath: args.chromium, args: CHROMIUM_ARGS });
    const first = await browser.newPage({ viewport: VIEWPORT });
    watchPage(first, 'page 1', pageErrors);
    await installSampler(first);

    // 1. The page connects and receives a snapshot.
    let loaded = false;
    await check('page-loads', async () => {
      const t0 = Date.now();
      await first.goto(pageUrl.toString(), { waitUntil: 'load', timeout: 10000 });
      await waitState(first, '(s) => s.connected && s.snapshots > 0', Math.max(1, 10000 - (Date.now() - t0)));
      const s = await state(first);
      loaded = true;
      report('page-loads', true, '', { ms: Date.now() - t0, vertices: s.vertexCount, triangles: s.triangleCount });
    });
    if (!loaded) {
      for (const name of ['canvas-shows-tissue-and-scalpel', 'planned-line-drawn', 'hud-beside-the-view', 'view-updates-as-tool-moves',
        'view-updates-after-cut',
        'late-joiner-catches-up', 'twenty-clients', 'hostile-input-refused', 'page-reports-no-errors']) {
        report(name, false, 'skipped: the page did not load');
      }
      return;
    }
    if (args.readyFile) fs.writeFileSync(args.readyFile, `${new Date().toISOString()}\n`);

    const pageChecks = (async () => {
      // 2. Tissue and scalpel are on the canvas.
      await check('canvas-shows-tissue-and-scalpel', async () => {
        await waitState(first, '(s) => s.rendered > 0 && s.tool !== null', 5000);
        await sleep(200);  // let the frame after the tool's first placement land
        await screenshot(first, 'page1-start');
        const { counts } = await canvasImage(first, 'page1-canvas-start');
        const ok = counts.tissue >= 500 && counts.tool >= 30;
        report('canvas-shows-tissue-and-scalpel', ok,
          `tissue pixels ${counts.tissue} (need ≥ 500), scalpel pixels ${counts.tool} (need ≥ 30)`, { counts });
      });
      // The planned incision, as the trainee's page draws it: the session's
      // plan (the ligament's two points) on the page and its colour on the
      // canvas.
      await check('planned-line-drawn', async () => {
        await waitState(first, '(s) => Array.isArray(s.plan) && s.plan.length >= 2', 3000);
        await sleep(200);  // the frame after the line was added
        const { plan } = await state(first);
        const { counts } = await canvasImage(first, 'page1-canvas-plan');
        const length = Math.hypot(...[0, 1, 2].map((k) => plan[plan.length - 1][k] - plan[0][k]));
        report('planned-line-drawn', counts.plan >= 20 && length > 0.001,
          `plan ${JSON.stringify(plan)} (${(1e3 * length).toFixed(1)} mm), its pixels ${counts.plan} (need ≥ 20)`,
          { plan, counts });
      });
      // The HUD is beside the view, never over the tissue.
      await check('hud-beside-the-view', async () => {
        const r = await first.evaluate(() => {
          const h = document.getElementById('hud').getBoundingClientRect();
          const v = document.getElementById('view').getBoundingClientRect();
          return { hudRight: h.right, hudBottom: h.bottom, viewLeft: v.left, viewWidth: v.width,
            height: window.innerHeight };
        });
        report('hud-beside-the-view', r.hudRight <= r.viewLeft + 0.5 && r.hudBottom <= r.height && r.viewWidth >= 900,
          JSON.stringify(r), r);
      });

      // 3. The picture and the tool tip change as the scalpel moves.
      await check('view-updates-as-tool-moves', async () => {
        const deadline = Date.now() + 6000;
        let found = null;
        let sampleCount = 0;
        while (!found && Date.now() < deadline) {
          await sleep(250);
          const samples = await first.evaluate(() => window.__observerSamples);
          sampleCount = samples.length;
          const last = samples[samples.length - 1];
          if (!last?.tip) continue;
          for (const earlier of samples) {
            if (last.t - earlier.t < 500) break;
            if (!earlier.tip) continue;
            const moved = Math.hypot(last.tip.x - earlier.tip.x, last.tip.y - earlier.tip.y, last.tip.z - earlier.tip.z);
            if (moved > 1e-6 && last.hash !== earlier.hash) {
              found = { apartMs: Math.round(last.t - earlier.t), tipMovedMm: +(1000 * moved).toFixed(3),
                simTimes: [earlier.simTime, last.simTime] };
              break;
            }
          }
        }
        report('view-updates-as-tool-moves', !!found,
          `no two samples ≥ 0.5 s apart with a moved tip and a different picture (${sampleCount} samples)`, found ?? {});
      });

      // 4. The cut is counted, faces open and the cut colour shows.
      await check('view-updates-after-cut', async () => {
        const cutDeadline = startedMs + 15000;
        await waitState(first, '(s) => s.cuts >= 1', Math.max(1, cutDeadline - Date.now()));
        await waitState(first, '(s) => s.openedCount > 0', 5000);
        // The cut opens over a fraction of a second; look until amber shows.
        let counts = null;
        const end = Date.now() + 5000;
        do {
          await sleep(250);
          ({ counts } = await canvasImage(first, null));
        } while (counts.cut < 20 && Date.now() < end);
        await canvasImage(first, 'page1-canvas-cut');
        await screenshot(first, 'page1-cut');
        const s = await state(first);
        report('view-updates-after-cut', counts.cut >= 20,
          `${counts.cut} cut-face pixels (need ≥ 20) with ${s.openedCount} opened faces`,
          { cuts: s.cuts, openedCount: s.openedCount, counts });
      });

      // 4b. The session's measures arrive and read as a cut does: the tip
      // travelled, touched, pushed, and stressed the tissue; the HUD shows them.
      await check('session-measures-shown', async () => {
        await waitState(first, '(s) => s.metrics && s.metrics.contactTime > 0 && s.metrics.maxStressOutside > 0', 5000);
        const s = await state(first);
        const m = s.metrics;
        const text = await first.evaluate(() => ({
          peak: document.getElementById('hud-peak-force').textContent,
          path: document.getElementById('hud-path').textContent,
          stress: document.getElementById('hud-stress').textContent,
        }));
        const ok = m.pathLength > 0 && m.peakForce > 0 && m.meanForce > 0 && m.meanForce <= m.peakForce &&
          m.contactTime > 0 && m.contactTime <= s.simTime && m.maxStressOutside >= m.stressOutside &&
          /\d mm$/.test(text.path) && /\d N$/.test(text.peak) && /kPa/.test(text.stress);
        report('session-measures-shown', ok, `measures ${JSON.stringify(m)}, HUD ${JSON.stringify(text)}`,
          { metrics: m, hud: text });
      });

      // 5. A page opened now draws the session at once and keeps up. The
      // limit applies from the moment the page starts to connect (the
      // bridge's part: the held snapshot at once; the page's: draw it); the
      // times from page creation and from navigation start, which add the
      // browser's own start-up and the script downloads, are reported too.
      await check('late-joiner-catches-up', async () => {
        const createdMs = Date.now();
        const late = await browser.newPage({ viewport: VIEWPORT });
        watchPage(late, 'page 2', pageErrors);
        try {
          await late.goto(pageUrl.toString(), { waitUntil: 'load', timeout: 10000 });
          await waitState(late, '(s) => s.rendered > 0', 10000);
          const timing = await late.evaluate(() => {
            const s = window.cutsimObserver.state;
            return {
              origin: performance.timeOrigin, firstRenderMs: s.firstRenderMs,
              connectStartMs: s.connectStartMs, connectedMs: s.connectedMs,
            };
          });
          const joinMs = Math.round(timing.firstRenderMs - timing.connectStartMs);
          const fromCreationMs = Math.round(timing.origin + timing.firstRenderMs - createdMs);
          const fromNavigationMs = Math.round(timing.firstRenderMs);
          await sleep(300);
          const [a, b] = await Promise.all([state(first), state(late)]);
          const skew = Math.abs(a.simTime - b.simTime);
          await screenshot(late, 'page2-late');
          // A late joiner must get its snapshot and follow the session; how
          // fast is the observer benchmark's to measure (a loaded test
          // machine takes over a second), so the bound here only catches a
          // page that never catches up.
          const ok = joinMs <= 5000 && skew <= 0.5;
          report('late-joiner-catches-up', ok,
            `first render ${joinMs} ms after the page began to connect (need ≤ 5000), ` +
            `clock skew ${skew.toFixed(3)} s (need ≤ 0.5)`,
            { joinMs, socketOpenMs: Math.round(timing.connectedMs - timing.connectStartMs),
              fromNavigationMs, fromCreationMs, simTimes: [a.simTime, b.simTime] });
          pageErrors.push(...b.errors.map((e) => `page 2: ${e}`));
        } finally {
          await late.close();
        }
      });
    })();

    // 6 and 7. Twenty plain clients are served side by side; while they are
    // held open, hostile clients come and go, and neither the twenty nor the
    // page may notice.
    const socketChecks = (async () => {
      const group = Array.from({ length: 20 }, () => openClient(socketUrl()));
      clients.push(...group);
      const served = (c) => c.opened && c.hello && c.snapshots >= 1 && c.sessions >= 1;
      const allServed = await until(() => group.every(served), 5000);
      const holdEnd = Date.now() + 2000;
      const hostile = check('hostile-input-refused', () => hostileClients());
      await sleep(Math.max(0, holdEnd - Date.now()));
      await check('twenty-clients', async () => {
        const closed = group.filter((c) => c.closed).length;
        const notServed = group.filter((c) => !served(c)).length;
        report('twenty-clients', allServed && closed === 0,
          `${notServed} of 20 not served (hello, snapshot and session), ${closed} closed within 2 s`,
          { sessionsMin: Math.min(...group.map((c) => c.sessions)),
            snapshotsMin: Math.min(...group.map((c) => c.snapshots)),
            closeCodes: group.filter((c) => c.closed).map((c) => c.closeCode) });
      });
      for (const c of group) c.ws.close();
      await hostile;
    })();

    /** Check 7: oversized, malformed, cross-origin and unauthenticated clients. */
    async function hostileClients() {
      const before = (await state(first)).framesReceived;
      const problems = [];
      const details = {};
      /** Opens a client and waits until it is open or refused. */
      const connectClient = async (url, options) => {
        const c = openClient(url, options);
        clients.push(c);
        await until(() => c.opened || c.closed || c.refused !== null || c.error !== null, 5000);
        return c;
      };
      /** Describes how a refused upgrade ended. */
      const refusal = (c) => (c.refused !== null ? `HTTP ${c.refused}`
        : c.error ?? (c.closed ? `closed ${c.closeCode}` : 'no answer'));

      const [big, junk, evil] = await Promise.all([
        connectClient(socketUrl()),
        connectClient(socketUrl()),
        connectClient(socketUrl(), { origin: 'http://evil.example' }),
      ]);

      if (!big.opened) {
        problems.push('oversized: could not connect');
      } else {
        big.ws.send(Buffer.alloc(2 * 1024 * 1024, 0x5a), { binary: true }, () => {});
      }
      if (!junk.opened) {
        problems.push('malformed: could not connect');
      } else {
        junk.ws.send('{"type": "session", this is not json', () => {});
        junk.ws.send(Buffer.from([0xff, 0x00, 0x13, 0x37]), { binary: true }, () => {});
      }
      details.crossOrigin = refusal(evil);
      if (evil.opened) problems.push('cross-origin: the upgrade succeeded');
      else if (evil.refused === null && evil.error === null && !evil.closed) problems.push('cross-origin: no answer');

      if (token !== null) {
        for (const [label, value] of [['noToken', null], ['wrongToken', `${token}x`]]) {
          const c = await connectClient(socketUrl(value));
          details[label] = refusal(c);
          if (c.opened) problems.push(`${label}: the upgrade succeeded`);
          else if (c.refused === null && c.error === null && !c.closed) problems.push(`${label}: no answer`);
        }
      }

      if (big.opened) {
        await whenSettled(big, 5000);
        details.oversized = big.closed ? `closed ${big.closeCode}` : 'still open';
        if (!big.closed) problems.push('oversized: a 2 MiB message did not close the connection');
      }
      if (junk.opened) {
        await whenSettled(junk, 500);
        details.malformed = junk.closed ? `closed ${junk.closeCode}` : 'ignored';
      }

      // The bridge still serves: a fresh client gets its hello, the page its frames.
      const fresh = openClient(socketUrl());
      clients.push(fresh);
      if (!(await until(() => fresh.hello, 3000))) problems.push('afterwards: a new client got no hello');
      fresh.ws.close();
      // Judged on the page's own count: under load the polling of
      // waitForFunction can lag the frames by seconds.
      try {
        await waitState(first, '(s, before) => s.framesReceived > before', 10000, before);
      } catch {
        // the count below decides
      }
      if ((await state(first)).framesReceived <= before) {
        problems.push(`afterwards: the page received no frame (framesReceived stayed ${before})`);
      }
      details.pageFramesMeanwhile = (await state(first)).framesReceived - before;
      report('hostile-input-refused', problems.length === 0, problems.join('; '), details);
    }

    await Promise.all([pageChecks, socketChecks]);

    // 8. Neither page saw a protocol error, an uncaught exception or a console error.
    await check('page-reports-no-errors', async () => {
      const s = await state(first);
      const all = [...s.errors.map((e) => `page 1: ${e}`), ...pageErrors];
      report('page-reports-no-errors', all.length === 0, `${all.length} error(s): ${all.slice(0, 3).join(' | ')}`,
        { errors: all.slice(0, 20), page1: { framesReceived: s.framesReceived, droppedFrames: s.droppedFrames, rendered: s.rendered } });
    });
  } catch (error) {
    report('harness', false, String(error?.message ?? error).split('\n')[0]);
  } finally {
    for (const c of clients) c.ws.terminate();
    if (browser) await browser.close().catch(() => {});
  }
}

await main();
const names = Object.keys(results);
const failed = names.filter((n) => !results[n].ok);
const summary = { passed: names.length - failed.length, failed: failed.length, failures: failed, checks: results };
writeOut('summary.json', `${JSON.stringify(summary, null, 2)}\n`);
console.log(JSON.stringify(summary));
process.exit(failed.length === 0 ? 0 : 1);
