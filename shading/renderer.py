"""Renderer: owns every per-frame buffer (visibility buffer, primitive arrays, output
image) for one image size, so rendering a frame allocates nothing large.

    r = Renderer(800, 800, aa=1)
    img = r.render(meshes, camera, light, "phong", params)   # r.image, reused

`params` (all optional): the shader constants (SPEC 5 names: k_a, I_a, k_s, p, k_h,
k_n, ...; see each shader's PARAMS), "background" (rgb), "texture", "height_map" (image
paths or (h,w,3) arrays), "cubemap" (folder with posx..negz.png or a (6,s,s,3) array),
"light_position", "light_intensity" (override `light`). Unknown keys are ignored.
"""
from __future__ import annotations

import threading
from concurrent.futures import ThreadPoolExecutor

import numba
import numpy as np

from . import raster as R
from .camera import Camera
from .shade import shade_rows
from .shaders import get_shader
from .textures import resolve

DEFAULT_LIGHT_POSITION = (0.5, 2.0, 2.0)
DEFAULT_LIGHT_INTENSITY = (3.0, 3.0, 3.0)
DEFAULT_BACKGROUND = (0.2, 0.25, 0.3)
_DUMMY_TEX = np.zeros((1, 1, 3))
_DUMMY_CUBE = np.zeros((6, 1, 1, 3))
_DUMMY_TEX.flags.writeable = False  # same numba type as loaded (read-only) textures
_DUMMY_CUBE.flags.writeable = False


def _vec3(v, what):
    a = np.asarray(v, dtype=np.float64).ravel()
    if a.size == 1:
        a = np.repeat(a, 3)
    if a.size != 3 or not np.all(np.isfinite(a)):
        raise ValueError(f"{what} must be 3 finite numbers, got {v!r}")
    return (float(a[0]), float(a[1]), float(a[2]))


def _grow(arr, n, shape_tail=(), dtype=None):
    if arr is not None and arr.shape[0] >= n:
        return arr
    cap = max(n, 16, 0 if arr is None else int(arr.shape[0] * 1.5))
    return np.empty((cap,) + shape_tail, dtype=dtype if dtype else arr.dtype)


