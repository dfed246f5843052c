"""Backward Euler linearised once per step (Baraff and Witkin 1998, "Large steps in cloth
simulation", section 4), matrix-free, with a filtered preconditioned conjugate gradient.

With f(x, v) = m g + elastic forces(x) + other forces(x, v, t) - gamma m v (gamma =
system.drag_rate), K = d(elastic forces)/dx at the start of the step (forces.jacobian_kernels:
the spring Jacobians of forces.spring_jacobian, or the FEM's filtered Hessian; the other
forces, wind, enter explicitly) and df/dv = -gamma M:

    ((1 + dt gamma) M - dt^2 K) dv = dt (f(x, v) + dt K v),   v' = v + dv,   x' = x + dt v'.

The system matrix is symmetric positive definite (compressed springs drop their transverse
term; the FEM keeps the semi-definite part of its Hessian); it is solved by conjugate gradients with a Jacobi preconditioner, never assembled.
Pinned points are handled as in the paper's modified PCG (section 5.3): the filter S zeroes
their components of the residual and the search directions, so they keep v = 0.
The solve stops at a relative residual of CG_TOLERANCE (or CG_MAX_ITERATIONS).
After the step come the shared position passes; their correction dx of a point becomes a
velocity change v' += dx / dt (docs/integrators.md).
"""
from __future__ import annotations

import numpy as np
from numba.core import types

from clothjit import KernelPointer, njit

from ..forces import jacobian_kernels, total_force
from ..mesh_model import MeshSprings
from ..system import System, corrected_velocities, drag_rate, position_passes, step_guard
from .euler import VelocityState

NAME = "implicit-euler"
CONDITIONALLY_STABLE = False
CG_TOLERANCE = 1e-9  # relative residual |r| <= tol |b|
CG_MAX_ITERATIONS = 1000


class State(VelocityState):
    def __init__(self, system: System) -> None:
        super().__init__(system)
        n = self.x.shape[1]
        # per spring: the grid's (direction, point), a mesh cloth's (0, spring)
        rows, columns = ((1, len(system.springs.a)) if isinstance(system.springs, MeshSprings)
                         else (6, n))
        self.unit = np.zeros((rows, 3, columns))
        self.alpha = np.zeros((rows, columns))
        self.buffer = np.zeros_like(system.spring_force)
        # rhs, dv, residual, preconditioned residual, direction, product, diagonal
        self.work = np.zeros((7, 3, n))
        self.iterations = np.zeros(1, dtype=np.int64)  # CG iterations done, summed
        # the solve, the model's Jacobian it calls and the update, through pointers:
        # compiled once rather than linked into (and optimised again in) the stepping
        # kernel of every System type, and apart (a first run compiles them in two
        # processes); the solve and the stepping kernel serve both models
        fem, springs = system.fem, system.springs
        self.jacobian = jacobian_kernels(system, self.x, self.unit, self.alpha, self.buffer)
        self.solve = KernelPointer(solve_step, (
            self.x, self.v, self.force, 0.0, system.pinned, system.mass, fem, springs,
            self.unit, self.alpha, self.buffer, self.work, 0.0, self.jacobian), types.int64)
        self.update = KernelPointer(_update, (self.x, self.v, self.last, self.work[1],
                                              system.pinned, 0.0, self.predicted))

    def arguments(self, system: System, steps: int, first_step: int) -> tuple:
        """The stepping kernel's arguments."""
        return (system, self.x, self.v, self.last, self.predicted, self.force, self.unit,
                self.alpha, self.buffer, self.work, self.iterations, self.solve, self.jacobian,
                self.update, steps, first_step)

    def advance(self, system: System, steps: int, first_step: int) -> tuple[int, float, float]:
        return advance(*self.arguments(system, steps, first_step))


@njit(cache=True, nogil=True, no_cpython_wrapper=True)
def _dot(a, b):
    total = 0.0
    for ax in range(3):
        for p in range(a.shape[1]):
            total += a[ax, p] * b[ax, p]
    return total


