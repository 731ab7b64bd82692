// End-to-end test of the lab page (web/lab) against a running lab bridge
// (`cutsim-viewer --lab`) on a network where sessions come and go:
//
//   node web/observer/test/lab_test.mjs --url http://127.0.0.1:PORT/ --sessions a,b --stopped b
//        --stop-file PATH [--station a --ready-file PATH] [--out DIR] [--chromium PATH]
//
// It lives beside the observer page's test because it uses that page's npm
// packages (playwright-core). Drives Debian's chromium headless; prints
// `ok NAME` or `FAIL NAME: why` per check and a JSON summary line; exits 0
// when every check passes, 1 otherwise, 2 on bad usage.
//
// Checks: lists-the-running-sessions (each named session appears live with
// its scene and trainee, found from the streams alone), grid-views-update
// (each session's small view receives frames and draws tissue),
// station-shown (the session with a station shows it connected; the
// --ready-file is created once the list is up, so a driver starts the
// station then),
// stopped-session-shown (after the driver stops one server, on the
// --stop-file it is asked to, the list shows it stopped and the others
// live), trend-shown (the stopped session's trainee gets a trend from the
// lab's history), opens-observer-view (clicking a grid cell opens that session's
// observer page, which shows it), page-reports-no-errors.

import fs from 'node:fs';
import path from 'node:path';
import { chromium } from 'playwright-core';

function parseArgs(argv) {
  const args = { url: null, sessions: [], stopped: null, stopFile: null, station: null, readyFile: null, out: null,
                 chromium: '/usr/bin/chromium' };
  for (let i = 0; i < argv.length; ++i) {
    const value = () => {
      if (i + 1 >= argv.length) usage(`${argv[i]} needs a value`);
      return argv[++i];
    };
    switch (argv[i]) {
      case '--url': args.url = value(); break;
      case '--sessions': args.sessions = value().split(',').filter((s) => s.length > 0); break;
      case '--stopped': args.stopped = value(); break;
      case '--stop-file': args.stopFile = value(); break;
      case '--station': args.station = value(); break;
      case '--ready-file': args.readyFile = value(); break;
      case '--out': args.out = value(); break;
      case '--chromium': args.chromium = value(); break;
      default: usage(`unknown argument ${argv[i]}`);
    }
  }
  if (!args.url || args.sessions.length === 0 || !args.stopped || !args.stopFile) {
    usage('--url, --sessions, --stopped and --stop-file are required');
  }
  return args;
}

