// Load and latency of the browser observers against a running bridge
// (`cutsim-viewer --serve`):
//
//   node bench/observer_bench.mjs --url http://127.0.0.1:PORT/ [--token T] [--browsers N] [--ws-clients M]
//        [--seconds S] [--warmup S] [--mark-file PATH] [--samples PATH] [--chromium PATH]
//
// Opens N observer pages in one headless chromium (WebGL through SwiftShader,
// driven by playwright-core) and M plain WebSocket clients (ws) that count
// what they receive. Once every page has drawn and every client has its
// first mesh frame, it measures for S seconds and prints one JSON line:
//
// - latency_ms: glass-to-glass latency over all pages (the page's
//   state.latenciesMs: server publish → end of the draw that first shows the
//   frame), without the first --warmup seconds of the window (default 1);
// - page_* and ws_*: payload bytes and binary mesh frames per second per
//   observer (mean and min), payload bytes per mesh frame (with its session
//   message), pages' draws per second, and the ws clients' receive latency
//   (server publish → the session message's arrival here, also without the
//   warm-up);
// - errors: page errors, console errors, the pages' own error lists, clients
//   that closed, and no publish times in the stream (a server without
//   observed.publishUnixNs).
//
// --mark-file PATH gets a line `start UNIX_MS` when the window opens and
// `end UNIX_MS` when it closes, for a driving script that samples other
// processes over the same window (a FIFO works). --samples PATH gets every
// latency of the window as JSON: the pages' by the second they were drained
// at, the clients' with their arrival time (ms into the window).
//
// The latencies are drained from each page once a second (spliced out of
// state.latenciesMs), so a window of any length keeps all of them.
//
// Exits 0 when the pages recorded latencies and nothing went wrong, 1
// otherwise, 2 on bad usage, 77 when chromium is missing.

import fs from 'node:fs';
import { createRequire } from 'node:module';

const require = createRequire(new URL('../web/observer/package.json', import.meta.url));
const { chromium } = require('playwright-core');
const WebSocket = require('ws');

// ---------------------------------------------------------------------------
// Arguments

function usage(problem) {
  if (problem) console.error(`observer_bench: ${problem}`);
  console.error('usage: node bench/observer_bench.mjs --url http://HOST:PORT/ [--token T] [--browsers N] ' +
    '[--ws-clients M] [--seconds S] [--warmup S] [--mark-file PATH] [--samples PATH] [--chromium PATH]');
  process.exit(2);
}

function parseArgs(argv) {
  const args = {
    url: null, token: null, browsers: 1, wsClients: 0, seconds: 10, warmup: 1, markFile: null, samples: null,
    chromium: '/usr/bin/chromium',
  };
  const count = (text, name) => {
    const n = Number(text);
    if (!Number.isInteger(n) || n < 0) usage(`${name} needs a whole number ≥ 0, not '${text}'`);
    return n;
  };
  const seconds = (text, name) => {
    const s = Number(text);
    if (!Number.isFinite(s) || s < 0) usage(`${name} needs seconds ≥ 0, not '${text}'`);
    return s;
  };
  for (let i = 0; i < argv.length; ++i) {
    const value = () => {
      if (i + 1 >= argv.length) usage(`${argv[i]} needs a value`);
      return argv[++i];
    };
    switch (argv[i]) {
      case '--url': args.url = value(); break;
      case '--token': args.token = value(); break;
      case '--browsers': args.browsers = count(value(), '--browsers'); break;
      case '--ws-clients': args.wsClients = count(value(), '--ws-clients'); break;
      case '--seconds': args.seconds = seconds(value(), '--seconds'); break;
      case '--warmup': args.warmup = seconds(value(), '--warmup'); break;
      case '--mark-file': args.markFile = value(); break;
      case '--samples': args.samples = value(); break;
      case '--chromium': args.chromium = value(); break;
      case '-h': case '--help': usage(null); break;
      default: usage(`unknown argument ${argv[i]}`);
    }
  }
  if (!args.url) usage('--url is required');
  if (!(args.seconds > args.warmup)) usage('--seconds must exceed --warmup');
  if (args.browsers + args.wsClients === 0) usage('nothing to measure: --browsers and --ws-clients are both 0');
  return args;
}

const args = parseArgs(process.argv.slice(2));
const pageUrl = new URL(args.url);
if (args.token !== null) pageUrl.searchParams.set('token', args.token);
const socketUrl = (() => {
  const u = new URL('/ws', pageUrl);
  u.protocol = pageUrl.protocol === 'https:' ? 'wss:' : 'ws:';
  const token = pageUrl.searchParams.get('token');
  if (token !== null) u.searchParams.set('token', token);
  return u.toString();
})();

if (args.browsers > 0 && !fs.existsSync(args.chromium)) {
  console.error(`observer_bench: ${args.chromium} is not installed`);
  process.exit(77);
}

// ---------------------------------------------------------------------------
// Statistics

const sleep = (ms) => new Promise((resolve) => setTimeout(resolve, ms));
const round = (x, digits = 1) => (Number.isFinite(x) ? Number(x.toFixed(digits)) : null);

