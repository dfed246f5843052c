"""The integrator bench (pipeline/cli/bench.py) with both cloth models: the FEM path of every
part (energy, probe, stability search, work-precision, charts, --models) on tiny grids and
short times. The default end-to-end run (both models) is
test_integrators.test_bench_writes_charts_and_csv.
"""
from __future__ import annotations

import csv
import json
import math

import numpy as np
import pytest

from pipeline.cli.bench import (STRAIN_LIMIT, Run, is_stable, main, own_strain_limit, resized,
                                scene_data, stability, with_model, with_stiffness, work_precision)
from pipeline.physics.fem import fem_energy
from pipeline.physics.forces import spring_energy
from pipeline.scene import INTEGRATORS
from pipeline.physics.system import stability_limit

from conftest import scene_path

def _pinned2(model: str, grid: int = 6) -> dict:
    return with_model(resized(scene_data(scene_path("pinned2")), grid, grid), model)


def _theory(data: dict) -> float:
    omega, _ = stability_limit(Run(data, "verlet").model)
    return 2.0 / omega


def test_model_selection_and_integrators():
    fem = _pinned2("fem")
    assert fem["simulation"]["model"] == "fem"
    assert Run(fem, "verlet").system.classic is False
    assert Run(_pinned2("classic"), "verlet").system.classic is True
    assert Run(fem, "xpbd").system.classic is False  # XPBD on the FEM's own constraints
    with pytest.raises(ValueError, match="unknown model"):
        with_model(fem, "cosserat")
    # a scene that asks for xpbd still runs under the FEM (the bench sets each integrator)
    data = _pinned2("classic")
    data["simulation"]["integrator"] = "xpbd"
    assert Run(with_model(data, "fem"), "verlet").system.classic is False


def test_energy_is_the_models_elastic_energy():
    """A flat sheet stretched uniformly by 5 % at rest (v = 0): the FEM's elastic energy is
    the membrane's k_stretch (0.05^2 / 2) per direction over the 1 m^2 sheet, whatever
    cloth.ks says; the classic model's is its springs' energy."""
    for stretch in (300.0, 1200.0):
        data = with_stiffness(_pinned2("fem"), "fem", stretch)
        start = Run(data, "symplectic-euler")
        x0 = start.x.T.copy()
        run = Run(data, "symplectic-euler", start_positions=1.05 * x0)
        s = run.system
        gravity = -float(np.sum(s.mass * s.gravity[:, None] * run.x))
        elastic = run.energy() - gravity
        assert elastic == pytest.approx(stretch * 0.05 ** 2, rel=1e-9)
        assert elastic == pytest.approx(fem_energy(run.x, s.fem), rel=1e-12)
    classic = Run(_pinned2("classic"), "symplectic-euler", start_positions=1.05 * x0)
    s = classic.system
    gravity = -float(np.sum(s.mass * s.gravity[:, None] * classic.x))
    offsets, _, exists, rest, stiffness = s.springs
    expected = spring_energy(classic.x, offsets, exists, rest, stiffness)
    assert classic.energy() - gravity == pytest.approx(expected, rel=1e-12)
    assert expected > 10 * stretch * 0.05 ** 2  # ks 5000 N/m springs: not the FEM's energy


def test_with_stiffness_scales_the_fem_shear_alike():
    data = with_stiffness(_pinned2("fem"), "fem", 3000.0)
    assert data["cloth"]["fem"] == {"stretch": 3000.0, "shear": 300.0}  # default 300 / 30
    assert data["cloth"]["ks"] == 5000.0  # untouched
    classic = with_stiffness(_pinned2("classic"), "classic", 1e5)
    assert classic["cloth"]["ks"] == 1e5 and "fem" not in classic["cloth"]
    # the FEM's limit follows the stretch stiffness: omega ~ sqrt(k)
    ratio = _theory(with_stiffness(_pinned2("fem"), "fem", 300.0)) / _theory(data)
    assert ratio == pytest.approx(math.sqrt(10.0), rel=0.03)


def test_probe_measures_the_fem_strain_geometrically():
    data = _pinned2("fem")
    x0 = Run(data, "symplectic-euler").x.T.copy()
    run = Run(data, "symplectic-euler", start_positions=1.05 * x0)
    before = run.x.copy()
    strain = run.probe_strain()
    assert np.array_equal(run.x, before)  # the probe does not change the run
    assert 0.045 < strain < 0.055  # 5 % on every structural and shearing pair
    # the classic enable flags do not hide the FEM's pairs from the probe
    data["cloth"]["enable_structural"] = data["cloth"]["enable_shearing"] = False
    assert 0.045 < Run(data, "symplectic-euler", start_positions=1.05 * x0).probe_strain()


@pytest.mark.parametrize("name", ("verlet", "symplectic-euler", "rk4"))
def test_fem_explicit_methods_fail_near_the_fem_limit(name):
    data = _pinned2("fem")
    limit = _theory(data)
    above = 2.0 if name == "rk4" else 1.5  # RK4: 2.83 on the imaginary axis, 1.41x
    assert is_stable(data, name, 0.8 * limit)
    assert not is_stable(data, name, above * limit)


