// The cutsim lab page: every session the lab bridge (`cutsim-viewer --lab`)
// hears, listed with its trainee, score so far and health, and up to 8 of
// them watched side by side as small live 3-D views. Clicking a session
// opens its full observer page (/observer.html?session=NAME).
//
// Streams: /ws carries the list ({"type":"lab", "sessions": [...]}, twice a
// second); /ws?session=NAME carries one session's frames exactly as a
// single session's bridge sends them (web/common/mesh_frames.js and the
// {"type":"session"} JSON). The page never sends anything.
//
// All views share one WebGL canvas fixed behind the grid: each cell is drawn
// into its own rectangle (scissor), so 8 views cost one GL context.

import * as THREE from 'three';
import { KIND_SNAPSHOT, parseMeshFrame } from '/common/mesh_frames.js';
import { makeScalpel } from '/common/scalpel.js';

const MAX_GRID = 8;
const COLOURS = { background: 0x1e222c, tissue: 0xe4988e, cutFace: 0xebb91e };
const VIEW_DIRECTION = new THREE.Vector3(1.0, -1.6, 1.2).normalize();
const FOV_DEG = 35;
const RECONNECT_MIN_MS = 500;
const RECONNECT_MAX_MS = 5000;
const MAX_ERRORS = 50;

/** Exposed for tests and the benchmark: list, views and their counters. */
const lab = { connection: 'connecting', sessions: [], views: new Map(), errors: [], lists: 0 };
window.labState = lab;

function recordError(message) {
  if (lab.errors.length < MAX_ERRORS) lab.errors.push(message);
}

function rawParam(name) {
  for (const part of window.location.search.replace(/^\?/, '').split('&')) {
    if (part.startsWith(`${name}=`)) return part.slice(name.length + 1);
  }
  return null;
}

/** The bridge's stream URL for `session` (null: the list). */
function socketUrl(session) {
  const scheme = window.location.protocol === 'https:' ? 'wss:' : 'ws:';
  const params = [];
  if (rawParam('token') !== null) params.push(`token=${rawParam('token')}`);
  if (session !== null) params.push(`session=${encodeURIComponent(session)}`);
  return `${scheme}//${window.location.host}/ws${params.length > 0 ? `?${params.join('&')}` : ''}`;
}

/** The observer page of `session`, with the lab's token. */
function observerUrl(session) {
  const token = rawParam('token');
  return `/observer.html?session=${encodeURIComponent(session)}${token !== null ? `&token=${token}` : ''}`;
}

function num(value) {
  const n = typeof value === 'number' ? value : Number(value);
  return Number.isFinite(n) ? n : null;
}

function fmt(value, scale, digits, unit) {
  const n = num(value);
  return n === null ? '–' : `${(n * scale).toFixed(digits)} ${unit}`;
}

// ---------------------------------------------------------------------------
// The shared renderer

const canvas = document.getElementById('views');
const renderer = new THREE.WebGLRenderer({ canvas, antialias: true, alpha: true, preserveDrawingBuffer: true });
THREE.ColorManagement.enabled = false;
renderer.outputColorSpace = THREE.LinearSRGBColorSpace;
renderer.setPixelRatio(window.devicePixelRatio || 1);
renderer.setScissorTest(true);
const tissueMaterial = new THREE.MeshLambertMaterial({ color: COLOURS.tissue, side: THREE.DoubleSide, flatShading: true });
const cutMaterial = new THREE.MeshLambertMaterial({
  color: COLOURS.cutFace, side: THREE.DoubleSide, flatShading: true,
  polygonOffset: true, polygonOffsetFactor: -1, polygonOffsetUnits: -1,
});

