// End-to-end test of the debrief (cutsim-server --replay FILE --live) as
// tests/integration/debrief_test.sh sets it up:
//
//   node web/observer/test/debrief_test.mjs --observer URL --instructor URL --commands FIFO
//        --frame-log FILE --server-log FILE [--out DIR] [--chromium PATH]
//
// --observer and --instructor are the bridge's page URLs (with the
// observers' token, and with the instructor's token too); --commands is the
// debrief's standard input; --frame-log a viewer's frame log (index seq hash
// sim_time mono_ns per rendered frame), which shows what observers see.
// Prints `ok NAME` or `FAIL NAME: why` per check and a JSON summary line;
// exits 0 when every check passes, 1 otherwise, 2 on bad usage.
//
// Checks: cli-seek (seeks back and forth on standard input show the right
// frame, within SEEK_LIMIT_MS; the latencies are in the summary), cli-steps
// (next and prev go to a cut step), cli-speed (speed 0.5 plays no faster
// than half real time),
// cli-refuses-by-field, ws-observer-read-only (an observer's command closes
// it with 1008, nothing applied), ws-wrong-instructor-refused (403),
// ws-instructor-controls (a command from the instructor's socket moves the
// picture), ws-refuses-by-field (bad commands answered with the field, a
// binary frame and an oversized message too), page-timeline (the strip with
// the timeline and the cursor at the picture's time), page-pause-at-peak
// (a click on the force peak seeks there, paused), page-next-cut (the next
// cut step button), observer-page-read-only (timeline, no controls),
// page-reports-no-errors.

import fs from 'node:fs';
import path from 'node:path';
import { chromium } from 'playwright-core';
import WebSocket from 'ws';

function parseArgs(argv) {
  const args = { observer: null, instructor: null, commands: null, frameLog: null, serverLog: null, out: null,
                 chromium: '/usr/bin/chromium' };
  for (let i = 0; i < argv.length; ++i) {
    const value = () => {
      if (i + 1 >= argv.length) usage(`${argv[i]} needs a value`);
      return argv[++i];
    };
    switch (argv[i]) {
      case '--observer': args.observer = value(); break;
      case '--instructor': args.instructor = value(); break;
      case '--commands': args.commands = value(); break;
      case '--frame-log': args.frameLog = value(); break;
      case '--server-log': args.serverLog = value(); break;
      case '--out': args.out = value(); break;
      case '--chromium': args.chromium = value(); break;
      default: usage(`unknown argument ${argv[i]}`);
    }
  }
  if (!args.observer || !args.instructor || !args.commands || !args.frameLog || !args.serverLog) {
    usage('--observer, --instructor, --commands, --frame-log and --server-log are required');
  }
  return args;
}

function usage(problem) {
  console.error(`debrief_test: ${problem}`);
  process.exit(2);
}

const args = parseArgs(process.argv.slice(2));
if (args.out) fs.mkdirSync(args.out, { recursive: true });
const results = {};
function report(name, ok, why = '', details = {}) {
  results[name] = { ok, ...(ok ? {} : { why }), ...details };
  console.log(ok ? `ok ${name}` : `FAIL ${name}: ${why}`);
}
async function check(name, body) {
  try {
    await body();
  } catch (error) {
    if (!(name in results)) report(name, false, String(error?.message ?? error).split('\n')[0]);
  }
}

const sleep = (ms) => new Promise((r) => setTimeout(r, ms));
const monoNs = () => process.hrtime.bigint();  // CLOCK_MONOTONIC, as the frame log's mono_ns
const FRAME_S = 0.005;                         // the ligament's frame
// A seek must show the right picture within this. The target is 1 s
// (bench/debrief_seek.sh measures it); on a shared machine under other
// builds a frame's simulation slows several-fold, so the test's default
// limit is wider and CUTSIM_DEBRIEF_SEEK_LIMIT_MS tightens it.
const SEEK_LIMIT_MS = Number(process.env.CUTSIM_DEBRIEF_SEEK_LIMIT_MS ?? 3000);

