"""Screen-space ambient occlusion (SSAO, Crytek 2007, normal-oriented hemisphere): how
much of the sky above a surface point the surfaces the camera sees hide, from the
visibility buffer the rasteriser already has.

Per output pixel (its first covered sample): TAPS points in the hemisphere of radius
`radius` (metres) about the two-sided normal, at lengths spread from 0.1 to 1 radius, the
pattern turned about the normal by one of 16 angles in a 4 x 4 tile of pixels. Each point
is projected into the image; it is occluded when the surface drawn there is nearer the
camera than the point, by up to `radius` (a surface much nearer is another object in front,
not an occluder: its weight falls as radius / depth difference). The pixel's factor is 1
minus the occluded fraction; a 4 x 4 box filter over pixels of similar depth then
averages the 16 turns of the pattern, so the result has no noise and no per-frame
flicker (the pattern is fixed: the same frame gives the same image). The factor scales
only the ambient term (shaders/__init__.py: `lit`).
"""
from __future__ import annotations

import math

import numpy as np
from clothjit import STAGE, njit

from .lighting import cross, normalize, two_sided
from .shade import fetch

DEFAULT_RADIUS = 0.1  # metres (render params "ao_radius")
TAPS = 8


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


@njit(cache=True, inline="always")
def _linear(z, near, far):
    """Window z -> distance along the camera's view axis."""
    return 2.0 * far * near / ((far + near) - (2.0 * z - 1.0) * (far - near))


@njit(**STAGE)
def occlusion_pass(f, g, vp, near, far, radius, kernel, depth, raw, dist):
    """raw[y * width + x] = 1 - occluded fraction, dist = view depth (inf: background)."""
    sw = f.width * f.aa
    sh = f.height * f.aa
    for y in range(g, f.height, f.groups):
        for x in range(f.width):
            i = y * f.width + x
            s = (y * f.aa) * sw + x * f.aa
            if f.prim[s] < 0:
                raw[i] = 1.0
                dist[i] = np.inf
                continue
            p, n0, v, _, _, _ = fetch(f, s)
            n = two_sided(n0, v)
            dc = _linear(depth[s], near, far)
            dist[i] = dc
            a = (1.0, 0.0, 0.0) if abs(n[0]) < 0.9 else (0.0, 1.0, 0.0)
            t = normalize(cross(n, a))
            b = cross(n, t)
            ang = (((x & 3) << 2) | (y & 3)) * (2.0 * math.pi / 16.0)
            ca = math.cos(ang)
            sa = math.sin(ang)
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
                qx = (vp[0, 0] * q[0] + vp[0, 1] * q[1] + vp[0, 2] * q[2] + vp[0, 3]) / cw
                qy = (vp[1, 0] * q[0] + vp[1, 1] * q[1] + vp[1, 2] * q[2] + vp[1, 3]) / cw
                px = int(math.floor((qx + 1.0) * 0.5 * sw))
                py = int(math.floor((1.0 - qy) * 0.5 * sh))
                if px < 0 or py < 0 or px >= sw or py >= sh:
                    continue
                zb = depth[py * sw + px]
                if zb == np.inf:
                    continue
                db = _linear(zb, near, far)
                if db < cw - 0.02 * radius:
                    gap = dc - db
                    occ += 1.0 if gap <= radius else radius / gap
            raw[i] = 1.0 - occ / kernel.shape[0]


@njit(**STAGE)
def blur_pass(f, g, radius, raw, dist, out):
    """out = the 4 x 4 box average of raw over pixels whose depth is within radius of the
    centre's (covered pixels only): the 16 turns of the tap pattern averaged."""
    for y in range(g, f.height, f.groups):
        for x in range(f.width):
            i = y * f.width + x
            dc = dist[i]
            if dc == np.inf:
                out[i] = 1.0
                continue
            acc = 0.0
            cnt = 0
            for yy in range(max(y - 2, 0), min(y + 2, f.height)):
                for xx in range(max(x - 2, 0), min(x + 2, f.width)):
                    j = yy * f.width + xx
                    if abs(dist[j] - dc) <= radius:
                        acc += raw[j]
                        cnt += 1
            out[i] = acc / cnt
