"""Box colliders, keyframed (moving) colliders and the rest-frame transforms."""
from __future__ import annotations

import math

import numpy as np
import pytest

from conftest import cloth_dict, scene_dict
from pipeline import Simulation, simulate
from pipeline.physics.colliders import collide_all, euler_matrix, pack_colliders, pose_at
from pipeline.scene import Box, Keyframe, Plane, Sphere, load_scene


def collide(colliders, p, last, t_start=0.0, t_end=0.0):
    """One point through the simulation's own collider pass (the kernel every scene has
    compiled): where it ends for a step from `last` at t_start to t_end."""
    x = np.asarray(p, float).reshape(3, 1).copy()
    collide_all(x, np.asarray(last, float).reshape(3, 1).copy(), np.zeros(1, np.uint8),
                pack_colliders(colliders), float(t_start), float(t_end))
    return x[:, 0]


def test_euler_matrix_is_rz_ry_rx():
    rx, ry, rz = 30.0, -50.0, 110.0

    def axis(k, deg):
        c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
        i, j = [(1, 2), (2, 0), (0, 1)][k]
        m = np.eye(3)
        m[i, i] = m[j, j] = c
        m[i, j], m[j, i] = -s, s
        return m

    expected = axis(2, rz) @ axis(1, ry) @ axis(0, rx)
    np.testing.assert_allclose(euler_matrix((rx, ry, rz)), expected, atol=1e-15)
    np.testing.assert_allclose(euler_matrix((0, 0, 90)) @ [1, 0, 0], [0, 1, 0], atol=1e-15)


# --- box --------------------------------------------------------------------------------

def test_box_pushes_an_inside_point_out_through_the_nearest_face():
    box = Box(center=(1.0, 2.0, 3.0), half_extents=(0.5, 0.2, 1.0), friction=0.0)
    # 0.05 below the top face (y = 2.2), well inside along x and z: out through the top,
    # to SURFACE_OFFSET (1e-4) above it
    np.testing.assert_allclose(collide([box], (1.1, 2.15, 3.3), (1.1, 2.3, 3.3)),
                               (1.1, 2.2001, 3.3), atol=1e-15)
    # nearest face is x = 0.5 (depth 0.02)
    np.testing.assert_allclose(collide([box], (0.52, 2.0, 3.0), (0.4, 2.0, 3.0)),
                               (0.4999, 2.0, 3.0), atol=1e-15)
    outside = (1.0, 2.3, 3.0)
    assert tuple(collide([box], outside, outside)) == outside


def test_box_rotation_and_friction():
    # a box turned 90 degrees about z: its local x axis is the world y axis
    box = Box(center=(0.0, 0.0, 0.0), half_extents=(1.0, 0.1, 0.5), friction=0.25,
              rotation=(0.0, 0.0, 90.0))
    # world (0.05, 0.3, 0): local (0.3, -0.05, 0): nearest face is local y = -0.1 = world x 0.1
    last = np.array([0.2, 0.3, 0.1])
    target = np.array([0.1001, 0.3, 0.0])
    got = collide([box], (0.05, 0.3, 0.0), last)
    np.testing.assert_allclose(got, last + 0.75 * (target - last), atol=1e-14)
    # the same point is outside the unrotated box's x extent? no: inside it too, but there
    # the nearest face is y = 0.1 (depth 0.0 along local y = world y 0.3 > 0.1 -> outside)
    unrotated = Box(center=(0.0, 0.0, 0.0), half_extents=(1.0, 0.1, 0.5), friction=0.25)
    assert tuple(collide([unrotated], (0.05, 0.3, 0.0), last)) == (0.05, 0.3, 0.0)