/** Frames rendered so far: {simTime, monoNs}. */
function frames() {
  const text = fs.existsSync(args.frameLog) ? fs.readFileSync(args.frameLog, 'utf8') : '';
  return text.split('\n').filter((l) => l.trim()).map((l) => {
    const f = l.trim().split(/\s+/);
    return { simTime: Number(f[3]), monoNs: BigInt(f[4]) };
  });
}

/** Waits for a rendered frame after `since` showing `t` (± one frame); its latency, ms. */
async function waitForPicture(t, since, limitMs = 5000) {
  const end = Date.now() + limitMs;
  while (Date.now() < end) {
    const hit = frames().find((f) => f.monoNs > since && Math.abs(f.simTime - t) <= FRAME_S + 1e-6);
    if (hit) return Number(hit.monoNs - since) / 1e6;
    await sleep(10);
  }
  const last = frames().at(-1);
  throw new Error(`no frame at ${t} s within ${limitMs} ms (last rendered ${last?.simTime} s)`);
}

function command(line) {
  const since = monoNs();
  fs.appendFileSync(args.commands, `${line}\n`);
  return since;
}

/** The server's log lines after `from` (a length) matching `re`. */
async function waitForLog(re, from, limitMs = 5000) {
  const end = Date.now() + limitMs;
  while (Date.now() < end) {
    const text = fs.readFileSync(args.serverLog, 'utf8').slice(from);
    const m = text.match(re);
    if (m) return m;
    await sleep(20);
  }
  throw new Error(`the server did not log ${re} within ${limitMs} ms`);
}
const logLength = () => fs.readFileSync(args.serverLog, 'utf8').length;

/** A WebSocket on the page URL's stream: resolves with the socket once open. */
function openSocket(pageUrl) {
  const u = new URL(pageUrl);
  const ws = new WebSocket(`ws://${u.host}/ws${u.search}`);
  ws.replies = [];
  ws.on('message', (data, binary) => {
    if (binary) return;
    const m = JSON.parse(String(data));
    if (m.type === 'control') ws.replies.push(m);
  });
  return new Promise((resolve, reject) => {
    ws.on('open', () => resolve(ws));
    ws.on('unexpected-response', (_req, res) => reject(new Error(`HTTP ${res.statusCode}`)));
    ws.on('error', reject);
  });
}
const closed = (ws) => new Promise((resolve) => ws.on('close', (code, reason) => resolve({ code, reason: String(reason) })));
async function reply(ws, count, limitMs = 3000) {
  const end = Date.now() + limitMs;
  while (ws.replies.length < count && Date.now() < end) await sleep(10);
  if (ws.replies.length < count) throw new Error('no reply');
  return ws.replies[count - 1];
}

async function cliChecks(latencies) {
  await check('cli-seek', async () => {
    command('pause');
    for (const t of [1.0, 2.5, 0.3, 3.7, 1.9, 1.2]) {
      const since = command(`seek ${t}`);
      latencies.push(await waitForPicture(t, since));
    }
    const max = Math.max(...latencies);
    if (max > SEEK_LIMIT_MS) throw new Error(`a seek took ${max.toFixed(0)} ms to show`);
    report('cli-seek', true, '', { seek_ms: latencies.map((x) => +x.toFixed(1)) });
  });
  await check('cli-steps', async () => {
    command('seek 0');
    await waitForPicture(0, monoNs() - 1n);
    const from = logLength();
    const since = command('next');
    const m = await waitForLog(/debrief: next \(from standard input\): at ([0-9.]+) s/, from);
    const t = Number(m[1]);
    if (!(t > 0)) throw new Error(`next went to ${t} s`);
    const ms = await waitForPicture(t, since);
    const from2 = logLength();
    command('prev');
    await waitForLog(/debrief: prev \(from standard input\): at ([0-9.]+) s/, from2);
    report('cli-steps', true, '', { first_cut_step_s: t, next_ms: +ms.toFixed(1) });
  });
  await check('cli-speed', async () => {
    command('seek 0.5');
    await waitForPicture(0.5, monoNs() - 1n);
    command('speed 0.5');
    const since = command('play');
    await sleep(1000);
    const shown = frames().filter((f) => f.monoNs > since);
    const a = shown[0];
    const b = shown.at(-1);
    const rate = (b.simTime - a.simTime) / (Number(b.monoNs - a.monoNs) / 1e9);
    command('pause');
    command('speed 1');
    // Never faster than asked; slower only when the machine cannot keep up
    // (the debrief then drops the backlog and counts it).
    if (!(rate > 0.1 && rate < 0.6)) throw new Error(`played at ${rate.toFixed(2)}× real time, asked 0.5×`);
    report('cli-speed', true, '', { rate: +rate.toFixed(2) });
  });
  await check('cli-refuses-by-field', async () => {
    const from = logLength();
    command('seek abc');
    await waitForLog(/command from standard input refused: time: /, from);
    report('cli-refuses-by-field', true);
  });
}

