"""Structured quadratic meshes of a box and CalculiX input decks on them.

The box [0, size] is cut into n[0]·n[1]·n[2] cells. All nodes of a quadratic
mesh of it (corners and mid-side nodes) lie on the "doubled" grid with
2·n + 1 points per axis, so a node is named by its doubled-grid index and the
meshes conform by construction.

  * C3D10: each cell is split into 6 tets around its lo→hi diagonal
    (Kuhn/Freudenthal), the same split as cutsim's MakeBox, so faces conform;
    mid-side nodes sit on the straight edges.
  * C3D20R: each cell is one 20-node serendipity hex (reduced integration),
    which does not lock for nearly incompressible material.

Node and element numbering follows CalculiX (the Abaqus convention).
"""

import itertools

import numpy as np

# Edges of a 10-node tet, by local corner index: nodes 5..10.
TET10_EDGES = ((0, 1), (1, 2), (2, 0), (0, 3), (1, 3), (2, 3))
# Faces of a tet by local corner index, with their edges' local node numbers.
TET_FACES = (((0, 1, 2), (4, 5, 6)), ((0, 1, 3), (4, 8, 7)), ((1, 2, 3), (5, 9, 8)), ((0, 2, 3), (6, 9, 7)))
# Corners of a 20-node hex (unit-cube offsets), then its edges: nodes 9..20.
HEX_CORNERS = ((0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0), (0, 0, 1), (1, 0, 1), (1, 1, 1), (0, 1, 1))
HEX20_EDGES = ((0, 1), (1, 2), (2, 3), (3, 0), (4, 5), (5, 6), (6, 7), (7, 4), (0, 4), (1, 5), (2, 6), (3, 7))
# Faces of a hex (corner indices, outward when seen from outside) and their edge nodes.
HEX_FACES = (
    ((0, 3, 2, 1), (11, 10, 9, 8)),
    ((4, 5, 6, 7), (12, 13, 14, 15)),
    ((0, 1, 5, 4), (8, 17, 12, 16)),
    ((1, 2, 6, 5), (9, 18, 13, 17)),
    ((2, 3, 7, 6), (10, 19, 14, 18)),
    ((3, 0, 4, 7), (11, 16, 15, 19)),
)


