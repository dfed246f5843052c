"""The mesh collider kind on its own: its signed distance grid (pipeline.physics.sdf) and its point
projection (pipeline.physics.colliders.mesh), against references that share nothing with them.

Exact signed distances are brute force in numpy: the distance to each triangle is the
distance to its plane where the foot falls inside it, else to its nearest edge segment (not
Ericson's region walk used by the grid); the sign is the generalized winding number (not
pseudo-normals or ray parity). The icosphere is also checked against the analytic sphere.
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import trimesh
from numba import njit

from pipeline.physics import sdf
from pipeline.physics.colliders import PARAMS_WIDTH, ColliderData, collide_all, pack_colliders
from pipeline.physics.colliders import mesh as mesh_kind
from pipeline.scene import MeshCollider, SceneError

MESHES = Path(__file__).resolve().parents[1] / "scenes" / "meshes"
THICKNESS = 0.005  # the scene default
TINY = 1e-3 * THICKNESS  # what a projection may miss the level set d = thickness by


# --------------------------------------------------------------------------------------
# references
# --------------------------------------------------------------------------------------

def _segment_distance(p, a, b):
    ab = b - a
    t = np.einsum("...k,...k->...", p - a, ab) / np.einsum("...k,...k->...", ab, ab)
    return np.linalg.norm(p - (a + np.clip(t, 0.0, 1.0)[..., None] * ab), axis=-1)


def unsigned_distance(points, vertices, faces, chunk=32):
    """min over triangles of (|distance to the plane| if the foot is inside, else inf, and
    the distances to the three edge segments)."""
    tri = vertices[faces]
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
    n = np.cross(b - a, c - a)
    n /= np.linalg.norm(n, axis=1)[:, None]
    out = np.empty(len(points))
    for s in range(0, len(points), chunk):
        p = points[s:s + chunk, None, :]
        height = np.einsum("ptk,tk->pt", p - a, n)
        foot = p - height[..., None] * n
        inside = np.ones(height.shape, dtype=bool)
        for u, v in ((a, b), (b, c), (c, a)):
            inside &= np.einsum("ptk,tk->pt", np.cross(v - u, foot - u), n) >= 0.0
        d = np.where(inside, np.abs(height), np.inf)
        for u, v in ((a, b), (b, c), (c, a)):
            d = np.minimum(d, _segment_distance(p, u, v))
        out[s:s + chunk] = d.min(axis=1)
    return out


def winding_numbers(points, vertices, faces):
    """Sum of the triangles' signed solid angles seen from each point / 4 pi (Van Oosterom
    and Strackee 1983): 1 inside a closed outward-wound mesh, 0 outside."""
    tri = vertices[faces]
    out = np.empty(len(points))
    for s in range(0, len(points), 64):
        r = tri[None] - points[s:s + 64, None, None, :]
        a, b, c = r[..., 0, :], r[..., 1, :], r[..., 2, :]
        la, lb, lc = (np.linalg.norm(v, axis=-1) for v in (a, b, c))
        det = np.einsum("ptk,ptk->pt", a, np.cross(b, c))
        den = (la * lb * lc + np.einsum("ptk,ptk->pt", a, b) * lc
               + np.einsum("ptk,ptk->pt", b, c) * la + np.einsum("ptk,ptk->pt", c, a) * lb)
        out[s:s + 64] = np.arctan2(det, den).sum(axis=1) / (2.0 * np.pi)
    return out


def exact_signed_distance(points, vertices, faces):
    """Positive outside (trimesh's signed_distance is positive inside)."""
    d = unsigned_distance(points, vertices, faces)
    return np.where(winding_numbers(points, vertices, faces) > 0.5, -d, d)


# --------------------------------------------------------------------------------------
# helpers
# --------------------------------------------------------------------------------------

def collider(name, **kw) -> MeshCollider:
    kw.setdefault("friction", 0.0)
    kw.setdefault("thickness", THICKNESS)
    return MeshCollider(path=MESHES / name, **kw)


def packed(*colliders):
    """(params (C, PARAMS_WIDTH), data) as the simulator packs them."""
    data = ColliderData()
    params = np.zeros((len(colliders), PARAMS_WIDTH))
    for c, obj in enumerate(colliders):
        row = mesh_kind.pack(obj, data)
        params[c, :len(row)] = row
    return params, data.array()


@njit  # not cached: numba's cache would keep an inlined mesh.project that has since changed
def _project_points(params, c, data, points, lasts, out):
    for p in range(points.shape[0]):
        out[p, 0], out[p, 1], out[p, 2] = mesh_kind.project(
            params, c, data, points[p, 0], points[p, 1], points[p, 2],
            lasts[p, 0], lasts[p, 1], lasts[p, 2])


def project(obj_or_packed, points, lasts=None, c=0):
    params, data = obj_or_packed if isinstance(obj_or_packed, tuple) else packed(obj_or_packed)
    points = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 3)
    lasts = points if lasts is None else np.ascontiguousarray(lasts, dtype=np.float64)
    out = np.empty_like(points)
    _project_points(params, c, data, points, lasts.reshape(-1, 3), out)
    return out


