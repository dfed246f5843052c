"""What a run of the physics raises or warns of."""
from __future__ import annotations


class DivergenceError(RuntimeError):
    """The simulation blew up; `str(err)` names the frame, step and quantity."""


class StabilityWarning(UserWarning):
    """The time step exceeds the explicit stability limit of the spring lattice."""


class StartTangledWarning(UserWarning):
    """Under robust contact, the cloth starts crossing itself: it stays so there."""


class SelfCollisionWarning(UserWarning):
    """Self-collision will act on neighbouring points of the cloth (edges under 2 x
    thickness)."""
