"""An independent checker of cloth-collider crossings (issue 43), written apart from the
solver's collider code: plain numpy (and benchmarks/crossings.py's exact orientation signs
and k-d tree pair finding), trimesh only to read mesh files.

    from collider_crossings import collider_violations
    v = collider_violations(points, edges, scene.colliders, t, pinned=sim.pinned)
    v["inside"], v["edges"]          # counts; v["inside_idx"], v["edges_idx"]: the indices

    python benchmarks/collider_crossings.py run.npz scene.json [--every N]

Layouts and units: `points` (N, 3) float64 world positions in metres (row = point; the
solver's (3, N) state must be transposed; a (3, N) array is refused unless N == 3),
`edges` (E, 2) point indices (crossings.unique_edges(faces) gives a mesh's), `t` seconds
(the simulated time of the frame: each collider is placed at its keyframed pose at t),
`pinned` None, an (N,) bool / uint8 mask, or an int array of point indices.

Each collider is checked in its rest frame (the pose the scene file gives): the cloth is
moved there by p_rest = R(t)^T (p - pivot - T(t)) + pivot, the keyframe convention of
docs/scene-format.md (T and the Euler angles of R = Rz Ry Rx interpolated linearly between
the keys around t, held before the first and after the last; pivot: the sphere's origin,
the plane's point, the box's center, the mesh's translation). The pose is computed here in
numpy, not by the solver's `collider_pose` (and nothing is compiled).

What counts, per collider kind:
- sphere (origin o, radius r): a point is inside when |p - o| < r (1 - 1e-9); an edge
  crosses when the closest point of its segment to o is inside in the same sense.
- box (center, Euler `rotation` of the file, half extents h; box coordinates
  q = Rb^T (p - center)): a point is inside when |q_i| < h_i for every i (strictly); an
  edge crosses when Liang-Barsky slab clipping leaves an interval of positive length of
  the segment strictly inside every slab.
- solid mesh: a point is inside by ray parity (three fixed generic directions, majority
  of those whose ray meets no triangle edge or corner exactly) and further than 1e-9 m
  from every triangle; an edge crosses when it has an end inside, passes through the
  interior of a triangle, or, meeting the surface only at triangles' edges or corners, has
  the midpoint between two consecutive such hits inside.
- one-sided mesh (`"solid": false`): an edge crosses when it meets a triangle, its edges
  and corners included (so once through a shared edge, and conservatively also exactly
  through the open rim); no points are "inside"; going round the rim is no crossing.
- plane (one-sided in this project by the side a point came from): `below` lists the
  points strictly on the side opposite the normal ((p - point) . n < 0), a count to read
  against the scene (not a violation by itself); an edge crosses when its ends lie
  strictly on opposite sides.
"Meets a triangle": the ends strictly on opposite sides of the triangle's plane and the
segment's line through the closed triangle, by orientation signs made exact as in
crossings.py (float determinants trusted beyond Shewchuk's bound, the rest in rational
arithmetic); an end exactly on the surface or a segment lying in it never meets it.

Pins: pinned points are never reported `inside` or `below` (colliders do not move them),
and edges with both ends pinned are left out; an edge with one free end is checked.
"""
from __future__ import annotations

import functools
import importlib.util
import math
import sys
from pathlib import Path

import numpy as np


def _load_crossings():
    """benchmarks/crossings.py (exact orientation signs, k-d tree pair finding), loaded by its
    path: benchmarks/ on sys.path would shadow packages (its distributed.py the Dask one)."""
    if "crossings" in sys.modules:
        return sys.modules["crossings"]
    spec = importlib.util.spec_from_file_location(
        "crossings", Path(__file__).resolve().with_name("crossings.py"))
    module = importlib.util.module_from_spec(spec)
    sys.modules["crossings"] = module
    spec.loader.exec_module(module)
    return module


_cx = _load_crossings()
unique_edges = _cx.unique_edges

__all__ = ["check_npz", "collider_violations", "euler", "main", "mesh_arrays",
           "point_in_solid_mesh", "pose", "unique_edges"]

