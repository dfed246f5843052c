"""Shadows from the point light: a shadow map drawn by this project's own rasteriser from
the light, looked up per sample with percentage-closer soft shadows (PCSS, Fernando 2005).

The map: one perspective view from the light fitted to the bounding sphere of the shadow
casters (every mesh but the planes, which receive shadows and cast none), or, when the
light is inside that sphere, a cube of six 90-degree views, `map_size` texels a side (the
penumbra is in world units: a map coarser than the image only blurs hard edges). Each
texel keeps the rasteriser's window z of the nearest caster (inf where none), compared
as it is (the receiver plane's depth is turned into window z, not each texel into a
distance), and tiles of TILE x TILE texels their least and greatest. Points outside every
view are lit: no caster lies between them and the light.

The lookup, per covered sample whose two-sided normal faces the light (a surface turned
away from the light is unlit, visibility 0):
- Depth bias: the receiver is the plane of its own triangle (the facet normal, not the
  smooth one), moved towards the light by OFFSET_TEXELS texel widths at its depth; each
  tap compares the caster's depth with that plane's depth along the tap's own ray. A flat
  lit surface therefore never shadows itself whatever its slope (no acne), and a fold's
  shadow starts within OFFSET_TEXELS texels of the fold (no gap).
- Soft shadows from a spherical light of radius a: a blocker search over the region of
  the map the light's disc covers as seen from the receiver (4 x 4 taps; decided by the
  tiles under it where every caster there lies behind the receiver plane, or every texel
  holds one in front of it: lit or umbra without a tap), the depth d_b
  of the farthest blocker found (the edge that casts the penumbra: the silhouette of a
  round blocker, not its nearer middle as PCSS's usual mean would take), the
  penumbra's full width at the receiver
  w = 2 a (d_r - d_b) / d_b, and a box filter of that width (up to 8 x 8 bilinear taps):
  the visibility ramps linearly across w, in world units, whatever the map's resolution.
  With a = 0 (or a penumbra under a texel) the four nearest texels are blended
  bilinearly: a hard shadow with a smooth edge.
- Where (visibility_pass): looked up at the corners of cells of 4 x 4 samples (8 x 8 from
  LARGE_FRAME samples on); a cell whose corners lie on one object, as all its samples
  do, and agree (or all lie in a penumbra) is filled with their blend, the others refined
  level by level, looking up only where neighbours disagree: about one sample in ten.
  Corners and neighbours on the background or past the image's edge are left out (the
  others must then agree exactly): silhouettes against the background and the image's
  last row and column of cells are not looked up sample by sample.
"""
from __future__ import annotations

import math

import numpy as np
from clothjit import STAGE, njit

from .camera import cross3, look_at, perspective
from .lighting import cross, dot, normalize, sub, two_sided
from .shade import fetch
from .visibility import VisibilityBuffer, run_groups

DEFAULT_RADIUS = 0.02  # metres, the light's default radius (render params "light_radius")
MAP_SIZE = 512  # texels per side of each view of the map, at least (`map_size`)
OFFSET_TEXELS = 1.5  # depth bias: receiver plane moved this many texel widths to the light
SEARCH_TAPS = 4  # blocker search: SEARCH_TAPS x SEARCH_TAPS taps
MAX_FILTER_TAPS = 8  # penumbra filter: at most MAX_FILTER_TAPS x MAX_FILTER_TAPS taps
LEVELS = 2  # looked up first at every 2 ** LEVELS-th sample of every 2 ** LEVELS-th row
LARGE_FRAME = 720  # one level more from this many samples on the shorter side (`levels`)
AGREE = 0.1  # samples of the grid differing by at most this much are blended, not refined
TILE = 8  # texels per side of the tiles of the map's least and greatest depth
# cube faces: the view axis (the direction a face looks along) and an up vector
_CUBE = (((1, 0, 0), (0, -1, 0)), ((-1, 0, 0), (0, -1, 0)), ((0, 1, 0), (0, 0, 1)),
         ((0, -1, 0), (0, 0, -1)), ((0, 0, 1), (0, -1, 0)), ((0, 0, -1), (0, -1, 0)))


def map_size(sw: int, sh: int) -> int:
    """The map's default side for a grid of sw x sh samples: 0.7 of its shorter side in
    steps of 128 texels, at least MAP_SIZE (800: 512, 1080: 768): about a texel per 1.5
    samples on the casters, so that hard edges stay smooth at any size (512 texels at
    1920 x 1080 leave steps of 4-6 pixels along them)."""
    return max(MAP_SIZE, 128 * round(0.7 * min(sw, sh) / 128))