def grid_of(obj) -> sdf.DistanceGrid:
    return mesh_kind._grid(*mesh_kind._key(obj), obj.thickness, obj.solid)


def load(name):
    m = trimesh.load(MESHES / name, force="mesh")
    return m, np.asarray(m.vertices, dtype=np.float64), np.asarray(m.faces)


def near_points(m, count, spread, seed):
    """Points at signed offsets in [-spread, spread] along the normals of surface samples."""
    p, face = trimesh.sample.sample_surface(m, count, seed=seed)
    offset = np.random.default_rng(seed).uniform(-spread, spread, count)
    return p + m.face_normals[face] * offset[:, None]


# --------------------------------------------------------------------------------------
# the mesh files
# --------------------------------------------------------------------------------------

@pytest.mark.parametrize("name, watertight, low, high", [
    ("torus.obj", True, 2000, 5000),
    ("bowl.obj", True, 2000, 5000),
    ("icosphere5k.obj", True, 5120, 5120),
    ("open_bowl.obj", False, 1000, 5000),
])
def test_mesh_files(name, watertight, low, high):
    m, v, _ = load(name)
    assert low <= len(m.faces) <= high
    assert m.is_watertight == watertight and m.is_winding_consistent
    if watertight:
        assert m.volume > 0.0  # outward
    if name == "icosphere5k.obj":
        np.testing.assert_allclose(np.linalg.norm(v, axis=1), 1.0, atol=1e-6)
    if name == "bowl.obj":  # thick hemispherical shell: outer radius 0.4, wall 0.05
        np.testing.assert_allclose(m.volume, 2 / 3 * math.pi * (0.4**3 - 0.35**3), rtol=0.01)


# --------------------------------------------------------------------------------------
# the distance grid
# --------------------------------------------------------------------------------------

@pytest.mark.parametrize("name", ["torus.obj", "bowl.obj"])
def test_grid_matches_exact_signed_distance(name):
    """Near the surface (within 2 cells) the interpolated distance is within the error the
    build measured (at cell centres, where trilinear error peaks; 25% allowance for the
    points in between), in the zone where the collider leaves points (0 <= d <= thickness +
    h), and within 0.3 h inside the solid (ridges of the distance field are blunted). The
    sign is right wherever |d| > h / 2. Far from the surface (random points of the grid
    box) the chamfer distance overestimates by at most 12% (a 3x3x3 chamfer's worst case)."""
    m, v, f = load(name)
    grid = grid_of(collider(name))
    h = grid.spacing
    assert 0.0 < grid.error <= THICKNESS / 2

    near = near_points(m, 200, 2 * h, seed=1)
    exact = exact_signed_distance(near, v, f)
    d, _ = grid.evaluate(near)
    error = np.abs(d - exact)
    zone = (exact >= 0.0) & (exact <= THICKNESS + h)
    assert zone.sum() > 30
    assert error[zone].max() <= 1.25 * grid.error
    assert error.max() <= 0.3 * h
    sure = np.abs(exact) > h / 2
    np.testing.assert_array_equal(np.sign(d[sure]), np.sign(exact[sure]))

    box_high = grid.origin + h * (np.array(grid.values.shape[::-1]) - 1)
    far = np.random.default_rng(2).uniform(grid.origin, box_high, (120, 3))
    exact = exact_signed_distance(far, v, f)
    d, _ = grid.evaluate(far)
    sure = np.abs(exact) > h / 2
    np.testing.assert_array_equal(np.sign(d[sure]), np.sign(exact[sure]))
    assert np.all(np.abs(d) >= np.abs(exact) - 0.3 * h)
    assert np.all(np.abs(d) <= 1.12 * np.abs(exact) + 0.3 * h)