SPHERE_REL = 1e-9  # inside a sphere: |p - o| < r (1 - SPHERE_REL)
MESH_GAP = 1e-9  # inside a solid mesh: more than this many metres from its surface
#: ray directions of the parity test (unit, generic: no two components alike)
_RAYS = np.array([[0.5773830, 0.6180340, 0.5334710],
                  [-0.7071423, 0.3141593, 0.6329124],
                  [0.2718282, -0.8414710, 0.4670139]])
_RAYS /= np.linalg.norm(_RAYS, axis=1, keepdims=True)
_CHUNK = 1 << 20


# --- poses ---------------------------------------------------------------------------------
def euler(degrees) -> np.ndarray:
    """R = Rz Ry Rx (3, 3) for Euler angles [rx, ry, rz] in degrees (x applied first)."""
    rx, ry, rz = (math.radians(float(a)) for a in degrees)
    cx, sx, cy, sy, cz, sz = (math.cos(rx), math.sin(rx), math.cos(ry), math.sin(ry),
                              math.cos(rz), math.sin(rz))
    rot_x = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    rot_y = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    rot_z = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    return rot_z @ rot_y @ rot_x


def pose(obj, t: float) -> tuple[np.ndarray, np.ndarray]:
    """(R (3, 3), T (3,)) of collider `obj` at time t: its rest-frame point p is at
    R (p - pivot) + pivot + T (identity without keyframes)."""
    keys = obj.keyframes
    if not keys:
        return np.eye(3), np.zeros(3)
    times = [k.time for k in keys]
    if t <= times[0]:
        a = b = keys[0]
        w = 0.0
    elif t >= times[-1]:
        a = b = keys[-1]
        w = 0.0
    else:
        k = int(np.searchsorted(times, t, side="right")) - 1
        a, b = keys[k], keys[k + 1]
        w = (t - a.time) / (b.time - a.time)
    lerp = [np.asarray(u, float) + w * (np.asarray(v, float) - np.asarray(u, float))
            for u, v in ((a.translation, b.translation), (a.rotation, b.rotation))]
    return euler(lerp[1]), lerp[0]


def _to_rest(points: np.ndarray, obj, t: float) -> np.ndarray:
    """World points (N, 3) in `obj`'s rest frame at time t."""
    if not obj.keyframes:
        return points
    rot, trans = pose(obj, t)
    pivot = np.asarray(obj.pivot, dtype=np.float64)
    return (points - pivot - trans) @ rot + pivot  # rows: R^T (p - pivot - T) + pivot


# --- mesh files ----------------------------------------------------------------------------
@functools.lru_cache(maxsize=16)
def _mesh_cached(path: str, mtime: int, translation: tuple, rotation: tuple, scale: tuple):
    import trimesh

    mesh = trimesh.load(path, force="mesh")
    mesh.update_faces(mesh.nondegenerate_faces())
    mesh.remove_unreferenced_vertices()
    v = (np.asarray(mesh.vertices, np.float64) * np.asarray(scale)) @ euler(rotation).T
    v = np.ascontiguousarray(v + np.asarray(translation))
    f = np.ascontiguousarray(mesh.faces, dtype=np.int64)
    v.flags.writeable = False
    f.flags.writeable = False
    return v, f


def mesh_arrays(obj) -> tuple[np.ndarray, np.ndarray]:
    """(vertices (V, 3), faces (F, 3)) of a MeshCollider placed in its rest frame:
    file vertex v at R (scale * v) + translation (read with trimesh, cached)."""
    path = Path(obj.path)
    return _mesh_cached(str(path), path.stat().st_mtime_ns, tuple(map(float, obj.translation)),
                        tuple(map(float, obj.rotation)), tuple(map(float, obj.scale)))


# --- exact-ish predicates ------------------------------------------------------------------
def _signs(a, b, c, d) -> np.ndarray:
    """Exact sign of det[a - d; b - d; c - d] per row (int8): crossings.py's filter, the
    uncertain rows in rational arithmetic."""
    s, certain = _cx._orient3d(a, b, c, d)
    for i in np.nonzero(~certain)[0]:
        s[i] = _cx._o3(*(_cx._fr(v) for v in (a[i], b[i], c[i], d[i])))
    return s