def levels(sw: int, sh: int) -> int:
    """The look-ups' levels (visibility_pass) for a grid of sw x sh samples: cells of 8
    samples a side from LARGE_FRAME on, of 4 below. At 800 x 800 cells of 8 need a
    quarter of the corner look-ups of cells of 4 (the pass 2.5 -> 1.8 ms); in the
    benchmark's scenes they change the visibility by 0.0002 on average (blends across
    penumbrae: 3 % of the samples, by up to 0.4; 7 of 290 000 samples across 0.5)."""
    return LEVELS + 1 if min(sw, sh) >= LARGE_FRAME else LEVELS


def _view(eye, axis, up, tanh, near, far):
    """(view matrix, projection matrix) of an eye looking along axis with a square view of
    tan(fov / 2) = tanh (up replaced when it is along the axis): a Camera's, without
    building one (its checks cost 0.3 ms a frame)."""
    f = np.asarray(axis, float) / np.linalg.norm(axis)
    up = np.asarray(up, float)
    if np.linalg.norm(cross3(f, up)) < 1e-6:
        up = np.array((1.0, 0.0, 0.0) if abs(f[0]) < 0.9 else (0.0, 0.0, 1.0))
    e = np.array([float(x) for x in eye])
    return (look_at(e, np.array([float(x) for x in e + f]), up),
            perspective(math.degrees(2.0 * math.atan(tanh)), 1.0, near, far))


@njit(cache=True, nogil=True, error_model="numpy")
def _tiles(g, groups, depth, rowlo, rowhi, out):
    """Tile rows g, g + groups, ... of one view's map (window z, n x n): out[0] and out[1]
    = the least and the greatest depth of each tile of TILE x TILE texels (inf where no
    caster; the greatest is inf unless casters cover the whole tile). Only the spans
    [rowlo, rowhi] the rasteriser wrote are read: every other texel is empty."""
    n = depth.shape[0]
    nt = out.shape[1]
    for ty in range(g, nt, groups):
        for tx in range(nt):
            out[0, ty, tx] = np.inf
            out[1, ty, tx] = np.inf if (ty + 1) * TILE > n else -np.inf
        for y in range(ty * TILE, min(ty * TILE + TILE, n)):
            a = rowlo[y]
            b = rowhi[y]
            for tx in range(nt):  # a tile reaching past the row's span has empty texels
                if tx * TILE < a or tx * TILE + TILE - 1 > b:
                    out[1, ty, tx] = np.inf
            for x in range(a, b + 1):
                z = depth[y, x]
                tx = x // TILE
                if z < out[0, ty, tx]:
                    out[0, ty, tx] = z
                if z > out[1, ty, tx]:
                    out[1, ty, tx] = z


