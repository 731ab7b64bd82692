// The trainee page: mouse, trackpad and keyboard drive the scalpel of a
// cutsim-haptic --device browser station; the station's force comes back as
// an arrow and a bar, and the cut as it happens.
//
// Sends one text message per input event: `p T U V W DX DY DZ B` (T the
// event's time in ms, U V W the tip in the workspace normalised to [0, 1],
// DX DY DZ the blade direction tip → handle, B the buttons: bit 0 cutting,
// bit 1 clutch). Receives a `hello` (the workspace box and force limit) and
// then `force` frames at 60 Hz. The view is the workspace from above: x to
// the right, y up; the depth z is the wheel or the arrow keys.

const state = {
  ws: null,
  workspace: null,        // {min: [x,y,z], max: [x,y,z]} in m
  maxForce: 8,
  u: 0.5, v: 0.5, w: 1.0, // the tip, normalised
  tiltX: 0, tiltY: 0,     // blade tilt about x and y, rad
  keyCut: false, mouseCut: false, clutch: false,
  frame: null,            // the last force frame
  trail: [],              // tip positions of the cut, m
  lastCuts: 0,
};

// What the tests and the latency benchmark read.
const stats = {
  framesReceived: 0,
  samplesSent: 0,
  maxForceSeen: 0,
  maxCuts: 0,
  closeCode: null,
  latencyMs: [],          // input event → first frame from a pose that includes it
  pending: [],            // input event times awaiting their frame
};
window.trainee = { state, stats, toClient, sendRaw: (text) => state.ws && state.ws.send(text) };

const canvas = document.getElementById('view');
const ctx = canvas.getContext('2d');
const $ = (id) => document.getElementById(id);

function clamp01(x) { return Math.min(1, Math.max(0, x)); }

/// The client (page) coordinates of the world point (x, y) m, for the tests.
function toClient(x, y) {
  const r = canvas.getBoundingClientRect();
  const ws = state.workspace;
  const u = (x - ws.min[0]) / (ws.max[0] - ws.min[0]);
  const v = (y - ws.min[1]) / (ws.max[1] - ws.min[1]);
  return { x: r.left + u * r.width, y: r.top + (1 - v) * r.height };
}

function bladeDirection() {
  // Upright (+z), tilted about y (toward x) and about x (toward −y).
  const dx = Math.sin(state.tiltY) * Math.cos(state.tiltX);
  const dy = -Math.sin(state.tiltX);
  const dz = Math.cos(state.tiltY) * Math.cos(state.tiltX);
  return [dx, dy, dz];
}

function buttons() {
  return ((state.keyCut || state.mouseCut) ? 1 : 0) | (state.clutch ? 2 : 0);
}

function send(timeStamp) {
  const ws = state.ws;
  if (!ws || ws.readyState !== WebSocket.OPEN || !state.workspace) return;
  const t = Math.max(0, timeStamp);
  const d = bladeDirection();
  const f = (x) => x.toFixed(6);
  ws.send(`p ${t.toFixed(3)} ${f(state.u)} ${f(state.v)} ${f(state.w)} ${f(d[0])} ${f(d[1])} ${f(d[2])} ${buttons()}`);
  stats.samplesSent += 1;
  if (stats.pending.length < 1000) stats.pending.push(t);
}

function depthStep() {
  const ws = state.workspace;
  return ws ? 0.001 / (ws.max[2] - ws.min[2]) : 0.02;
}

// ---------------------------------------------------------------------------
// Input

canvas.addEventListener('pointermove', (e) => {
  const r = canvas.getBoundingClientRect();
  state.u = clamp01((e.clientX - r.left) / r.width);
  state.v = clamp01(1 - (e.clientY - r.top) / r.height);
  send(e.timeStamp);
});
canvas.addEventListener('pointerdown', (e) => {
  if (e.button !== 0) return;
  canvas.focus();
  canvas.setPointerCapture(e.pointerId);
  state.mouseCut = true;
  send(e.timeStamp);
});
canvas.addEventListener('pointerup', (e) => {
  if (e.button !== 0) return;
  state.mouseCut = false;
  send(e.timeStamp);
});
canvas.addEventListener('wheel', (e) => {
  e.preventDefault();
  state.w = clamp01(state.w - e.deltaY * depthStep() / 100);
  send(e.timeStamp);
}, { passive: false });

