// The cutsim observer page: follows a running session over the read-only
// WebSocket that `cutsim-viewer --serve` offers at /ws and draws the tissue
// surface, the scalpel and the force on it with three.js, plus a HUD with the
// force history, the cut count, the session clock and the link's health.
//
// Wire protocol (version 1): the bridge sends text frames with JSON
// ({"type":"hello"} once, then {"type":"session"} after each mesh frame) and
// binary mesh frames with a 32-byte little-endian header (web/common/mesh_frames.js).
// An observer's page never sends anything; an instructor's page in a debrief
// sends the control commands of debrief.js.
//
// Colours and lighting follow the C++ renderer (common/render/palette.h):
// white ambient + diffuse light with no specular term and a total ≤ 1, applied
// to the raw sRGB base colours, so shading scales a pixel's brightness but
// keeps its hue and saturation, and the same hue/saturation pixel classifiers
// apply to both renderers.

import * as THREE from 'three';
import { OrbitControls } from '/vendor/OrbitControls.js';
import { KIND_SNAPSHOT, parseMeshFrame } from '/common/mesh_frames.js';
import { makeScalpel } from '/common/scalpel.js';
import { makePlanLine } from '/common/plan_line.js';
import { Debrief } from '/debrief.js';

// ---------------------------------------------------------------------------
// Constants

const PROTOCOL_VERSION = 1;

const COLOURS = {
  background: 0x1e222c,
  tissue: 0xe4988e,
  cutFace: 0xebb91e,
  tool: 0xb4bcce,
  force: 0x3cc85a,
};

// Lighting budget of the C++ renderer: ambient + key + fill = 1. three.js's
// Lambert BRDF divides irradiance by π, so each intensity is scaled by π.
const AMBIENT = 0.22;
const KEY_DIFFUSE = 0.66;
const FILL_DIFFUSE = 0.12;
// Light directions in eye space (x right, y up, z towards the viewer): the
// lights follow the camera, key from the upper right, fill from the lower left.
const KEY_DIRECTION = new THREE.Vector3(-0.35, 0.45, 1.0);
const FILL_DIRECTION = new THREE.Vector3(0.6, -0.3, 0.4);

// Camera framing of the C++ viewer (common/render/camera.h): look at the
// first mesh's bounding box from this direction with this field of view.
const VIEW_DIRECTION = new THREE.Vector3(1.0, -1.6, 1.2).normalize();
const FOV_DEG = 35;

// Tool and force-arrow proportions, relative to the framed scene's radius.
const ARROW_RADIUS = 0.015;
const ARROW_LENGTH = 0.5;      // at full scale
const FORCE_FULL_SCALE = 1.0;  // N: the force drawn at ARROW_LENGTH
const ARROW_MAX_SCALE = 1.5;   // larger forces are drawn at 1.5 × full scale

const PLOT_WINDOW_S = 10;
const MAX_ERRORS = 100;
const MAX_LATENCIES = 2000;
const RECONNECT_MIN_MS = 500;
const RECONNECT_MAX_MS = 5000;

// ---------------------------------------------------------------------------
// Observable state (read by the tests as window.cutsimObserver.state)

const state = {
  connected: false,
  connection: 'connecting',  // connecting | open | closed
  session: null,             // session name from the hello message
  framesReceived: 0,         // binary mesh frames accepted
  snapshots: 0,              // of which surface snapshots
  droppedFrames: 0,          // seq gaps between consecutive binary frames
  lastSeq: null,
  simTime: 0,                // session clock from the last session message, s
  wallTime: 0,
  cuts: 0,
  topologyVersion: 0,
  tool: null,                // {tip, bladeDir, bladeLength, force, contact}
  link: null,                // {frame_age_ms, bridge_gaps, clients}
  metrics: null,             // the session's measures (SessionMetrics, SI units), or null before any
  plan: null,                // the planned incision's points ([x, y, z], m), or null: none heard of yet
  vertexCount: 0,
  triangleCount: 0,
  openedCount: 0,
  rendered: 0,               // frames drawn
  lastRenderMs: null,        // performance.now() of the last draw
  firstRenderMs: null,       // performance.now() of the first draw
  connectStartMs: null,      // performance.now() when the page last began to connect
  connectedMs: null,         // performance.now() when the socket last opened
  closeCode: null,           // close code of the last closed socket
  lastFrameSimTime: null,    // sim_time of the mesh frame last drawn
  latenciesMs: [],           // glass-to-glass latency of the last MAX_LATENCIES mesh frames drawn, ms
  errors: [],                // protocol and page errors, newest last
};

