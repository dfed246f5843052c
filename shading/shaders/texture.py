"""texture: bilinear sample of the colour texture at uv, wrap repeat, no mipmaps,
no lighting (the default texture is textures/cloth.png; RenderSettings.texture)."""
from clothjit import njit

from ..textures import bilinear
from . import Shader


@njit(cache=True, inline="always")
def fragment(p, n0, v, uv, t, kd, lp, li, prm, tex, hmap, cube, lit):
    return bilinear(tex, uv[0], uv[1], True)


SHADER = Shader("texture", fragment, textures=("texture",), lit=(), doc=__doc__)
