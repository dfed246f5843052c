"""Shadows from the point light: a shadow map drawn by this project's own rasteriser from
the light, looked up per sample with percentage-closer soft shadows (PCSS, Fernando 2005).

The map: one perspective view from the light fitted to the bounding sphere of the shadow
casters (every mesh but the planes, which receive shadows and cast none), or, when the
light is inside that sphere, a cube of six 90-degree views. Each texel keeps the linear
depth (distance along the view axis) of the nearest caster; texels no caster covers are
infinitely far. Points outside every view are lit: no caster lies between them and the
light.

The lookup, per covered sample whose two-sided normal faces the light (a surface turned
away from the light is unlit, visibility 0):
- Depth bias: the receiver is the plane of its own triangle (the facet normal, not the
  smooth one), moved towards the light by OFFSET_TEXELS texel widths at its depth; each
  tap compares the caster's depth with that plane's depth along the tap's own ray. A flat
  lit surface therefore never shadows itself whatever its slope (no acne), and a fold's
  shadow starts within OFFSET_TEXELS texels of the fold (no gap).
- Soft shadows from a spherical light of radius a: a blocker search over the region of
  the map the light's disc covers as seen from the receiver (4 x 4 taps), the depth d_b
  of the farthest blocker found (the edge that casts the penumbra: the silhouette of a
  round blocker, not its nearer middle as PCSS's usual mean would take), the
  penumbra's full width at the receiver
  w = 2 a (d_r - d_b) / d_b, and a box filter of that width (up to 8 x 8 bilinear taps):
  the visibility ramps linearly across w, in world units, whatever the map's resolution.
  With a = 0 (or a penumbra under a texel) the four nearest texels are blended
  bilinearly: a hard shadow with a smooth edge.
"""
from __future__ import annotations

import math

import numpy as np
from clothjit import STAGE, njit

from .lighting import cross, dot, normalize, sub, two_sided
from .shade import fetch
from .camera import Camera
from .visibility import VisibilityBuffer, run_groups, view_distance

DEFAULT_RADIUS = 0.02  # metres, the light's default radius (render params "light_radius")
MAP_SIZE = 1024  # texels per side of each view of the map (params "shadow_map_size")
OFFSET_TEXELS = 1.5  # depth bias: receiver plane moved this many texel widths to the light
SEARCH_TAPS = 4  # blocker search: SEARCH_TAPS x SEARCH_TAPS taps
MAX_FILTER_TAPS = 8  # penumbra filter: at most MAX_FILTER_TAPS x MAX_FILTER_TAPS taps
LEVELS = 2  # looked up first at every 2 ** LEVELS-th sample of every 2 ** LEVELS-th row
# cube faces: the view axis (the direction a face looks along) and an up vector
_CUBE = (((1, 0, 0), (0, -1, 0)), ((-1, 0, 0), (0, -1, 0)), ((0, 1, 0), (0, 0, 1)),
         ((0, -1, 0), (0, 0, -1)), ((0, 0, 1), (0, -1, 0)), ((0, 0, -1), (0, -1, 0)))


def _view(eye, axis, up, tanh, near, far, size):
    """The Camera at eye looking along axis with a square view of tan(fov / 2) = tanh (up
    replaced when it is along the axis)."""
    f = np.asarray(axis, float) / np.linalg.norm(axis)
    if np.linalg.norm(np.cross(f, up)) < 1e-6:
        up = (1.0, 0.0, 0.0) if abs(f[0]) < 0.9 else (0.0, 0.0, 1.0)
    return Camera(tuple(eye), tuple(np.asarray(eye, float) + f), tuple(up),
                  math.degrees(2.0 * math.atan(tanh)), near, far, size, size)