window.cutsimObserver = { state };

// Drawing on demand: requestFrame queues one animation frame that redraws
// what is marked dirty.
let frameQueued = false;
let sceneDirty = false;
let hudDirty = true;

/** Records a problem for the HUD and the tests; keeps the newest MAX_ERRORS. */
function recordError(message) {
  state.errors.push(message);
  if (state.errors.length > MAX_ERRORS) state.errors.shift();
  console.warn(`cutsim observer: ${message}`);
  // Written directly, not on the next frame: this also reports errors that
  // stop the page before it can draw (no WebGL, say).
  const line = document.getElementById('hud-error');
  line.hidden = false;
  line.textContent = `${state.errors.length} error(s); last: ${message}`;
}

window.addEventListener('error', (event) => recordError(`page error: ${event.message}`));
window.addEventListener('unhandledrejection', (event) => recordError(`unhandled rejection: ${event.reason}`));

// ---------------------------------------------------------------------------
// Scene

const canvas = document.getElementById('view');
// preserveDrawingBuffer keeps the last frame readable (screenshots, tests);
// the page only draws when something changed, so its cost is negligible.
const renderer = new THREE.WebGLRenderer({ canvas, antialias: true, preserveDrawingBuffer: true });
// Raw sRGB colours in, raw values out: lighting then scales the base colours
// exactly as the C++ renderer's fixed-function lighting does.
THREE.ColorManagement.enabled = false;
renderer.outputColorSpace = THREE.LinearSRGBColorSpace;
renderer.setPixelRatio(window.devicePixelRatio || 1);
renderer.setClearColor(COLOURS.background, 1);

const scene = new THREE.Scene();
scene.background = new THREE.Color(COLOURS.background);

const camera = new THREE.PerspectiveCamera(FOV_DEG, 1, 1e-4, 10);
camera.up.set(0, 0, 1);  // world z is up
camera.position.copy(VIEW_DIRECTION).multiplyScalar(0.1);
scene.add(camera);

scene.add(new THREE.AmbientLight(0xffffff, AMBIENT * Math.PI));
for (const [intensity, direction] of [[KEY_DIFFUSE, KEY_DIRECTION], [FILL_DIFFUSE, FILL_DIRECTION]]) {
  const light = new THREE.DirectionalLight(0xffffff, intensity * Math.PI);
  light.position.copy(direction).normalize();
  light.target = camera;  // shines from camera-space `direction` towards the eye's origin
  camera.add(light);
}

// Intact faces and faces opened by a cut: one geometry, two groups.
// Flat shading takes each face's normal from screen-space derivatives, which
// always face the viewer, so both sides of a face are lit (two-sided lighting).
const tissueMaterial = new THREE.MeshLambertMaterial({
  color: COLOURS.tissue, side: THREE.DoubleSide, flatShading: true,
});
const cutMaterial = new THREE.MeshLambertMaterial({
  color: COLOURS.cutFace, side: THREE.DoubleSide, flatShading: true,
  // Opened faces often coincide with the face across the cut; the offset
  // lets the cut colour win the depth test there.
  polygonOffset: true, polygonOffsetFactor: -1, polygonOffsetUnits: -1,
});
let surfaceMesh = null;   // THREE.Mesh of the current snapshot
let meshSimTime = null;   // sim_time of the mesh frame now in surfaceMesh
let meshSeq = null;       // seq of the mesh frame now in surfaceMesh
let sceneRadius = null;   // half the diagonal of the first mesh's bounding box, m

// The scalpel (web/common/scalpel.js): handle and flat blade, its edge
// facing the way the tip last moved.
const scalpel = makeScalpel(THREE);
scene.add(scalpel.group);

// The planned incision (web/common/plan_line.js, as the trainee's page has
// it), from the session's `plan` (sent about once a second; kept between).
let planLine = null;

