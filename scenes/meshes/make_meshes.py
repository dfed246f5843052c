"""Regenerate the meshes of this folder (y is up; sizes in metres).

    python scenes/meshes/make_meshes.py

Deterministic: the same files on every run. Collider meshes (solid ones watertight):

torus.obj       major radius 0.3, minor radius 0.1, axis y (4096 triangles).
bowl.obj        a thick hemispherical bowl, watertight: outer radius 0.4, wall 0.05, flat rim
                at y = 0, opening up (concave: its cavity is outside the solid).
icosphere5k.obj an icosphere of radius 1 (5120 triangles).
open_bowl.obj   an open hemispherical shell of radius 0.4, opening up: NOT watertight, for
                one-sided (`"solid": false`) mesh colliders.
round_table.obj a pedestal table standing on y = 0: a round top of radius 0.45 and thickness
                0.05 (upper face at y = 0.75), a leg of radius 0.05, a foot of radius 0.25.
torso.obj       a torso for the T-shirt: a body of elliptic section (waist about y = 0,
                shoulders about y = 0.6), a neck and two arm stubs along x at y = 0.558.

Cloth meshes (`cloth.mesh`; OBJ with `vt` uvs and `g` groups), checked at the end of main()
with pipeline.physics.cloth_mesh (one piece, manifold, orientable, no degenerate triangle):

tablecloth.obj       a disc of radius 0.75 in the plane y = 0, normal +y: 24 concentric rings
                     (1801 points, edges about 3.5 cm); uv planar.
flag_swallowtail.obj a flag 1.2 x 0.8 in the plane z = 0 (normal +z), hoist edge on x = 0,
                     a V cut 0.35 deep into the fly edge; uv = (x / 1.2, y / 0.8); groups
                     `hoist` (the faces along x = 0) and `flag`.
skirt.obj            an open frustum about the y axis: waist radius 0.16 at y = 0, hem radius
                     0.35 at y = -0.45; uv u = angle / 2 pi (a seam along +x), v = 1 at the
                     waist; groups `waistband` (the top band of faces) and `skirt`.
tshirt.obj           a T-shirt around the torso: waist at y = 0, shoulder seam at y = 0.648,
                     sleeves along x to the cuffs at |x| = 0.396, front towards +z; open at
                     the neck, waist and cuffs. Two T-shaped panels sewn along the shoulder,
                     sleeve and side seams, inflated; uv: the flat pattern, front in u < 0.5,
                     back in u > 0.5; groups `front` and `back`. It clears torso.obj by
                     1.5 cm or more.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import trimesh

HERE = Path(__file__).resolve().parent
Z_UP_TO_Y_UP = trimesh.transformations.rotation_matrix(-np.pi / 2, [1, 0, 0])
ARC = 16  # profile segments of a quarter circle
SECTIONS = 64  # segments around the axis


def _quarter_arc(radius: float) -> np.ndarray:
    """(ARC + 1, 2) points (r, z) from the bottom pole (0, -radius) to the rim (radius, 0)."""
    angle = np.linspace(0.0, np.pi / 2, ARC + 1)
    return np.column_stack([radius * np.sin(angle), -radius * np.cos(angle)])


def torus() -> trimesh.Trimesh:
    return trimesh.creation.torus(0.3, 0.1, major_sections=64, minor_sections=32,
                                  transform=Z_UP_TO_Y_UP)


def bowl(radius: float = 0.4, wall: float = 0.05) -> trimesh.Trimesh:
    outer = _quarter_arc(radius)
    inner = _quarter_arc(radius - wall)[::-1]
    profile = np.vstack([outer, inner, outer[:1]])  # closed: outer arc, rim, inner arc, axis
    return trimesh.creation.revolve(profile, sections=SECTIONS, transform=Z_UP_TO_Y_UP)


def open_bowl(radius: float = 0.4) -> trimesh.Trimesh:
    return trimesh.creation.revolve(_quarter_arc(radius), sections=SECTIONS,
                                    transform=Z_UP_TO_Y_UP)


def icosphere() -> trimesh.Trimesh:
    return trimesh.creation.icosphere(subdivisions=4, radius=1.0)


# --------------------------------------------------------------------------------------
# Cloth meshes (`cloth.mesh`) and their colliders. OBJ with `vt` uvs, written with 6
# decimals; each checked by pipeline.physics.cloth_mesh at the end of main().
# --------------------------------------------------------------------------------------

class Sheet:
    """A mesh being built: positions, uvs, and triangles as (position, uv) index triples,
    each triangle in an OBJ group."""

    def __init__(self) -> None:
        self.v: list[tuple[float, float, float]] = []
        self.vt: list[tuple[float, float]] = []
        self.uv_of: dict[int, int] = {}  # a vertex's own uv, when it has one
        self.faces: list[tuple[str, tuple[int, int, int], tuple[int, int, int]]] = []

    def vertex(self, p, uv=None) -> int:
        """A position (and its own uv, when given): its index."""
        self.v.append(tuple(float(c) for c in p))
        if uv is not None:
            self.uv_of[len(self.v) - 1] = self.uv(uv)
        return len(self.v) - 1

    def uv(self, uv) -> int:
        self.vt.append((float(uv[0]), float(uv[1])))
        return len(self.vt) - 1

    def face(self, group: str, pos, uvs=None) -> None:
        """A triangle: position indices and uv indices (default: the vertices' own uvs)."""
        uvs = [self.uv_of[k] for k in pos] if uvs is None else uvs
        self.faces.append((group, tuple(int(k) for k in pos), tuple(int(k) for k in uvs)))

    def obj(self, header: str) -> str:
        lines = [f"# {line}".rstrip() for line in header.strip().splitlines()]
        lines += [f"v {x:.6f} {y:.6f} {z:.6f}" for x, y, z in self.v]
        lines += [f"vt {u:.6f} {v:.6f}" for u, v in self.vt]
        group = None
        for g, pos, uvs in self.faces:
            if g != group:
                lines.append(f"g {g}")
                group = g
            lines.append("f " + " ".join(f"{p + 1}/{t + 1}" for p, t in zip(pos, uvs)))
        return "\n".join(lines) + "\n"


def _strip(a: list[float], b: list[float], cyclic: bool) -> list[tuple[str, int, int]]:
    """Triangles between two rows of points given by their parameters along the row
    (increasing; in [0, 1) for a closed ring, from 0 to 1 for an open row): greedy,
    advancing the row whose next point comes first. Corners as ('a' | 'b', index), where a
    closed ring's index len(row) is its first point again (across the seam)."""
    ta = list(a) + ([a[0] + 1.0] if cyclic else [])
    tb = list(b) + ([b[0] + 1.0] if cyclic else [])
    i = j = 0
    out = []
    while i < len(ta) - 1 or j < len(tb) - 1:
        if j == len(tb) - 1 or (i < len(ta) - 1 and ta[i + 1] <= tb[j + 1]):
            out.append((("a", i), ("a", i + 1), ("b", j)))
            i += 1
        else:
            out.append((("a", i), ("b", j + 1), ("b", j)))
            j += 1
    return out


def _ring_strips(sheet: Sheet, group, rows: list[list[int]], params: list[list[float]],
                 cyclic: bool, uv_rows: list[list[int]] | None = None) -> None:
    """Faces between consecutive rows (lists of vertex indices), in `group` (a name, or a
    function of the row number). A closed ring's seam corner takes uv_rows' extra last
    entry (the seam's other side) when given."""
    for r in range(len(rows) - 1):
        rowa, rowb = rows[r], rows[r + 1]
        for tri in _strip(params[r], params[r + 1], cyclic):
            pos, uvs = [], []
            for which, k in tri:
                row, uv_row = (rowa, None if uv_rows is None else uv_rows[r]) if which == "a" \
                    else (rowb, None if uv_rows is None else uv_rows[r + 1])
                pos.append(row[k % len(row)])
                uvs.append(sheet.uv_of[row[k % len(row)]] if uv_row is None else uv_row[k])
            sheet.face(group(r) if callable(group) else group, pos, uvs)


def tablecloth(radius: float = 0.75, rings: int = 24) -> Sheet:
    """A disc in the plane y = 0, normal +y: concentric rings k = 1..rings of 6k points
    (spacing radius / rings), a centre point; uv planar (u along +x, v along -z)."""
    s = Sheet()

    def uv(x, z):
        return (0.5 + x / (2 * radius), 0.5 - z / (2 * radius))

    rows, params = [[s.vertex((0, 0, 0), uv(0, 0))]], [[0.0]]
    for k in range(1, rings + 1):
        r, n = radius * k / rings, 6 * k
        t = [(i + 0.5 * (k % 2)) / n for i in range(n)]  # odd rings turned half a step
        row = []
        for ti in t:
            a = 2 * np.pi * ti
            x, z = r * np.cos(a), -r * np.sin(a)  # counter-clockwise seen from +y
            row.append(s.vertex((x, 0, z), uv(x, z)))
        rows.append(row)
        params.append(t)
    # the centre fan, then ring strips
    for i in range(6):
        s.face("tablecloth", (rows[0][0], rows[1][(i + 1) % 6], rows[1][i]))  # as the strips
    _ring_strips(s, "tablecloth", rows[1:], params[1:], cyclic=True)
    return _facing(s, (0, 1, 0))


def _facing(s: Sheet, normal) -> Sheet:
    """Turn every face so that the summed face normal points along `normal`."""
    v = np.array(s.v)
    total = np.zeros(3)
    for _, pos, _ in s.faces:
        a, b, c = v[list(pos)]
        total += np.cross(b - a, c - a)
    if total @ np.asarray(normal, dtype=float) < 0:
        s.faces = [(g, (p[0], p[2], p[1]), (t[0], t[2], t[1])) for g, p, t in s.faces]
    return s


def flag_swallowtail(width: float = 1.2, height: float = 0.8, cut: float = 0.35,
                     spacing: float = 0.0235) -> Sheet:
    """A flag in the plane z = 0 (normal +z), hoist edge on x = 0 from y = 0 to height, fly
    edge at x = width with a V cut `cut` deep at mid height (the swallowtail). Rows of
    points at constant y, alternate rows shifted half a step; uv = (x / width, y / height).
    Groups: `hoist` (the faces along x = 0), `flag`."""
    s = Sheet()
    nrows = 2 * int(round(height / (spacing * np.sqrt(3))))  # even: a row through the V's tip
    rows, params = [], []
    for r in range(nrows + 1):
        y = height * r / nrows
        fly = width - cut * (1 - abs(y - height / 2) / (height / 2))
        n = max(2, int(round(fly / spacing)))
        if r % 2:
            t = [0.0] + [(i + 0.5) / n for i in range(n)] + [1.0]
        else:
            t = [i / n for i in range(n + 1)]
        rows.append([s.vertex((fly * ti, y, 0), (fly * ti / width, y / height)) for ti in t])
        params.append(t)
    # a V notch: the rows above and below mid height end on the cut's two edges; the strip
    # between rows stays open-ended (not cyclic), so the cut is a boundary
    _ring_strips(s, "flag", rows, params, cyclic=False)
    v = np.array(s.v)
    s.faces = [("hoist" if min(v[list(p)][:, 0]) == 0.0 else "flag", p, t)
               for _, p, t in s.faces]
    s.faces.sort(key=lambda f: f[0] != "hoist")  # stable: hoist faces first
    return _facing(s, (0, 0, 1))


def skirt(waist: float = 0.16, hem: float = 0.35, length: float = 0.45,
          spacing: float = 0.024) -> Sheet:
    """An open frustum about the y axis: the waist ring (radius `waist`) at y = 0, the hem
    (radius `hem`) at y = -length; normals outward. uv: u = angle / 2 pi around the axis
    (a seam along the +x line, where u wraps from 1 to 0), v = 1 at the waist, 0 at the
    hem. Groups: `waistband` (the faces of the top band), `skirt`."""
    s = Sheet()
    slant = float(np.hypot(hem - waist, length))
    nrows = int(round(slant / (spacing * np.sqrt(3) / 2)))
    rows, uv_rows, params = [], [], []
    for r in range(nrows + 1):
        f = r / nrows
        radius, y = waist + (hem - waist) * f, -length * f
        n = int(round(2 * np.pi * radius / spacing))
        t = [(i + 0.5 * (r % 2)) / n for i in range(n)]
        row = []
        for ti in t:
            a = 2 * np.pi * ti
            row.append(s.vertex((radius * np.cos(a), y, -radius * np.sin(a)), (ti, 1 - f)))
        uv_rows.append([s.uv_of[k] for k in row] + [s.uv((t[0] + 1.0, 1 - f))])  # + the seam
        rows.append(row)
        params.append(t)
    _ring_strips(s, lambda r: "waistband" if r == 0 else "skirt", rows, params, cyclic=True,
                 uv_rows=uv_rows)
    return _outward(s)


def _outward(s: Sheet) -> Sheet:
    """Turn every face so that its normal points away from the y axis (on average)."""
    v = np.array(s.v)
    total = 0.0
    for _, pos, _ in s.faces:
        a, b, c = v[list(pos)]
        centre = (a + b + c) / 3
        total += float(np.cross(b - a, c - a) @ np.array([centre[0], 0, centre[2]]))
    if total < 0:
        s.faces = [(g, (p[0], p[2], p[1]), (t[0], t[2], t[1])) for g, p, t in s.faces]
    return s


def round_table(radius: float = 0.45, top: float = 0.05, height: float = 0.75) -> trimesh.Trimesh:
    """A pedestal table, one watertight solid of revolution about the y axis: a top of
    `radius` and thickness `top` (upper face at y = height, edge rounded), a leg of radius
    0.05, a foot of radius 0.25 on y = 0."""
    r_leg, r_foot = 0.05, 0.25
    bevel = 0.01
    under = height - top
    profile = [(0.0, 0.0), (r_foot, 0.0), (r_foot, 0.02), (r_leg + 0.03, 0.05), (r_leg, 0.08),
               (r_leg, under - 0.05), (r_leg + 0.05, under), (radius - bevel, under),
               (radius, under + bevel), (radius, height - bevel), (radius - bevel, height),
               (0.0, height)]
    return trimesh.creation.revolve(np.array(profile), sections=96, transform=Z_UP_TO_Y_UP)


# -- the T-shirt: two flat T-shaped panels (front, back) sewn along the shoulder, sleeve
# and side seams, inflated (a Poisson "pillow"); open at the neck, waist and cuffs ---------

SHIRT_H = 0.018  # the panels' grid step
SHIRT_W = 0.216  # the body's half width
SHIRT_L = 0.18  # a sleeve's length beyond the body
SHIRT_RS = 0.09  # half a sleeve's width (its radius once inflated)
SHIRT_TOP = 0.648  # the shoulder seam's height (the waist is at y = 0)
SHIRT_DEPTH = 0.15  # the body's half depth (front to back) at the chest
SHIRT_POWER = 0.75  # section shape: 0.5 round (but long edges at the seams), 1 a lens
NECK_W, NECK_D = 0.09, 0.054  # the neck hole: half width, depth below the shoulder seam
# the torso inside (torso_sdf): the body's radius across, its depth / width, the height of
# its upper end's centre
TORSO_R, TORSO_ZSCALE, TORSO_SHOULDER = 0.165, 0.64, 0.45


def _panel():
    """The T-shaped panel (x, y) in the plane: its points, triangles and which points lie on
    a seam (the boundary but the waist, the cuffs and the neck)."""
    h, w, sl, rs, top = SHIRT_H, SHIRT_W, SHIRT_L, SHIRT_RS, SHIRT_TOP
    arm = top - 2 * rs  # the underarm seam's height
    nx, ny = int(round((w + sl) / h)), int(round(top / h))
    xs = np.linspace(-(w + sl), w + sl, 2 * nx + 1)
    ys = np.linspace(0.0, top, ny + 1)

    def inside(x, y):  # a point of the T minus the neck hole (centroids only)
        in_t = (abs(x) < w or y > arm) and 0 < y < top and abs(x) < w + sl
        in_neck = (x / NECK_W) ** 2 + ((y - top) / NECK_D) ** 2 < 1.0
        return in_t and not in_neck

    index: dict[tuple[int, int], int] = {}
    points, tris = [], []

    def vid(i, j):
        if (i, j) not in index:
            index[(i, j)] = len(points)
            points.append((xs[i], ys[j]))
        return index[(i, j)]

    for j in range(ny):
        for i in range(2 * nx):
            x0, x1, y0, y1 = xs[i], xs[i + 1], ys[j], ys[j + 1]
            # diagonals running away from the centre line keep the layout symmetric
            if x0 + x1 >= 0:
                cand = [((i, j), (i + 1, j), (i + 1, j + 1)), ((i, j), (i + 1, j + 1), (i, j + 1))]
            else:
                cand = [((i, j), (i + 1, j), (i, j + 1)), ((i + 1, j), (i + 1, j + 1), (i, j + 1))]
            for tri in cand:
                cx = sum(xs[a] for a, _ in tri) / 3
                cy = sum(ys[b] for _, b in tri) / 3
                if inside(cx, cy):
                    tris.append(tuple(vid(a, b) for a, b in tri))
    pts, tris = np.array(points), np.array(tris)
    # boundary edges, and which are open: waist (y = 0), cuffs (|x| = w + sl), neck
    edges: dict[tuple[int, int], int] = {}
    for t in tris:
        for k in range(3):
            e = tuple(sorted((t[k], t[(k + 1) % 3])))
            edges[e] = edges.get(e, 0) + 1
    seam = np.zeros(len(pts), dtype=bool)
    for (a, b), count in edges.items():
        if count != 1:
            continue
        pa, pb = pts[a], pts[b]
        waist = pa[1] == 0 and pb[1] == 0
        cuff = abs(pa[0]) == w + sl and abs(pb[0]) == w + sl
        neck = (max(abs(pa[0]), abs(pb[0])) <= NECK_W + 1e-9
                and min(pa[1], pb[1]) >= top - NECK_D - h
                and not (pa[1] == top and pb[1] == top))
        if not (waist or cuff or neck):
            seam[[a, b]] = True
    return pts, tris, seam


def _cross2(a, b) -> float:
    return float(a[0] * b[1] - a[1] * b[0])


def _inflate(pts, tris, seam) -> np.ndarray:
    """The panel's height above its plane: u solves the Poisson problem -lap u = 1 with u = 0
    on the seams (free at the open edges; cotangent weights, lumped masses), then scaled per
    region to the body's depth (ellipse-like sections across the body) and the sleeve's
    radius (round sleeves)."""
    n = len(pts)
    lap = np.zeros((n, n))
    mass = np.zeros(n)
    for t in tris:
        p = pts[list(t)]
        area = 0.5 * abs(_cross2(p[1] - p[0], p[2] - p[0]))
        mass[list(t)] += area / 3
        for k in range(3):
            i, j, o = t[k], t[(k + 1) % 3], t[(k + 2) % 3]
            u, v = pts[i] - pts[o], pts[j] - pts[o]
            cot = float(u @ v) / abs(_cross2(u, v))
            lap[i, j] -= cot / 2
            lap[j, i] -= cot / 2
            lap[i, i] += cot / 2
            lap[j, j] += cot / 2
    free = ~seam
    u = np.zeros(n)
    u[free] = np.linalg.solve(lap[np.ix_(free, free)], mass[free])
    body = SHIRT_DEPTH * (2 * u / SHIRT_W ** 2) ** SHIRT_POWER
    sleeve = SHIRT_RS * (2 * u / SHIRT_RS ** 2) ** SHIRT_POWER
    blend = np.clip((np.abs(pts[:, 0]) - (SHIRT_W - 0.03)) / 0.09, 0.0, 1.0)
    blend = blend * blend * (3 - 2 * blend)
    return (1 - blend) * body + blend * sleeve


def tshirt() -> Sheet:
    """A T-shirt around the y axis: body from the waist (y = 0) up to the shoulder seam
    (y = SHIRT_TOP), sleeves along x to the cuffs at |x| = SHIRT_W + SHIRT_L; front towards
    +z. Open at the neck, the waist and the two cuffs; one manifold piece. uv: the flat
    pattern, front panel in u < 0.5, back panel in u > 0.5. Groups: `front`, `back`."""
    pts, tris, seam = _panel()
    height = _inflate(pts, tris, seam)
    s = Sheet()
    span = 2 * (SHIRT_W + SHIRT_L)
    front = [s.vertex((x, y, z), (0.5 * (x / span + 0.5), y / span))
             for (x, y), z in zip(pts, height)]
    back = []
    for k, ((x, y), z) in enumerate(zip(pts, height)):
        if seam[k]:
            back.append(front[k])
        else:
            back.append(s.vertex((x, y, -z)))
    # the back panel's own uvs (seam points too: its pattern piece is separate)
    back_uv = [s.uv((0.5 + 0.5 * (-x / span + 0.5), y / span)) for x, y in pts]
    for t in tris:
        s.face("front", [front[k] for k in t])
    for t in tris:
        s.face("back", [back[k] for k in t[::-1]], [back_uv[k] for k in t[::-1]])
    return s


def torso_sdf(p: np.ndarray) -> np.ndarray:
    """Signed distance (approximate; exact zero set) of the torso: a body (a capsule of
    elliptic section), a neck and two arm stubs, smoothly joined."""
    def capsule(q, a, b, r, zscale=1.0):
        q = q / np.array([1.0, 1.0, zscale])
        a, b = np.asarray(a, float), np.asarray(b, float)
        ab = b - a
        t = np.clip(((q - a) @ ab) / (ab @ ab), 0, 1)
        return (np.linalg.norm(q - (a + t[:, None] * ab), axis=1) - r) * min(1.0, zscale)

    def smin(d1, d2, k=0.03):
        hh = np.clip(0.5 + 0.5 * (d2 - d1) / k, 0, 1)
        return d2 * (1 - hh) + d1 * hh - k * hh * (1 - hh)

    arm_y = SHIRT_TOP - SHIRT_RS
    d = capsule(p, (0, -0.05, 0), (0, TORSO_SHOULDER, 0), TORSO_R, TORSO_ZSCALE)
    d = smin(d, capsule(p, (0, TORSO_SHOULDER, 0), (0, TORSO_SHOULDER + 0.25, 0), 0.055))
    for side in (-1, 1):
        d = smin(d, capsule(p, (side * 0.10, arm_y, 0), (side * 0.33, arm_y, 0), 0.05))
    return d


def torso() -> trimesh.Trimesh:
    """The torso of torso_sdf as a closed mesh: an icosphere about a point inside, each
    vertex moved along its ray to the outermost crossing of the surface (the shape is
    star-shaped about that point)."""
    centre = np.array([0.0, SHIRT_TOP - SHIRT_RS, 0.0])
    sphere = trimesh.creation.icosphere(subdivisions=4)
    dirs = np.asarray(sphere.vertices)
    radii = np.linspace(0.0, 1.2, 601)
    values = torso_sdf((centre + radii[:, None, None] * dirs[None]).reshape(-1, 3))
    inside = values.reshape(len(radii), len(dirs)) < 0
    last = len(radii) - 1 - np.argmax(inside[::-1], axis=0)  # the outermost inside sample
    lo, hi = radii[last], radii[last + 1]
    for _ in range(40):  # bisection, all rays at once
        mid = 0.5 * (lo + hi)
        inner = torso_sdf(centre + mid[:, None] * dirs) < 0
        lo, hi = np.where(inner, mid, lo), np.where(inner, hi, mid)
    crossing = 0.5 * (lo + hi)
    return trimesh.Trimesh(centre + dirs * crossing[:, None], sphere.faces, process=False)


CLOTH_MESHES = {  # cloth meshes: name -> (builder, header comment)
    "tablecloth": (tablecloth, "a round tablecloth: a disc of radius 0.75 m in the plane y = 0"),
    "flag_swallowtail": (flag_swallowtail, "a swallowtail flag 1.2 x 0.8 m in the plane z = 0, "
                         "hoist edge on x = 0"),
    "skirt": (skirt, "a skirt: an open frustum about the y axis, waist (r 0.16) at y = 0, hem "
              "(r 0.35) at y = -0.45"),
    "tshirt": (tshirt, "a T-shirt: waist at y = 0, shoulders at y = 0.648, sleeves along x, "
               "front towards +z"),
}


def main() -> None:
    meshes = {"torus": torus(), "bowl": bowl(), "icosphere5k": icosphere(),
              "open_bowl": open_bowl(), "round_table": round_table(), "torso": torso()}
    for name, mesh in meshes.items():
        text = trimesh.exchange.obj.export_obj(mesh, include_normals=False, digits=6)
        (HERE / f"{name}.obj").write_text(text)
        print(f"{name}.obj: {len(mesh.faces)} triangles, watertight={mesh.is_watertight}")
    for name, (build, what) in CLOTH_MESHES.items():
        sheet = build()
        (HERE / f"{name}.obj").write_text(sheet.obj(f"{what}\nmade by make_meshes.py"))
    check()


def check() -> None:
    """Every cloth mesh loads as a cloth (one piece, manifold, orientable, no degenerate
    triangle); the colliders are closed solids; the T-shirt clears the torso."""
    import sys

    sys.path.insert(0, str(HERE.parents[1]))
    from pipeline.physics.cloth_mesh import load_cloth_mesh
    from pipeline.scene import ClothMeshSource

    for name in CLOTH_MESHES:
        cloth = load_cloth_mesh(ClothMeshSource(path=HERE / f"{name}.obj"))
        p, t = cloth.points, cloth.triangles
        edges = np.concatenate([t[:, [0, 1]], t[:, [1, 2]], t[:, [2, 0]]])
        length = np.linalg.norm(p[edges[:, 0]] - p[edges[:, 1]], axis=1)
        print(f"{name}.obj: {len(p)} points, {len(t)} triangles, {cloth.pieces} piece, "
              f"edges {length.min() * 100:.1f}-{length.max() * 100:.1f} cm "
              f"(mean {length.mean() * 100:.1f}), groups {sorted(cloth.groups)}")
        assert cloth.pieces == 1 and cloth.has_uv
    for name in ("round_table", "torso"):
        mesh = trimesh.load(HERE / f"{name}.obj", force="mesh")
        assert mesh.is_watertight and mesh.is_winding_consistent and mesh.volume > 0, name
    shirt = load_cloth_mesh(ClothMeshSource(path=HERE / "tshirt.obj"))
    gap = torso_sdf(shirt.points)
    print(f"tshirt.obj clears the torso by {gap.min() * 100:.1f} cm or more")
    assert gap.min() > 0.015


if __name__ == "__main__":
    main()
