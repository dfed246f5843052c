"""An independent self-intersection checker for cloth meshes (issue 43), written apart from
the solver's contact code: plain numpy and scipy, brute force made fast by pruning.

    from crossings import edge_triangle_crossings, min_separation
    n = edge_triangle_crossings(points, triangles)        # proper crossings, an int
    d = min_separation(points, triangles, r=3 * thickness) # inf if nothing closer than r

Crossings. Every edge of the cloth (the unique edges of its triangles) against every triangle
that shares no vertex with it: does the closed segment meet the closed triangle? Pairs are
pruned by bounding spheres (scipy.spatial.cKDTree on edge midpoints and triangle centroids,
the rare elements far larger than the median tested against everything) and then by bounding
boxes; the survivors are decided by orientation signs:

    sp, sq = orient(a, b, c, p), orient(a, b, c, q)          (the ends against the plane)
    s1, s2, s3 = orient(p, q, a, b), orient(p, q, b, c), orient(p, q, c, a)  (the line
                                                              against the triangle's edges)

Every sign is exact: the float64 determinant is trusted when it exceeds Shewchuk's error
bound for orient3d (doubled), or when every product in it is an exact zero (points sharing a
coordinate plane, e.g. a flat cloth); otherwise it is recomputed exactly in rational
arithmetic (fractions.Fraction of the float64 inputs). Degenerate cases, decided exactly:

- a **crossing** (the count): the ends strictly on opposite sides of the triangle's plane
  (sp * sq < 0) and the line strictly inside the triangle (s1, s2, s3 all non-zero, one
  sign): the segment passes through the triangle's interior at a single point.
- **touching** (reported apart, never counted as a crossing): the closed segment meets the
  closed triangle in any other way: an end lying on the triangle (sp or sq = 0), the segment
  passing exactly through a triangle edge or corner (a zero among s1..s3, the others of one
  sign), or segment and triangle coplanar and overlapping (sp = sq = 0; decided by exact 2-D
  tests in a coordinate plane the configuration does not collapse in).
- nothing otherwise (the ends strictly on one side, or s1..s3 of both strict signs).

So a pass-through exactly at an edge or vertex of a triangle shows as touching, not as a
crossing (a watertight count would need symbolic perturbation, and would turn a one-sided
touch into two crossings). In simulated float positions exact zeros do not happen in
practice; hand-built meshes and flat cloths are where they do. Coplanar and near-coplanar
pairs are first cleared in floats when their distance (segment ends to triangle, segment
to triangle edges) is clearly larger than the smaller plane distance of the ends, which any
meeting pair cannot exceed; only the rest go to rational arithmetic.

Separation. `min_separation` is the smallest vertex-triangle distance (a point against a
triangle not containing it) and edge-edge distance (two edges sharing no vertex), among pairs
closer than r (pruned the same way), inf when there are none. With `rest_points` and
`rest_min`, pairs whose distance in the rest shape is at most rest_min are left out (issue 43
asks for the pairs "further apart than thickness at rest").
"""
from __future__ import annotations

from fractions import Fraction
from typing import NamedTuple

import numpy as np
from scipy.spatial import cKDTree

__all__ = [
    "Contacts",
    "Separation",
    "edge_triangle_contacts",
    "edge_triangle_crossing_pairs",
    "edge_triangle_crossings",
    "min_separation",
    "point_triangle_distance",
    "segment_segment_distance",
    "segment_triangle_distance",
    "separation_pairs",
    "unique_edges",
]

_EPS = 2.0 ** -53
#: Shewchuk's orient3d error bound (errboundA), doubled for the other expansion order used here
_O3D_BOUND = 2.0 * (7.0 + 56.0 * _EPS) * _EPS
#: products of three float64 factors each at least this large cannot underflow
_NO_UNDERFLOW = 1e-100
#: pairs per vectorised batch (memory)
_BATCH = 1 << 21


# --- topology ------------------------------------------------------------------------------
def unique_edges(triangles: np.ndarray) -> np.ndarray:
    """(E, 2) int64: the unique edges of `triangles`, each (low, high), sorted."""
    t = np.asarray(triangles, dtype=np.int64).reshape(-1, 3)
    if len(t) == 0:
        return np.zeros((0, 2), dtype=np.int64)
    e = np.concatenate([t[:, [0, 1]], t[:, [1, 2]], t[:, [2, 0]]])
    e.sort(axis=1)
    return np.unique(e, axis=0)


