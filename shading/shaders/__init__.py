"""Shaders, discovered from the modules of this package.

A shader module defines `SHADER = Shader(...)`:
  name       the name used in scenes and on the command line (defaults to the module)
  fragment   an @njit(inline="always") colour function
             fragment(p, n0, v, uv, t, kd, lp, li, prm, tex, hmap, cube) -> (r, g, b)
             p position, n0 = normalize(interpolated normal) (NOT yet two-sided: use
             lighting.two_sided(n0, v)), v unit vector to the eye, uv, t =
             normalize(interpolated tangent), kd object colour, lp / li light position
             and intensity (tuples), prm the packed params (float64 array, see
             `param_offsets`), tex (h,w,3) colour texture, hmap (h,w,3) height map (red
             channel), cube (6,s,s,3) cube map. Colours are clamped by the caller.
  stage      the shader's fragment stage: an @njit(**shade.STAGE) kernel
             stage(frame, g, prm, tex, hmap, cube) over the rows of group g, the
             few-line loop of shade.py's docstring calling `fragment` (copy it from any
             shader module). Cached on disk, so a new process loads it instead of
             compiling it. If None, one is built from `fragment` by shade.stage_for
             (compiled in every process: fine for experiments, not for shipping).
  params     ordered defaults {name: float or 3-tuple}; `render(..., params)` overrides
  vertex     optional vertex stage vertex(positions, normals, uvs, prm, hmap) -> new
             positions (V,3), run on every mesh before projection
  primitive  "triangles" (default) or "lines" (mesh edges instead of triangles)
  textures   the texture slots it reads: subset of ("texture", "height_map", "cubemap")
Adding a shader = adding one module here.
"""
from __future__ import annotations

import importlib
import pkgutil
from pathlib import Path
from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np


@dataclass(frozen=True)
class Shader:
    name: str
    fragment: Any
    params: dict = field(default_factory=dict)
    vertex: Callable | None = None
    primitive: str = "triangles"
    textures: tuple = ()
    doc: str = ""
    stage: Any = None

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


def _drop_stale_stage_caches() -> None:
    """numba keys a function's disk cache on its own file only, but every stage kernel
    inlines the helpers of shade.py, lighting.py and textures.py: when one of those
    changes, drop this package's cached kernels (in-tree cache only: installed packages
    are replaced whole)."""
    pkg = Path(__file__).resolve().parent
    cache = pkg / "__pycache__"
    try:
        stamp = ";".join(f"{f.name}:{f.stat().st_mtime_ns}:{f.stat().st_size}"
                         for f in (pkg.parent / n for n in _HELPERS))
        mark = cache / "helpers.stamp"
        if mark.is_file() and mark.read_text() == stamp:
            return
        for f in list(cache.glob("*.nbi")) + list(cache.glob("*.nbc")):
            f.unlink(missing_ok=True)
        cache.mkdir(exist_ok=True)
        mark.write_text(stamp)
    except OSError:  # read-only install or a race with another process: leave it
        pass


_HELPERS = ("shade.py", "lighting.py", "textures.py")


def _discover() -> dict:
    found = {}
    for info in sorted(pkgutil.iter_modules(__path__), key=lambda i: i.name):
        if info.name.startswith("_"):
            continue
        mod = importlib.import_module(f"{__name__}.{info.name}")
        sh = getattr(mod, "SHADER", None)
        if isinstance(sh, Shader):
            found[sh.name] = sh
    return found


_drop_stale_stage_caches()
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