const kTilt = Math.PI / 12;
const kMaxTilt = Math.PI / 3;
window.addEventListener('keydown', (e) => {
  let handled = true;
  switch (e.key) {
    case ' ': state.keyCut = true; break;
    case 'c': case 'C': state.clutch = true; break;
    case 'ArrowUp': case 'PageUp': state.w = clamp01(state.w + depthStep()); break;
    case 'ArrowDown': case 'PageDown': state.w = clamp01(state.w - depthStep()); break;
    case 'a': case 'A': state.tiltY = Math.max(-kMaxTilt, state.tiltY - kTilt); break;
    case 'd': case 'D': state.tiltY = Math.min(kMaxTilt, state.tiltY + kTilt); break;
    case 'q': case 'Q': state.tiltX = Math.max(-kMaxTilt, state.tiltX - kTilt); break;
    case 'e': case 'E': state.tiltX = Math.min(kMaxTilt, state.tiltX + kTilt); break;
    case 'r': case 'R': state.tiltX = 0; state.tiltY = 0; break;
    default: handled = false;
  }
  if (!handled) return;
  e.preventDefault();
  send(e.timeStamp);
});
window.addEventListener('keyup', (e) => {
  if (e.key === ' ') state.keyCut = false;
  else if (e.key === 'c' || e.key === 'C') state.clutch = false;
  else return;
  e.preventDefault();
  send(e.timeStamp);
});

// ---------------------------------------------------------------------------
// The station

function onFrame(m) {
  const now = performance.now();
  stats.framesReceived += 1;
  state.frame = m;
  const f = Math.hypot(m.force[0], m.force[1], m.force[2]);
  stats.maxForceSeen = Math.max(stats.maxForceSeen, f);
  stats.maxCuts = Math.max(stats.maxCuts, m.cuts);
  if (m.cuts > state.lastCuts) state.trail.push([m.tip[0], m.tip[1]]);
  state.lastCuts = m.cuts;
  // Latency: every input up to the newest sample in the rendered pose.
  if (m.used_ms >= 0) {
    let n = 0;
    while (n < stats.pending.length && stats.pending[n] <= m.used_ms + 1e-3) ++n;
    for (let i = 0; i < n; ++i) {
      if (stats.latencyMs.length < 100000) stats.latencyMs.push(now - stats.pending[i]);
    }
    stats.pending.splice(0, n);
  }
  $('force-value').textContent = `${f.toFixed(2)} N`;
  $('force-bar').style.width = `${Math.min(100, 100 * f / state.maxForce).toFixed(1)}%`;
  $('cuts').textContent = String(m.cuts);
  const cutting = (m.buttons & 1) !== 0;
  $('cutting').dataset.on = String(cutting);
  $('cutting').textContent = cutting ? 'CUTTING' : 'cutting off';
  $('contact').dataset.on = String(m.contact);
  $('contact').textContent = m.contact ? 'contact' : 'no contact';
  const ws = state.workspace;
  $('depth-value').textContent = `${(1e3 * m.tip[2]).toFixed(1)} mm`;
  $('depth-bar').style.width = `${(100 * (m.tip[2] - ws.min[2]) / (ws.max[2] - ws.min[2])).toFixed(1)}%`;
  $('tip').textContent = `tip ${m.tip.map((x) => (1e3 * x).toFixed(1)).join(', ')} mm`;
}

