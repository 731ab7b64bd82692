// End-to-end test of the trainee page against a running
// `cutsim-haptic --device browser --serve` station whose server simulates
// the ligament (scenes/ligament.pbtxt):
//
//   node web/trainee/test/trainee_test.mjs --url http://127.0.0.1:PORT/?token=T [--out DIR]
//        [--chromium PATH]
//
// Drives Debian's chromium headless through playwright-core (from
// web/observer's npm packages) at 1280×720: the page shows the tissue in
// 3-D with the scalpel beside (never under) its HUD; the mouse and keyboard
// bring the scalpel down beside the ligament, switch cutting on and draw it
// across, as scenes/ligament-cut.path does; turning the view moves no tool.
// Screenshots before and after the cut go to DIR (trainee-before.png,
// trainee-after.png). Plain WebSocket clients (ws) try a wrong token, a
// foreign Origin, a rebound Host, a second trainee, oversized and malformed
// messages.
// Prints `ok NAME` or `FAIL NAME: why` per check and a JSON summary line
// (also DIR/summary.json); exits 0 when every check passes, 1 otherwise.

import fs from 'node:fs';
import path from 'node:path';
import { check, classifyCanvas, openTraineePage, parseArgs, require, results, sleep } from './page.mjs';

const WebSocket = require('ws');
const args = parseArgs(process.argv.slice(2), 'trainee_test.mjs --url URL [--out DIR] [--chromium PATH]');
const url = new URL(args.url);
const token = url.searchParams.get('token');
const wsUrl = (t) => `ws://${url.host}/ws?token=${t}`;

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
  const { browser, page, errors } = await openTraineePage(args);
  check('page-connects', true);
  // The tissue from the session's mesh stream, the scalpel over it.
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

  // An oversized message closes the trainee's socket; the slot is free again.
  await page.evaluate(() => window.trainee.sendRaw('p'.repeat(4096)));
  await page.waitForFunction(() => window.trainee.stats.closeCode !== null, null, { timeout: 5000 }).catch(() => {});
  const closed = await page.evaluate(() => window.trainee.stats.closeCode);
  check('oversized-message-closes', closed !== null, 'the page is still connected');
  const next = await tryWs(wsUrl(token), { origin: url.origin }, (ws) => setTimeout(() => ws.close(), 200));
  check('slot-free-after-close', next.opened, JSON.stringify(next));
  check('page-reports-no-errors', errors.length === 0, errors.join('; '));
  await browser.close();
  const summary = { kind: 'trainee_test', passed: results.every((r) => r.ok), results,
    view_fps: Math.round(fps * 10) / 10, pixels_before: before, pixels_after: after };
  if (args.out) fs.writeFileSync(path.join(args.out, 'summary.json'), JSON.stringify(summary, null, 1));
  console.log(JSON.stringify(summary));
  process.exit(summary.passed ? 0 : 1);
}

main().catch((e) => { console.error(`FAIL trainee_test: ${e.stack || e}`); process.exit(1); });
