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
Occlusion is a low-frequency term, and it scales only the ambient term (shaders/__init__.py:
`lit`): cells of 4 x 4 pixels cost a quarter of cells of 2 x 2 and change a pixel by at
most a few levels of 255, and cells of 6 instead of 4 at 800 x 800 by at most 5.
"""
from __future__ import annotations

import math

import numpy as np
from clothjit import STAGE, njit

from .lighting import cross, normalize, two_sided
from .shade import fetch
from .visibility import view_distance

DEFAULT_RADIUS = 0.1  # metres (render params "ao_radius")
TAPS = 8
STEP = 4  # pixels per side of a cell of the grid, at least (cell_step)
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


@njit(**STAGE)
def occlusion_pass(f, g, step, vp, near, far, radius, kernel, turns, depth, raw, dist):
    """On the grid of cells of `step` pixels (cell (i, j) = output pixel (i, j) times the
    step, its first sample): raw = 1 - occluded fraction, dist = view depth (inf:
    background)."""
    sw = f.width * f.aa
    sh = f.height * f.aa
    hw = (f.width + step - 1) // step
    for j in range(g, (f.height + step - 1) // step, f.groups):
        for i in range(hw):
            c = j * hw + i
            s = (step * j * f.aa) * sw + step * i * f.aa
            if f.prim[s] < 0:
                raw[c] = 1.0
                dist[c] = np.inf
                continue
            p, n0, v, _, _, _ = fetch(f, s)
            n = two_sided(n0, v)
            dc = view_distance(depth[s], near, far)
            dist[c] = dc
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
                qz = 0.5 * (vp[2, 0] * q[0] + vp[2, 1] * q[1] + vp[2, 2] * q[2] + vp[2, 3]) * iw
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


@njit(**STAGE)
def upsample_pass(f, g, step, near, far, depth, dist, cells, out):
    """out[y * width + x] = the factor of output pixel (x, y) (on the background:
    undefined), rows g, g + f.groups, ...: of the 2 x 2 cells around it, their common
    factor (most of the image: a store per pixel), or where they differ the factor of the
    cell whose depth is nearest the pixel's (so that none is carried across a silhouette).
    By cells of a row: no division per pixel."""
    hw = (f.width + step - 1) // step
    hh = (f.height + step - 1) // step
    for y in range(g, f.height, f.groups):
        j0 = y // step
        j1 = min(j0 + (1 if y % step else -1), hh - 1) if y > 0 else 0
        row = (y * f.aa) * (f.width * f.aa)
        o = y * f.width
        for i0 in range(hw):
            xs = i0 * step
            xe = min(f.width, xs + step)
            val = cells[j0 * hw + i0]
            same = False
            i1 = 0
            for x in range(xs, xe):
                if x <= xs + 1:  # the cells around: the cell's own column pairs with the
                    # one before, the others with the one after
                    i1 = min(i0 + (1 if x > xs else -1), hw - 1) if x > 0 else 0
                    same = (cells[j0 * hw + i1] == val and cells[j1 * hw + i0] == val
                            and cells[j1 * hw + i1] == val)
                    if same and x > xs:  # so do the cell's pixels after this one
                        for xx in range(o + x, o + xe):
                            out[xx] = val
                        break
                if same:
                    out[o + x] = val
                    continue
                s = row + x * f.aa
                if f.prim[s] < 0:
                    continue
                d = view_distance(depth[s], near, far)
                best = np.inf
                v = val
                for q in range(4):
                    c = (j1 if q >> 1 else j0) * hw + (i1 if q & 1 else i0)
                    e = abs(dist[c] - d)
                    if e < best:
                        best = e
                        v = cells[c]
                out[o + x] = v