def _check(points, triangles) -> tuple[np.ndarray, np.ndarray]:
    p = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 3)
    t = np.ascontiguousarray(triangles, dtype=np.int64).reshape(-1, 3)
    if not np.all(np.isfinite(p)):
        raise ValueError("points must be finite (did the run diverge?)")
    if len(t) and (t.min() < 0 or t.max() >= len(p)):
        raise ValueError("triangle indices out of range")
    return p, t


# --- vector helpers ------------------------------------------------------------------------
def _dot(u, v):
    return np.einsum("ij,ij->i", u, v)


def _norm(u):
    return np.sqrt(_dot(u, u))


def _orient3d(a, b, c, d) -> tuple[np.ndarray, np.ndarray]:
    """Sign of det[a - d; b - d; c - d] per row (int8) and whether it is certain."""
    ad, bd, cd = a - d, b - d, c - d
    adx, ady, adz = ad.T
    bdx, bdy, bdz = bd.T
    cdx, cdy, cdz = cd.T
    m1, m2 = bdx * cdy, bdy * cdx
    m3, m4 = cdx * ady, cdy * adx
    m5, m6 = adx * bdy, ady * bdx
    det = adz * (m1 - m2) + bdz * (m3 - m4) + cdz * (m5 - m6)
    perm = (np.abs(adz) * (np.abs(m1) + np.abs(m2)) + np.abs(bdz) * (np.abs(m3) + np.abs(m4))
            + np.abs(cdz) * (np.abs(m5) + np.abs(m6)))
    certain = np.abs(det) > _O3D_BOUND * perm
    # every product an exact zero: one factor of each is an exact zero (x - y == 0 iff x == y),
    # unless non-zero factors underflowed together: excluded by their size
    diffs = np.abs(np.concatenate([ad, bd, cd], axis=1))
    tiny = np.any((diffs > 0) & (diffs < _NO_UNDERFLOW), axis=1)
    zero = (perm == 0) & ~tiny
    sign = np.where(certain, np.sign(det), 0).astype(np.int8)
    return sign, certain | zero


# --- distances (float, vectorised over rows) ------------------------------------------------
def _point_segment(p, a, b):
    ab = b - a
    ll = _dot(ab, ab)
    with np.errstate(invalid="ignore", divide="ignore"):
        t = np.where(ll > 0, _dot(p - a, ab) / np.where(ll > 0, ll, 1.0), 0.0)
    t = np.clip(t, 0.0, 1.0)
    return _norm(p - (a + t[:, None] * ab))


def segment_segment_distance(p1, q1, p2, q2) -> np.ndarray:
    """Distance between segments [p1, q1] and [p2, q2], row by row ((K, 3) arrays): the
    smallest of the four end-to-segment distances and, when it lies inside both segments,
    the common perpendicular's length (parallel segments need no special case)."""
    p1, q1, p2, q2 = (np.atleast_2d(np.asarray(x, dtype=np.float64)) for x in (p1, q1, p2, q2))
    d = np.minimum(np.minimum(_point_segment(p1, p2, q2), _point_segment(q1, p2, q2)),
                   np.minimum(_point_segment(p2, p1, q1), _point_segment(q2, p1, q1)))
    d1, d2, r = q1 - p1, q2 - p2, p1 - p2
    a, e, b = _dot(d1, d1), _dot(d2, d2), _dot(d1, d2)
    c, f = _dot(d1, r), _dot(d2, r)
    den = a * e - b * b
    ok = den > 1e-12 * a * e
    safe = np.where(ok, den, 1.0)
    s = (b * f - c * e) / safe
    t = (a * f - b * c) / safe
    inside = ok & (s >= 0) & (s <= 1) & (t >= 0) & (t <= 1)
    if np.any(inside):
        di = _norm((p1 + s[:, None] * d1) - (p2 + t[:, None] * d2))
        d = np.where(inside, np.minimum(d, di), d)
    return d


