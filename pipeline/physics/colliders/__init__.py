"""Colliders (SPEC section 2, step 4): static or keyframed, applied in scene order.

A collider kind is one module in this package defining:
    KIND: int           its code in the packed table,
    SCENE_TYPE: type    the scene dataclass it packs,
    pack(obj, data) -> np.ndarray   its parameters as floats (at most PARAMS_WIDTH); bulk
                        arrays (a mesh's distance grid) go to `data.add(array) -> offset`,
    project(params, c, data, x, y, z, lx, ly, lz) -> (x, y, z)   an @njit point projection
                        reading its parameters from row c of the packed table, in the
                        collider's rest frame (the pose the scene file gives).
Adding a kind: its module, plus its entry in `_KINDS`, its sweep in `_SWEEPS` (made by
`_sweep_of` from its projection) and a ColliderTable field for it, in KIND order, and its
branch in `_collide_range`.

Motion. A collider with keyframes has pose (R(t), T(t)) at time t: a point p of its rest
frame is at R(t) (p - pivot) + pivot + T(t) in the world (pivot: sphere origin, plane point,
box center, mesh translation). A step from t - dt to t projects in the rest frame: the
point's position now through the pose at t, its start-of-step position through the pose at
t - dt. The friction rule `last + (1 - friction) (target - last)` then acts relative to the
moving surface: friction 1 carries a touching point along with the collider, friction 0
leaves its tangential motion alone. Static colliders skip the transforms (bit-identical to
the course code).
"""
from __future__ import annotations

import math
from collections.abc import Sequence
from types import FunctionType
from typing import NamedTuple

import numpy as np
from numba.core import types

from clothjit import KernelPointer, njit, prange

from ..forces import PARALLEL_POINTS
from . import box, mesh, plane, sphere

PARAMS_WIDTH = 16
POSE_WIDTH = 12  # R row-major (9), T (3)
_KINDS = (sphere, plane, box, mesh)
_BY_TYPE = {kind.SCENE_TYPE: kind for kind in _KINDS}
CHUNKS = 8  # work items of the parallel point loop


class ColliderData:
    """One flat float64 array that collider kinds append bulk parameters to."""

    def __init__(self) -> None:
        self._parts: list[np.ndarray] = []
        self._size = 0

    def add(self, array: np.ndarray) -> int:
        """Append `array` (flattened, as float64); returns its offset."""
        flat = np.ascontiguousarray(array, dtype=np.float64).ravel()
        offset = self._size
        self._parts.append(flat)
        self._size += flat.size
        return offset

    def array(self) -> np.ndarray:
        return np.concatenate(self._parts) if self._parts else np.zeros(1)


class ColliderTable(NamedTuple):
    """The scene's colliders packed for the kernels, in scene order (C colliders)."""

    kinds: np.ndarray  # (C,) int64
    params: np.ndarray  # (C, PARAMS_WIDTH) float64
    data: np.ndarray  # (D,) float64, see ColliderData
    keys: np.ndarray  # (C, K, 7) float64: time, translation (3), Euler angles in radians (3)
    key_count: np.ndarray  # (C,) int64, 0 = static
    pivot: np.ndarray  # (C, 3)
    pose: np.ndarray  # (C, 2, POSE_WIDTH) scratch: poses at the start and the end of a step
    active: np.ndarray  # (C,) uint8: 0 = skipped while nothing can reach it (pipeline.physics.reach)
    mesh: KernelPointer | None = None  # mesh.project, or _unmoved when no collider is a mesh
    # each kind's sweep (sweep_sphere, ...); absent for a kind the scene has not (four fields:
    # numba's parallel loops take no tuple of pointers)
    sphere: KernelPointer | None = None
    plane: KernelPointer | None = None
    box: KernelPointer | None = None
    mesh_sweep: KernelPointer | None = None
    poses: KernelPointer | None = None  # update_poses; absent when no collider has keyframes
    range: KernelPointer | None = None  # _collide_range for this table; None inside it
    # the loop over the points (_collide_serially or _collide_in_chunks, by the cloth's size:
    # forces.PARALLEL_POINTS; collide_all compiles in 0.5-0.6 s without the parallel loop
    # linked, 1.3-1.7 s with it); None inside it
    points: KernelPointer | None = None


