// What the trainee page's chromium tests share: the browser, the checks
// they print, the page's pixel classes and latency quantiles.

import path from 'node:path';
import { createRequire } from 'node:module';
import { fileURLToPath } from 'node:url';

const here = path.dirname(fileURLToPath(import.meta.url));
export const require = createRequire(path.join(here, '../../observer/package.json'));
const { chromium } = require('playwright-core');

export const sleep = (ms) => new Promise((r) => setTimeout(r, ms));

/** The checks so far; check() prints `ok NAME` or `FAIL NAME: why`. */
export const results = [];
export function check(name, ok, why) {
  results.push({ name, ok, why: ok ? undefined : why });
  console.log(ok ? `ok ${name}` : `FAIL ${name}: ${why}`);
}

/**
 * Parses `--url URL [--out DIR] [--bench N] [--chromium PATH]`; exits 2 on
 * anything else.
 */
export function parseArgs(argv, usage) {
  const args = { url: null, out: null, bench: 0, chromium: '/usr/bin/chromium' };
  for (let i = 0; i < argv.length; ++i) {
    const value = () => argv[++i];
    switch (argv[i]) {
      case '--url': args.url = value(); break;
      case '--out': args.out = value(); break;
      case '--bench': args.bench = Number(value()); break;
      case '--chromium': args.chromium = value(); break;
      default:
        console.error(`unknown argument ${argv[i]}\nusage: ${usage}`);
        process.exit(2);
    }
  }
  if (!args.url) { console.error(`usage: ${usage}`); process.exit(2); }
  return args;
}

/**
 * Headless chromium (SwiftShader WebGL) on the trainee page at 1280×720,
 * waiting until force frames and the first mesh frame arrived. Returns
 * {browser, page, errors}: the page's uncaught errors collect in `errors`.
 */
export async function openTraineePage(args) {
  const browser = await chromium.launch({
    executablePath: args.chromium,
    args: ['--headless=new', '--use-gl=swiftshader', '--enable-unsafe-swiftshader', '--no-sandbox'],
  });
  const page = await browser.newPage({ viewport: { width: 1280, height: 720 } });
  const errors = [];
  page.on('pageerror', (e) => errors.push(String(e)));
  await page.goto(args.url);
  await page.waitForFunction(() => window.trainee && window.trainee.stats.framesReceived > 5, null, { timeout: 15000 });
  await page.waitForFunction(() => window.trainee.stats.meshFrames >= 1, null, { timeout: 20000 }).catch(() => {});
  return { browser, page, errors };
}

/**
 * Runs in the page: pixel classes of the WebGL canvas (the observer test's
 * rules): tissue (pink), tool (steel), cut faces (yellow) and the planned
 * line (light blue).
 */
export function classifyCanvas() {
  const src = document.getElementById('view');
  const c = document.createElement('canvas');
  c.width = src.width;
  c.height = src.height;
  const g = c.getContext('2d');
  g.drawImage(src, 0, 0);
  const d = g.getImageData(0, 0, c.width, c.height).data;
  const counts = { pixels: c.width * c.height, tissue: 0, tool: 0, cut: 0, plan: 0 };
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
    if (hue >= 194 && hue <= 204 && sat >= 0.6 && hi >= 200) counts.plan += 1;
  }
  return counts;
}

/** p10/p50/p90/p99/max (ms, 2 decimals) and the count of `values`. */
export function quantiles(values) {
  const v = values.slice().sort((a, b) => a - b);
  const q = (f) => v[Math.min(v.length - 1, Math.floor(f * v.length))];
  const r = (x) => (x === undefined ? null : Math.round(x * 100) / 100);
  return { samples: v.length, p10_ms: r(q(0.1)), p50_ms: r(q(0.5)), p90_ms: r(q(0.9)), p99_ms: r(q(0.99)),
    max_ms: r(v[v.length - 1]) };
}
