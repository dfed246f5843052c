"""bump: normal perturbed by the height map (red channel) through TBN = [t, n0 x t, n0]
(forward differences of one texel, scaled by k_h * k_n), then Blinn-Phong."""
from numba import njit

from ..lighting import blinn_phong, bump_normal, vec3
from ..shade import STAGE, ZERO, add, begin_row, fetch, put, sample
from . import Shader, param_offsets

PARAMS = {"k_a": 0.1, "I_a": (1.0, 1.0, 1.0), "k_s": 0.5, "p": 100.0, "k_h": 0.1, "k_n": 2.0}
K_A, I_A, K_S, P_EXP, K_H, K_N = param_offsets(PARAMS)


@njit(cache=True, inline="always")
def fragment(p, n0, v, uv, t, kd, lp, li, prm, tex, hmap, cube):
    n = bump_normal(n0, t, v, uv, hmap, prm[K_H], prm[K_N])
    return blinn_phong(p, n, v, kd, lp, li, prm[K_A], vec3(prm, I_A), prm[K_S], prm[P_EXP])


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


SHADER = Shader("bump", fragment, PARAMS, textures=("height_map",), doc=__doc__, stage=stage)
