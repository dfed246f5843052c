"""The integrators of issue 6 (pipeline/integrators/*) against closed forms and each other.

Orders of convergence are measured, not assumed: the position error at t = 1 s as the step
halves, on a single spring-mass oscillator (exact solution A cos(omega t)) and on a small
undamped grid (against rk4 at a much smaller step). Energy behaviour over 1e5 steps,
stability around the theoretical explicit limit 2 / omega_max and at 100x it, contact with
the course sphere, and the integrator choice through the scene are checked too.
Everything runs on one numba thread (tiny grids: threads only add overhead) and small grids.
"""
from __future__ import annotations

import importlib
import math
import warnings

import numba
import numpy as np
import pytest

from pipeline import load_scene
from pipeline.cli.bench import Run, is_stable, resized, scene_data
from pipeline.physics.integrators import state_class
from pipeline.scene import INTEGRATORS
from pipeline.simulation import Simulation
from pipeline.physics.system import stability_limit

from conftest import cloth_dict, scene_dict, scene_path

EXPECTED_ORDER = {"verlet": 2, "euler": 1, "symplectic-euler": 1, "rk4": 4,
                  "implicit-euler": 1, "xpbd": 1, "vbd": 1}
SYMPLECTIC = ("verlet", "symplectic-euler")
EXPLICIT = ("verlet", "euler", "symplectic-euler", "rk4")


@pytest.fixture(autouse=True, scope="module")
def one_thread():
    before = numba.get_num_threads()
    numba.set_num_threads(1)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # StabilityWarning at the large steps, on purpose
        yield
    numba.set_num_threads(before)


# --- the benchmark itself (first: it compiles every integrator for both models, which the
# FEM tests of another file then load from numba's cache instead of compiling beside it) ---

def test_bench_writes_charts_and_csv(tmp_path):
    pytest.importorskip("matplotlib")
    from pipeline.cli.bench import AUTO_TOLERANCES, main

    out = tmp_path / "bench"
    assert main([str(scene_path("pinned2")), "--out", str(out), "--grid", "6",
                 "--stability-grid", "6", "--stability-time", "0.1", "--time", "0.1",
                 "--sweep", "8,30",
                 "--ks", "1e4", "--stretch", "300"]) == 0
    for stem in ("pinned2_work_precision", "pinned2_stability"):
        for ext in ("png", "svg", "csv"):
            assert (out / f"{stem}.{ext}").stat().st_size > 0
    # both models by default (tests/test_bench.py covers the FEM path), every integrator
    fem = len(INTEGRATORS)
    auto = len(AUTO_TOLERANCES)  # fidelity auto: one point per tolerance and model
    rows = (out / "pinned2_work_precision.csv").read_text().splitlines()
    assert len(rows) == 1 + 2 * len(INTEGRATORS) + 2 * fem + 2 * auto
    assert rows[0].startswith("model,integrator,")
    assert sum(r.startswith("classic,xpbd,") for r in rows) == 2
    assert sum(r.startswith("classic,auto,") for r in rows) == auto
    assert sum(r.startswith("fem,") for r in rows) == 2 * fem + auto
    stab = (out / "pinned2_stability.csv").read_text().splitlines()
    assert len(stab) == 1 + len(INTEGRATORS) + fem


def test_every_integrator_has_a_module_behind_the_same_interface():
    assert set(EXPECTED_ORDER) == set(INTEGRATORS)
    for name in INTEGRATORS:
        module = importlib.import_module("pipeline.physics.integrators." + name.replace("-", "_"))
        assert module.NAME == name
        assert state_class(name) is module.State
    with pytest.raises(ValueError, match="unknown integrator"):
        state_class("leapfrog")


def test_integrator_chosen_through_scene_overrides():
    scene = load_scene(scene_path("pinned2"), overrides=["simulation.integrator=rk4"])
    assert scene.simulation.integrator == "rk4"
    sim = Simulation(scene)
    assert type(sim._state) is state_class("rk4")
    sim.step(3)
    assert sim.positions.shape == (2500, 3) and np.all(np.isfinite(sim.velocities))
    assert sim.last_positions.shape == (2500, 3)


