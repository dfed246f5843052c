"""The cloth's elastic energy element by element, per vertex, for Vertex Block Descent
(pipeline.physics.integrators.vbd; Chen, Liu, Yang and Yuksel, ACM TOG 2024).

One flat list of elements for every cloth (`VbdElements`, built once per System by
`vbd_elements`): the classic model's springs (the grid's structural, shearing and bending
springs, or a mesh cloth's MeshSprings), or the FEM's triangles and hinges (the grid's
FemParams or a mesh cloth's MeshFem); a per-vertex incidence list (`start`, `incident`,
`corner`: which element, and which of its vertices the point is); and a greedy colouring
of the points (`colour_start`, `order`) in which no two points of one colour share an
element, so a colour's points can be updated in any order (or at once).

The energies are the models' own, so that VBD converges to backward Euler of the same model:

    spring   0.5 k (|x_a - x_b| - rest)^2                         (forces.spring_energy)
    membrane 0.5 a (k_stretch ((|w_u| - 1)^2 + (|w_v| - 1)^2) + k_shear (w_u . w_v)^2)
    hinge    k_bend f (theta - rest angle)^2                      (fem.fem_energy,
                                                                   mesh_forces.mesh_fem_energy)

with the FEM's own helpers (fem._deformation, fem._hinge, fem._hinge_gradient), so the same
floating-point theta and w. Per vertex each element gives its energy, its exact gradient
and a positive semi-definite 3x3 Hessian block: the spring's k u u^T + k max(0, 1 -
rest / l) (I - u u^T) (a compressed spring drops its negative transverse term, as
forces.spring_jacobian), the membrane's filtered Hessian (fem._membrane_hessian with
`filtered`: compressed stretch drops its transverse term, shear keeps its Gauss-Newton
part), the hinge's Gauss-Newton 2 k_bend f g g^T (g = d theta / dx). The gradient is exact,
so the fixed point is backward Euler's; the projected blocks keep every vertex's Hessian
positive definite (the inertia term adds m / h^2 I), so its Newton step always descends.
"""
from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from clothjit import njit

from .fem import (
    HINGE_KINDS,
    HINGE_VERTICES,
    TRIANGLE_KINDS,
    TRIANGLE_VERTICES,
    FemParams,
    _deformation,
    _dot,
    _hinge,
    _hinge_gradient,
)
from .mesh_model import MeshSprings


class VbdElements(NamedTuple):
    """A cloth's elements as flat arrays, its incidence and its colouring."""

    springs: np.ndarray  # (S, 2) int64 end points
    spring_rest: np.ndarray  # (S,) rest length
    spring_k: np.ndarray  # (S,) stiffness
    triangles: np.ndarray  # (T, 3) int64 (x0, x1, x2 of the FEM's R^-1 [x1 - x0, x2 - x0])
    tri_area: np.ndarray  # (T,) rest area
    tri_inv: np.ndarray  # (T, 4) R^-1 (00, 01, 10, 11)
    hinges: np.ndarray  # (H, 4) int64 (a, b, c, d): edge a-b, triangles (a, b, c), (b, a, d)
    hinge_k: np.ndarray  # (H,) k_bend f: the energy is hinge_k (theta - rest)^2
    rest_angle: np.ndarray  # (H,)
    k_stretch: float
    k_shear: float
    # point p's springs are rows rows[p, 0]:rows[p, 1] of incident and corner, its
    # triangles rows[p, 1]:rows[p, 2], its hinges rows[p, 2]:rows[p, 3]
    rows: np.ndarray  # (N, 4) int64
    incident: np.ndarray  # (M,) int64 the spring, triangle or hinge (its index in its list)
    corner: np.ndarray  # (M,) int64 which of the element's vertices the point is
    colour_start: np.ndarray  # (C + 1,) int64: colour c's points are order[cs[c]:cs[c + 1]]
    order: np.ndarray  # (N,) int64 the points, colour by colour, ascending within one


# --- building -------------------------------------------------------------------------------