@njit(cache=True, nogil=True, error_model="numpy")
def _linear_depth(g, groups, depth, near, far, out, least):
    """Rows g, g + groups, ... of the map: window z of the rasteriser's depth test ->
    distance along the view axis (float32: half the memory the look-ups read);
    least[g] = the least."""
    n = out.shape[1]
    lo = np.inf
    for j in range(g, n, groups):
        for i in range(n):
            z = depth[j * n + i]
            if z == np.inf:
                out[j, i] = np.inf
            else:
                d = view_distance(z, near, far)
                out[j, i] = d
                lo = min(lo, d)
    least[g] = lo


class ShadowMap:
    """The shadow map of one frame (rebuilt by `build`), `size` texels per side."""

    def __init__(self, size: int = MAP_SIZE):
        self.size = int(size)
        self.buffers: list[VisibilityBuffer] = []
        self.lin = np.empty((0, self.size, self.size), np.float32)
        self.views = np.empty((0, 3, 4))
        self.tanh = np.empty(0)
        self.near = np.empty(0)

    def build(self, va, nv, verts, bounds, light, radius, groups):
        """Draw the casters (triangles verts, vertex ids into va[:nv]; bounds: their
        vertices' bounds as `shadow_geometry` gives them, None without casters) from the
        light at `light` (3 numbers) of radius `radius`."""
        L = np.asarray(light, float)
        if bounds is None or verts.shape[0] == 0:
            self._views([])
            return
        c0, c1, c2, r, dmin, dmax = bounds
        c = np.array([c0, c1, c2])
        # a triangle can come nearer the light than its vertices: half the nearest vertex
        near = max(0.5 * dmin, 1e-4)
        far = dmax * 1.01 + 1e-4
        d = float(np.linalg.norm(c - L))
        n = self.size
        if d > 1.02 * r:  # one view fitted to the casters' bounding sphere
            # widened by the penumbra beyond the casters' outline: seen from the light, it
            # reaches at most radius / (nearest caster distance) further (tan units)
            tanh = (math.tan(math.asin(r / d)) + radius / max(d - r, near)) * 1.02
            cams = [_view(L, c - L, (0.0, 1.0, 0.0), tanh, near, far, n)]
        else:  # the light among the casters: a cube of six views
            cams = [_view(L, a, u, 1.0, near, far, n) for a, u in _CUBE]
        self._views(cams)
        for k, cam in enumerate(cams):
            buf = self.buffers[k]
            buf.draw(va, nv, verts, verts.shape[0], cam.view_projection(), groups)
            least = np.empty(groups)
            run_groups(_linear_depth, groups, (buf.depth, near, far, self.lin[k], least))
            # the blocker search reaches no nearer the light than the nearest caster
            self.near[k] = least.min()

    def _views(self, cams):
        """The look-ups' arrays of these views (Cameras): each view's 3x4 view matrix and
        tan(fov / 2) as its projection has it; near is set as each map is made."""
        k = len(cams)
        while len(self.buffers) < k:
            self.buffers.append(VisibilityBuffer(self.size, self.size))
        if self.lin.shape[0] != k:
            self.lin = np.empty((k, self.size, self.size), np.float32)
        self.views = np.array([cam.view_matrix()[:3] for cam in cams]).reshape(k, 3, 4)
        self.tanh = np.array([1.0 / cam.projection_matrix()[1, 1] for cam in cams])
        self.near = np.zeros(k)



