"""Shaders, discovered from the modules of this package.

A shader module defines `SHADER = Shader(...)`:
  name       the name used in scenes and on the command line (defaults to the module)
  fragment   an @njit(cache=True, inline="always") colour function
             fragment(p, n0, v, uv, t, kd, lp, li, prm, tex, hmap, cube, lit) -> (r, g, b)
             p position, n0 = normalize(interpolated normal) (NOT yet two-sided: use
             lighting.two_sided(n0, v)), v unit vector to the eye, uv, t =
             normalize(interpolated tangent), kd object colour, lp / li light position
             and intensity (tuples), prm the packed params (float64 array, see
             `param_offsets`), tex (h,w,3) colour texture, hmap (h,w,3) height map (red
             channel), cube (6,s,s,3) cube map, lit = (vis, ao) the light's visibility
             (shadows: it scales the diffuse and specular terms) and the ambient
             occlusion factor (it scales the ambient term), both exactly 1 when off.
             Colours are clamped by the caller.
  params     ordered defaults {name: float or 3-tuple}; `render(..., params)` overrides
  vertex     optional vertex stage vertex(positions, normals, uvs, prm, hmap) -> new
             positions (V,3), run on every mesh before projection
  primitive  "triangles" (default) or "lines" (mesh edges instead of triangles)
  textures   the texture slots it reads: subset of ("texture", "height_map", "cubemap")
  lit        the factors of `lit` its fragment reads: subset of ("shadows", "occlusion")
             (default both); the renderer computes neither the shadow map nor the
             occlusion for a frame whose shaders do not read it (they cost nothing there)
  dark       True when its colour is exactly black where the light's visibility is 0
             (every term scaled by it, no ambient term): with shadows the fragment stage
             then skips such samples, whose colour the look-ups already decided
Adding a shader = adding one module here. The fragment stage (shade.fragment_stage, one
loop for every shader) is compiled once per shader with its fragment inlined, and cached;
a Shader made at run time outside this package works too, compiled once per process.
"""
from __future__ import annotations

import importlib
import pkgutil
from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np

from ..shade import shader_key


@dataclass(frozen=True)
class Shader:
    name: str
    fragment: Any
    params: dict = field(default_factory=dict)
    vertex: Callable | None = None
    primitive: str = "triangles"
    textures: tuple = ()
    lit: tuple = ("shadows", "occlusion")
    dark: bool = False
    doc: str = ""
    key: Any = field(default=None, compare=False, repr=False)  # shade.ShaderKey, see stage_key

    def stage_key(self):
        """This shader's key for shade.fragment_stage (a run-time key if not registered)."""
        if self.key is None:
            object.__setattr__(self, "key", shader_key(self.name, self.fragment, False))
        return self.key

    def pack(self, overrides: dict | None = None) -> np.ndarray:
        """Defaults overridden by `overrides` (unknown keys ignored), as a flat array."""
        vals = []
        for k, d in self.params.items():
            v = d if overrides is None or k not in overrides else overrides[k]
            a = np.atleast_1d(np.asarray(v, dtype=np.float64)).ravel()
            dn = np.atleast_1d(np.asarray(d)).size
            if a.size == 1 and dn == 3:
                a = np.repeat(a, 3)
            if a.size != dn:
                raise ValueError(f"shader {self.name}: param {k!r} needs {dn} value(s), "
                                 f"got {a.size}")
            if not np.all(np.isfinite(a)):
                raise ValueError(f"shader {self.name}: param {k!r} must be finite")
            vals.append(a)
        return np.concatenate(vals) if vals else np.zeros(1)


def param_offsets(params: dict) -> tuple:
    """Offsets of each parameter in the packed array, in order (for the fragment)."""
    offs, o = [], 0
    for v in params.values():
        offs.append(o)
        o += np.atleast_1d(np.asarray(v)).size
    return tuple(offs)


def _discover() -> dict:
    found = {}
    for info in sorted(pkgutil.iter_modules(__path__), key=lambda i: i.name):
        if info.name.startswith("_"):
            continue
        mod = importlib.import_module(f"{__name__}.{info.name}")
        sh = getattr(mod, "SHADER", None)
        if isinstance(sh, Shader):
            # keyed by the fragment, so shaders sharing one (bump, displacement) share its kernel
            frag = sh.fragment.py_func
            object.__setattr__(sh, "key", shader_key(f"{frag.__module__}.{frag.__qualname__}",
                                                     sh.fragment, True))
            found[sh.name] = sh
    return found


REGISTRY: dict = _discover()
SHADERS: tuple = tuple(REGISTRY)


def get_shader(name_or_shader) -> Shader:
    if isinstance(name_or_shader, Shader):
        return name_or_shader
    try:
        return REGISTRY[name_or_shader]
    except KeyError:
        raise ValueError(f"unknown shader {name_or_shader!r}; expected one of "
                         f"{', '.join(SHADERS)}") from None
