"""diffuse: k_d * I / r^2 * max(0, n.l)."""
from numba import njit

from ..lighting import light_terms, two_sided
from ..shade import STAGE, ZERO, add, begin_row, fetch, put, sample
from . import Shader


@njit(cache=True, inline="always")
def fragment(p, n0, v, uv, t, kd, lp, li, prm, tex, hmap, cube):
    e, ndl, _ = light_terms(p, two_sided(n0, v), v, lp, li)
    return (kd[0] * e[0] * ndl, kd[1] * e[1] * ndl, kd[2] * e[2] * ndl)


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


SHADER = Shader("diffuse", fragment, doc=__doc__, stage=stage)
