"""wireframe: every mesh edge (for the cloth: every enabled spring; for colliders their
grid lines) as a 1-pixel line over the background, colour k_d * line_colour (cloth and
sphere white, plane 0.7 grey). Lines are depth tested against each other only."""
from clothjit import njit

from . import Shader, param_offsets

PARAMS = {"line_colour": (1.0, 1.0, 1.0)}
(LINE,) = param_offsets(PARAMS)


@njit(cache=True, inline="always")
def fragment(p, n0, v, uv, t, kd, lp, li, prm, tex, hmap, cube, lit):
    return (kd[0] * prm[LINE], kd[1] * prm[LINE + 1], kd[2] * prm[LINE + 2])


SHADER = Shader("wireframe", fragment, PARAMS, primitive="lines", lit=(), doc=__doc__)
