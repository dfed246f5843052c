"""displacement: every vertex moves to p + n h(uv) k_h before projection; fragments are
shaded as bump at the displaced position with the undisplaced normal and tangent."""
import numpy as np
from clothjit import njit, read_only

from ..textures import bilinear
from . import Shader
from .bump import K_H, PARAMS, fragment


@njit(cache=True, nogil=True)
def _displace(pos, nrm, uvs, kh, hmap, out):
    for i in range(pos.shape[0]):
        h = bilinear(hmap, uvs[i, 0], uvs[i, 1], True)[0] * kh
        for k in range(3):
            out[i, k] = pos[i, k] + nrm[i, k] * h


def vertex(positions, normals, uvs, prm, hmap, out=None):
    if out is None:
        out = np.empty_like(positions)
    _displace(read_only(positions), read_only(normals), uvs, prm[K_H], hmap, out)
    return out


SHADER = Shader("displacement", fragment, PARAMS, vertex=vertex, textures=("height_map",),
                doc=__doc__)  # fragments shaded exactly as bump
