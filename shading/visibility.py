"""A visibility buffer for one grid of samples: the rasteriser's buffers and its pipeline
(project, set up, bin, raster) seen through one view-projection. The renderer owns one
for the camera's image and, with shadows on, one for the light's shadow map."""
from __future__ import annotations

import threading
import time
from concurrent.futures import ThreadPoolExecutor

import numpy as np
from clothjit import njit

from . import raster as R


@njit(cache=True, inline="always")
def view_distance(z, near, far):
    """A depth buffer's window z (raster.py) -> distance along the view axis, for a
    perspective projection with these near and far planes."""
    return 2.0 * far * near / ((far + near) - (2.0 * z - 1.0) * (far - near))


class VisibilityBuffer:
    """Depth (window z), primitive id and barycentrics of every sample of a W x H grid,
    and the per-primitive and per-vertex scratch the rasteriser needs (grown on demand,
    never shrunk: drawing a frame allocates nothing large). `depth`: the depth buffer to
    draw into (float64 (W * H,), a view of the caller's array), else one of its own."""

    def __init__(self, width: int, height: int, depth: np.ndarray | None = None):
        self.width, self.height = int(width), int(height)
        ns = self.width * self.height
        # rowlo/rowhi = the whole row: the first frame clears all
        self.depth = np.full(ns, np.inf) if depth is None else depth
        self.prim = np.full(ns, -1, np.int32)
        self.bary = np.zeros((ns, 2), np.float32)
        self.rowlo = np.zeros(self.height, np.int32)
        self.rowhi = np.full(self.height, self.width - 1, np.int32)
        self.count = np.zeros(1, np.int32)  # replaced by a per-sample buffer on demand
        self.nb = (self.height + R.BAND - 1) // R.BAND
        self.band_start = np.zeros(self.nb + 1, np.int64)
        self.items = np.empty(1024, np.int64)
        self._prims(1024)
        self.clip = self.vcode = self.vx = None
        self.n_prims = 0

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

    def draw(self, va, nv, verts, npr, vp, groups, *, lines_aa=0, count_coverage=False,
             timings=None, depth_only=None):
        """Rasterise primitives verts[:npr] (vertex ids into va[:nv], whose columns 0:3 are
        world positions) through the 4x4 view-projection vp: triangles, or lines drawn
        lines_aa samples thick when lines_aa > 0. timings: receives "geometry" (projection,
        setup, binning) and "raster" seconds. depth_only: the ranges ((k, 2) [start, end))
        of the vertices of triangles whose depth alone is read (a shadow map's; primitive
        ids and barycentrics left as they are), drawn by raster.raster_depth when none of
        those vertices needs clipping (a floor plane's far corners may: they draw nothing)."""
        W, H = self.width, self.height
        if self.clip is None or self.clip.shape[0] < nv:
            self.clip = np.empty((va.shape[0], 4))
            self.vcode = np.empty(va.shape[0], np.int32)
        if self.vx is None or self.vx.shape[0] < nv + 64:
            self._vertices(nv + max(1024, nv // 4))
        setup = R.setup_lines if lines_aa else R.setup_triangles
        extra = (lines_aa,) if lines_aa else ()
        clock = time.perf_counter if timings is not None else None
        if clock:
            t0 = clock()
        projected = None
        while True:
            if projected is not self.vx:  # (again if the vertex slots were reallocated)
                codes = R.project(va[:nv], vp, W, H, self.clip, self.vcode, self.vx,
                                  self.vy, self.vz, self.viw)
                projected = self.vx
            if depth_only is not None and not lines_aa and not (
                    codes & 31 and any(np.bitwise_or.reduce(self.vcode[a:b]) & 31
                                       for a, b in depth_only)):
                if clock:
                    t1 = clock()
                run_groups(R.raster_depth, groups, (verts[:npr], W, H, self.vcode, self.vx,
                                                    self.vy, self.vz, self.depth, self.prim,
                                                    self.rowlo, self.rowhi, self.count))
                self.n_prims = npr
                if clock:
                    timings.update(geometry=t1 - t0, raster=clock() - t1)
                return
            m, e = setup(verts[:npr], self.clip, self.vcode, nv, W, H, *extra, self.vx,
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
        if clock:
            t1 = clock()
        common = (self.nb, W, H, nv, self.band_start, self.items, self.pv, self.pflag,
                  self.psrc, self.pbox, self.vx, self.vy, self.vz, self.viw, self.wb,
                  self.depth, self.prim, self.bary, self.rowlo, self.rowhi, self.count,
                  bool(count_coverage))
        if lines_aa:
            run_groups(R.raster_lines, groups, (lines_aa,) + common)
        else:
            run_groups(R.raster_triangles, groups, common)
        if clock:
            timings.update(geometry=t1 - t0, raster=clock() - t1)


_pool = None  # the groups' threads: their tasks never wait on other tasks
_aside = None  # beside()'s threads: their tasks wait only on the groups' tasks
_pool_lock = threading.Lock()


def _workers(n):
    """The render pool, with at least n threads."""
    global _pool
    with _pool_lock:
        if _pool is None or _pool._max_workers < n:
            _pool = ThreadPoolExecutor(max_workers=n, thread_name_prefix="render")
        return _pool


def run_groups(kernel, groups, args, first=False):
    """kernel(g, groups, *args) for g in range(groups) (with first=True:
    kernel(args[0], g, *args[1:]), the fragment-stage signature); group 0 on this thread,
    the others on a thread pool (the kernels release the GIL; the pool's idle threads
    sleep, they do not spin). Every row belongs to exactly one group."""
    if first:
        call = lambda g: kernel(args[0], g, *args[1:])  # noqa: E731
    else:
        call = lambda g: kernel(g, groups, *args)  # noqa: E731
    if groups == 1:
        call(0)
        return
    futs = [_workers(groups - 1).submit(call, g) for g in range(1, groups)]
    call(0)
    for fu in futs:
        fu.result()


def beside(task, this, groups):
    """task(groups - 1) on a thread of its own while this() runs on this thread; returns
    this()'s result once both are done. task may run_groups with its groups - 1 (on the
    render pool, whose tasks wait on nothing: renderers on several threads at once cannot
    hold each other up)."""
    global _aside
    with _pool_lock:
        if _aside is None:
            _aside = ThreadPoolExecutor(max_workers=4, thread_name_prefix="render-beside")
    fut = _aside.submit(task, groups - 1)
    try:
        return this()
    finally:
        fut.result()
