// End-to-end test of the trainee page against a running
// `cutsim-haptic --device browser --serve` station whose server simulates
// the ligament (scenes/ligament.pbtxt):
//
//   node web/trainee/test/trainee_test.mjs --url http://127.0.0.1:PORT/?token=T [--out DIR]
//        [--bench N] [--chromium PATH]
//
// Drives Debian's chromium headless through playwright-core (from
// web/observer's npm packages) at 1280×720: the page shows the tissue in
// 3-D with the scalpel beside (never under) its HUD; the mouse and keyboard
// bring the scalpel down beside the ligament, switch cutting on and draw it
// across, as scenes/ligament-cut.path does; turning the view moves no tool.
// Screenshots before and after the cut go to DIR (trainee-before.png,
// trainee-after.png). Plain WebSocket clients (ws) try a wrong token, a
// foreign Origin, a rebound Host, a second trainee, oversized and malformed
// messages. With --bench N, N mouse moves are timed from the input event to
// the first force frame computed from a pose that includes it.
// Prints `ok NAME` or `FAIL NAME: why` per check and a JSON summary line
// (also DIR/summary.json); exits 0 when every check passes, 1 otherwise.

import fs from 'node:fs';
import path from 'node:path';
import { createRequire } from 'node:module';
import { fileURLToPath } from 'node:url';

const here = path.dirname(fileURLToPath(import.meta.url));
const require = createRequire(path.join(here, '../../observer/package.json'));
const { chromium } = require('playwright-core');
const WebSocket = require('ws');

function parseArgs(argv) {
  const args = { url: null, out: null, bench: 0, chromium: '/usr/bin/chromium' };
  for (let i = 0; i < argv.length; ++i) {
    const value = () => argv[++i];
    switch (argv[i]) {
      case '--url': args.url = value(); break;
      case '--out': args.out = value(); break;
      case '--bench': args.bench = Number(value()); break;
      case '--chromium': args.chromium = value(); break;
      default:
        console.error(`trainee_test: unknown argument ${argv[i]}`);
        process.exit(2);
    }
  }
  if (!args.url) { console.error('usage: trainee_test.mjs --url URL [--out DIR] [--bench N]'); process.exit(2); }
  return args;
}

const args = parseArgs(process.argv.slice(2));
const url = new URL(args.url);
const token = url.searchParams.get('token');
const wsUrl = (t) => `ws://${url.host}/ws?token=${t}`;
const sleep = (ms) => new Promise((r) => setTimeout(r, ms));
const results = [];
function check(name, ok, why) {
  results.push({ name, ok, why: ok ? undefined : why });
  console.log(ok ? `ok ${name}` : `FAIL ${name}: ${why}`);
}

/// Opens a WebSocket; resolves {opened, status, closeCode}.
function tryWs(target, options = {}, onOpen = null) {
  return new Promise((resolve) => {
    const ws = new WebSocket(target, options);
    let opened = false;
    ws.on('unexpected-response', (req, res) => resolve({ opened: false, status: res.statusCode }));
    ws.on('error', () => resolve({ opened, status: 0 }));
    ws.on('open', () => { opened = true; if (onOpen) onOpen(ws); });
    ws.on('close', (code) => resolve({ opened, closeCode: code }));
  });
}

/// Pixel classes of the page's WebGL canvas (the observer test's rules).
function classifyCanvas() {
  const src = document.getElementById('view');
  const c = document.createElement('canvas');
  c.width = src.width;
  c.height = src.height;
  const g = c.getContext('2d');
  g.drawImage(src, 0, 0);
  const d = g.getImageData(0, 0, c.width, c.height).data;
  const counts = { pixels: c.width * c.height, tissue: 0, tool: 0, cut: 0 };
  for (let i = 0; i < d.length; i += 4) {
    const r = d[i], gr = d[i + 1], b = d[i + 2];
    const hi = Math.max(r, gr, b), lo = Math.min(r, gr, b);
    if (hi < 40 || hi === lo) continue;
    const delta = hi - lo;
    let hue = hi === r ? (60 * (gr - b)) / delta : hi === gr ? 60 * (2 + (b - r) / delta) : 60 * (4 + (r - gr) / delta);
    if (hue < 0) hue += 360;
    const sat = delta / hi;
    if ((hue >= 345 || hue <= 20) && sat >= 0.2 && sat <= 0.6) counts.tissue += 1;
    if (hue >= 195 && hue <= 250 && sat >= 0.04 && sat <= 0.22) counts.tool += 1;
    if (hue >= 30 && hue <= 65 && sat >= 0.6) counts.cut += 1;
  }
  return counts;
}

