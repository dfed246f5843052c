"""mirror: w_i = 2 (v.n) n - v, colour = cube map along w_i (OpenGL face table), no
lighting (default cube map textures/cubemap/; RenderSettings.cubemap)."""
from clothjit import njit

from ..lighting import dot, two_sided
from ..textures import sample_cube
from . import Shader


@njit(cache=True, inline="always")
def fragment(p, n0, v, uv, t, kd, lp, li, prm, tex, hmap, cube, lit):
    n = two_sided(n0, v)
    d = 2.0 * dot(v, n)
    return sample_cube(cube, (d * n[0] - v[0], d * n[1] - v[1], d * n[2] - v[2]))


SHADER = Shader("mirror", fragment, textures=("cubemap",), lit=(), doc=__doc__)