def test_icosphere_grid_matches_the_sphere():
    """Distance |p| - 1 to within the faceting (the gap between the unit sphere and its
    flat faces) plus the measured interpolation error; gradient along p."""
    m, v, f = load("icosphere5k.obj")
    grid = grid_of(collider("icosphere5k.obj"))
    centroids = v[f].mean(axis=1)
    normals = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    plane_gap = 1.0 - np.abs(np.einsum("ij,ij->i", centroids, normals)
                             / np.linalg.norm(normals, axis=1)).min()
    assert 0.0 < plane_gap < 2e-3
    rng = np.random.default_rng(3)
    directions = rng.normal(size=(4000, 3))
    directions /= np.linalg.norm(directions, axis=1)[:, None]
    radii = 1.0 + rng.uniform(-0.05, 0.05, len(directions))
    d, gradient = grid.evaluate(directions * radii[:, None])
    assert np.abs(d - (radii - 1.0)).max() <= plane_gap + grid.error
    cosines = np.einsum("ij,ij->i", gradient, directions)
    assert cosines.min() > math.cos(math.radians(5.0))


def test_ray_parity_is_exact_through_edges_and_vertices():
    """Solid meshes sign the nodes beyond the exact band by the parity of crossings of a
    ray along x. On a grid aligned with a unit cube, the rays run exactly through its edges,
    its vertices and the diagonals splitting its faces into triangles: every node off the
    surface must still be classified right (each crossing counted once)."""
    box = trimesh.creation.box((1.0, 1.0, 1.0))
    n, h = 9, 0.25
    origin = np.full(3, -1.0)
    counts = np.zeros((n, n, n), dtype=np.int32)
    sdf._ray_crossings(sdf.read_only(np.asarray(box.vertices, float)),
                       sdf.read_only(np.asarray(box.faces, np.int64)), origin, h, counts)
    inside = np.cumsum(counts, axis=2) % 2 == 1  # counts[k, j, i], x fastest
    z, y, x = np.meshgrid(*[origin[0] + h * np.arange(n)] * 3, indexing="ij")
    norm = np.maximum(np.maximum(np.abs(x), np.abs(y)), np.abs(z))
    off_surface = norm != 0.5
    np.testing.assert_array_equal(inside[off_surface], (norm < 0.5)[off_surface])


def test_grid_build_refines_until_the_error_is_within_half_the_thickness():
    """The bowl's sharp rim needs a finer grid than half its median edge (about 0.02 m)."""
    _, v, f = load("bowl.obj")
    coarse = sdf.build_grid(v, f, solid=True, thickness=THICKNESS, max_nodes=200_000)
    fine = grid_of(collider("bowl.obj"))
    assert coarse.error > THICKNESS / 2 >= fine.error
    assert fine.spacing < coarse.spacing


# --------------------------------------------------------------------------------------
# projection
# --------------------------------------------------------------------------------------

@pytest.mark.parametrize("name", ["torus.obj", "bowl.obj", "icosphere5k.obj"])
def test_points_inside_or_too_close_end_at_thickness(name):
    """Points up to 2 cm inside the solid, or closer than the thickness outside, end on the
    level set d = thickness of the grid: within TINY for 99% of them, within 2% of the
    thickness for all (Newton steps near sharp edges); hence at an exact distance of at
    least the thickness minus the measured error. Farther points do not move at all."""
    m, v, f = load(name)
    obj = collider(name)
    grid = grid_of(obj)
    points = near_points(m, 400, 0.02, seed=4)
    before, _ = grid.evaluate(points)
    out = project(obj, points)
    after, _ = grid.evaluate(out)
    touched = before < THICKNESS
    assert touched.sum() > 150 and (~touched).sum() > 50
    assert np.mean(after[touched] >= THICKNESS - TINY) >= 0.99
    assert after[touched].min() >= 0.98 * THICKNESS
    np.testing.assert_array_equal(out[~touched], points[~touched])
    exact = exact_signed_distance(out[touched][:100], v, f)
    assert exact.min() >= 0.98 * THICKNESS - grid.error


def test_bowl_cavity_is_outside_the_solid():
    """Points in the bowl's cavity (inside the hemisphere of radius 0.35 - 2 thickness, below
    the rim) are outside the solid and farther than the thickness: untouched. Points within
    the thickness of the inner surface go up into the cavity, not through the wall."""
    rng = np.random.default_rng(5)
    directions = rng.normal(size=(600, 3))
    directions[:, 1] = -np.abs(directions[:, 1])  # the cavity is below the rim (y < 0)
    directions /= np.linalg.norm(directions, axis=1)[:, None]
    inner = 0.35  # inner radius of the bowl
    cavity = directions * rng.uniform(0.0, inner - 2 * THICKNESS, (600, 1))
    obj = collider("bowl.obj")
    np.testing.assert_array_equal(project(obj, cavity), cavity)

    deep = directions[directions[:, 1] < -0.3]  # away from the rim
    close = deep * (inner - 0.5 * THICKNESS)  # inside the cavity, 2.5 mm from the wall
    out = project(obj, close)
    radii = np.linalg.norm(out, axis=1)
    assert np.all(radii < inner - THICKNESS + 2 * grid_of(obj).error)  # moved inwards
    assert np.all(radii < np.linalg.norm(close, axis=1))