/** One session's small live view: its own scene, camera and socket. */
class SessionView {
  constructor(session) {
    this.session = session;
    this.frames = 0;          // mesh frames applied
    this.frameTimes = [];     // performance.now() of the frames of the last 2 s
    this.simTime = null;
    this.cuts = 0;
    this.peakForce = null;
    this.closed = false;
    this.scene = new THREE.Scene();
    this.camera = new THREE.PerspectiveCamera(FOV_DEG, 1, 1e-4, 10);
    this.camera.up.set(0, 0, 1);
    this.scene.add(this.camera);
    this.scene.add(new THREE.AmbientLight(0xffffff, 0.22 * Math.PI));
    const key = new THREE.DirectionalLight(0xffffff, 0.78 * Math.PI);
    key.position.set(-0.35, 0.45, 1.0);
    key.target = this.camera;
    this.camera.add(key);
    this.mesh = null;
    this.framed = false;
    this.scalpel = makeScalpel(THREE);
    this.scalpel.group.visible = false;
    this.scene.add(this.scalpel.group);
    this.cell = this.makeCell();
    this.reconnectDelay = RECONNECT_MIN_MS;
    this.connect();
  }

  makeCell() {
    const cell = document.createElement('div');
    cell.className = 'cell';
    cell.dataset.session = this.session;
    cell.title = `Open ${this.session}'s full observer view`;
    cell.innerHTML = '<div class="caption"><b></b><span class="who"></span></div><div class="foot"></div>';
    cell.querySelector('b').textContent = this.session;
    cell.addEventListener('click', () => { window.location.href = observerUrl(this.session); });
    document.getElementById('grid').appendChild(cell);
    return cell;
  }

  connect() {
    if (this.closed) return;
    const socket = new WebSocket(socketUrl(this.session));
    socket.binaryType = 'arraybuffer';
    this.socket = socket;
    socket.addEventListener('open', () => { this.reconnectDelay = RECONNECT_MIN_MS; });
    socket.addEventListener('message', (event) => {
      if (event.data instanceof ArrayBuffer) this.onFrame(event.data);
      else this.onText(event.data);
    });
    socket.addEventListener('close', () => {
      if (this.closed) return;
      setTimeout(() => this.connect(), this.reconnectDelay);
      this.reconnectDelay = Math.min(2 * this.reconnectDelay, RECONNECT_MAX_MS);
    });
  }

  onFrame(buffer) {
    const frame = parseMeshFrame(buffer);
    if (typeof frame === 'string') {
      recordError(`${this.session}: ${frame}`);
      return;
    }
    if (frame.kind === KIND_SNAPSHOT) {
      const geometry = new THREE.BufferGeometry();
      geometry.setAttribute('position', new THREE.BufferAttribute(frame.positions, 3));
      geometry.setIndex(new THREE.BufferAttribute(frame.triangles, 1));
      geometry.addGroup(0, 3 * (frame.F - frame.O), 0);
      geometry.addGroup(3 * (frame.F - frame.O), 3 * frame.O, 1);
      geometry.computeBoundingBox();
      if (this.mesh) {
        this.mesh.geometry.dispose();
        this.mesh.geometry = geometry;
      } else {
        this.mesh = new THREE.Mesh(geometry, [tissueMaterial, cutMaterial]);
        this.mesh.frustumCulled = false;
        this.scene.add(this.mesh);
      }
      if (!this.framed && frame.V > 0) this.frame(geometry.boundingBox);
    } else {
      if (!this.mesh) return;
      const position = this.mesh.geometry.getAttribute('position');
      if (position.count !== frame.V) {
        recordError(`${this.session}: positions update for ${frame.V} vertices, the snapshot has ${position.count}`);
        return;
      }
      position.array.set(frame.positions);
      position.needsUpdate = true;
    }
    this.simTime = frame.simTime;
    this.frames += 1;
    const now = performance.now();
    this.frameTimes.push(now);
    while (this.frameTimes.length > 0 && now - this.frameTimes[0] > 2000) this.frameTimes.shift();
    requestDraw();
  }