async function hostileChecks(page) {
  const wrongToken = await tryWs(wsUrl('0'.repeat(64)), { origin: url.origin });
  check('wrong-key-refused', !wrongToken.opened && wrongToken.status === 403, JSON.stringify(wrongToken));
  const foreign = await tryWs(wsUrl(token), { origin: 'http://evil.example' });
  check('foreign-origin-refused', !foreign.opened && foreign.status === 403, JSON.stringify(foreign));
  const rebound = await tryWs(wsUrl(token), { origin: `http://evil.example:${url.port}`,
    headers: { Host: `evil.example:${url.port}` } });
  check('rebound-host-refused', !rebound.opened && rebound.status === 403, JSON.stringify(rebound));
  const second = await tryWs(wsUrl(token), { origin: url.origin });
  check('second-trainee-refused', !second.opened && second.status === 503, JSON.stringify(second));
  // Through the page's own socket: malformed samples are refused and counted
  // (the haptic log shows them), the pose is unharmed.
  const before = await page.evaluate(() => window.trainee.state.frame.tip);
  await page.evaluate(() => {
    for (const m of ['p 1e9 nan 0 0 0 0 1 0', 'p 1e9 0.5 0.5 7 0 0 1 1', 'hello', '{"p":1}', 'p 1e9 0.5 0.5 0.5 0 0 0 1',
      'p 1e9 0.5 0.5 0.5 0 0 1 9']) window.trainee.sendRaw(m);
  });
  await sleep(300);
  const after = await page.evaluate(() => window.trainee.state.frame.tip);
  const moved = Math.hypot(after[0] - before[0], after[1] - before[1], after[2] - before[2]);
  check('malformed-messages-harmless', moved < 1e-4, `the tip moved ${moved} m`);
}