@njit(cache=True, nogil=True, error_model="numpy")
def shadow_geometry(va, verts, runs, lp, out):
    """out[t] = the unit normal of triangle verts[t] (vertex ids into va) on the side of
    the light at lp (a triangle's plane does not pass through the light's side); returns
    the casters' bounds: (centre of the bounding box, radius of the sphere about it,
    nearest and farthest distance to lp) of the vertices va[a:b, :3] of every run (a, b),
    the bits of numpy's reductions without their copies of the strided columns (3-4 ms at
    40k vertices). One kernel: one compile at the first frame with shadows."""
    for t in range(verts.shape[0]):
        i0 = verts[t, 0]
        i1 = verts[t, 1]
        i2 = verts[t, 2]
        ng = cross((va[i1, 0] - va[i0, 0], va[i1, 1] - va[i0, 1], va[i1, 2] - va[i0, 2]),
                   (va[i2, 0] - va[i0, 0], va[i2, 1] - va[i0, 1], va[i2, 2] - va[i0, 2]))
        if dot(ng, (lp[0] - va[i0, 0], lp[1] - va[i0, 1], lp[2] - va[i0, 2])) < 0.0:
            ng = (-ng[0], -ng[1], -ng[2])
        ng = normalize(ng)
        out[t, 0] = ng[0]
        out[t, 1] = ng[1]
        out[t, 2] = ng[2]
    lo = (np.inf, np.inf, np.inf)
    hi = (-np.inf, -np.inf, -np.inf)
    for k in range(runs.shape[0]):
        for i in range(runs[k, 0], runs[k, 1]):
            p = (va[i, 0], va[i, 1], va[i, 2])
            lo = (p[0] if p[0] < lo[0] else lo[0], p[1] if p[1] < lo[1] else lo[1],
                  p[2] if p[2] < lo[2] else lo[2])
            hi = (p[0] if p[0] > hi[0] else hi[0], p[1] if p[1] > hi[1] else hi[1],
                  p[2] if p[2] > hi[2] else hi[2])
    cx, cy, cz = 0.5 * (lo[0] + hi[0]), 0.5 * (lo[1] + hi[1]), 0.5 * (lo[2] + hi[2])
    r2 = 0.0
    d2lo = np.inf
    d2hi = 0.0
    for k in range(runs.shape[0]):
        for i in range(runs[k, 0], runs[k, 1]):
            x, y, z = va[i, 0], va[i, 1], va[i, 2]
            e2 = (x - cx) * (x - cx) + (y - cy) * (y - cy) + (z - cz) * (z - cz)
            d2 = ((x - lp[0]) * (x - lp[0]) + (y - lp[1]) * (y - lp[1])
                  + (z - lp[2]) * (z - lp[2]))
            if e2 > r2:
                r2 = e2
            if d2 < d2lo:
                d2lo = d2
            if d2 > d2hi:
                d2hi = d2
    return cx, cy, cz, math.sqrt(r2), math.sqrt(d2lo), math.sqrt(d2hi)


@njit(cache=True, inline="always")
def _xform(v, p, w):
    """Rows of the 3x4 matrix v applied to p (w = 1: a point, w = 0: a direction)."""
    return (v[0, 0] * p[0] + v[0, 1] * p[1] + v[0, 2] * p[2] + w * v[0, 3],
            v[1, 0] * p[0] + v[1, 1] * p[1] + v[1, 2] * p[2] + w * v[1, 3],
            v[2, 0] * p[0] + v[2, 1] * p[1] + v[2, 2] * p[2] + w * v[2, 3])


@njit(cache=True, inline="always")
def _tap(lin, k, i, j, n, tanh, nv, c, d):
    """Depth of the caster at texel (i, j) of view k, and whether it is nearer the light
    than the receiver plane (nv . x = c, in view space) along that texel's ray."""
    if i < 0 or j < 0 or i >= n or j >= n:
        return np.inf, False
    z = np.float64(lin[k, j, i])
    if z == np.inf:
        return z, False
    a = ((i + 0.5) * 2.0 / n - 1.0) * tanh
    b = (1.0 - (j + 0.5) * 2.0 / n) * tanh
    den = nv[0] * a + nv[1] * b - nv[2]
    if den < -1e-9:  # z < c / den, the receiver plane's depth on this ray (den < 0)
        return z, z * den > c
    return z, z < d


