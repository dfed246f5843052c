"""Renderer: owns every per-frame buffer (visibility buffer, primitive arrays, output
image) for one image size, so rendering a frame allocates nothing large.

    r = Renderer(800, 800, aa=1)
    img = r.render(meshes, camera, light, "phong", params)   # r.image, reused

`params` (all optional): the shader constants (SPEC 5 names: k_a, I_a, k_s, p, k_h,
k_n, ...; see each shader's PARAMS), "background" (rgb), "texture", "height_map" (image
paths or (h,w,3) arrays), "cubemap" (folder with posx..negz.png or a (6,s,s,3) array),
"light_position", "light_intensity", "light_radius" (override `light`), "shadows" (bool),
"shadow_map_size" (texels, default shadow.map_size: 512 at 800 x 800, 768 at 1920 x 1080),
"ambient_occlusion" (bool), "ao_radius" (metres, default 0.1); each look is computed only
when a shader of the frame reads it (`Shader.lit`: texture, mirror and normal read neither,
diffuse only the shadows). Unknown keys are ignored.
"""
from __future__ import annotations

import math
import time

import numba
import numpy as np
from clothjit import njit

from .camera import Camera
from .occlusion import DEFAULT_RADIUS as AO_RADIUS
from .occlusion import KERNEL as AO_KERNEL
from .occlusion import PHASES as AO_PHASES
from .occlusion import TURNS as AO_TURNS
from .occlusion import blur_pass, cell_step, occlusion_pass, upsample_pass
from .shade import Frame, ShaderKey, fragment_stage, uncached_fragment_stage
from .shaders import get_shader
from .shadow import (DEFAULT_RADIUS, ShadowMap, caster_bounds, levels, map_size,
                     visibility_pass)
from .textures import resolve
from .visibility import VisibilityBuffer, beside, run_groups

DEFAULT_LIGHT_POSITION = (0.5, 2.0, 2.0)
DEFAULT_LIGHT_INTENSITY = (3.0, 3.0, 3.0)
DEFAULT_BACKGROUND = (0.2, 0.25, 0.3)
_DUMMY_TEX = np.zeros((1, 1, 3))
_DUMMY_CUBE = np.zeros((6, 1, 1, 3))
_DUMMY_TEX.flags.writeable = False  # same numba type as loaded (read-only) textures
_DUMMY_CUBE.flags.writeable = False
_OFF = np.ones(0, np.float32)  # Frame.occ / Frame.vis without occlusion / shadows
_ONE_PASS = (np.zeros(0, np.int32), 0, 1, np.zeros((0, 3)))  # Frame's fields, one shader
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


