// The trainee page: mouse, trackpad and keyboard drive the scalpel of a
// cutsim-haptic --device browser station, over a live 3-D view of the tissue
// being cut (three.js): the tissue with its opened faces in their own
// colour, the scalpel, the force on it, the planned incision, and where the
// tip is against the surface under it.
//
// Sends one text message per input event: `p T U V W DX DY DZ B` (T the
// event's time in ms, U V W the tip in the workspace normalised to [0, 1],
// DX DY DZ the blade direction tip → handle, B the buttons: bit 0 cutting,
// bit 1 clutch), and `h` once a second while nothing else is sent (the
// station frees a seat it hears nothing from). Receives a `hello` (the
// workspace, its mapping to the world, the blade, the plan), `force` frames
// at 60 Hz, and binary mesh frames (web/common/mesh_frames.js) from the
// session's mesh stream.
//
// Input lands where the trainee looks: the cursor points at the place on
// the tissue where the blade goes in. The mouse moves the tip in the plane
// through it that faces the camera most (the horizontal plane from above),
// so the depth stays while the mouse moves, and puts the tip where the
// blade, at that depth, crosses the tissue's face towards the camera under
// the cursor: a line seen on the surface is cut where it is seen, whatever
// the depth and the view's tilt. The wheel and the arrow keys change the
// depth along that plane's axis.

import * as THREE from 'three';
import { parseMeshFrame, KIND_SNAPSHOT } from '/common/mesh_frames.js';
import { makeScalpel } from '/common/scalpel.js';
import { makePlanLine } from '/common/plan_line.js';

const COLOURS = {
  background: 0x1e222c,
  tissue: 0xe4988e,
  cutFace: 0xebb91e,
  force: 0x3cc85a,
  above: 0x9be29b,    // the tip's line to the surface: above it
  inside: 0xff8c40,   // below it (in the tissue)
  contact: 0x40e0ff,
  grid: 0x39404c,
};
const FOV_DEG = 35;
const VIEW_DIRECTION = new THREE.Vector3(0.0, -0.55, 1.0).normalize();  // from above, tilted towards −y
const HEARTBEAT_MS = 1000;
const ARROW_FULL_LENGTH = 0.03;  // m, the arrow of the largest force

const state = {
  ws: null,
  renderer: '',           // the WebGL renderer's name (webglRenderer)
  antialias: true,        // multisampled: false on a software renderer
  workspace: null,        // {min: [x,y,z], max: [x,y,z]} in m, device
  worldScale: 1, worldOffset: [0, 0, 0],
  bladeLength: 0.02,
  plan: [],
  meshExpected: false,
  maxForce: 8,
  u: 0.5, v: 0.5, w: 1.0, // the tip, normalised
  tiltX: 0, tiltY: 0,     // blade tilt about x and y, rad
  keyCut: false, mouseCut: false, clutch: false,
  frame: null,            // the last force frame
  lastCuts: 0,
  lastSentMs: 0,
  surfaceGap: null,       // m, tip above (+) or below (−) the surface under it; null: no surface there
  tissueBox: null,        // world box of the tissue as first shown: the cursor aims on its face towards the camera
};

// What the tests and the latency benchmark read.
const stats = {
  framesReceived: 0,
  meshFrames: 0,
  meshSnapshots: 0,
  vertexCount: 0,
  openedCount: 0,
  samplesSent: 0,
  heartbeats: 0,
  maxForceSeen: 0,
  maxCuts: 0,
  closeCode: null,
  rendered: 0,
  fps: 0,
  errors: [],
  latencyMs: [],          // input event → first force frame from a pose that includes it
  pictureMs: [],          // input event → the animation frame after the one that drew that pose
  pending: [],            // input event times awaiting their frame
};
window.trainee = { state, stats, toClient, worldToClient, sendRaw: (text) => state.ws && state.ws.send(text) };

const canvas = document.getElementById('view');
const $ = (id) => document.getElementById(id);
const clamp01 = (x) => Math.min(1, Math.max(0, x));

// ---------------------------------------------------------------------------
// Scene

// The view is drawn on the animation frames after something changed (a
// force frame that moves the tool or changes the force, a mesh frame, the
// camera), so a still page costs nothing.
let dirty = true;