def point_triangle_distance(p, a, b, c) -> np.ndarray:
    """Distance from points p to triangles (a, b, c), row by row ((K, 3) arrays): the plane
    distance when p projects inside the triangle, else the nearest edge's."""
    p, a, b, c = (np.atleast_2d(np.asarray(x, dtype=np.float64)) for x in (p, a, b, c))
    d = np.minimum(np.minimum(_point_segment(p, a, b), _point_segment(p, b, c)),
                   _point_segment(p, c, a))
    n = np.cross(b - a, c - a)
    nn = _dot(n, n)
    w1 = _dot(np.cross(b - a, p - a), n)
    w2 = _dot(np.cross(c - b, p - b), n)
    w3 = _dot(np.cross(a - c, p - c), n)
    inside = (nn > 0) & (w1 >= 0) & (w2 >= 0) & (w3 >= 0)
    if np.any(inside):
        h = np.abs(_dot(p - a, n)) / np.sqrt(np.where(nn > 0, nn, 1.0))
        d = np.where(inside, np.minimum(d, h), d)
    return d


def segment_triangle_distance(p, q, a, b, c) -> np.ndarray:
    """min(ends to triangle, segment to triangle edges): the distance between segment and
    triangle when they do not meet (0 is not detected for a segment through the interior)."""
    return np.minimum.reduce([point_triangle_distance(p, a, b, c),
                              point_triangle_distance(q, a, b, c),
                              segment_segment_distance(p, q, a, b),
                              segment_segment_distance(p, q, b, c),
                              segment_segment_distance(p, q, c, a)])


# --- the same distances over index pairs, compiled (numba, serial; numpy when it is absent) ---
try:
    import numba
except ImportError:  # pragma: no cover
    numba = None


def _pair_distances_py(p, tris, vi, ti, edges, ei, ej):
    """(vertex-triangle distances, edge-edge distances) of the given index pairs (numpy)."""
    dv = np.concatenate([np.zeros(0)] + [point_triangle_distance(
        p[vi[k:k + _BATCH]], *(p[tris[ti[k:k + _BATCH], m]] for m in range(3)))
        for k in range(0, len(vi), _BATCH)])
    de = np.concatenate([np.zeros(0)] + [segment_segment_distance(
        p[edges[ei[k:k + _BATCH], 0]], p[edges[ei[k:k + _BATCH], 1]],
        p[edges[ej[k:k + _BATCH], 0]], p[edges[ej[k:k + _BATCH], 1]])
        for k in range(0, len(ei), _BATCH)])
    return dv, de