  onText(text) {
    let message;
    try {
      message = JSON.parse(text);
    } catch {
      recordError(`${this.session}: a text frame that is not JSON`);
      return;
    }
    if (message?.type !== 'session' || typeof message.observed !== 'object') return;
    const tools = Array.isArray(message.observed.tools) ? message.observed.tools : [];
    const t = tools[0];
    if (t && this.radius) {
      const tip = new THREE.Vector3(num(t.tip?.x) ?? 0, num(t.tip?.y) ?? 0, num(t.tip?.z) ?? 0);
      const dir = new THREE.Vector3(num(t.bladeDir?.x) ?? 0, num(t.bladeDir?.y) ?? 0, num(t.bladeDir?.z) ?? 1);
      if (!(dir.length() > 0)) dir.set(0, 0, 1);
      this.scalpel.place(tip, dir.normalize(), num(t.bladeLength) ?? 0);
      this.scalpel.group.visible = (num(t.bladeLength) ?? 0) > 0;
    } else {
      this.scalpel.group.visible = false;
    }
  }

  frame(box) {
    const centre = box.getCenter(new THREE.Vector3());
    const radius = Math.max(0.5 * box.getSize(new THREE.Vector3()).length(), 1e-3);
    this.radius = radius;
    const distance = 1.05 * radius / Math.sin(THREE.MathUtils.degToRad(0.5 * FOV_DEG));
    this.camera.near = distance * 0.01;
    this.camera.far = distance * 100;
    this.camera.position.copy(centre).addScaledVector(VIEW_DIRECTION, distance);
    this.camera.lookAt(centre);
    this.framed = true;
  }

  /** Frames per second over the last 2 s. */
  fps() {
    const now = performance.now();
    return this.frameTimes.filter((t) => now - t <= 2000).length / 2;
  }

  close() {
    this.closed = true;
    this.socket?.close();
    this.cell.remove();
    if (this.mesh) this.mesh.geometry.dispose();
  }
}

// ---------------------------------------------------------------------------
// Drawing: each view into its cell's rectangle of the shared canvas

let drawPending = false;
function requestDraw() {
  if (drawPending) return;
  drawPending = true;
  requestAnimationFrame(draw);
}

function draw() {
  drawPending = false;
  const width = window.innerWidth;
  const height = window.innerHeight;
  if (canvas.width !== Math.floor(width * renderer.getPixelRatio()) ||
      canvas.height !== Math.floor(height * renderer.getPixelRatio())) {
    renderer.setSize(width, height, false);
  }
  canvas.style.width = `${width}px`;
  canvas.style.height = `${height}px`;
  canvas.style.top = `${window.scrollY}px`;
  renderer.setScissor(0, 0, width, height);
  renderer.setClearColor(0x000000, 0);
  renderer.clear();
  for (const view of lab.views.values()) {
    const r = view.cell.getBoundingClientRect();
    if (r.bottom < 0 || r.top > height || r.right < 0 || r.left > width) continue;
    const y = height - r.bottom;
    renderer.setViewport(r.left, y, r.width, r.height);
    renderer.setScissor(r.left, y, r.width, r.height);
    renderer.setClearColor(COLOURS.background, 1);
    renderer.clear();
    if (!view.mesh) continue;
    view.camera.aspect = r.width / Math.max(r.height, 1);
    view.camera.updateProjectionMatrix();
    renderer.render(view.scene, view.camera);
  }
}
window.addEventListener('resize', requestDraw);
window.addEventListener('scroll', requestDraw);

// ---------------------------------------------------------------------------
// The list

/** Sessions the instructor put in the grid or took out (by name). */
const chosen = new Map();

function inGrid(s, index) {
  if (chosen.has(s.session)) return chosen.get(s.session);
  return s.live && index < MAX_GRID;
}

function statusBadge(s) {
  if (!s.live) return '<span class="badge stopped">stopped</span>';
  if (!s.current) return '<span class="badge warn">no frames</span>';
  if (num(s.frame_age_ms) > 1000 || num(s.overruns_per_s) > 5) return '<span class="badge warn">lagging</span>';
  return '<span class="badge live">live</span>';
}

function cellText(tag, text, cls) {
  const td = document.createElement(tag);
  td.textContent = text;
  if (cls) td.className = cls;
  return td;
}

const SVG_NS = 'http://www.w3.org/2000/svg';

