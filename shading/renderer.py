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

import math
import threading
import time
from concurrent.futures import ThreadPoolExecutor

import numba
import numpy as np
from clothjit import njit

from . import raster as R
from .camera import Camera
from .shade import Frame, fragment_stage, uncached_fragment_stage
from .shaders import get_shader
from .textures import resolve

DEFAULT_LIGHT_POSITION = (0.5, 2.0, 2.0)
DEFAULT_LIGHT_INTENSITY = (3.0, 3.0, 3.0)
DEFAULT_BACKGROUND = (0.2, 0.25, 0.3)
_DUMMY_TEX = np.zeros((1, 1, 3))
_DUMMY_CUBE = np.zeros((6, 1, 1, 3))
_DUMMY_TEX.flags.writeable = False  # same numba type as loaded (read-only) textures
_DUMMY_CUBE.flags.writeable = False
VA_COLS = 12  # position 0:3, normal 3:6, uv 6:8, tangent 8:11 (shade.Frame.va)


def _vec3(v, what):
    if isinstance(v, tuple) and len(v) == 3 and all(type(x) is float and math.isfinite(x)
                                                    for x in v):
        return v
    a = np.asarray(v, dtype=np.float64).ravel()
    if a.size == 1:
        a = np.repeat(a, 3)
    if a.size != 3 or not np.all(np.isfinite(a)):
        raise ValueError(f"{what} must be 3 finite numbers, got {v!r}")
    return (float(a[0]), float(a[1]), float(a[2]))


def _ro(a):
    """A read-only view (one numba type whatever the caller's flags) of a float64 /
    int32 C-contiguous array."""
    if a.flags.writeable:
        a = a.view()
        a.flags.writeable = False
    return a


@njit(cache=True, nogil=True)
def _pack_vertices(va, v0, pos, nrm, uv, tan):
    """va[v0 + i] = (position, normal, uv, tangent) of vertex i: one pass."""
    for i in range(pos.shape[0]):
        r = v0 + i
        va[r, 0] = pos[i, 0]
        va[r, 1] = pos[i, 1]
        va[r, 2] = pos[i, 2]
        va[r, 3] = nrm[i, 0]
        va[r, 4] = nrm[i, 1]
        va[r, 5] = nrm[i, 2]
        va[r, 6] = uv[i, 0]
        va[r, 7] = uv[i, 1]
        va[r, 8] = tan[i, 0]
        va[r, 9] = tan[i, 1]
        va[r, 10] = tan[i, 2]


@njit(cache=True, nogil=True)
def _pack_prims(verts, obj_of, p0, idx, v0, obj):
    """verts[p0 + k] = idx[k] + v0 (a line (a, b) becomes (a, b, b)), obj_of = obj."""
    last = idx.shape[1] - 1
    for k in range(idx.shape[0]):
        verts[p0 + k, 0] = idx[k, 0] + v0
        verts[p0 + k, 1] = idx[k, 1] + v0
        verts[p0 + k, 2] = idx[k, last] + v0
        obj_of[p0 + k] = obj


def _grow(arr, n, shape_tail=(), dtype=None):
    if arr is not None and arr.shape[0] >= n:
        return arr
    cap = max(n, 16, 0 if arr is None else int(arr.shape[0] * 1.5))
    return np.empty((cap,) + shape_tail, dtype=dtype if dtype else arr.dtype)