class ShadowMap:
    """The shadow map of one frame (rebuilt by `build`), `size` texels per side: per view
    the depth buffer of the casters (window z of the view's projection, whose near and far
    planes give `zab`), its tiles' least and greatest depth (`_tiles`), the view matrix,
    tan(fov / 2) and the nearest caster's distance along the view axis."""

    def __init__(self, size: int = MAP_SIZE):
        self.size = int(size)
        self.buffers: list[VisibilityBuffer] = []
        self.depth = np.empty((0, self.size, self.size))
        nt = (self.size + TILE - 1) // TILE
        self.tiles = np.empty((0, 2, nt, nt))
        self.views = np.empty((0, 3, 4))
        self.tanh = np.empty(0)
        self.closest = np.empty(0)
        self.zab = (1.0, 0.0)

    def build(self, va, nv, verts, runs, bounds, light, radius, groups):
        """Draw the casters (triangles verts, vertex ids into va[:nv] within the ranges
        `runs` ((k, 2) [start, end)); bounds: their vertices' bounds as `caster_bounds`
        gives them, None without casters) from the light at `light` (3 numbers) of radius
        `radius`."""
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
        if d > 1.02 * r:  # one view fitted to the casters' bounding sphere
            # widened by the penumbra beyond the casters' outline: seen from the light, it
            # reaches at most radius / (nearest caster distance) further (tan units)
            tanh = (math.tan(math.asin(r / d)) + radius / max(d - r, near)) * 1.02
            cams = [_view(L, c - L, (0.0, 1.0, 0.0), tanh, near, far)]
        else:  # the light among the casters: a cube of six views
            cams = [_view(L, a, u, 1.0, near, far) for a, u in _CUBE]
        views = [v for v, _ in cams]
        proj = cams[0][1]  # the same for every view
        self._views(views, proj)
        # window z = A - B / distance along the view axis (visibility.view_distance)
        self.zab = (far / (far - near), far * near / (far - near))
        for k, view in enumerate(views):
            buf = self.buffers[k]
            buf.draw(va, nv, verts, verts.shape[0], proj @ view, groups, depth_only=runs)
            run_groups(_tiles, groups, (self.depth[k], buf.rowlo, buf.rowhi, self.tiles[k]))
            # the blocker search reaches no nearer the light than the nearest caster
            z = self.tiles[k, 0].min()
            self.closest[k] = self.zab[1] / (self.zab[0] - z) if z < np.inf else np.inf

    def _views(self, views, proj=None):
        """The look-ups' arrays of these views (view matrices of Cameras, whose projection
        is proj): each view's 3x4 view matrix and tan(fov / 2) as proj has it; closest is
        set as each map is made."""
        k = len(views)
        if self.depth.shape[0] != k:
            self.depth = np.full((k, self.size, self.size), np.inf)
            self.tiles = np.empty((k,) + self.tiles.shape[1:])
            self.buffers = [VisibilityBuffer(self.size, self.size, self.depth[i].reshape(-1))
                            for i in range(k)]
        self.views = np.array([v[:3] for v in views]).reshape(k, 3, 4)
        self.tanh = np.full(k, 1.0 / proj[1, 1] if k else 1.0)
        self.closest = np.zeros(k)


@njit(cache=True, nogil=True, error_model="numpy")
def caster_bounds(va, runs, lp):
    """The casters' bounds: (centre of the bounding box, radius of the sphere about it,
    nearest and farthest distance to lp) of the vertices va[a:b, :3] of every run (a, b),
    the bits of numpy's reductions without their copies of the strided columns (3-4 ms at
    40k vertices)."""
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
def _tap(depth, k, i, j, n, rp):
    """Depth (window z) of the caster at texel (i, j) of view k, and whether it is nearer
    the light than the receiver plane along that texel's ray; rp = (e0, ex, ey, kc, c, A,
    zd) from `light_visibility`."""
    if i < 0 or j < 0 or i >= n or j >= n:
        return np.inf, False
    z = depth[k, j, i]
    return z, z < _plane_z(rp, i, j)


@njit(cache=True, inline="always")
def _plane_z(rp, i, j):
    """The window z of the receiver plane (nv . X = c, view space) along the ray of texel
    (i, j), (a_i, b_j, -1): a caster is nearer the light where its depth is less. The ray
    meets the plane at distance c / den, den = e0 + ex i + ey j < 0 (linear in i and j),
    whose window z is A + kc den (kc = B / -c; window z = A - B / distance, `zab`), with
    c < 0 (c >= 0: the plane lies behind the light, nothing is nearer: -inf); a ray that
    does not meet it (den >= 0) compares with the receiver's own depth zd."""
    e0, ex, ey, kc, c, A, zd = rp
    den = e0 + ex * i + ey * j
    if den < -1e-9:
        return A + kc * den if c < 0.0 else -np.inf
    return zd


@njit(cache=True, inline="always")
def _bilinear(depth, k, x, y, n, rp):
    """Visibility from the four texels around (x, y), weighted bilinearly."""
    i0 = int(math.floor(x))
    j0 = int(math.floor(y))
    fx = x - i0
    fy = y - j0
    vis = 0.0
    for q in range(4):
        i = i0 + (q & 1)
        j = j0 + (q >> 1)
        if not _tap(depth, k, i, j, n, rp)[1]:
            vis += (fx if q & 1 else 1.0 - fx) * (fy if q >> 1 else 1.0 - fy)
    return vis