/**
 * The WebGL renderer's name, and whether it draws in software (SwiftShader,
 * llvmpipe: a station without a GPU, or a headless browser). There a
 * multisampled frame takes most of the page's time, and the page's one
 * thread would hold every input event and force frame behind it, so the
 * view is drawn without multisampling.
 */
function webglRenderer() {
  const probe = document.createElement('canvas');
  const gl = probe.getContext('webgl2') || probe.getContext('webgl');
  if (!gl) return { name: 'none', software: false };
  const info = gl.getExtension('WEBGL_debug_renderer_info');
  const name = String(gl.getParameter(info ? info.UNMASKED_RENDERER_WEBGL : gl.RENDERER));
  const lose = gl.getExtension('WEBGL_lose_context');
  if (lose) lose.loseContext();
  return { name, software: /swiftshader|llvmpipe|softpipe|software/i.test(name) };
}
const gpu = webglRenderer();
state.renderer = gpu.name;
state.antialias = !gpu.software;

const renderer = new THREE.WebGLRenderer({ canvas, antialias: state.antialias, preserveDrawingBuffer: true });
THREE.ColorManagement.enabled = false;
renderer.outputColorSpace = THREE.LinearSRGBColorSpace;
renderer.setPixelRatio(window.devicePixelRatio || 1);
const scene = new THREE.Scene();
scene.background = new THREE.Color(COLOURS.background);
const camera = new THREE.PerspectiveCamera(FOV_DEG, 1, 1e-4, 10);
camera.up.set(0, 0, 1);
scene.add(camera);
scene.add(new THREE.AmbientLight(0xffffff, 0.22 * Math.PI));
for (const [intensity, direction] of [[0.66, new THREE.Vector3(-0.35, 0.45, 1.0)], [0.12, new THREE.Vector3(0.6, -0.3, 0.4)]]) {
  const light = new THREE.DirectionalLight(0xffffff, intensity * Math.PI);
  light.position.copy(direction).normalize();
  light.target = camera;
  camera.add(light);
}
const view = { target: new THREE.Vector3(), distance: 0.15, azimuth: 0, polar: 0, framed: false };
{
  // Azimuth and polar angle (from +z) of VIEW_DIRECTION.
  view.polar = Math.acos(VIEW_DIRECTION.z);
  view.azimuth = Math.atan2(VIEW_DIRECTION.y, VIEW_DIRECTION.x);
}

const tissueMaterial = new THREE.MeshLambertMaterial({ color: COLOURS.tissue, side: THREE.DoubleSide, flatShading: true });
const cutMaterial = new THREE.MeshLambertMaterial({
  color: COLOURS.cutFace, side: THREE.DoubleSide, flatShading: true,
  polygonOffset: true, polygonOffsetFactor: -1, polygonOffsetUnits: -1,
});
let surfaceMesh = null;

const scalpel = makeScalpel(THREE);
scene.add(scalpel.group);

const forceMaterial = new THREE.MeshLambertMaterial({ color: COLOURS.force });
const forceShaft = new THREE.Mesh(new THREE.CylinderGeometry(1, 1, 1, 12).translate(0, 0.5, 0), forceMaterial);
const forceHead = new THREE.Mesh(new THREE.ConeGeometry(1, 1, 16).translate(0, 0.5, 0), forceMaterial);
const forceArrow = new THREE.Group();
forceArrow.add(forceShaft, forceHead);
forceArrow.visible = false;
scene.add(forceArrow);

// The depth cue: a ring on the surface under the tip, a line from the tip
// to it (its colour says above or inside), the ring lit on contact.
const ringMaterial = new THREE.MeshBasicMaterial({ color: COLOURS.above, side: THREE.DoubleSide, depthTest: false,
  transparent: true, opacity: 0.9 });
const ring = new THREE.Mesh(new THREE.RingGeometry(0.7, 1.0, 32), ringMaterial);
ring.renderOrder = 10;
ring.visible = false;
scene.add(ring);
const gapMaterial = new THREE.LineDashedMaterial({ color: COLOURS.above, dashSize: 0.001, gapSize: 0.0007,
  depthTest: false });
const gapLine = new THREE.Line(new THREE.BufferGeometry().setFromPoints([new THREE.Vector3(), new THREE.Vector3()]),
  gapMaterial);