/** Draws the plan of `observed.plan` when its points changed. */
function updatePlan(plan) {
  if (!plan || typeof plan !== 'object' || !Array.isArray(plan.points)) return;
  const points = plan.points.map((p) => [num(p.x), num(p.y), num(p.z)]);
  if (JSON.stringify(points) === JSON.stringify(state.plan)) return;
  state.plan = points;
  if (planLine) {
    scene.remove(planLine);
    planLine.geometry.dispose();
  }
  planLine = makePlanLine(THREE, points);
  if (planLine) scene.add(planLine);
}

// The force on the tool: a shaft (70 % of the length) and a cone, both unit
// shapes along +y, scaled and turned onto the force direction.
const forceMaterial = new THREE.MeshLambertMaterial({ color: COLOURS.force });
const shaftMesh = new THREE.Mesh(
  new THREE.CylinderGeometry(1, 1, 1, 12, 1, false).translate(0, 0.5, 0), forceMaterial);
const headMesh = new THREE.Mesh(new THREE.ConeGeometry(1, 1, 16).translate(0, 0.5, 0), forceMaterial);
const forceArrow = new THREE.Group();
forceArrow.add(shaftMesh, headMesh);
forceArrow.visible = false;
scene.add(forceArrow);

const controls = new OrbitControls(camera, canvas);
controls.enableDamping = false;  // damping would need a continuous render loop
controls.addEventListener('change', () => requestFrame(true));

/** Sets the camera on `box` as the C++ viewer frames its first mesh. */
function frameCamera(box) {
  const centre = box.getCenter(new THREE.Vector3());
  const radius = Math.max(0.5 * box.getSize(new THREE.Vector3()).length(), 1e-3);
  sceneRadius = radius;
  const halfV = THREE.MathUtils.degToRad(0.5 * FOV_DEG);
  const halfH = Math.atan(camera.aspect * Math.tan(halfV));
  const distance = 1.05 * radius / Math.sin(Math.min(halfV, halfH));
  camera.near = distance * 0.01;
  camera.far = distance * 100;
  camera.position.copy(centre).addScaledVector(VIEW_DIRECTION, distance);
  camera.updateProjectionMatrix();
  controls.target.copy(centre);
  controls.minDistance = radius * 0.05;
  controls.maxDistance = distance * 20;
  controls.update();
}

function resize() {
  const width = canvas.clientWidth || window.innerWidth;
  const height = canvas.clientHeight || window.innerHeight;
  renderer.setSize(width, height, false);
  camera.aspect = width / Math.max(height, 1);
  camera.updateProjectionMatrix();
  requestFrame(true);
}
window.addEventListener('resize', resize);

// The debrief strip under the view (shown only when the session is a
// recording played again); the view shrinks to make room for it.
const debrief = new Debrief({ instructor: rawParam('instructor') !== null, onLayout: resize });
window.cutsimDebrief = debrief;  // for the page's test and the console

const Y_AXIS = new THREE.Vector3(0, 1, 0);

/** Places the scalpel and the force arrow from the session's first tool. */
function placeTool(tool) {
  if (!tool) {
    scalpel.group.visible = false;
    forceArrow.visible = false;
    return;
  }
  const scale = sceneRadius ?? Math.max(tool.bladeLength, 0.01);
  const tip = new THREE.Vector3(tool.tip.x, tool.tip.y, tool.tip.z);
  const dir = new THREE.Vector3(tool.bladeDir.x, tool.bladeDir.y, tool.bladeDir.z);
  if (!(dir.length() > 0)) dir.set(0, 0, 1);
  dir.normalize();
  scalpel.place(tip, dir, tool.bladeLength);
  scalpel.group.visible = tool.bladeLength > 0;

  const f = new THREE.Vector3(tool.force.x, tool.force.y, tool.force.z);
  const magnitude = f.length();
  if (!(magnitude > 0) || !Number.isFinite(magnitude)) {
    forceArrow.visible = false;
    return;
  }
  const length = ARROW_LENGTH * scale * Math.min(magnitude / FORCE_FULL_SCALE, ARROW_MAX_SCALE);
  const r = ARROW_RADIUS * scale;
  forceArrow.position.copy(tip);
  forceArrow.quaternion.setFromUnitVectors(Y_AXIS, f.divideScalar(magnitude));
  shaftMesh.scale.set(r, 0.7 * length, r);
  headMesh.position.set(0, 0.7 * length, 0);
  headMesh.scale.set(2.5 * r, 0.3 * length, 2.5 * r);
  forceArrow.visible = true;
}