/** Nearest-rank quantile of sorted values. */
function quantile(sorted, q) {
  if (sorted.length === 0) return null;
  return sorted[Math.min(sorted.length - 1, Math.max(0, Math.ceil(q * sorted.length) - 1))];
}

function distribution(values) {
  const sorted = [...values].sort((a, b) => a - b);
  return {
    p50: round(quantile(sorted, 0.5)), p99: round(quantile(sorted, 0.99)),
    max: round(sorted[sorted.length - 1] ?? NaN), n: sorted.length,
  };
}

/** Mean and minimum of per-observer rates. */
function spread(values, digits = 1) {
  if (values.length === 0) return { mean: null, min: null };
  return { mean: round(values.reduce((a, b) => a + b, 0) / values.length, digits), min: round(Math.min(...values), digits) };
}

// ---------------------------------------------------------------------------
// Observers. Each counts its payload bytes and binary mesh frames while
// `counting` holds (the measured window).

let counting = false;
let windowStartMs = null;
const errors = [];
let sessionsSeen = 0;         // session messages seen (pages and clients)
let sessionsWithPublish = 0;  // of which with observed.publishUnixNs

/**
 * Reads a text frame: its type, and for a session message the server's
 * publish time of the frame (ms since the epoch) or null without one.
 */
function readText(text) {
  let message;
  try {
    message = JSON.parse(text);
  } catch {
    return { type: null, publishMs: null };
  }
  if (message?.type !== 'session') return { type: message?.type ?? null, publishMs: null };
  sessionsSeen += 1;
  const ns = message.observed?.publishUnixNs;
  if (ns === undefined) return { type: 'session', publishMs: null };
  sessionsWithPublish += 1;
  return { type: 'session', publishMs: Number(ns) / 1e6 };
}

/** A plain WebSocket client; served once it has the hello and a mesh frame. */
function openClient(index) {
  const c = {
    ws: new WebSocket(socketUrl, { handshakeTimeout: 10000 }), bytes: 0, frames: 0, receiveMs: [],
    hello: false, firstFrame: false, closed: null,
  };
  c.ws.on('message', (data, isBinary) => {
    const bytes = Buffer.isBuffer(data) ? data : Buffer.concat(data);
    if (isBinary) {
      c.firstFrame = true;
      if (counting) {
        c.bytes += bytes.length;
        c.frames += 1;
      }
      return;
    }
    const now = Date.now();
    if (counting) c.bytes += bytes.length;
    const { type, publishMs } = readText(bytes.toString());
    if (type === 'hello') c.hello = true;
    if (counting && publishMs !== null) c.receiveMs.push([now - windowStartMs, now - publishMs]);
  });
  c.ws.on('unexpected-response', (req, res) => {
    errors.push(`ws client ${index}: upgrade refused (HTTP ${res.statusCode})`);
    req.destroy();
  });
  c.ws.on('error', (error) => errors.push(`ws client ${index}: ${error.message}`));
  c.ws.on('close', (code) => { c.closed = code; });
  return c;
}

const CHROMIUM_ARGS = ['--headless=new', '--use-gl=swiftshader', '--enable-unsafe-swiftshader', '--no-sandbox'];
const VIEWPORT = { width: 960, height: 600 };

/** An observer page; counts its socket's frames as the browser reports them. */
async function openPage(browser, index) {
  const page = await browser.newPage({ viewport: VIEWPORT });
  const p = { page, index, bytes: 0, drains: [], start: null, end: null };
  page.on('pageerror', (error) => errors.push(`page ${index}: page error: ${error.message}`));
  page.on('console', (message) => {
    if (message.type() === 'error') errors.push(`page ${index}: console: ${message.text()}`);
  });
  page.on('websocket', (socket) => {
    socket.on('framereceived', ({ payload }) => {
      if (typeof payload === 'string') readText(payload);
      if (counting) p.bytes += typeof payload === 'string' ? Buffer.byteLength(payload) : payload.length;
    });
  });
  await page.goto(pageUrl.toString(), { waitUntil: 'load', timeout: 20000 });
  return p;
}

/** The page's counters, and its latencies since the last call (removed from the page). */
function drain(p) {
  return p.page.evaluate(() => {
    const s = window.cutsimObserver?.state;
    if (!s) return null;
    return {
      latencies: s.latenciesMs.splice(0), framesReceived: s.framesReceived, rendered: s.rendered,
      droppedFrames: s.droppedFrames, errors: [...s.errors],
    };
  });
}

async function until(condition, timeoutMs, stepMs = 100) {
  const end = Date.now() + timeoutMs;
  while (Date.now() < end) {
    if (await condition()) return true;
    await sleep(stepMs);
  }
  return condition();
}

function mark(word) {
  if (args.markFile) fs.appendFileSync(args.markFile, `${word} ${Date.now()}\n`);
}

// ---------------------------------------------------------------------------
// The run

