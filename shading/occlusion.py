"""Screen-space ambient occlusion (SSAO, Crytek 2007, normal-oriented hemisphere): how
much of the sky above a surface point the surfaces the camera sees hide, from the
visibility buffer the rasteriser already has.

On a grid of cells of `cell_step` pixels a side (each cell's top-left pixel, its first
sample; 4 up to 607 pixels on the frame's shorter side, 6 at 800, 8 at 1080), per cell:
TAPS points in the hemisphere of radius
`radius` (metres) about the two-sided normal, at lengths spread from 0.1 to 1 radius, the
pattern turned about the normal by one of 16 angles in a 4 x 4 tile of cells. Each point
is projected into the image; it is occluded when the surface drawn there is nearer the
camera than the point, by up to `radius` (a surface much nearer is another object in front,
not an occluder: its weight falls as radius / depth difference). The pixel's factor is 1
minus the occluded fraction; a 4 x 4 box filter over cells of similar depth then
averages the 16 turns of the pattern, so the result has no noise and no per-frame
flicker (the pattern is fixed: the same frame gives the same image); each output pixel
takes the factor of the neighbouring cell nearest its depth (no halo at silhouettes).
The taps are cast at every fourth cell of every fourth row first, then at the cells
between only where the cells around them are not all open (`occlusion_pass`): most of
an image is unoccluded, and most cells there cost a look at their neighbours.
Occlusion is a low-frequency term, and it scales only the ambient term (shaders/__init__.py:
`lit`): cells of 4 x 4 pixels cost a quarter of cells of 2 x 2 and change a pixel by at
most a few levels of 255, and cells of 6 instead of 4 at 800 x 800 by at most 5.
"""
from __future__ import annotations

import math

import numpy as np
from clothjit import STAGE, njit

from .lighting import cross, normalize, two_sided
from .shade import covered_span, fetch
from .visibility import view_distance

DEFAULT_RADIUS = 0.1  # metres (render params "ao_radius")
TAPS = 8
STEP = 4  # pixels per side of a cell of the grid, at least (cell_step)
PHASES = 2  # occlusion_pass: taps first at every 2 ** PHASES-th cell of every such row
CELLS = 135  # cells along the frame's shorter side, at most


def cell_step(width: int, height: int) -> int:
    """The cells' side in pixels for a width x height frame: about 1 / CELLS of its
    shorter side, at least STEP (800 pixels: 6, 1080: 8; the same cells on the scene
    whatever the size, as the occlusion's radius is)."""
    return max(STEP, round(min(width, height) / CELLS))


def _kernel(taps: int) -> np.ndarray:
    """Unit-hemisphere offsets (z up): a Fibonacci spiral of directions at least 10
    degrees above the horizon, lengths growing from 0.1 to 1 (denser near the point)."""
    k = np.arange(taps)
    z = 0.17 + 0.83 * (k + 0.5) / taps
    phi = k * math.pi * (3.0 - math.sqrt(5.0))
    r = np.sqrt(1.0 - z * z)
    scale = 0.1 + 0.9 * ((k + 1) / taps) ** 2
    return np.ascontiguousarray(np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)
                                * scale[:, None])


KERNEL = _kernel(TAPS)
TURNS = np.array([(math.cos(k * math.pi / 8.0), math.sin(k * math.pi / 8.0))
                  for k in range(16)])  # the 16 turns of the pattern


@njit(cache=True, inline="always")
def _open(raw, dist, hw, hh, i, j, h, dc, radius):
    """Whether the two or four cells of the grid of spacing 2 h around cell (i, j) (its
    row's, its column's or its diagonal's neighbours there) all lie on its surface (within
    radius of its depth dc) and are unoccluded: raw exactly 1, no tap of theirs hit
    anything."""
    i0 = i & ~(2 * h - 1)
    j0 = j & ~(2 * h - 1)
    i1 = i0 + 2 * h if i & h else i0
    j1 = j0 + 2 * h if j & h else j0
    if i1 >= hw or j1 >= hh:
        return False
    for c in (j0 * hw + i0, j0 * hw + i1, j1 * hw + i0, j1 * hw + i1):
        if raw[c] != 1.0 or abs(dist[c] - dc) > radius:
            return False
    return True