// ---------------------------------------------------------------------------
// Binary mesh frames

/** Replaces the surface with a snapshot's; frames the camera on the first. */
function applySnapshot(frame) {
  const geometry = new THREE.BufferGeometry();
  const position = new THREE.BufferAttribute(frame.positions, 3);
  position.setUsage(THREE.DynamicDrawUsage);
  geometry.setAttribute('position', position);
  geometry.setIndex(new THREE.BufferAttribute(frame.triangles, 1));
  const intact = frame.F - frame.O;
  geometry.addGroup(0, 3 * intact, 0);
  geometry.addGroup(3 * intact, 3 * frame.O, 1);
  geometry.computeBoundingBox();
  geometry.computeBoundingSphere();

  if (surfaceMesh) {
    surfaceMesh.geometry.dispose();
    surfaceMesh.geometry = geometry;
  } else {
    surfaceMesh = new THREE.Mesh(geometry, [tissueMaterial, cutMaterial]);
    // The tissue deforms between bounding-sphere updates; never cull it.
    surfaceMesh.frustumCulled = false;
    scene.add(surfaceMesh);
  }
  if (sceneRadius === null && frame.V > 0) {
    // The first mesh with vertices sets the view and the tool's proportions.
    frameCamera(geometry.boundingBox);
    if (state.tool) placeTool(state.tool);
  }
  state.vertexCount = frame.V;
  state.triangleCount = frame.F;
  state.openedCount = frame.O;
  state.snapshots += 1;
}

/** Moves the current surface's vertices; the topology stays. */
function applyPositions(frame) {
  if (!surfaceMesh) return 'positions update before any snapshot';
  if (frame.V !== state.vertexCount) return `positions update for ${frame.V} vertices, the snapshot has ${state.vertexCount}`;
  const position = surfaceMesh.geometry.getAttribute('position');
  position.array.set(frame.positions);
  position.needsUpdate = true;
  return null;
}

function onBinaryMessage(buffer) {
  const frame = parseMeshFrame(buffer);
  if (typeof frame === 'string') {
    recordError(frame);
    return;
  }
  if (frame.kind === KIND_SNAPSHOT) {
    applySnapshot(frame);
  } else {
    const why = applyPositions(frame);
    if (why) {
      recordError(why);
      return;
    }
  }
  // Sequence numbers of consecutive frames differ by 1; a larger step means
  // frames were dropped. A step back (the session restarted) starts afresh.
  if (state.lastSeq !== null && frame.seq > state.lastSeq + 1) {
    state.droppedFrames += frame.seq - state.lastSeq - 1;
  }
  state.lastSeq = frame.seq;
  state.framesReceived += 1;
  meshSimTime = frame.simTime;
  meshSeq = frame.seq;
  requestFrame(true);
}

// ---------------------------------------------------------------------------
// Glass-to-glass latency: from the server publishing a mesh frame (its wall
// clock, observed.publishUnixNs in the session message of the same seq) to
// the end of the draw that first shows the frame (this page's wall clock).
// The two clocks agree only when server and browser run on one host. The
// session message follows its mesh frame, so a draw may come between the
// two: then the draw's time is kept until the message arrives.

let lastPublished = null;  // {seq, ms}: the newest session message's publish time
let drawnSeq = null;       // seq of the mesh frame last drawn
let drawnAwaiting = null;  // {seq, ms}: a drawn frame whose publish time has not arrived

function recordLatency(ms) {
  state.latenciesMs.push(ms);
  if (state.latenciesMs.length > MAX_LATENCIES) state.latenciesMs.shift();
}

/** Notes the publish time of frame `seq` (wall clock, ms). */
function notePublished(seq, ms) {
  lastPublished = { seq, ms };
  if (drawnAwaiting?.seq === seq) {
    recordLatency(drawnAwaiting.ms - ms);
    drawnAwaiting = null;
  }
}

