"""Wind in the simulator: closed-form motions of a flat sheet and a flag that keeps flapping.

The drag law (docs/wind.md): per triangle F = -1/2 rho C_D A |v_n| v_n n, v_n the normal
component of the cloth's velocity relative to the air. A flat sheet moving along its normal
therefore feels -1/2 rho C_D A_total |v| v. Each point gets a third of its triangles' force;
giving each point a mass proportional to its share of the area (the mass map below, worked
out here from the triangulation) makes every point accelerate alike, so the sheet stays flat
and moves as one body: the closed forms hold exactly, up to the time discretisation.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from conftest import cloth_dict, scene_dict
from pipeline import Simulation, simulate
from pipeline.scene import INTEGRATORS

RHO, CD = 1.225, 1.0


def area_share_rows(nw: int, nh: int) -> list[list[float]]:
    """Each point's third of the area of its triangles, in cells, as mass-map rows (top
    edge first). Triangles per cell (A, C, B) and (B, C, D) with A = (i, j), B = (i, j+1),
    C = (i+1, j), D = (i+1, j+1), as the renderer draws them."""
    share = np.zeros((nh, nw))
    for i in range(nh - 1):
        for j in range(nw - 1):
            for tri in (((i, j), (i + 1, j), (i, j + 1)), ((i, j + 1), (i + 1, j), (i + 1, j + 1))):
                for r, c in tri:
                    share[r, c] += 0.5 / 3.0
    return share[::-1].tolist()


def sheet(nw, nh, *, gravity, wind, fps=60, spf=100, ks=2000.0, density=0.1):
    cloth = cloth_dict(nw, nh, width=1.0, height=1.0, orientation=0, damping=0.0,
                       density=density, ks=ks)
    cloth["mass_map"] = area_share_rows(nw, nh)
    d = scene_dict(cloth, gravity=gravity, frames_per_sec=fps, steps_per_frame=spf)
    d["wind"] = wind
    return d


def test_area_shares_add_up_to_the_sheet():
    rows = np.array(area_share_rows(7, 5))
    assert rows.sum() == pytest.approx(6 * 4)  # cells
    assert rows[2, 3] == pytest.approx(1.0)  # an inner point carries one cell


@pytest.mark.parametrize("integrator", ["verlet", "rk4"])
def test_falling_sheet_reaches_the_drag_law_terminal_velocity(integrator):
    """Still air, gravity: m dv/dt = m g - 1/2 rho C_D A v^2 gives v(t) = v_T tanh(g t / v_T)
    with v_T = sqrt(2 M g / (rho C_D A))."""
    nw = nh = 9
    g = 9.8
    d = sheet(nw, nh, gravity=(0.0, -g, 0.0), wind={"drag": CD, "lift": 0.5})
    d["simulation"]["integrator"] = integrator
    sim = Simulation(d)
    mass = sim.model.point_mass.sum()
    v_t = math.sqrt(2.0 * mass * g / (RHO * CD * 1.0))
    assert 0.5 < v_t < 3.0  # a light sheet: terminal speed ~1 m/s
    for frame in (6, 15, 30, 60):  # 0.1 .. 1 s
        sim.advance(frame - sim.step_count // 100)
        t = sim.time
        v = -sim.velocities[:, 1]
        assert np.ptp(v) < 1e-6 * v_t  # flat: every point at the same speed
        assert v.mean() == pytest.approx(v_t * math.tanh(g * t / v_t), rel=2e-3)
    y = sim.positions[:, 1]
    assert np.ptp(y) < 1e-6  # still flat after 1 s


@pytest.mark.parametrize("integrator", INTEGRATORS)
def test_sheet_in_steady_wind_follows_the_closed_form(integrator):
    """No gravity, wind U along the sheet's normal, start at rest:
    dv/dt = k (U - v)^2 with k = rho C_D A / (2 M) gives v(t) = U - 1 / (1/U + k t).
    Every integrator sees the wind through the shared force function."""
    nw = nh = 9
    u = 4.0
    # no springs: explicit Euler would amplify rounding noise in undamped springs, and the
    # points move alike without them
    d = sheet(nw, nh, gravity=(0.0, 0.0, 0.0), wind={"velocity": [0.0, u, 0.0], "drag": CD},
              ks=0.0)
    d["simulation"]["integrator"] = integrator
    sim = Simulation(d)
    k = RHO * CD * 1.0 / (2.0 * sim.model.point_mass.sum())
    for frame in (6, 30, 90):
        sim.advance(frame - sim.step_count // 100)
        v = sim.velocities[:, 1]
        assert np.ptp(v) < 1e-7 * u  # flat: all points alike, up to rounding
        assert v.mean() == pytest.approx(u - 1.0 / (1.0 / u + k * sim.time), rel=2e-3)
    assert np.abs(sim.velocities[:, [0, 2]]).max() < 1e-7 * u  # no sideways force on a flat sheet


def test_drag_on_an_edge_on_sheet_is_zero_and_lift_acts_across_the_flow():
    """Wind in the sheet's own plane exerts no force; tilted 30 degrees it lifts the sheet
    (a force with a component across the flow, on the side the flow pushes the sheet)."""
    cloth = cloth_dict(5, 5, orientation=0, damping=0.0, density=0.1, ks=2000.0)
    flat = scene_dict(cloth, gravity=(0, 0, 0), frames_per_sec=60, steps_per_frame=100)
    flat["wind"] = {"velocity": [3.0, 0.0, 0.0], "lift": 0.5}
    frames = simulate(flat, 5)
    assert np.array_equal(frames[-1], Simulation(flat).positions)  # nothing moves
    tilted = dict(flat, wind={"velocity": [3.0 * math.cos(math.radians(30)),
                                           -3.0 * math.sin(math.radians(30)), 0.0],
                              "drag": 0.0, "lift": 0.5})
    sim = Simulation(tilted)
    sim.step(1)  # the first step's velocity change: the force at rest, before the flow turns
    v = sim.velocities.mean(axis=0)
    # lift is perpendicular to the relative flow (the air comes along (cos, -sin) 30 deg)
    flow = np.array([math.cos(math.radians(30)), -math.sin(math.radians(30)), 0.0])
    assert abs(np.dot(v, flow)) < 1e-6 * np.linalg.norm(v)
    assert v[1] < 0.0  # pushed the way the air blows through the sheet (down)


def test_gusts_are_deterministic_and_seeded():
    cloth = cloth_dict(6, 6, orientation=1, damping=0.5, density=0.2, ks=500.0,
                       pinned=[(0, 5), (0, 0)])
    d = scene_dict(cloth, frames_per_sec=60, steps_per_frame=20, seed=3)
    d["wind"] = {"velocity": [2.0, 0.0, 1.0], "gust": 1.5, "gust_scale": 0.5, "gust_time": 0.3}
    a, b = simulate(d, 20), simulate(d, 20)
    assert np.array_equal(a, b)
    other = dict(d, simulation=dict(d["simulation"], seed=4))
    c = simulate(other, 20)
    assert not np.array_equal(a, c)


def test_flag_keeps_flapping_for_30_seconds():
    """A flag pinned along one edge in a gusty wind along it: kinetic energy does not decay
    to zero (every second of the last ten has a mean well above the still-flag level) and
    the run stays finite (no divergence) for 30 s of simulated time."""
    nw, nh = 24, 16
    cloth = cloth_dict(nw, nh, width=1.2, height=0.8, orientation=1, damping=0.2,
                       density=0.2, ks=800.0, thickness=0.01,
                       pinned=[(0, i) for i in range(nh)])
    d = scene_dict(cloth, frames_per_sec=30, steps_per_frame=60)
    d["wind"] = {"velocity": [6.0, 0.0, 0.0], "gust": 1.5, "gust_scale": 0.6, "gust_time": 0.5}
    sim = Simulation(d)
    mass = sim.model.point_mass
    kinetic = []
    for _ in range(30 * 30):
        sim.advance(1)
        v = sim.velocities
        kinetic.append(0.5 * float(np.sum(mass[:, None] * v * v)))
    kinetic = np.array(kinetic)
    assert np.all(np.isfinite(kinetic)) and np.all(np.isfinite(sim.positions))
    per_second = kinetic.reshape(30, 30).mean(axis=1)
    # a flag moving at 5 cm/s on average has 0.5 * M * 0.05^2 of kinetic energy
    floor = 0.5 * mass.sum() * 0.05 ** 2
    assert per_second[20:].min() > floor, per_second
    assert np.ptp(sim.positions[:, 2]) > 0.05  # it waves out of its plane, not just streams
