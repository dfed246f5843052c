"""Continuous collision detection between moving points, edges and triangles (Bridson,
Fedkiw and Anderson 2002, section 6; Provot 1997): every vertex moves on a straight line
from its start-of-step to its end-of-step position, t in [0, 1].

A point p and a triangle (a, b, c), or two edges (a, b) and (c, d), can only meet at a
time when their four points are coplanar: the roots in [0, 1] of the cubic
    f(t) = ((b - a) x (c - a)) . (p - a)     or     ((b - a) x (d - c)) . (c - a).
The cubic's critical points cut [0, 1] into monotone pieces; a piece whose ends differ in
sign (or touch zero) holds one root, found by bisection to ~1e-15. At each root the pair's
distance is measured; it collides if that is within `tolerance`. A motion coplanar all along
(f near zero everywhere against the motion's length cubed, e.g. parallel edges moving in
their plane) has no telling roots: its distance is measured at SAMPLES + 1 even times and
refined by golden-section search around the closest.

All functions are numba kernels on 3-tuples (values, no arrays), for the contact passes.
"""
from __future__ import annotations

import math

import numpy as np

from clothjit import njit

BISECTIONS = 60  # halvings of a piece: far below double precision's resolution of [0, 1]
SAMPLES = 32  # times at which a motion coplanar all along is measured
DEGENERATE = 1e-12  # a cubic below this times the motion's length cubed: coplanar all along


@njit(cache=True, nogil=True, error_model="numpy", forceinline=True)
def _sub(a, b):
    return (a[0] - b[0], a[1] - b[1], a[2] - b[2])


@njit(cache=True, nogil=True, error_model="numpy", forceinline=True)
def _add_scaled(a, s, b):
    return (a[0] + s * b[0], a[1] + s * b[1], a[2] + s * b[2])