def _line_through(p, q, a, b, c) -> tuple[np.ndarray, np.ndarray]:
    """(through, exact_edge): the line pq passes through the closed triangle abc (no two
    strict signs among its three edge orientations), and it does so at an edge or corner
    (one of them zero)."""
    s1, s2, s3 = _signs(p, q, a, b), _signs(p, q, b, c), _signs(p, q, c, a)
    s = np.stack([s1, s2, s3])
    pos, neg, zero = (s > 0).any(0), (s < 0).any(0), (s == 0).any(0)
    through = ~(pos & neg) & (pos | neg)
    return through, through & zero


def _segments_meet_triangles(p, q, a, b, c) -> tuple[np.ndarray, np.ndarray]:
    """Per row (meets, at_edge): segment pq meets triangle abc with its ends strictly on
    opposite sides of the triangle's plane (the module doc), and it does so exactly at an
    edge or corner of the triangle."""
    meets = np.zeros(len(p), dtype=bool)
    at_edge = np.zeros(len(p), dtype=bool)
    if len(p) == 0:
        return meets, at_edge
    opp = _signs(a, b, c, p).astype(np.int16) * _signs(a, b, c, q) < 0
    k = np.nonzero(opp)[0]
    if len(k):
        meets[k], at_edge[k] = _line_through(p[k], q[k], a[k], b[k], c[k])
    return meets, at_edge


def _tri_spheres(v, f):
    a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    cen = (a + b + c) / 3.0
    rad = np.maximum.reduce([_cx._norm(a - cen), _cx._norm(b - cen), _cx._norm(c - cen)])
    return a, b, c, cen, rad


def _edges_meeting_mesh(p, q, v, f) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(through (E,) bool, ei, ti): segment p[i] q[i] passes through the interior of a
    triangle of the mesh (v, f); the (segment, triangle) pairs meeting only at a triangle's
    edge or corner."""
    hit = np.zeros(len(p), dtype=bool)
    none = np.zeros(0, dtype=np.int64)
    if len(p) == 0 or len(f) == 0:
        return hit, none, none
    a, b, c, cen, rad = _tri_spheres(v, f)
    slack = 1e-9 * (1.0 + float(np.abs(v).max()))
    ei, ti = _cx._sphere_pairs(0.5 * (p + q), 0.5 * _cx._norm(q - p) + slack, cen, rad + slack)
    lo, hi = np.minimum(p, q), np.maximum(p, q)
    tlo, thi = np.minimum(np.minimum(a, b), c), np.maximum(np.maximum(a, b), c)
    ok = np.all((lo[ei] <= thi[ti] + slack) & (tlo[ti] <= hi[ei] + slack), axis=1)
    ei, ti = ei[ok], ti[ok]
    edge_e, edge_t = [none], [none]
    for k in range(0, len(ei), _CHUNK):
        e, t = ei[k:k + _CHUNK], ti[k:k + _CHUNK]
        meets, at_edge = _segments_meet_triangles(p[e], q[e], a[t], b[t], c[t])
        hit[e[meets & ~at_edge]] = True
        edge_e.append(e[at_edge])
        edge_t.append(t[at_edge])
    return hit, np.concatenate(edge_e), np.concatenate(edge_t)


def _through_solid(p, q, v, f, ei, ti) -> np.ndarray:
    """Edges ei (meeting triangles ti only at their edges or corners) that pass through the
    solid's interior: a point midway between consecutive surface hits strictly inside."""
    out = np.zeros(0, dtype=np.int64)
    if len(ei) == 0:
        return out
    a, b, c = v[f[ti, 0]], v[f[ti, 1]], v[f[ti, 2]]
    n = np.cross(b - a, c - a)
    s = _cx._dot(n, a - p[ei]) / _cx._dot(n, q[ei] - p[ei])
    edges, probes = [], []
    for e in np.unique(ei):
        cuts = np.unique(np.concatenate([[0.0, 1.0], np.clip(s[ei == e], 0.0, 1.0)]))
        mids = 0.5 * (cuts[1:] + cuts[:-1])
        probes.append(p[e] + mids[:, None] * (q[e] - p[e]))
        edges.append(np.full(len(mids), e))
    edges = np.concatenate(edges)
    inside = point_in_solid_mesh(np.concatenate(probes), v, f)
    return np.unique(edges[inside])