gapLine.renderOrder = 10;
gapLine.visible = false;
scene.add(gapLine);
let planLine = null;
let grid = null;

const raycaster = new THREE.Raycaster();
const Y_AXIS = new THREE.Vector3(0, 1, 0);

function toWorld(d) {
  const s = state.worldScale, o = state.worldOffset;
  return new THREE.Vector3(s * d[0] + o[0], s * d[1] + o[1], s * d[2] + o[2]);
}
function toDevice(p) {
  const s = state.worldScale, o = state.worldOffset;
  return [(p.x - o[0]) / s, (p.y - o[1]) / s, (p.z - o[2]) / s];
}
/** The commanded tip in device metres. */
function commandedDevice() {
  const ws = state.workspace;
  const n = [state.u, state.v, state.w];
  return n.map((x, i) => ws.min[i] + x * (ws.max[i] - ws.min[i]));
}

function placeCamera() {
  const dir = new THREE.Vector3(Math.sin(view.polar) * Math.cos(view.azimuth),
    Math.sin(view.polar) * Math.sin(view.azimuth), Math.cos(view.polar));
  camera.position.copy(view.target).addScaledVector(dir, view.distance);
  camera.near = view.distance * 0.01;
  camera.far = view.distance * 100;
  camera.lookAt(view.target);
  camera.updateProjectionMatrix();
  $('view-state').textContent = `view ${THREE.MathUtils.radToDeg(view.azimuth).toFixed(0)}° around, `
    + `${THREE.MathUtils.radToDeg(view.polar).toFixed(0)}° from above`;
  dirty = true;
}

/** Frames `box` (world) in the view. */
function frameOn(box) {
  const radius = Math.max(0.5 * box.getSize(new THREE.Vector3()).length(), 1e-3);
  box.getCenter(view.target);
  const halfV = THREE.MathUtils.degToRad(0.5 * FOV_DEG);
  const halfH = Math.atan(camera.aspect * Math.tan(halfV));
  view.distance = 1.05 * radius / Math.sin(Math.min(halfV, halfH));
  placeCamera();
}

function workspaceBox() {
  const ws = state.workspace;
  return new THREE.Box3().setFromPoints([toWorld(ws.min), toWorld(ws.max)]);
}

function resize() {
  const width = canvas.clientWidth || window.innerWidth;
  const height = canvas.clientHeight || window.innerHeight;
  renderer.setSize(width, height, false);
  camera.aspect = width / Math.max(height, 1);
  camera.updateProjectionMatrix();
  dirty = true;
}
window.addEventListener('resize', resize);

function applyMesh(buffer) {
  const frame = parseMeshFrame(buffer);
  if (typeof frame === 'string') {
    if (stats.errors.length < 100) stats.errors.push(frame);
    return;
  }
  if (frame.kind === KIND_SNAPSHOT) {
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
      surfaceMesh.frustumCulled = false;
      scene.add(surfaceMesh);
    }
    if (!view.framed && frame.V > 0) {
      state.tissueBox = geometry.boundingBox.clone();
      // The tissue fills the view, with room around it for the tool.
      const box = geometry.boundingBox.clone();
      const centre = box.getCenter(new THREE.Vector3());
      box.min.sub(centre).multiplyScalar(1.3).add(centre);
      box.max.sub(centre).multiplyScalar(1.3).add(centre);
      frameOn(box);
      view.framed = true;
    }
    stats.meshSnapshots += 1;
    stats.vertexCount = frame.V;
    stats.openedCount = frame.O;
  } else {
    if (!surfaceMesh || frame.V !== stats.vertexCount) return;
    const position = surfaceMesh.geometry.getAttribute('position');
    position.array.set(frame.positions);
    position.needsUpdate = true;
    surfaceMesh.geometry.computeBoundingSphere();
  }
  stats.meshFrames += 1;
  dirty = true;
}

