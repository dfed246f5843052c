"""phong (Blinn-Phong): k_a I_a + k_d I/r^2 max(0, n.l) + k_s I/r^2 max(0, n.h)^p."""
from clothjit import njit

from ..lighting import blinn_phong, two_sided, vec3
from . import Shader, param_offsets

PARAMS = {"k_a": 0.1, "I_a": (1.0, 1.0, 1.0), "k_s": 0.5, "p": 100.0}
K_A, I_A, K_S, P_EXP = param_offsets(PARAMS)


@njit(cache=True, inline="always")
def fragment(p, n0, v, uv, t, kd, lp, li, prm, tex, hmap, cube, lit):
    return blinn_phong(p, two_sided(n0, v), v, kd, lp, li,
                       prm[K_A], vec3(prm, I_A), prm[K_S], prm[P_EXP], lit)


SHADER = Shader("phong", fragment, PARAMS, doc=__doc__)
