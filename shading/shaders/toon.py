"""toon: q = ceil(levels max(0, n.l)) / levels; s = 1 if max(0, n.h)^p > threshold;
colour = k_d (ambient + diffuse q) + spec s, times outline_factor where n.v < outline.
No distance fall-off (I and r are not used). With shadows and ambient occlusion, max(0, n.l)
and s are scaled by the light's visibility (before quantising) and ambient by the
occlusion factor."""
import math

from clothjit import njit

from ..lighting import dot, normalize, powf, sub, two_sided
from . import Shader, param_offsets

PARAMS = {"levels": 4.0, "ambient": 0.15, "diffuse": 0.85, "p": 100.0,
          "threshold": 0.5, "spec": 0.5, "outline": 0.2, "outline_factor": 0.2}
LEVELS, AMB, DIF, P_EXP, THR, SPEC, OUTL, OUTF = param_offsets(PARAMS)


@njit(cache=True, inline="always")
def fragment(p, n0, v, uv, t, kd, lp, li, prm, tex, hmap, cube, lit):
    n = two_sided(n0, v)
    l = normalize(sub(lp, p))
    h = normalize((l[0] + v[0], l[1] + v[1], l[2] + v[2]))
    q = math.ceil(prm[LEVELS] * (max(0.0, dot(n, l)) * lit[0])) / prm[LEVELS]
    s = (prm[SPEC] if powf(max(0.0, dot(n, h)), prm[P_EXP]) > prm[THR] else 0.0) * lit[0]
    f = prm[OUTF] if dot(n, v) < prm[OUTL] else 1.0
    a = prm[AMB] * lit[1] + prm[DIF] * q
    return ((kd[0] * a + s) * f, (kd[1] * a + s) * f, (kd[2] * a + s) * f)


SHADER = Shader("toon", fragment, PARAMS, doc=__doc__)
