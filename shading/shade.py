"""Deferred shading over the visibility buffer: the fragment stage of every shader (SPEC
4-5), numba, cached.

One kernel, `fragment_stage`, is the fragment stage of every shader: for each output row of
its group (`begin_row` fills the background outside the row's covered span), each covered
sample (`sample`, `fetch`) is shaded by the shader's colour function `fragment`
(shaders/phong.py), clamped and summed (`add`), and each pixel's aa x aa samples are box
filtered to 8 bits (`put`).

The shader is an argument, a `ShaderKey`: an int that numba types as its literal value, so
numba compiles the kernel once per shader with that shader's fragment inlined (as if each
shader had its own copy of the loop), and caches each on disk under the key. A registered
shader's key is a checksum of its fragment's name and of the sources it is built from
(`shader_key`), so editing a shader or a helper gives a new key rather than a stale kernel.
A shader made at run time (not a module of shading/shaders) gets a negative key and the
uncached twin of the kernel (`uncached_fragment_stage`): compiled once per process.

The renderer runs groups 0 .. f.groups - 1 on as many threads (the GIL is released), so
each output row has one owner and the image is the same for any number of threads.
(Not a numba prange: numba's parfor pass mishandles the tuples these helpers use.)
`f` is a `Frame` (the visibility buffer, the vertex attributes, the light, the output
image); `fetch` interpolates a sample's inputs: p position, n0 = normalize(interpolated
normal) (not yet two-sided), v unit vector to the eye, uv, t = normalize(interpolated
tangent), kd the object colour (perspective-correct weights from the rasteriser);
`add` clamps a colour to [0, 1] and accumulates it, `put` box filters the aa x aa
samples of a pixel and writes 8 bits, rounded to nearest. `begin_row` also means the
background costs a fill, not a look-up per sample.

`fetch` and `begin_row` (and the larger helpers of the fragments: `blinn_phong`,
`bump_normal`, `sample_cube`) are kernels of their own, compiled once for every shader with
the stage's options (`jit.STAGE`: the same arithmetic as inlined) and called, not inlined
into each shader's copy of the loop: numba's inlining re-types the whole loop per inlined
call, so this halves a shader's first compile (all nine: 69 s to 34-40 s, 2026-11-24),
with the same images and no measured change in speed (LLVM may still inline them).
"""
from __future__ import annotations

import itertools
import math
import zlib
from collections import namedtuple
from pathlib import Path

import numpy as np
from numba.core import types
from numba.extending import overload, typeof_impl

from clothjit import STAGE, njit

from .lighting import normalize

Frame = namedtuple("Frame", [
    "height", "width", "aa", "groups",  # output size, supersampling, row groups (threads)
    "prim", "bary",  # visibility buffer: int32 (S,), float32 (S, 2), row-major samples
    "rowlo", "rowhi",  # int32 (sample rows,): span of samples written per sample row
    "verts", "obj_of",  # int32 (prims, 3) vertex ids, int32 (prims,) object id
    "va",  # float64 (V, 12): position 0:3, normal 3:6, uv 6:8, tangent 8:11
    "kd",  # float64 (objects, 3)
    "eye", "lp", "li", "bg",  # 3-tuples of float
    "out",  # uint8 (height, width, 3)
    "occ",  # float32 (height * width,): ambient occlusion factor per pixel; (0,) when off
    "vis",  # float32 (S,): the light's visibility per sample (shadow.py); (0,) when off
    # objects of several shaders: per object its pass (int32; (0,): one shader), this
    # pass and how many, each pixel's sum so far (float64 (height * width, 3))
    "obj_pass", "pass_id", "passes", "acc",
])

ZERO = (0.0, 0.0, 0.0)