async function socketChecks(latencies) {
  await check('ws-observer-read-only', async () => {
    const ws = await openSocket(args.observer);
    const done = closed(ws);
    const from = logLength();
    ws.send('seek 3.0');
    const { code, reason } = await done;
    if (code !== 1008 || !reason.includes('instructor')) throw new Error(`closed with ${code} "${reason}"`);
    await sleep(300);
    if (/seek 3\.000000 \(from the page\)/.test(fs.readFileSync(args.serverLog, 'utf8').slice(from))) {
      throw new Error("the observer's command reached the debrief");
    }
    report('ws-observer-read-only', true, '', { code, reason });
  });
  await check('ws-wrong-instructor-refused', async () => {
    const u = new URL(args.instructor);
    u.searchParams.set('instructor', 'not-the-instructors-token');
    let refused = null;
    try {
      const ws = await openSocket(u.toString());
      ws.close();
    } catch (error) {
      refused = String(error.message);
    }
    if (refused !== 'HTTP 403') throw new Error(`a wrong instructor token got: ${refused ?? 'a socket'}`);
    report('ws-wrong-instructor-refused', true);
  });
  await check('ws-instructor-controls', async () => {
    const ws = await openSocket(args.instructor);
    const since = monoNs();
    ws.send('seek 2.2');
    const r = await reply(ws, 1);
    if (!r.ok || r.command !== 'seek 2.200000') throw new Error(`reply ${JSON.stringify(r)}`);
    const ms = await waitForPicture(2.2, since);
    latencies.push(ms);
    ws.close();
    report('ws-instructor-controls', true, '', { seek_ms: +ms.toFixed(1) });
  });
  await check('ws-refuses-by-field', async () => {
    const ws = await openSocket(args.instructor);
    const cases = [['seek abc', 'time'], ['jump 3', 'action'], ['speed 99', 'factor'], ['', 'command'],
                   ['play now', 'command'], ['seek -2', 'time'], ['seek NaN', 'time']];
    let n = 0;
    for (const [line, field] of cases) {
      ws.send(line);
      const r = await reply(ws, ++n);
      if (r.ok || r.field !== field) throw new Error(`"${line}": ${JSON.stringify(r)}, expected field ${field}`);
    }
    ws.send(Buffer.from([1, 2, 3]), { binary: true });
    const r = await reply(ws, ++n);
    if (r.ok || r.field !== 'command') throw new Error(`binary frame: ${JSON.stringify(r)}`);
    const done = closed(ws);
    ws.send('x'.repeat(4096));
    const { code } = await done;
    if (code !== 1009) throw new Error(`an oversized message closed with ${code}, not 1009`);
    report('ws-refuses-by-field', true);
  });
}

