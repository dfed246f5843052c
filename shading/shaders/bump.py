"""bump: normal perturbed by the height map (red channel) through TBN = [t, n0 x t, n0]
(forward differences of one texel, scaled by k_h * k_n), then Blinn-Phong."""
from clothjit import njit

from ..lighting import blinn_phong, bump_normal, vec3
from . import Shader, param_offsets

PARAMS = {"k_a": 0.1, "I_a": (1.0, 1.0, 1.0), "k_s": 0.5, "p": 100.0, "k_h": 0.1, "k_n": 2.0}
K_A, I_A, K_S, P_EXP, K_H, K_N = param_offsets(PARAMS)


@njit(cache=True, inline="always")
def fragment(p, n0, v, uv, t, kd, lp, li, prm, tex, hmap, cube, lit):
    n = bump_normal(n0, t, v, uv, hmap, prm[K_H], prm[K_N])
    return blinn_phong(p, n, v, kd, lp, li, prm[K_A], vec3(prm, I_A), prm[K_S], prm[P_EXP], lit)


SHADER = Shader("bump", fragment, PARAMS, textures=("height_map",), doc=__doc__)