/** Notes that the draw just ended shows mesh frame `seq` (once per frame). */
function noteDrawn(seq) {
  if (seq === null || seq === drawnSeq) return;
  drawnSeq = seq;
  const now = Date.now();
  if (lastPublished?.seq === seq) {
    recordLatency(now - lastPublished.ms);
    drawnAwaiting = null;
  } else {
    drawnAwaiting = { seq, ms: now };
  }
}

// ---------------------------------------------------------------------------
// Text messages

/** A proto3-JSON number (64-bit integers arrive as strings); missing → 0. */
function num(value) {
  if (value === undefined || value === null) return 0;
  const n = typeof value === 'number' ? value : Number(value);
  return Number.isFinite(n) ? n : 0;
}

function vec3(v) {
  return { x: num(v?.x), y: num(v?.y), z: num(v?.z) };
}

/** A ToolView in proto3 JSON as a plain object with every field present. */
function toolView(t) {
  return {
    tip: vec3(t?.tip),
    bladeDir: vec3(t?.bladeDir),
    bladeLength: num(t?.bladeLength),
    force: vec3(t?.force),
    contact: t?.contact === true,
  };
}

/** The session's measures from protobuf JSON (absent fields are 0). */
function metricsView(m) {
  return {
    peakForce: num(m.peakForce),
    meanForce: num(m.meanForce),
    pathLength: num(m.pathLength),
    contactTime: num(m.contactTime),
    cutOffVolume: num(m.cutOffVolume),
    openedArea: num(m.openedArea),
    maxStressOutside: num(m.maxStressOutside),
    stressOutside: num(m.stressOutside),
  };
}

// |F| history for the force plot: {t: sim time, f: N}.
const forceHistory = [];
// performance.now() when the last link report arrived: the HUD ages the
// reported frame age by the time since, so a stalled stream shows as growing.
let linkReceivedMs = null;

function onSessionMessage(message) {
  const observed = message.observed ?? {};
  if (typeof observed !== 'object') {
    recordError('session message whose "observed" is not an object');
    return;
  }
  const simTime = num(observed.simTime);
  if (simTime < state.simTime) forceHistory.length = 0;  // a new session clock
  state.simTime = simTime;
  state.wallTime = num(observed.wallTime);
  state.cuts = num(observed.cuts);
  state.topologyVersion = num(observed.topologyVersion);
  const tools = Array.isArray(observed.tools) ? observed.tools : [];
  state.tool = tools.length > 0 ? toolView(tools[0]) : null;
  if (observed.metrics && typeof observed.metrics === 'object') state.metrics = metricsView(observed.metrics);
  if (message.link && typeof message.link === 'object') {
    linkReceivedMs = performance.now();
    state.link = {
      frame_age_ms: num(message.link.frame_age_ms),
      bridge_gaps: num(message.link.bridge_gaps),
      clients: num(message.link.clients),
    };
  }
  const publishNs = num(observed.publishUnixNs);
  if (publishNs > 0 && message.seq !== undefined) notePublished(num(message.seq), publishNs / 1e6);
  const f = state.tool ? Math.hypot(state.tool.force.x, state.tool.force.y, state.tool.force.z) : 0;
  forceHistory.push({ t: simTime, f });
  while (forceHistory.length > 0 && forceHistory[0].t < simTime - PLOT_WINDOW_S) forceHistory.shift();
  placeTool(state.tool);
  updatePlan(observed.plan);
  debrief.update(observed.debrief);
  requestFrame(true);
}

function onTextMessage(text) {
  let message;
  try {
    message = JSON.parse(text);
  } catch {
    recordError(`text frame is not JSON: ${text.slice(0, 80)}`);
    return;
  }
  if (message?.type === 'hello') {
    if (message.protocol !== PROTOCOL_VERSION) {
      recordError(`bridge speaks protocol ${message.protocol}, this page ${PROTOCOL_VERSION}`);
    }
    state.session = typeof message.session === 'string' ? message.session : null;
    hudDirty = true;
    requestFrame();
  } else if (message?.type === 'session') {
    onSessionMessage(message);
  } else if (message?.type === 'control') {
    debrief.onReply(message);
  }
  // Other message types are for newer pages; this one ignores them.
}

