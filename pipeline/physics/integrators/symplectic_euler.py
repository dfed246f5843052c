"""Symplectic (semi-implicit) Euler: v' = v + dt a(x, v), then x' = x + dt v'.

The same kernel as explicit Euler (pipeline/physics/integrators/euler.py) with the update order
swapped; damping, pins, position passes and the guard are shared with it.
"""
from __future__ import annotations

from . import euler

NAME = "symplectic-euler"
CONDITIONALLY_STABLE = True


class State(euler.State):
    symplectic = True
