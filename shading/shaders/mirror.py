"""mirror: w_i = 2 (v.n) n - v, colour = cube map along w_i (OpenGL face table), no
lighting (default cube map textures/cubemap/; RenderSettings.cubemap)."""
from numba import njit

from ..lighting import dot, two_sided
from ..textures import sample_cube
from ..shade import STAGE, ZERO, add, begin_row, fetch, put, sample
from . import Shader


@njit(cache=True, inline="always")
def fragment(p, n0, v, uv, t, kd, lp, li, prm, tex, hmap, cube):
    n = two_sided(n0, v)
    d = 2.0 * dot(v, n)
    return sample_cube(cube, (d * n[0] - v[0], d * n[1] - v[1], d * n[2] - v[2]))


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


SHADER = Shader("mirror", fragment, textures=("cubemap",), doc=__doc__, stage=stage)