function onHello(m) {
  state.workspace = { min: m.workspace_min, max: m.workspace_max };
  state.maxForce = m.max_force > 0 ? m.max_force : 8;
  state.worldScale = m.world_scale > 0 ? m.world_scale : 1;
  state.worldOffset = Array.isArray(m.world_offset) ? m.world_offset : [0, 0, 0];
  state.bladeLength = m.blade_length > 0 ? m.blade_length : 0.02;
  state.plan = Array.isArray(m.plan) ? m.plan : [];
  state.meshExpected = m.mesh === true;
  if (!state.meshExpected) $('surface').textContent = 'no tissue view (the station reads no mesh stream)';
  const box = workspaceBox();
  if (grid) scene.remove(grid);
  const size = box.getSize(new THREE.Vector3());
  grid = new THREE.GridHelper(Math.max(size.x, size.y), Math.round(Math.max(size.x, size.y) / 0.005), COLOURS.grid, COLOURS.grid);
  grid.rotation.x = Math.PI / 2;  // the xy plane
  grid.position.set(box.getCenter(new THREE.Vector3()).x, box.getCenter(new THREE.Vector3()).y, box.min.z);
  scene.add(grid);
  if (planLine) scene.remove(planLine);
  planLine = makePlanLine(THREE, state.plan);
  if (planLine) scene.add(planLine);
  if (!view.framed) frameOn(box);
  send(performance.now());
}

// ---------------------------------------------------------------------------
// Input

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
  state.lastSentMs = performance.now();
  stats.samplesSent += 1;
  if (stats.pending.length < 1000) stats.pending.push(t);
}

/** The world axis (0, 1, 2) the camera looks along most, and its sign towards the camera. */
function inputAxis() {
  const toCamera = new THREE.Vector3().subVectors(camera.position, view.target);
  const a = [Math.abs(toCamera.x), Math.abs(toCamera.y), Math.abs(toCamera.z)];
  const axis = a[2] >= a[0] && a[2] >= a[1] ? 2 : (a[0] >= a[1] ? 0 : 1);
  return { axis, sign: Math.sign(toCamera.getComponent(axis)) || 1 };
}

const ndc = new THREE.Vector2();

/**
 * Where the cursor aims along the input axis: the tissue's face towards the
 * camera as first shown (its top seen from above); without a tissue view,
 * the tip's own plane.
 */
function aimLevel(axis, sign, tip) {
  const box = state.tissueBox;
  if (!box) return tip.getComponent(axis);
  return sign > 0 ? box.max.getComponent(axis) : box.min.getComponent(axis);
}

/**
 * From the tip (world) to where its blade crosses the aim level: along the
 * blade while it is within 60° of the input axis, else straight along the
 * axis.
 */
function tipToAim(tip, axis, level) {
  const d = bladeDirection();
  const along = Math.abs(d[axis]) >= 0.5 ? new THREE.Vector3(d[0], d[1], d[2])
    : new THREE.Vector3().setComponent(axis, 1);
  return along.multiplyScalar((level - tip.getComponent(axis)) / along.getComponent(axis));
}

/** Moves the commanded tip, at its depth, under the client point (x, y) (see the file's comment). */
function aimAt(clientX, clientY) {
  if (!state.workspace) return;
  const r = canvas.getBoundingClientRect();
  ndc.set(2 * (clientX - r.left) / r.width - 1, 1 - 2 * (clientY - r.top) / r.height);
  raycaster.setFromCamera(ndc, camera);
  const { axis, sign } = inputAxis();
  const tip = toWorld(commandedDevice());
  const level = aimLevel(axis, sign, tip);
  const normal = new THREE.Vector3().setComponent(axis, 1);
  const plane = new THREE.Plane(normal, -level);
  const hit = raycaster.ray.intersectPlane(plane, new THREE.Vector3());
  if (!hit) return;
  hit.sub(tipToAim(tip, axis, level));  // the tip at its depth under the aimed point
  hit.setComponent(axis, tip.getComponent(axis));
  const d = toDevice(hit);
  const ws = state.workspace;
  const n = d.map((x, i) => clamp01((x - ws.min[i]) / (ws.max[i] - ws.min[i])));
  if (axis !== 0) state.u = n[0];
  if (axis !== 1) state.v = n[1];
  if (axis !== 2) state.w = n[2];
}

/** The client point of world point `p` ([x, y, z], m) in the view (tests). */
function worldToClient(p) {
  const q = new THREE.Vector3(p[0], p[1], p[2]).project(camera);
  const r = canvas.getBoundingClientRect();
  return { x: r.left + (q.x + 1) / 2 * r.width, y: r.top + (1 - q.y) / 2 * r.height };
}

