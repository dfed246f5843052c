"""Shared numba helpers for fragment shaders: vector maths, two-sided normals,
Blinn-Phong (SPEC 5) and bump-mapped normals. 3-vectors are tuples (no allocation).
All are inlined into the shader kernels that use them."""
from __future__ import annotations

import math

from clothjit import STAGE, njit

from .textures import bilinear


@njit(cache=True, inline="always")
def dot(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


@njit(cache=True, inline="always")
def cross(a, b):
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


@njit(cache=True, inline="always")
def normalize(a):
    """a / |a| (one division: within an ulp of dividing each component); 0 stays 0."""
    n = math.sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2])
    if n > 0.0:
        r = 1.0 / n
        return (a[0] * r, a[1] * r, a[2] * r)
    return a


@njit(cache=True, inline="always")
def sub(a, b):
    return (a[0] - b[0], a[1] - b[1], a[2] - b[2])


@njit(cache=True, inline="always")
def scale(a, s):
    return (a[0] * s, a[1] * s, a[2] * s)


@njit(cache=True, inline="always")
def vec3(prm, i):
    """prm[i:i+3] as a tuple."""
    return (prm[i], prm[i + 1], prm[i + 2])


@njit(cache=True, inline="always")
def two_sided(n0, v):
    """SPEC 4: n = -n0 if n0.v < 0 else n0."""
    if dot(n0, v) < 0.0:
        return (-n0[0], -n0[1], -n0[2])
    return n0


@njit(cache=True, inline="always")
def powf(x, p):
    """x ** p; for integral 0 <= p <= 4096 (the usual Phong exponents) by repeated
    squaring, a few ulps from pow() and several times cheaper."""
    if p >= 0.0 and p <= 4096.0 and p == math.floor(p):
        n = int(p)
        r = 1.0
        b = x
        while n:
            if n & 1:
                r *= b
            b *= b
            n >>= 1
        return r
    return x ** p


@njit(cache=True, inline="always")
def light_terms(p, n, v, lp, li, vis):
    """(vis I / r^2 (rgb tuple), max(0, n.l), max(0, n.h)) for a point light at lp seen
    with visibility vis (1: unshadowed; exactly I / r^2 then)."""
    d = sub(lp, p)
    r2 = dot(d, d)
    inv = 1.0 / r2 if r2 > 0.0 else 0.0
    ir = math.sqrt(inv)
    l = (d[0] * ir, d[1] * ir, d[2] * ir)
    h = normalize((l[0] + v[0], l[1] + v[1], l[2] + v[2]))
    return ((li[0] * inv * vis, li[1] * inv * vis, li[2] * inv * vis), max(0.0, dot(n, l)),
            max(0.0, dot(n, h)))


@njit(**STAGE, no_cpython_wrapper=True)
def blinn_phong(p, n, v, kd, lp, li, ka, ia, ks, pexp, lit):
    """k_a I_a ao + (k_d I/r^2 max(0, n.l) + k_s I/r^2 max(0, n.h)^p) vis, where
    lit = (vis, ao): the light's visibility (shadows) and the ambient occlusion factor,
    both 1 without shadows and occlusion (the SPEC 5 colour, bit for bit)."""
    e, ndl, ndh = light_terms(p, n, v, lp, li, lit[0])
    spec = ks * powf(ndh, pexp)
    ao = lit[1]
    return (ka * ia[0] * ao + kd[0] * e[0] * ndl + spec * e[0],
            ka * ia[1] * ao + kd[1] * e[1] * ndl + spec * e[1],
            ka * ia[2] * ao + kd[2] * e[2] * ndl + spec * e[2])


@njit(**STAGE, no_cpython_wrapper=True)
def bump_normal(n0, t, v, uv, hmap, kh, kn):
    """SPEC 5 bump: TBN from the unflipped n0 and t, height = red channel of hmap,
    forward differences of one texel; the result gets the sign of the two-sided flip."""
    hh = hmap.shape[0]
    hw = hmap.shape[1]
    # the three samples in a loop: one call site, so numba inlines bilinear once, not
    # three times (most of bump's first compile); u + 0.0 samples exactly as u does
    h0 = hu = hv = 0.0
    for k in range(3):
        h = bilinear(hmap, uv[0] + (1.0 / hw if k == 1 else 0.0),
                     uv[1] + (1.0 / hh if k == 2 else 0.0), True)[0]
        if k == 0:
            h0 = h
        elif k == 1:
            hu = h
        else:
            hv = h
    du = (hu - h0) * kh * kn
    dv = (hv - h0) * kh * kn
    b = cross(n0, t)
    nd = normalize((-du * t[0] - dv * b[0] + n0[0],
                    -du * t[1] - dv * b[1] + n0[1],
                    -du * t[2] - dv * b[2] + n0[2]))
    if dot(n0, v) < 0.0:
        return (-nd[0], -nd[1], -nd[2])
    return nd
