// The scalpel both pages draw: a flat steel blade (a No. 10 blade's outline:
// straight back, curved cutting edge rising from the tip) on a slimmer
// handle, oriented by the tool's blade direction (tip → handle). The blade's
// flat side holds the blade direction and the direction the tip last moved
// across it, so the edge faces the way the blade cuts. Sizes are in metres,
// the blade's length from the scene (ToolView.blade_length).

const BLADE_COLOUR = 0xb4bcce;   // steel (the pages' tool hue, 195–250°)
const HANDLE_COLOUR = 0x7c8aa8;
const BLADE_THICKNESS = 0.0004;  // m
const HANDLE_LENGTH = 0.05;      // m
const HANDLE_WIDTH = 0.008;      // m
const HANDLE_THICKNESS = 0.003;  // m

/**
 * Builds a scalpel with `THREE`. Returns {group, place(tip, bladeDir,
 * bladeLength)}: vectors THREE.Vector3 in world metres. The edge faces the
 * way the tip last moved across the blade (a move along the blade, a change
 * of depth, keeps it where it was); before any move it faces +x.
 */
export function makeScalpel(THREE) {
  const group = new THREE.Group();
  // Local frame: +y from the tip along the blade to the handle, +x the edge
  // side, z the blade's thin axis. Unit blade length; scaled in place().
  const outline = new THREE.Shape();
  outline.moveTo(0, 0);
  outline.quadraticCurveTo(0.32, 0.18, 0.3, 0.62);  // the curved edge
  outline.lineTo(0.2, 1.0);
  outline.lineTo(-0.06, 1.0);
  outline.lineTo(-0.06, 0.3);                       // the straight back
  outline.lineTo(0, 0);
  const bladeGeometry = new THREE.ExtrudeGeometry(outline, { depth: 1, bevelEnabled: false, curveSegments: 10 });
  bladeGeometry.translate(0, 0, -0.5);
  // The blade glows a little so steel reads as steel from any side.
  const blade = new THREE.Mesh(bladeGeometry, new THREE.MeshLambertMaterial({
    color: BLADE_COLOUR, emissive: 0x23262c, side: THREE.DoubleSide }));
  const handleGeometry = new THREE.BoxGeometry(1, 1, 1).translate(0, 0.5, 0);
  // The handle is see-through, so it never hides the tissue under the blade.
  const handle = new THREE.Mesh(handleGeometry, new THREE.MeshLambertMaterial({
    color: HANDLE_COLOUR, transparent: true, opacity: 0.45, depthWrite: false }));
  handle.renderOrder = 2;
  group.add(blade, handle);
  group.visible = false;

  const basis = new THREE.Matrix4();
  const x = new THREE.Vector3();
  const y = new THREE.Vector3();
  const z = new THREE.Vector3();
  const cutDir = new THREE.Vector3(1, 0, 0);
  const lastTip = new THREE.Vector3();
  const move = new THREE.Vector3();
  let moved = false;

  function place(tip, bladeDir, bladeLength) {
    y.copy(bladeDir);
    if (!(y.lengthSq() > 0)) y.set(0, 0, 1);
    y.normalize();
    if (moved) {
      move.subVectors(tip, lastTip);
      const total = move.lengthSq();
      move.addScaledVector(y, -move.dot(y));
      if (move.lengthSq() > 1e-10 && move.lengthSq() > 0.25 * total) cutDir.copy(move);
    }
    lastTip.copy(tip);
    moved = true;
    // The edge side: cutDir without its part along the blade.
    x.copy(cutDir);
    x.addScaledVector(y, -x.dot(y));
    if (x.lengthSq() < 1e-8) x.set(0, 1, 0).addScaledVector(y, -y.y);
    if (x.lengthSq() < 1e-8) x.set(1, 0, 0).addScaledVector(y, -y.x);
    x.normalize();
    z.crossVectors(x, y);
    basis.makeBasis(x, y, z);
    group.position.copy(tip);
    group.quaternion.setFromRotationMatrix(basis);
    const L = bladeLength > 0 ? bladeLength : 0.02;
    blade.scale.set(L, L, BLADE_THICKNESS);
    handle.position.set(0.07 * L, L, 0);
    handle.scale.set(HANDLE_WIDTH, HANDLE_LENGTH, HANDLE_THICKNESS);
    group.visible = true;
  }

  return { group, place };
}