@njit(cache=True, inline="always")
def light_visibility(f, m, depth, tiles, views, tanh, closest, zab, radius, p, n0, v):
    """The light's visibility (0..1) at point p of triangle m of frame f (interpolated
    normal n0, unit vector v to the eye) from the shadow map (depth, tiles, views, tanh,
    closest, zab: ShadowMap's) of the light at f.lp of radius `radius`."""
    lp = f.lp
    if dot(two_sided(n0, v), sub(lp, p)) <= 0.0:
        return 0.0  # the light is behind the surface
    n = depth.shape[1]
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
        nv = _xform(views[k], facet_normal(f, m, lp), 0.0)
        tw = 2.0 * d * th / n  # a texel's width at the receiver
        # the receiver plane nv . X = c (view space), and den of texel (i, j)'s ray
        # (a_i, b_j, -1): a_i = ((2 i + 1) / n - 1) th, b_j = (1 - (2 j + 1) / n) th
        c = dot(nv, pv) + OFFSET_TEXELS * tw
        e0 = (nv[0] - nv[1]) * th * (1.0 / n - 1.0) - nv[2]
        A, B = zab
        rp = (e0, 2.0 * nv[0] * th / n, -2.0 * nv[1] * th / n, B / -c if c < 0.0 else 0.0, c,
              A, A - B / d)
        return _pcss(depth, tiles, k, x, y, n, th, rp, d, closest[k], radius, tw, zab)
    return 1.0


# _tiles_decide, _pcss, _fill_cell and _from_grid are called, not inlined: the look-up
# pass compiles 0.5 s sooner; without reference counts, as a call per sample costs them
@njit(**STAGE, no_cpython_wrapper=True, _nrt=False)
def _tiles_decide(tiles, x, y, n, rs, rp):
    """1 (lit) or 0 (umbra) when the tiles under the blocker search's taps (within rs
    texels of (x, y)) decide it as the taps would: every caster there behind the receiver
    plane, or every texel covered by one in front of it; else -1 (tap)."""
    i0 = int(math.floor(x - rs + 0.5))
    i1 = int(math.floor(x + rs + 0.5))
    j0 = int(math.floor(y - rs + 0.5))
    j1 = int(math.floor(y + rs + 0.5))
    tx0 = max(i0, 0) // TILE
    tx1 = min(i1, n - 1) // TILE
    ty0 = max(j0, 0) // TILE
    ty1 = min(j1, n - 1) // TILE
    if tx0 > tx1 or ty0 > ty1 or (tx1 - tx0 + 1) * (ty1 - ty0 + 1) > 16:
        return -1.0
    # the plane's window z over the search square (`_plane_z`: den linear in i and j,
    # extreme at its corners; z rising with den): its least and greatest
    e0, ex, ey, kc, c, A, _ = rp
    den_hi = e0 + max(ex * i0, ex * i1) + max(ey * j0, ey * j1)
    if den_hi >= -1e-9:
        return -1.0  # a ray that misses the plane: another comparison
    if c >= 0.0:
        return 1.0  # the plane behind the light: nothing in front of it
    lo_z = A + kc * (e0 + min(ex * i0, ex * i1) + min(ey * j0, ey * j1))
    hi_z = A + kc * den_hi
    lo = np.inf
    hi = -np.inf
    for ty in range(ty0, ty1 + 1):
        for tx in range(tx0, tx1 + 1):
            lo = min(lo, tiles[0, ty, tx])
            hi = max(hi, tiles[1, ty, tx])
    if lo >= hi_z:
        return 1.0
    if hi < lo_z and i0 >= 0 and j0 >= 0 and i1 < n and j1 < n:
        return 0.0
    return -1.0