def point_in_solid_mesh(points, vertices, faces, gap: float = MESH_GAP) -> np.ndarray:
    """(N,) bool: points strictly inside the closed mesh (vertices, faces), by ray parity
    (module doc) and further than `gap` from its surface (a point whose three rays all meet
    triangle edges or corners exactly reads as outside). Orientation-free; the mesh must be
    closed."""
    pts = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 3)
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    out = np.zeros(len(pts), dtype=bool)
    if len(pts) == 0 or len(f) == 0:
        return out
    cand = np.nonzero(np.all((pts > v.min(0)) & (pts < v.max(0)), axis=1))[0]
    if len(cand) == 0:
        return out
    pc = pts[cand]
    a, b, c, cen, rad = _tri_spheres(v, f)
    slack = 1e-9 * (1.0 + float(np.abs(v).max()))
    votes_in = np.zeros(len(pc), dtype=np.int64)
    votes = np.zeros(len(pc), dtype=np.int64)
    for d in _RAYS:
        # pairs whose projections along d can overlap: a 2-D k-d tree
        u = np.cross(d, [1.0, 0.0, 0.0] if abs(d[0]) < 0.9 else [0.0, 1.0, 0.0])
        u /= np.linalg.norm(u)
        w = np.cross(d, u)
        basis = np.stack([u, w], axis=1)
        pi, ti = _cx._sphere_pairs(pc @ basis, np.full(len(pc), slack), cen @ basis,
                                   rad + slack)
        # ... and with the triangle not wholly behind the point
        ahead = np.maximum.reduce([a[ti] @ d, b[ti] @ d, c[ti] @ d]) >= pc[pi] @ d - slack
        pi, ti = pi[ahead], ti[ahead]
        hits = np.zeros(len(pc), dtype=np.int64)
        unsure = np.zeros(len(pc), dtype=bool)
        for k in range(0, len(pi), _CHUNK):
            i, t = pi[k:k + _CHUNK], ti[k:k + _CHUNK]
            p0 = pc[i]
            through, at_edge = _line_through(p0, p0 + d, a[t], b[t], c[t])
            n = np.cross(b[t] - a[t], c[t] - a[t])
            nd = _cx._dot(n, np.broadcast_to(d, n.shape))
            with np.errstate(divide="ignore", invalid="ignore"):
                s = _cx._dot(n, a[t] - p0) / nd
            front = through & (nd != 0) & (s > 0)
            np.add.at(hits, i[front & ~at_edge], 1)
            unsure[i[front & at_edge]] = True
            unsure[i[through & (nd == 0)]] = True  # the ray in a triangle's plane
        votes += ~unsure
        votes_in += ~unsure & (hits % 2 == 1)
    inside = 2 * votes_in > votes
    k = np.nonzero(inside)[0]
    if len(k) and gap >= 0:
        pi, ti = _cx._sphere_pairs(pc[k], np.full(len(k), gap + slack), cen, rad + slack)
        if len(pi):
            dist = _cx.point_triangle_distance(pc[k][pi], a[ti], b[ti], c[ti])
            inside[k[np.unique(pi[dist <= gap])]] = False
    out[cand[inside]] = True
    return out


# --- per kind ------------------------------------------------------------------------------
def _sphere(obj, x, p, q):
    o, r = np.asarray(obj.origin, np.float64), float(obj.radius)
    lim = r * (1.0 - SPHERE_REL)
    ins = _cx._norm(x - o) < lim
    d = q - p
    dd = _cx._dot(d, d)
    with np.errstate(divide="ignore", invalid="ignore"):
        s = np.clip(np.where(dd > 0, _cx._dot(o - p, d) / np.where(dd > 0, dd, 1.0), 0.0), 0, 1)
    cross = _cx._norm(p + s[:, None] * d - o) < lim
    return ins, cross


