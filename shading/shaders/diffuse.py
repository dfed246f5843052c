"""diffuse: k_d * I / r^2 * max(0, n.l)."""
from clothjit import njit

from ..lighting import light_terms, two_sided
from . import Shader


@njit(cache=True, inline="always")
def fragment(p, n0, v, uv, t, kd, lp, li, prm, tex, hmap, cube, lit):
    e, ndl, _ = light_terms(p, two_sided(n0, v), v, lp, li, lit[0])
    return (kd[0] * e[0] * ndl, kd[1] * e[1] * ndl, kd[2] * e[2] * ndl)


SHADER = Shader("diffuse", fragment, lit=("shadows",), dark=True, doc=__doc__)
