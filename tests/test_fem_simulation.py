"""The FEM model (`"model": "fem"`) inside the simulator: integrators, statics, stability,
colliders and wind. The kernels themselves are tested in test_fem_kernels.py."""
from __future__ import annotations

import numpy as np
import pytest

from conftest import cloth_dict, scene_dict, scene_path
from pipeline import Simulation, load_scene
from pipeline.physics.forces import elastic_energy, total_force_now
from pipeline.physics.errors import DivergenceError, StabilityWarning

FREE_INTEGRATORS = ("verlet", "euler", "symplectic-euler", "rk4", "implicit-euler")


def fem_scene(nw=8, nh=8, *, pinned=(), orientation=1, damping=0.0, steps_per_frame=30,
              gravity=(0.0, -9.8, 0.0), integrator="verlet", material=None, **kw) -> dict:
    scene = scene_dict(cloth_dict(nw, nh, orientation=orientation, damping=damping,
                                  pinned=pinned), gravity=gravity,
                       steps_per_frame=steps_per_frame, **kw)
    scene["simulation"].update(model="fem", integrator=integrator)
    if material is not None:
        scene["cloth"]["fem"] = material
    return scene


def test_a_scene_naming_only_the_model_gets_cotton_at_the_course_step():
    scene = load_scene(scene_path("pinned2"), overrides=["simulation.model=fem"])
    assert scene.cloth.fem.density == 0.15 and scene.cloth.fem.stretch == 300.0
    sim = Simulation(scene)
    # the lumped masses carry the whole sheet: density * area (not the classic cloth.density)
    assert sim.model.point_mass.sum() == pytest.approx(0.15 * scene.cloth.width
                                                       * scene.cloth.height, rel=1e-12)
    assert sim.dt < sim.dt_max  # the course's 90 x 30 steps per second stay below the limit


@pytest.mark.parametrize("integrator", FREE_INTEGRATORS)
def test_every_integrator_converges_to_the_same_motion(integrator):
    """A hanging sheet released from rest, 0.05 s: each integrator at a small step stays
    within its truncation error of RK4 at a quarter of that step."""
    pins = ((0, 7), (7, 7))

    def run(name, spf):
        sim = Simulation(fem_scene(pinned=pins, integrator=name, steps_per_frame=spf,
                                   material={"bending": 1e-4}))
        sim.step(int(round(0.05 / sim.dt)))
        return sim.positions.copy(), Simulation(fem_scene(pinned=pins)).positions

    reference, start = run("rk4", 960)
    moved = np.abs(reference - start).max()
    x, _ = run(integrator, 240)
    assert moved > 5e-3  # the sheet did fall and stretch
    error = np.abs(x - reference).max()
    # O(dt) ~ 1e-3 of the motion: the first-order methods, and the classic Verlet, whose
    # start from x_last = x0 puts a dt^2 / 2 error in the first step; RK4: far below
    limit = 1e-5 if integrator == "rk4" else 3e-3
    assert error < limit * moved, (integrator, error, moved)


def test_hanging_sheet_comes_to_rest_with_zero_net_force():
    nw = nh = 8
    scene = fem_scene(nw, nh, pinned=((0, nh - 1), (nw - 1, nh - 1)), damping=10.0,
                      integrator="implicit-euler", steps_per_frame=1,
                      material={"stretch": 60.0, "shear": 6.0, "bending": 1e-3})
    scene["simulation"]["frames_per_sec"] = 30  # large implicit steps: close to Newton
    sim = Simulation(scene)
    sim.advance(6 * 30)  # 6 s
    s = sim.system
    x = np.ascontiguousarray(sim.positions.T)
    f = np.empty_like(x)
    total_force_now(x, np.zeros_like(x), sim.time, s, f)
    pinned = sim.pinned
    weight = s.mass * 9.8
    residual = np.linalg.norm(f[:, ~pinned], axis=0) / weight[~pinned]
    assert residual.max() < 1e-5  # every free point: forces balance to 1e-5 of its weight
    assert np.abs(sim.velocities).max() < 1e-5
    # the two pins carry the weight of the free points (not half each: the triangles' diagonals
    # all run one way, so the mesh is not mirror-symmetric)
    held = f[:, pinned] - s.mass[pinned] * s.gravity[:, None]  # the elastic pull on a pin
    assert held[1].sum() == pytest.approx(-weight[~pinned].sum(), rel=1e-5)
    # the sheet really hangs: stretched near the pins, the middle of the top edge sags
    top = sim.positions[(nh - 1) * nw:]
    assert top[nw // 2, 1] < top[0, 1] - 0.05


@pytest.mark.parametrize("factor, diverges", [(0.95, False), (1.05, True)])
def test_verlet_fails_where_the_fem_stability_limit_says(factor, diverges):
    """No gravity, no pins, no damping: a sheet with a little noise on its rest positions.
    5 % below dt_max the noise stays bounded (the energy it holds cannot grow); 5 % above,
    the highest mode grows and the guard stops the run within a few steps."""
    scene = fem_scene(10, 10, gravity=(0.0, 0.0, 0.0))
    probe = Simulation(scene)
    dt = factor * probe.dt_max
    scene["simulation"]["steps_per_frame"] = 1
    scene["simulation"]["frames_per_sec"] = 1.0 / dt
    x0 = probe.positions + np.random.default_rng(3).normal(0.0, 1e-4, probe.positions.shape)
    if diverges:
        with pytest.warns(StabilityWarning, match="exceeds the explicit stability limit"):
            sim = Simulation(scene, initial_positions=x0)
        with pytest.raises(DivergenceError, match="kinetic energy|non-finite"):
            sim.step(4000)
        assert sim.step_count < 100
    else:
        sim = Simulation(scene, initial_positions=x0)
        energy = elastic_energy(np.ascontiguousarray(x0.T), sim.system)
        sim.step(4000)
        kinetic = 0.5 * (sim.system.mass * (sim.velocities**2).sum(axis=1)).sum()
        assert kinetic < 4.0 * energy  # Verlet's velocity estimate may overstate it near dt_max
        assert np.abs(sim.positions - x0).max() < 1e-2


@pytest.mark.parametrize("integrator", ["verlet", "rk4", "implicit-euler"])
def test_fem_cloth_on_a_sphere_in_wind_stays_outside_and_is_deterministic(integrator):
    def run():
        scene = fem_scene(12, 12, orientation=0, damping=0.2, integrator=integrator,
                          spheres=[((0.5, 0.6, 0.5), 0.25, 0.3)])
        scene["wind"] = {"velocity": [1.0, 0.0, 0.0], "gust": 0.5}
        sim = Simulation(scene)
        frames = []
        for _ in range(45):  # 0.5 s: the cloth lands and drapes
            sim.advance(1)
            frames.append(sim.positions.copy())
        return np.array(frames)

    a = run()
    assert np.isfinite(a).all()
    distance = np.linalg.norm(a - np.array([0.5, 0.6, 0.5]), axis=2)
    # no point inside the sphere at any frame (beyond the friction rule's chord, < 1 um)
    assert distance.min() >= 0.25 - 1e-6
    assert a[-1, :, 1].min() < 0.6  # it draped past the sphere's equator
    np.testing.assert_array_equal(run(), a)  # same scene, same frames, bit for bit


def test_fem_needs_no_edit_to_render(tmp_path):
    from pipeline.cli import main

    out = tmp_path / "fem.png"
    code = main([str(scene_path("sphere")), "--set", "simulation.model=fem", "--out", str(out),
                 "--at", "0.3", "--size", "64x64", "--quiet"])
    assert code == 0 and out.stat().st_size > 0
