"""Mesh collider: a triangle mesh file, through its signed distance grid (pipeline.physics.sdf).

Solid (closed) meshes push any point closer than `thickness` (inside included) out along
the distance gradient to the level set d = thickness. One-sided meshes act like a curved
plane: a point that crossed the surface during the step, or came closer than `thickness`,
goes to distance `thickness` on the side it came from. Then the friction rule
last + (1 - friction) (target - last).

Parameter row (15 of PARAMS_WIDTH): 0-9 the grid header (pipeline.physics.sdf.HEADER_WIDTH:
offset of the grid in `data`, origin x y z, h, 1/h, nx, ny, nz, h sqrt(3)), 10 friction,
11 thickness, 12 solid (1 or 0), 13 crossing slack (twice the grid's measured error),
14 the squared Newton step length beyond which a step is followed by another.
"""
from __future__ import annotations

import functools
import math
import warnings
from pathlib import Path

import numpy as np

from clothjit import njit
from pipeline.scene import MeshCollider, SceneError

from .. import sdf

KIND = 3
SCENE_TYPE = MeshCollider
_FRICTION, _THICKNESS, _SOLID, _SLACK, _LONG_STEP2 = range(sdf.HEADER_WIDTH, sdf.HEADER_WIDTH + 5)
#: A Newton step of length s in a trilinear cell of size h misses the level set by up to
#: about s^2 / h: steps longer than sqrt(_TOLERANCE * thickness * h) / 2 get another one
#: (two more at most), so the miss stays near _TOLERANCE * thickness.
_TOLERANCE = 1e-3
_MIN_GRADIENT = 0.5  # Newton steps divide by |gradient|^2, taken at least this squared


def pack(obj: MeshCollider, data) -> np.ndarray:
    """The parameter row of `obj`; its distance grid goes to `data`."""
    grid = distance_grid(obj)
    offset = data.add(grid.values)
    return np.array([*grid.header(offset), obj.friction, obj.thickness, float(obj.solid),
                     2.0 * grid.error + 1e-12, _TOLERANCE * obj.thickness * grid.spacing / 4.0])


def grid_bounds(obj: MeshCollider) -> tuple[np.ndarray, np.ndarray]:
    """(low (3,), high (3,)) corners of the box outside which `obj` acts on nothing (its
    distance grid's nodes, padded by one cell), in its rest frame."""
    grid = distance_grid(obj)
    nz, ny, nx = grid.values.shape
    h = grid.spacing
    return grid.origin - h, grid.origin + h * np.array([nx, ny, nz], dtype=np.float64)


def distance_grid(obj: MeshCollider) -> sdf.DistanceGrid:
    """The signed distance grid of `obj` in its rest frame (built once, cached)."""
    return _grid(*_key(obj), float(obj.thickness), bool(obj.solid))


def collider_mesh_arrays(obj: MeshCollider) -> tuple[np.ndarray, np.ndarray]:
    """(vertices (V, 3) float64, faces (F, 3) int64) of `obj` placed in its rest frame
    (read-only arrays, cached)."""
    return _mesh(*_key(obj))


def _key(obj: MeshCollider) -> tuple:
    path = Path(obj.path)
    try:
        mtime = path.stat().st_mtime_ns
    except OSError as err:
        raise SceneError(f"{path}: cannot read the mesh file ({err.strerror})") from None
    return (str(path), mtime, tuple(map(float, obj.translation)),
            tuple(map(float, obj.rotation)), tuple(map(float, obj.scale)))


@functools.lru_cache(maxsize=16)
def _mesh(path: str, mtime: int, translation: tuple, rotation: tuple, scale: tuple
          ) -> tuple[np.ndarray, np.ndarray]:
    import trimesh

    from . import euler_matrix

    try:
        mesh = trimesh.load(path, force="mesh")
    except Exception as err:  # trimesh raises many types for unreadable files
        raise SceneError(f"{path}: not a readable triangle mesh ({err})") from None
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise SceneError(f"{path}: the file holds no triangles")
    mesh.update_faces(mesh.nondegenerate_faces())
    mesh.remove_unreferenced_vertices()
    matrix = np.eye(4)
    matrix[:3, :3] = euler_matrix(rotation) * np.asarray(scale)[None, :]
    matrix[:3, 3] = translation
    mesh.apply_transform(matrix)  # also keeps the winding outward under a mirroring scale
    vertices = np.ascontiguousarray(mesh.vertices, dtype=np.float64)
    faces = np.ascontiguousarray(mesh.faces, dtype=np.int64)
    vertices.flags.writeable = False
    faces.flags.writeable = False
    return vertices, faces


@functools.lru_cache(maxsize=8)
def _grid(path: str, mtime: int, translation: tuple, rotation: tuple, scale: tuple,
          thickness: float, solid: bool) -> sdf.DistanceGrid:
    import trimesh

    vertices, faces = _mesh(path, mtime, translation, rotation, scale)
    if solid:
        mesh = trimesh.Trimesh(vertices, faces, process=False)
        if not (mesh.is_watertight and mesh.is_winding_consistent):
            raise SceneError(f'{path}: the mesh is not closed (watertight): a "solid" mesh '
                             'collider needs one; give "solid": false for a one-sided surface')
        if mesh.volume < 0.0:
            faces = faces[:, ::-1]
    grid = sdf.build_grid(vertices, faces, solid=solid, thickness=thickness)
    if grid.error > 0.5 * thickness:
        warnings.warn(f"{path}: the distance grid is off by up to {grid.error:.2g} m near the "
                      f"surface (thickness {thickness:g} m); contacts may be uneven",
                      RuntimeWarning, stacklevel=2)
    return grid