@njit(cache=True, inline="always")
def _bilinear(lin, k, x, y, n, tanh, nv, c, d):
    """Visibility from the four texels around (x, y), weighted bilinearly."""
    i0 = int(math.floor(x))
    j0 = int(math.floor(y))
    fx = x - i0
    fy = y - j0
    vis = 0.0
    for q in range(4):
        i = i0 + (q & 1)
        j = j0 + (q >> 1)
        if not _tap(lin, k, i, j, n, tanh, nv, c, d)[1]:
            vis += (fx if q & 1 else 1.0 - fx) * (fy if q >> 1 else 1.0 - fy)
    return vis


# no reference counting: the helpers would otherwise take and drop a reference to every
# array of the frame per sample (atomic operations: 3-10x the pass's time)
@njit(**STAGE, _nrt=False)
def visibility_pass(f, g, lin, views, tanh, near, radius, normals, level, out):
    """out[s] = the light's visibility of the covered samples of `level` in the rows of
    group g. Level LEVELS: the samples whose x and y are multiples of 2 ** LEVELS, each
    looked up. A level l below: the samples of x and y multiples of s = 2 ** l, not both
    of 2 s, each the middle of an edge or of a cell of the grid of spacing 2 s (done by the
    levels above), taken from the two or four grid samples around it when they lie on its
    object and agree on full light or full shadow (copied) or all lie inside a penumbra
    (interpolated: the ramp is linear there), else looked up (shadow edges, silhouettes).
    A shadow edge runs between grid samples that differ, so only a shadow narrower than
    2 ** LEVELS samples between agreeing ones can be missed; about one sample in ten is
    looked up."""
    sw = f.width * f.aa
    sh = f.height * f.aa
    s = 1 << level
    top = level == LEVELS
    rows = (sh + s - 1) // s if top else (sh + 2 * s - 1) // (2 * s)
    # two passes over the level's samples: from the grid (or -1), then the samples left at
    # -1 looked up (one place that looks up, inlined once)
    for look in range(2):
        for r in range(g, rows, f.groups):
            # top: rows r s; below: the row of cells of the grid of spacing 2 s starting at
            # row 2 r s, whose samples of this level are the middles of each cell's top
            # edge, left edge and of the cell
            y0 = r * s if top else 2 * r * s
            for sy in range(y0, min(y0 + (s if top else 2 * s), sh), s):
                for sx in range((f.rowlo[sy] + s - 1) & ~(s - 1), f.rowhi[sy] + 1, s):
                    q = sy * sw + sx
                    m = f.prim[q]
                    if m < 0:
                        continue  # not covered
                    if look == 0:
                        if top or sx & s or sy & s:  # else a grid sample (done)
                            out[q] = -1.0 if top else _from_grid(
                                f.prim, f.obj_of, out, sw, sh, sx, sy, s, f.obj_of[m])
                    elif out[q] < 0.0:
                        p, n0, v, _, _, _ = fetch(f, q)
                        out[q] = light_visibility(lin, views, tanh, near, radius,
                                                  (normals[m, 0], normals[m, 1], normals[m, 2]),
                                                  f.lp, p, n0, v)


@njit(cache=True, inline="always")
def _from_grid(prim, obj_of, out, sw, sh, x, y, s, o):
    """The visibility of sample (x, y) of object o, of level s, from the two or four
    samples of the grid of spacing 2 s around it (see visibility_pass), or -1 (to be
    looked up)."""
    x0 = x & ~(2 * s - 1)
    y0 = y & ~(2 * s - 1)
    fx = 0.5 if x & s else 0.0
    fy = 0.5 if y & s else 0.0
    lo = 2.0
    hi = -1.0
    acc = 0.0
    for k in range(4):
        if (k & 1 and fx == 0.0) or (k >> 1 and fy == 0.0):
            continue  # on an edge of the cell: its two ends only
        cx = x0 + 2 * s * (k & 1)
        cy = y0 + 2 * s * (k >> 1)
        if cx >= sw or cy >= sh:
            return -1.0
        mc = prim[cy * sw + cx]
        if mc < 0 or obj_of[mc] != o:
            return -1.0
        v = np.float64(out[cy * sw + cx])
        lo = min(lo, v)
        hi = max(hi, v)
        acc += ((fx if k & 1 else 1.0 - fx) * (fy if k >> 1 else 1.0 - fy)) * v
    if lo == hi and (lo == 0.0 or lo == 1.0):
        return lo
    if lo > 0.0 and hi < 1.0:
        return acc
    return -1.0