function usage(problem) {
  console.error(`lab_test: ${problem}`);
  console.error('usage: node lab_test.mjs --url URL --sessions a,b --stopped b --stop-file PATH [--station a] [--out DIR]');
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

const CHROMIUM_ARGS = ['--headless=new', '--use-gl=swiftshader', '--enable-unsafe-swiftshader', '--no-sandbox'];
const VIEWPORT = { width: 1280, height: 800 };
// Waits are for conditions; these limits only end a run that never gets there.
const LIST_LIMIT_MS = 60000;

async function screenshot(page, name) {
  if (args.out) await page.screenshot({ path: path.join(args.out, `${name}.png`) });
}

/** The list as the page holds it. */
const listOf = (page) => page.evaluate(() => window.labState.sessions.map((s) => ({
  session: s.session, live: s.live, scene: s.scene, trainee: s.trainee, station: s.trainee_connected,
})));

async function main() {
  const browser = await chromium.launch({ executablePath: args.chromium, args: CHROMIUM_ARGS });
  const pageErrors = [];
  try {
    const page = await browser.newPage({ viewport: VIEWPORT });
    page.on('pageerror', (e) => pageErrors.push(String(e)));
    page.on('console', (m) => { if (m.type() === 'error') pageErrors.push(m.text()); });
    await page.goto(args.url);

    await check('lists-the-running-sessions', async () => {
      await page.waitForFunction((names) => names.every((n) => window.labState.sessions.some(
        (s) => s.session === n && s.live && s.scene !== '')), args.sessions, { timeout: LIST_LIMIT_MS });
      const list = await listOf(page);
      const rows = await page.$$eval('#session-rows tr', (trs) => trs.map((tr) => tr.dataset.session));
      for (const name of args.sessions) {
        if (!rows.includes(name)) throw new Error(`no table row for ${name}`);
      }
      report('lists-the-running-sessions', true, '', { list });
    });

    if (args.station) {
      if (args.readyFile) fs.writeFileSync(args.readyFile, 'ready\n');
      await check('station-shown', async () => {
        await page.waitForFunction((n) => window.labState.sessions.some((s) => s.session === n && s.trainee_connected),
                                   args.station, { timeout: LIST_LIMIT_MS });
        report('station-shown', true);
      });
    }

    await check('grid-views-update', async () => {
      // Each view counts the frames it applied; two readings apart, every
      // view must have moved on.
      await page.waitForFunction((names) => names.every((n) => window.labState.views.get(n)?.frames > 0),
                                 args.sessions, { timeout: LIST_LIMIT_MS });
      const first = await page.evaluate(() => Object.fromEntries([...window.labState.views].map(([n, v]) => [n, v.frames])));
      await page.waitForFunction((before) => Object.entries(before).every(
        ([n, f]) => window.labState.views.get(n)?.frames > f), first, { timeout: LIST_LIMIT_MS });
      const cells = await page.$$eval('#grid .cell', (cs) => cs.map((c) => c.dataset.session));
      for (const name of args.sessions) if (!cells.includes(name)) throw new Error(`no grid cell for ${name}`);
      await screenshot(page, 'lab-live');
      const fps = await page.evaluate(() => Object.fromEntries([...window.labState.views].map(([n, v]) => [n, v.fps()])));
      report('grid-views-update', true, '', { cells, fps });
    });

    await check('stopped-session-shown', async () => {
      fs.writeFileSync(args.stopFile, 'stop\n');
      await page.waitForFunction((n) => window.labState.sessions.some((s) => s.session === n && !s.live),
                                 args.stopped, { timeout: LIST_LIMIT_MS });
      const list = await listOf(page);
      for (const s of list) {
        if (s.session !== args.stopped && !s.live) throw new Error(`${s.session} shows stopped too`);
      }
      const rowClass = await page.$eval(`#session-rows tr[data-session="${args.stopped}"]`, (tr) => tr.className);
      if (rowClass !== 'stopped') throw new Error(`the stopped session's row is '${rowClass}'`);
      await screenshot(page, 'lab-one-stopped');
      report('stopped-session-shown', true, '', { list });
    });

    await check('trend-shown', async () => {
      // The stopped server appended its session to the lab's history; the
      // bridge reads it every 10 s and the list carries the trainee's trend.
      await page.waitForFunction((n) => window.labState.sessions.some(
        (s) => s.session === n && Array.isArray(s.trend) && s.trend.length > 0), args.stopped,
      { timeout: LIST_LIMIT_MS });
      await page.waitForFunction((n) => Number(document.querySelector(
        `#session-rows tr[data-session="${n}"] td.trend`)?.dataset.sessions) > 0, args.stopped,
      { timeout: LIST_LIMIT_MS });
      await screenshot(page, 'lab-trend');
      report('trend-shown', true);
    });

    await check('opens-observer-view', async () => {
      const target = args.sessions.find((n) => n !== args.stopped);
      await page.click(`#grid .cell[data-session="${target}"]`);
      await page.waitForURL((u) => u.pathname === '/observer.html' && u.searchParams.get('session') === target,
                            { timeout: LIST_LIMIT_MS });
      await page.waitForFunction((n) => document.getElementById('hud-session')?.textContent === n, target,
                                 { timeout: LIST_LIMIT_MS });
      await page.waitForFunction(() => Number(document.getElementById('hud-frames')?.textContent) > 0, null,
                                 { timeout: LIST_LIMIT_MS });
      await screenshot(page, 'lab-observer');
      report('opens-observer-view', true);
    });

    const labErrors = await page.evaluate(() => window.labState?.errors ?? []).catch(() => []);
    report('page-reports-no-errors', pageErrors.length === 0 && labErrors.length === 0,
           JSON.stringify([...pageErrors, ...labErrors]).slice(0, 400));
  } finally {
    await browser.close();
  }
  const failed = Object.entries(results).filter(([, r]) => !r.ok).map(([n]) => n);
  const summary = { ok: failed.length === 0, failed, results };
  console.log(JSON.stringify(summary));
  if (args.out) fs.writeFileSync(path.join(args.out, 'summary.json'), JSON.stringify(summary, null, 2));
  process.exit(failed.length === 0 ? 0 : 1);
}

main().catch((e) => {
  console.error(`lab_test: ${e?.stack ?? e}`);
  process.exit(1);
});