/** The client point that puts the tip over device (x, y) at the commanded depth (tests). */
function toClient(x, y) {
  const { axis, sign } = inputAxis();
  const tip = toWorld([x, y, commandedDevice()[2]]);
  const aimed = tip.clone().add(tipToAim(tip, axis, aimLevel(axis, sign, tip)));
  return worldToClient([aimed.x, aimed.y, aimed.z]);
}

function stepDepth(sign) {
  const ws = state.workspace;
  if (!ws) return;
  const { axis, sign: towards } = inputAxis();
  const step = 0.001 / (ws.max[axis] - ws.min[axis]);
  const key = ['u', 'v', 'w'][axis];
  state[key] = clamp01(state[key] + sign * towards * step);
}

let orbiting = null;  // the last pointer position of a right-button drag
canvas.addEventListener('contextmenu', (e) => e.preventDefault());
canvas.addEventListener('pointermove', (e) => {
  if (orbiting) {
    orbit(-(e.clientX - orbiting.x) * 0.008, -(e.clientY - orbiting.y) * 0.008);
    orbiting = { x: e.clientX, y: e.clientY };
    return;
  }
  aimAt(e.clientX, e.clientY);
  send(e.timeStamp);
});
canvas.addEventListener('pointerdown', (e) => {
  canvas.focus();
  canvas.setPointerCapture(e.pointerId);
  if (e.button === 2) {
    orbiting = { x: e.clientX, y: e.clientY };
    return;
  }
  if (e.button !== 0) return;
  state.mouseCut = true;
  send(e.timeStamp);
});
canvas.addEventListener('pointerup', (e) => {
  if (e.button === 2) {
    orbiting = null;
    return;
  }
  if (e.button !== 0) return;
  state.mouseCut = false;
  send(e.timeStamp);
});
canvas.addEventListener('wheel', (e) => {
  e.preventDefault();
  if (e.shiftKey) {
    zoom(e.deltaY > 0 ? 1.1 : 1 / 1.1);  // Shift + wheel: zoom, the tool stays
    return;
  }
  stepDepth(-Math.sign(e.deltaY));
  send(e.timeStamp);
}, { passive: false });

function orbit(dAzimuth, dPolar) {
  view.azimuth += dAzimuth;
  view.polar = Math.min(Math.PI * 0.95, Math.max(0.02, view.polar + dPolar));
  placeCamera();
}

function zoom(factor) {
  view.distance = Math.min(2, Math.max(0.01, view.distance * factor));
  placeCamera();
}

const kTilt = Math.PI / 12;
const kMaxTilt = Math.PI / 3;
const kOrbit = Math.PI / 12;
window.addEventListener('keydown', (e) => {
  let moved = true;
  switch (e.key) {
    case ' ': state.keyCut = true; break;
    case 'c': case 'C': state.clutch = true; break;
    case 'ArrowUp': case 'PageUp': stepDepth(1); break;
    case 'ArrowDown': case 'PageDown': stepDepth(-1); break;
    case 'a': case 'A': state.tiltY = Math.max(-kMaxTilt, state.tiltY - kTilt); break;
    case 'd': case 'D': state.tiltY = Math.min(kMaxTilt, state.tiltY + kTilt); break;
    case 'q': case 'Q': state.tiltX = Math.max(-kMaxTilt, state.tiltX - kTilt); break;
    case 'e': case 'E': state.tiltX = Math.min(kMaxTilt, state.tiltX + kTilt); break;
    case 'r': case 'R': state.tiltX = 0; state.tiltY = 0; break;
    case 'j': case 'J': moved = false; orbit(-kOrbit, 0); break;
    case 'l': case 'L': moved = false; orbit(kOrbit, 0); break;
    case 'i': case 'I': moved = false; orbit(0, -kOrbit / 2); break;
    case 'k': case 'K': moved = false; orbit(0, kOrbit / 2); break;
    case '+': case '=': moved = false; zoom(1 / 1.2); break;
    case '-': case '_': moved = false; zoom(1.2); break;
    default: return;
  }
  e.preventDefault();
  if (moved) send(e.timeStamp);  // turning the view never moves the tool
});
window.addEventListener('keyup', (e) => {
  if (e.key === ' ') state.keyCut = false;
  else if (e.key === 'c' || e.key === 'C') state.clutch = false;
  else return;
  e.preventDefault();
  send(e.timeStamp);
});

