"""Extended position-based dynamics (Macklin, Mueller and Chentanez 2016, "XPBD").

Every enabled spring is a distance constraint C = |x_q - x_p| - rest with compliance
alpha = 1 / k (k = ks, or 0.2 ks for bending: the same material as the force-based
methods). One step: v <- (1 - damping) v + dt F_ext / m (the Verlet damping per step;
F_ext = gravity and the other forces, forces.external_force), predict
x = x + dt v, then ITERATIONS Gauss-Seidel sweeps over the spring list (in SPEC order),
each applying d_lambda = (-C - alpha~ lambda) / (w_p + w_q + alpha~), alpha~ = alpha / dt^2,
w = 1/m_p (0 when pinned); then the shared position passes (self-collision, colliders,
Provot) and v = (x - x_start) / dt for every free point.
State: positions x, velocities v, start-of-step positions last (3, N), multipliers (6, N).
"""
from __future__ import annotations

import numpy as np
from numba import njit

from ..forces import external_force
from ..system import System, position_passes, step_guard
from .euler import VelocityState

NAME = "xpbd"
CONDITIONALLY_STABLE = False
ITERATIONS = 1  # solver sweeps per step: XPBD's "small steps" regime (Macklin et al. 2019)


class State(VelocityState):
    def __init__(self, system: System) -> None:
        super().__init__(system)
        self.multiplier = np.zeros(system.rest.shape)

    def advance(self, system: System, steps: int, first_step: int) -> tuple[int, float, float]:
        return advance(system, self.x, self.v, self.last, self.force, self.multiplier, steps,
                       first_step, ITERATIONS)


@njit(cache=True, nogil=True)
def _solve(x, lam, s, dt2, iterations):
    n = x.shape[1]
    for _ in range(iterations):
        for p in range(n):
            wp = 0.0 if s.pinned[p] else 1.0 / s.mass[p]
            for d in range(6):
                k = s.stiffness[d]
                q = p + s.offsets[d]
                if k == 0.0 or q < 0 or not s.exists[d, p]:
                    continue
                wq = 0.0 if s.pinned[q] else 1.0 / s.mass[q]
                if wp + wq == 0.0:
                    continue
                dx = x[0, q] - x[0, p]
                dy = x[1, q] - x[1, p]
                dz = x[2, q] - x[2, p]
                length = np.sqrt(dx * dx + dy * dy + dz * dz)
                if not length > 0.0:
                    continue
                compliance = 1.0 / (k * dt2)
                dl = (-(length - s.rest[d, p]) - compliance * lam[d, p]) / (wp + wq + compliance)
                lam[d, p] += dl
                ux, uy, uz = dx / length, dy / length, dz / length
                # grad_p C = -u, grad_q C = u
                x[0, p] -= wp * dl * ux
                x[1, p] -= wp * dl * uy
                x[2, p] -= wp * dl * uz
                x[0, q] += wq * dl * ux
                x[1, q] += wq * dl * uy
                x[2, q] += wq * dl * uz


@njit(cache=True, nogil=True)
def advance(s, x, v, last, force, lam, steps, first_step, iterations):
    """Run `steps` steps; returns (steps done, kinetic energy, bound) like verlet.advance."""
    h = s.dt
    keep = 1.0 - s.damping
    n = x.shape[1]
    kinetic = bound = 0.0
    for step in range(steps):
        t = (first_step + step) * h
        external_force(x, v, t, s, force)
        for p in range(n):
            for a in range(3):
                last[a, p] = x[a, p]
                if not s.pinned[p]:
                    v[a, p] = keep * v[a, p] + h * (force[a, p] / s.mass[p])
                    x[a, p] += h * v[a, p]
        lam[:] = 0.0
        _solve(x, lam, s, h * h, iterations)
        position_passes(x, last, s, t)
        for p in range(n):
            if not s.pinned[p]:
                for a in range(3):
                    v[a, p] = (x[a, p] - last[a, p]) / h
        ok, kinetic, bound = step_guard(x, last, s)
        if not ok:
            return step + 1, kinetic, bound
    return steps, kinetic, bound
