"""The finite-element cloth model (seed 002): physics kernels over flat arrays.

Baraff and Witkin 1998 ("Large steps in cloth simulation", section 4) membrane energies on
the triangles of the classic model's grid, plus discrete-shells bending (Grinspun et al.
2003) on the interior edges, in physical units. Formulas, units and defaults: docs/fem.md.

Mesh. Points are the classic grid, row-major p = i * nw + j. Cell (i, j) (i < nh - 1,
j < nw - 1) with A = p, B = A + 1, C = A + nw, D = C + 1 holds the triangles (A, C, B) and
(B, C, D), as the renderer draws them. Rest (u, v) = (width j / (nw - 1), height i / (nh - 1)).

Energies (a: rest area; [w_u w_v] = [x1 - x0, x2 - x0] R^-1, R the rest edge matrix):

    stretch  E_s = a k_stretch / 2 ((|w_u| - 1)^2 + (|w_v| - 1)^2)
    shear    E_h = a k_shear / 2 (w_u . w_v)^2
    bending  E_b = k_bend |e|^2 / (2 (A1 + A2)) theta^2    per interior edge

with |e|, A1, A2 the rest edge length and rest areas of its two triangles and theta the
signed dihedral angle (atan2, smooth through 0). k_bend is the flexural rigidity D: a
cylindrical bend of curvature kappa along a grid direction costs D kappa^2 / 2 per unit
area (the discrete-shells energy 3 |e|^2 / (A1 + A2) theta^2 with stiffness D / 6).

Layout. Every element is anchored at a point (triangles and the diagonal and vertical edges
at A, the horizontal edge A-B at A) and each element kind keeps its per-anchor constants in
its own rows, so a pass over one kind is a loop over contiguous slices. The 18
(kind, local vertex) *slots* are: 0-2 triangle (A, C, B), 3-5 triangle (B, C, D), 6-9
diagonal edge B-C, 10-13 horizontal edge A-B, 14-17 vertical edge A-C; slot s belongs to the
point anchor + slot_offsets[s]. The element passes write per-element results to
`work[s, axis, pad + anchor]`; then each point sums its 18 slots in slot order, a fixed
per-point order (the grid's implicit CSR list): results are bit-for-bit the same for any
number of threads, with no atomic or racy scatter.

Speed. LLVM vectorises a loop only if it can check at run time that its arrays do not
overlap, and gives up beyond a handful of arrays. So every element computation is split into
small passes of at most 14 input and 6 output slices (positions -> deformation -> stress ->
per-vertex forces), with the intermediate rows in `scratch`. Only the exact bending Hessian
(`fem_jacobian_product`, a reference for tests and Newton solvers) is a scalar loop.

`work` and `scratch` belong to the FemParams: two kernels must not run on the same FemParams
at the same time.
"""
from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit, prange

from .forces import CHUNKS, _chunk


class FemParams(NamedTuple):
    nw: int
    nh: int
    width: float
    height: float
    k_stretch: float  # N/m, membrane stiffness (Young's modulus x thickness)
    k_shear: float  # N/m, in-plane shear stiffness
    k_bend: float  # N m, flexural rigidity D
    density: float  # kg/m^2
    x_rest: np.ndarray  # (3, N) the flat rest sheet (u, v, 0)
    tri_area: np.ndarray  # (2, N) rest area of triangle kind t anchored at p, 0 if none
    tri_inv: np.ndarray  # (2, 4, N) R^-1 entries (00, 01, 10, 11) of that triangle
    edge_factor: np.ndarray  # (3, N) |e|^2 / (2 (A1 + A2)) of edge kind k at p, 0 if none
    slot_offsets: np.ndarray  # (18,) int64, point of slot s = anchor + slot_offsets[s]
    pad: int  # anchor p is column p + pad of `work`
    work: np.ndarray  # (18, 3, N + 2 pad) per-slot results of the element passes
    scratch: np.ndarray  # (18, N) intermediate rows of the element passes


TRIANGLE_KINDS, EDGE_KINDS, SLOTS, SCRATCH_ROWS = 2, 3, 18, 18
FORCE, PRODUCT, FILTERED_PRODUCT, DIAGONAL = 0, 1, 2, 3  # what an element pass computes
# scratch rows: triangles w_u, w_v, dE/dw_u, dE/dw_v, dw_u, dw_v (3 each)
WU, WV, PU, PV, DWU, DWV = 0, 3, 6, 9, 12, 15
# hinges: N1 (3), t1, |e|, N2 (3), t2, theta, S1 (3), S2 (3), d theta (or ones)
N1, T1, LENGTH, N2, T2, THETA, S1, S2, DTHETA = 0, 3, 4, 5, 8, 9, 10, 13, 16

# cephes atan: rational approximation on |z| <= 0.66, ~1 ulp; branch-free so loops vectorise
_P = (-8.750608600031904122785e-1, -1.615753718733365076637e1, -7.500855792314704667340e1,
      -1.228866684490136173410e2, -6.485021904942025371773e1)
_Q = (2.485846490142306297962e1, 1.650270098316988542046e2, 4.328810604912902668951e2,
      4.853903996359136964868e2, 1.945506571482613964390e2)
_MOREBITS = 6.123233995736765886130e-17