@njit(cache=True, nogil=True, error_model="numpy", forceinline=True)
def _dot(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


@njit(cache=True, nogil=True, error_model="numpy", forceinline=True)
def _cross(a, b):
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


@njit(cache=True, nogil=True, error_model="numpy", forceinline=True)
def orient(a, b, c, d):
    """Six times the signed volume of the tetrahedron (a, b, c, d); swapping c and d
    negates it exactly (robust contact's and the mesh colliders' crossing tests)."""
    return _dot(_sub(b, a), _cross(_sub(c, a), _sub(d, a)))


@njit(cache=True, nogil=True, error_model="numpy")
def coplanarity_cubic(e1, d1, e2, d2, w, dw):
    """Coefficients (c0, c1, c2, c3) of f(t) = ((e1 + t d1) x (e2 + t d2)) . (w + t dw)."""
    n0 = _cross(e1, e2)
    n1 = _add_scaled(_cross(e1, d2), 1.0, _cross(d1, e2))
    n2 = _cross(d1, d2)
    return (_dot(n0, w), _dot(n0, dw) + _dot(n1, w), _dot(n1, dw) + _dot(n2, w), _dot(n2, dw))


@njit(cache=True, nogil=True, error_model="numpy", forceinline=True)
def _cubic(c, t):
    return ((c[3] * t + c[2]) * t + c[1]) * t + c[0]


@njit(cache=True, nogil=True, error_model="numpy")
def _bisect(c, lo, hi, flo):
    for _ in range(BISECTIONS):
        mid = 0.5 * (lo + hi)
        fm = _cubic(c, mid)
        if (fm <= 0.0) == (flo <= 0.0) and fm != 0.0:
            lo, flo = mid, fm
        else:
            hi = mid
    return hi


@njit(cache=True, nogil=True, error_model="numpy")
def cubic_roots(c, out):
    """The roots of the cubic c in [0, 1], ascending, into out (length >= 4); returns how
    many. A double root where the cubic touches zero without a sign change counts where its
    value is within 1e-14 of the cubic's scale."""
    scale = abs(c[0]) + abs(c[1]) + abs(c[2]) + abs(c[3])
    if scale == 0.0:
        return 0
    # the critical points, roots of 3 c3 t^2 + 2 c2 t + c1 clipped to [0, 1], cut it into
    # up to three monotone pieces [0, r1], [r1, r2], [r2, 1]
    r1, r2 = 0.0, 0.0
    qa, qb, qc = 3.0 * c[3], 2.0 * c[2], c[1]
    if qa != 0.0:
        disc = qb * qb - 4.0 * qa * qc
        if disc >= 0.0:
            sq = math.sqrt(disc)
            s1, s2 = (-qb - sq) / (2.0 * qa), (-qb + sq) / (2.0 * qa)
            r1, r2 = min(max(min(s1, s2), 0.0), 1.0), min(max(max(s1, s2), 0.0), 1.0)
    elif qb != 0.0:
        r1 = r2 = min(max(-qc / qb, 0.0), 1.0)
    count = 0
    tiny = 1e-14 * scale
    for i in range(3):
        lo = 0.0 if i == 0 else (r1 if i == 1 else r2)
        hi = r1 if i == 0 else (r2 if i == 1 else 1.0)
        if hi < lo or (hi == lo and i != 0):
            continue
        flo, fhi = _cubic(c, lo), _cubic(c, hi)
        if abs(flo) <= tiny:
            root = lo
        elif abs(fhi) <= tiny:
            root = hi
        elif (flo < 0.0) != (fhi < 0.0):
            root = _bisect(c, lo, hi, flo)
        else:
            continue
        if count == 0 or root > out[count - 1]:
            out[count] = root
            count += 1
    return count


@njit(cache=True, nogil=True, error_model="numpy")
def point_triangle_distance(p, a, b, c):
    """(distance, u, v, w): the distance from p to the triangle (a, b, c) and the
    barycentric weights of its closest point (Ericson, Real-Time Collision Detection 5.1.5)."""
    ab, ac, ap = _sub(b, a), _sub(c, a), _sub(p, a)
    d1, d2 = _dot(ab, ap), _dot(ac, ap)
    if d1 <= 0.0 and d2 <= 0.0:
        u, v, w = 1.0, 0.0, 0.0
    else:
        bp = _sub(p, b)
        d3, d4 = _dot(ab, bp), _dot(ac, bp)
        cp = _sub(p, c)
        d5, d6 = _dot(ab, cp), _dot(ac, cp)
        vc = d1 * d4 - d3 * d2
        vb = d5 * d2 - d1 * d6
        va = d3 * d6 - d5 * d4
        if d3 >= 0.0 and d4 <= d3:
            u, v, w = 0.0, 1.0, 0.0
        elif vc <= 0.0 and d1 >= 0.0 and d3 <= 0.0:
            s = d1 / (d1 - d3)
            u, v, w = 1.0 - s, s, 0.0
        elif d6 >= 0.0 and d5 <= d6:
            u, v, w = 0.0, 0.0, 1.0
        elif vb <= 0.0 and d2 >= 0.0 and d6 <= 0.0:
            s = d2 / (d2 - d6)
            u, v, w = 1.0 - s, 0.0, s
        elif va <= 0.0 and (d4 - d3) >= 0.0 and (d5 - d6) >= 0.0:
            s = (d4 - d3) / ((d4 - d3) + (d5 - d6))
            u, v, w = 0.0, 1.0 - s, s
        else:
            denom = 1.0 / (va + vb + vc)
            v = vb * denom
            w = vc * denom
            u = 1.0 - v - w
    q = (u * a[0] + v * b[0] + w * c[0], u * a[1] + v * b[1] + w * c[1],
         u * a[2] + v * b[2] + w * c[2])
    d = _sub(p, q)
    return math.sqrt(_dot(d, d)), u, v, w


@njit(cache=True, nogil=True, error_model="numpy")
def edge_edge_distance(a, b, c, d):
    """(distance, s, t): the distance between the segments a-b and c-d and the parameters of
    their closest points (a + s (b - a), c + t (d - c)) (Ericson 5.1.9)."""
    d1, d2, r = _sub(b, a), _sub(d, c), _sub(a, c)
    aa, ee, f = _dot(d1, d1), _dot(d2, d2), _dot(d2, r)
    if aa <= 1e-300 and ee <= 1e-300:
        s = t = 0.0
    elif aa <= 1e-300:
        s, t = 0.0, min(max(f / ee, 0.0), 1.0)
    else:
        cc = _dot(d1, r)
        if ee <= 1e-300:
            t, s = 0.0, min(max(-cc / aa, 0.0), 1.0)
        else:
            bb = _dot(d1, d2)
            denom = aa * ee - bb * bb
            s = min(max((bb * f - cc * ee) / denom, 0.0), 1.0) if denom > 0.0 else 0.0
            t = (bb * s + f) / ee
            if t < 0.0:
                t, s = 0.0, min(max(-cc / aa, 0.0), 1.0)
            elif t > 1.0:
                t, s = 1.0, min(max((bb - cc) / aa, 0.0), 1.0)
    p = _add_scaled(a, s, d1)
    q = _add_scaled(c, t, d2)
    g = _sub(p, q)
    return math.sqrt(_dot(g, g)), s, t


@njit(cache=True, nogil=True, error_model="numpy", forceinline=True)
def _at(x0, x1, t):
    return (x0[0] + t * (x1[0] - x0[0]), x0[1] + t * (x1[1] - x0[1]),
            x0[2] + t * (x1[2] - x0[2]))


@njit(cache=True, nogil=True, error_model="numpy")
def point_triangle_impact(p0, a0, b0, c0, p1, a1, b1, c1, tolerance, roots):
    """The first time in [0, 1] at which the moving point comes within `tolerance` of the
    moving triangle at a coplanar instant, or -1.0; `roots` scratch (4,)."""
    e1, e2, w = _sub(b0, a0), _sub(c0, a0), _sub(p0, a0)
    va = _sub(a1, a0)
    d1 = _sub(_sub(b1, b0), va)
    d2 = _sub(_sub(c1, c0), va)
    dw = _sub(_sub(p1, p0), va)
    c = coplanarity_cubic(e1, d1, e2, d2, w, dw)
    if _degenerate(c, e1, e2, w, d1, d2, dw):
        return _sampled(np.int64(0), p0, a0, b0, c0, p1, a1, b1, c1, tolerance)
    count = cubic_roots(c, roots)
    for i in range(count):
        t = roots[i]
        if point_triangle_distance(_at(p0, p1, t), _at(a0, a1, t), _at(b0, b1, t),
                                   _at(c0, c1, t))[0] <= tolerance:
            return t
    return -1.0


@njit(cache=True, nogil=True, error_model="numpy")
def edge_edge_impact(a0, b0, c0, d0, a1, b1, c1, d1, tolerance, roots):
    """The first time in [0, 1] at which the moving segments a-b and c-d come within
    `tolerance` at a coplanar instant, or -1.0; `roots` scratch (4,)."""
    e1, e2, w = _sub(b0, a0), _sub(d0, c0), _sub(c0, a0)
    va = _sub(a1, a0)
    vc = _sub(c1, c0)
    de1 = _sub(_sub(b1, b0), va)
    de2 = _sub(_sub(d1, d0), vc)
    dw = _sub(vc, va)
    c = coplanarity_cubic(e1, de1, e2, de2, w, dw)
    if _degenerate(c, e1, e2, w, de1, de2, dw):
        return _sampled(np.int64(1), a0, b0, c0, d0, a1, b1, c1, d1, tolerance)
    count = cubic_roots(c, roots)
    for i in range(count):
        t = roots[i]
        if edge_edge_distance(_at(a0, a1, t), _at(b0, b1, t), _at(c0, c1, t),
                              _at(d0, d1, t))[0] <= tolerance:
            return t
    return -1.0


@njit(cache=True, nogil=True, error_model="numpy")
def _degenerate(c, e1, e2, w, d1, d2, dw):
    """Whether the cubic c is zero to rounding against the motion's lengths."""
    length = 0.0
    for v in (e1, e2, w, d1, d2, dw):
        length = max(length, abs(v[0]) + abs(v[1]) + abs(v[2]))
    size = abs(c[0]) + abs(c[1]) + abs(c[2]) + abs(c[3])
    return size <= DEGENERATE * length * length * length


@njit(cache=True, nogil=True, error_model="numpy")
def _distance_at(kind, p0, q0, r0, s0, p1, q1, r1, s1, t):
    """The pair's distance at time t: kind 0 point p and triangle (q, r, s), kind 1 the
    edges p-q and r-s."""
    p, q, r, s = _at(p0, p1, t), _at(q0, q1, t), _at(r0, r1, t), _at(s0, s1, t)
    if kind == 0:
        return point_triangle_distance(p, q, r, s)[0]
    return edge_edge_distance(p, q, r, s)[0]


@njit(cache=True, nogil=True, error_model="numpy")
def _sampled(kind, p0, q0, r0, s0, p1, q1, r1, s1, tolerance):
    """The first sampled time within `tolerance`, else the golden-section minimum around
    the closest sample if within it, else -1.0 (for motions coplanar all along)."""
    best, best_t = math.inf, 0.0
    for i in range(SAMPLES + 1):
        t = i / SAMPLES
        d = _distance_at(kind, p0, q0, r0, s0, p1, q1, r1, s1, t)
        if d <= tolerance:
            return t
        if d < best:
            best, best_t = d, t
    lo, hi = max(best_t - 1.0 / SAMPLES, 0.0), min(best_t + 1.0 / SAMPLES, 1.0)
    g = 0.5 * (math.sqrt(5.0) - 1.0)
    for _ in range(BISECTIONS):
        m1, m2 = hi - g * (hi - lo), lo + g * (hi - lo)
        if (_distance_at(kind, p0, q0, r0, s0, p1, q1, r1, s1, m1)
                < _distance_at(kind, p0, q0, r0, s0, p1, q1, r1, s1, m2)):
            hi = m2
        else:
            lo = m1
    t = 0.5 * (lo + hi)
    return t if _distance_at(kind, p0, q0, r0, s0, p1, q1, r1, s1, t) <= tolerance else -1.0