def _box(obj, x, p, q):
    rot = euler(obj.rotation)
    c, h = np.asarray(obj.center, np.float64), np.asarray(obj.half_extents, np.float64)
    qx, qp, qq = ((y - c) @ rot for y in (x, p, q))  # rows: R^T (y - center)
    ins = np.all(np.abs(qx) < h, axis=1)
    d = qq - qp
    enter = np.zeros(len(p))
    leave = np.ones(len(p))
    ok = np.ones(len(p), dtype=bool)
    for i in range(3):
        flat = d[:, i] == 0
        ok &= ~flat | (np.abs(qp[:, i]) < h[i])
        with np.errstate(divide="ignore", invalid="ignore"):
            s1 = (-h[i] - qp[:, i]) / d[:, i]
            s2 = (h[i] - qp[:, i]) / d[:, i]
        enter = np.where(flat, enter, np.maximum(enter, np.minimum(s1, s2)))
        leave = np.where(flat, leave, np.minimum(leave, np.maximum(s1, s2)))
    return ins, ok & (enter < leave)


def _plane(obj, x, p, q):
    n = np.asarray(obj.normal, np.float64)
    n = n / np.linalg.norm(n)
    o = np.asarray(obj.point, np.float64)
    sx, sp, sq = ((y - o) @ n for y in (x, p, q))
    return sx < 0, np.sign(sp) * np.sign(sq) < 0


def _mesh(obj, x, p, q):
    v, f = mesh_arrays(obj)
    cross, ei, ti = _edges_meeting_mesh(p, q, v, f)
    if not obj.solid:  # through an edge or corner: counted (conservative at the rim)
        cross[ei] = True
        return np.zeros(len(x), dtype=bool), cross
    cross[_through_solid(p, q, v, f, ei, ti)] = True
    return point_in_solid_mesh(x, v, f), cross  # ends inside: added by the caller


_KIND = {"Sphere": ("sphere", _sphere), "Box": ("box", _box), "Plane": ("plane", _plane),
         "MeshCollider": ("mesh", _mesh)}


def _pinned_mask(pinned, n: int) -> np.ndarray:
    if pinned is None:
        return np.zeros(n, dtype=bool)
    a = np.asarray(pinned)
    if a.dtype == bool or a.dtype == np.uint8:
        if a.shape != (n,):
            raise ValueError(f"pinned mask must have shape ({n},), got {a.shape}")
        return a.astype(bool)
    mask = np.zeros(n, dtype=bool)
    mask[a.astype(np.int64).ravel()] = True
    return mask


def collider_violations(points, edges, colliders, t: float, pinned=None) -> dict:
    """Cloth points inside and cloth edges through the scene's colliders at time t.

    points (N, 3) metres, edges (E, 2) point indices, colliders the Scene's list (Sphere,
    Plane, Box, MeshCollider, scene order), t seconds, pinned None / (N,) bool or uint8
    mask / int indices (module doc). Returns a dict:
      inside, inside_idx   free points strictly inside a solid collider (sphere, box,
                           solid mesh): the count and the sorted point indices
      edges, edges_idx     edges (not both ends pinned) through a solid collider's
                           interior, across a one-sided mesh or across a plane: the count
                           and the sorted row indices into `edges`
      chords, chords_idx   those of `edges` through a solid collider with neither end
                           inside it (the crossings a point test cannot see)
      below, below_idx     free points strictly below a plane (opposite its normal)
      colliders            per collider, scene order: {"index", "kind", "inside", "edges",
                           "chords", "below"}, each an index array as above
    """
    x = np.asarray(points, dtype=np.float64)
    if x.ndim != 2 or x.shape[1] != 3:
        raise ValueError(f"points must be (N, 3), got {x.shape} (transpose a (3, N) state)")
    if not np.all(np.isfinite(x)):
        raise ValueError("points must be finite (did the run diverge?)")
    e = np.asarray(edges, dtype=np.int64).reshape(-1, 2)
    if len(e) and (e.min() < 0 or e.max() >= len(x)):
        raise ValueError("edge indices out of range")
    pin = _pinned_mask(pinned, len(x))
    free = ~pin
    checked = ~(pin[e[:, 0]] & pin[e[:, 1]])
    per = []
    all_in = np.zeros(len(x), dtype=bool)
    all_below = np.zeros(len(x), dtype=bool)
    all_cross = np.zeros(len(e), dtype=bool)
    all_chord = np.zeros(len(e), dtype=bool)
    for index, obj in enumerate(colliders):
        kind, test = _KIND[type(obj).__name__]
        xr = _to_rest(x, obj, t)
        ins, cross = test(obj, xr, xr[e[:, 0]], xr[e[:, 1]])
        solid = kind in ("sphere", "box") or (kind == "mesh" and obj.solid)
        ends_in = ins[e[:, 0]] | ins[e[:, 1]] if solid else np.zeros(len(e), dtype=bool)
        cross = (cross | ends_in) & checked
        chord = cross & ~ends_in if solid else np.zeros(len(e), dtype=bool)
        below = ins & free if kind == "plane" else np.zeros(len(x), dtype=bool)
        inside = ins & free if kind != "plane" else np.zeros(len(x), dtype=bool)
        per.append({"index": index, "kind": kind, "inside": np.nonzero(inside)[0],
                    "edges": np.nonzero(cross)[0], "chords": np.nonzero(chord)[0],
                    "below": np.nonzero(below)[0]})
        all_in |= inside
        all_below |= below
        all_cross |= cross
        all_chord |= chord
    out = {}
    for name, mask in (("inside", all_in), ("edges", all_cross), ("chords", all_chord),
                       ("below", all_below)):
        out[name] = int(mask.sum())
        out[name + "_idx"] = np.nonzero(mask)[0]
    out["colliders"] = per
    out["time"] = float(t)
    return out