def test_cloth_dropped_over_a_table_edge_drapes_and_stays_out_of_the_box():
    """A 1 m horizontal cloth at y = 1 falls on a table (top y = 0.8) whose edge runs under
    the middle of the cloth: the half over the table rests on it, the other half hangs down
    past the edge, and no point is inside the box at any frame."""
    box = {"center": [-0.5, 0.4, 0.5], "half_extents": [1.0, 0.4, 1.5], "friction": 0.5}
    d = scene_dict(cloth_dict(21, 21, ks=2000.0, density=0.5, damping=0.2, thickness=0.01),
                   frames_per_sec=60, steps_per_frame=40)
    d["box"] = box
    frames = simulate(d, 120)
    q = frames - np.array(box["center"])  # axis-aligned box: local = world - center
    h = np.array(box["half_extents"])
    depth = np.min(h - np.abs(q), axis=2)  # > 0 inside
    assert depth.max() <= 1e-4  # the stretch limit may nudge a point a hair inside
    last = frames[-1].reshape(21, 21, 3)
    inner = last[:, :4]  # x <= 0.15: lies flat on the table top
    assert np.all(np.abs(inner[..., 1] - 0.8) < 1e-3)
    assert inner[..., 1].min() >= 0.8  # on the face, not in it
    near_edge = last[:, 4:10]  # 0.2 <= x <= 0.45: buckles into a low ridge before the edge
    assert np.all((near_edge[..., 1] > 0.8) & (near_edge[..., 1] < 0.86))
    beyond = last[:, -1]  # the far edge, x = 1 at rest
    assert beyond[:, 1].max() < 0.5 and beyond[:, 0].max() < 0.8  # hangs down past the edge


# --- keyframes ----------------------------------------------------------------------------

def test_pose_interpolates_linearly_and_holds_outside_the_keys():
    keys = np.zeros((3, 7))
    keys[:, 0] = (1.0, 2.0, 4.0)
    keys[1, 1:4] = (2.0, 0.0, -2.0)
    keys[2, 1:4] = (2.0, 4.0, -2.0)
    keys[2, 6] = math.pi / 2  # 90 degrees about z at t = 4
    out = np.empty(12)
    for t, translation, angle in ((0.0, (0, 0, 0), 0.0), (1.5, (1, 0, -1), 0.0),
                                  (3.0, (2, 2, -2), math.pi / 4), (9.0, (2, 4, -2), math.pi / 2)):
        pose_at(keys, 3, t, out)
        np.testing.assert_allclose(out[9:], translation, atol=1e-15)
        np.testing.assert_allclose(out[:9].reshape(3, 3), euler_matrix((0, 0, math.degrees(angle))),
                                   atol=1e-15)


def test_moving_sphere_sees_points_in_its_own_frame():
    """A sphere moving +x by 1 m/s: a point at rest that the sphere's surface reaches is
    pushed out; with friction 1 a touching point is carried exactly with the sphere."""
    keys = (Keyframe(0.0), Keyframe(1.0, translation=(1.0, 0.0, 0.0)))
    moving = Sphere(origin=(0.0, 0.0, 0.0), radius=0.5, friction=1.0, keyframes=keys)
    # at t = 0.5 the sphere is centred at x = 0.5; a point at (0.9, 0, 0) is inside
    last = np.array([0.9, 0.0, 0.0])
    got = collide([moving], last, last, 0.49, 0.5)
    np.testing.assert_allclose(got, last + [0.01, 0.0, 0.0], atol=1e-14)  # carried along
    frictionless = Sphere(origin=(0.0, 0.0, 0.0), radius=0.5, friction=0.0, keyframes=keys)
    np.testing.assert_allclose(collide([frictionless], last, last, 0.49, 0.5),
                               (1.0, 0.0, 0.0), atol=1e-14)  # pushed to the surface
    # a point the sphere has not reached is untouched, bit for bit
    far = (1.2, 0.1, 0.0)
    assert tuple(collide([moving], far, far, 0.49, 0.5)) == far


def test_rotating_box_carries_a_stuck_point_around_its_axis():
    keys = (Keyframe(0.0), Keyframe(1.0, rotation=(0.0, 90.0, 0.0)))
    box = Box(center=(0.0, 0.0, 0.0), half_extents=(1.0, 0.1, 1.0), friction=1.0, keyframes=keys)
    # a point resting on top at (0.5, 0.1, 0) sinks slightly; over the step t 0 -> 0.5 the
    # box turns 45 degrees about y, and friction 1 carries the point with it
    got = collide([box], (0.5, 0.09, 0.0), (0.5, 0.1, 0.0), 0.0, 0.5)
    c = math.cos(math.radians(45.0))
    np.testing.assert_allclose(got, (0.5 * c, 0.1, -0.5 * c), atol=1e-14)


