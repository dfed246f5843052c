"""Extended position-based dynamics (Macklin, Mueller and Chentanez 2016, "XPBD").

Classic model: every enabled spring is a distance constraint C = |x_q - x_p| - rest with
compliance alpha = 1 / k (k = ks, or 0.2 ks for bending: the same material as the
force-based methods). FEM model (system.fem, pipeline/physics/fem.py): per triangle the stretch
constraints C_u = |w_u| - 1, C_v = |w_v| - 1 with alpha = 1 / (a k_stretch) and the shear
constraint C_s = w_u . w_v with alpha = 1 / (a k_shear) (a: rest area), per interior hinge
C = theta with alpha = 1 / (2 k_bend edge_factor), so that C^2 / (2 alpha) is the FEM energy
(constraints with zero stiffness are skipped). One step: v <- (1 - damping) v + dt F_ext / m
(the Verlet damping per step; F_ext = gravity and the other forces, forces.external_force),
predict x = x + dt v, then ITERATIONS Gauss-Seidel sweeps over the constraints in a fixed
order (classic: the spring list in SPEC order; FEM: the triangles anchor by anchor, kind by
kind, each C_u, C_v, C_s, then the hinges likewise), each applying
d_lambda = (-C - alpha~ lambda) / (sum_i w_i |grad_i C|^2 + alpha~), alpha~ = alpha / dt^2,
x_i += w_i grad_i C d_lambda, w = 1/m_p (0 when pinned); then the shared position passes
(self-collision, colliders, Provot on the classic model) and v = (x - x_start) / dt for
every free point. The State points `constraints` at the model's sweeps (`solve_springs` or
`solve_fem`, one signature): the stepping kernel, the same for both models, contains
neither.
State: positions x, velocities v, start-of-step positions last (3, N), multipliers (6, N)
for the classic springs or (9, N) for the FEM (rows 3 t + (0, 1, 2): C_u, C_v, C_s of the
triangle of kind t; rows 6 + k: the hinge of kind k), reset each step.
A mesh cloth (System.springs a mesh_model.MeshSprings): the same constraints over the
mesh's spring list or its triangles then hinges, in list order, FEM hinges bending about
their rest angles (C = theta - rest_angle): pipeline.physics.mesh_xpbd's sweeps, which the
State points `constraints` at, and flat multipliers (S,) or (3 T + H,) (its docstring).
"""
from __future__ import annotations

import numpy as np
from numba.core import types

from clothjit import KernelPointer, njit

from ..fem import (HINGE_KINDS, HINGE_VERTICES, TRIANGLE_KINDS, TRIANGLE_VERTICES, _comb,
                   _deformation, _dot, _hinge, _hinge_gradient, _scale)
from ..forces import external_force
from ..mesh_model import MeshSprings
from ..mesh_xpbd import (_inverse_mass, _move, _point, multipliers, solve_mesh_fem,
                         solve_mesh_springs)
from ..system import System, position_passes, step_guard
from .euler import VelocityState

NAME = "xpbd"
CONDITIONALLY_STABLE = False
ITERATIONS = 1  # solver sweeps per step: XPBD's "small steps" regime (Macklin et al. 2019)


class State(VelocityState):
    def __init__(self, system: System) -> None:
        super().__init__(system)
        fem = system.fem
        if isinstance(system.springs, MeshSprings):  # a mesh cloth: pipeline.physics.mesh_xpbd
            # flat multipliers: (S,) per spring, or (3 T + H,) for the FEM (3 t + c: C_u,
            # C_v, C_s of triangle t; 3 T + h: hinge h)
            self.multiplier = multipliers(system.springs, fem, system.classic)
            sweeps = solve_mesh_springs if system.classic else solve_mesh_fem
        else:
            self.multiplier = (np.zeros((6, system.x0.shape[1])) if system.classic
                               else np.zeros((3 * TRIANGLE_KINDS + HINGE_KINDS,
                                              fem.nw * fem.nh)))
            sweeps = solve_springs if system.classic else solve_fem
        self.constraints = KernelPointer(
            sweeps, (self.x, self.multiplier, system.pinned, system.mass, system.springs, fem,
                     0.0, types.int64))

    def arguments(self, system: System, steps: int, first_step: int) -> tuple:
        """The stepping kernel's arguments."""
        return (system, self.x, self.v, self.last, self.force, self.multiplier,
                self.constraints, steps, first_step, ITERATIONS)

    def advance(self, system: System, steps: int, first_step: int) -> tuple[int, float, float]:
        return advance(*self.arguments(system, steps, first_step))


@njit(cache=True, nogil=True, no_cpython_wrapper=True, pointer=True)
def solve_springs(x, lam, pinned, mass, springs, fem, dt2, iterations):
    """Gauss-Seidel sweeps over the springs' distance constraints, in SPEC order (`fem`
    unused: the signature of solve_fem)."""
    offsets, _, exists, rest, stiffness = springs
    n = x.shape[1]
    for _ in range(iterations):
        for p in range(n):
            wp = _inverse_mass(pinned, mass, p)
            for d in range(6):
                k = stiffness[d]
                q = p + offsets[d]
                if k == 0.0 or q < 0 or not exists[d, p]:
                    continue
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
                dl = (-(length - rest[d, p]) - compliance * lam[d, p]) / (wp + wq + compliance)
                lam[d, p] += dl
                ux, uy, uz = dx / length, dy / length, dz / length
                # grad_p C = -u, grad_q C = u
                x[0, p] -= wp * dl * ux
                x[1, p] -= wp * dl * uy
                x[2, p] -= wp * dl * uz
                x[0, q] += wq * dl * ux
                x[1, q] += wq * dl * uy
                x[2, q] += wq * dl * uz