@njit(cache=True, inline="always")
def light_visibility(lin, views, tanh, near, radius, ng, lp, p, n0, v):
    """The light's visibility (0..1) at point p of a triangle whose unit normal facing the
    light is ng (`shadow_geometry`; interpolated normal n0, unit vector v to the eye) from
    the shadow map (lin, views, tanh, near: ShadowMap's arrays) of the light at lp of
    radius `radius`."""
    if dot(two_sided(n0, v), sub(lp, p)) <= 0.0:
        return 0.0  # the light is behind the surface
    n = lin.shape[1]
    for k in range(views.shape[0]):
        pv = _xform(views[k], p, 1.0)
        d = -pv[2]
        th = tanh[k]
        if d <= 0.0 or abs(pv[0]) > d * th or abs(pv[1]) > d * th:
            continue  # outside this view (and so lit by it: no caster there)
        u = pv[0] / (d * th)
        w = pv[1] / (d * th)
        x = (u + 1.0) * 0.5 * n - 0.5
        y = (1.0 - w) * 0.5 * n - 0.5
        nv = _xform(views[k], ng, 0.0)
        tw = 2.0 * d * th / n  # a texel's width at the receiver
        c = dot(nv, pv) + OFFSET_TEXELS * tw
        return _pcss(lin, k, x, y, n, th, nv, c, d, near[k], radius, tw)
    return 1.0


@njit(cache=True, inline="always")
def _pcss(lin, k, x, y, n, th, nv, c, d, near, radius, tw):
    """Percentage-closer soft shadows at texel position (x, y) of view k."""
    # the light's disc seen from the receiver covers, at the nearest caster depth, this
    # many texels of the map (radius of the region)
    rs = radius * (d - near) / (d * near) / (2.0 * th / n)
    rf = 0.0  # the penumbra's half width, in texels
    if rs >= 1.0:
        rs = min(rs, n / 8.0)
        found = 0
        zb = 0.0
        for q in range(SEARCH_TAPS * SEARCH_TAPS):
            ox = (2.0 * (q % SEARCH_TAPS) / (SEARCH_TAPS - 1) - 1.0) * rs
            oy = (2.0 * (q // SEARCH_TAPS) / (SEARCH_TAPS - 1) - 1.0) * rs
            z, hit = _tap(lin, k, int(math.floor(x + ox + 0.5)),
                          int(math.floor(y + oy + 0.5)), n, th, nv, c, d)
            if hit:
                found += 1
                zb = max(zb, z)
        if found == 0:
            return 1.0
        if found == SEARCH_TAPS * SEARCH_TAPS:
            return 0.0  # blockers all over the light's disc: the umbra
        rf = radius * (d - zb) / zb / tw
    # bilinear taps at the centres of taps x taps equal cells of the filter's square: the
    # box filter's linear ramp, not a staircase of taps x taps levels; under a texel, one
    # tap at (x, y) (a hard shadow with a smooth edge). One call site: _bilinear is
    # inlined once, not three times (the pass's compile)
    taps = 1 if rf < 1.0 else min(MAX_FILTER_TAPS, int(math.ceil(rf)) + 1)
    lit = 0.0
    for q in range(taps * taps):
        ox = ((2.0 * (q % taps) + 1.0) / taps - 1.0) * rf
        oy = ((2.0 * (q // taps) + 1.0) / taps - 1.0) * rf
        lit += _bilinear(lin, k, x + ox, y + oy, n, th, nv, c, d)
    return lit / (taps * taps)