@pytest.mark.parametrize("friction, expected_shift", [(1.0, 0.1), (0.0, 0.0)])
def test_cloth_on_a_translating_plane_moves_with_it_only_under_friction(friction, expected_shift):
    """A cloth resting on a floor that slides along x at 0.1 m/s for 1 s: with friction 1
    it rides along (moves 0.1 m), with friction 0 it stays put."""
    plane = {"point": [0.0, 0.99, 0.0], "normal": [0.0, 1.0, 0.0], "friction": friction,
             "keyframes": [{"time": 0.3}, {"time": 1.3, "translation": [0.1, 0.0, 0.0]}]}
    d = scene_dict(cloth_dict(8, 8, ks=500.0, density=0.5, damping=0.2),
                   frames_per_sec=100, steps_per_frame=20)
    d["plane"] = plane
    sim = Simulation(d)
    sim.advance(30)  # settles onto the floor before the floor starts moving at t = 0.3 s
    start = sim.positions.copy()
    assert np.all(np.abs(start[:, 1] - 0.99) < 2e-3)
    sim.advance(100)
    shift = sim.positions - start
    assert np.mean(shift[:, 0]) == pytest.approx(expected_shift, abs=2e-3)
    assert np.abs(shift[:, 2]).max() < 1e-3
    assert np.all(sim.positions[:, 1] > 0.99)  # never below the floor


def test_static_colliders_pack_no_motion_and_keyframes_load_from_json(tmp_path):
    table = pack_colliders([Plane((0, 0, 0), (0, 1, 0), 0.5)])
    assert table.key_count.tolist() == [0]
    d = scene_dict(cloth_dict(4, 4))
    d["sphere"] = {"origin": [0, 0, 0], "radius": 0.3, "friction": 0.2,
                   "keyframes": [{"time": 0, "rotation": [0, 0, 10]},
                                 {"time": 2, "translation": [0, 1, 0]}]}
    s = load_scene(d)
    assert s.colliders[0].keyframes == (Keyframe(0.0, (0.0, 0.0, 0.0), (0.0, 0.0, 10.0)),
                                        Keyframe(2.0, (0.0, 1.0, 0.0), (0.0, 0.0, 0.0)))
    table = pack_colliders(s.colliders)
    assert table.key_count.tolist() == [2]
    np.testing.assert_allclose(table.keys[0, 0], [0, 0, 0, 0, 0, 0, math.radians(10)])


def test_the_parallel_loop_over_the_points_moves_them_as_the_serial_one():
    """A cloth of PARALLEL_POINTS points or more goes through the colliders in parallel
    chunks, a smaller one in one call: the same positions, bit for bit (each point meets the
    colliders on its own), for points inside, on and outside a moving box and a sphere."""
    from pipeline.physics.forces import PARALLEL_POINTS

    colliders = [Sphere((0.1, 0.0, 0.0), 0.5, friction=0.3),
                 Box((0.0, 0.2, 0.0), (0.6, 0.3, 0.4), 0.2, (0, 20, 10),
                     (Keyframe(0.0), Keyframe(1.0, (0.1, 0, 0), (0, 30, 0))))]
    rng = np.random.default_rng(7)
    last = rng.uniform(-0.8, 0.8, (3, PARALLEL_POINTS + 11))
    moved = last + rng.normal(0.0, 0.05, last.shape)
    pinned = (rng.random(last.shape[1]) < 0.05).astype(np.uint8)
    ends = []
    for points in (0, PARALLEL_POINTS):  # the serial loop, then the parallel one
        table = pack_colliders(colliders, points)
        x = moved.copy()
        collide_all(x, last.copy(), pinned, table, 0.25, 0.26)
        ends.append(x)
    assert [pack_colliders(colliders, n).points.dispatcher.py_func.__name__
            for n in (PARALLEL_POINTS - 1, PARALLEL_POINTS)] == ["_collide_serially",
                                                               "_collide_in_chunks"]
    assert not np.array_equal(ends[0], moved)  # the colliders moved points
    assert ends[0].tobytes() == ends[1].tobytes()
