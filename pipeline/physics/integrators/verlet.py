"""Verlet with damping, the classic model's integrator (SPEC section 2), exactly as the course.

x' = x + (1 - damping) (x - x_last) + (F / m) dt^2; pinned points never move. Under fidelity
auto the factor dt^2 is `system.force_dt2` = dt damping / gamma (gamma the drag rate), which
makes the update exact for a constant force under the drag (the course's dt^2 overshoots
the terminal velocity by about gamma dt / 2); it tends to dt^2 as gamma -> 0.
State: positions x and last positions x_last, both (3, N). Velocity-dependent forces (wind)
see the velocity of the last step, (x - x_last) / dt.
"""
from __future__ import annotations

import numpy as np

from clothjit import KernelPointer, njit

from ..forces import total_force
from ..system import System, position_passes, step_guard

NAME = "verlet"
CONDITIONALLY_STABLE = True


class State:
    """Positions and last positions, (3, N) each, the force buffer, and the update of the
    points through a pointer (compiled once, on its own, not again in every stepping
    kernel: see clothjit.KernelPointer)."""

    def __init__(self, system: System) -> None:
        self.x = system.x0.copy()
        self.last = system.x0.copy()
        self.force = np.zeros_like(system.x0)
        self.v = np.zeros_like(system.x0)  # (x - last) / dt, when a force needs it
        self.update = KernelPointer(_update_all, (self.x, self.last, self.force, system.pinned,
                                                  system.mass, 0.0, 0.0))

    def velocity(self, system: System) -> np.ndarray:
        return (self.x - self.last) / system.dt

    def arguments(self, system: System, steps: int, first_step: int) -> tuple:
        """The stepping kernel's arguments."""
        return system, self.x, self.last, self.v, self.force, self.update, steps, first_step

    def advance(self, system: System, steps: int, first_step: int) -> tuple[int, float, float]:
        return advance(*self.arguments(system, steps, first_step))


@njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True, pointer=True)
def _update_all(x, last, force, pinned, mass, keep, dt2):
    """The Verlet step of every point. Serial: LLVM vectorises this loop (pins are a select,
    each point read once from x and from last), 5-6 us for the 2500 points of the README
    scene against 11-17 us for the former parallel loop over chunks, whose views of the
    rows it did not vectorise; and a serial kernel compiles sooner than a parallel one."""
    for a in range(3):
        for i in range(x.shape[1]):
            xi = x[a, i]
            li = last[a, i]
            moved = xi + keep * (xi - li) + (force[a, i] / mass[i]) * dt2
            free = pinned[i] == 0
            x[a, i] = moved if free else xi
            last[a, i] = xi if free else li


@njit(cache=True, nogil=True)
def advance(s, x, last, v, force, update, steps, first_step):
    """Run `steps` steps, the first being step number `first_step` of the run. Returns
    (steps done, kinetic energy, bound); fewer steps than asked means the divergence guard
    tripped after the last one (see system.energy_guard)."""
    keep = 1.0 - s.damping
    dt2 = s.force_dt2
    kinetic = bound = 0.0
    for step in range(steps):
        t = (first_step + step) * s.dt
        if s.needs_velocity:
            for a in range(3):
                for p in range(x.shape[1]):
                    v[a, p] = (x[a, p] - last[a, p]) / s.dt
        total_force(x, v, t, s, force)
        update(x, last, force, s.pinned, s.mass, keep, dt2)
        position_passes(x, last, s, t)
        ok, kinetic, bound = step_guard(x, last, s)
        if not ok:
            return step + 1, kinetic, bound
    return steps, kinetic, bound