def euler_matrix(degrees: Sequence[float]) -> np.ndarray:
    """R = Rz Ry Rx for Euler angles in degrees (x applied first)."""
    out = np.empty(9)
    _euler_into(out, 0, *(math.radians(float(a)) for a in degrees))
    return out.reshape(3, 3)


def pack_colliders(colliders: Sequence[object], points: int = 0) -> ColliderTable:
    """The packed table of `colliders` (scene order), for a cloth of `points` points."""
    table = _unpacked(colliders)
    data = ColliderData()
    for c, obj in enumerate(colliders):
        values = _BY_TYPE[type(obj)].pack(obj, data)
        table.params[c, : len(values)] = values
        table.pivot[c] = obj.pivot
        for k, key in enumerate(obj.keyframes):
            table.keys[c, k] = (key.time, *key.translation, *np.radians(key.rotation))
    return _with_pointers(table._replace(data=data.array()), points)


def stand_in_table(colliders: Sequence[object], points: int = 0) -> ColliderTable:
    """A table of the types of pack_colliders(colliders, points), its pointers the same,
    without packing anything (no mesh's distance grid is built): what the first run's
    helper compiles from while this process builds the grids (pipeline.run.warmup)."""
    return _with_pointers(_unpacked(colliders), points)


def _unpacked(colliders: Sequence[object]) -> ColliderTable:
    """The table's arrays for `colliders`, their kinds and keyframe counts set, the rest
    zero (data a single zero), without pointers."""
    count = len(colliders)
    key_len = max([len(obj.keyframes) for obj in colliders] + [1])
    return ColliderTable(
        np.array([_BY_TYPE[type(obj)].KIND for obj in colliders], dtype=np.int64),
        np.zeros((count, PARAMS_WIDTH)), np.zeros(1), np.zeros((count, key_len, 7)),
        np.array([len(obj.keyframes) for obj in colliders], dtype=np.int64),
        np.zeros((count, 3)), np.zeros((count, 2, POSE_WIDTH)), np.ones(count, dtype=np.uint8))


def _with_pointers(table: ColliderTable, points: int) -> ColliderTable:
    """`table` with its kernel pointers, for a cloth of `points` points."""
    kinds, key_count = table.kinds, table.key_count
    projection = mesh.project if mesh.KIND in kinds else _unmoved
    table = table._replace(mesh=KernelPointer(
        projection, (table.params, np.int64(0), table.data) + (0.0,) * 6, POINT))
    field = types.float64[:, ::1]  # positions, and positions a step earlier: (3, N)
    sweep_args = (table.params, table.data, table.mesh, table.pose, table.pivot, np.int64(0),
                  False, field, field, types.uint8[::1], np.int64(0), np.int64(1))
    table = table._replace(**{
        field: KernelPointer(sweep, sweep_args, present=bool(np.any(kinds == k)))
        for k, (field, sweep) in enumerate(zip(_SWEEP_FIELDS, _SWEEPS))})
    table = table._replace(poses=KernelPointer(
        update_poses, (table.keys, table.key_count, table.pose, 0.0, 0.0),
        present=bool(np.any(key_count))))
    table = table._replace(range=KernelPointer(
        _collide_range, (field, field, types.uint8[::1], table, np.int64(0), np.int64(1))))
    loop = _collide_in_chunks if points >= PARALLEL_POINTS else _collide_serially
    return table._replace(points=KernelPointer(loop, (field, field, types.uint8[::1], table)))


POINT = types.UniTuple(types.float64, 3)  # what a projection returns