def test_friction_blends_between_last_and_target():
    """SPEC rule: last + (1 - friction) (target - last)."""
    m, _, _ = load("torus.obj")
    points = near_points(m, 50, 0.002, seed=6)
    points = points[grid_of(collider("torus.obj")).evaluate(points)[0] < THICKNESS]
    lasts = points + np.random.default_rng(7).normal(scale=0.003, size=points.shape)
    target = project(collider("torus.obj", friction=0.0), points, lasts)
    assert np.all(np.any(target != points, axis=1))
    np.testing.assert_array_equal(project(collider("torus.obj", friction=1.0), points, lasts),
                                  lasts)
    np.testing.assert_allclose(project(collider("torus.obj", friction=0.3), points, lasts),
                               lasts + 0.7 * (target - lasts), rtol=0, atol=1e-15)


def test_points_outside_the_grid_or_nan_are_returned_as_they_are():
    obj = collider("torus.obj")
    points = np.array([[5.0, 0.0, 0.0], [0.3, 0.5, 0.0], [np.nan, 0.0, 0.0], [0.3, np.inf, 0.0]])
    out = project(obj, points, points * 0.5)
    np.testing.assert_array_equal(out, points)


def test_placement_scale_rotation_translation():
    """world = R (scale v) + translation: an icosphere scaled by (0.5, 0.25, 0.5), turned 90
    degrees about z (its short axis becomes x) and moved: points just inside go out along
    the axes to that ellipsoid plus the thickness (within its faceting, about 1 mm)."""
    t = np.array([0.5, 0.3, -0.2])
    obj = collider("icosphere5k.obj", translation=tuple(t), rotation=(0.0, 0.0, 90.0),
                   scale=(0.5, 0.25, 0.5))
    v, f = mesh_kind.collider_mesh_arrays(obj)
    np.testing.assert_allclose(np.abs(v - t).max(axis=0), [0.25, 0.5, 0.5], atol=1e-6)
    assert not v.flags.writeable and mesh_kind.collider_mesh_arrays(obj)[0] is v
    out = project(obj, t + np.array([[0.24, 0.0, 0.0], [0.0, 0.49, 0.0], [0.0, 0.0, -0.49]]))
    np.testing.assert_allclose(out - t, [[0.25 + THICKNESS, 0, 0], [0, 0.5 + THICKNESS, 0],
                                         [0, 0, -0.5 - THICKNESS]], atol=1e-3)


def test_two_meshes_share_the_data_array():
    a, b = collider("torus.obj"), collider("icosphere5k.obj", translation=(3.0, 0.0, 0.0))
    params, data = packed(a, b)
    assert params[0, 0] == 0 and params[1, 0] == grid_of(a).values.size
    assert data.size == grid_of(a).values.size + grid_of(b).values.size
    p = np.array([[3.0, 0.99, 0.0]])
    out = project((params, data), p, c=1)
    np.testing.assert_allclose(out, [[3.0, 1.0 + THICKNESS, 0.0]], atol=2e-3)
    assert abs(grid_of(b).evaluate(out)[0][0] - THICKNESS) <= TINY
    np.testing.assert_array_equal(project((params, data), p, c=0), p)


# --------------------------------------------------------------------------------------
# one-sided surfaces
# --------------------------------------------------------------------------------------

def _shell_points(count, radius, seed):
    """Points of the open hemispherical shell (radius 0.4, below y = 0) away from its rim."""
    rng = np.random.default_rng(seed)
    d = rng.normal(size=(count, 3))
    d[:, 1] = -np.abs(d[:, 1]) - 0.5
    d /= np.linalg.norm(d, axis=1)[:, None]
    return d * radius