def test_fem_implicit_euler_stable_far_beyond_the_explicit_limit():
    data = _pinned2("fem")
    dt = 50.0 * _theory(data)
    assert is_stable(data, "implicit-euler", dt, t_end=10 * dt)
    assert not is_stable(data, "verlet", 2.0 * _theory(data))


def test_stability_search_per_model():
    rows = stability(_pinned2("fem"), grid=6, ks_values=(300.0,), log=lambda *a: None)
    assert [r["integrator"] for r in rows] == list(INTEGRATORS)
    by = {r["integrator"]: r for r in rows}
    assert {r["model"] for r in rows} == {"fem"} and all(r["stiffness"] == 300 for r in rows)
    assert 0.95 <= by["verlet"]["ratio"] <= 1.2, by["verlet"]
    assert 1.3 <= by["rk4"]["ratio"] <= 1.7, by["rk4"]
    assert by["euler"]["ratio"] < 0.5
    assert by["implicit-euler"]["ratio"] > 20


def test_vbd_on_soft_classic_springs_is_judged_against_its_own_stretch():
    """VBD runs the classic springs without Provot's limit: a 100 N/m sheet hangs far past
    STRAIN_LIMIT by itself, which is the model, not a blow-up. Its bound is that stretch plus
    STRAIN_LIMIT, and it is stable up to one step per frame (the search's top for VBD)."""
    data = with_stiffness(_pinned2("classic"), "classic", 100.0)
    lo = _theory(data) / 16
    own = own_strain_limit(data, "vbd", lo)
    assert own > 2 * STRAIN_LIMIT  # it stretches by itself (Provot would stop it at 0.1)
    assert own_strain_limit(data, "verlet", lo) == STRAIN_LIMIT  # Provot acts: the fixed bound
    assert not is_stable(data, "vbd", 1.0 / 90, t_end=0.5)  # the fixed bound calls it crumpled
    rows = stability(data, grid=6, ks_values=(100.0,), integrators=("vbd",), log=lambda *a: None)
    frame = 1.0 / Run(data, "vbd").scene.simulation.frames_per_sec
    assert rows[0]["dt_stable"] >= frame and rows[0]["strain_limit"] == pytest.approx(own)


def test_fem_work_precision_converges():
    rows, info = work_precision(_pinned2("fem"), t_end=0.2, sweep=(30, 60),
                                integrators=("verlet", "rk4", "implicit-euler", "xpbd"),
                                log=lambda *a: None, auto_tolerances=(0.002, 4.0))
    assert info["model"] == "fem" and info["reference_check_rms"] < 1e-8
    auto = {r["tolerance_px"]: r for r in rows if r["integrator"] == "auto"}
    rows = [r for r in rows if r["integrator"] != "auto"]
    assert {r["integrator"] for r in rows} == {"verlet", "rk4", "implicit-euler", "xpbd"}
    # fidelity auto: a tighter tolerance takes more steps and lands nearer the reference
    assert auto[0.002]["ok"] and auto[4.0]["ok"]
    assert auto[0.002]["steps_per_frame"] > auto[4.0]["steps_per_frame"]
    assert auto[0.002]["rms_error"] < auto[4.0]["rms_error"]
    by = {(r["integrator"], r["steps_per_frame"]): r for r in rows}
    assert all(r["ok"] and r["probe_strain_p99"] < STRAIN_LIMIT for r in rows)
    for name in ("verlet", "rk4"):  # errors shrink with the step
        assert by[name, 60]["rms_error"] < 0.6 * by[name, 30]["rms_error"]
    assert by["rk4", 30]["rms_error"] < 1e-3 * by["verlet", 30]["rms_error"]
    assert by["implicit-euler", 30]["cg_iterations_per_step"] >= 1
    assert math.isnan(by["verlet", 30]["cg_iterations_per_step"])


def test_bench_fem_only_and_bad_model(tmp_path):
    pytest.importorskip("matplotlib")
    out = tmp_path / "bench"
    assert main([str(scene_path("pinned2")), "--out", str(out), "--models", "fem",
                 "--grid", "5", "--stability-grid", "5", "--stability-time", "0.1",
                 "--time", "0.05", "--sweep", "30",
                 "--stretch", "300,3000"]) == 0
    with (out / "pinned2_work_precision.csv").open() as fh:
        rows = list(csv.DictReader(fh))
    assert [r["integrator"] for r in rows] == list(INTEGRATORS) + ["auto"] * 4
    assert {r["model"] for r in rows} == {"fem"}
    with (out / "pinned2_stability.csv").open() as fh:
        stab = list(csv.DictReader(fh))
    assert len(stab) == 2 * len(INTEGRATORS)
    assert sorted({float(r["stiffness"]) for r in stab}) == [300.0, 3000.0]
    assert list(json.loads((out / "pinned2_reference.json").read_text())) == ["fem"]
    for stem in ("pinned2_work_precision", "pinned2_stability"):
        for ext in ("png", "svg"):
            assert (out / f"{stem}.{ext}").stat().st_size > 0
    with pytest.raises(SystemExit):
        main([str(scene_path("pinned2")), "--out", str(out), "--models", "classic,cosserat"])
    for bad in ("0", "-1", "nan"):
        with pytest.raises(SystemExit) as stop:
            main([str(scene_path("pinned2")), "--out", str(out), "--stability-time", bad])
        assert stop.value.code == 2
