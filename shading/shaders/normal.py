"""normal: (n + 1) / 2 with the two-sided normal n."""
from numba import njit

from ..lighting import two_sided
from ..shade import STAGE, ZERO, add, begin_row, fetch, put, sample
from . import Shader


@njit(cache=True, inline="always")
def fragment(p, n0, v, uv, t, kd, lp, li, prm, tex, hmap, cube):
    n = two_sided(n0, v)
    return ((n[0] + 1.0) * 0.5, (n[1] + 1.0) * 0.5, (n[2] + 1.0) * 0.5)


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


SHADER = Shader("normal", fragment, doc=__doc__, stage=stage)