# --- (a) orders of convergence ----------------------------------------------------------

OSCILLATOR_KS = 50.0  # N/m on 1 kg: omega = sqrt(50) rad/s
AMPLITUDE = 0.02  # m: 2 % strain, far from Provot's 10 %


def _oscillator():
    """2x2 cloth, 1 kg points, shearing off, left column pinned, no gravity: the two right
    points are two independent spring-mass oscillators along x (their vertical spring moves
    rigidly with them). Start displaced by AMPLITUDE, at rest."""
    cloth = cloth_dict(2, 2, density=4.0, ks=OSCILLATOR_KS, shearing=False, bending=False,
                       pinned=[(0, 0), (0, 1)])
    scene = scene_dict(cloth, gravity=(0.0, 0.0, 0.0))
    start = Run(scene, "verlet").model.initial_positions.copy()
    start[[1, 3], 0] += AMPLITUDE
    return scene, start


def _observed_orders(errors):
    return [math.log2(errors[i] / errors[i + 1]) for i in range(len(errors) - 1)]


@pytest.mark.parametrize("name", INTEGRATORS)
def test_order_of_convergence_on_a_spring_mass_oscillator(name):
    scene, start = _oscillator()
    omega = math.sqrt(OSCILLATOR_KS / 1.0)
    exact = 1.0 + AMPLITUDE * math.cos(omega * 1.0)
    steps = (50, 100, 200, 400) if name == "rk4" else (400, 800, 1600, 3200)
    errors = []
    for n in steps:
        run = Run(scene, name, dt=1.0 / n, start_positions=start)
        assert run.advance(n)
        errors.append(abs(run.x[0, 1] - exact))
    orders = _observed_orders(errors)
    assert all(abs(p - EXPECTED_ORDER[name]) < 0.3 for p in orders), (errors, orders)


def _small_grid():
    """4x4 undamped cloth, two corners pinned, no gravity, every free point displaced by up
    to 0.5 % of the spacing (springs stay far below Provot's cap)."""
    cloth = cloth_dict(4, 4, density=1.0, ks=10.0, pinned=[(0, 0), (3, 0)])
    scene = scene_dict(cloth, gravity=(0.0, 0.0, 0.0))
    start = Run(scene, "verlet").model.initial_positions.copy()
    rng = np.random.default_rng(7)
    free = np.ones(16, dtype=bool)
    free[[0, 3]] = False  # the pinned corners stay
    start[free] += rng.uniform(-1, 1, size=(14, 3)) * (0.005 / 3)
    return scene, start


@pytest.mark.parametrize("name", INTEGRATORS)
def test_order_of_convergence_on_a_small_grid(name):
    scene, start = _small_grid()
    reference = Run(scene, "rk4", dt=1.0 / 25600, start_positions=start)
    assert reference.advance(25600)
    steps = (100, 200, 400) if name == "rk4" else (1600, 3200, 6400)
    errors = []
    for n in steps:
        run = Run(scene, name, dt=1.0 / n, start_positions=start)
        assert run.advance(n)
        errors.append(np.sqrt(np.mean((run.x - reference.x) ** 2)))
    orders = _observed_orders(errors)
    assert all(abs(p - EXPECTED_ORDER[name]) < 0.3 for p in orders), (errors, orders)


# --- (c) energy -----------------------------------------------------------------------------

ENERGY_STEPS = 100_000