// ---------------------------------------------------------------------------
// Connection

/** The raw query parameter `name` of the page URL, or null. */
function rawParam(name) {
  for (const part of window.location.search.replace(/^\?/, '').split('&')) {
    if (part.startsWith(`${name}=`)) return part.slice(name.length + 1);
  }
  return null;
}

/** The stream's URL: the token, and on a lab bridge the session to watch. */
function socketUrl() {
  const scheme = window.location.protocol === 'https:' ? 'wss:' : 'ws:';
  const params = ['token', 'session', 'instructor'].filter((n) => rawParam(n) !== null)
    .map((n) => `${n}=${rawParam(n)}`);
  return `${scheme}//${window.location.host}/ws${params.length > 0 ? `?${params.join('&')}` : ''}`;
}

let reconnectDelay = RECONNECT_MIN_MS;

function setConnection(name) {
  state.connection = name;
  state.connected = name === 'open';
  hudDirty = true;
  requestFrame();
}

/** Opens the socket; reopens it with a growing delay when it closes. */
function connect() {
  setConnection('connecting');
  state.connectStartMs = performance.now();
  const socket = new WebSocket(socketUrl());
  socket.binaryType = 'arraybuffer';
  socket.addEventListener('open', () => {
    debrief.setSocket(socket);
    reconnectDelay = RECONNECT_MIN_MS;
    state.lastSeq = null;  // sequence gaps are counted within one connection
    state.connectedMs = performance.now();
    setConnection('open');
  });
  socket.addEventListener('message', (event) => {
    if (event.data instanceof ArrayBuffer) onBinaryMessage(event.data);
    else onTextMessage(event.data);
  });
  socket.addEventListener('close', (event) => {
    debrief.setSocket(null);
    setConnection('closed');
    state.closeCode = event.code;
    setTimeout(connect, reconnectDelay);
    reconnectDelay = Math.min(2 * reconnectDelay, RECONNECT_MAX_MS);
  });
}

// ---------------------------------------------------------------------------
// HUD

const hud = {
  session: document.getElementById('hud-session'),
  conn: document.getElementById('hud-conn'),
  force: document.getElementById('hud-force'),
  clock: document.getElementById('hud-clock'),
  cuts: document.getElementById('hud-cuts'),
  age: document.getElementById('hud-age'),
  frames: document.getElementById('hud-frames'),
  dropped: document.getElementById('hud-dropped'),
  clients: document.getElementById('hud-clients'),
  peakForce: document.getElementById('hud-peak-force'),
  meanForce: document.getElementById('hud-mean-force'),
  path: document.getElementById('hud-path'),
  contact: document.getElementById('hud-contact'),
  cutOff: document.getElementById('hud-cut-off'),
  stress: document.getElementById('hud-stress'),
  stressNow: document.getElementById('hud-stress-now'),
  plot: document.getElementById('force-plot'),
};
const plot = hud.plot.getContext('2d');

function updateHud() {
  hud.session.textContent = state.session ?? 'cutsim';
  hud.conn.textContent = state.connection;
  hud.conn.className = `conn-${state.connection}`;
  const f = forceHistory.length > 0 ? forceHistory[forceHistory.length - 1].f : 0;
  hud.force.textContent = `${f.toFixed(3)} N`;
  hud.clock.textContent = `${state.simTime.toFixed(3)} s`;
  hud.cuts.textContent = String(state.cuts);
  hud.age.textContent = state.link
    ? `${(state.link.frame_age_ms + performance.now() - linkReceivedMs).toFixed(0)} ms` : '–';
  hud.frames.textContent = String(state.framesReceived);
  hud.dropped.textContent = String(state.droppedFrames);
  hud.clients.textContent = state.link ? String(state.link.clients) : '–';
  updateMetricsHud();
  drawForcePlot();
}

