"""normal: (n + 1) / 2 with the two-sided normal n."""
from clothjit import njit

from ..lighting import two_sided
from . import Shader


@njit(cache=True, inline="always")
def fragment(p, n0, v, uv, t, kd, lp, li, prm, tex, hmap, cube, lit):
    n = two_sided(n0, v)
    return ((n[0] + 1.0) * 0.5, (n[1] + 1.0) * 0.5, (n[2] + 1.0) * 0.5)


SHADER = Shader("normal", fragment, lit=(), doc=__doc__)
