// A trainee incises the skin pad from the trainee page, against a running
// `cutsim-haptic --device browser --serve` station whose server simulates
// scenes/skin_pad.pbtxt:
//
//   node web/trainee/test/incision_test.mjs --url http://127.0.0.1:PORT/?token=T [--out DIR]
//        [--bench N] [--chromium PATH]
//
// Drives Debian's chromium headless through playwright-core at 1280×720 as
// a trainee would: the page shows the pad, the scalpel and the planned
// incision (the blue line, found in the picture where the page says it
// draws it); the mouse goes to the line's start, Space is held, ↓ brings
// the tip 3 mm deep (through the 2 mm of skin), the mouse is drawn along
// the line to its end in about 2.4 s, Space is released and ↑ lifts the
// blade out. Screenshots before and after the cut go to DIR
// (incision-before.png, incision-after.png). The server's report and final
// mesh are checked by tests/integration/trainee_incision_test.sh.
//
// With --bench N, N more mouse moves over the pad are timed from the input
// event to the first force frame from a pose that includes it (input to
// force) and to the animation frame after the one that drew that pose
// (input to picture); the last line on stdout is that JSON.
// Prints `ok NAME` or `FAIL NAME: why` per check and a JSON summary line
// (also DIR/summary.json); exits 0 when every check passes, 1 otherwise.

import fs from 'node:fs';
import path from 'node:path';
import { check, classifyCanvas, openTraineePage, parseArgs, quantiles, results, sleep } from './page.mjs';

const args = parseArgs(process.argv.slice(2),
  'incision_test.mjs --url URL [--out DIR] [--bench N] [--chromium PATH]');
const kDepth = -0.003;        // m, the tip's depth while cutting (world z; the skin's top is at 0)
const kSteps = 120;           // mouse moves along the line
const kStepMs = 20;           // ms between them (plus each move's own round trip)

/** Runs in the page: plan-coloured pixels within `r` px of client point (x, y). */
function planPixelsNear([x, y, r]) {
  const src = document.getElementById('view');
  const box = src.getBoundingClientRect();
  const scale = src.width / box.width;
  const cx = Math.round((x - box.left) * scale), cy = Math.round((y - box.top) * scale), R = Math.ceil(r * scale);
  const c = document.createElement('canvas');
  c.width = 2 * R + 1;
  c.height = 2 * R + 1;
  const g = c.getContext('2d');
  g.drawImage(src, cx - R, cy - R, c.width, c.height, 0, 0, c.width, c.height);
  const d = g.getImageData(0, 0, c.width, c.height).data;
  let n = 0;
  for (let i = 0; i < d.length; i += 4) {
    const [red, gr, b] = [d[i], d[i + 1], d[i + 2]];
    if (b >= 200 && gr >= 150 && red <= 140 && b - red >= 100) n += 1;
  }
  return n;
}

const tipOf = (page) => page.evaluate(() => window.trainee.state.frame.tip);

async function pictureChecks(page, name, file, needCut) {
  const counts = await page.evaluate(classifyCanvas);
  const cutOk = !needCut || counts.cut >= 50;
  check(name, counts.tissue >= 20000 && counts.tool >= 30 && cutOk,
    `tissue pixels ${counts.tissue} (need ≥ 20000), blade ${counts.tool} (need ≥ 30)`
    + (needCut ? `, cut faces ${counts.cut} (need ≥ 50)` : ''));
  if (args.out) await page.screenshot({ path: path.join(args.out, file) });
  return counts;
}

/** The cut: to the line's start, down with Space held, along the line, up. */
async function incise(page, plan) {
  const start = await page.evaluate((p) => window.trainee.worldToClient(p), plan[0]);
  const end = await page.evaluate((p) => window.trainee.worldToClient(p), plan[plan.length - 1]);
  await page.mouse.move(start.x, start.y, { steps: 10 });
  await page.focus('#view');
  await page.keyboard.down('Space');
  const top = await page.evaluate(() => window.trainee.state.workspace.max[2]);
  const presses = Math.round((top - kDepth) / 0.001);
  for (let i = 0; i < presses; ++i) { await page.keyboard.press('ArrowDown'); await sleep(40); }
  await page.waitForFunction((z) => Math.abs(window.trainee.state.frame.tip[2] - z) < 3e-4, kDepth,
    { timeout: 5000 }).catch(() => {});
  const down = await tipOf(page);
  check('tip-down-at-the-line-start', Math.abs(down[2] - kDepth) < 3e-4
    && Math.hypot(down[0] - plan[0][0], down[1] - plan[0][1]) < 5e-4,
  `tip ${down.map((x) => (1e3 * x).toFixed(2))} mm, the line starts at ${plan[0].map((x) => 1e3 * x)} mm`);
  const t0 = Date.now();
  for (let i = 1; i <= kSteps; ++i) {
    const f = i / kSteps;
    await page.mouse.move(start.x + f * (end.x - start.x), start.y + f * (end.y - start.y));
    await sleep(kStepMs);
  }
  const drawSeconds = (Date.now() - t0) / 1000;
  await sleep(300);
  const last = plan[plan.length - 1];
  const atEnd = await tipOf(page);
  check('tip-followed-the-line', Math.hypot(atEnd[0] - last[0], atEnd[1] - last[1]) < 5e-4,
    `tip ${atEnd.map((x) => (1e3 * x).toFixed(2))} mm, the line ends at ${last.map((x) => 1e3 * x)} mm`);
  await page.keyboard.up('Space');
  for (let i = 0; i < presses; ++i) { await page.keyboard.press('ArrowUp'); await sleep(10); }
  return drawSeconds;
}