@njit(cache=True, nogil=True, inline="always")
def _newton(x, y, z, d, gx, gy, gz, level):
    """A Newton step towards the level set d = level along the gradient g: the new point
    and the squared step length. The step is (level - d) g / |g|^2, with |g|^2 taken
    >= _MIN_GRADIENT^2 (bounded steps where the gradient vanishes)."""
    g2 = gx * gx + gy * gy + gz * gz
    scale = (level - d) / max(g2, _MIN_GRADIENT * _MIN_GRADIENT)
    return x + scale * gx, y + scale * gy, z + scale * gz, scale * scale * g2


@njit(cache=True, nogil=True, inline="always")
def _step_again(grid, data, x, y, z, level):
    """Another Newton step from (x, y, z) (none once it left the grid)."""
    base, tx, ty, tz, inside = sdf.locate(grid, x, y, z)
    d, gx, gy, gz = sdf.trilinear(grid, data, base, tx, ty, tz)
    qx, qy, qz, step2 = _newton(x, y, z, d, gx, gy, gz, level)
    if not inside:
        return x, y, z, 0.0
    return qx, qy, qz, step2


@njit(cache=True, nogil=True, inline="always")
def far(params, c, data, x, y, z, lx, ly, lz):
    """Whether `project` certainly leaves the point where it is (its first tests): outside
    the grid, or the point's cell corner farther from the surface than the cell's diagonal
    plus the contact distance. The colliders inline it and call `project` (through a
    pointer) only for the other points."""
    grid = sdf.grid_of(params, c)
    base, _, _, _, inside = sdf.locate(grid, x, y, z)
    if not inside:
        return True
    corner, diagonal, thickness = data[base], grid[9], params[c, _THICKNESS]
    if params[c, _SOLID] != 0.0:
        return corner - diagonal >= thickness
    return abs(corner) - diagonal >= max(thickness, _move(params, c, x, y, z, lx, ly, lz))


@njit(cache=True, nogil=True, inline="always")
def _move(params, c, x, y, z, lx, ly, lz):
    """The step's length plus the crossing slack."""
    mx, my, mz = x - lx, y - ly, z - lz
    return math.sqrt(mx * mx + my * my + mz * mz) + params[c, _SLACK]


@njit(cache=True, nogil=True, pointer=True)
def project(params, c, data, x, y, z, lx, ly, lz):
    """The point now at (x, y, z), at (lx, ly, lz) at the start of the step, corrected by
    mesh collider c (rest frame). Written with few branches, no loop and no merge after a
    use of `data`: numba then prunes the reference counting of the arrays, which otherwise
    costs atomic increments on every call (several times this kernel's own cost)."""
    grid = sdf.grid_of(params, c)
    thickness, keep = params[c, _THICKNESS], 1.0 - params[c, _FRICTION]
    solid, long_step2 = params[c, _SOLID] != 0.0, params[c, _LONG_STEP2]
    base, tx, ty, tz, inside = sdf.locate(grid, x, y, z)
    if not inside:
        return x, y, z
    corner, diagonal = data[base], grid[9]  # d in the cell is within `diagonal` of `corner`
    if solid:
        if corner - diagonal >= thickness:
            return x, y, z
        d, gx, gy, gz = sdf.trilinear(grid, data, base, tx, ty, tz)
        if d >= thickness:
            return x, y, z
        level = thickness
    else:
        move = _move(params, c, x, y, z, lx, ly, lz)
        if abs(corner) - diagonal >= max(thickness, move) or not sdf.trusted(grid, data, base):
            return x, y, z
        d, gx, gy, gz = sdf.trilinear(grid, data, base, tx, ty, tz)
        last, ltx, lty, ltz, last_inside = sdf.locate(grid, lx, ly, lz)
        d_last = sdf.trilinear(grid, data, last, ltx, lty, ltz)[0]
        known = last_inside & sdf.trusted(grid, data, last) & (d_last != 0.0)
        side = math.copysign(1.0, d_last if known else d)
        crossed = (d * side < 0.0) & (abs(d) + abs(d_last) <= move) & known
        if not (crossed or abs(d) < thickness):
            return x, y, z
        level = side * thickness
    # after a long step the cell's curvature may leave a visible miss: step again
    x, y, z, step2 = _newton(x, y, z, d, gx, gy, gz, level)
    if step2 <= long_step2:
        return lx + keep * (x - lx), ly + keep * (y - ly), lz + keep * (z - lz)
    x, y, z, step2 = _step_again(grid, data, x, y, z, level)
    if step2 <= long_step2:
        return lx + keep * (x - lx), ly + keep * (y - ly), lz + keep * (z - lz)
    x, y, z, step2 = _step_again(grid, data, x, y, z, level)
    return lx + keep * (x - lx), ly + keep * (y - ly), lz + keep * (z - lz)