// The station frees a seat it hears nothing from: say we are here.
setInterval(() => {
  const ws = state.ws;
  if (ws && ws.readyState === WebSocket.OPEN && performance.now() - state.lastSentMs >= HEARTBEAT_MS) {
    ws.send('h');
    state.lastSentMs = performance.now();
    stats.heartbeats += 1;
  }
}, HEARTBEAT_MS / 2);

// ---------------------------------------------------------------------------
// The station

function onFrame(m) {
  const now = performance.now();
  stats.framesReceived += 1;
  const last = state.frame;
  if (!last || m.contact !== last.contact || m.buttons !== last.buttons || m.cuts !== last.cuts
      || m.tip.some((x, i) => x !== last.tip[i]) || m.force.some((x, i) => x !== last.force[i])) {
    dirty = true;
  }
  state.frame = m;
  const f = Math.hypot(m.force[0], m.force[1], m.force[2]);
  stats.maxForceSeen = Math.max(stats.maxForceSeen, f);
  stats.maxCuts = Math.max(stats.maxCuts, m.cuts);
  state.lastCuts = m.cuts;
  // Latency: every input up to the newest sample in the rendered pose; the
  // view draws that pose at the next animation frame.
  if (m.used_ms >= 0) {
    let n = 0;
    while (n < stats.pending.length && stats.pending[n] <= m.used_ms + 1e-3) ++n;
    for (let i = 0; i < n; ++i) {
      if (stats.latencyMs.length < 100000) stats.latencyMs.push(now - stats.pending[i]);
      if (toDraw.length < 1000) toDraw.push(stats.pending[i]);
    }
    stats.pending.splice(0, n);
    if (n > 0) dirty = true;
  }
  $('force-value').textContent = `${f.toFixed(2)} N`;
  $('force-bar').style.width = `${Math.min(100, 100 * f / state.maxForce).toFixed(1)}%`;
  $('cuts').textContent = String(m.cuts);
  const cutting = (m.buttons & 1) !== 0;
  $('cutting').dataset.on = String(cutting);
  $('cutting').textContent = cutting ? 'CUTTING' : 'cutting off';
  $('contact').dataset.on = String(m.contact);
  $('contact').textContent = m.contact ? 'CONTACT' : 'no contact';
  const ws = state.workspace;
  $('depth-value').textContent = `${(1e3 * m.tip[2]).toFixed(1)} mm`;
  $('depth-bar').style.width = `${(100 * (m.tip[2] - ws.min[2]) / (ws.max[2] - ws.min[2])).toFixed(1)}%`;
  $('tip').textContent = `tip ${m.tip.map((x) => (1e3 * x).toFixed(1)).join(', ')} mm`;
}

function connect() {
  const params = new URLSearchParams(location.search);
  const token = params.get('token') || '';
  const ws = new WebSocket(`ws://${location.host}/ws?token=${encodeURIComponent(token)}`);
  ws.binaryType = 'arraybuffer';
  state.ws = ws;
  ws.onopen = () => { $('status').dataset.state = 'connected'; $('status').textContent = 'connected'; };
  ws.onclose = (e) => {
    stats.closeCode = e.code;
    const refused = state.workspace === null;
    $('status').dataset.state = refused ? 'refused' : 'closed';
    $('status').textContent = refused ? 'refused (wrong link, or a trainee is already connected)' : `closed (${e.code})`;
  };
  ws.onmessage = (e) => {
    if (e.data instanceof ArrayBuffer) {
      applyMesh(e.data);
      return;
    }
    const m = JSON.parse(e.data);
    if (m.kind === 'hello') onHello(m);
    else if (m.kind === 'force') onFrame(m);
  };
}

// ---------------------------------------------------------------------------
// Drawing: at the animation frame after anything changed (the blade moves
// with the force frames, one per new input).