_pair_distances = _pair_distances_py
if numba is not None:
    @numba.njit(cache=False)
    def _xyz(p, i):
        return p[i, 0], p[i, 1], p[i, 2]

    @numba.njit(cache=False, fastmath=False)
    def _nb_point_segment(px, py, pz, ax, ay, az, bx, by, bz):
        ux, uy, uz = bx - ax, by - ay, bz - az
        ll = ux * ux + uy * uy + uz * uz
        t = 0.0
        if ll > 0:
            t = ((px - ax) * ux + (py - ay) * uy + (pz - az) * uz) / ll
            t = min(max(t, 0.0), 1.0)
        dx, dy, dz = px - (ax + t * ux), py - (ay + t * uy), pz - (az + t * uz)
        return np.sqrt(dx * dx + dy * dy + dz * dz)

    @numba.njit(cache=False)
    def _nb_seg_seg(p, a0, a1, b0, b1):
        p1x, p1y, p1z = _xyz(p, a0)
        q1x, q1y, q1z = _xyz(p, a1)
        p2x, p2y, p2z = _xyz(p, b0)
        q2x, q2y, q2z = _xyz(p, b1)
        d = min(min(_nb_point_segment(p1x, p1y, p1z, p2x, p2y, p2z, q2x, q2y, q2z),
                    _nb_point_segment(q1x, q1y, q1z, p2x, p2y, p2z, q2x, q2y, q2z)),
                min(_nb_point_segment(p2x, p2y, p2z, p1x, p1y, p1z, q1x, q1y, q1z),
                    _nb_point_segment(q2x, q2y, q2z, p1x, p1y, p1z, q1x, q1y, q1z)))
        d1x, d1y, d1z = q1x - p1x, q1y - p1y, q1z - p1z
        d2x, d2y, d2z = q2x - p2x, q2y - p2y, q2z - p2z
        rx, ry, rz = p1x - p2x, p1y - p2y, p1z - p2z
        a = d1x * d1x + d1y * d1y + d1z * d1z
        e = d2x * d2x + d2y * d2y + d2z * d2z
        b = d1x * d2x + d1y * d2y + d1z * d2z
        c = d1x * rx + d1y * ry + d1z * rz
        f = d2x * rx + d2y * ry + d2z * rz
        den = a * e - b * b
        if den > 1e-12 * a * e:
            s = (b * f - c * e) / den
            t = (a * f - b * c) / den
            if 0.0 <= s <= 1.0 and 0.0 <= t <= 1.0:
                x = (p1x + s * d1x) - (p2x + t * d2x)
                y = (p1y + s * d1y) - (p2y + t * d2y)
                z = (p1z + s * d1z) - (p2z + t * d2z)
                d = min(d, np.sqrt(x * x + y * y + z * z))
        return d

    @numba.njit(cache=False)
    def _nb_pt_tri(p, v, i0, i1, i2):
        px, py, pz = _xyz(p, v)
        ax, ay, az = _xyz(p, i0)
        bx, by, bz = _xyz(p, i1)
        cx, cy, cz = _xyz(p, i2)
        d = min(min(_nb_point_segment(px, py, pz, ax, ay, az, bx, by, bz),
                    _nb_point_segment(px, py, pz, bx, by, bz, cx, cy, cz)),
                _nb_point_segment(px, py, pz, cx, cy, cz, ax, ay, az))
        ux, uy, uz = bx - ax, by - ay, bz - az
        wx, wy, wz = cx - ax, cy - ay, cz - az
        nx, ny, nz = uy * wz - uz * wy, uz * wx - ux * wz, ux * wy - uy * wx
        nn = nx * nx + ny * ny + nz * nz
        if nn > 0:
            ok = True
            for (sx, sy, sz, ex, ey, ez) in ((ax, ay, az, bx, by, bz), (bx, by, bz, cx, cy, cz),
                                             (cx, cy, cz, ax, ay, az)):
                gx, gy, gz = ex - sx, ey - sy, ez - sz
                hx, hy, hz = px - sx, py - sy, pz - sz
                kx, ky, kz = gy * hz - gz * hy, gz * hx - gx * hz, gx * hy - gy * hx
                if kx * nx + ky * ny + kz * nz < 0:
                    ok = False
            if ok:
                h = abs((px - ax) * nx + (py - ay) * ny + (pz - az) * nz) / np.sqrt(nn)
                d = min(d, h)
        return d

    @numba.njit(cache=False)
    def _nb_pair_distances(p, tris, vi, ti, edges, ei, ej):
        dv = np.empty(len(vi))
        for k in range(len(vi)):
            t = ti[k]
            dv[k] = _nb_pt_tri(p, vi[k], tris[t, 0], tris[t, 1], tris[t, 2])
        de = np.empty(len(ei))
        for k in range(len(ei)):
            de[k] = _nb_seg_seg(p, edges[ei[k], 0], edges[ei[k], 1], edges[ej[k], 0],
                                edges[ej[k], 1])
        return dv, de

    def _pair_distances(p, tris, vi, ti, edges, ei, ej):
        """(vertex-triangle distances, edge-edge distances) of the given index pairs."""
        return _nb_pair_distances(np.ascontiguousarray(p, dtype=np.float64),
                                  np.ascontiguousarray(tris, dtype=np.int64),
                                  np.ascontiguousarray(vi, dtype=np.int64),
                                  np.ascontiguousarray(ti, dtype=np.int64),
                                  np.ascontiguousarray(edges, dtype=np.int64),
                                  np.ascontiguousarray(ei, dtype=np.int64),
                                  np.ascontiguousarray(ej, dtype=np.int64))


# --- exact predicates (rational arithmetic, one pair at a time) ----------------------------
def _fr(v) -> tuple[Fraction, Fraction, Fraction]:
    return tuple(Fraction(float(x)) for x in v)


def _sgn(x) -> int:
    return (x > 0) - (x < 0)


def _o3(a, b, c, d) -> int:
    adx, ady, adz = a[0] - d[0], a[1] - d[1], a[2] - d[2]
    bdx, bdy, bdz = b[0] - d[0], b[1] - d[1], b[2] - d[2]
    cdx, cdy, cdz = c[0] - d[0], c[1] - d[1], c[2] - d[2]
    return _sgn(adz * (bdx * cdy - bdy * cdx) + bdz * (cdx * ady - cdy * adx)
                + cdz * (adx * bdy - ady * bdx))


def _o2(a, b, c) -> int:
    return _sgn((b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0]))


def _cross_exact(u, v):
    return (u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0])