@njit(cache=True, nogil=True, no_cpython_wrapper=True)
def _project(x, lam, row, p, c, compliance, p0, p1, p2, w0, w1, w2, g0, g1, g2):
    """One XPBD update of the constraint with value c and gradients g0, g1, g2 at the points
    p0, p1, p2 (inverse masses w0, w1, w2); compliance = alpha / dt^2."""
    wsum = w0 * _dot(g0, g0) + w1 * _dot(g1, g1) + w2 * _dot(g2, g2)
    if not wsum > 0.0:
        return
    dl = (-c - compliance * lam[row, p]) / (wsum + compliance)
    lam[row, p] += dl
    _move(x, p0, w0 * dl, g0)
    _move(x, p1, w1 * dl, g1)
    _move(x, p2, w2 * dl, g2)


@njit(cache=True, nogil=True, no_cpython_wrapper=True)
def _triangle(x, lam, pinned, mass, fem, t, p, dt2):
    """The stretch and shear constraints of the triangle of kind t anchored at p."""
    area = fem.tri_area[t, p]
    if not area > 0.0:
        return
    p0 = p + fem.offsets[TRIANGLE_VERTICES[t, 0]]
    p1 = p + fem.offsets[TRIANGLE_VERTICES[t, 1]]
    p2 = p + fem.offsets[TRIANGLE_VERTICES[t, 2]]
    w0 = _inverse_mass(pinned, mass, p0)
    w1 = _inverse_mass(pinned, mass, p1)
    w2 = _inverse_mass(pinned, mass, p2)
    i00, i01 = fem.tri_inv[t, 0, p], fem.tri_inv[t, 1, p]
    i10, i11 = fem.tri_inv[t, 2, p], fem.tri_inv[t, 3, p]
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
            _project(x, lam, 3 * t + c, p, length - 1.0, compliance, p0, p1, p2, w0, w1, w2,
                     g0, g1, g2)
    # shear: C = w_u . w_v, dC/dw_u = w_v, dC/dw_v = w_u
    if fem.k_shear > 0.0:
        compliance = 1.0 / (area * fem.k_shear * dt2)
        wu, wv = _deformation(_point(x, p0), _point(x, p1), _point(x, p2), i00, i01, i10, i11)
        g1, g2 = _comb(wv, i00, wu, i01), _comb(wv, i10, wu, i11)
        g0 = _comb(g1, -1.0, g2, -1.0)
        _project(x, lam, 3 * t + 2, p, _dot(wu, wv), compliance, p0, p1, p2, w0, w1, w2,
                 g0, g1, g2)


@njit(cache=True, nogil=True, no_cpython_wrapper=True)
def _bend(x, lam, pinned, mass, fem, k, p, dt2):
    """The bending constraint C = theta of the hinge of kind k anchored at p."""
    factor = fem.edge_factor[k, p]
    if not factor > 0.0:
        return
    pa = p + fem.offsets[HINGE_VERTICES[k, 0]]
    pb = p + fem.offsets[HINGE_VERTICES[k, 1]]
    pc = p + fem.offsets[HINGE_VERTICES[k, 2]]
    pd = p + fem.offsets[HINGE_VERTICES[k, 3]]
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
    row = 3 * TRIANGLE_KINDS + k
    dl = (-theta - compliance * lam[row, p]) / (wsum + compliance)
    lam[row, p] += dl
    _move(x, pa, wa * dl, ga)
    _move(x, pb, wb * dl, gb)
    _move(x, pc, wc * dl, gc)
    _move(x, pd, wd * dl, gd)


@njit(cache=True, nogil=True, no_cpython_wrapper=True, pointer=True)
def solve_fem(x, lam, pinned, mass, springs, fem, dt2, iterations):
    """Gauss-Seidel sweeps over the FEM constraints: triangles, then hinges, anchor order
    (`springs` unused: the signature of solve_springs)."""
    n = x.shape[1]
    for _ in range(iterations):
        for p in range(n):
            for t in range(TRIANGLE_KINDS):
                _triangle(x, lam, pinned, mass, fem, t, p, dt2)
        if fem.k_bend > 0.0:
            for p in range(n):
                for k in range(HINGE_KINDS):
                    _bend(x, lam, pinned, mass, fem, k, p, dt2)


@njit(cache=True, nogil=True)
def advance(s, x, v, last, force, lam, constraints, steps, first_step, iterations):
    """Run `steps` steps; returns (steps done, kinetic energy, bound) like verlet.advance."""
    h = s.dt
    keep = 1.0 - s.damping
    n = x.shape[1]
    kinetic = bound = 0.0
    for step in range(steps):
        t = (first_step + step) * h
        external_force(x, v, t, s.mass, s.gravity, s.wind, s.kernels.wind, force)
        for p in range(n):
            for a in range(3):
                last[a, p] = x[a, p]
                if not s.pinned[p]:
                    v[a, p] = keep * v[a, p] + h * (force[a, p] / s.mass[p])
                    x[a, p] += h * v[a, p]
        lam[:] = 0.0
        constraints(x, lam, s.pinned, s.mass, s.springs, s.fem, h * h, iterations)
        position_passes(x, last, s, t)
        for p in range(n):
            if not s.pinned[p]:
                for a in range(3):
                    v[a, p] = (x[a, p] - last[a, p]) / h
        ok, kinetic, bound = step_guard(x, last, s)
        if not ok:
            return step + 1, kinetic, bound
    return steps, kinetic, bound