@njit(cache=True, nogil=True, no_cpython_wrapper=True, pointer=True)
def _unmoved(params, c, data, x, y, z, lx, ly, lz):
    """The mesh projection's stand-in in a table without a mesh collider (never called)."""
    return x, y, z


def collider_pose(obj, t: float) -> tuple[np.ndarray, np.ndarray]:
    """(R (3, 3), T (3,)) of a collider's keyframed motion at time t (identity if static):
    its rest-frame point p is at R (p - pivot) + pivot + T."""
    if not obj.keyframes:
        return np.eye(3), np.zeros(3)
    keys = np.array([(k.time, *k.translation, *np.radians(k.rotation)) for k in obj.keyframes])
    out = np.empty(POSE_WIDTH)
    pose_at(keys, len(keys), float(t), out)
    return out[:9].reshape(3, 3), out[9:].copy()


def max_surface_speed(colliders: Sequence[object], extent: float) -> float:
    """An upper bound of the speed of any collider surface point within `extent` metres of
    its pivot (|T'| + |angular velocity| * extent over every key segment), for the guard."""
    speed = 0.0
    for obj in colliders:
        keys = obj.keyframes
        for a, b in zip(keys, keys[1:]):
            span = b.time - a.time
            move = np.linalg.norm(np.subtract(b.translation, a.translation)) / span
            turn = np.abs(np.radians(np.subtract(b.rotation, a.rotation))).sum() / span
            speed = max(speed, move + turn * extent)
    return float(speed)


@njit(cache=True, nogil=True)
def _euler_into(out, o, rx, ry, rz):
    """out[o:o+9] = Rz Ry Rx, row-major."""
    cx, sx = np.cos(rx), np.sin(rx)
    cy, sy = np.cos(ry), np.sin(ry)
    cz, sz = np.cos(rz), np.sin(rz)
    out[o + 0] = cz * cy
    out[o + 1] = cz * sy * sx - sz * cx
    out[o + 2] = cz * sy * cx + sz * sx
    out[o + 3] = sz * cy
    out[o + 4] = sz * sy * sx + cz * cx
    out[o + 5] = sz * sy * cx - cz * sx
    out[o + 6] = -sy
    out[o + 7] = cy * sx
    out[o + 8] = cy * cx


@njit(cache=True, nogil=True)
def pose_at(keys, count, t, out):
    """out[:12] = the pose (R row-major, T) at time t of keyframes keys[:count] (linear
    interpolation of translation and Euler angles; held before the first and after the last)."""
    if t <= keys[0, 0]:
        k, w = 0, 0.0
    elif t >= keys[count - 1, 0]:
        k, w = count - 1, 0.0
    else:
        k = 0
        while keys[k + 1, 0] <= t:
            k += 1
        w = (t - keys[k, 0]) / (keys[k + 1, 0] - keys[k, 0])
    k2 = min(k + 1, count - 1)
    for i in range(3):  # translation, then the angles: no scratch array per step
        out[9 + i] = keys[k, 1 + i] + w * (keys[k2, 1 + i] - keys[k, 1 + i])
    _euler_into(out, np.int64(0), keys[k, 4] + w * (keys[k2, 4] - keys[k, 4]),  # as from Python
                keys[k, 5] + w * (keys[k2, 5] - keys[k, 5]),
                keys[k, 6] + w * (keys[k2, 6] - keys[k, 6]))


# The transforms index the pose table directly: a view per point costs more than the
# projection itself.

@njit(cache=True, nogil=True, inline="always")
def _to_rest(pose, c, s, px, py, pz, x, y, z):
    """R^T (p - pivot - T) + pivot with the pose (R, T) = pose[c, s]."""
    dx, dy, dz = x - px - pose[c, s, 9], y - py - pose[c, s, 10], z - pz - pose[c, s, 11]
    return (px + pose[c, s, 0] * dx + pose[c, s, 3] * dy + pose[c, s, 6] * dz,
            py + pose[c, s, 1] * dx + pose[c, s, 4] * dy + pose[c, s, 7] * dz,
            pz + pose[c, s, 2] * dx + pose[c, s, 5] * dy + pose[c, s, 8] * dz)