@njit(cache=True, inline="always")
def sample(f, y, x, k):
    """Index of sample k (row-major within the pixel) of output pixel (x, y)."""
    if f.aa == 1:
        return y * f.width + x
    return (y * f.aa + k // f.aa) * (f.width * f.aa) + x * f.aa + k % f.aa


@njit(cache=True, inline="always")
def add(c, col):
    """c + col clamped to [0, 1]."""
    return (c[0] + min(max(col[0], 0.0), 1.0),
            c[1] + min(max(col[1], 0.0), 1.0),
            c[2] + min(max(col[2], 0.0), 1.0))


@njit(cache=True, inline="always")
def put(f, y, x, c):
    """Box filter of the accumulated samples, 8 bits, round to nearest."""
    inv = 1.0 / (f.aa * f.aa)
    f.out[y, x, 0] = int(math.floor(c[0] * inv * 255.0 + 0.5))
    f.out[y, x, 1] = int(math.floor(c[1] * inv * 255.0 + 0.5))
    f.out[y, x, 2] = int(math.floor(c[2] * inv * 255.0 + 0.5))


@njit(**STAGE, no_cpython_wrapper=True)
def covered_span(f, y):
    """Pixels [x0, x1) of output row y that hold every written sample of the row
    (x0 = x1 = width: none)."""
    aa = f.aa
    lo = f.width * aa
    hi = -1
    for sy in range(y * aa, y * aa + aa):
        lo = min(lo, f.rowlo[sy])
        hi = max(hi, f.rowhi[sy])
    if lo > hi:
        return f.width, f.width
    return lo // aa, hi // aa + 1


@njit(**STAGE, no_cpython_wrapper=True)
def begin_row(f, y):
    """Pixels [x0, x1) of output row y that have a written sample; every other pixel of
    the row is set to the background (as `put` would from aa x aa background samples)."""
    aa = f.aa
    x0, x1 = covered_span(f, y)
    c = ZERO
    for k in range(aa * aa):
        c = add(c, f.bg)
    inv = 1.0 / (aa * aa)
    r = np.uint8(math.floor(c[0] * inv * 255.0 + 0.5))
    g = np.uint8(math.floor(c[1] * inv * 255.0 + 0.5))
    b = np.uint8(math.floor(c[2] * inv * 255.0 + 0.5))
    out = f.out
    for x in range(0, x0):
        out[y, x, 0] = r
        out[y, x, 1] = g
        out[y, x, 2] = b
    for x in range(x1, f.width):
        out[y, x, 0] = r
        out[y, x, 1] = g
        out[y, x, 2] = b
    if x0 == f.width:
        return 0, 0
    return x0, x1


@njit(**STAGE, no_cpython_wrapper=True)
def fetch(f, s):
    """(p, n0, v, uv, t, kd) of the covered sample s (f.prim[s] >= 0)."""
    m = f.prim[s]
    i0 = f.verts[m, 0]
    i1 = f.verts[m, 1]
    i2 = f.verts[m, 2]
    b1 = np.float64(f.bary[s, 0])
    b2 = np.float64(f.bary[s, 1])
    b0 = 1.0 - b1 - b2
    a = f.va
    p = (b0 * a[i0, 0] + b1 * a[i1, 0] + b2 * a[i2, 0],
         b0 * a[i0, 1] + b1 * a[i1, 1] + b2 * a[i2, 1],
         b0 * a[i0, 2] + b1 * a[i1, 2] + b2 * a[i2, 2])
    n0 = normalize((b0 * a[i0, 3] + b1 * a[i1, 3] + b2 * a[i2, 3],
                    b0 * a[i0, 4] + b1 * a[i1, 4] + b2 * a[i2, 4],
                    b0 * a[i0, 5] + b1 * a[i1, 5] + b2 * a[i2, 5]))
    uv = (b0 * a[i0, 6] + b1 * a[i1, 6] + b2 * a[i2, 6],
          b0 * a[i0, 7] + b1 * a[i1, 7] + b2 * a[i2, 7])
    t = normalize((b0 * a[i0, 8] + b1 * a[i1, 8] + b2 * a[i2, 8],
                   b0 * a[i0, 9] + b1 * a[i1, 9] + b2 * a[i2, 9],
                   b0 * a[i0, 10] + b1 * a[i1, 10] + b2 * a[i2, 10]))
    e = f.eye
    v = normalize((e[0] - p[0], e[1] - p[1], e[2] - p[2]))
    o = f.obj_of[m]
    kd = (f.kd[o, 0], f.kd[o, 1], f.kd[o, 2])
    return p, n0, v, uv, t, kd


@njit(**STAGE, no_cpython_wrapper=True, _nrt=False)
def accumulate(acc, i, pass_id, passes, c):
    """With objects of several shaders: pixel i's colour so far, c (pass pass_id's
    samples) plus the earlier passes' sum, kept in acc for the passes after this one.
    Without reference counts: counting them at a call per pixel (or this inlined in the
    pixel loop) made such frames 6x slower."""
    if pass_id > 0:
        c = (c[0] + acc[i, 0], c[1] + acc[i, 1], c[2] + acc[i, 2])
    if pass_id < passes - 1:
        acc[i, 0] = c[0]
        acc[i, 1] = c[1]
        acc[i, 2] = c[2]
    return c


class ShaderKey(int):
    """A shader's key for `fragment_stage`: numba types it as its literal value."""


@typeof_impl.register(ShaderKey)
def _typeof_shader_key(value, context):
    return types.IntegerLiteral(int(value))


_FRAGMENTS: dict[int, object] = {}  # key -> fragment (an @njit colour function)
_run_time_keys = itertools.count(-1, -1)
_SOURCES = ("lighting.py", "textures.py")  # helpers a fragment inlines


def shader_key(name: str, fragment, registered: bool) -> ShaderKey:
    """The key of a shader's `fragment`: for a module of shading/shaders (`registered`), a
    checksum of `name` (the fragment's qualified name) and of the sources a fragment can
    inline (every shader module and the helpers); else a new negative key of this
    process."""
    if registered:
        here = Path(__file__).resolve().parent
        files = sorted((here / "shaders").glob("*.py")) + [here / n for n in _SOURCES]
        key = zlib.crc32(name.encode())
        for path in files:
            key = zlib.crc32(path.read_bytes(), key)
    else:
        key = next(_run_time_keys)
    _FRAGMENTS[key] = fragment
    return ShaderKey(key)


def _colour(key, p, n0, v, uv, t, kd, lp, li, prm, tex, hmap, cube, lit):
    """The colour of a sample by shader `key` (a stub: numba compiles the overload)."""
    raise NotImplementedError("only callable from numba")


@overload(_colour, inline="always", jit_options=dict(STAGE, cache=False))
def _colour_overload(key, p, n0, v, uv, t, kd, lp, li, prm, tex, hmap, cube, lit):
    if not isinstance(key, types.IntegerLiteral):
        return None  # numba retries with the literal
    fragment = _FRAGMENTS[key.literal_value]

    def colour(key, p, n0, v, uv, t, kd, lp, li, prm, tex, hmap, cube, lit):
        return fragment(p, n0, v, uv, t, kd, lp, li, prm, tex, hmap, cube, lit)
    return colour


def _fragment_stage(f, g, prm, tex, hmap, cube, key, extras):
    """The fragment stage of output rows g, g + f.groups, ... by the shader `key`.

    `extras` (a ShaderKey: numba compiles each value apart, so a frame without them runs
    the plain loop, none of their branches): 1 when the frame has shadows (f.vis), ambient
    occlusion (f.occ) or objects of several shaders (f.obj_pass); 2 as 1, with shadows and
    a `dark` shader: a sample the light does not reach adds black without being shaded.
    With several shaders the stage runs once per shader, pass f.pass_id of f.passes, and
    shades only the samples of the objects of its pass (and the background, in pass 0);
    each pixel's sum is kept in f.acc between passes (`accumulate`). Every pass writes the
    pixel, the last one its final colour: a pixel loop without a branch around `put` (with
    one, the loop ran 5-15 % slower, even with a single shader)."""
    multi = extras and f.obj_pass.shape[0] > 0
    for y in range(g, f.height, f.groups):
        x0, x1 = begin_row(f, y)
        for x in range(x0, x1):
            c = ZERO
            for k in range(f.aa * f.aa):
                s = sample(f, y, x, k)
                if f.prim[s] < 0:
                    if not multi or f.pass_id == 0:
                        c = add(c, f.bg)
                elif multi and f.obj_pass[f.obj_of[f.prim[s]]] != f.pass_id:
                    continue
                elif extras == 2 and f.vis[s] == 0.0:
                    continue  # the colour's every term is scaled by 0
                else:
                    p, n0, v, uv, t, kd = fetch(f, s)
                    lit = (1.0, 1.0)
                    if extras:
                        lit = (np.float64(f.vis[s]) if f.vis.shape[0] else 1.0,
                               np.float64(f.occ[y * f.width + x]) if f.occ.shape[0] else 1.0)
                    c = add(c, _colour(key, p, n0, v, uv, t, kd, f.lp, f.li, prm, tex, hmap,
                                       cube, lit))
            if extras and multi:
                c = accumulate(f.acc, y * f.width + x, f.pass_id, f.passes, c)
            put(f, y, x, c)


fragment_stage = njit(**STAGE)(_fragment_stage)
uncached_fragment_stage = njit(**dict(STAGE, cache=False))(_fragment_stage)