async function main() {
  const browser = await chromium.launch({
    executablePath: args.chromium,
    args: ['--headless=new', '--use-gl=swiftshader', '--enable-unsafe-swiftshader', '--no-sandbox'],
  });
  const page = await browser.newPage({ viewport: { width: 1280, height: 720 } });
  const errors = [];
  page.on('pageerror', (e) => errors.push(String(e)));
  await page.goto(args.url);
  await page.waitForFunction(() => window.trainee && window.trainee.stats.framesReceived > 5, null, { timeout: 15000 });
  check('page-connects', true);
  // The tissue from the session's mesh stream, the scalpel over it.
  await page.waitForFunction(() => window.trainee.stats.meshFrames >= 1, null, { timeout: 20000 }).catch(() => {});
  await sleep(500);
  const before = await page.evaluate(classifyCanvas);
  check('page-shows-tissue-and-blade', before.tissue >= 2000 && before.tool >= 30,
    `tissue pixels ${before.tissue} (need ≥ 2000), blade pixels ${before.tool} (need ≥ 30)`);
  if (args.out) await page.screenshot({ path: path.join(args.out, 'trainee-before.png') });
  const layout = await page.evaluate(() => {
    const h = document.getElementById('hud').getBoundingClientRect();
    const v = document.getElementById('view').getBoundingClientRect();
    const cues = ['force-bar', 'depth-bar'].map((id) => document.getElementById(id).parentElement.getBoundingClientRect());
    return { hudRight: h.right, viewLeft: v.left, viewWidth: v.width,
      cuesInView: cues.every((c) => c.bottom <= window.innerHeight && c.right <= window.innerWidth && c.width > 0) };
  });
  check('hud-beside-the-view', layout.hudRight <= layout.viewLeft + 0.5 && layout.viewWidth >= 900 && layout.cuesInView,
    JSON.stringify(layout));

  const to = (x, y) => page.evaluate(([a, b]) => window.trainee.toClient(a, b), [x, y]);
  // Above the start of the cut, then down to z = −6 mm beside the ligament
  // (the arrow keys step 1 mm from the top of the workspace at +20 mm).
  let p = await to(0.0163, -0.008);
  await page.mouse.move(p.x, p.y, { steps: 10 });
  await page.focus('#view');
  for (let i = 0; i < 26; ++i) { await page.keyboard.press('ArrowDown'); await sleep(15); }
  // The station follows the page one input period behind: wait for it.
  await page.waitForFunction(() => Math.abs(window.trainee.state.frame.tip[2] + 0.006) < 3e-4, null,
    { timeout: 5000 }).catch(() => {});
  const depth = await page.evaluate(() => window.trainee.state.frame.tip[2]);
  const commanded = await page.evaluate(() => ({ w: window.trainee.state.w, sent: window.trainee.stats.samplesSent }));
  check('keys-set-the-depth', Math.abs(depth + 0.006) < 3e-4, `tip z ${depth} m (commanded ${JSON.stringify(commanded)})`);
  // Cut: hold Space and draw across the ligament along +y over 2 s.
  await page.keyboard.down('Space');
  for (let i = 0; i <= 100; ++i) {
    p = await to(0.0163, -0.008 + 0.016 * i / 100);
    await page.mouse.move(p.x, p.y);
    await sleep(20);
  }
  const fps = await page.evaluate(() => window.trainee.stats.fps);  // drawn per second while the tool moves
  await page.waitForFunction(() => window.trainee.stats.maxCuts >= 1, null, { timeout: 5000 }).catch(() => {});
  await page.keyboard.up('Space');
  for (let i = 0; i < 26; ++i) { await page.keyboard.press('ArrowUp'); await sleep(10); }
  await sleep(500);
  const after = await page.evaluate(classifyCanvas);
  if (args.out) await page.screenshot({ path: path.join(args.out, 'trainee-after.png') });
  const s = await page.evaluate(() => window.trainee.stats);
  check('opened-faces-shown', s.openedCount >= 1 && after.cut >= 1,
    `opened faces in the mesh ${s.openedCount}, cut-colour pixels ${after.cut}`);
  check('force-bar-shown', s.maxForceSeen > 0.05, `max force seen ${s.maxForceSeen} N`);
  check('page-shows-the-cut', s.maxCuts >= 1, `cuts shown ${s.maxCuts}`);
  const bar = await page.evaluate(() => document.getElementById('cuts').textContent);
  check('cut-count-on-page', Number(bar) >= 1, `#cuts shows ${bar}`);
  // Turning the view (keys, as the right button does) moves no tool.
  const sent = await page.evaluate(() => window.trainee.stats.samplesSent);
  const viewBefore = await page.evaluate(() => document.getElementById('view-state').textContent);
  for (const key of ['l', 'l', 'i']) await page.keyboard.press(key);
  await sleep(200);
  const turned = await page.evaluate(() => ({ sent: window.trainee.stats.samplesSent,
    view: document.getElementById('view-state').textContent }));
  check('view-turns-without-moving-the-tool', turned.sent === sent && turned.view !== viewBefore,
    JSON.stringify({ ...turned, before: viewBefore, sentBefore: sent }));
  for (const key of ['k', 'j', 'j']) await page.keyboard.press(key);

  await hostileChecks(page);

  let bench = null;
  if (args.bench > 0) {
    await page.evaluate(() => { window.trainee.stats.latencyMs = []; window.trainee.stats.pending = []; });
    // Above the ligament (the tip is back at +20 mm), inside the view.
    const a = await to(0.01, 0.0);
    const b = await to(0.02, 0.0);
    for (let i = 0; i < args.bench; ++i) {
      const f = 0.5 + 0.5 * Math.sin(i / 10);
      await page.mouse.move(a.x + f * (b.x - a.x), a.y);
      await sleep(8 + (i % 9));  // ~60–120 Hz, off the frame clock
    }
    await sleep(300);
    const lat = (await page.evaluate(() => window.trainee.stats.latencyMs)).slice().sort((a, b) => a - b);
    const q = (f) => lat[Math.min(lat.length - 1, Math.floor(f * lat.length))];
    const r = (x) => Math.round(x * 100) / 100;
    bench = { kind: 'trainee_latency', inputs: args.bench, samples: lat.length, p10_ms: r(q(0.1)), p50_ms: r(q(0.5)),
      p90_ms: r(q(0.9)), p99_ms: r(q(0.99)), max_ms: r(lat[lat.length - 1]) };
    check('latency-measured', lat.length >= args.bench * 0.9, `${lat.length} of ${args.bench} inputs timed`);
  }
  // An oversized message closes the trainee's socket; the slot is free again.
  await page.evaluate(() => window.trainee.sendRaw('p'.repeat(4096)));
  await page.waitForFunction(() => window.trainee.stats.closeCode !== null, null, { timeout: 5000 }).catch(() => {});
  const closed = await page.evaluate(() => window.trainee.stats.closeCode);
  check('oversized-message-closes', closed !== null, 'the page is still connected');
  const next = await tryWs(wsUrl(token), { origin: url.origin }, (ws) => setTimeout(() => ws.close(), 200));
  check('slot-free-after-close', next.opened, JSON.stringify(next));
  check('page-reports-no-errors', errors.length === 0, errors.join('; '));
  await browser.close();
  const summary = { kind: 'trainee_test', passed: results.every((r) => r.ok), results, latency: bench,
    view_fps: Math.round(fps * 10) / 10, pixels_before: before, pixels_after: after };
  if (args.out) fs.writeFileSync(path.join(args.out, 'summary.json'), JSON.stringify(summary, null, 1));
  console.log(JSON.stringify(bench ?? summary));
  process.exit(summary.passed ? 0 : 1);
}

main().catch((e) => { console.error(`FAIL trainee_test: ${e.stack || e}`); process.exit(1); });