@pytest.mark.parametrize("outside_first", [True, False])
def test_one_sided_keeps_points_on_their_side(outside_first):
    """A point that crossed the shell during the step goes back to the side it came from,
    at the thickness; so does one that came closer than the thickness without crossing."""
    obj = collider("open_bowl.obj", solid=False)
    grid = grid_of(obj)
    sign = 1.0 if outside_first else -1.0
    lasts = _shell_points(200, 0.4 + sign * 0.004, seed=8)  # 4 mm on one side
    nows = _shell_points(200, 0.4 - sign * 0.002, seed=8)  # 2 mm on the other side
    out = project(obj, nows, lasts)
    radii = np.linalg.norm(out, axis=1)
    assert np.all(sign * (radii - 0.4) > 0.0)  # back on the side of `last`
    d_last, _ = grid.evaluate(lasts)
    d_out, _ = grid.evaluate(out)
    assert np.all(np.sign(d_out) == np.sign(d_last))
    assert np.abs(d_out).min() >= THICKNESS - TINY

    close = _shell_points(200, 0.4 + sign * 0.002, seed=9)  # same side, too close
    out = project(obj, close, _shell_points(200, 0.4 + sign * 0.003, seed=9))
    d_out, _ = grid.evaluate(out)
    assert np.all(sign * (np.linalg.norm(out, axis=1) - 0.4) > 0.0)
    assert np.abs(d_out).min() >= THICKNESS - TINY


def test_one_sided_ignores_far_points_and_the_side_flip_beyond_the_rim():
    """Beyond the open rim the sign of the distance flips along the shell's continuation
    (the cylinder x^2 + z^2 = 0.4^2 above y = 0): points moving across it 1 to 5 cm above
    the rim, slowly (through cells straddling the flip) or fast (a 5 cm step between cells
    on either side, too short to have gone through the shell), and points far from the
    shell, are untouched."""
    obj = collider("open_bowl.obj", solid=False)
    rng = np.random.default_rng(10)
    angle = rng.uniform(0.0, 2.0 * np.pi, 300)
    height = rng.uniform(0.01, 0.05, 300)
    ring = np.column_stack([np.cos(angle), np.zeros(300), np.sin(angle)])
    nows = ring * 0.399 + np.column_stack([np.zeros(300), height, np.zeros(300)])
    lasts = ring * 0.401 + np.column_stack([np.zeros(300), height, np.zeros(300)])
    np.testing.assert_array_equal(project(obj, nows, lasts), nows)
    np.testing.assert_array_equal(project(obj, lasts, nows), lasts)
    height = np.column_stack([np.zeros(300), rng.uniform(0.03, 0.05, 300), np.zeros(300)])
    nows, lasts = ring * 0.375 + height, ring * 0.425 + height
    np.testing.assert_array_equal(project(obj, nows, lasts), nows)
    np.testing.assert_array_equal(project(obj, lasts, nows), lasts)
    far = _shell_points(100, 0.3, seed=11)
    np.testing.assert_array_equal(project(obj, far, far * 1.01), far)


@njit  # not cached, as _project_points
def _far_points(params, c, data, points, lasts, out):
    for p in range(points.shape[0]):
        out[p] = mesh_kind.far(params, c, data, points[p, 0], points[p, 1], points[p, 2],
                               lasts[p, 0], lasts[p, 1], lasts[p, 2])


@pytest.mark.parametrize("name, solid", [("bowl.obj", True), ("open_bowl.obj", False)])
def test_the_pass_skips_only_points_the_projection_leaves(name, solid):
    """The colliders' pass tests mesh.far inline and calls the projection (through a
    pointer) only where it is false: far must hold only for points `project` returns as
    they are, and the pass (pack_colliders, collide_all) must move every point exactly as
    `project` does."""
    m, _, _ = load(name)
    obj = collider(name, solid=solid)
    rng = np.random.default_rng(12)
    points = np.concatenate([near_points(m, 300, 0.03, seed=12),
                             rng.uniform(-0.6, 0.6, (100, 3))])  # some outside the grid
    lasts = points + rng.normal(scale=0.004, size=points.shape)
    params, data = packed(obj)
    far = np.zeros(len(points), dtype=np.bool_)
    _far_points(params, 0, data, points, lasts, far)
    out = project((params, data), points, lasts)
    assert far.sum() > 50 and (~far).sum() > 50
    np.testing.assert_array_equal(out[far], points[far])
    assert (out[~far] != points[~far]).any(axis=1).sum() > 20
    x, last = np.ascontiguousarray(points.T), np.ascontiguousarray(lasts.T)
    collide_all(x, last, np.zeros(len(points), np.uint8), pack_colliders([obj]), 0.0, 0.0)
    np.testing.assert_array_equal(x.T, out)


def test_solid_needs_a_closed_mesh():
    with pytest.raises(SceneError, match="not closed"):
        packed(collider("open_bowl.obj", solid=True))