@njit(**STAGE, _nrt=False)
def occlusion_pass(f, g, step, vp, near, far, radius, kernel, turns, depth, first, last,
                   raw, dist):
    """On the grid of cells of `step` pixels (cell (i, j) = output pixel (i, j) times the
    step, its first sample): raw = 1 - occluded fraction, dist = view depth (inf:
    background), by phases first .. last (with several groups one a call, each after
    the one before for every group): 0, the cells whose column and row are multiples of
    2 ** PHASES; phase k, those of multiples of h = 2 ** (PHASES - k) not of 2 h, each
    unoccluded without taps where the cells of the grid of spacing 2 h around it are
    (`_open`; occlusion is smooth, an occluder shows over several cells: most of an image
    is open, and most cells cost a look at their neighbours, not 8 taps)."""
    sw = f.width * f.aa
    sh = f.height * f.aa
    hw = (f.width + step - 1) // step
    hh = (f.height + step - 1) // step
    for phase in range(first, last + 1):
        h = 1 << (PHASES - phase)  # this phase's spacing (phase 0: every 2 ** PHASES-th)
        for j in range(g, hh, f.groups):
            if j & (h - 1):
                continue
            for i in range(0, hw, h):
                if phase > 0 and not (i | j) & h:
                    continue  # a cell of an earlier phase
                c = j * hw + i
                s = (step * j * f.aa) * sw + step * i * f.aa
                if f.prim[s] < 0:
                    raw[c] = 1.0
                    dist[c] = np.inf
                    continue
                dc = view_distance(depth[s], near, far)
                dist[c] = dc
                if phase > 0 and _open(raw, dist, hw, hh, i, j, h, dc, radius):
                    raw[c] = 1.0
                    continue
                p, n0, v, _, _, _ = fetch(f, s)
                n = two_sided(n0, v)
                a = (1.0, 0.0, 0.0) if abs(n[0]) < 0.9 else (0.0, 1.0, 0.0)
                t = normalize(cross(n, a))
                b = cross(n, t)
                turn = ((i & 3) << 2) | (j & 3)
                ca = turns[turn, 0]
                sa = turns[turn, 1]
                t, b = ((ca * t[0] + sa * b[0], ca * t[1] + sa * b[1], ca * t[2] + sa * b[2]),
                        (ca * b[0] - sa * t[0], ca * b[1] - sa * t[1], ca * b[2] - sa * t[2]))
                occ = 0.0
                for k in range(kernel.shape[0]):
                    o = (kernel[k, 0] * radius, kernel[k, 1] * radius, kernel[k, 2] * radius)
                    q = (p[0] + o[0] * t[0] + o[1] * b[0] + o[2] * n[0],
                         p[1] + o[0] * t[1] + o[1] * b[1] + o[2] * n[1],
                         p[2] + o[0] * t[2] + o[1] * b[2] + o[2] * n[2])
                    cw = vp[3, 0] * q[0] + vp[3, 1] * q[1] + vp[3, 2] * q[2] + vp[3, 3]
                    if cw <= near:
                        continue
                    iw = 1.0 / cw
                    qx = (vp[0, 0] * q[0] + vp[0, 1] * q[1] + vp[0, 2] * q[2] + vp[0, 3]) * iw
                    qy = (vp[1, 0] * q[0] + vp[1, 1] * q[1] + vp[1, 2] * q[2] + vp[1, 3]) * iw
                    px = int(math.floor((qx + 1.0) * 0.5 * sw))
                    py = int(math.floor((1.0 - qy) * 0.5 * sh))
                    if px < 0 or py < 0 or px >= sw or py >= sh:
                        continue
                    zb = depth[py * sw + px]
                    # window z grows with depth: a surface drawn behind the tap's point (or
                    # none) cannot hide it, and needs no conversion to a distance
                    qz = 0.5 * (vp[2, 0] * q[0] + vp[2, 1] * q[1] + vp[2, 2] * q[2]
                                + vp[2, 3]) * iw
                    if zb >= qz + 0.5:
                        continue
                    db = view_distance(zb, near, far)
                    if db < cw - 0.02 * radius:
                        gap = dc - db
                        occ += 1.0 if gap <= radius else radius / gap
                raw[c] = 1.0 - occ / kernel.shape[0]