function connect() {
  const params = new URLSearchParams(location.search);
  const token = params.get('token') || '';
  const ws = new WebSocket(`ws://${location.host}/ws?token=${encodeURIComponent(token)}`);
  state.ws = ws;
  ws.onopen = () => { $('status').dataset.state = 'connected'; $('status').textContent = 'connected'; };
  ws.onclose = (e) => {
    stats.closeCode = e.code;
    const refused = state.workspace === null;
    $('status').dataset.state = refused ? 'refused' : 'closed';
    $('status').textContent = refused ? 'refused (wrong link, or a trainee is already connected)' : `closed (${e.code})`;
  };
  ws.onmessage = (e) => {
    const m = JSON.parse(e.data);
    if (m.kind === 'hello') {
      state.workspace = { min: m.workspace_min, max: m.workspace_max };
      state.maxForce = m.max_force > 0 ? m.max_force : 8;
      send(performance.now());
    } else if (m.kind === 'force') {
      onFrame(m);
    }
  };
}

// ---------------------------------------------------------------------------
// Drawing: the workspace from above, 5 mm grid, the cut in red, the blade
// and the force arrow at the tip.

function draw() {
  requestAnimationFrame(draw);
  const ws = state.workspace;
  const w = canvas.width, h = canvas.height;
  ctx.clearRect(0, 0, w, h);
  if (!ws) return;
  const px = (x) => (x - ws.min[0]) / (ws.max[0] - ws.min[0]) * w;
  const py = (y) => (1 - (y - ws.min[1]) / (ws.max[1] - ws.min[1])) * h;
  ctx.strokeStyle = '#252a30';
  ctx.lineWidth = 1;
  for (let x = Math.ceil(ws.min[0] / 0.005) * 0.005; x <= ws.max[0]; x += 0.005) {
    ctx.beginPath(); ctx.moveTo(px(x), 0); ctx.lineTo(px(x), h); ctx.stroke();
  }
  for (let y = Math.ceil(ws.min[1] / 0.005) * 0.005; y <= ws.max[1]; y += 0.005) {
    ctx.beginPath(); ctx.moveTo(0, py(y)); ctx.lineTo(w, py(y)); ctx.stroke();
  }
  ctx.strokeStyle = '#555';
  ctx.beginPath(); ctx.moveTo(px(0), 0); ctx.lineTo(px(0), h); ctx.moveTo(0, py(0)); ctx.lineTo(w, py(0)); ctx.stroke();
  if (state.trail.length > 0) {
    ctx.fillStyle = '#ff4040';
    for (const [x, y] of state.trail) { ctx.beginPath(); ctx.arc(px(x), py(y), 3, 0, 2 * Math.PI); ctx.fill(); }
  }
  const m = state.frame;
  if (!m) return;
  const tx = px(m.tip[0]), ty = py(m.tip[1]);
  const d = bladeDirection();
  $('blade').textContent = `blade ${d.map((x) => x.toFixed(2)).join(', ')}`;
  ctx.strokeStyle = (m.buttons & 1) ? '#ffb347' : '#cccccc';
  ctx.lineWidth = 3;
  ctx.beginPath(); ctx.moveTo(tx, ty); ctx.lineTo(tx + 60 * d[0], ty - 60 * d[1]); ctx.stroke();
  ctx.fillStyle = m.contact ? '#7fc7ff' : '#ffffff';
  ctx.beginPath(); ctx.arc(tx, ty, 5, 0, 2 * Math.PI); ctx.fill();
  const f = m.force;
  const scale = 120 / state.maxForce;  // px per N
  const ax = tx + scale * f[0], ay = ty - scale * f[1];
  if (Math.hypot(f[0], f[1], f[2]) > 1e-3) {
    ctx.strokeStyle = '#e05050';
    ctx.fillStyle = '#e05050';
    ctx.lineWidth = 3;
    ctx.beginPath(); ctx.moveTo(tx, ty); ctx.lineTo(ax, ay); ctx.stroke();
    const a = Math.atan2(ay - ty, ax - tx);
    ctx.beginPath();
    ctx.moveTo(ax, ay);
    ctx.lineTo(ax - 10 * Math.cos(a - 0.4), ay - 10 * Math.sin(a - 0.4));
    ctx.lineTo(ax - 10 * Math.cos(a + 0.4), ay - 10 * Math.sin(a + 0.4));
    ctx.fill();
    ctx.fillText(`fz ${f[2].toFixed(2)} N`, tx + 8, ty + 16);
  }
}

connect();
requestAnimationFrame(draw);