def vbd_elements(system) -> VbdElements:
    """The System's cloth as VBD's elements: the grid's or a mesh cloth's, classic or FEM."""
    n = system.x0.shape[1]
    i2, f1, f4 = np.zeros((0, 2), np.int64), np.zeros(0), np.zeros((0, 4))
    springs, rest, k = i2, f1, f1
    tris, area, inv = np.zeros((0, 3), np.int64), f1, f4
    hinges, hinge_k, angle = np.zeros((0, 4), np.int64), f1, f1
    k_stretch = k_shear = 0.0
    fem = system.fem
    if system.classic:
        springs, rest, k = _spring_list(system.springs)
    elif isinstance(fem, FemParams):  # the grid's FEM
        tris, area, inv, hinges, hinge_k = _grid_fem_lists(fem)
        angle = np.zeros(len(hinges))
        k_stretch, k_shear = fem.k_stretch, fem.k_shear
    else:  # a mesh cloth's MeshFem
        tris, area, inv = fem.triangles, fem.tri_area, fem.tri_inv
        hinges, hinge_k, angle = fem.hinges, fem.k_bend * fem.hinge_factor, fem.rest_angle
        if fem.k_bend == 0.0:
            hinges, hinge_k, angle = np.zeros((0, 4), np.int64), f1, f1
        k_stretch, k_shear = fem.k_stretch, fem.k_shear
    members = [springs, tris, hinges]
    rows, incident, corner = incidence(members, n)
    colour_start, order = colouring(members, n)
    def c(a, dtype):  # writable copies: a mesh's arrays may be read-only (another type)
        return np.array(a, dtype=dtype, order="C")

    return VbdElements(
        springs=c(springs, dtype=np.int64), spring_rest=c(rest, dtype=np.float64),
        spring_k=c(k, dtype=np.float64), triangles=c(tris, dtype=np.int64),
        tri_area=c(area, dtype=np.float64), tri_inv=c(inv, dtype=np.float64),
        hinges=c(hinges, dtype=np.int64), hinge_k=c(hinge_k, dtype=np.float64),
        rest_angle=c(angle, dtype=np.float64), k_stretch=float(k_stretch),
        k_shear=float(k_shear), rows=rows, incident=incident, corner=corner,
        colour_start=colour_start, order=order)


def _spring_list(springs) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(ends (S, 2), rest (S,), k (S,)) of the springs that exert a force: a mesh cloth's
    MeshSprings, or the grid's (offsets, order, exists, rest, stiffness)."""
    if isinstance(springs, MeshSprings):
        keep = springs.stiffness != 0.0
        return (np.stack([springs.a, springs.b], axis=1)[keep], springs.rest[keep],
                springs.stiffness[keep])
    offsets, _, exists, rest, stiffness = springs
    ends, rests, ks = [], [], []
    for d in range(6):
        p = np.nonzero(exists[d] & (np.arange(exists.shape[1]) + offsets[d] >= 0))[0]
        if stiffness[d] == 0.0 or len(p) == 0:
            continue
        ends.append(np.stack([p, p + offsets[d]], axis=1))
        rests.append(rest[d, p])
        ks.append(np.full(len(p), stiffness[d]))
    if not ends:
        return np.zeros((0, 2), np.int64), np.zeros(0), np.zeros(0)
    return np.concatenate(ends), np.concatenate(rests), np.concatenate(ks)


def _grid_fem_lists(fem: FemParams) -> tuple:
    """The grid FEM's triangles (vertices, areas, R^-1) and hinges (vertices, k_bend f) as
    lists, from its per-anchor rows (pipeline.physics.fem's layout)."""
    tris, area, inv, hinges, hinge_k = [], [], [], [], []
    for t in range(TRIANGLE_KINDS):
        p = np.nonzero(fem.tri_area[t])[0]
        tris.append(p[:, None] + fem.offsets[TRIANGLE_VERTICES[t]][None, :])
        area.append(fem.tri_area[t, p])
        inv.append(fem.tri_inv[t][:, p].T)
    if fem.k_bend != 0.0:
        for k in range(HINGE_KINDS):
            p = np.nonzero(fem.edge_factor[k])[0]
            hinges.append(p[:, None] + fem.offsets[HINGE_VERTICES[k]][None, :])
            hinge_k.append(fem.k_bend * fem.edge_factor[k, p])
    return (np.concatenate(tris), np.concatenate(area), np.concatenate(inv),
            np.concatenate(hinges) if hinges else np.zeros((0, 4), np.int64),
            np.concatenate(hinge_k) if hinge_k else np.zeros(0))


