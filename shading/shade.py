"""Deferred shading: one generic numba kernel over the visibility buffer.

For every output pixel and each of its aa x aa samples the kernel fetches the primitive
and barycentrics written by the rasteriser, interpolates position, normal, uv and
tangent (perspective-correct weights), normalises normal and tangent, computes v and
calls the shader's fragment function; samples are clamped to [0, 1], box filtered and
written as 8 bits (round to nearest). Background samples get the background colour.

The fragment is a numba function passed as an argument, so the kernel is specialised
(and inlined) per shader; numba cannot cache such specialisations on disk, so each
shader costs one compile (about a second) per process on first use.
"""
from __future__ import annotations

import math

from numba import njit

from .lighting import normalize


@njit(nogil=True)
def shade_rows(frag, y0, y1, ystep, W, aa, prim, bary, verts, P, N, UV, TG, obj_of, obj_kd,
               eye, lp, li, prm, tex, hmap, cube, bg, out):
    """Shade output rows y0, y0 + ystep, ... < y1 (the GIL is released: the renderer
    runs interleaved row sets on a thread pool)."""
    SW = W * aa
    inv = 1.0 / (aa * aa)
    for y in range(y0, y1, ystep):
        for x in range(W):
            r = 0.0
            g = 0.0
            b = 0.0
            for sy in range(aa):
                row = (y * aa + sy) * SW + x * aa
                for sx in range(aa):
                    s = row + sx
                    m = prim[s]
                    if m < 0:
                        cr, cg, cb = bg
                    else:
                        i0 = verts[m, 0]
                        i1 = verts[m, 1]
                        i2 = verts[m, 2]
                        b1 = bary[s, 0]
                        b2 = bary[s, 1]
                        b0 = 1.0 - b1 - b2
                        p = (b0 * P[i0, 0] + b1 * P[i1, 0] + b2 * P[i2, 0],
                             b0 * P[i0, 1] + b1 * P[i1, 1] + b2 * P[i2, 1],
                             b0 * P[i0, 2] + b1 * P[i1, 2] + b2 * P[i2, 2])
                        n0 = normalize((b0 * N[i0, 0] + b1 * N[i1, 0] + b2 * N[i2, 0],
                                        b0 * N[i0, 1] + b1 * N[i1, 1] + b2 * N[i2, 1],
                                        b0 * N[i0, 2] + b1 * N[i1, 2] + b2 * N[i2, 2]))
                        t = normalize((b0 * TG[i0, 0] + b1 * TG[i1, 0] + b2 * TG[i2, 0],
                                       b0 * TG[i0, 1] + b1 * TG[i1, 1] + b2 * TG[i2, 1],
                                       b0 * TG[i0, 2] + b1 * TG[i1, 2] + b2 * TG[i2, 2]))
                        uv = (b0 * UV[i0, 0] + b1 * UV[i1, 0] + b2 * UV[i2, 0],
                              b0 * UV[i0, 1] + b1 * UV[i1, 1] + b2 * UV[i2, 1])
                        v = normalize((eye[0] - p[0], eye[1] - p[1], eye[2] - p[2]))
                        o = obj_of[m]
                        kd = (obj_kd[o, 0], obj_kd[o, 1], obj_kd[o, 2])
                        cr, cg, cb = frag(p, n0, v, uv, t, kd, lp, li, prm, tex, hmap, cube)
                    r += min(max(cr, 0.0), 1.0)
                    g += min(max(cg, 0.0), 1.0)
                    b += min(max(cb, 0.0), 1.0)
            out[y, x, 0] = int(math.floor(r * inv * 255.0 + 0.5))
            out[y, x, 1] = int(math.floor(g * inv * 255.0 + 0.5))
            out[y, x, 2] = int(math.floor(b * inv * 255.0 + 0.5))