def _sub(u, v):
    return (u[0] - v[0], u[1] - v[1], u[2] - v[2])


def _on_segment_2d(a, b, p) -> bool:
    """p (collinear with a, b) within the closed box of a, b."""
    return (min(a[0], b[0]) <= p[0] <= max(a[0], b[0])
            and min(a[1], b[1]) <= p[1] <= max(a[1], b[1]))


def _segments_meet_2d(p, q, a, b) -> bool:
    o1, o2, o3, o4 = _o2(p, q, a), _o2(p, q, b), _o2(a, b, p), _o2(a, b, q)
    if o1 * o2 < 0 and o3 * o4 < 0:
        return True
    return ((o1 == 0 and _on_segment_2d(p, q, a)) or (o2 == 0 and _on_segment_2d(p, q, b))
            or (o3 == 0 and _on_segment_2d(a, b, p)) or (o4 == 0 and _on_segment_2d(a, b, q)))


def _coplanar_meet(p, q, a, b, c) -> bool:
    """Closed segment pq meets closed triangle abc, all five points coplanar (exact)."""
    pts = (p, q, a, b, c)
    normal = None
    for u, v, w in ((a, b, c), (p, q, a), (p, q, b), (p, q, c), (p, a, b), (q, a, b)):
        n = _cross_exact(_sub(v, u), _sub(w, u))
        if any(x != 0 for x in n):
            normal = n
            break
    if normal is not None:  # drop the axis of the largest normal component
        drop = max(range(3), key=lambda k: abs(normal[k]))
    else:  # all on one line (or one point): keep its longest axis
        d = next((_sub(v, pts[0]) for v in pts[1:] if any(x != 0 for x in _sub(v, pts[0]))),
                 (1, 0, 0))
        keep = max(range(3), key=lambda k: abs(d[k]))
        drop = (keep + 1) % 3
    k0, k1 = [k for k in range(3) if k != drop]
    p2, q2, a2, b2, c2 = ((v[k0], v[k1]) for v in pts)
    s = (_o2(a2, b2, c2))
    if s != 0:  # a proper triangle: an end inside it
        for x in (p2, q2):
            o = (_o2(a2, b2, x), _o2(b2, c2, x), _o2(c2, a2, x))
            if all(v * s >= 0 for v in o):
                return True
    return any(_segments_meet_2d(p2, q2, u, v) for u, v in ((a2, b2), (b2, c2), (c2, a2)))


def _classify_exact(p, q, a, b, c) -> int:
    """0 apart, 1 crossing, 2 touching (see the module's doc), in rational arithmetic."""
    p, q, a, b, c = (_fr(v) for v in (p, q, a, b, c))
    sp, sq = _o3(a, b, c, p), _o3(a, b, c, q)
    if sp * sq > 0:
        return 0
    if sp == 0 and sq == 0:
        return 2 if _coplanar_meet(p, q, a, b, c) else 0
    s = (_o3(p, q, a, b), _o3(p, q, b, c), _o3(p, q, c, a))
    if max(s) > 0 and min(s) < 0:
        return 0
    if sp * sq < 0 and 0 not in s:
        return 1
    return 2


# --- pair finding ----------------------------------------------------------------------------
def _unique(key: np.ndarray) -> np.ndarray:
    """Sorted unique values (a sort: faster here than numpy's hashing unique)."""
    key = np.sort(key)
    return key[np.concatenate([[True], key[1:] != key[:-1]])] if len(key) else key


def _big(r: np.ndarray) -> np.ndarray:
    """Elements whose bounding radius is far above the median: tested against everything."""
    if len(r) == 0:
        return np.zeros(0, dtype=bool)
    med = float(np.median(r))
    return r > 4.0 * med if med > 0 else np.zeros(len(r), dtype=bool)