@njit(cache=True, nogil=True, no_cpython_wrapper=True)
def _apply(x, y, out, pinned, mass, fem, springs, unit, alpha, buffer, mass_factor, h2,
           product, passes):
    """out = S ((1 + h gamma) M - h^2 K) y (S: zero on pinned points; K at x, by `product`:
    forces.JacobianKernels.product, `passes` its passes); mass_factor is 1 + h gamma."""
    product(x, y, fem, springs, unit, alpha, buffer, out, passes)
    for ax in range(3):
        for p in range(y.shape[1]):
            out[ax, p] = (0.0 if pinned[p] else
                          mass_factor * mass[p] * y[ax, p] - h2 * out[ax, p])


@njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True, pointer=True)
def solve_step(x, v, force, h, pinned, mass, fem, springs, unit, alpha, buffer, work, gamma,
               jacobian):
    """dv of one linearised backward-Euler step of length h (in work[1]), `force` the forces
    at its start; returns CG iterations. It takes the System's fields (`springs`:
    System.springs), so it compiles once, not per System type; the stepping kernel calls
    it through State.solve, and it calls the model's Jacobian through `jacobian`
    (forces.JacobianKernels)."""
    h2 = h * h
    b, dv, r, z, d, q, diag = work[0], work[1], work[2], work[3], work[4], work[5], work[6]
    n = x.shape[1]
    prepare, product, diagonal, passes = jacobian
    prepare(x, fem, springs, unit, alpha)
    product(x, v, fem, springs, unit, alpha, buffer, q, passes)
    diagonal(x, fem, springs, unit, alpha, diag)
    mass_factor = 1.0 + h * gamma
    for ax in range(3):
        for p in range(n):
            if pinned[p]:
                b[ax, p] = 0.0
            else:
                b[ax, p] = h * (force[ax, p] - gamma * mass[p] * v[ax, p] + h * q[ax, p])
            diag[ax, p] = mass_factor * mass[p] + h2 * diag[ax, p]
            dv[ax, p] = 0.0
            r[ax, p] = b[ax, p]
            z[ax, p] = r[ax, p] / diag[ax, p]
            d[ax, p] = z[ax, p]
    target = CG_TOLERANCE * CG_TOLERANCE * _dot(b, b)
    rz = _dot(r, z)
    iterations = 0
    while iterations < CG_MAX_ITERATIONS and _dot(r, r) > target:
        _apply(x, d, q, pinned, mass, fem, springs, unit, alpha, buffer, mass_factor, h2,
               product, passes)
        dq = _dot(d, q)
        if not dq > 0.0:
            break
        step = rz / dq
        for ax in range(3):
            for p in range(n):
                dv[ax, p] += step * d[ax, p]
                r[ax, p] -= step * q[ax, p]
                z[ax, p] = r[ax, p] / diag[ax, p]
        rz_new = _dot(r, z)
        beta = rz_new / rz
        rz = rz_new
        for ax in range(3):
            for p in range(n):
                d[ax, p] = z[ax, p] + beta * d[ax, p]
        iterations += 1
    return iterations


@njit(cache=True, nogil=True, no_cpython_wrapper=True, pointer=True)
def _update(x, v, last, dv, pinned, dt, predicted):
    """v += dv and x += dt v on the free points (last and predicted: the positions before and
    after). Serial: once per step, a parallel loop would not pay for its compile."""
    for p in range(x.shape[1]):
        for a in range(3):
            last[a, p] = x[a, p]
            if not pinned[p]:
                v[a, p] += dv[a, p]
                x[a, p] += dt * v[a, p]
            predicted[a, p] = x[a, p]


@njit(cache=True, nogil=True)
def advance(s, x, v, last, predicted, force, unit, alpha, buffer, work, iterations, solve,
            jacobian, update, steps, first_step):
    """Run `steps` steps; returns (steps done, kinetic energy, bound) like verlet.advance."""
    gamma = drag_rate(s)
    kinetic = bound = 0.0
    for step in range(steps):
        t = (first_step + step) * s.dt
        total_force(x, v, t, s, force)
        iterations[0] += solve(x, v, force, s.dt, s.pinned, s.mass, s.fem, s.springs, unit,
                               alpha, buffer, work, gamma, jacobian)
        update(x, v, last, work[1], s.pinned, s.dt, predicted)
        position_passes(x, last, s, t)
        corrected_velocities(x, predicted, v, s.pinned, s.dt)
        ok, kinetic, bound = step_guard(x, last, s)
        if not ok:
            return step + 1, kinetic, bound
    return steps, kinetic, bound
