// The planned incision both pages draw: a thin tube along the scene's
// planned line (world metres, in cutting order), drawn over the tissue
// (no depth test) so the trainee and the instructor see the whole line even
// where it runs on the surface. A tube rather than a line: WebGL draws lines
// one pixel wide, too faint on the tissue to aim at.

export const PLAN_COLOUR = 0x4fc3f7;
export const PLAN_RADIUS = 0.00025;  // m

/**
 * Builds the line with `THREE` from `points` ([x, y, z] arrays, m). Returns
 * a THREE.Mesh, or null for fewer than two points.
 */
export function makePlanLine(THREE, points) {
  if (!Array.isArray(points) || points.length < 2) return null;
  const v = points.map((p) => new THREE.Vector3(p[0], p[1], p[2]));
  const path = new THREE.CurvePath();
  for (let i = 1; i < v.length; ++i) path.add(new THREE.LineCurve3(v[i - 1], v[i]));
  const line = new THREE.Mesh(new THREE.TubeGeometry(path, 16 * (v.length - 1), PLAN_RADIUS, 8, false),
    new THREE.MeshBasicMaterial({ color: PLAN_COLOUR, depthTest: false }));
  line.renderOrder = 5;
  return line;
}