def incidence(members: list[np.ndarray], n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(rows, incident, corner): the elements of each point, kind by kind (`members`: the
    vertex arrays (E_k, v_k) of the kinds), ascending within a kind, with the point's place
    in each; rows[p, k]:rows[p, k + 1] are point p's elements of kind k."""
    owners, kinds, elements, corners = [], [], [], []
    for kind, m in enumerate(members):
        count, width = m.shape
        owners.append(m.reshape(-1))
        kinds.append(np.full(count * width, kind))
        elements.append(np.repeat(np.arange(count), width))
        corners.append(np.tile(np.arange(width), count))
    owner = np.concatenate(owners).astype(np.int64)
    kind = np.concatenate(kinds).astype(np.int64)
    element = np.concatenate(elements).astype(np.int64)
    corner = np.concatenate(corners).astype(np.int64)
    slot = np.lexsort((element, kind, owner))
    counts = np.zeros((n, len(members)), dtype=np.int64)
    np.add.at(counts, (owner, kind), 1)
    rows = np.zeros((n, len(members) + 1), dtype=np.int64)
    rows[:, 1:] = np.cumsum(counts, axis=1)
    rows += np.concatenate([[0], np.cumsum(counts.sum(axis=1))[:-1]])[:, None]
    return rows, np.ascontiguousarray(element[slot]), np.ascontiguousarray(corner[slot])


def neighbours(members: list[np.ndarray], n: int) -> tuple[np.ndarray, np.ndarray]:
    """(start, points): for each point the other points it shares an element with (CSR)."""
    pairs = [np.zeros((0, 2), np.int64)]
    for m in members:
        for i in range(m.shape[1]):
            for j in range(m.shape[1]):
                if i != j:
                    pairs.append(np.stack([m[:, i], m[:, j]], axis=1))
    both = np.unique(np.concatenate(pairs).astype(np.int64), axis=0)
    both = both[both[:, 0] != both[:, 1]]
    start = np.zeros(n + 1, dtype=np.int64)
    np.cumsum(np.bincount(both[:, 0], minlength=n), out=start[1:])
    return start, both[:, 1]


def colouring(members: list[np.ndarray], n: int) -> tuple[np.ndarray, np.ndarray]:
    """(colour_start, order): a greedy colouring of the points over every pair that shares
    an element (points in index order, each the smallest colour none of its coloured
    neighbours has), the points listed colour by colour."""
    start, adjacent = neighbours(members, n)
    starts, points = start.tolist(), adjacent.tolist()
    colour = [-1] * n
    for p in range(n):
        taken = {colour[q] for q in points[starts[p]:starts[p + 1]]}
        c = 0
        while c in taken:
            c += 1
        colour[p] = c
    colours = np.array(colour, dtype=np.int64)
    order = np.argsort(colours, kind="stable").astype(np.int64)
    colour_start = np.zeros((colours.max() + 2) if n else 1, dtype=np.int64)
    np.cumsum(np.bincount(colours, minlength=len(colour_start) - 1), out=colour_start[1:])
    return colour_start, order


# --- one element at one of its vertices: (energy, gradient, Hessian block) ------------------
# The Hessian block is a symmetric 3x3 as (xx, yy, zz, xy, xz, yz).


@njit(cache=True, nogil=True, error_model="numpy", forceinline=True, no_cpython_wrapper=True)
def add_terms(a, b):
    """The sum of two (energy, gradient, Hessian block) terms."""
    g, h, u, k = a[1], a[2], b[1], b[2]
    return (a[0] + b[0], (g[0] + u[0], g[1] + u[1], g[2] + u[2]),
            (h[0] + k[0], h[1] + k[1], h[2] + k[2], h[3] + k[3], h[4] + k[4], h[5] + k[5]))


@njit(cache=True, nogil=True, error_model="numpy", forceinline=True, no_cpython_wrapper=True)
def _at(x, p):
    return (x[0, p], x[1, p], x[2, p])


@njit(cache=True, nogil=True, error_model="numpy", forceinline=True, no_cpython_wrapper=True)
def _spring_terms(x, el, s, corner):
    """0.5 k (l - rest)^2 of spring s, its gradient and block at its vertex `corner`."""
    a, b = el.springs[s, corner], el.springs[s, 1 - corner]
    k, rest = el.spring_k[s], el.spring_rest[s]
    d = (x[0, a] - x[0, b], x[1, a] - x[1, b], x[2, a] - x[2, b])
    length = math.sqrt(_dot(d, d))
    stretch = length - rest
    energy = 0.5 * k * stretch * stretch
    if not length > 0.0:  # zero length: no direction, no force (forces._direction_forces)
        return energy, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    inv = 1.0 / length
    u = (d[0] * inv, d[1] * inv, d[2] * inv)
    s_ = k * stretch
    across = k * max(0.0, 1.0 - rest * inv)
    along = k - across
    return energy, (s_ * u[0], s_ * u[1], s_ * u[2]), (
        across + along * u[0] * u[0], across + along * u[1] * u[1],
        across + along * u[2] * u[2], along * u[0] * u[1], along * u[0] * u[2],
        along * u[1] * u[2])


@njit(cache=True, nogil=True, error_model="numpy", forceinline=True, no_cpython_wrapper=True)
def _stretch_block(w, scale):
    """scale (alpha I + (1 - alpha) u u^T), u = w / |w|, alpha = max(0, 1 - 1 / |w|) (1 at
    |w| = 0): the filtered d^2 / dw^2 of (|w| - 1)^2 / 2 (fem._stretch_hessian's)."""
    length = math.sqrt(_dot(w, w))
    inv = 1.0 / length if length > 0.0 else 0.0
    alpha = max(1.0 - inv, 0.0)
    b = scale * (1.0 - alpha)
    a = scale * alpha
    u = (w[0] * inv, w[1] * inv, w[2] * inv)
    return (a + b * u[0] * u[0], a + b * u[1] * u[1], a + b * u[2] * u[2],
            b * u[0] * u[1], b * u[0] * u[2], b * u[1] * u[2])


@njit(cache=True, nogil=True, error_model="numpy", forceinline=True, no_cpython_wrapper=True)
def _triangle_terms(x, el, t, corner):
    """The membrane energy of triangle t, its gradient and filtered block at `corner`."""
    tris, inv = el.triangles, el.tri_inv
    i00, i01, i10, i11 = inv[t, 0], inv[t, 1], inv[t, 2], inv[t, 3]
    wu, wv = _deformation(_at(x, tris[t, 0]), _at(x, tris[t, 1]), _at(x, tris[t, 2]),
                          i00, i01, i10, i11)
    ka, kb = el.tri_area[t] * el.k_stretch, el.tri_area[t] * el.k_shear
    if corner == 0:
        cu, cv = -(i00 + i10), -(i01 + i11)
    elif corner == 1:
        cu, cv = i00, i01
    else:
        cu, cv = i10, i11
    lu, lv = math.sqrt(_dot(wu, wu)), math.sqrt(_dot(wv, wv))
    shear = _dot(wu, wv)
    energy = 0.5 * (ka * ((lu - 1.0) ** 2 + (lv - 1.0) ** 2) + kb * shear * shear)
    # dE/dw_u, dE/dw_v as fem._membrane_stress
    su = ka * (1.0 - 1.0 / lu) if lu > 0.0 else 0.0
    sv = ka * (1.0 - 1.0 / lv) if lv > 0.0 else 0.0
    s = kb * shear
    g = (cu * (su * wu[0] + s * wv[0]) + cv * (sv * wv[0] + s * wu[0]),
         cu * (su * wu[1] + s * wv[1]) + cv * (sv * wv[1] + s * wu[1]),
         cu * (su * wu[2] + s * wv[2]) + cv * (sv * wv[2] + s * wu[2]))
    hu, hv = _stretch_block(wu, ka * cu * cu), _stretch_block(wv, ka * cv * cv)
    q = (cu * wv[0] + cv * wu[0], cu * wv[1] + cv * wu[1], cu * wv[2] + cv * wu[2])
    return energy, g, (hu[0] + hv[0] + kb * q[0] * q[0], hu[1] + hv[1] + kb * q[1] * q[1],
                       hu[2] + hv[2] + kb * q[2] * q[2], hu[3] + hv[3] + kb * q[0] * q[1],
                       hu[4] + hv[4] + kb * q[0] * q[2], hu[5] + hv[5] + kb * q[1] * q[2])


@njit(cache=True, nogil=True, error_model="numpy", forceinline=True, no_cpython_wrapper=True)
def _hinge_terms(x, el, h, corner):
    """The bending energy of hinge h, its gradient and Gauss-Newton block at `corner`."""
    v = el.hinges
    theta, ok, length, n1, n2, inv1, inv2, t1, t2 = _hinge(
        _at(x, v[h, 0]), _at(x, v[h, 1]), _at(x, v[h, 2]), _at(x, v[h, 3]))
    if not ok:
        return 0.0, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    k = el.hinge_k[h]
    bend = theta - el.rest_angle[h]
    g = _hinge_gradient(length, (n1[0] * inv1, n1[1] * inv1, n1[2] * inv1),
                        (n2[0] * inv2, n2[1] * inv2, n2[2] * inv2), t1, t2)[corner]
    s, w = 2.0 * k * bend, 2.0 * k
    return k * bend * bend, (s * g[0], s * g[1], s * g[2]), (
        w * g[0] * g[0], w * g[1] * g[1], w * g[2] * g[2], w * g[0] * g[1], w * g[0] * g[2],
        w * g[1] * g[2])