/**
 * A sparkline of the trainee's finished sessions (oldest left): the mean
 * deviation as a line, the peak force as dots, each scaled to its own
 * range; the tooltip lists the values.
 */
function trendCell(trend) {
  const td = document.createElement('td');
  td.className = 'trend';
  const points = Array.isArray(trend) ? trend.filter((p) => p && typeof p === 'object') : [];
  if (points.length === 0) {
    td.textContent = '–';
    return td;
  }
  const width = 90;
  const height = 22;
  const svg = document.createElementNS(SVG_NS, 'svg');
  svg.setAttribute('width', width);
  svg.setAttribute('height', height);
  const x = (i) => (points.length === 1 ? width / 2 : 3 + (i * (width - 6)) / (points.length - 1));
  const scaled = (key) => {
    const values = points.map((p) => num(p[key]) ?? 0);
    const lo = Math.min(...values);
    const hi = Math.max(...values);
    return values.map((v) => (hi > lo ? height - 3 - ((v - lo) * (height - 6)) / (hi - lo) : height / 2));
  };
  const dev = scaled('mean_deviation');
  const line = document.createElementNS(SVG_NS, 'polyline');
  line.setAttribute('points', dev.map((y, i) => `${x(i).toFixed(1)},${y.toFixed(1)}`).join(' '));
  line.setAttribute('fill', 'none');
  line.setAttribute('stroke', '#8fb8ff');
  line.setAttribute('stroke-width', '1.5');
  svg.appendChild(line);
  scaled('peak_force').forEach((y, i) => {
    const dot = document.createElementNS(SVG_NS, 'circle');
    dot.setAttribute('cx', x(i).toFixed(1));
    dot.setAttribute('cy', y.toFixed(1));
    dot.setAttribute('r', '1.8');
    dot.setAttribute('fill', '#ebb91e');
    svg.appendChild(dot);
  });
  td.appendChild(svg);
  td.append(` ${points.length}`);
  td.title = points.map((p, i) => `#${i + 1}: deviation ${fmt(p.mean_deviation, 1e3, 2, 'mm')}, depth error ` +
    `${fmt(p.depth_error, 1e3, 2, 'mm')}, peak ${fmt(p.peak_force, 1, 2, 'N')}, ${fmt(p.duration, 1, 0, 's')}`).join('\n');
  td.dataset.sessions = String(points.length);
  return td;
}

function renderList() {
  const rows = document.getElementById('session-rows');
  rows.replaceChildren();
  let gridCount = 0;
  const wanted = new Set();
  lab.sessions.forEach((s, index) => {
    const tr = document.createElement('tr');
    tr.className = s.live ? 'live' : 'stopped';
    tr.dataset.session = s.session;
    const box = document.createElement('input');
    box.type = 'checkbox';
    const shown = inGrid(s, index) && gridCount < MAX_GRID;
    box.checked = shown;
    box.title = 'Show in the grid';
    box.addEventListener('change', () => {
      chosen.set(s.session, box.checked);
      renderList();
    });
    if (shown) {
      gridCount += 1;
      wanted.add(s.session);
    }
    const tdBox = document.createElement('td');
    tdBox.appendChild(box);
    tr.appendChild(tdBox);
    const tdName = document.createElement('td');
    const a = document.createElement('a');
    a.href = observerUrl(s.session);
    a.textContent = s.session;
    tdName.appendChild(a);
    tr.appendChild(tdName);
    tr.appendChild(cellText('td', s.trainee || '–'));
    tr.appendChild(cellText('td', s.scene || '–'));
    const tdStatus = document.createElement('td');
    tdStatus.innerHTML = statusBadge(s);
    tr.appendChild(tdStatus);
    const station = document.createElement('td');
    station.innerHTML = s.trainee_connected ? '<span class="badge live">connected</span>'
                                            : '<span class="badge off">none</span>';
    tr.appendChild(station);
    tr.appendChild(cellText('td', fmt(s.sim_time, 1, 1, 's'), 'num'));
    tr.appendChild(cellText('td', String(num(s.cuts) ?? 0), 'num'));
    tr.appendChild(cellText('td', s.score ? fmt(s.score.mean_deviation, 1e3, 2, 'mm') : '–', 'num'));
    tr.appendChild(cellText('td', s.score ? fmt(s.score.depth_error, 1e3, 2, 'mm') : '–', 'num'));
    tr.appendChild(cellText('td', s.score ? fmt(s.score.coverage, 100, 0, '%') : '–', 'num'));
    tr.appendChild(cellText('td', s.metrics ? fmt(s.metrics.peak_force, 1, 2, 'N') : '–', 'num'));
    tr.appendChild(trendCell(s.trend));
    const frames = s.live ? `${(num(s.frames_per_s) ?? 0).toFixed(0)}/s, ${s.frame_age_ms === null ? '–'
      : `${num(s.frame_age_ms).toFixed(0)} ms`}, ${(num(s.overruns_per_s) ?? 0).toFixed(1)} late/s` : '–';
    tr.appendChild(cellText('td', frames, 'num'));
    rows.appendChild(tr);
  });
  document.getElementById('empty').hidden = lab.sessions.length > 0;
  const live = lab.sessions.filter((s) => s.live).length;
  document.getElementById('lab-summary').textContent =
    `${live} live, ${lab.sessions.length - live} stopped; ${wanted.size} in the grid`;
  updateGrid(wanted);
}