/** The measures in the units an instructor reads: N, mm, s, cm³ (mL), kPa. */
function updateMetricsHud() {
  const m = state.metrics;
  if (!m) return;
  hud.peakForce.textContent = `${m.peakForce.toFixed(3)} N`;
  hud.meanForce.textContent = `${m.meanForce.toFixed(3)} N`;
  hud.path.textContent = `${(m.pathLength * 1e3).toFixed(1)} mm`;
  hud.contact.textContent = `${m.contactTime.toFixed(2)} s`;
  hud.cutOff.textContent = `${(m.cutOffVolume * 1e6).toFixed(3)} cm³`;
  hud.stress.textContent = `${(m.maxStressOutside / 1e3).toFixed(2)} kPa`;
  hud.stressNow.textContent = `${(m.stressOutside / 1e3).toFixed(2)} kPa`;
}

/** |F| over the last PLOT_WINDOW_S seconds of session time, auto-scaled. */
function drawForcePlot() {
  const { width, height } = hud.plot;
  plot.clearRect(0, 0, width, height);
  const peak = forceHistory.reduce((m, s) => Math.max(m, s.f), 0);
  const top = Math.max(0.1, peak * 1.15);
  // Grid: the window's seconds and the scale's top.
  plot.strokeStyle = 'rgba(255,255,255,0.08)';
  plot.lineWidth = 1;
  for (let s = 1; s < PLOT_WINDOW_S; ++s) {
    const x = Math.round((s / PLOT_WINDOW_S) * width) + 0.5;
    plot.beginPath();
    plot.moveTo(x, 0);
    plot.lineTo(x, height);
    plot.stroke();
  }
  plot.fillStyle = '#9aa1b2';
  plot.font = '10px system-ui, sans-serif';
  plot.fillText(`${top.toPrecision(2)} N`, 3, 10);
  if (forceHistory.length === 0) return;
  const end = forceHistory[forceHistory.length - 1].t;
  plot.strokeStyle = '#3cc85a';
  plot.lineWidth = 1.5;
  plot.beginPath();
  forceHistory.forEach((s, i) => {
    const x = width * (1 - (end - s.t) / PLOT_WINDOW_S);
    const y = height - 2 - (height - 14) * (s.f / top);
    if (i === 0) plot.moveTo(x, y);
    else plot.lineTo(x, y);
  });
  plot.stroke();
}

// ---------------------------------------------------------------------------
// Drawing on demand: one requestAnimationFrame per batch of changes.

/** Asks for a draw at the next animation frame; `sceneChanged` marks the 3D view dirty. */
function requestFrame(sceneChanged = false) {
  if (sceneChanged) {
    sceneDirty = true;
    hudDirty = true;
  }
  if (frameQueued) return;
  frameQueued = true;
  requestAnimationFrame(drawFrame);
}

function drawFrame() {
  frameQueued = false;
  if (hudDirty) {
    hudDirty = false;
    updateHud();
  }
  if (sceneDirty && surfaceMesh) {
    sceneDirty = false;
    renderer.render(scene, camera);
    noteDrawn(meshSeq);
    const now = performance.now();
    state.rendered += 1;
    state.lastRenderMs = now;
    state.firstRenderMs ??= now;
    state.lastFrameSimTime = meshSimTime;
  }
}

/**
 * Compiles the shader programs of every material now, while the socket
 * connects, so that the first snapshot only has to upload its buffers: shader
 * compilation is the slowest part of a first frame under software rendering.
 */
function precompileShaders() {
  const placeholder = new THREE.BufferGeometry();
  placeholder.setAttribute('position', new THREE.Float32BufferAttribute([0, 0, 0, 1, 0, 0, 0, 1, 0], 3));
  placeholder.setIndex([0, 1, 2, 0, 2, 1]);
  placeholder.addGroup(0, 3, 0);
  placeholder.addGroup(3, 3, 1);
  const probe = new THREE.Mesh(placeholder, [tissueMaterial, cutMaterial]);
  scene.add(probe);
  scalpel.group.visible = true;
  forceArrow.visible = true;
  renderer.compile(scene, camera);
  scene.remove(probe);
  placeholder.dispose();
  scalpel.group.visible = false;
  forceArrow.visible = false;
}

// The HUD's frame age grows while no frame arrives; refresh the HUD (not the
// 3D view) twice a second so that a stall shows.
setInterval(() => {
  if (state.link) {
    hudDirty = true;
    requestFrame();
  }
}, 500);

resize();
connect();
precompileShaders();