def _energy_track(name, steps=ENERGY_STEPS):
    """Energy (kinetic + springs) of a free 4x4 cloth, no gravity, no damping, no pins,
    every 1000 steps over `steps` steps of dt = 1e-3 s (omega_max dt ~ 0.04)."""
    cloth = cloth_dict(4, 4, density=1.0, ks=10.0)
    scene = scene_dict(cloth, gravity=(0.0, 0.0, 0.0))
    start = Run(scene, "verlet").model.initial_positions.copy()
    start += np.random.default_rng(3).uniform(-1, 1, size=start.shape) * (0.01 / 3)
    run = Run(scene, name, dt=1e-3, start_positions=start)
    energies = [run.energy()]
    for _ in range(steps // 1000):
        if not run.advance(1000):
            energies.append(math.inf)  # the guard tripped: energy came from nowhere
            break
        energies.append(run.energy())
    return np.array(energies)


@pytest.mark.parametrize("name", SYMPLECTIC)
def test_symplectic_methods_keep_energy_in_a_band(name):
    e = _energy_track(name)
    assert len(e) == ENERGY_STEPS // 1000 + 1 and np.all(np.isfinite(e))
    band = (e.max() - e.min()) / e[0]
    assert band < 0.05, band
    # no drift: the band of the last tenth is like that of the first
    first, last = e[: len(e) // 10], e[-len(e) // 10:]
    assert abs(last.mean() - first.mean()) / e[0] < 0.02


def test_explicit_euler_gains_energy():
    e = _energy_track("euler")
    assert e[-1] > 2.0 * e[0], e[-1] / e[0]


def test_implicit_euler_loses_energy():
    e = _energy_track("implicit-euler", 10_000)  # it keeps 3 % of its energy by then
    assert np.all(np.diff(e) <= 1e-12 * e[0])  # monotone
    assert e[-1] < 0.5 * e[0], e[-1] / e[0]


# --- stability ------------------------------------------------------------------------------

def _pinned2_small(ks=1e4):
    data = resized(scene_data(scene_path("pinned2")), 10, 10)
    data["cloth"]["ks"] = ks
    return data


def _theory(data):
    omega, _ = stability_limit(Run(data, "verlet").model)
    return 2.0 / omega


@pytest.mark.parametrize("name", EXPLICIT)
def test_explicit_methods_fail_near_the_theoretical_limit(name):
    data = _pinned2_small()
    limit = _theory(data)
    # RK4's stability region reaches 2.83 on the imaginary axis: 1.41 x 2 / omega
    above = 2.0 if name == "rk4" else 1.5
    assert not is_stable(data, name, above * limit)
    if name != "euler":  # explicit Euler needs damping to be stable at all (far below)
        assert is_stable(data, name, 0.8 * limit)


def test_implicit_euler_stable_at_100x_the_explicit_limit():
    data = _pinned2_small()
    dt = 100.0 * _theory(data)  # 0.87 s
    assert is_stable(data, "implicit-euler", dt, t_end=20 * dt)
    assert not is_stable(data, "symplectic-euler", 2.0 * _theory(data))


# --- contact --------------------------------------------------------------------------------

@pytest.mark.parametrize("name", [n for n in INTEGRATORS if n != "vbd"])
def test_course_sphere_scene_without_penetration(name):
    # (VBD's collider test is tests/test_vbd.py's: its ten sweeps a step at the course's 30
    # steps per frame cost ~24 s on this 50x50 cloth)
    """Same tolerance as the Verlet test (test_simulation): Provot's chords over the sphere
    may sink a point by at most the sagitta (1.1 s)^2 / (8 r)."""
    scene = load_scene(scene_path("sphere"), overrides=[f"simulation.integrator={name}"])
    (sphere,) = scene.colliders
    origin = np.array(sphere.origin)
    spacing = scene.cloth.width / (scene.cloth.num_width_points - 1)
    sagitta = (1.1 * spacing) ** 2 / (8 * sphere.radius)
    sim = Simulation(scene)
    for _ in range(60):  # 2/3 s: the cloth reaches the sphere at about 0.35 s
        sim.advance(1)
        depth = sphere.radius - np.linalg.norm(sim.positions - origin, axis=1)
        assert depth.max() <= sagitta, depth.max()
    assert np.abs(depth).min() < 1e-3  # it does lie on the sphere