def _brute_pairs(ca, ra, cb, rb, ia, ib):
    """(i, j) among ia x ib with |ca_i - cb_j| <= ra_i + rb_j (chunked)."""
    out_i, out_j = [], []
    if len(ia) == 0 or len(ib) == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    step = max(1, _BATCH // len(ib))
    for k in range(0, len(ia), step):
        ii = ia[k:k + step]
        d = np.linalg.norm(ca[ii][:, None, :] - cb[ib][None, :, :], axis=2)
        hit = d <= ra[ii][:, None] + rb[ib][None, :]
        x, y = np.nonzero(hit)
        out_i.append(ii[x])
        out_j.append(ib[y])
    return np.concatenate(out_i), np.concatenate(out_j)


def _sphere_pairs(ca, ra, cb, rb) -> tuple[np.ndarray, np.ndarray]:
    """All (i, j) with |ca_i - cb_j| <= ra_i + rb_j: a k-d tree for the ordinary elements,
    brute force for the few big ones."""
    big_a, big_b = _big(ra), _big(rb)
    sa, sb = np.nonzero(~big_a)[0], np.nonzero(~big_b)[0]
    parts_i, parts_j = [], []
    if len(sa) and len(sb):
        reach = float(ra[sa].max() + rb[sb].max())
        ta, tb = cKDTree(ca[sa]), cKDTree(cb[sb])
        m = ta.sparse_distance_matrix(tb, reach, output_type="ndarray")
        i, j = sa[m["i"]], sb[m["j"]]
        keep = m["v"] <= ra[i] + rb[j]
        parts_i.append(i[keep])
        parts_j.append(j[keep])
    all_a, all_b = np.arange(len(ca)), np.arange(len(cb))
    i, j = _brute_pairs(ca, ra, cb, rb, np.nonzero(big_a)[0], all_b)
    parts_i.append(i)
    parts_j.append(j)
    i, j = _brute_pairs(cb, rb, ca, ra, np.nonzero(big_b)[0], all_a[~big_a])
    parts_i.append(j)
    parts_j.append(i)
    i = np.concatenate(parts_i).astype(np.int64)
    j = np.concatenate(parts_j).astype(np.int64)
    if len(i) and (big_a.any() or big_b.any()):  # the brute force repeats some tree pairs
        i, j = np.divmod(_unique(i * len(cb) + j), len(cb))
    return i, j


def _slack(p: np.ndarray) -> float:
    return 1e-9 * (1.0 + float(np.abs(p).max())) if len(p) else 0.0


def _edge_triangle_candidates(p, edges, tris):
    """(edge index, triangle index) pairs whose boxes overlap and which share no vertex."""
    slack = _slack(p)
    e0, e1 = p[edges[:, 0]], p[edges[:, 1]]
    ec = 0.5 * (e0 + e1)
    er = 0.5 * _norm(e1 - e0) + slack
    ta, tb, tc = p[tris[:, 0]], p[tris[:, 1]], p[tris[:, 2]]
    tcen = (ta + tb + tc) / 3.0
    tr = np.maximum.reduce([_norm(ta - tcen), _norm(tb - tcen), _norm(tc - tcen)]) + slack
    ei, ti = _sphere_pairs(ec, er, tcen, tr)
    if len(ei) == 0:
        return ei, ti
    # shared vertex
    u, v = edges[ei, 0], edges[ei, 1]
    t = tris[ti]
    share = ((u[:, None] == t) | (v[:, None] == t)).any(axis=1)
    ei, ti = ei[~share], ti[~share]
    # boxes
    elo, ehi = np.minimum(e0, e1), np.maximum(e0, e1)
    tlo = np.minimum(np.minimum(ta, tb), tc)
    thi = np.maximum(np.maximum(ta, tb), tc)
    ok = np.all((elo[ei] <= thi[ti] + slack) & (tlo[ti] <= ehi[ei] + slack), axis=1)
    return ei[ok], ti[ok]


# --- crossings -----------------------------------------------------------------------------
class Contacts(NamedTuple):
    """Edge-triangle pairs, each row (edge vertex i, edge vertex j, triangle index), sorted."""

    crossings: np.ndarray  # (K, 3): the segment passes through the triangle's interior
    touching: np.ndarray  # (M, 3): they meet only degenerately (see the module's doc)


def _classify(P, Q, A, B, C, scale_tol: float) -> np.ndarray:
    """0 apart, 1 crossing, 2 touching for each row."""
    k = len(P)
    out = np.zeros(k, dtype=np.int8)
    sp, cp = _orient3d(A, B, C, P)
    sq, cq = _orient3d(A, B, C, Q)
    both = cp & cq
    opp = both & (sp.astype(np.int16) * sq < 0)
    undecided = np.zeros(k, dtype=bool)

    idx = np.nonzero(opp)[0]
    if len(idx):
        p, q, a, b, c = P[idx], Q[idx], A[idx], B[idx], C[idx]
        s1, c1 = _orient3d(p, q, a, b)
        s2, c2 = _orient3d(p, q, b, c)
        s3, c3 = _orient3d(p, q, c, a)
        pos = ((s1 > 0) & c1) | ((s2 > 0) & c2) | ((s3 > 0) & c3)
        neg = ((s1 < 0) & c1) | ((s2 < 0) & c2) | ((s3 < 0) & c3)
        allc = c1 & c2 & c3
        strict = allc & (s1 != 0) & (s1 == s2) & (s2 == s3)
        out[idx[strict]] = 1
        out[idx[allc & ~(pos & neg) & ~strict]] = 2
        undecided[idx[~allc & ~(pos & neg)]] = True

    # an end on or near the plane (or the plane sign uncertain): clear in floats what is
    # clearly apart, decide the rest exactly
    near = ~(both & (sp.astype(np.int16) * sq != 0))
    idx = np.nonzero(near)[0]
    if len(idx):
        p, q, a, b, c = P[idx], Q[idx], A[idx], B[idx], C[idx]
        n = np.cross(b - a, c - a)
        nl = _norm(n)
        good = nl > 0
        safe = np.where(good, nl, 1.0)
        hp = np.abs(_dot(p - a, n)) / safe
        hq = np.abs(_dot(q - a, n)) / safe
        dist = segment_triangle_distance(p, q, a, b, c)
        apart = good & (dist > np.minimum(hp, hq) + scale_tol)
        undecided[idx[~apart]] = True

    for i in np.nonzero(undecided)[0]:
        out[i] = _classify_exact(P[i], Q[i], A[i], B[i], C[i])
    return out


def edge_triangle_contacts(points, triangles) -> Contacts:
    """Every edge against every triangle sharing no vertex with it: the proper crossings and
    the degenerate touchings (module doc), as (edge i, edge j, triangle) rows."""
    p, tris = _check(points, triangles)
    edges = unique_edges(tris)
    empty = np.zeros((0, 3), dtype=np.int64)
    if len(edges) == 0:
        return Contacts(empty, empty)
    ei, ti = _edge_triangle_candidates(p, edges, tris)
    tol = _slack(p)
    cross, touch = [empty], [empty]
    for k in range(0, len(ei), _BATCH):
        e, t = ei[k:k + _BATCH], ti[k:k + _BATCH]
        kind = _classify(p[edges[e, 0]], p[edges[e, 1]], p[tris[t, 0]], p[tris[t, 1]],
                         p[tris[t, 2]], tol)
        rows = np.column_stack([edges[e], t])
        cross.append(rows[kind == 1])
        touch.append(rows[kind == 2])
    c, t = np.concatenate(cross), np.concatenate(touch)
    return Contacts(c[np.lexsort(c.T[::-1])], t[np.lexsort(t.T[::-1])])


def edge_triangle_crossing_pairs(points, triangles) -> np.ndarray:
    """(K, 3) rows (edge vertex i, edge vertex j, triangle index): each edge passing through
    the interior of a triangle that shares no vertex with it."""
    return edge_triangle_contacts(points, triangles).crossings


def edge_triangle_crossings(points, triangles) -> int:
    """How many (edge, triangle) pairs cross: edges of `triangles` through the interior of
    triangles sharing no vertex with them (touching, coplanar: not counted; module doc)."""
    return len(edge_triangle_crossing_pairs(points, triangles))


# --- separation ----------------------------------------------------------------------------
class Separation(NamedTuple):
    """Pairs closer than r: vertex-triangle rows (vertex, triangle) with their distances, and
    edge-edge rows (i, j, k, l) (edge i-j against edge k-l) with theirs."""

    vt: np.ndarray
    vt_dist: np.ndarray
    ee: np.ndarray
    ee_dist: np.ndarray

    @property
    def min(self) -> float:
        m = [float(x.min()) for x in (self.vt_dist, self.ee_dist) if len(x)]
        return min(m) if m else float("inf")


def _self_pairs(c, r) -> tuple[np.ndarray, np.ndarray]:
    """All i < j with |c_i - c_j| <= r_i + r_j."""
    big = _big(r)
    s = np.nonzero(~big)[0]
    parts_i, parts_j = [], []
    if len(s) > 1:
        reach = 2.0 * float(r[s].max())
        pairs = cKDTree(c[s]).query_pairs(reach, output_type="ndarray")
        if len(pairs):
            i, j = s[pairs[:, 0]], s[pairs[:, 1]]
            keep = _norm(c[i] - c[j]) <= r[i] + r[j]
            parts_i.append(i[keep])
            parts_j.append(j[keep])
    if big.any():
        i, j = _brute_pairs(c, r, c, r, np.nonzero(big)[0], np.arange(len(c)))
        lo, hi = np.minimum(i, j), np.maximum(i, j)
        keep = lo != hi
        parts_i.append(lo[keep])
        parts_j.append(hi[keep])
    if not parts_i:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    i = np.concatenate(parts_i).astype(np.int64)
    j = np.concatenate(parts_j).astype(np.int64)
    if big.any():
        i, j = np.divmod(_unique(i * len(c) + j), len(c))
    return i, j


def separation_pairs(points, triangles, r: float, *, rest_points=None,
                     rest_min: float = 0.0, compiled: bool = True) -> Separation:
    """Vertex-triangle (vertex not in the triangle; every point, in a triangle or not) and
    edge-edge (no shared vertex) pairs at distance <= r; with `rest_points`, leaving out the
    pairs at distance <= rest_min in that shape. `compiled`: the distances by the numba
    loops (when numba imports) or, False, by the numpy functions above (the same formulas)."""
    p, tris = _check(points, triangles)
    r = float(r)
    if not np.isfinite(r) or r < 0:
        raise ValueError("r must be a finite distance >= 0")
    rest = None if rest_points is None else _check(rest_points, tris)[0]
    if len(tris) == 0:
        z = np.zeros(0)
        return Separation(np.zeros((0, 2), np.int64), z, np.zeros((0, 4), np.int64), z)
    distances = _pair_distances if compiled else _pair_distances_py
    slack = _slack(p)
    edges = unique_edges(tris)

    ta, tb, tc = p[tris[:, 0]], p[tris[:, 1]], p[tris[:, 2]]
    tcen = (ta + tb + tc) / 3.0
    tr = np.maximum.reduce([_norm(ta - tcen), _norm(tb - tcen), _norm(tc - tcen)])
    vi, ti = _sphere_pairs(p, np.full(len(p), r + slack), tcen, tr + slack)
    own = (tris[ti] == vi[:, None]).any(axis=1)
    vi, ti = vi[~own], ti[~own]
    lo = np.minimum(np.minimum(ta, tb), tc) - (r + slack)
    hi = np.maximum(np.maximum(ta, tb), tc) + (r + slack)
    ok = np.all((p[vi] >= lo[ti]) & (p[vi] <= hi[ti]), axis=1)
    vi, ti = vi[ok], ti[ok]

    e0, e1 = p[edges[:, 0]], p[edges[:, 1]]
    i, j = _self_pairs(0.5 * (e0 + e1), 0.5 * _norm(e1 - e0) + 0.5 * r + slack)
    share = (edges[i][:, :, None] == edges[j][:, None, :]).reshape(-1, 4).any(axis=1)
    i, j = i[~share], j[~share]
    lo, hi = np.minimum(e0, e1), np.maximum(e0, e1)
    ok = np.all((lo[i] <= hi[j] + (r + slack)) & (lo[j] <= hi[i] + (r + slack)), axis=1)
    i, j = i[ok], j[ok]

    dv, de = distances(p, tris, vi, ti, edges, i, j)
    keep = dv <= r
    vi, ti, dv = vi[keep], ti[keep], dv[keep]
    keep = de <= r
    i, j, de = i[keep], j[keep], de[keep]
    if rest is not None:
        rv, re = distances(rest, tris, vi, ti, edges, i, j)
        keep = rv > rest_min
        vi, ti, dv = vi[keep], ti[keep], dv[keep]
        keep = re > rest_min
        i, j, de = i[keep], j[keep], de[keep]
    return Separation(np.column_stack([vi, ti]), dv, np.column_stack([edges[i], edges[j]]), de)


def min_separation(points, triangles, r: float, *, rest_points=None,
                   rest_min: float = 0.0) -> float:
    """The smallest vertex-triangle (vertex not in the triangle) and edge-edge (no shared
    vertex) distance among pairs closer than r; inf when no pair is within r. `rest_points`
    and `rest_min`: leave out the pairs no further apart than rest_min in that shape."""
    return separation_pairs(points, triangles, r, rest_points=rest_points,
                            rest_min=rest_min).min