@njit(cache=True, nogil=True, inline="always")
def _to_world(pose, c, s, px, py, pz, x, y, z):
    """R (p - pivot) + pivot + T with the pose (R, T) = pose[c, s]."""
    dx, dy, dz = x - px, y - py, z - pz
    return (px + pose[c, s, 0] * dx + pose[c, s, 1] * dy + pose[c, s, 2] * dz + pose[c, s, 9],
            py + pose[c, s, 3] * dx + pose[c, s, 4] * dy + pose[c, s, 5] * dz + pose[c, s, 10],
            pz + pose[c, s, 6] * dx + pose[c, s, 7] * dy + pose[c, s, 8] * dz + pose[c, s, 11])


def _sweep(params, data, mesh_project, pose, pivot, c, moving, x, last, pinned, lo, hi):
    """One collider (c) on the free points [lo, hi): the source of each kind's sweep
    (`_sweep_of`), in which `project` is the kind's projection."""
    if not moving:  # the rest frame is the world's
        for p in range(lo, hi):
            if pinned[p] == 0:
                x[0, p], x[1, p], x[2, p] = project(  # noqa: F821 (_sweep_of's global)
                    params, c, data, mesh_project, x[0, p], x[1, p], x[2, p], last[0, p],
                    last[1, p], last[2, p])
        return
    px, py, pz = pivot[c, 0], pivot[c, 1], pivot[c, 2]
    for p in range(lo, hi):
        if pinned[p]:
            continue
        rx, ry, rz = _to_rest(pose, c, 1, px, py, pz, x[0, p], x[1, p], x[2, p])
        rlx, rly, rlz = _to_rest(pose, c, 0, px, py, pz, last[0, p], last[1, p], last[2, p])
        qx, qy, qz = project(params, c, data, mesh_project,  # noqa: F821 (as above)
                             rx, ry, rz, rlx, rly, rlz)
        if qx != rx or qy != ry or qz != rz:  # untouched points keep their exact bits
            x[0, p], x[1, p], x[2, p] = _to_world(pose, c, 1, px, py, pz, qx, qy, qz)


def _sweep_of(project, name: str):
    """The kernel `name`: `_sweep` with `project` a kind's projection (rest frame; the
    mesh's pointer is every kind's argument). One kernel per kind, from one source: each
    point's loop has one kind and keeps its parameters in registers (one loop testing the
    kind of every collider at every point took 2-2.5x the time: 24-30 against 9-13 us per
    pass on the sphere scene, one thread), and a scene compiles the kernels of its kinds
    only, called through pointers (ColliderTable). `project` is a global of the kernel's own
    (numba reads globals when it compiles; a closure's would key its cache on the
    dispatcher's pickle, which differs in every process). Compiled without numba's
    reference counts (`_nrt=False`, as numba's own sort and string kernels are: nothing
    here allocates): with them, the inlined projection's array arguments cost an atomic
    incref and decref each per point (3.7x the whole pass on the sphere scene)."""
    function = FunctionType(_sweep.__code__, {**globals(), "project": project}, name)
    function.__qualname__ = name  # its own cache file and warm-up job
    function.__doc__ = _sweep.__doc__
    return njit(cache=True, nogil=True, error_model="numpy", _nrt=False,
                no_cpython_wrapper=True, pointer=True)(function)


def _taking_pointer(project):
    """`project` (a kind's) taking the mesh's pointer too, as every sweep passes it."""
    return njit(nogil=True, inline="always")(
        lambda params, c, data, mesh_project, x, y, z, lx, ly, lz:
        project(params, c, data, x, y, z, lx, ly, lz))


@njit(nogil=True, inline="always")
def _mesh(params, c, data, mesh_project, x, y, z, lx, ly, lz):
    if mesh.far(params, c, data, x, y, z, lx, ly, lz):  # most points: no call
        return x, y, z
    return mesh_project(params, c, data, x, y, z, lx, ly, lz)