def slot_offsets(nw: int) -> np.ndarray:
    """Point of each slot relative to its element's anchor (see the module docstring)."""
    return np.array([0, nw, 1,  # triangle (A, C, B)
                     1, nw, nw + 1,  # triangle (B, C, D)
                     nw, 1, 0, nw + 1,  # diagonal B-C: a = C, b = B, c = A, d = D
                     1, 0, nw, 1 - nw,  # horizontal A-B: a = B, b = A, c = C, d = (i-1, j+1)
                     0, nw, 1, nw - 1],  # vertical A-C: a = A, b = C, c = B, d = (i+1, j-1)
                    dtype=np.int64)


def build_fem(nw: int, nh: int, width: float, height: float, k_stretch: float,
              k_shear: float, k_bend: float, density: float) -> FemParams:
    """Rest geometry and per-element constants of the nw x nh FEM cloth."""
    if nw < 2 or nh < 2:
        raise ValueError(f"the FEM cloth needs at least 2 x 2 points, got {nw} x {nh}")
    n = nw * nh
    i, j = np.divmod(np.arange(n), nw)
    uv = np.stack([width * j / (nw - 1), height * i / (nh - 1)])
    offsets = slot_offsets(nw)
    cell = (i < nh - 1) & (j < nw - 1)
    tri_area = np.zeros((TRIANGLE_KINDS, n))
    tri_inv = np.zeros((TRIANGLE_KINDS, 4, n))
    for t in range(TRIANGLE_KINDS):
        p = np.nonzero(cell)[0]
        x0, x1, x2 = (uv[:, p + offsets[3 * t + k]] for k in range(3))
        r = np.stack([x1 - x0, x2 - x0], axis=-1).transpose(1, 0, 2)  # (P, 2 uv, 2 edges)
        tri_area[t, p] = 0.5 * np.abs(np.linalg.det(r))
        tri_inv[t, :, p] = np.linalg.inv(r).reshape(-1, 4)
    edge_exists = (cell,  # diagonal
                   (i > 0) & (i < nh - 1) & (j < nw - 1),  # horizontal
                   (i < nh - 1) & (j > 0) & (j < nw - 1))  # vertical
    edge_factor = np.zeros((EDGE_KINDS, n))
    for k in range(EDGE_KINDS):
        p = np.nonzero(edge_exists[k])[0]
        a, b, c, d = (uv[:, p + offsets[6 + 4 * k + m]] for m in range(4))
        e, ca, da = b - a, c - a, d - a
        area1 = 0.5 * np.abs(e[0] * ca[1] - e[1] * ca[0])
        area2 = 0.5 * np.abs(da[0] * e[1] - da[1] * e[0])
        edge_factor[k, p] = (e[0] ** 2 + e[1] ** 2) / (2.0 * (area1 + area2))
    pad = nw + 1
    return FemParams(
        nw=nw, nh=nh, width=float(width), height=float(height), k_stretch=float(k_stretch),
        k_shear=float(k_shear), k_bend=float(k_bend), density=float(density),
        x_rest=np.ascontiguousarray(np.vstack([uv, np.zeros(n)])),
        tri_area=tri_area, tri_inv=tri_inv, edge_factor=edge_factor, slot_offsets=offsets,
        pad=pad, work=np.zeros((SLOTS, 3, n + 2 * pad)), scratch=np.zeros((SCRATCH_ROWS, n)),
    )


def lumped_masses(params: FemParams) -> np.ndarray:
    """(N,) point masses: density times a third of the rest area of every adjacent triangle."""
    area = np.zeros(params.nw * params.nh)
    for t in range(TRIANGLE_KINDS):
        p = np.nonzero(params.tri_area[t])[0]
        for k in range(3):
            np.add.at(area, p + params.slot_offsets[3 * t + k], params.tri_area[t, p] / 3.0)
    return params.density * area


# --- 3-vectors as tuples (LLVM keeps them in registers) ---------------------------------------


@njit(cache=True, nogil=True, error_model="numpy")
def _sub(a, b):
    return (a[0] - b[0], a[1] - b[1], a[2] - b[2])


@njit(cache=True, nogil=True, error_model="numpy")
def _comb(a, s, b, t):
    """s a + t b."""
    return (s * a[0] + t * b[0], s * a[1] + t * b[1], s * a[2] + t * b[2])


@njit(cache=True, nogil=True, error_model="numpy")
def _scale(a, s):
    return (s * a[0], s * a[1], s * a[2])