def _inputs(shader, params):
    """(packed params, texture, height map, cube map, stage key) of `shader`."""
    tex = resolve("texture", params.get("texture")) if "texture" in shader.textures else _DUMMY_TEX
    hmap = (resolve("height_map", params.get("height_map"))
            if "height_map" in shader.textures else _DUMMY_TEX)
    cube = (resolve("cubemap", params.get("cubemap")) if "cubemap" in shader.textures
            else _DUMMY_CUBE)
    return shader.pack(params), tex, hmap, cube, shader.stage_key()


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
        self.view = VisibilityBuffer(self.sw, self.sh)  # the camera's
        self.image = np.empty((self.height, self.width, 3), np.uint8)
        self.va = None
        self.verts = self.obj_of = self.disp = None
        self.casts = np.empty(0, bool)  # per mesh: does it cast shadows (not a plane)
        self.mesh_vertices = np.zeros(1, np.int64)  # mesh i's vertices: [v_i, v_i+1)
        self.mesh_prims = np.zeros(1, np.int64)  # mesh i's primitives: [p_i, p_i+1)
        self.own_positions = []  # per mesh: its positions where no vertex stage moved them
        self.shadow_map = None  # a shadow.ShadowMap once shadows are asked for
        self.acc = np.empty((0, 3))  # per pixel, with meshes of several shaders
        self.vis = _OFF  # per sample, with shadows
        self.refine = np.empty(0, bool)  # per cell of the look-ups: refined (shadow.py)
        self.frame = None  # the last frame's shade.Frame
        # with ambient occlusion: per cell of occlusion.cell_step pixels the raw and
        # filtered factors and the depth, and the factor of every pixel
        self.occ_raw = self.occ_blur = self.occlusion = _OFF
        self.occ_dist = np.empty(0)
        self.threads = None  # None: numba.get_num_threads() (NUMBA_NUM_THREADS)

    # the camera's visibility buffer, as the tests and debugging aids read it
    depth = property(lambda self: self.view.depth)
    prim = property(lambda self: self.view.prim)
    bary = property(lambda self: self.view.bary)
    count = property(lambda self: self.view.count)
    n_prims = property(lambda self: self.view.n_prims)

    def _gather(self, meshes, shader, looks):
        """Pack every mesh's vertices and primitives; looks[i] = (shader, its _inputs) of
        mesh i, whose vertex stage (if any) moves its vertices."""
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
        self.verts = _grow(self.verts, max(npr, 1), (3,), np.int32)
        self.obj_of = _grow(self.obj_of, max(npr, 1), (), np.int32)
        kd = np.empty((max(len(meshes), 1), 3))
        self.casts = np.empty(len(meshes), bool)
        self.own_positions = []  # per mesh: its positions where no vertex stage moved them
        self.mesh_vertices = np.empty(len(meshes) + 1, np.int64)
        self.mesh_prims = np.empty(len(meshes) + 1, np.int64)
        va, verts = self.va, self.verts
        v = p = 0
        for i, m in enumerate(meshes):
            n = m.positions.shape[0]
            pos = m.positions
            own, (prm, _, hmap, _, _) = looks[i]
            if own.vertex is not None:
                self.disp = _grow(self.disp, n, (3,), np.float64)
                pos = own.vertex(m.positions, m.normals, m.uvs, prm, hmap, out=self.disp[:n])
            _pack_vertices(va, v, _ro(pos), _ro(m.normals), _ro(m.uvs), _ro(m.tangents))
            self.mesh_prims[i] = p
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
            self.casts[i] = not m.name.startswith("plane")  # "plane", "plane_0", ...
            self.mesh_vertices[i] = v
            self.own_positions.append(pos if own.vertex is None else None)
            v += n
        self.mesh_vertices[len(meshes)] = v
        self.mesh_prims[len(meshes)] = p
        return nv, npr, kd

    def render(self, meshes, camera: Camera, light=None, shader="phong", params=None, *,
               count_coverage=False, timings: dict | None = None) -> np.ndarray:
        """Render into self.image (returned; overwritten by the next call).

        count_coverage=True also fills self.count (per sample, row-major) with the number
        of fragments each sample received (before the depth test): a debugging aid.
        timings: a dict that receives the seconds spent in each stage ("prepare",
        "gather", "geometry" = project + setup + binning, "raster", "shadows" = the shadow
        map, its look-ups and ambient occlusion, "shade").
        With params["shadows"], `light_visibility()` then gives each sample's visibility
        of the light, as the shaders saw it (shadow.py).
        """
        clock = time.perf_counter if timings is not None else None
        if clock:
            t0 = clock()
        if (camera.width, camera.height) != (self.width, self.height):
            raise ValueError(f"camera is {camera.width}x{camera.height}, renderer "
                             f"{self.width}x{self.height}")
        sh = get_shader(shader)
        params = {} if params is None else params
        lines = sh.primitive == "lines"
        # the shaders of the passes: the frame's, then those meshes of their own ask for
        # (a wireframe frame draws every mesh's lines)
        passes = [sh]
        mesh_pass = [0] * len(meshes)
        if not lines:
            for i, m in enumerate(meshes):
                if m.shader is not None and m.shader != sh.name:
                    own = get_shader(m.shader)
                    if own.primitive == "lines":
                        raise ValueError(f"mesh {m.name!r}: shader {m.shader!r} draws lines; "
                                         "a mesh's own shader must draw triangles")
                    if own not in passes:
                        passes.append(own)
                    mesh_pass[i] = passes.index(own)
        inputs = [_inputs(s, params) for s in passes]
        lp = getattr(light, "position", DEFAULT_LIGHT_POSITION) if light is not None \
            else DEFAULT_LIGHT_POSITION
        li = getattr(light, "intensity", DEFAULT_LIGHT_INTENSITY) if light is not None \
            else DEFAULT_LIGHT_INTENSITY
        radius = getattr(light, "radius", DEFAULT_RADIUS) if light is not None else DEFAULT_RADIUS
        lp = _vec3(params.get("light_position", lp), "light position")
        li = _vec3(params.get("light_intensity", li), "light intensity")
        radius = float(params.get("light_radius", radius))
        if not (math.isfinite(radius) and radius >= 0.0):
            raise ValueError(f"light radius must be a number >= 0, got {radius!r}")
        bg = _vec3(params.get("background", DEFAULT_BACKGROUND), "background")
        # a look only where a shader of the frame reads it (texture, mirror, normal: none)
        shadows = bool(params.get("shadows", False)) and not lines and any(
            "shadows" in s.lit for s in passes)
        occlusion = bool(params.get("ambient_occlusion", False)) and not lines and any(
            "occlusion" in s.lit for s in passes)
        if clock:
            t1 = clock()
        nv, npr, kd = self._gather(meshes, sh, [(passes[k], inputs[k]) for k in mesh_pass])
        if clock:
            t2 = clock()
        groups = self.threads or numba.get_num_threads()
        vp = camera.view_projection()
        self.view.draw(self.va, nv, self.verts, npr, vp, groups,
                       lines_aa=self.aa if lines else 0, count_coverage=count_coverage,
                       timings=timings)
        if clock:
            t3 = clock()
        f = Frame(self.height, self.width, self.aa, groups, self.view.prim, self.view.bary,
                  self.view.rowlo, self.view.rowhi, self.verts, self.obj_of, self.va, kd,
                  camera.eye, lp, li, bg, self.image, _OFF, _OFF, *_ONE_PASS)
        if shadows and occlusion and groups > 1:
            # the occlusion's passes on this thread beside the shadow map drawn on the
            # others: either, spread over all threads, barely runs faster (short kernels,
            # each call a wait for the other threads to wake; a map's triangles set up by
            # each thread whose bands they reach); side by side they take the longer's time
            size = self._map_size(params)
            f = beside(lambda g: self._shadow_map(nv, npr, lp, radius, size, g),
                       lambda: self._occlusion(f._replace(groups=1), camera, vp, params, 1),
                       groups)._replace(groups=groups)
            f = self._lookups(f, radius, groups)
        else:
            if shadows:
                self._shadow_map(nv, npr, lp, radius, self._map_size(params), groups)
                f = self._lookups(f, radius, groups)
            if occlusion:
                f = self._occlusion(f, camera, vp, params, groups)
        self.frame = f
        if clock:
            t4 = clock()
        if len(passes) > 1:
            n = self.width * self.height
            if self.acc.shape[0] != n:
                self.acc = np.empty((n, 3))
            f = f._replace(obj_pass=np.array(mesh_pass, np.int32), passes=len(passes),
                           acc=self.acc)
        extras = ShaderKey(int(bool(f.vis.shape[0] or f.occ.shape[0] or len(passes) > 1)))
        for k, (prm, tex, hmap, cube, key) in enumerate(inputs):
            stage = fragment_stage if key >= 0 else uncached_fragment_stage
            dark = ShaderKey(2) if f.vis.shape[0] and passes[k].dark else extras
            run_groups(stage, groups, (f._replace(pass_id=k), prm, tex, hmap, cube, key,
                                       dark), first=True)
        if clock:
            t5 = clock()
            timings.update(prepare=t1 - t0, gather=t2 - t1, shadows=t4 - t3, shade=t5 - t4)
        return self.image

    def _map_size(self, params) -> int:
        """The shadow map's side: params["shadow_map_size"], else shadow.map_size's."""
        size = int(params.get("shadow_map_size", map_size(self.sw, self.sh)))
        if size < 16:
            raise ValueError(f"shadow_map_size must be >= 16, got {size}")
        return size

    def _shadow_map(self, nv, npr, lp, radius, size, groups):
        """The shadow map (size x size texels a view) of the meshes that cast shadows (all
        but planes), drawn from the light at lp (shadow.py)."""
        if self.shadow_map is None or self.shadow_map.size != size:
            self.shadow_map = ShadowMap(size)
        # the casting meshes' primitives and vertices, in runs of consecutive meshes: one
        # slice (no copy) when the planes come first or last, as they usually do
        mp, mv = self.mesh_prims, self.mesh_vertices
        runs = [[i, i + 1] for i in np.flatnonzero(self.casts)]
        for k in range(len(runs) - 1, 0, -1):
            if runs[k - 1][1] == runs[k][0]:
                runs[k - 1][1] = runs.pop(k)[1]
        verts = (self.verts[mp[runs[0][0]]:mp[runs[0][1]]] if len(runs) == 1 else
                 np.concatenate([self.verts[mp[a]:mp[b]] for a, b in runs] or
                                [np.empty((0, 3), np.int32)]))
        vruns = np.array([(mv[a], mv[b]) for a, b in runs], np.int64).reshape(-1, 2)
        # one casting mesh: its bounds from its own positions (rows of 24 bytes, not of va's
        # 96: 0.2 instead of 0.37 ms at 40 000 vertices), the same numbers
        one = self.own_positions[runs[0][0]] if len(runs) == 1 and \
            runs[0][1] == runs[0][0] + 1 else None
        if one is not None and one.dtype == np.float64 and one.flags.c_contiguous and \
                one.flags.writeable:  # (the same compiled kernel as for va)
            bounds = caster_bounds(one, np.array([[0, one.shape[0]]], np.int64), lp)
        else:
            bounds = caster_bounds(self.va, vruns, lp) if runs else None
        self.shadow_map.build(self.va, nv, verts, vruns, bounds, lp, radius, groups)

    def _lookups(self, f, radius, groups):
        """Frame f with each sample's visibility of the light, looked up in the shadow
        map."""
        m = self.shadow_map
        ns = self.view.prim.shape[0]
        top = levels(self.sw, self.sh)
        cell = 1 << top
        if self.vis.shape[0] != ns:
            self.vis = np.empty(ns, np.float32)
            self.refine = np.empty(((self.sw + cell - 1) // cell)
                                   * ((self.sh + cell - 1) // cell), bool)
        # one call per step, each after the one before in every group; one call in all on
        # one thread (each call waits for the pool's threads to wake: 40-90 us here)
        for step in range(top, -1, -1) if groups > 1 else (top,):
            run_groups(visibility_pass, groups, (f, m.depth, m.tiles, m.views, m.tanh,
                                                 m.closest, m.zab, radius, top, step,
                                                 step if groups > 1 else 0, self.refine,
                                                 self.vis), first=True)
        return f._replace(vis=self.vis)

    def _occlusion(self, f, camera, vp, params, groups):
        """Frame f with its pixels' ambient occlusion factors (occlusion.py)."""
        radius = float(params.get("ao_radius", AO_RADIUS))
        if not (math.isfinite(radius) and radius > 0.0):
            raise ValueError(f"ao_radius must be a number > 0, got {radius!r}")
        step = cell_step(self.width, self.height)
        n = self.width * self.height
        nh = ((self.width + step - 1) // step) * ((self.height + step - 1) // step)
        if self.occlusion.shape[0] != n:
            self.occ_raw = np.empty(nh, np.float32)
            self.occ_blur = np.empty(nh, np.float32)
            self.occ_dist = np.empty(nh)
            self.occlusion = np.ones(n, np.float32)  # the background: never written
        depth = self.view.depth
        # its phases, one call each after the one before in every group (one call in all
        # on one thread)
        for first, last in ([(k, k) for k in range(AO_PHASES + 1)] if groups > 1
                            else [(0, AO_PHASES)]):
            run_groups(occlusion_pass, groups, (f, step, vp, camera.near, camera.far, radius,
                                                AO_KERNEL, AO_TURNS, depth, first, last,
                                                self.occ_raw, self.occ_dist), first=True)
        run_groups(blur_pass, groups, (f, step, radius, self.occ_raw, self.occ_dist,
                                       self.occ_blur), first=True)
        run_groups(upsample_pass, groups, (f, step, camera.near, camera.far, depth,
                                           self.occ_dist, self.occ_blur, self.occlusion),
                   first=True)
        return f._replace(occ=self.occlusion)

    def light_visibility(self) -> np.ndarray:
        """Per sample (row-major, float32) the light's visibility the last render's shaders
        used (1 without shadows; undefined on the background): a debugging and testing
        aid."""
        if self.frame is None or not self.frame.vis.shape[0]:
            return np.ones(self.view.prim.shape[0], np.float32)
        return self.frame.vis.copy()


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