# --- exported runs -------------------------------------------------------------------------
def check_npz(npz_path, scene_path, every: int = 1, out=sys.stdout) -> list[dict]:
    """Every `every`-th frame of a `render --export-npz` file (positions (F, N, 3), faces,
    sim_times) against the colliders of its scene (JSON); prints a line per frame and
    returns the results. Pins: the cloth model's (pipeline.physics.model.build_model)."""
    root = str(Path(__file__).resolve().parents[1])
    if root not in sys.path:
        sys.path.append(root)  # the repository's pipeline, when not installed
    from pipeline import load_scene
    from pipeline.physics.model import build_model

    data = np.load(npz_path)
    positions, faces = data["positions"], data["faces"]
    times = data["sim_times"] if "sim_times" in data.files else data["times"]
    frames = data["sim_frames"] if "sim_frames" in data.files else np.arange(len(positions))
    scene = load_scene(str(scene_path))
    pinned = build_model(scene).pinned.astype(bool)
    if len(pinned) != positions.shape[1]:
        print(f"note: {len(pinned)} model points against {positions.shape[1]} exported: "
              "pins not applied", file=out)
        pinned = None
    edges = unique_edges(faces)
    kinds = ", ".join(_KIND[type(c).__name__][0] for c in scene.colliders) or "none"
    print(f"{npz_path}: {positions.shape[1]} points, {len(edges)} edges, {len(positions)} "
          f"frames; colliders: {kinds}", file=out)
    print(f"{'frame':>6} {'time':>7} {'inside':>7} {'edges':>6} {'chords':>6} {'below':>6}",
          file=out)
    rows = []
    for k in range(0, len(positions), max(1, int(every))):
        v = collider_violations(positions[k], edges, scene.colliders, float(times[k]), pinned)
        rows.append(v)
        print(f"{int(frames[k]):6d} {float(times[k]):7.3f} {v['inside']:7d} {v['edges']:6d} "
              f"{v['chords']:6d} {v['below']:6d}", file=out, flush=True)
    worst = max((r["inside"] + r["edges"] for r in rows), default=0)
    print(f"{len(rows)} frames checked, {sum(r['inside'] + r['edges'] > 0 for r in rows)} with "
          f"points inside or edges through a collider (worst {worst})", file=out)
    return rows


def main(argv=None) -> int:
    import argparse

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("npz", help="a file written by render --export-npz")
    ap.add_argument("scene", help="the scene JSON it was rendered from")
    ap.add_argument("--every", type=int, default=1, help="check every n-th frame (default 1)")
    args = ap.parse_args(argv)
    rows = check_npz(args.npz, args.scene, args.every)
    return 1 if any(r["inside"] or r["edges"] for r in rows) else 0


if __name__ == "__main__":
    sys.exit(main())
