"""phong (Blinn-Phong): k_a I_a + k_d I/r^2 max(0, n.l) + k_s I/r^2 max(0, n.h)^p."""
from numba import njit

from ..lighting import blinn_phong, two_sided, vec3
from ..shade import STAGE, ZERO, add, begin_row, fetch, put, sample
from . import Shader, param_offsets

PARAMS = {"k_a": 0.1, "I_a": (1.0, 1.0, 1.0), "k_s": 0.5, "p": 100.0}
K_A, I_A, K_S, P_EXP = param_offsets(PARAMS)


@njit(cache=True, inline="always")
def fragment(p, n0, v, uv, t, kd, lp, li, prm, tex, hmap, cube):
    return blinn_phong(p, two_sided(n0, v), v, kd, lp, li,
                       prm[K_A], vec3(prm, I_A), prm[K_S], prm[P_EXP])


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


SHADER = Shader("phong", fragment, PARAMS, doc=__doc__, stage=stage)
