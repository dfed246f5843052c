"""XPBD's constraint sweeps for a mesh cloth (pipeline.physics.mesh_model): the kernels
xpbd.State points `constraints` at when System.springs is a MeshSprings, with the signature
of the grid's (integrators/xpbd.py: solve_springs, solve_fem), so the stepping kernel is
xpbd.advance for the grid and the mesh alike.

The constraints and their update are the grid's, taken over the mesh's lists in list order:

* classic (solve_mesh_springs): every spring of the MeshSprings (structural, then bending,
  as the list holds them) is the distance constraint C = |x_b - x_a| - rest with compliance
  alpha = 1 / k (k its stiffness; a spring of stiffness 0 is skipped);
* FEM (solve_mesh_fem): per triangle of the MeshFem, C_u = |w_u| - 1 and C_v = |w_v| - 1
  with alpha = 1 / (a k_stretch) and C_s = w_u . w_v with alpha = 1 / (a k_shear) (a: the
  rest area), then per hinge C = theta - rest_angle with alpha = 1 / (2 k_bend hinge_factor),
  so that C^2 / (2 alpha) is mesh_forces' FEM energy term by term (constraints of zero
  stiffness skipped). The element quantities are pipeline.physics.fem's (_deformation,
  _hinge, _hinge_gradient), as the grid's sweep and mesh_forces use them.

Each update: d_lambda = (-C - alpha~ lambda) / (sum_i w_i |grad_i C|^2 + alpha~),
alpha~ = alpha / dt^2, x_i += w_i grad_i C d_lambda, w = 1/m (0 for a pinned point).
Gauss-Seidel: each constraint sees the positions its predecessors left, so the sweeps are
serial (one order, whatever the number of threads).

Multipliers (xpbd.State.multiplier, reset each step), one flat array:
classic (S,): lam[s] of spring s; FEM (3 T + H,): lam[3 t + c] of triangle t's C_u (c = 0),
C_v (1), C_s (2), then lam[3 T + h] of hinge h.
"""
from __future__ import annotations

import numpy as np

from clothjit import njit

from .fem import _comb, _deformation, _dot, _hinge, _hinge_gradient, _scale


def multipliers(springs, fem, classic: bool) -> np.ndarray:
    """The zeroed multipliers of a mesh cloth, in the layout above."""
    if classic:
        return np.zeros(len(springs.a))
    return np.zeros(3 * len(fem.triangles) + len(fem.hinges))


# the point helpers of both models' sweeps (integrators.xpbd's too)
@njit(cache=True, nogil=True, no_cpython_wrapper=True)
def _inverse_mass(pinned, mass, p):
    return 0.0 if pinned[p] else 1.0 / mass[p]


@njit(cache=True, nogil=True, no_cpython_wrapper=True)
def _point(x, p):
    return (x[0, p], x[1, p], x[2, p])


@njit(cache=True, nogil=True, no_cpython_wrapper=True)
def _move(x, p, scale, g):
    """x_p += scale g."""
    x[0, p] += scale * g[0]
    x[1, p] += scale * g[1]
    x[2, p] += scale * g[2]


@njit(cache=True, nogil=True, no_cpython_wrapper=True, pointer=True)
def solve_mesh_springs(x, lam, pinned, mass, springs, fem, dt2, iterations):
    """Gauss-Seidel sweeps over a MeshSprings' distance constraints in list order (`fem`
    unused: the signature of xpbd.solve_springs). The spring's a is the grid's p (the point
    that creates it), its b the grid's q."""
    a, b, rest, stiffness = springs.a, springs.b, springs.rest, springs.stiffness
    for _ in range(iterations):
        for s in range(a.shape[0]):
            k = stiffness[s]
            if k == 0.0:
                continue
            p, q = a[s], b[s]
            wp = _inverse_mass(pinned, mass, p)
            wq = _inverse_mass(pinned, mass, q)
            if wp + wq == 0.0:
                continue
            dx = x[0, q] - x[0, p]
            dy = x[1, q] - x[1, p]
            dz = x[2, q] - x[2, p]
            length = np.sqrt(dx * dx + dy * dy + dz * dz)
            if not length > 0.0:
                continue
            compliance = 1.0 / (k * dt2)
            dl = (-(length - rest[s]) - compliance * lam[s]) / (wp + wq + compliance)
            lam[s] += dl
            ux, uy, uz = dx / length, dy / length, dz / length
            # grad_p C = -u, grad_q C = u
            x[0, p] -= wp * dl * ux
            x[1, p] -= wp * dl * uy
            x[2, p] -= wp * dl * uz
            x[0, q] += wq * dl * ux
            x[1, q] += wq * dl * uy
            x[2, q] += wq * dl * uz


@njit(cache=True, nogil=True, no_cpython_wrapper=True)
def _project(x, lam, row, c, compliance, p0, p1, p2, w0, w1, w2, g0, g1, g2):
    """One XPBD update of the constraint lam[row] with value c and gradients g0, g1, g2 at
    the points p0, p1, p2 (inverse masses w0, w1, w2); compliance = alpha / dt^2."""
    wsum = w0 * _dot(g0, g0) + w1 * _dot(g1, g1) + w2 * _dot(g2, g2)
    if not wsum > 0.0:
        return
    dl = (-c - compliance * lam[row]) / (wsum + compliance)
    lam[row] += dl
    _move(x, p0, w0 * dl, g0)
    _move(x, p1, w1 * dl, g1)
    _move(x, p2, w2 * dl, g2)