@njit(cache=True, nogil=True, error_model="numpy")
def _dot(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


@njit(cache=True, nogil=True, error_model="numpy")
def _cross(a, b):
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


@njit(cache=True, nogil=True, error_model="numpy")
def _atan2(y, x):
    """atan2(y, x) without a library call or branch (cephes atan, within 2 ulp)."""
    ay, ax = abs(y), abs(x)
    num, den = min(ay, ax), max(ay, ax)
    big = num > 0.66 * den  # atan(t) = pi/4 + atan((t - 1) / (t + 1))
    z = (num - den if big else num) / ((num + den if big else den) if den > 0.0 else 1.0)
    zz = z * z
    p = (((_P[0] * zz + _P[1]) * zz + _P[2]) * zz + _P[3]) * zz + _P[4]
    q = ((((zz + _Q[0]) * zz + _Q[1]) * zz + _Q[2]) * zz + _Q[3]) * zz + _Q[4]
    r = z + z * (zz * p / q)
    r = r + (math.pi / 4 + 0.5 * _MOREBITS) if big else r
    r = (math.pi / 2 + _MOREBITS) - r if ay > ax else r
    r = (math.pi + 2.0 * _MOREBITS) - r if x < 0.0 else r
    return -r if y < 0.0 else r


# --- one element (membrane: w_u, w_v; hinge: edge a-b, triangles (a, b, c), (b, a, d)) -----


@njit(cache=True, nogil=True, error_model="numpy")
def _deformation(x0, x1, x2, i00, i01, i10, i11):
    """(w_u, w_v) of the triangle at positions x0, x1, x2."""
    e1, e2 = _sub(x1, x0), _sub(x2, x0)
    return _comb(e1, i00, e2, i10), _comb(e1, i01, e2, i11)


@njit(cache=True, nogil=True, error_model="numpy")
def _membrane_stress(wu, wv, ka, kb):
    """(dE/dw_u, dE/dw_v) with ka = a k_stretch, kb = a k_shear."""
    lu, lv = math.sqrt(_dot(wu, wu)), math.sqrt(_dot(wv, wv))
    su = ka * (1.0 - 1.0 / lu) if lu > 0.0 else 0.0
    sv = ka * (1.0 - 1.0 / lv) if lv > 0.0 else 0.0
    s = kb * _dot(wu, wv)
    return _comb(wu, su, wv, s), _comb(wv, sv, wu, s)


@njit(cache=True, nogil=True, error_model="numpy")
def _stretch_hessian(w, dw, ka, filtered):
    """ka (alpha I + (1 - alpha) u u^T) dw, u = w / |w|, alpha = 1 - 1 / |w| (clamped at 0 if
    filtered): the derivative of ka (|w| - 1) u along dw."""
    length = math.sqrt(_dot(w, w))
    inv = 1.0 / length if length > 0.0 else 0.0
    alpha = max(1.0 - inv, 0.0) if filtered else 1.0 - inv
    u = _scale(w, inv)
    return _comb(dw, ka * alpha, u, ka * (1.0 - alpha) * _dot(u, dw))


@njit(cache=True, nogil=True, error_model="numpy")
def _membrane_hessian(wu, wv, dwu, dwv, ka, kb, filtered):
    """Derivative of (dE/dw_u, dE/dw_v) along (dw_u, dw_v); filtered keeps its positive
    semi-definite part (compressed stretch loses its transverse term, shear its
    (w_u . w_v) (dw_v, dw_u) term: Gauss-Newton)."""
    s = 0.0 if filtered else kb * _dot(wu, wv)
    ds = kb * (_dot(dwu, wv) + _dot(wu, dwv))
    hu, hv = _stretch_hessian(wu, dwu, ka, filtered), _stretch_hessian(wv, dwv, ka, filtered)
    gu, gv = _comb(wv, ds, dwv, s), _comb(wu, ds, dwu, s)
    return ((hu[0] + gu[0], hu[1] + gu[1], hu[2] + gu[2]),
            (hv[0] + gv[0], hv[1] + gv[1], hv[2] + gv[2]))


@njit(cache=True, nogil=True, error_model="numpy")
def _membrane_diagonal(w, other, ka, kb):
    """One axis of the filtered Hessian's diagonal in w-space: d^2 E / dw^2 for w one of
    (w_u, w_v) and `other` the other one (ka (alpha + (1 - alpha) u_axis^2) + kb other_axis^2)
    as a function of the three components of w; returns the three diagonal entries."""
    length = math.sqrt(_dot(w, w))
    inv = 1.0 / length if length > 0.0 else 0.0
    alpha = max(1.0 - inv, 0.0)
    u = _scale(w, inv)
    return (ka * (alpha + (1.0 - alpha) * u[0] * u[0]) + kb * other[0] * other[0],
            ka * (alpha + (1.0 - alpha) * u[1] * u[1]) + kb * other[1] * other[1],
            ka * (alpha + (1.0 - alpha) * u[2] * u[2]) + kb * other[2] * other[2])


@njit(cache=True, nogil=True, error_model="numpy")
def _normal_one(a, b, c):
    """Triangle 1 of a hinge: N1 = e x (c - a), t1 = (c - a) . e / |e|, |e| (e = b - a)."""
    e, ca = _sub(b, a), _sub(c, a)
    length = math.sqrt(_dot(e, e))
    il = 1.0 / length if length > 0.0 else 0.0
    return _cross(e, ca), _dot(ca, e) * il, length


@njit(cache=True, nogil=True, error_model="numpy")
def _normal_two(a, b, d, n1):
    """Triangle 2 of a hinge: N2 = (d - a) x e, t2 = (d - a) . e / |e|, and the dihedral angle
    theta = atan2(e^ . (N1 x N2), N1 . N2) = atan2(-|e| N1 . (d - a), N1 . N2)."""
    e, da = _sub(b, a), _sub(d, a)
    length = math.sqrt(_dot(e, e))
    il = 1.0 / length if length > 0.0 else 0.0
    n2 = _cross(da, e)
    return n2, _dot(da, e) * il, _atan2(-length * _dot(n1, da), _dot(n1, n2))


@njit(cache=True, nogil=True, error_model="numpy")
def _hinge(a, b, c, d):
    """Dihedral angle theta, validity (no zero-length edge or zero-area triangle) and what
    the Hessian needs; the inverses are 0 for an invalid hinge, so its gradient is 0."""
    n1, t1, length = _normal_one(a, b, c)
    n2, t2, theta = _normal_two(a, b, d, n1)
    n1sq, n2sq = _dot(n1, n1), _dot(n2, n2)
    ok = (n1sq > 0.0) & (n2sq > 0.0) & (length > 0.0)
    inv1 = 1.0 / n1sq if ok else 0.0
    inv2 = 1.0 / n2sq if ok else 0.0
    return theta, ok, length, n1, n2, inv1, inv2, t1, t2


@njit(cache=True, nogil=True, error_model="numpy")
def _hinge_gradient(length, q1, q2, t1, t2):
    """d theta / d(a, b, c, d), q_k = N_k / |N_k|^2."""
    return (_comb(q1, length - t1, q2, length - t2), _comb(q1, t1, q2, t2),
            _scale(q1, -length), _scale(q2, -length))


@njit(cache=True, nogil=True, error_model="numpy")
def _hinge_gradient_derivative(a, b, c, d, ya, yb, yc, yd, length, n1, n2, inv1, inv2, t1,
                               t2):
    """Derivative of d theta / d(a, b, c, d) along the displacement (ya, yb, yc, yd)."""
    e, ca, da = _sub(b, a), _sub(c, a), _sub(d, a)
    de, dca, dda = _sub(yb, ya), _sub(yc, ya), _sub(yd, ya)
    il = 1.0 / length if length > 0.0 else 0.0
    unit = _scale(e, il)
    dl = _dot(unit, de)
    dunit = _scale(_comb(de, 1.0, unit, -dl), il)
    q1, q2 = _scale(n1, inv1), _scale(n2, inv2)
    dn1 = _comb(_cross(de, ca), 1.0, _cross(e, dca), 1.0)
    dn2 = _comb(_cross(dda, e), 1.0, _cross(da, de), 1.0)
    dq1 = _scale(_comb(dn1, 1.0, q1, -2.0 * _dot(n1, dn1)), inv1)  # d (N / |N|^2)
    dq2 = _scale(_comb(dn2, 1.0, q2, -2.0 * _dot(n2, dn2)), inv2)
    dt1 = _dot(dca, unit) + _dot(ca, dunit)
    dt2 = _dot(dda, unit) + _dot(da, dunit)
    ga = _comb(_comb(q1, dl - dt1, q2, dl - dt2), 1.0, _comb(dq1, length - t1, dq2, length - t2),
               1.0)
    gb = _comb(_comb(q1, dt1, q2, dt2), 1.0, _comb(dq1, t1, dq2, t2), 1.0)
    gc = _comb(q1, -dl, dq1, -length)
    gd = _comb(q2, -dl, dq2, -length)
    return ga, gb, gc, gd


# --- vectorised passes: each a loop over the slices of one element kind -----------------------
# Arguments are tuples of slices, unpacked before the loop (an array taken from a tuple
# inside a loop costs a reference count per iteration and stops vectorisation).


@njit(cache=True, nogil=True)
def _rows(x, start, stop):
    return x[0, start:stop], x[1, start:stop], x[2, start:stop]


@njit(cache=True, nogil=True, error_model="numpy")
def _deform_pass(xa, xb, xc, inv, wu, wv):
    """(w_u, w_v) per triangle from its vertex rows and R^-1 rows."""
    a0, a1, a2 = xa
    b0, b1, b2 = xb
    c0, c1, c2 = xc
    i00, i01, i10, i11 = inv
    u0, u1, u2 = wu
    v0, v1, v2 = wv
    for i in range(a0.size):
        u, v = _deformation((a0[i], a1[i], a2[i]), (b0[i], b1[i], b2[i]), (c0[i], c1[i], c2[i]),
                            i00[i], i01[i], i10[i], i11[i])
        u0[i], u1[i], u2[i] = u
        v0[i], v1[i], v2[i] = v


@njit(cache=True, nogil=True, error_model="numpy")
def _stress_pass(wu, wv, area, ks, kh, pu, pv):
    """(dE/dw_u, dE/dw_v) per triangle."""
    u0, u1, u2 = wu
    v0, v1, v2 = wv
    p0, p1, p2 = pu
    q0, q1, q2 = pv
    for i in range(u0.size):
        gu, gv = _membrane_stress((u0[i], u1[i], u2[i]), (v0[i], v1[i], v2[i]), area[i] * ks,
                                  area[i] * kh)
        p0[i], p1[i], p2[i] = gu
        q0[i], q1[i], q2[i] = gv


@njit(cache=True, nogil=True, error_model="numpy")
def _hessian_pass(wu, wv, dwu, dwv, area, ks, kh, filtered, pu, pv):
    """Derivative of (dE/dw_u, dE/dw_v) along (dw_u, dw_v) per triangle."""
    u0, u1, u2 = wu
    v0, v1, v2 = wv
    du0, du1, du2 = dwu
    dv0, dv1, dv2 = dwv
    p0, p1, p2 = pu
    q0, q1, q2 = pv
    for i in range(u0.size):
        gu, gv = _membrane_hessian((u0[i], u1[i], u2[i]), (v0[i], v1[i], v2[i]),
                                   (du0[i], du1[i], du2[i]), (dv0[i], dv1[i], dv2[i]),
                                   area[i] * ks, area[i] * kh, filtered)
        p0[i], p1[i], p2[i] = gu
        q0[i], q1[i], q2[i] = gv


@njit(cache=True, nogil=True, error_model="numpy")
def _spread_pass(pu, pv, inv, sa, sb, out):
    """out = -(pu cu + pv cv) with cu = sa R^-1_00 + sb R^-1_10, cv = sa R^-1_01 + sb R^-1_11:
    minus the gradient at one vertex ((sa, sb) = (-1, -1), (1, 0), (0, 1) for x0, x1, x2)."""
    p0, p1, p2 = pu
    q0, q1, q2 = pv
    i00, i01, i10, i11 = inv
    o0, o1, o2 = out
    for i in range(p0.size):
        cu = sa * i00[i] + sb * i10[i]
        cv = sa * i01[i] + sb * i11[i]
        o0[i] = -(p0[i] * cu + q0[i] * cv)
        o1[i] = -(p1[i] * cu + q1[i] * cv)
        o2[i] = -(p2[i] * cu + q2[i] * cv)


@njit(cache=True, nogil=True, error_model="numpy")
def _membrane_diagonal_pass(wu, wv, area, ks, kh, inv, sa, sb, out):
    """Diagonal of the filtered membrane Hessian block of one vertex (as _spread_pass):
    cu^2 H_uu + 2 cu cv H_uv + cv^2 H_vv per axis, H_uv = kh a w_u w_v^T (Gauss-Newton)."""
    u0, u1, u2 = wu
    v0, v1, v2 = wv
    i00, i01, i10, i11 = inv
    o0, o1, o2 = out
    for i in range(u0.size):
        ka, kb = area[i] * ks, area[i] * kh
        u, v = (u0[i], u1[i], u2[i]), (v0[i], v1[i], v2[i])
        huu, hvv = _membrane_diagonal(u, v, ka, kb), _membrane_diagonal(v, u, ka, kb)
        cu = sa * i00[i] + sb * i10[i]
        cv = sa * i01[i] + sb * i11[i]
        o0[i] = cu * cu * huu[0] + 2.0 * cu * cv * kb * u[0] * v[0] + cv * cv * hvv[0]
        o1[i] = cu * cu * huu[1] + 2.0 * cu * cv * kb * u[1] * v[1] + cv * cv * hvv[1]
        o2[i] = cu * cu * huu[2] + 2.0 * cu * cv * kb * u[2] * v[2] + cv * cv * hvv[2]


@njit(cache=True, nogil=True, error_model="numpy")
def _normal_one_pass(xa, xb, xc, n1, t1, length):
    a0, a1, a2 = xa
    b0, b1, b2 = xb
    c0, c1, c2 = xc
    m0, m1, m2 = n1
    for i in range(a0.size):
        n, t, el = _normal_one((a0[i], a1[i], a2[i]), (b0[i], b1[i], b2[i]),
                               (c0[i], c1[i], c2[i]))
        m0[i], m1[i], m2[i] = n
        t1[i] = t
        length[i] = el


@njit(cache=True, nogil=True, error_model="numpy")
def _normal_two_pass(xa, xb, xd, n1, n2, t2, theta):
    a0, a1, a2 = xa
    b0, b1, b2 = xb
    d0, d1, d2 = xd
    m0, m1, m2 = n1
    k0, k1, k2 = n2
    for i in range(a0.size):
        n, t, th = _normal_two((a0[i], a1[i], a2[i]), (b0[i], b1[i], b2[i]),
                               (d0[i], d1[i], d2[i]), (m0[i], m1[i], m2[i]))
        k0[i], k1[i], k2[i] = n
        t2[i] = t
        theta[i] = th


@njit(cache=True, nogil=True, error_model="numpy")
def _project_pass(n, length, t, ya, yb, yc, accumulate, out):
    """out (+)= q . ((|e| - t) ya + t yb - |e| yc), q = N / |N|^2: the part of
    d theta . y of one triangle of each hinge (yc: that triangle's opposite vertex)."""
    n0, n1, n2 = n
    a0, a1, a2 = ya
    b0, b1, b2 = yb
    c0, c1, c2 = yc
    for i in range(n0.size):
        nsq = n0[i] * n0[i] + n1[i] * n1[i] + n2[i] * n2[i]
        inv = 1.0 / nsq if nsq > 0.0 else 0.0
        el, tt = length[i], t[i]
        v = (n0[i] * ((el - tt) * a0[i] + tt * b0[i] - el * c0[i])
             + n1[i] * ((el - tt) * a1[i] + tt * b1[i] - el * c1[i])
             + n2[i] * ((el - tt) * a2[i] + tt * b2[i] - el * c2[i])) * inv
        out[i] = out[i] + v if accumulate else v


@njit(cache=True, nogil=True, error_model="numpy")
def _scale_pass(n1, n2, factor, r, coefficient, s1, s2):
    """S_k = coefficient factor r N_k / |N_k|^2 (0 for a zero normal)."""
    m0, m1, m2 = n1
    k0, k1, k2 = n2
    a0, a1, a2 = s1
    b0, b1, b2 = s2
    for i in range(m0.size):
        s = coefficient * factor[i] * r[i]
        sq1 = m0[i] * m0[i] + m1[i] * m1[i] + m2[i] * m2[i]
        sq2 = k0[i] * k0[i] + k1[i] * k1[i] + k2[i] * k2[i]
        c1 = s / sq1 if sq1 > 0.0 else 0.0
        c2 = s / sq2 if sq2 > 0.0 else 0.0
        a0[i], a1[i], a2[i] = m0[i] * c1, m1[i] * c1, m2[i] * c1
        b0[i], b1[i], b2[i] = k0[i] * c2, k1[i] * c2, k2[i] * c2


@njit(cache=True, nogil=True, error_model="numpy")
def _hinge_vertex_pass(s1, s2, length, t1, t2, e1, f1, e2, f2, square, factor, coefficient,
                       out):
    """One vertex of the hinges: v = (e1 |e| + f1 t1) S1 + (e2 |e| + f2 t2) S2, the vertex's
    d theta / dx times the scale ((e1, f1, e2, f2) = (1, -1, 1, -1), (0, 1, 0, 1), (-1, 0, 0, 0),
    (0, 0, -1, 0) for a, b, c, d); out = v, or coefficient factor v^2 per axis if square."""
    a0, a1, a2 = s1
    b0, b1, b2 = s2
    o0, o1, o2 = out
    for i in range(a0.size):
        c1 = e1 * length[i] + f1 * t1[i]
        c2 = e2 * length[i] + f2 * t2[i]
        v0 = c1 * a0[i] + c2 * b0[i]
        v1 = c1 * a1[i] + c2 * b1[i]
        v2 = c1 * a2[i] + c2 * b2[i]
        if square:
            k = coefficient * factor[i]
            v0, v1, v2 = k * v0 * v0, k * v1 * v1, k * v2 * v2
        o0[i], o1[i], o2[i] = v0, v1, v2


# --- the exact bending Hessian product (scalar reference) --------------------------------------


@njit(cache=True, nogil=True, error_model="numpy")
def _exact_hinges(x, y, params, k, lo, hi):
    """Slots of K y for the hinges of kind k anchored in [lo, hi): the exact bending Hessian
    2 k_bend f (g g^T + theta d g / dx), g = d theta / dx."""
    s0 = 6 + 4 * k
    o = params.slot_offsets[s0:s0 + 4]
    w, pad = params.work, params.pad
    for p in range(max(lo, -o.min()), min(hi, x.shape[1] - o.max())):
        v = [(x[0, p + o[m]], x[1, p + o[m]], x[2, p + o[m]]) for m in range(4)]
        dv = [(y[0, p + o[m]], y[1, p + o[m]], y[2, p + o[m]]) for m in range(4)]
        theta, ok, length, n1, n2, inv1, inv2, t1, t2 = _hinge(v[0], v[1], v[2], v[3])
        g = _hinge_gradient(length, _scale(n1, inv1), _scale(n2, inv2), t1, t2)
        h = _hinge_gradient_derivative(v[0], v[1], v[2], v[3], dv[0], dv[1], dv[2], dv[3],
                                       length, n1, n2, inv1, inv2, t1, t2)
        stiff = 2.0 * params.k_bend * params.edge_factor[k, p] if ok else 0.0
        s = -stiff * (_dot(g[0], dv[0]) + _dot(g[1], dv[1]) + _dot(g[2], dv[2])
                      + _dot(g[3], dv[3]))
        for m in range(4):
            r = _comb(g[m], s, h[m], -stiff * theta)
            for ax in range(3):
                w[s0 + m, ax, pad + p] = r[ax]


# --- one chunk of anchors ---------------------------------------------------------------------


@njit(cache=True, nogil=True)
def _triangle_chunk(x, y, params, t, mode, lo, hi):
    """Slots of the triangles of kind t anchored in [lo, hi): minus the gradient of E
    (FORCE), K y (PRODUCT), K_f y (FILTERED_PRODUCT) or the diagonal of -K_f (DIAGONAL)."""
    off = params.slot_offsets[3 * t:3 * t + 3]
    stop = min(hi, x.shape[1] - off.max())
    if stop <= lo:
        return
    sc, w, pad = params.scratch, params.work, params.pad
    inv = (params.tri_inv[t, 0, lo:stop], params.tri_inv[t, 1, lo:stop],
           params.tri_inv[t, 2, lo:stop], params.tri_inv[t, 3, lo:stop])
    area = params.tri_area[t, lo:stop]
    wu, wv = _rows(sc[WU:WU + 3], lo, stop), _rows(sc[WV:WV + 3], lo, stop)
    pu, pv = _rows(sc[PU:PU + 3], lo, stop), _rows(sc[PV:PV + 3], lo, stop)
    x0, x1, x2 = (_rows(x, lo + off[0], stop + off[0]), _rows(x, lo + off[1], stop + off[1]),
                  _rows(x, lo + off[2], stop + off[2]))
    out0, out1, out2 = (_rows(w[3 * t], pad + lo, pad + stop),
                        _rows(w[3 * t + 1], pad + lo, pad + stop),
                        _rows(w[3 * t + 2], pad + lo, pad + stop))
    ks, kh = params.k_stretch, params.k_shear
    _deform_pass(x0, x1, x2, inv, wu, wv)
    if mode == DIAGONAL:
        _membrane_diagonal_pass(wu, wv, area, ks, kh, inv, -1.0, -1.0, out0)
        _membrane_diagonal_pass(wu, wv, area, ks, kh, inv, 1.0, 0.0, out1)
        _membrane_diagonal_pass(wu, wv, area, ks, kh, inv, 0.0, 1.0, out2)
        return
    if mode == FORCE:
        _stress_pass(wu, wv, area, ks, kh, pu, pv)
    else:
        dwu, dwv = _rows(sc[DWU:DWU + 3], lo, stop), _rows(sc[DWV:DWV + 3], lo, stop)
        _deform_pass(_rows(y, lo + off[0], stop + off[0]), _rows(y, lo + off[1], stop + off[1]),
                     _rows(y, lo + off[2], stop + off[2]), inv, dwu, dwv)
        _hessian_pass(wu, wv, dwu, dwv, area, ks, kh, mode == FILTERED_PRODUCT, pu, pv)
    _spread_pass(pu, pv, inv, -1.0, -1.0, out0)
    _spread_pass(pu, pv, inv, 1.0, 0.0, out1)
    _spread_pass(pu, pv, inv, 0.0, 1.0, out2)


@njit(cache=True, nogil=True)
def _hinge_chunk(x, y, params, k, mode, lo, hi):
    """Slots of the hinges of kind k anchored in [lo, hi), as _triangle_chunk."""
    if mode == PRODUCT:
        _exact_hinges(x, y, params, k, lo, hi)
        return
    s0 = 6 + 4 * k
    off = params.slot_offsets[s0:s0 + 4]
    start, stop = max(lo, -off.min()), min(hi, x.shape[1] - off.max())
    if stop <= start:
        return
    sc, w, pad = params.scratch, params.work, params.pad
    n1, n2 = _rows(sc[N1:N1 + 3], start, stop), _rows(sc[N2:N2 + 3], start, stop)
    s1, s2 = _rows(sc[S1:S1 + 3], start, stop), _rows(sc[S2:S2 + 3], start, stop)
    t1, t2, length = sc[T1, start:stop], sc[T2, start:stop], sc[LENGTH, start:stop]
    theta, dtheta = sc[THETA, start:stop], sc[DTHETA, start:stop]
    factor = params.edge_factor[k, start:stop]
    xa, xb = _rows(x, start + off[0], stop + off[0]), _rows(x, start + off[1], stop + off[1])
    xc, xd = _rows(x, start + off[2], stop + off[2]), _rows(x, start + off[3], stop + off[3])
    _normal_one_pass(xa, xb, xc, n1, t1, length)
    _normal_two_pass(xa, xb, xd, n1, n2, t2, theta)
    kb = params.k_bend
    if mode == FORCE:
        _scale_pass(n1, n2, factor, theta, -2.0 * kb, s1, s2)  # -dE/dtheta q
    elif mode == FILTERED_PRODUCT:
        ya, yb = _rows(y, start + off[0], stop + off[0]), _rows(y, start + off[1], stop + off[1])
        yc, yd = _rows(y, start + off[2], stop + off[2]), _rows(y, start + off[3], stop + off[3])
        _project_pass(n1, length, t1, ya, yb, yc, False, dtheta)
        _project_pass(n2, length, t2, ya, yb, yd, True, dtheta)
        _scale_pass(n1, n2, factor, dtheta, -2.0 * kb, s1, s2)
    else:  # DIAGONAL: S_k = q_k, squared per vertex below
        for i in range(dtheta.size):
            dtheta[i] = 1.0
        _scale_pass(n1, n2, dtheta, dtheta, 1.0, s1, s2)
    square = mode == DIAGONAL
    for m, (e1, f1, e2, f2) in enumerate(((1.0, -1.0, 1.0, -1.0), (0.0, 1.0, 0.0, 1.0),
                                           (-1.0, 0.0, 0.0, 0.0), (0.0, 0.0, -1.0, 0.0))):
        _hinge_vertex_pass(s1, s2, length, t1, t2, e1, f1, e2, f2, square, factor, 2.0 * kb,
                           _rows(w[s0 + m], pad + start, pad + stop))


@njit(cache=True, nogil=True, parallel=True)
def _element_pass(x, y, params, mode):
    """Fill params.work for every element (hinges only if k_bend != 0)."""
    n = x.shape[1]
    for c in prange(CHUNKS):
        lo, hi = _chunk(c, n)
        for t in range(TRIANGLE_KINDS):
            _triangle_chunk(x, y, params, t, mode, lo, hi)
        if params.k_bend != 0.0:
            for k in range(EDGE_KINDS):
                _hinge_chunk(x, y, params, k, mode, lo, hi)


@njit(cache=True, nogil=True, parallel=True)
def _gather_pass(params, out, accumulate):
    """out[:, p] (+)= the slots of point p, in slot order (a fixed order: deterministic)."""
    n = out.shape[1]
    slots = SLOTS if params.k_bend != 0.0 else 3 * TRIANGLE_KINDS
    w, pad, off = params.work, params.pad, params.slot_offsets
    for c in prange(CHUNKS):
        lo, hi = _chunk(c, n)
        m = hi - lo
        for ax in range(3):
            o = out[ax, lo:hi]
            if not accumulate:
                for i in range(m):
                    o[i] = 0.0
            for s in range(slots):
                src = w[s, ax, pad + lo - off[s]:pad + hi - off[s]]
                for i in range(m):
                    o[i] += src[i]


# --- public kernels -------------------------------------------------------------------------


@njit(cache=True, nogil=True, error_model="numpy")
def fem_energy(x: np.ndarray, params: FemParams) -> float:
    """Elastic energy (J) of the cloth at positions x (3, N): stretch + shear + bending."""
    n = x.shape[1]
    energy = 0.0
    for t in range(TRIANGLE_KINDS):
        o = params.slot_offsets[3 * t:3 * t + 3]
        for p in range(n - o.max()):
            area = params.tri_area[t, p]
            if area == 0.0:
                continue
            inv = params.tri_inv[t, :, p]
            v = [(x[0, p + o[m]], x[1, p + o[m]], x[2, p + o[m]]) for m in range(3)]
            wu, wv = _deformation(v[0], v[1], v[2], inv[0], inv[1], inv[2], inv[3])
            lu, lv = math.sqrt(_dot(wu, wu)), math.sqrt(_dot(wv, wv))
            s = _dot(wu, wv)
            energy += 0.5 * area * (params.k_stretch * ((lu - 1.0) ** 2 + (lv - 1.0) ** 2)
                                    + params.k_shear * s * s)
    if params.k_bend == 0.0:
        return energy
    for k in range(EDGE_KINDS):
        o = params.slot_offsets[6 + 4 * k:10 + 4 * k]
        for p in range(max(0, -o.min()), n - o.max()):
            factor = params.edge_factor[k, p]
            if factor == 0.0:
                continue
            v = [(x[0, p + o[m]], x[1, p + o[m]], x[2, p + o[m]]) for m in range(4)]
            theta, ok = _hinge(v[0], v[1], v[2], v[3])[:2]
            if ok:
                energy += params.k_bend * factor * theta * theta
    return energy


@njit(cache=True, nogil=True)
def add_fem_forces(x: np.ndarray, params: FemParams, f: np.ndarray) -> None:
    """f += -dE/dx at positions x (3, N): the exact elastic forces."""
    _element_pass(x, x, params, FORCE)
    _gather_pass(params, f, True)


@njit(cache=True, nogil=True)
def fem_jacobian_product(x: np.ndarray, params: FemParams, y: np.ndarray,
                         out: np.ndarray) -> None:
    """out = K y, K = d f / d x = -(Hessian of E) at x (3N x 3N, symmetric; exact, so it may
    be indefinite away from rest), matrix-free."""
    _element_pass(x, y, params, PRODUCT)
    _gather_pass(params, out, False)


@njit(cache=True, nogil=True)
def fem_filtered_jacobian_product(x: np.ndarray, params: FemParams, y: np.ndarray,
                                  out: np.ndarray) -> None:
    """out = K_f y, K_f the negative semi-definite part of K that implicit Euler needs
    (M - h^2 K_f stays SPD): compressed stretch drops its transverse term (as
    forces.spring_jacobian), shear and bending keep their Gauss-Newton part (dC dC^T of
    C = w_u . w_v and C = theta). Equal to K at the rest state."""
    _element_pass(x, y, params, FILTERED_PRODUCT)
    _gather_pass(params, out, False)


@njit(cache=True, nogil=True)
def fem_jacobian_diagonal(x: np.ndarray, params: FemParams, out: np.ndarray) -> None:
    """out[a, p] = -(K_f)_{pa, pa} >= 0: the diagonal of the filtered -K per (axis, point),
    for a Jacobi preconditioner."""
    _element_pass(x, x, params, DIAGONAL)
    _gather_pass(params, out, False)


def estimate_omega_max(params: FemParams, masses: np.ndarray, iterations: int = 50) -> float:
    """Highest angular frequency (rad/s) of the free cloth at rest: sqrt of the largest
    eigenvalue of M^-1 (-K), by power iteration on the symmetric M^-1/2 (-K) M^-1/2 from a
    fixed pseudo-random start (a Rayleigh quotient: it converges from below).
    dt_max = 2 / omega_max for undamped Verlet."""
    x = params.x_rest
    scale = 1.0 / np.sqrt(np.asarray(masses, dtype=np.float64))
    z = np.random.default_rng(0).standard_normal(x.shape)
    z /= np.linalg.norm(z)
    out = np.empty_like(z)
    lam = 0.0
    for _ in range(iterations):
        fem_filtered_jacobian_product(x, params, z * scale, out)
        nz = -out * scale
        lam = float(np.vdot(z, nz))
        norm = np.linalg.norm(nz)
        if norm == 0.0:
            return 0.0
        z = nz / norm
    return math.sqrt(max(lam, 0.0))
