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

Layout. The anchor A = i nw + j holds the elements of cell (i, j): its triangles and three
hinges (bending edges: the diagonal B-C, the horizontal A-B shared with the cell above, the
vertical A-C shared with the cell to the left). Each element kind keeps its constants in
per-anchor rows, so a pass over one kind is a loop over consecutive anchors. The elements of
an anchor touch the points A, B, C, D, E = (i-1, j+1) and F = (i+1, j-1), all within one row
of the anchor's row. Passes add each element's vertex forces straight into the output; to
do that without races, the cell rows are cut into bands of at least two rows, and the even
bands run in parallel, then the odd ones: two bands running together never touch the same
point. Every point sums its contributions in the same order whatever the number of threads,
so results are bit-for-bit reproducible (no atomics, no racy scatter).

Speed. LLVM vectorises a loop only if it can check at run time that its arrays do not
overlap, and gives up beyond a handful of rows. So every element computation is split into
passes of at most ~14 input and 6 output rows (positions -> deformation -> stress -> vertex
forces), with intermediate rows in `scratch`. Loops index with unsigned integers (no
wraparound test) and make no array views (each would cost atomic reference counts). Only the
exact bending Hessian (`fem_jacobian_product`, a reference for tests and Newton solvers) is a
scalar loop. `scratch` belongs to the FemParams: two kernels must not run on the same
FemParams at the same time.
"""
from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from clothjit import KernelPointer, njit, prange


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
    edge_factor: np.ndarray  # (3, N) |e|^2 / (2 (A1 + A2)) of hinge kind k at p, 0 if none
    offsets: np.ndarray  # (6,) int64, index of A, B, C, D, E, F minus the anchor's
    scratch: np.ndarray  # (18, N) intermediate rows of the passes
    # _triangles and _hinges for these params (build_fem); None in the params they are passed
    triangles: KernelPointer | None = None
    hinges: KernelPointer | None = None
    bands: KernelPointer | None = None  # _bands_of_parity (build_fem); None where passed


TRIANGLE_KINDS, HINGE_KINDS, SCRATCH_ROWS = 2, 3, 18
# the points (indices into offsets) of each element's vertices: triangles (A, C, B),
# (B, C, D); hinges (a, b, c, d) with edge a-b and triangles (a, b, c), (b, a, d): diagonal
# (C, B, A, D), horizontal (B, A, C, E), vertical (A, C, B, F)
TRIANGLE_VERTICES = np.array([[0, 2, 1], [1, 2, 3]], dtype=np.int64)
HINGE_VERTICES = np.array([[2, 1, 0, 3], [1, 0, 2, 4], [0, 2, 1, 5]], dtype=np.int64)
# d theta / dx at the hinge vertices a, b, c, d is (e1 |e| + f1 t1) q1 + (e2 |e| + f2 t2) q2
# with these (e1, f1, e2, f2) (see _hinge_gradient)
HINGE_GRADIENT = ((1.0, -1.0, 1.0, -1.0), (0.0, 1.0, 0.0, 1.0), (-1.0, 0.0, 0.0, 0.0),
                  (0.0, 0.0, -1.0, 0.0))
MAX_BANDS = 16
FORCE, PRODUCT, FILTERED_PRODUCT, DIAGONAL = 0, 1, 2, 3  # what the element pass computes
# scratch rows: triangles w_u, w_v, dE/dw_u, dE/dw_v, dw_u, dw_v (3 each)
WU, WV, PU, PV, DWU, DWV = 0, 3, 6, 9, 12, 15
# hinges: N1 (3), t1, |e|, 1 / |e|, N2 (3), t2, theta, S1 (3), S2 (3), d theta (or ones)
N1, T1, LENGTH, INV_LENGTH, N2, T2, THETA, S1, S2, DTHETA = 0, 3, 4, 5, 6, 9, 10, 11, 14, 17

# cephes atan: rational approximation on |z| <= 0.66, ~1 ulp; branch-free so loops vectorise
_P = (-8.750608600031904122785e-1, -1.615753718733365076637e1, -7.500855792314704667340e1,
      -1.228866684490136173410e2, -6.485021904942025371773e1)
_Q = (2.485846490142306297962e1, 1.650270098316988542046e2, 4.328810604912902668951e2,
      4.853903996359136964868e2, 1.945506571482613964390e2)
_MOREBITS = 6.123233995736765886130e-17


def point_offsets(nw: int) -> np.ndarray:
    """Index of A, B, C, D, E, F minus the index of the anchor A."""
    return np.array([0, 1, nw, nw + 1, 1 - nw, nw - 1], dtype=np.int64)


def build_fem(nw: int, nh: int, width: float, height: float, k_stretch: float,
              k_shear: float, k_bend: float, density: float) -> FemParams:
    """Rest geometry and per-element constants of the nw x nh FEM cloth."""
    if nw < 2 or nh < 2:
        raise ValueError(f"the FEM cloth needs at least 2 x 2 points, got {nw} x {nh}")
    n = nw * nh
    i, j = np.divmod(np.arange(n), nw)
    uv = np.stack([width * j / (nw - 1), height * i / (nh - 1)])
    offsets = point_offsets(nw)
    cell = (i < nh - 1) & (j < nw - 1)
    tri_area = np.zeros((TRIANGLE_KINDS, n))
    tri_inv = np.zeros((TRIANGLE_KINDS, 4, n))
    for t in range(TRIANGLE_KINDS):
        p = np.nonzero(cell)[0]
        x0, x1, x2 = (uv[:, p + offsets[TRIANGLE_VERTICES[t, m]]] for m in range(3))
        r = np.stack([x1 - x0, x2 - x0], axis=-1).transpose(1, 0, 2)  # (P, 2 uv, 2 edges)
        tri_area[t, p] = 0.5 * np.abs(np.linalg.det(r))
        tri_inv[t, :, p] = np.linalg.inv(r).reshape(-1, 4)
    edge_exists = (cell,  # diagonal
                   (i > 0) & (i < nh - 1) & (j < nw - 1),  # horizontal
                   (i < nh - 1) & (j > 0) & (j < nw - 1))  # vertical
    edge_factor = np.zeros((HINGE_KINDS, n))
    for k in range(HINGE_KINDS):
        p = np.nonzero(edge_exists[k])[0]
        a, b, c, d = (uv[:, p + offsets[HINGE_VERTICES[k, m]]] for m in range(4))
        e, ca, da = b - a, c - a, d - a
        area1 = 0.5 * np.abs(e[0] * ca[1] - e[1] * ca[0])
        area2 = 0.5 * np.abs(da[0] * e[1] - da[1] * e[0])
        edge_factor[k, p] = (e[0] ** 2 + e[1] ** 2) / (2.0 * (area1 + area2))
    params = FemParams(
        nw=nw, nh=nh, width=float(width), height=float(height), k_stretch=float(k_stretch),
        k_shear=float(k_shear), k_bend=float(k_bend), density=float(density),
        x_rest=np.ascontiguousarray(np.vstack([uv, np.zeros(n)])),
        tri_area=tri_area, tri_inv=tri_inv, edge_factor=edge_factor, offsets=offsets,
        scratch=np.zeros((SCRATCH_ROWS, n)),
    )
    return _with_passes(params, present=True)


def no_fem() -> FemParams:
    """The classic model's FemParams: no points, absent pointers, the types of a real one's,
    so that a classic System has the type of a FEM one (system.StepKernels)."""
    z2, z3 = np.zeros((2, 0)), np.zeros((2, 4, 0))
    params = FemParams(nw=0, nh=0, width=0.0, height=0.0, k_stretch=0.0, k_shear=0.0,
                       k_bend=0.0, density=0.0, x_rest=np.zeros((3, 0)), tri_area=z2,
                       tri_inv=z3, edge_factor=np.zeros((3, 0)),
                       offsets=np.zeros(6, dtype=np.int64), scratch=np.zeros((SCRATCH_ROWS, 0)))
    return _with_passes(params, present=False)


def _with_passes(params: FemParams, present: bool) -> FemParams:
    """`params` with the pointers to its element passes and to the parallel loop calling
    them (absent unless `present`)."""
    args = element_args(params)
    triangles = KernelPointer(_triangles, args, present=present)
    hinges = KernelPointer(_hinges, args, present=present)
    x, elements, i = args[0], args[2], np.int64(0)
    bands = KernelPointer(_bands_of_parity, (x, x, elements, triangles, hinges, i, i, i, x),
                          present=present)
    return params._replace(triangles=triangles, hinges=hinges, bands=bands)


def element_args(params: FemParams) -> tuple:
    """Arguments of the types _bands_of_parity passes to _triangles and _hinges (positions,
    direction and out are (3, N) float64 arrays; the params without their pointers; mode,
    lo, hi)."""
    x, i = params.x_rest, np.int64(0)
    return x, x, params._replace(triangles=None, hinges=None, bands=None), i, i, i, x


def lumped_masses(params: FemParams) -> np.ndarray:
    """(N,) point masses: density times a third of the rest area of every adjacent triangle."""
    area = np.zeros(params.nw * params.nh)
    for t in range(TRIANGLE_KINDS):
        p = np.nonzero(params.tri_area[t])[0]
        for k in range(3):
            np.add.at(area, p + params.offsets[TRIANGLE_VERTICES[t, k]],
                      params.tri_area[t, p] / 3.0)
    return params.density * area


# --- 3-vectors as tuples (LLVM keeps them in registers) ---------------------------------------


@njit(cache=True, nogil=True, error_model="numpy", forceinline=True, no_cpython_wrapper=True)
def _sub(a, b):
    return (a[0] - b[0], a[1] - b[1], a[2] - b[2])


@njit(cache=True, nogil=True, error_model="numpy", forceinline=True, no_cpython_wrapper=True)
def _comb(a, s, b, t):
    """s a + t b."""
    return (s * a[0] + t * b[0], s * a[1] + t * b[1], s * a[2] + t * b[2])


@njit(cache=True, nogil=True, error_model="numpy", forceinline=True, no_cpython_wrapper=True)
def _scale(a, s):
    return (s * a[0], s * a[1], s * a[2])


@njit(cache=True, nogil=True, error_model="numpy", forceinline=True, no_cpython_wrapper=True)
def _dot(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


@njit(cache=True, nogil=True, error_model="numpy", forceinline=True, no_cpython_wrapper=True)
def _cross(a, b):
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


@njit(cache=True, nogil=True, error_model="numpy", forceinline=True)
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


@njit(cache=True, nogil=True, error_model="numpy", forceinline=True, no_cpython_wrapper=True)
def _deformation(x0, x1, x2, i00, i01, i10, i11):
    """(w_u, w_v) of the triangle at positions x0, x1, x2."""
    e1, e2 = _sub(x1, x0), _sub(x2, x0)
    return _comb(e1, i00, e2, i10), _comb(e1, i01, e2, i11)


@njit(cache=True, nogil=True, error_model="numpy", forceinline=True, no_cpython_wrapper=True)
def _membrane_stress(wu, wv, ka, kb):
    """(dE/dw_u, dE/dw_v) with ka = a k_stretch, kb = a k_shear."""
    lu, lv = math.sqrt(_dot(wu, wu)), math.sqrt(_dot(wv, wv))
    su = ka * (1.0 - 1.0 / lu) if lu > 0.0 else 0.0
    sv = ka * (1.0 - 1.0 / lv) if lv > 0.0 else 0.0
    s = kb * _dot(wu, wv)
    return _comb(wu, su, wv, s), _comb(wv, sv, wu, s)


@njit(cache=True, nogil=True, error_model="numpy", forceinline=True, no_cpython_wrapper=True)
def _stretch_hessian(w, dw, ka, filtered):
    """ka (alpha I + (1 - alpha) u u^T) dw, u = w / |w|, alpha = 1 - 1 / |w| (clamped at 0 if
    filtered): the derivative of ka (|w| - 1) u along dw."""
    length = math.sqrt(_dot(w, w))
    inv = 1.0 / length if length > 0.0 else 0.0
    alpha = max(1.0 - inv, 0.0) if filtered else 1.0 - inv
    u = _scale(w, inv)
    return _comb(dw, ka * alpha, u, ka * (1.0 - alpha) * _dot(u, dw))


@njit(cache=True, nogil=True, error_model="numpy", forceinline=True, no_cpython_wrapper=True)
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


@njit(cache=True, nogil=True, error_model="numpy", forceinline=True, no_cpython_wrapper=True)
def _membrane_diagonal(w, other, ka, kb):
    """Diagonal of the filtered d^2 E / dw^2 (3 x 3) for w one of (w_u, w_v) and `other` the
    other: ka (alpha + (1 - alpha) u_axis^2) + kb other_axis^2, u = w / |w|, alpha =
    max(0, 1 - 1 / |w|)."""
    length = math.sqrt(_dot(w, w))
    inv = 1.0 / length if length > 0.0 else 0.0
    alpha = max(1.0 - inv, 0.0)
    u = _scale(w, inv)
    return (ka * (alpha + (1.0 - alpha) * u[0] * u[0]) + kb * other[0] * other[0],
            ka * (alpha + (1.0 - alpha) * u[1] * u[1]) + kb * other[1] * other[1],
            ka * (alpha + (1.0 - alpha) * u[2] * u[2]) + kb * other[2] * other[2])


@njit(cache=True, nogil=True, error_model="numpy", forceinline=True, no_cpython_wrapper=True)
def _normal_one(a, b, c):
    """Triangle 1 of a hinge: N1 = e x (c - a), t1 = (c - a) . e / |e|, |e|, 1 / |e| (0 for
    a zero edge); e = b - a."""
    e, ca = _sub(b, a), _sub(c, a)
    length = math.sqrt(_dot(e, e))
    il = 1.0 / length if length > 0.0 else 0.0
    return _cross(e, ca), _dot(ca, e) * il, length, il


@njit(cache=True, nogil=True, error_model="numpy", forceinline=True, no_cpython_wrapper=True)
def _normal_two(a, b, d, n1, length, il):
    """Triangle 2 of a hinge: N2 = (d - a) x e, t2 = (d - a) . e / |e|, and the dihedral angle
    theta = atan2(e^ . (N1 x N2), N1 . N2) = atan2(-|e| N1 . (d - a), N1 . N2)."""
    e, da = _sub(b, a), _sub(d, a)
    n2 = _cross(da, e)
    return n2, _dot(da, e) * il, _atan2(-length * _dot(n1, da), _dot(n1, n2))


@njit(cache=True, nogil=True, error_model="numpy", forceinline=True, no_cpython_wrapper=True)
def _hinge(a, b, c, d):
    """Dihedral angle theta, validity (no zero-length edge or zero-area triangle) and what
    the Hessian needs; the inverses are 0 for an invalid hinge, so its gradient is 0."""
    n1, t1, length, il = _normal_one(a, b, c)
    n2, t2, theta = _normal_two(a, b, d, n1, length, il)
    n1sq, n2sq = _dot(n1, n1), _dot(n2, n2)
    ok = (n1sq > 0.0) & (n2sq > 0.0) & (length > 0.0)
    inv1 = 1.0 / n1sq if ok else 0.0
    inv2 = 1.0 / n2sq if ok else 0.0
    return theta, ok, length, n1, n2, inv1, inv2, t1, t2


@njit(cache=True, nogil=True, error_model="numpy", forceinline=True, no_cpython_wrapper=True)
def _hinge_gradient(length, q1, q2, t1, t2):
    """d theta / d(a, b, c, d), q_k = N_k / |N_k|^2."""
    return (_comb(q1, length - t1, q2, length - t2), _comb(q1, t1, q2, t2),
            _scale(q1, -length), _scale(q2, -length))


@njit(cache=True, nogil=True, error_model="numpy", forceinline=True, no_cpython_wrapper=True)
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


# --- passes: one loop over the m elements of one kind anchored at s, s + 1, ..., s + m - 1 ----
# s, m and the vertex columns c (the vertex of the element anchored at s + i is column c + i)
# are uint64: numba then emits no wraparound test and LLVM vectorises. `out` is (3, N).


@njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True)
def _deform_pass(x, c0, c1, c2, params, t, s, m, row):
    """scratch[row:row + 6] = (w_u, w_v) of the triangles of kind t at positions x."""
    inv, sc = params.tri_inv, params.scratch
    for i in range(m):
        a = s + i
        u, v = _deformation((x[0, c0 + i], x[1, c0 + i], x[2, c0 + i]),
                            (x[0, c1 + i], x[1, c1 + i], x[2, c1 + i]),
                            (x[0, c2 + i], x[1, c2 + i], x[2, c2 + i]),
                            inv[t, 0, a], inv[t, 1, a], inv[t, 2, a], inv[t, 3, a])
        sc[row, a], sc[row + 1, a], sc[row + 2, a] = u
        sc[row + 3, a], sc[row + 4, a], sc[row + 5, a] = v


@njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True)
def _stress_pass(params, t, s, m):
    """(dE/dw_u, dE/dw_v) from (w_u, w_v)."""
    sc, area = params.scratch, params.tri_area
    ks, kh = params.k_stretch, params.k_shear
    for i in range(m):
        a = s + i
        gu, gv = _membrane_stress((sc[WU, a], sc[WU + 1, a], sc[WU + 2, a]),
                                  (sc[WV, a], sc[WV + 1, a], sc[WV + 2, a]),
                                  area[t, a] * ks, area[t, a] * kh)
        sc[PU, a], sc[PU + 1, a], sc[PU + 2, a] = gu
        sc[PV, a], sc[PV + 1, a], sc[PV + 2, a] = gv


@njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True)
def _hessian_pass(params, t, s, m, filtered):
    """The derivative of (dE/dw_u, dE/dw_v) along (dw_u, dw_v), in place of the stress."""
    sc, area = params.scratch, params.tri_area
    ks, kh = params.k_stretch, params.k_shear
    for i in range(m):
        a = s + i
        gu, gv = _membrane_hessian((sc[WU, a], sc[WU + 1, a], sc[WU + 2, a]),
                                   (sc[WV, a], sc[WV + 1, a], sc[WV + 2, a]),
                                   (sc[DWU, a], sc[DWU + 1, a], sc[DWU + 2, a]),
                                   (sc[DWV, a], sc[DWV + 1, a], sc[DWV + 2, a]),
                                   area[t, a] * ks, area[t, a] * kh, filtered)
        sc[PU, a], sc[PU + 1, a], sc[PU + 2, a] = gu
        sc[PV, a], sc[PV + 1, a], sc[PV + 2, a] = gv


@njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True)
def _spread_pass(params, t, s, m, sa, sb, out, c):
    """out[:, c + i] -= pu cu + pv cv with (pu, pv) the stress rows, cu = sa R^-1_00 +
    sb R^-1_10 and cv = sa R^-1_01 + sb R^-1_11: minus the gradient at one vertex
    ((sa, sb) = (-1, -1), (1, 0), (0, 1) for x0, x1, x2)."""
    sc, inv = params.scratch, params.tri_inv
    for i in range(m):
        a = s + i
        cu = sa * inv[t, 0, a] + sb * inv[t, 2, a]
        cv = sa * inv[t, 1, a] + sb * inv[t, 3, a]
        out[0, c + i] -= sc[PU, a] * cu + sc[PV, a] * cv
        out[1, c + i] -= sc[PU + 1, a] * cu + sc[PV + 1, a] * cv
        out[2, c + i] -= sc[PU + 2, a] * cu + sc[PV + 2, a] * cv


@njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True)
def _membrane_diagonal_pass(params, t, s, m, sa, sb, out, c):
    """out[:, c + i] += the diagonal of the filtered membrane Hessian block of one vertex (as
    _spread_pass): cu^2 H_uu + 2 cu cv H_uv + cv^2 H_vv, H_uv = a k_shear w_v w_u^T."""
    sc, inv, area = params.scratch, params.tri_inv, params.tri_area
    ks, kh = params.k_stretch, params.k_shear
    for i in range(m):
        a = s + i
        ka, kb = area[t, a] * ks, area[t, a] * kh
        u = (sc[WU, a], sc[WU + 1, a], sc[WU + 2, a])
        v = (sc[WV, a], sc[WV + 1, a], sc[WV + 2, a])
        huu, hvv = _membrane_diagonal(u, v, ka, kb), _membrane_diagonal(v, u, ka, kb)
        cu = sa * inv[t, 0, a] + sb * inv[t, 2, a]
        cv = sa * inv[t, 1, a] + sb * inv[t, 3, a]
        out[0, c + i] += cu * cu * huu[0] + 2.0 * cu * cv * kb * u[0] * v[0] + cv * cv * hvv[0]
        out[1, c + i] += cu * cu * huu[1] + 2.0 * cu * cv * kb * u[1] * v[1] + cv * cv * hvv[1]
        out[2, c + i] += cu * cu * huu[2] + 2.0 * cu * cv * kb * u[2] * v[2] + cv * cv * hvv[2]


@njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True)
def _normal_one_pass(x, ca, cb, cc, params, s, m):
    """N1, t1, |e| and 1 / |e| of the hinges with vertices a, b, c at x."""
    sc = params.scratch
    for i in range(m):
        a = s + i
        n, t, length, il = _normal_one((x[0, ca + i], x[1, ca + i], x[2, ca + i]),
                                       (x[0, cb + i], x[1, cb + i], x[2, cb + i]),
                                       (x[0, cc + i], x[1, cc + i], x[2, cc + i]))
        sc[N1, a], sc[N1 + 1, a], sc[N1 + 2, a] = n
        sc[T1, a], sc[LENGTH, a], sc[INV_LENGTH, a] = t, length, il


@njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True)
def _normal_two_pass(x, ca, cb, cd, params, s, m):
    """N2, t2 and theta of the hinges with vertices a, b, d at x (after _normal_one_pass)."""
    sc = params.scratch
    for i in range(m):
        a = s + i
        n, t, theta = _normal_two((x[0, ca + i], x[1, ca + i], x[2, ca + i]),
                                  (x[0, cb + i], x[1, cb + i], x[2, cb + i]),
                                  (x[0, cd + i], x[1, cd + i], x[2, cd + i]),
                                  (sc[N1, a], sc[N1 + 1, a], sc[N1 + 2, a]), sc[LENGTH, a],
                                  sc[INV_LENGTH, a])
        sc[N2, a], sc[N2 + 1, a], sc[N2 + 2, a] = n
        sc[T2, a], sc[THETA, a] = t, theta


@njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True)
def _project_pass(y, ca, cb, cc, params, normal, t, s, m, accumulate):
    """d theta (+)= q . ((|e| - t) ya + t yb - |e| yc), q = N / |N|^2 with N, t the rows
    `normal`, `t` of one triangle of each hinge and yc its opposite vertex."""
    sc = params.scratch
    for i in range(m):
        a = s + i
        nsq = sc[normal, a] ** 2 + sc[normal + 1, a] ** 2 + sc[normal + 2, a] ** 2
        inv = 1.0 / nsq if nsq > 0.0 else 0.0
        el, tt = sc[LENGTH, a], sc[t, a]
        v = (sc[normal, a] * ((el - tt) * y[0, ca + i] + tt * y[0, cb + i] - el * y[0, cc + i])
             + sc[normal + 1, a] * ((el - tt) * y[1, ca + i] + tt * y[1, cb + i]
                                    - el * y[1, cc + i])
             + sc[normal + 2, a] * ((el - tt) * y[2, ca + i] + tt * y[2, cb + i]
                                    - el * y[2, cc + i])) * inv
        sc[DTHETA, a] = sc[DTHETA, a] + v if accumulate else v


@njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True)
def _scale_pass(params, k, r, coefficient, s, m):
    """S_j = coefficient f r N_j / |N_j|^2 (j = 1, 2; r a scratch row; 0 for a zero normal)."""
    sc, factor = params.scratch, params.edge_factor
    for i in range(m):
        a = s + i
        sq1 = sc[N1, a] ** 2 + sc[N1 + 1, a] ** 2 + sc[N1 + 2, a] ** 2
        sq2 = sc[N2, a] ** 2 + sc[N2 + 1, a] ** 2 + sc[N2 + 2, a] ** 2
        product = sq1 * sq2
        scale = coefficient * factor[k, a] * sc[r, a] / product if product > 0.0 else 0.0
        c1, c2 = scale * sq2, scale * sq1
        sc[S1, a], sc[S1 + 1, a], sc[S1 + 2, a] = c1 * sc[N1, a], c1 * sc[N1 + 1, a], c1 * sc[
            N1 + 2, a]
        sc[S2, a], sc[S2 + 1, a], sc[S2 + 2, a] = c2 * sc[N2, a], c2 * sc[N2 + 1, a], c2 * sc[
            N2 + 2, a]


@njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True)
def _vertex_pass(params, k, s, m, gradient, square, out, c):
    """out[:, c + i] += v = (e1 |e| + f1 t1) S1 + (e2 |e| + f2 t2) S2 ((e1, f1, e2, f2) =
    `gradient`: one vertex's d theta / dx times the scale), or (2 k_bend / f) v^2 per axis if
    square (the scale then is f, so this is 2 k_bend f (d theta / dx)^2; 0 without hinge)."""
    sc, factor = params.scratch, params.edge_factor
    e1, f1, e2, f2 = gradient
    kb = 2.0 * params.k_bend
    for i in range(m):
        a = s + i
        c1 = e1 * sc[LENGTH, a] + f1 * sc[T1, a]
        c2 = e2 * sc[LENGTH, a] + f2 * sc[T2, a]
        v0 = c1 * sc[S1, a] + c2 * sc[S2, a]
        v1 = c1 * sc[S1 + 1, a] + c2 * sc[S2 + 1, a]
        v2 = c1 * sc[S1 + 2, a] + c2 * sc[S2 + 2, a]
        if square:
            w = kb / factor[k, a] if factor[k, a] > 0.0 else 0.0
            v0, v1, v2 = w * v0 * v0, w * v1 * v1, w * v2 * v2
        out[0, c + i] += v0
        out[1, c + i] += v1
        out[2, c + i] += v2


@njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True)
def _exact_hinges(x, y, params, k, c, start, stop, out):
    """out += K y of the hinges of kind k anchored in [start, stop) (vertex offsets c): the
    exact bending Hessian 2 k_bend f (g g^T + theta dg/dx), g = d theta / dx. Scalar."""
    for p in range(start, stop):
        factor = params.edge_factor[k, p]
        v = [(x[0, p + c[j]], x[1, p + c[j]], x[2, p + c[j]]) for j in range(4)]
        dv = [(y[0, p + c[j]], y[1, p + c[j]], y[2, p + c[j]]) for j in range(4)]
        theta, ok, length, n1, n2, inv1, inv2, t1, t2 = _hinge(v[0], v[1], v[2], v[3])
        g = _hinge_gradient(length, _scale(n1, inv1), _scale(n2, inv2), t1, t2)
        h = _hinge_gradient_derivative(v[0], v[1], v[2], v[3], dv[0], dv[1], dv[2], dv[3],
                                       length, n1, n2, inv1, inv2, t1, t2)
        stiff = 2.0 * params.k_bend * factor if ok else 0.0
        s = -stiff * (_dot(g[0], dv[0]) + _dot(g[1], dv[1]) + _dot(g[2], dv[2])
                      + _dot(g[3], dv[3]))
        for j in range(4):
            r = _comb(g[j], s, h[j], -stiff * theta)
            for ax in range(3):
                out[ax, p + c[j]] += r[ax]


# --- one element kind over a range of anchors --------------------------------------------------


@njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True, pointer=True)
def _triangles(x, y, params, mode, lo, hi, out):
    """Add the triangles anchored in [lo, hi) to out: minus the gradient of E (FORCE),
    K y (PRODUCT), K_f y (FILTERED_PRODUCT) or the diagonal of -K_f (DIAGONAL)."""
    for t in range(TRIANGLE_KINDS):
        _triangle_kind(x, y, params, t, mode, lo, hi, out)


@njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True)
def _triangle_kind(x, y, params, t, mode, lo, hi, out):
    """_triangles for the triangles of kind t."""
    o0, o1, o2 = (params.offsets[TRIANGLE_VERTICES[t, 0]], params.offsets[TRIANGLE_VERTICES[t, 1]],
                  params.offsets[TRIANGLE_VERTICES[t, 2]])
    stop = min(hi, x.shape[1] - max(o0, o1, o2))  # the offsets are >= 0
    if stop <= lo:
        return
    s, m = np.uint64(lo), np.uint64(stop - lo)
    c0, c1, c2 = np.uint64(lo + o0), np.uint64(lo + o1), np.uint64(lo + o2)
    # Rows and flags go in as typed values, not literals: one compile of each pass.
    _deform_pass(x, c0, c1, c2, params, t, s, m, np.int64(WU))
    if mode == DIAGONAL:
        _membrane_diagonal_pass(params, t, s, m, -1.0, -1.0, out, c0)
        _membrane_diagonal_pass(params, t, s, m, 1.0, 0.0, out, c1)
        _membrane_diagonal_pass(params, t, s, m, 0.0, 1.0, out, c2)
        return
    if mode == FORCE:
        _stress_pass(params, t, s, m)
    else:
        _deform_pass(y, c0, c1, c2, params, t, s, m, np.int64(DWU))
        _hessian_pass(params, t, s, m, mode == FILTERED_PRODUCT)
    _spread_pass(params, t, s, m, -1.0, -1.0, out, c0)
    _spread_pass(params, t, s, m, 1.0, 0.0, out, c1)
    _spread_pass(params, t, s, m, 0.0, 1.0, out, c2)


@njit(cache=True, nogil=True, inline="always")
def _hinge_anchors(params, k, lo, hi, n):
    """(vertex offsets, start, stop): the hinges of kind k anchored in [lo, hi) of n points
    are those anchored in [start, stop) (none if stop <= start)."""
    o = (params.offsets[HINGE_VERTICES[k, 0]], params.offsets[HINGE_VERTICES[k, 1]],
         params.offsets[HINGE_VERTICES[k, 2]], params.offsets[HINGE_VERTICES[k, 3]])
    return (o, max(lo, -min(o[0], o[1], o[2], o[3])),
            min(hi, n - max(o[0], o[1], o[2], o[3])))


@njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True, pointer=True)
def _hinges(x, y, params, mode, lo, hi, out):
    """Add the hinges anchored in [lo, hi) to out, as _triangles (none without bending
    stiffness, nor for PRODUCT: fem_jacobian_product adds the exact hinges itself)."""
    if params.k_bend == 0.0 or mode == PRODUCT:
        return
    for k in range(HINGE_KINDS):
        _hinge_kind(x, y, params, k, mode, lo, hi, out)


@njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True)
def _hinge_kind(x, y, params, k, mode, lo, hi, out):
    """_hinges for the hinges of kind k."""
    o, start, stop = _hinge_anchors(params, k, lo, hi, x.shape[1])
    if stop <= start:
        return
    s, m = np.uint64(start), np.uint64(stop - start)
    c = (np.uint64(start + o[0]), np.uint64(start + o[1]), np.uint64(start + o[2]),
         np.uint64(start + o[3]))
    _normal_one_pass(x, c[0], c[1], c[2], params, s, m)
    _normal_two_pass(x, c[0], c[1], c[3], params, s, m)
    kb = params.k_bend
    # Rows and flags go in as typed values, not literals: one compile of each pass.
    if mode == FORCE:
        _scale_pass(params, k, np.int64(THETA), -2.0 * kb, s, m)  # S_j = -dE/dtheta q_j
    elif mode == FILTERED_PRODUCT:  # S_j = -2 k_bend f (d theta . y) q_j
        _project_pass(y, c[0], c[1], c[2], params, np.int64(N1), np.int64(T1), s, m,
                      np.bool_(False))
        _project_pass(y, c[0], c[1], c[3], params, np.int64(N2), np.int64(T2), s, m,
                      np.bool_(True))
        _scale_pass(params, k, np.int64(DTHETA), -2.0 * kb, s, m)
    else:  # DIAGONAL: S_j = f q_j, squared per vertex (and divided by f)
        params.scratch[DTHETA, start:stop] = 1.0
        _scale_pass(params, k, np.int64(DTHETA), 1.0, s, m)
    for j in range(4):
        _vertex_pass(params, k, s, m, HINGE_GRADIENT[j], mode == DIAGONAL, out, c[j])


@njit(cache=True, nogil=True, parallel=True, no_cpython_wrapper=True, pointer=True)
def _bands_of_parity(x, y, elements, triangles, hinges, mode, parity, bands, out):
    """Add the elements of bands parity, parity + 2, ... to out, in parallel: band b holds
    the elements anchored in cell rows [b * rows // bands, (b + 1) * rows // bands)
    (rows = nh - 1). _triangles and _hinges are called through pointers: linked in, they
    made this loop's compile the longest part of a first FEM run (numba optimises a parallel
    loop's linked code four times), and apart they compile in two processes at once
    (pipeline.run.warmup). This loop is itself called through a pointer (FemParams.bands): each
    kernel of the FEM linked it (forces, products, diagonal), compiling the parallel loop
    again, about 1.1 s each."""
    rows, nw = elements.nh - 1, elements.nw
    for b in prange(bands // 2):
        band = 2 * b + parity
        lo, hi = (band * rows // bands) * nw, ((band + 1) * rows // bands) * nw
        triangles(x, y, elements, mode, lo, hi, out)
        hinges(x, y, elements, mode, lo, hi, out)


@njit(cache=True, nogil=True, inline="always")
def _element_pass(x, y, params, mode, out):
    """Add every element to out: the even bands in parallel, then the odd ones (a band has
    at least two cell rows, so bands running together touch disjoint points). One parallel
    loop for every mode and both parities: each parallel loop costs seconds to compile."""
    bands = 2 * max(1, min(MAX_BANDS // 2, (params.nh - 1) // 4))
    elements = FemParams(*params[:-3], None, None, None)
    for parity in range(2):
        params.bands(x, y, elements, params.triangles, params.hinges, mode, np.int64(parity),
                     bands, out)


# --- public kernels -------------------------------------------------------------------------


@njit(cache=True, nogil=True, error_model="numpy")
def fem_energy(x: np.ndarray, params: FemParams) -> float:
    """Elastic energy (J) of the cloth at positions x (3, N): stretch + shear + bending."""
    n = x.shape[1]
    energy = 0.0
    for t in range(TRIANGLE_KINDS):
        o = params.offsets[TRIANGLE_VERTICES[t]]
        for p in range(n):
            area = params.tri_area[t, p]
            if area == 0.0:  # no triangle here
                continue
            inv = params.tri_inv[t, :, p]
            v = [(x[0, p + o[j]], x[1, p + o[j]], x[2, p + o[j]]) for j in range(3)]
            wu, wv = _deformation(v[0], v[1], v[2], inv[0], inv[1], inv[2], inv[3])
            lu, lv = math.sqrt(_dot(wu, wu)), math.sqrt(_dot(wv, wv))
            s = _dot(wu, wv)
            energy += 0.5 * area * (params.k_stretch * ((lu - 1.0) ** 2 + (lv - 1.0) ** 2)
                                    + params.k_shear * s * s)
    if params.k_bend == 0.0:
        return energy
    for k in range(HINGE_KINDS):
        o = params.offsets[HINGE_VERTICES[k]]
        for p in range(n):
            factor = params.edge_factor[k, p]
            if factor == 0.0:  # no interior edge here
                continue
            v = [(x[0, p + o[j]], x[1, p + o[j]], x[2, p + o[j]]) for j in range(4)]
            theta, ok = _hinge(v[0], v[1], v[2], v[3])[:2]
            if ok:
                energy += params.k_bend * factor * theta * theta
    return energy


@njit(cache=True, nogil=True, inline="always")
def add_fem_forces(x: np.ndarray, params: FemParams, f: np.ndarray) -> None:
    """f += -dE/dx at positions x (3, N): the exact elastic forces."""
    _element_pass(x, x, params, np.int64(FORCE), f)  # a run-time mode: one compiled pass


@njit(cache=True, nogil=True)
def fem_jacobian_product(x: np.ndarray, params: FemParams, y: np.ndarray,
                         out: np.ndarray) -> None:
    """out = K y, K = d f / d x = -(Hessian of E) at x (3N x 3N, symmetric; exact, so it may
    be indefinite away from rest), matrix-free. The exact hinges are a serial loop after
    the parallel pass over the triangles: compiled only when this kernel is (tests, Newton
    solvers), not with the simulation's element pass."""
    out[:] = 0.0
    _element_pass(x, y, params, np.int64(PRODUCT), out)
    if params.k_bend != 0.0:
        for k in range(HINGE_KINDS):
            # every element is anchored in a cell row, as the bands count them
            o, start, stop = _hinge_anchors(params, k, 0, (params.nh - 1) * params.nw,
                                            x.shape[1])
            if stop > start:
                _exact_hinges(x, y, params, k, o, start, stop, out)


@njit(cache=True, nogil=True)
def fem_filtered_jacobian_product(x: np.ndarray, params: FemParams, y: np.ndarray,
                                  out: np.ndarray) -> None:
    """out = K_f y, K_f the negative semi-definite part of K that implicit Euler needs
    (M - h^2 K_f stays SPD): compressed stretch drops its transverse term (as
    forces.spring_jacobian), shear and bending keep their Gauss-Newton part (dC dC^T of
    C = w_u . w_v and C = theta). Equal to K at the rest state."""
    out[:] = 0.0
    _element_pass(x, y, params, np.int64(FILTERED_PRODUCT), out)


@njit(cache=True, nogil=True)
def fem_jacobian_diagonal(x: np.ndarray, params: FemParams, out: np.ndarray) -> None:
    """out[a, p] = -(K_f)_{pa, pa} >= 0: the diagonal of the filtered -K per (axis, point),
    for a Jacobi preconditioner."""
    out[:] = 0.0
    _element_pass(x, x, params, np.int64(DIAGONAL), out)


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
