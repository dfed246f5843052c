"""Verlet with damping, the classic model's integrator (SPEC section 2), exactly as the course.

x' = x + (1 - damping) (x - x_last) + (F / m) dt^2; pinned points never move.
State: positions x and last positions x_last, both (3, N).
"""
from __future__ import annotations

import numpy as np
from numba import njit

from ..colliders import collide_all
from ..constraints import limit_stretch
from ..forces import spring_forces
from ..self_collision import self_collide
from ..system import System, energy_guard

NAME = "verlet"


class State:
    """Positions and last positions, (3, N) each, plus the force buffer."""

    def __init__(self, system: System) -> None:
        self.x = system.x0.copy()
        self.last = system.x0.copy()
        self.force = np.zeros_like(system.x0)

    def velocity(self, system: System) -> np.ndarray:
        return (self.x - self.last) / system.dt

    def advance(self, system: System, steps: int) -> tuple[int, float, float]:
        return advance(system, self.x, self.last, self.force, steps)


@njit(cache=True, nogil=True)
def advance(system, x, last, force, steps):
    """Run `steps` steps. Returns (steps done, kinetic energy, bound); fewer steps than asked
    means the energy guard tripped after the last one (see system.energy_guard)."""
    s = system
    keep = 1.0 - s.damping
    dt2 = s.dt * s.dt
    kinetic = bound = 0.0
    for step in range(steps):
        spring_forces(x, s.nw, s.exists, s.rest, s.stiffness, s.mass, s.gravity, force)
        for p in range(x.shape[1]):
            if s.pinned[p]:
                continue
            for a in range(3):
                xa = x[a, p]
                x[a, p] = xa + keep * (xa - last[a, p]) + (force[a, p] / s.mass) * dt2
                last[a, p] = xa
        if s.self_collision:
            self_collide(x, s.pinned, s.width, s.height, s.nw, s.nh, s.thickness,
                         s.steps_per_frame, s.scratch)
        if s.collider_kinds.shape[0] > 0:
            collide_all(x, last, s.pinned, s.collider_kinds, s.collider_params)
        limit_stretch(x, s.nw, s.exists, s.limit, s.limit_sq_lo, s.pinned)
        v_sq = 0.0
        finite = True
        for p in range(x.shape[1]):
            for a in range(3):
                v = x[a, p] - last[a, p]
                v_sq += v * v
            finite &= np.isfinite(x[0, p]) and np.isfinite(x[1, p]) and np.isfinite(x[2, p])
        kinetic, bound = energy_guard(x, v_sq / dt2, s)
        if not finite or not kinetic <= bound:
            return step + 1, kinetic, bound
    return steps, kinetic, bound