@njit(**STAGE)
def blur_pass(f, g, step, radius, raw, dist, out):
    """out = the 4 x 4 box average of raw (the grid of cells) over cells whose depth is
    within radius of the centre's: the 16 turns of the tap pattern averaged."""
    hw = (f.width + step - 1) // step
    hh = (f.height + step - 1) // step
    for j in range(g, hh, f.groups):
        for i in range(hw):
            c = j * hw + i
            dc = dist[c]
            if dc == np.inf:
                out[c] = 1.0
                continue
            acc = 0.0
            cnt = 0
            for jj in range(max(j - 2, 0), min(j + 2, hh)):
                for ii in range(max(i - 2, 0), min(i + 2, hw)):
                    e = jj * hw + ii
                    if abs(dist[e] - dc) <= radius:
                        acc += raw[e]
                        cnt += 1
            out[c] = acc / cnt


@njit(**STAGE, no_cpython_wrapper=True, _nrt=False)
def _nearest_cells(prim, depth, dist, cells, out, o, row, aa, xa, xb, near, far, c00, c01,
                   c10, c11):
    """out[o + x] for x in [xa, xb): the factor of the cell (of four, in this order) whose
    depth is nearest that of the pixel's first sample (row + x aa): none carried across a
    silhouette (the background's: undefined, not written). A call, not inlined: a loop of
    its own is several times quicker than this inlined in the pixel loop."""
    for x in range(xa, xb):
        s = row + x * aa
        if prim[s] < 0:
            continue
        d = view_distance(depth[s], near, far)
        best = abs(dist[c00] - d)
        v = cells[c00]
        e = abs(dist[c01] - d)
        if e < best:
            best = e
            v = cells[c01]
        e = abs(dist[c10] - d)
        if e < best:
            best = e
            v = cells[c10]
        if abs(dist[c11] - d) < best:
            v = cells[c11]
        out[o + x] = v


@njit(**STAGE)
def upsample_pass(f, g, step, near, far, depth, dist, cells, out):
    """out[y * width + x] = the factor of output pixel (x, y), rows g, g + f.groups, ...,
    only over the row's span of covered samples (the background's is undefined, never
    read): of the 2 x 2 cells around it (the cell's first column pairs with the column
    before, its others with the one after; its first row likewise), their common factor
    (most of the image: a store per pixel, in a loop over the cell's pixels), or where they
    differ the factor of the cell whose depth is nearest the pixel's (`_nearest_cells`)."""
    hw = (f.width + step - 1) // step
    hh = (f.height + step - 1) // step
    aa = f.aa
    prim = f.prim
    for y in range(g, f.height, f.groups):
        xa, xb = covered_span(f, y)
        if xa == xb:
            continue
        j0 = y // step
        j1 = min(j0 + (1 if y % step else -1), hh - 1) if y > 0 else 0
        r0 = j0 * hw
        r1 = j1 * hw
        row = (y * aa) * (f.width * aa)
        o = y * f.width
        for i0 in range(xa // step, (xb - 1) // step + 1):
            xs = i0 * step
            xe = min(xb, xs + step)
            val = cells[r0 + i0]
            down = cells[r1 + i0] == val
            if xs >= xa:  # the cell's first column, with the column before
                i1 = i0 - 1 if xs > 0 else 0
                if down and cells[r0 + i1] == val and cells[r1 + i1] == val:
                    out[o + xs] = val
                else:
                    _nearest_cells(prim, depth, dist, cells, out, o, row, aa, xs, xs + 1,
                                   near, far, r0 + i0, r0 + i1, r1 + i0, r1 + i1)
            i1 = min(i0 + 1, hw - 1)
            x0 = max(xs + 1, xa)
            if down and cells[r0 + i1] == val and cells[r1 + i1] == val:
                for x in range(x0, xe):
                    out[o + x] = val
            else:
                _nearest_cells(prim, depth, dist, cells, out, o, row, aa, x0, xe, near, far,
                               r0 + i0, r0 + i1, r1 + i0, r1 + i1)