/**
 * N mouse moves over the pad, each 8–16 ms after the last was handled
 * (chromium coalesces moves queued while the page is busy, so moves that
 * do not wait are not all delivered); the latency quantiles and the mean
 * period of the moves as the page sent them.
 */
async function latencyBench(page, n) {
  const start = await page.evaluate(() => {
    const s = window.trainee.stats;
    s.latencyMs = []; s.pictureMs = []; s.pending = [];
    return { t: performance.now(), sent: s.samplesSent };
  });
  const a = await page.evaluate(() => window.trainee.worldToClient([-0.01, 0.006, 0]));
  const b = await page.evaluate(() => window.trainee.worldToClient([0.01, 0.006, 0]));
  for (let i = 0; i < n; ++i) {
    const f = 0.5 + 0.5 * Math.sin(i / 10);
    await page.mouse.move(a.x + f * (b.x - a.x), a.y + f * (b.y - a.y));
    await sleep(8 + (i % 9));  // off the frame clock
  }
  const end = await page.evaluate(() => ({ t: performance.now(), sent: window.trainee.stats.samplesSent }));
  await sleep(300);
  const { latencyMs, pictureMs } = await page.evaluate(() => window.trainee.stats);
  check('latency-measured', latencyMs.length >= n * 0.9 && pictureMs.length >= n * 0.9,
    `${latencyMs.length} (force) and ${pictureMs.length} (picture) of ${n} inputs timed`);
  const period = (end.t - start.t) / Math.max(1, end.sent - start.sent);
  const gl = await page.evaluate(() => ({ renderer: window.trainee.state.renderer, antialias: window.trainee.state.antialias }));
  return { kind: 'trainee_latency', scene: 'skin_pad', inputs: n, input_period_ms: Math.round(period * 10) / 10,
    renderer: gl.renderer, antialias: gl.antialias,
    input_to_force: quantiles(latencyMs), input_to_picture: quantiles(pictureMs) };
}

async function main() {
  const { browser, page, errors } = await openTraineePage(args);
  await page.waitForFunction(() => window.trainee.state.tissueBox !== null, null, { timeout: 20000 }).catch(() => {});
  await sleep(500);
  const gl = await page.evaluate(() => ({ renderer: window.trainee.state.renderer, antialias: window.trainee.state.antialias }));
  // Headless chromium draws with SwiftShader: the page must see it and draw
  // without multisampling, which would hold its one thread for most of a frame.
  const software = /swiftshader|llvmpipe|softpipe|software/i.test(gl.renderer);
  check('software-webgl-draws-without-multisampling', gl.renderer !== '' && gl.antialias === !software,
    `renderer '${gl.renderer}', antialias ${gl.antialias}`);
  const plan = await page.evaluate(() => window.trainee.state.plan);
  check('page-has-the-plan', plan.length >= 2, `plan ${JSON.stringify(plan)}`);
  const before = await pictureChecks(page, 'page-shows-tissue-and-blade-before', 'incision-before.png', false);
  // The blue line is drawn where the page projects the plan: the mouse aims at what is seen.
  const near = [];
  for (const f of [0.05, 0.25, 0.5, 0.75, 0.95]) {
    const p = plan[0].map((x, k) => x + f * (plan[plan.length - 1][k] - x));
    const c = await page.evaluate((q) => window.trainee.worldToClient(q), p);
    near.push(await page.evaluate(planPixelsNear, [c.x, c.y, 3]));
  }
  check('plan-drawn-where-aimed', near.filter((n) => n > 0).length >= 4, `plan pixels near 5 points: ${near}`);

  const drawSeconds = await incise(page, plan);
  const fps = await page.evaluate(() => window.trainee.stats.fps);
  await sleep(1500);  // the wound opens as the tissue settles
  const s = await page.evaluate(() => window.trainee.stats);
  check('page-shows-the-cut', s.maxCuts >= 1 && s.openedCount >= 1,
    `cuts shown ${s.maxCuts}, opened faces in the mesh ${s.openedCount}`);
  const after = await pictureChecks(page, 'page-shows-tissue-blade-and-wound-after', 'incision-after.png', true);

  const bench = args.bench > 0 ? await latencyBench(page, args.bench) : null;
  check('page-reports-no-errors', errors.length === 0 && s.errors.length === 0, [...errors, ...s.errors].join('; '));
  await browser.close();
  const summary = { kind: 'incision_test', passed: results.every((r) => r.ok), results, draw_seconds: drawSeconds,
    view_fps: Math.round(fps * 10) / 10, renderer: gl.renderer, antialias: gl.antialias, pixels_before: before,
    pixels_after: after, latency: bench };
  if (args.out) fs.writeFileSync(path.join(args.out, 'summary.json'), JSON.stringify(summary, null, 1));
  console.log(JSON.stringify(bench ?? summary));
  process.exit(summary.passed ? 0 : 1);
}

main().catch((e) => { console.error(`FAIL incision_test: ${e.stack || e}`); process.exit(1); });