class Renderer:
    """Buffers for width x height images with aa x aa supersampling.

    Raster and fragment stage run on `threads` threads (default NUMBA_NUM_THREADS), each
    owning interleaved bands / rows: the image does not depend on the number."""

    def __init__(self, width: int, height: int, aa: int = 1):
        aa = int(aa)
        if aa < 1:
            raise ValueError(f"aa must be >= 1, got {aa}")
        self.width, self.height, self.aa = int(width), int(height), aa
        self.sw, self.sh = self.width * aa, self.height * aa
        ns = self.sw * self.sh
        # visibility buffer (raster.py); rowlo/rowhi = the whole row: first frame clears all
        self.depth = np.full(ns, np.inf)
        self.prim = np.full(ns, -1, np.int32)
        self.bary = np.zeros((ns, 2), np.float32)
        self.rowlo = np.zeros(self.sh, np.int32)
        self.rowhi = np.full(self.sh, self.sw - 1, np.int32)
        self.count = np.zeros(1, np.int32)  # replaced by a per-sample buffer on demand
        self.image = np.empty((self.height, self.width, 3), np.uint8)
        self.band_h = R.BAND
        self.nb = (self.sh + self.band_h - 1) // self.band_h
        self.band_start = np.zeros(self.nb + 1, np.int64)
        self.items = np.empty(1024, np.int64)
        self._prims(1024)
        self.va = self.clip = self.vcode = self.vx = self.vy = self.vz = self.viw = None
        self.verts = self.obj_of = self.disp = None
        self.wb = np.empty((256, 3))
        self.n_prims = 0
        self.threads = None  # None: numba.get_num_threads() (NUMBA_NUM_THREADS)

    def _prims(self, cap):
        self.pv = np.empty((cap, 3), np.int32)
        self.pflag = np.empty(cap, np.int8)
        self.psrc = np.empty(cap, np.int32)
        self.pbox = np.empty((cap, 4), np.int64)

    def _vertices(self, cap):
        """Window-space vertex slots: the mesh vertices, then the ones made by clipping."""
        self.vx = np.empty(cap, np.int64)
        self.vy = np.empty(cap, np.int64)
        self.vz = np.empty(cap)
        self.viw = np.empty(cap)
        self.wb = np.empty((cap, 3))  # row e: source weights of slot nv + e (<= cap)

    def _gather(self, meshes, shader, prm, hmap):
        lines = shader.primitive == "lines"
        nv = npr = 0
        for m in meshes:
            nv += m.positions.shape[0]
            if lines:
                npr += 0 if m.edges is None else m.edges.shape[0]
            else:
                npr += m.triangles.shape[0]
        if self.va is None or self.va.shape[0] < nv:
            self.va = _grow(self.va, nv, (VA_COLS,), np.float64)
            self.va[:, 11] = 0.0
            self.clip = np.empty((self.va.shape[0], 4))
            self.vcode = np.empty(self.va.shape[0], np.int32)
        if self.vx is None or self.vx.shape[0] < nv + 64:
            self._vertices(nv + max(1024, nv // 4))
        self.verts = _grow(self.verts, max(npr, 1), (3,), np.int32)
        self.obj_of = _grow(self.obj_of, max(npr, 1), (), np.int32)
        kd = np.empty((max(len(meshes), 1), 3))
        va, verts = self.va, self.verts
        v = p = 0
        for i, m in enumerate(meshes):
            n = m.positions.shape[0]
            pos = m.positions
            if shader.vertex is not None:
                self.disp = _grow(self.disp, n, (3,), np.float64)
                pos = shader.vertex(m.positions, m.normals, m.uvs, prm, hmap, out=self.disp[:n])
            _pack_vertices(va, v, _ro(pos), _ro(m.normals), _ro(m.uvs), _ro(m.tangents))
            if lines:
                if m.edges is not None:
                    k = m.edges.shape[0]
                    _pack_prims(verts, self.obj_of, p, _ro(m.edges), v, i)
                    p += k
            else:
                k = m.triangles.shape[0]
                _pack_prims(verts, self.obj_of, p, _ro(m.triangles), v, i)
                p += k
            kd[i] = m.colour
            v += n
        return nv, npr, kd

    def render(self, meshes, camera: Camera, light=None, shader="phong", params=None, *,
               count_coverage=False, timings: dict | None = None) -> np.ndarray:
        """Render into self.image (returned; overwritten by the next call).

        count_coverage=True also fills self.count (per sample, row-major) with the number
        of fragments each sample received (before the depth test): a debugging aid.
        timings: a dict that receives the seconds spent in each stage ("prepare",
        "gather", "geometry" = project + setup + binning, "raster", "shade").
        """
        clock = time.perf_counter if timings is not None else None
        if clock:
            t0 = clock()
        if (camera.width, camera.height) != (self.width, self.height):
            raise ValueError(f"camera is {camera.width}x{camera.height}, renderer "
                             f"{self.width}x{self.height}")
        sh = get_shader(shader)
        params = {} if params is None else params
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
        key = sh.stage_key()
        stage = fragment_stage if key >= 0 else uncached_fragment_stage
        if clock:
            t1 = clock()
        nv, npr, kd = self._gather(meshes, sh, prm, hmap)
        if clock:
            t2 = clock()
        W, H = self.sw, self.sh
        vp = camera.view_projection()
        setup = R.setup_lines if lines else R.setup_triangles
        extra = (self.aa,) if lines else ()
        projected = None
        while True:
            if projected is not self.vx:  # (again if the vertex slots were reallocated)
                R.project(self.va[:nv], vp, W, H, self.clip, self.vcode, self.vx, self.vy,
                          self.vz, self.viw)
                projected = self.vx
            m, e = setup(self.verts[:npr], self.clip, self.vcode, nv, W, H, *extra, self.vx,
                         self.vy, self.vz, self.viw, self.wb, self.pv, self.pflag, self.psrc,
                         self.pbox, self.band_start)
            if m <= self.pv.shape[0] and nv + e <= self.vx.shape[0]:
                break
            if m > self.pv.shape[0]:
                self._prims(int(m * 1.25) + 16)
            if nv + e > self.vx.shape[0]:
                self._vertices(nv + int(e * 1.25) + 16)
        self.n_prims = m
        while True:
            total = R.bin_prims(self.pbox, m, self.nb, self.band_start, self.items)
            if total <= self.items.shape[0]:
                break
            self.items = np.empty(int(total * 1.25) + 16, np.int64)
        if count_coverage and self.count.shape[0] != self.depth.shape[0]:
            self.count = np.zeros(self.depth.shape[0], np.int32)
        groups = self.threads or numba.get_num_threads()
        if clock:
            t3 = clock()
        common = (self.nb, W, H, nv, self.band_start, self.items, self.pv, self.pflag,
                  self.psrc, self.pbox, self.vx, self.vy, self.vz, self.viw, self.wb,
                  self.depth, self.prim, self.bary, self.rowlo, self.rowhi, self.count,
                  bool(count_coverage))
        if lines:
            _run_groups(R.raster_lines, groups, (self.aa,) + common)
        else:
            _run_groups(R.raster_triangles, groups, common)
        if clock:
            t4 = clock()
        f = Frame(self.height, self.width, self.aa, groups, self.prim, self.bary, self.rowlo,
                  self.rowhi, self.verts, self.obj_of, self.va, kd, camera.eye, lp, li, bg,
                  self.image)
        _run_groups(stage, groups, (f, prm, tex, hmap, cube, key), first=True)
        if clock:
            t5 = clock()
            timings.update(prepare=t1 - t0, gather=t2 - t1, geometry=t3 - t2, raster=t4 - t3,
                           shade=t5 - t4)
        return self.image


_pool = None
_pool_lock = threading.Lock()


def _run_groups(kernel, groups, args, first=False):
    """kernel(g, groups, *args) for g in range(groups) (with first=True:
    kernel(args[0], g, *args[1:]), the fragment-stage signature); group 0 on this thread,
    the others on a thread pool (the kernels release the GIL; the pool's idle threads
    sleep, they do not spin). Every row belongs to exactly one group."""
    global _pool
    if first:
        call = lambda g: kernel(args[0], g, *args[1:])  # noqa: E731
    else:
        call = lambda g: kernel(g, groups, *args)  # noqa: E731
    if groups == 1:
        call(0)
        return
    with _pool_lock:
        if _pool is None or _pool._max_workers < groups - 1:
            _pool = ThreadPoolExecutor(max_workers=groups - 1, thread_name_prefix="render")
    futs = [_pool.submit(call, g) for g in range(1, groups)]
    call(0)
    for fu in futs:
        fu.result()


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