class Renderer:
    """Buffers for width x height images with aa x aa supersampling."""

    def __init__(self, width: int, height: int, aa: int = 1):
        aa = int(aa)
        if aa < 1:
            raise ValueError(f"aa must be >= 1, got {aa}")
        self.width, self.height, self.aa = int(width), int(height), aa
        self.sw, self.sh = self.width * aa, self.height * aa
        ns = self.sw * self.sh
        self.depth = np.empty(ns)
        self.prim = np.empty(ns, np.int32)
        self.bary = np.empty((ns, 2))
        self.count = np.zeros(1, np.int32)  # replaced by a per-sample buffer on demand
        self.image = np.empty((self.height, self.width, 3), np.uint8)
        self.band_h = R.BAND
        self.nb = (self.sh + self.band_h - 1) // self.band_h
        self.band_start = np.empty(self.nb + 1, np.int64)
        self.items = np.empty(1024, np.int64)
        self._prims(1024)
        self.P = self.N = self.UV = self.TG = self.clip = None
        self.verts = self.obj_of = None
        self.n_prims = 0

    def _prims(self, cap):
        self.px = np.empty((cap, 3), np.int64)
        self.py = np.empty((cap, 3), np.int64)
        self.pz = np.empty((cap, 3))
        self.piw = np.empty((cap, 3))
        self.pb = np.empty((cap, 3, 3))
        self.psrc = np.empty(cap, np.int32)
        self.pbox = np.empty((cap, 4), np.int64)

    def _gather(self, meshes, shader, prm, hmap):
        lines = shader.primitive == "lines"
        nv = sum(m.positions.shape[0] for m in meshes)
        if lines:
            npr = sum(0 if m.edges is None else m.edges.shape[0] for m in meshes)
        else:
            npr = sum(m.triangles.shape[0] for m in meshes)
        self.P = _grow(self.P, nv, (3,), np.float64)
        self.N = _grow(self.N, nv, (3,), np.float64)
        self.UV = _grow(self.UV, nv, (2,), np.float64)
        self.TG = _grow(self.TG, nv, (3,), np.float64)
        self.clip = _grow(self.clip, nv, (4,), np.float64)
        self.verts = _grow(self.verts, max(npr, 1), (3,), np.int32)
        self.obj_of = _grow(self.obj_of, max(npr, 1), (), np.int32)
        kd = np.empty((max(len(meshes), 1), 3))
        v = p = 0
        for i, m in enumerate(meshes):
            n = m.positions.shape[0]
            if shader.vertex is not None:
                shader.vertex(m.positions, m.normals, m.uvs, prm, hmap, out=self.P[v:v + n])
            else:
                self.P[v:v + n] = m.positions
            self.N[v:v + n] = m.normals
            self.UV[v:v + n] = m.uvs
            self.TG[v:v + n] = m.tangents
            if lines:
                if m.edges is not None:
                    k = m.edges.shape[0]
                    self.verts[p:p + k, 0] = m.edges[:, 0] + v
                    self.verts[p:p + k, 1] = m.edges[:, 1] + v
                    self.verts[p:p + k, 2] = m.edges[:, 1] + v
                    self.obj_of[p:p + k] = i
                    p += k
            else:
                k = m.triangles.shape[0]
                np.add(m.triangles, v, out=self.verts[p:p + k])
                self.obj_of[p:p + k] = i
                p += k
            kd[i] = m.colour
            v += n
        return nv, npr, kd

    def render(self, meshes, camera: Camera, light=None, shader="phong", params=None, *,
               count_coverage=False) -> np.ndarray:
        """Render into self.image (returned; overwritten by the next call).

        count_coverage=True also fills self.count (per sample, row-major) with the number
        of fragments each sample received (before the depth test): a debugging aid.
        """
        if (camera.width, camera.height) != (self.width, self.height):
            raise ValueError(f"camera is {camera.width}x{camera.height}, renderer "
                             f"{self.width}x{self.height}")
        sh = get_shader(shader)
        params = {} if params is None else dict(params)
        prm = sh.pack(params)
        tex = resolve("texture", params.get("texture")) if "texture" in sh.textures else _DUMMY_TEX
        hmap = (resolve("height_map", params.get("height_map"))
                if "height_map" in sh.textures else _DUMMY_TEX)
        cube = resolve("cubemap", params.get("cubemap")) if "cubemap" in sh.textures else _DUMMY_CUBE
        lp = getattr(light, "position", DEFAULT_LIGHT_POSITION) if light is not None \
            else DEFAULT_LIGHT_POSITION
        li = getattr(light, "intensity", DEFAULT_LIGHT_INTENSITY) if light is not None \
            else DEFAULT_LIGHT_INTENSITY
        lp = _vec3(params.get("light_position", lp), "light position")
        li = _vec3(params.get("light_intensity", li), "light intensity")
        bg = _vec3(params.get("background", DEFAULT_BACKGROUND), "background")
        lines = sh.primitive == "lines"

        nv, npr, kd = self._gather(meshes, sh, prm, hmap)
        P, clip, verts = self.P[:nv], self.clip[:nv], self.verts[:npr]
        vp = np.ascontiguousarray(camera.view_projection())
        if nv:
            R.transform(P, vp, clip)
        while True:
            if lines:
                m = R.setup_lines(clip, verts, self.sw, self.sh, self.aa, self.px, self.py,
                                  self.pz, self.piw, self.pb, self.psrc, self.pbox)
            else:
                m = R.setup_triangles(clip, verts, self.sw, self.sh, self.px, self.py,
                                      self.pz, self.piw, self.pb, self.psrc, self.pbox)
            if m <= self.px.shape[0]:
                break
            self._prims(int(m * 1.25) + 16)
        self.n_prims = m
        while True:
            total = R.bin_prims(self.pbox, m, self.band_h, self.nb, self.band_start, self.items)
            if total <= self.items.shape[0]:
                break
            self.items = np.empty(int(total * 1.25) + 16, np.int64)
        if count_coverage and self.count.shape[0] != self.depth.shape[0]:
            self.count = np.zeros(self.depth.shape[0], np.int32)
        old = numba.get_parallel_chunksize()
        numba.set_parallel_chunksize(1)
        try:
            R.raster(lines, self.aa, self.nb, self.band_h, self.sw, self.sh, self.band_start,
                     self.items, self.px, self.py, self.pz, self.piw, self.pb, self.psrc,
                     self.pbox, self.depth, self.prim, self.bary, self.count, count_coverage)
        finally:
            numba.set_parallel_chunksize(old)
        args = (self.width, self.aa, self.prim, self.bary, self.verts, self.P, self.N,
                self.UV, self.TG, self.obj_of, kd, tuple(float(x) for x in camera.eye),
                lp, li, prm, tex, hmap, cube, bg, self.image)
        _run_rows(sh.fragment, self.height, args)
        return self.image


_pool = None
_pool_lock = threading.Lock()


def _threads() -> int:
    return max(1, numba.config.NUMBA_NUM_THREADS)


def _run_rows(frag, height, args):
    """Shade every row: interleaved row sets (row k goes to set k mod n) on a thread
    pool, GIL released inside the kernel. Each pixel is written by exactly one task."""
    n = _threads()
    if n == 1 or height < 2 * n:
        shade_rows(frag, 0, height, 1, *args)
        return
    global _pool
    with _pool_lock:
        if _pool is None:
            _pool = ThreadPoolExecutor(max_workers=n - 1, thread_name_prefix="shade")
    futs = [_pool.submit(shade_rows, frag, k, height, n, *args) for k in range(1, n)]
    shade_rows(frag, 0, height, n, *args)
    for f in futs:
        f.result()


_renderers: dict = {}


def get_renderer(width, height, aa=1) -> Renderer:
    key = (int(width), int(height), int(aa))
    r = _renderers.get(key)
    if r is None:
        if len(_renderers) >= 4:
            _renderers.pop(next(iter(_renderers)))
        r = _renderers[key] = Renderer(*key)
    return r


def render(meshes, camera: Camera, light=None, shader="phong", params=None) -> np.ndarray:
    """Render `meshes` (drawn in list order) seen by `camera` into a new (H, W, 3) uint8
    image. The size is camera.width x camera.height; params["aa"] (default 1) is the
    supersampling factor; other params as in `Renderer`. Buffers are cached per size."""
    aa = int((params or {}).get("aa", 1))
    r = get_renderer(camera.width, camera.height, aa)
    return r.render(meshes, camera, light, shader, params).copy()
