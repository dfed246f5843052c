"""wireframe: every mesh edge (for the cloth: every enabled spring; for colliders their
grid lines) as a 1-pixel line over the background, colour k_d * line_colour (cloth and
sphere white, plane 0.7 grey). Lines are depth tested against each other only."""
from numba import njit

from ..shade import STAGE, ZERO, add, begin_row, fetch, put, sample
from . import Shader, param_offsets

PARAMS = {"line_colour": (1.0, 1.0, 1.0)}
(LINE,) = param_offsets(PARAMS)


@njit(cache=True, inline="always")
def fragment(p, n0, v, uv, t, kd, lp, li, prm, tex, hmap, cube):
    return (kd[0] * prm[LINE], kd[1] * prm[LINE + 1], kd[2] * prm[LINE + 2])


@njit(**STAGE)
def stage(f, g, prm, tex, hmap, cube):
    """The fragment stage (see shade.py) of output rows g, g + f.groups, ..."""
    for y in range(g, f.height, f.groups):
        x0, x1 = begin_row(f, y)
        for x in range(x0, x1):
            c = ZERO
            for k in range(f.aa * f.aa):
                s = sample(f, y, x, k)
                if f.prim[s] < 0:
                    c = add(c, f.bg)
                else:
                    p, n0, v, uv, t, kd = fetch(f, s)
                    c = add(c, fragment(p, n0, v, uv, t, kd, f.lp, f.li, prm, tex, hmap, cube))
            put(f, y, x, c)


SHADER = Shader("wireframe", fragment, PARAMS, primitive="lines", doc=__doc__, stage=stage)