const down = new THREE.Vector3();
function updateDepthCue(tip, contact) {
  state.surfaceGap = null;
  if (!surfaceMesh) {
    ring.visible = gapLine.visible = false;
    return;
  }
  // The surface under the tip, seen from the camera's side along the input axis.
  const { axis, sign } = inputAxis();
  down.set(0, 0, 0).setComponent(axis, -sign);
  const from = tip.clone().addScaledVector(down, -10 * view.distance);
  raycaster.set(from, down);
  raycaster.near = 0;
  raycaster.far = Infinity;
  const hits = raycaster.intersectObject(surfaceMesh, false);
  if (hits.length === 0) {
    ring.visible = gapLine.visible = false;
    $('surface').textContent = 'no tissue under the tip';
    return;
  }
  const p = hits[0].point;
  const gap = tip.clone().sub(p).dot(down) * -1;  // + above the surface
  state.surfaceGap = gap;
  const colour = contact ? COLOURS.contact : (gap >= 0 ? COLOURS.above : COLOURS.inside);
  ringMaterial.color.setHex(colour);
  gapMaterial.color.setHex(colour);
  ring.position.copy(p).addScaledVector(down, -1e-4);
  ring.quaternion.setFromUnitVectors(new THREE.Vector3(0, 0, 1), down);
  const r = (contact ? 0.0025 : 0.0015) * Math.max(1, view.distance / 0.15);
  ring.scale.set(r, r, r);
  ring.visible = true;
  gapLine.geometry.setFromPoints([tip, p]);
  gapLine.computeLineDistances();
  gapLine.visible = true;
  $('surface').textContent = contact ? `CONTACT, ${(1e3 * Math.abs(gap)).toFixed(1)} mm ${gap >= 0 ? 'above' : 'into'} the surface`
    : (gap >= 0 ? `${(1e3 * gap).toFixed(1)} mm above the surface` : `${(1e3 * -gap).toFixed(1)} mm into the tissue`);
}

function placeTool() {
  const m = state.frame;
  if (!m || !state.workspace) return;
  const tip = toWorld(m.tip);
  const d = bladeDirection();
  $('blade').textContent = `blade ${d.map((x) => x.toFixed(2)).join(', ')}`;
  scalpel.place(tip, new THREE.Vector3(d[0], d[1], d[2]), state.bladeLength);
  const f = new THREE.Vector3(m.force[0], m.force[1], m.force[2]);
  const magnitude = f.length();
  if (magnitude > 1e-3 && Number.isFinite(magnitude)) {
    const length = ARROW_FULL_LENGTH * Math.min(1, magnitude / state.maxForce) + 0.002;
    const r = 0.0004;
    forceArrow.position.copy(tip);
    forceArrow.quaternion.setFromUnitVectors(Y_AXIS, f.divideScalar(magnitude));
    forceShaft.scale.set(r, 0.75 * length, r);
    forceHead.position.set(0, 0.75 * length, 0);
    forceHead.scale.set(2.5 * r, 0.25 * length, 2.5 * r);
    forceArrow.visible = true;
  } else {
    forceArrow.visible = false;
  }
  updateDepthCue(tip, m.contact);
}

let fpsWindowStart = performance.now();
let fpsFrames = 0;
let lastBlade = '';
// Input-to-picture: the input times whose pose a force frame brought
// (toDraw), then drawn and waiting for the next animation frame, by which
// the drawn frame has gone to the compositor (drawn).
let toDraw = [];
let drawn = [];
function draw(now) {
  requestAnimationFrame(draw);
  if (drawn.length > 0) {
    const shown = performance.now();
    for (const t of drawn) if (stats.pictureMs.length < 100000) stats.pictureMs.push(shown - t);
    drawn = [];
  }
  const blade = `${state.tiltX} ${state.tiltY}`;
  if (blade !== lastBlade) {
    lastBlade = blade;
    dirty = true;
  }
  if (!dirty) return;
  dirty = false;
  placeTool();
  renderer.render(scene, camera);
  drawn = toDraw;
  toDraw = [];
  stats.rendered += 1;
  fpsFrames += 1;
  if (now - fpsWindowStart >= 1000) {
    stats.fps = 1000 * fpsFrames / (now - fpsWindowStart);
    fpsWindowStart = now;
    fpsFrames = 0;
  }
}

resize();
placeCamera();
connect();
requestAnimationFrame(draw);