/** Opens views for the sessions in the grid, closes the others. */
function updateGrid(wanted) {
  for (const [name, view] of lab.views) {
    if (!wanted.has(name)) {
      view.close();
      lab.views.delete(name);
    }
  }
  for (const name of wanted) {
    if (!lab.views.has(name)) lab.views.set(name, new SessionView(name));
  }
  // Cells follow the list's order.
  const grid = document.getElementById('grid');
  for (const s of lab.sessions) {
    const view = lab.views.get(s.session);
    if (!view) continue;
    grid.appendChild(view.cell);
    view.cell.classList.toggle('stopped', !s.live);
    view.cell.querySelector('.who').textContent = `${s.trainee || 'no trainee named'} · ${s.scene || ''}`;
    const score = s.score ? `dev ${fmt(s.score.mean_deviation, 1e3, 1, 'mm')}, cov ${fmt(s.score.coverage, 100, 0, '%')}`
                          : 'no plan';
    view.cell.querySelector('.foot').textContent =
      `${s.live ? 'live' : 'stopped'} · ${fmt(s.sim_time, 1, 1, 's')} · ${num(s.cuts) ?? 0} cuts · ` +
      `peak ${s.metrics ? fmt(s.metrics.peak_force, 1, 2, 'N') : '–'} · ${score} · ${view.fps().toFixed(0)} fps`;
  }
  requestDraw();
}

function onList(text) {
  let message;
  try {
    message = JSON.parse(text);
  } catch {
    recordError('a list frame that is not JSON');
    return;
  }
  if (message?.type !== 'lab' || !Array.isArray(message.sessions)) return;
  lab.sessions = message.sessions.filter((s) => s && typeof s.session === 'string');
  lab.authenticated = message.authenticated === true;
  lab.lists += 1;
  document.getElementById('lab-auth').textContent = lab.authenticated ? 'sessions signed with the lab key'
    : 'open lab: sessions not authenticated';
  renderList();
}

let listDelay = RECONNECT_MIN_MS;
function connectList() {
  const conn = document.getElementById('lab-conn');
  const socket = new WebSocket(socketUrl(null));
  socket.addEventListener('open', () => {
    listDelay = RECONNECT_MIN_MS;
    lab.connection = 'open';
    conn.textContent = 'connected';
    conn.className = 'conn-open';
  });
  socket.addEventListener('message', (event) => {
    if (typeof event.data === 'string') onList(event.data);
  });
  socket.addEventListener('close', () => {
    lab.connection = 'closed';
    conn.textContent = 'reconnecting';
    conn.className = 'conn-closed';
    setTimeout(connectList, listDelay);
    listDelay = Math.min(2 * listDelay, RECONNECT_MAX_MS);
  });
}

connectList();