async function pageChecks(browser) {
  const pageErrors = [];
  const page = await browser.newPage({ viewport: { width: 1280, height: 800 } });
  page.on('pageerror', (e) => pageErrors.push(String(e)));
  page.on('console', (m) => { if (m.type() === 'error') pageErrors.push(m.text()); });
  await page.goto(args.instructor);
  const debriefState = () => page.evaluate(() => ({ ...window.cutsimDebrief.state }));
  await check('page-timeline', async () => {
    await page.waitForFunction(() => window.cutsimDebrief?.timeline && !document.getElementById('debrief').hidden,
                               null, { timeout: 20000 });
    const tl = await page.evaluate(() => window.cutsimDebrief.timeline);
    if (!(tl.forceN.length > 10 && tl.stepT.length > 0)) throw new Error(`timeline ${JSON.stringify(tl).slice(0, 200)}`);
    const box = await page.locator('#debrief-timeline').boundingBox();
    const view = await page.locator('#view').boundingBox();
    if (!(box.y >= view.y + view.height - 1)) throw new Error('the timeline is not under the 3-D view');
    report('page-timeline', true, '', { samples: tl.forceN.length, steps: tl.stepT.length });
  });
  const seekByClick = async (t) => {
    const box = await page.locator('#debrief-timeline').boundingBox();
    const duration = await page.evaluate(() => window.cutsimDebrief.duration());
    const left = 44;
    await page.mouse.click(box.x + left + (box.width - left - 8) * (t / duration), box.y + box.height / 2);
  };
  await check('page-pause-at-peak', async () => {
    const tl = await page.evaluate(() => window.cutsimDebrief.timeline);
    let k = 0;
    tl.forceN.forEach((f, i) => { if (f > tl.forceN[k]) k = i; });
    const peak = tl.forceT[k];
    if (!(await debriefState()).paused) await page.click('#debrief-play');
    await page.waitForFunction(() => window.cutsimDebrief.state.paused, null, { timeout: 5000 });
    await seekByClick(peak);
    const span = tl.duration / tl.forceT.length;
    await page.waitForFunction(([t, tol]) => Math.abs(window.cutsimDebrief.state.position - t) <= tol,
                               [peak, span + 0.02], { timeout: 5000 });
    await sleep(300);  // the picture and the cursor drawn
    await page.screenshot({ path: path.join(args.out, 'debrief-force-peak.png') });
    const s = await debriefState();
    if (!s.paused) throw new Error('not paused at the peak');
    report('page-pause-at-peak', true, '', { peak_s: peak, position_s: s.position });
  });
  await check('page-next-cut', async () => {
    const steps = await page.evaluate(() => window.cutsimDebrief.timeline.stepT);
    await seekByClick(0);
    await page.waitForFunction(() => window.cutsimDebrief.state.position < 0.05, null, { timeout: 5000 });
    await page.click('#debrief-next');
    await page.waitForFunction((t) => Math.abs(window.cutsimDebrief.state.position - t) < 1e-3, steps[0],
                               { timeout: 5000 });
    await sleep(300);
    await page.screenshot({ path: path.join(args.out, 'debrief-next-cut.png') });
    const reply = await page.textContent('#debrief-reply');
    report('page-next-cut', true, '', { step_s: steps[0], reply });
  });
  const observer = await browser.newPage({ viewport: { width: 1280, height: 800 } });
  observer.on('pageerror', (e) => pageErrors.push(String(e)));
  await observer.goto(args.observer);
  await check('observer-page-read-only', async () => {
    await observer.waitForFunction(() => window.cutsimDebrief?.timeline && !document.getElementById('debrief').hidden,
                                   null, { timeout: 20000 });
    const buttons = await observer.locator('#debrief button').count();
    if (buttons !== 0) throw new Error(`the observer's page has ${buttons} control buttons`);
    await sleep(300);
    await observer.screenshot({ path: path.join(args.out, 'debrief-observer.png') });
    report('observer-page-read-only', true);
  });
  await check('page-reports-no-errors', async () => {
    if (pageErrors.length > 0) throw new Error(pageErrors.slice(0, 3).join(' | '));
    report('page-reports-no-errors', true);
  });
}

async function main() {
  const latencies = [];
  await cliChecks(latencies);
  await socketChecks(latencies);
  const browser = await chromium.launch({ executablePath: args.chromium,
                                          args: ['--headless=new', '--use-gl=swiftshader', '--enable-unsafe-swiftshader',
                                                 '--no-sandbox'] });
  try {
    await pageChecks(browser);
  } finally {
    await browser.close();
  }
  const ok = Object.values(results).every((r) => r.ok);
  console.log(JSON.stringify({ ok, seek_ms_max: Math.max(...latencies), results }));
  process.exit(ok ? 0 : 1);
}

main().catch((error) => {
  console.error(`debrief_test: ${error?.stack ?? error}`);
  process.exit(1);
});