# by KIND (sphere 0, plane 1, box 2, mesh 3)
sweep_sphere = _sweep_of(_taking_pointer(sphere.project), "sweep_sphere")
sweep_plane = _sweep_of(_taking_pointer(plane.project), "sweep_plane")
sweep_box = _sweep_of(_taking_pointer(box.project), "sweep_box")
sweep_mesh = _sweep_of(_mesh, "sweep_mesh")
_SWEEPS = (sweep_sphere, sweep_plane, sweep_box, sweep_mesh)
_SWEEP_FIELDS = ("sphere", "plane", "box", "mesh_sweep")  # ColliderTable's, by KIND


@njit(cache=True, nogil=True, no_cpython_wrapper=True, pointer=True)
def update_poses(keys, key_count, pose, t_start, t_end):
    """Poses of the keyframed colliders at the start and the end of a step (a ColliderTable's
    fields). Called through a pointer (ColliderTable.poses), present only in a scene with
    keyframes: a static scene does not compile the keyframes' interpolation (about 1 s)."""
    for c in range(key_count.shape[0]):
        n = key_count[c]
        if n > 0:
            pose_at(keys[c], n, t_start, pose[c, 0])
            pose_at(keys[c], n, t_end, pose[c, 1])


@njit(cache=True, nogil=True, _nrt=False, no_cpython_wrapper=True, pointer=True)
def _collide_range(x, last, pinned, table, lo, hi):
    """Every active collider, in order, on the free points [lo, hi), with the poses of
    update_poses: each through its kind's sweep (each point meets the colliders in order
    all the same: points do not interact here)."""
    params, data, mesh_project, pose, pivot = (table.params, table.data, table.mesh,
                                               table.pose, table.pivot)
    for c in range(table.kinds.shape[0]):
        if table.active[c] == 0:
            continue
        kind, moving = table.kinds[c], table.key_count[c] != 0
        if kind == sphere.KIND:
            sweep = table.sphere
        elif kind == plane.KIND:
            sweep = table.plane
        elif kind == box.KIND:
            sweep = table.box
        else:
            sweep = table.mesh_sweep
        sweep(params, data, mesh_project, pose, pivot, c, moving, x, last, pinned, lo, hi)


@njit(cache=True, nogil=True, no_cpython_wrapper=True, pointer=True)
def _collide_serially(x, last, pinned, table):
    """Every point in one call of _collide_range (through table.range)."""
    table.range(x, last, pinned, ColliderTable(*table[:-2], None, None), 0, x.shape[1])


@njit(cache=True, nogil=True, parallel=True, no_cpython_wrapper=True, pointer=True)
def _collide_in_chunks(x, last, pinned, table):
    # The parallel loop only calls _collide_range, through table.range: numba copies a
    # parallel loop's body several times while compiling it and optimises linked code again
    # in every caller, so the colliders' inlined code is compiled once, on its own.
    n = x.shape[1]
    collide, points = table.range, ColliderTable(*table[:-2], None, None)
    for chunk in prange(CHUNKS):
        c = np.int64(chunk)
        collide(x, last, pinned, points, (c * n) // CHUNKS, ((c + 1) * n) // CHUNKS)


@njit(cache=True, nogil=True, error_model="numpy", pointer=True)
def collide_all(x, last, pinned, table, t_start, t_end):
    """Apply the colliders to every free point of x (3, N) for the step from t_start (when
    the points were at `last`) to t_end."""
    for on in table.active:  # a loop, not np.any (see reach.reach_check)
        if on:
            break
    else:  # none active, or no collider
        return
    for n in table.key_count:  # the poses pointer is absent without keyframes
        if n:
            table.poses(table.keys, table.key_count, table.pose, t_start, t_end)
            break
    table.points(x, last, pinned, ColliderTable(*table[:-1], None))