@njit(cache=True, nogil=True, no_cpython_wrapper=True)
def _triangle(x, lam, pinned, mass, fem, t, dt2):
    """The stretch and shear constraints of triangle t (xpbd._triangle's, per list entry)."""
    area = fem.tri_area[t]
    if not area > 0.0:
        return
    p0, p1, p2 = fem.triangles[t, 0], fem.triangles[t, 1], fem.triangles[t, 2]
    w0 = _inverse_mass(pinned, mass, p0)
    w1 = _inverse_mass(pinned, mass, p1)
    w2 = _inverse_mass(pinned, mass, p2)
    i00, i01 = fem.tri_inv[t, 0], fem.tri_inv[t, 1]
    i10, i11 = fem.tri_inv[t, 2], fem.tri_inv[t, 3]
    # stretch: C = |w| - 1, dC/dw = w / |w|; w_u = i00 e1 + i10 e2, w_v = i01 e1 + i11 e2
    if fem.k_stretch > 0.0:
        compliance = 1.0 / (area * fem.k_stretch * dt2)
        for c in range(2):  # recomputed after each projection: Gauss-Seidel
            ia, ib = (i00, i10) if c == 0 else (i01, i11)
            wu, wv = _deformation(_point(x, p0), _point(x, p1), _point(x, p2), i00, i01, i10,
                                  i11)
            w = wu if c == 0 else wv
            length = np.sqrt(_dot(w, w))
            if not length > 0.0:
                continue
            n = (w[0] / length, w[1] / length, w[2] / length)
            g1, g2 = _scale(n, ia), _scale(n, ib)
            g0 = _comb(g1, -1.0, g2, -1.0)
            _project(x, lam, 3 * t + c, length - 1.0, compliance, p0, p1, p2, w0, w1, w2,
                     g0, g1, g2)
    # shear: C = w_u . w_v, dC/dw_u = w_v, dC/dw_v = w_u
    if fem.k_shear > 0.0:
        compliance = 1.0 / (area * fem.k_shear * dt2)
        wu, wv = _deformation(_point(x, p0), _point(x, p1), _point(x, p2), i00, i01, i10, i11)
        g1, g2 = _comb(wv, i00, wu, i01), _comb(wv, i10, wu, i11)
        g0 = _comb(g1, -1.0, g2, -1.0)
        _project(x, lam, 3 * t + 2, _dot(wu, wv), compliance, p0, p1, p2, w0, w1, w2,
                 g0, g1, g2)


@njit(cache=True, nogil=True, no_cpython_wrapper=True)
def _bend(x, lam, pinned, mass, fem, h, row, dt2):
    """The bending constraint C = theta - rest_angle of hinge h (multiplier lam[row])."""
    factor = fem.hinge_factor[h]
    if not factor > 0.0:
        return
    pa, pb = fem.hinges[h, 0], fem.hinges[h, 1]
    pc, pd = fem.hinges[h, 2], fem.hinges[h, 3]
    theta, ok, length, n1, n2, inv1, inv2, t1, t2 = _hinge(
        _point(x, pa), _point(x, pb), _point(x, pc), _point(x, pd))
    if not ok:
        return
    ga, gb, gc, gd = _hinge_gradient(length, _scale(n1, inv1), _scale(n2, inv2), t1, t2)
    wa, wb = _inverse_mass(pinned, mass, pa), _inverse_mass(pinned, mass, pb)
    wc, wd = _inverse_mass(pinned, mass, pc), _inverse_mass(pinned, mass, pd)
    wsum = wa * _dot(ga, ga) + wb * _dot(gb, gb) + wc * _dot(gc, gc) + wd * _dot(gd, gd)
    if not wsum > 0.0:
        return
    compliance = 1.0 / (2.0 * fem.k_bend * factor * dt2)
    dl = (-(theta - fem.rest_angle[h]) - compliance * lam[row]) / (wsum + compliance)
    lam[row] += dl
    _move(x, pa, wa * dl, ga)
    _move(x, pb, wb * dl, gb)
    _move(x, pc, wc * dl, gc)
    _move(x, pd, wd * dl, gd)


@njit(cache=True, nogil=True, no_cpython_wrapper=True, pointer=True)
def solve_mesh_fem(x, lam, pinned, mass, springs, fem, dt2, iterations):
    """Gauss-Seidel sweeps over a MeshFem's constraints: the triangles, then the hinges, in
    list order (`springs` unused: the signature of xpbd.solve_fem)."""
    n_tri = fem.triangles.shape[0]
    for _ in range(iterations):
        for t in range(n_tri):
            _triangle(x, lam, pinned, mass, fem, t, dt2)
        if fem.k_bend > 0.0:
            for h in range(fem.hinges.shape[0]):
                _bend(x, lam, pinned, mass, fem, h, 3 * n_tri + h, dt2)