@njit(**STAGE, no_cpython_wrapper=True, _nrt=False)
def _pcss(depth, tiles, k, x, y, n, th, rp, d, near, radius, tw, zab):
    """Percentage-closer soft shadows at texel position (x, y) of view k."""
    # the light's disc seen from the receiver covers, at the nearest caster depth, this
    # many texels of the map (radius of the region)
    rs = radius * (d - near) / (d * near) / (2.0 * th / n)
    rf = 0.0  # the penumbra's half width, in texels
    if rs >= 1.0:
        rs = min(rs, n / 8.0)
        decided = _tiles_decide(tiles[k], x, y, n, rs, rp)
        if decided >= 0.0:
            return decided
        found = 0
        zb = 0.0
        for q in range(SEARCH_TAPS * SEARCH_TAPS):
            ox = (2.0 * (q % SEARCH_TAPS) / (SEARCH_TAPS - 1) - 1.0) * rs
            oy = (2.0 * (q // SEARCH_TAPS) / (SEARCH_TAPS - 1) - 1.0) * rs
            z, hit = _tap(depth, k, int(math.floor(x + ox + 0.5)),
                          int(math.floor(y + oy + 0.5)), n, rp)
            if hit:
                found += 1
                zb = max(zb, z)
        if found == 0:
            return 1.0
        if found == SEARCH_TAPS * SEARCH_TAPS:
            return 0.0  # blockers all over the light's disc: the umbra
        zb = zab[1] / (zab[0] - zb)  # its distance along the view axis
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
        lit += _bilinear(depth, k, x + ox, y + oy, n, rp)
    return lit / (taps * taps)


@njit(cache=True, inline="always")
def facet_normal(f, m, lp):
    """The unit normal of triangle m of frame f on the side of the light at lp (a
    triangle's plane does not pass through the light's side)."""
    a = f.va
    i0 = f.verts[m, 0]
    i1 = f.verts[m, 1]
    i2 = f.verts[m, 2]
    ng = cross((a[i1, 0] - a[i0, 0], a[i1, 1] - a[i0, 1], a[i1, 2] - a[i0, 2]),
               (a[i2, 0] - a[i0, 0], a[i2, 1] - a[i0, 1], a[i2, 2] - a[i0, 2]))
    if dot(ng, (lp[0] - a[i0, 0], lp[1] - a[i0, 1], lp[2] - a[i0, 2])) < 0.0:
        ng = (-ng[0], -ng[1], -ng[2])
    return normalize(ng)


@njit(**STAGE, no_cpython_wrapper=True, _nrt=False)
def _fill_cell(prim, obj_of, out, sw, sh, x0, y0, cell):
    """When the cell of cell x cell samples at sample (x0, y0) is uniform, fill its
    samples and return True: its corners (looked up) lie on one object, as every covered
    sample of the cell does, and their values blend (`_blends`): each sample takes their
    bilinear blend. Corners on the background or past the image's edge are left out, and
    the others must then agree exactly (silhouettes and the image's last cells, else
    looked up sample by sample). Else False, with some samples written that the
    refinement writes again."""
    o = -1
    lo = 2.0
    hi = -1.0
    missing = False
    for k in range(4):
        x = x0 + (cell if k & 1 else 0)
        y = y0 + (cell if k >> 1 else 0)
        mk = prim[y * sw + x] if x < sw and y < sh else -1
        if mk < 0:
            missing = True
            continue
        if o < 0:
            o = obj_of[mk]
        elif obj_of[mk] != o:
            return False
        vk = np.float64(out[y * sw + x])
        lo = min(lo, vk)
        hi = max(hi, vk)
    q = y0 * sw + x0
    if o < 0:  # no corner covered: done when no sample is (the background in a row's span)
        for dy in range(min(cell, sh - y0)):
            for dx in range(min(cell, sw - x0)):
                if prim[q + dy * sw + dx] >= 0:
                    return False
        return True
    if lo == hi:  # most cells: full light or full shadow
        for dy in range(min(cell, sh - y0)):
            for dx in range(min(cell, sw - x0)):
                mk = prim[q + dy * sw + dx]
                if mk >= 0:
                    if obj_of[mk] != o:
                        return False
                    out[q + dy * sw + dx] = lo
        return True
    if missing or not _blends(lo, hi):
        return False
    v00 = np.float64(out[q])
    v10 = np.float64(out[q + cell])
    v01 = np.float64(out[q + cell * sw])
    v11 = np.float64(out[q + cell * sw + cell])
    for dy in range(cell):
        fy = dy / cell
        for dx in range(cell):
            mk = prim[q + dy * sw + dx]
            if mk >= 0:
                if obj_of[mk] != o:
                    return False
                fx = dx / cell
                out[q + dy * sw + dx] = ((1.0 - fx) * (1.0 - fy) * v00 + fx * (1.0 - fy) * v10
                                         + (1.0 - fx) * fy * v01 + fx * fy * v11)
    return True


# no reference counting: the helpers would otherwise take and drop a reference to every
# array of the frame per sample (atomic operations: 3-10x the pass's time)
@njit(**STAGE, _nrt=False)
def visibility_pass(f, g, depth, tiles, views, tanh, closest, zab, radius, levels, first,
                    last, refine, out):
    """out[s] = the light's visibility of the covered samples of the rows of cells of
    2 ** levels samples a side of group g, by steps first, first - 1, ..., last (from
    `levels` down to 0; with several groups one step a call, each after the one before
    for every group). Step `levels`: each cell's corner (its top-left sample), looked up.
    The next: each cell that `_fill_cell` finds uniform is filled (most cells: a sample
    costs a few reads and a write), the others marked in `refine`, where the samples of
    each level l below (x and y multiples of s = 2 ** l, not both of 2 s) are each the
    middle of an edge or of a cell of the grid of spacing 2 s, taken from the two or four
    grid samples around it when they lie on its object and their values blend
    (`_blends`), else looked up (shadow edges, silhouettes). A shadow edge runs between
    corners that differ, so only a shadow narrower than a cell between agreeing ones can
    be missed."""
    sw = f.width * f.aa
    sh = f.height * f.aa
    cell = 1 << levels
    cw = (sw + cell - 1) // cell
    for step in range(first, last - 1, -1):
        for j in range(g, (sh + cell - 1) // cell, f.groups):
            y0 = j * cell
            lo = sw
            hi = -1
            for y in range(y0, min(y0 + cell, sh)):
                lo = min(lo, f.rowlo[y])
                hi = max(hi, f.rowhi[y])
            for i in range(lo // cell, hi // cell + 1):
                x0 = i * cell
                if step == levels - 1:
                    filled = _fill_cell(f.prim, f.obj_of, out, sw, sh, x0, y0, cell)
                    refine[j * cw + i] = not filled
                    if filled:
                        continue
                elif step < levels - 1 and not refine[j * cw + i]:
                    continue
                # the cell's samples of this level, each from the grid or looked up (one
                # place that looks up, inlined once)
                s = 1 << step
                for dy in range(0, cell, s):
                    for dx in range(0, cell, s):
                        x = x0 + dx
                        y = y0 + dy
                        if (step < levels and not (dx | dy) & s) or x >= sw or y >= sh:
                            continue  # a sample of a level above, or outside the image
                        q = y * sw + x
                        m = f.prim[q]
                        if m < 0:
                            continue  # not covered
                        val = -1.0 if step == levels else _from_grid(
                            f.prim, f.obj_of, out, sw, sh, x, y, s, f.obj_of[m])
                        if val < 0.0:
                            p, n0, v, _, _, _ = fetch(f, q)
                            val = light_visibility(f, m, depth, tiles, views, tanh,
                                                   closest, zab, radius, p, n0, v)
                        out[q] = val


@njit(**STAGE, no_cpython_wrapper=True, _nrt=False)
def _from_grid(prim, obj_of, out, sw, sh, x, y, s, o):
    """The visibility of sample (x, y) of object o, of level s, from the two or four
    samples of the grid of spacing 2 s around it (see visibility_pass; those on the
    background or past the image's edge left out, the others then agreeing exactly), or
    -1 (to be looked up)."""
    x0 = x & ~(2 * s - 1)
    y0 = y & ~(2 * s - 1)
    fx = 0.5 if x & s else 0.0
    fy = 0.5 if y & s else 0.0
    lo = 2.0
    hi = -1.0
    acc = 0.0
    missing = False
    for k in range(4):
        if (k & 1 and fx == 0.0) or (k >> 1 and fy == 0.0):
            continue  # on an edge of the cell: its two ends only
        cx = x0 + 2 * s * (k & 1)
        cy = y0 + 2 * s * (k >> 1)
        mc = prim[cy * sw + cx] if cx < sw and cy < sh else -1
        if mc < 0:  # on the background or past the image's edge: left out
            missing = True
            continue
        if obj_of[mc] != o:
            return -1.0
        v = np.float64(out[cy * sw + cx])
        lo = min(lo, v)
        hi = max(hi, v)
        acc += ((fx if k & 1 else 1.0 - fx) * (fy if k >> 1 else 1.0 - fy)) * v
    if missing:  # the others must agree exactly
        return lo if lo == hi else -1.0
    return acc if _blends(lo, hi) else -1.0


@njit(cache=True, inline="always")
def _blends(lo, hi):
    """Whether grid samples whose visibility lies in [lo, hi] give the samples between
    them their bilinear blend: when they agree (on full light or shadow, or within AGREE:
    the blend is then within AGREE / 2 of a ramp with a kink between them) or all lie
    inside a penumbra (the ramp is linear there)."""
    return hi - lo <= AGREE or (lo > 0.0 and hi < 1.0)