class QuadraticBoxMesh:
    """Quadratic mesh of the box [0, size] with n cells per axis.

    Attributes:
      nodes: dict node id → position (m), ids 1-based as CalculiX wants them.
      elements: list of node-id tuples (10 or 20 nodes).
      element_type: "C3D10" or "C3D20R".
      faces: list of (corner ids, mid-side ids) of every element face (a face
        shared by two elements appears twice; boundary faces once).
    """

    def __init__(self, size, n, element_type):
        if element_type not in ("C3D10", "C3D20R"):
            raise ValueError(f"unsupported element type {element_type!r}")
        self.size = np.asarray(size, dtype=float)
        self.n = tuple(int(v) for v in n)
        self.element_type = element_type
        self._dims = tuple(2 * v + 1 for v in self.n)
        self.nodes = {}
        self.elements = []
        self.faces = []
        for cell in itertools.product(*(range(v) for v in self.n)):
            if element_type == "C3D10":
                self._add_kuhn_tets(cell)
            else:
                self._add_hex(cell)

    # ---- nodes on the doubled grid ------------------------------------------
    def _node(self, doubled):
        i, j, k = doubled
        nid = 1 + i + self._dims[0] * (j + self._dims[1] * k)
        if nid not in self.nodes:
            self.nodes[nid] = self.size * np.array(doubled, dtype=float) / (2.0 * np.array(self.n))
        return nid

    def _corner(self, cell, offset):
        return tuple(2 * (c + o) for c, o in zip(cell, offset))

    def _mid(self, a, b):
        return tuple((p + q) // 2 for p, q in zip(a, b))

    # ---- elements -------------------------------------------------------------
    def _add_kuhn_tets(self, cell):
        for perm in itertools.permutations(range(3)):
            offsets = [(0, 0, 0)]
            step = [0, 0, 0]
            for axis in perm:
                step[axis] = 1
                offsets.append(tuple(step))
            corners = [self._corner(cell, o) for o in offsets]
            if _signed_volume([np.array(c, dtype=float) for c in corners]) < 0:
                corners[1], corners[2] = corners[2], corners[1]
            ids = [self._node(c) for c in corners]
            ids += [self._node(self._mid(corners[a], corners[b])) for a, b in TET10_EDGES]
            self.elements.append(tuple(ids))
            self._add_faces(ids, TET_FACES)

    def _add_hex(self, cell):
        corners = [self._corner(cell, o) for o in HEX_CORNERS]
        ids = [self._node(c) for c in corners]
        ids += [self._node(self._mid(corners[a], corners[b])) for a, b in HEX20_EDGES]
        self.elements.append(tuple(ids))
        self._add_faces(ids, HEX_FACES)

    def _add_faces(self, ids, table):
        """Adds the element's faces, each ordered so its normal points out."""
        centre = np.mean([self.nodes[i] for i in ids], axis=0)
        for face_corners, face_mids in table:
            corners = [ids[c] for c in face_corners]
            mids = [ids[m] for m in face_mids]
            p = [self.nodes[c] for c in corners]
            normal = np.cross(p[1] - p[0], p[2] - p[0])
            if np.dot(normal, np.mean(p, axis=0) - centre) < 0:
                corners = corners[:1] + corners[:0:-1]
                mids = mids[::-1]
            self.faces.append((tuple(corners), tuple(mids)))

    # ---- queries --------------------------------------------------------------
    def nodes_where(self, predicate):
        """Sorted ids of the nodes whose position satisfies predicate(p)."""
        return sorted(nid for nid, p in self.nodes.items() if predicate(p))

    def corner_ids(self):
        """Ids of the element corner nodes (the nodes a linear mesh would have)."""
        count = 4 if self.element_type == "C3D10" else 8
        return sorted({nid for element in self.elements for nid in element[:count]})

    def boundary_faces(self):
        """Faces that belong to exactly one element."""
        seen = {}
        for face in self.faces:
            seen.setdefault(frozenset(face[0]), []).append(face)
        return [faces[0] for faces in seen.values() if len(faces) == 1]

    def faces_on_plane(self, axis, value, tol=1e-12):
        """Boundary faces whose corners all lie on the plane x[axis] = value."""
        return [f for f in self.boundary_faces() if all(abs(self.nodes[c][axis] - value) < tol for c in f[0])]


def _signed_volume(p):
    return float(np.dot(np.cross(p[1] - p[0], p[2] - p[0]), p[3] - p[0])) / 6.0


# ---- face integration (quadratic faces) --------------------------------------
# Integration weights of a nodal field over a flat face, as fractions of the
# face area: 6-node triangle (corners 0, mid-sides 1/3) and 8-node serendipity
# quad on a parallelogram (corners −1/12, mid-sides 1/3).
_FACE_WEIGHTS = {3: (0.0, 1.0 / 3.0), 4: (-1.0 / 12.0, 1.0 / 3.0)}


def _flat_face_area(points):
    if len(points) == 3:
        return 0.5 * np.linalg.norm(np.cross(points[1] - points[0], points[2] - points[0]))
    return np.linalg.norm(np.cross(points[2] - points[0], points[3] - points[1])) * 0.5


def face_mean(mesh, faces, values):
    """Area-weighted mean over `faces` (undeformed) of the nodal field `values`
    (dict node id → float), integrated with the quadratic shape functions."""
    total, area = 0.0, 0.0
    for corners, mids in faces:
        a = _flat_face_area([mesh.nodes[c] for c in corners])
        wc, wm = _FACE_WEIGHTS[len(corners)]
        total += a * (wc * sum(values[c] for c in corners) + wm * sum(values[m] for m in mids))
        area += a
    return total / area


# Degree-4 rule on the unit triangle (6 points, Dunavant), weights sum to 1/2.
_TRI_RULE = (
    [(0.445948490915965, 0.445948490915965), (0.108103018168070, 0.445948490915965),
     (0.445948490915965, 0.108103018168070), (0.091576213509771, 0.091576213509771),
     (0.816847572980459, 0.091576213509771), (0.091576213509771, 0.816847572980459)],
    [0.111690794839005] * 3 + [0.054975871827661] * 3,
)
_GAUSS4 = np.polynomial.legendre.leggauss(4)


def _tri6(r, s):
    t = 1.0 - r - s
    n = np.array([t * (2 * t - 1), r * (2 * r - 1), s * (2 * s - 1), 4 * t * r, 4 * r * s, 4 * s * t])
    dr = np.array([1 - 4 * t, 4 * r - 1, 0, 4 * (t - r), 4 * s, -4 * s])
    ds = np.array([1 - 4 * t, 0, 4 * s - 1, -4 * r, 4 * r, 4 * (t - s)])
    return n, dr, ds


def _quad8(r, s):
    xi = np.array([-1, 1, 1, -1])
    eta = np.array([-1, -1, 1, 1])
    n = np.zeros(8)
    dr = np.zeros(8)
    ds = np.zeros(8)
    for i in range(4):
        a, b = 1 + xi[i] * r, 1 + eta[i] * s
        n[i] = 0.25 * a * b * (xi[i] * r + eta[i] * s - 1)
        dr[i] = 0.25 * xi[i] * b * (2 * xi[i] * r + eta[i] * s)
        ds[i] = 0.25 * eta[i] * a * (xi[i] * r + 2 * eta[i] * s)
    for i, (ex, ey) in enumerate(((0, -1), (1, 0), (0, 1), (-1, 0))):
        if ex == 0:
            n[4 + i] = 0.5 * (1 - r * r) * (1 + ey * s)
            dr[4 + i] = -r * (1 + ey * s)
            ds[4 + i] = 0.5 * ey * (1 - r * r)
        else:
            n[4 + i] = 0.5 * (1 + ex * r) * (1 - s * s)
            dr[4 + i] = 0.5 * ex * (1 - s * s)
            ds[4 + i] = -s * (1 + ex * r)
    return n, dr, ds


def _face_points(corners):
    if len(corners) == 3:
        return [(_tri6(r, s), w) for (r, s), w in zip(*_TRI_RULE)]
    g, w = _GAUSS4
    return [(_quad8(r, s), wr * ws) for r, wr in zip(g, w) for s, ws in zip(g, w)]


def enclosed_volume(mesh, positions):
    """Volume enclosed by the mesh's boundary at `positions` (dict id → xyz),
    V = ⅓∮ x·n dA over the quadratic boundary faces (exact for them)."""
    volume = 0.0
    for corners, mids in mesh.boundary_faces():
        x = np.array([positions[i] for i in corners + mids])  # #face nodes×3
        for (n, dr, ds), w in _face_points(corners):
            p, tr, ts = n @ x, dr @ x, ds @ x
            volume += w * float(np.dot(p, np.cross(tr, ts))) / 3.0
    return volume


# ---- the deck ----------------------------------------------------------------
def _id_lines(ids, per_line=12):
    return [", ".join(str(i) for i in ids[k:k + per_line]) + "," for k in range(0, len(ids), per_line)]


def write_deck(path, mesh, material, node_sets, boundary, loads, outputs, increment=0.25):
    """Writes a one-step *STATIC, NLGEOM CalculiX deck.

    material: dict young_pa, poisson, density (kg/m³, optional).
    node_sets: dict name → node ids.
    boundary: list of (set name or node id, first dof, last dof, value m).
    loads: list of *DLOAD data lines on ELALL (e.g. "ELALL, GRAV, 9.81, 0, 0, -1").
    outputs: list of (*NODE PRINT parameters, fields), e.g. ("NSET=NTIP", "U").
    """
    lines = ["*HEADING", f"cutsim reference: {mesh.element_type} {mesh.n}", "*NODE"]
    lines += [f"{nid}, {p[0]:.17g}, {p[1]:.17g}, {p[2]:.17g}" for nid, p in sorted(mesh.nodes.items())]
    lines.append(f"*ELEMENT, TYPE={mesh.element_type}, ELSET=ELALL")
    for eid, element in enumerate(mesh.elements, start=1):
        ids = [str(eid)] + [str(i) for i in element]
        # CalculiX continues an element's node list on the next line after 16 entries.
        lines.append(", ".join(ids[:16]) + ("," if len(ids) > 16 else ""))
        if len(ids) > 16:
            lines.append(", ".join(ids[16:]))
    for name, ids in node_sets.items():
        lines.append(f"*NSET, NSET={name}")
        lines += _id_lines(ids)
    lines += ["*MATERIAL, NAME=TISSUE", "*ELASTIC", f"{material['young_pa']:.17g}, {material['poisson']:.17g}"]
    if material.get("density"):
        lines += ["*DENSITY", f"{material['density']:.17g}"]
    lines += ["*SOLID SECTION, ELSET=ELALL, MATERIAL=TISSUE", "*STEP, NLGEOM, INC=1000", "*STATIC",
              f"{increment:.6g}, 1.0, 1e-6, {increment:.6g}", "*BOUNDARY"]
    lines += [f"{target}, {first}, {last}, {value:.17g}" for target, first, last, value in boundary]
    if loads:
        lines.append("*DLOAD")
        lines += loads
    for params, fields in outputs:
        lines += [f"*NODE PRINT, {params}", fields]
    lines.append("*END STEP")
    with open(path, "w", encoding="ascii") as f:
        f.write("\n".join(lines) + "\n")