async function main() {
  let browser = null;
  const clients = [];
  const pages = [];
  const result = {
    kind: 'observer_bench', browsers: args.browsers, ws_clients: args.wsClients, seconds: args.seconds,
    warmup_s: args.warmup,
  };
  try {
    for (let i = 0; i < args.wsClients; ++i) clients.push(openClient(i + 1));
    if (args.browsers > 0) {
      browser = await chromium.launch({ executablePath: args.chromium, args: CHROMIUM_ARGS });
      for (let i = 0; i < args.browsers; ++i) pages.push(await openPage(browser, i + 1));
    }
    const ready = await until(async () => {
      if (!clients.every((c) => c.hello && c.firstFrame)) return false;
      for (const p of pages) {
        const rendered = await p.page.evaluate(() => window.cutsimObserver?.state?.rendered ?? 0);
        if (rendered === 0) return false;
      }
      return true;
    }, 30000);
    if (!ready) {
      errors.push('not every observer got the session within 30 s');
      return result;
    }

    // The window: discard what came before it, count for args.seconds,
    // drain the pages once a second and at the end of the warm-up; the
    // latencies drained up to the end of the warm-up are discarded.
    for (const p of pages) p.start = await drain(p);
    counting = true;
    const startMs = Date.now();
    windowStartMs = startMs;
    mark('start');
    const drainsS = [args.warmup, args.seconds];
    for (let t = 1; t < args.seconds; ++t) drainsS.push(t);
    drainsS.sort((a, b) => a - b);
    let endMs = null;
    for (const [i, t] of drainsS.entries()) {
      if (i > 0 && t === drainsS[i - 1]) continue;
      await sleep(Math.max(0, startMs + 1000 * t - Date.now()));
      const last = t === args.seconds;
      if (last) {
        counting = false;
        endMs = Date.now();
        mark('end');
      }
      for (const p of pages) {
        const d = await drain(p);
        if (d === null) continue;
        if (t > args.warmup) p.drains.push({ s: t, latencies: d.latencies });
        if (last) p.end = d;
      }
    }
    const windowS = (endMs - startMs) / 1000;
    result.window_s = round(windowS, 3);

    const latencies = pages.flatMap((p) => p.drains.flatMap((d) => d.latencies));
    result.latency_ms = distribution(latencies);
    const measured = pages.filter((p) => p.start && p.end);
    const pageFrames = (p) => p.end.framesReceived - p.start.framesReceived;
    result.page_bytes_per_s = spread(measured.map((p) => p.bytes / windowS), 0);
    result.page_bytes_per_frame = spread(measured.filter((p) => pageFrames(p) > 0).map((p) => p.bytes / pageFrames(p)), 0);
    result.page_frames_per_s = spread(measured.map((p) => pageFrames(p) / windowS));
    result.page_draws_per_s = spread(measured.map((p) => (p.end.rendered - p.start.rendered) / windowS));
    result.page_dropped_frames = measured.reduce((n, p) => n + p.end.droppedFrames - p.start.droppedFrames, 0);
    result.ws_bytes_per_s = spread(clients.map((c) => c.bytes / windowS), 0);
    result.ws_bytes_per_frame = spread(clients.filter((c) => c.frames > 0).map((c) => c.bytes / c.frames), 0);
    result.ws_frames_per_s = spread(clients.map((c) => c.frames / windowS));
    const warmupMs = 1000 * args.warmup;
    const received = clients.map((c) => c.receiveMs.filter(([atMs]) => atMs > warmupMs));
    result.ws_receive_latency_ms = distribution(received.flatMap((r) => r.map(([, ms]) => ms)));
    if (args.samples) {
      fs.writeFileSync(args.samples, `${JSON.stringify({
        window_start_unix_ms: startMs, warmup_s: args.warmup,
        pages: pages.map((p) => p.drains),
        ws_clients: received,
      })}\n`);
    }
    for (const p of measured) errors.push(...p.end.errors.map((e) => `page ${p.index}: ${e}`));
    const closed = clients.filter((c) => c.closed !== null);
    if (closed.length > 0) errors.push(`${closed.length} ws client(s) closed (codes ${closed.map((c) => c.closed).join(', ')})`);
    if (sessionsSeen > 0 && sessionsWithPublish === 0) {
      errors.push('the session messages carry no observed.publishUnixNs (a server without publish times)');
    } else if (args.browsers > 0 && latencies.length === 0) {
      errors.push('the pages recorded no latencies');
    }
  } catch (error) {
    errors.push(`harness: ${String(error?.message ?? error).split('\n')[0]}`);
  } finally {
    // Leave with close frames (chromium sends 1001 as a page closes).
    counting = false;
    for (const c of clients) c.ws.close(1000);
    await Promise.all(pages.map((p) => p.page.close().catch(() => {})));
    await until(() => clients.every((c) => c.closed !== null), 2000, 20);
    for (const c of clients) c.ws.terminate();
    if (browser) await browser.close().catch(() => {});
    result.errors = errors.slice(0, 20);
    result.error_count = errors.length;
  }
  return result;
}

const result = await main();
console.log(JSON.stringify(result));
process.exit(result.errors.length === 0 && (args.browsers === 0 || result.latency_ms?.n > 0) ? 0 : 1);
