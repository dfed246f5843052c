"""fidelity auto (pipeline.fidelity.controller, pipeline.physics.reach): the error controller against a closed
form, pass skipping bit-identical to running the passes, sleep and wake, clean contacts, a
stiff cloth exact cannot run, the plan."""
from __future__ import annotations

import json
import math
import warnings

import numpy as np
import pytest

import pipeline
from pipeline.physics.colliders import euler_matrix
from pipeline.fidelity import controller
from pipeline.fidelity.controller import screen_distance
from pipeline.physics.errors import StabilityWarning

from conftest import cloth_dict, scene_dict
from pipeline.cli import main

pytestmark = pytest.mark.usefixtures("serial_numba")


def auto(data: dict, tolerance: float = 1.0) -> dict:
    data = json.loads(json.dumps(data))
    data["simulation"].update(fidelity="auto", tolerance_px=tolerance)
    return data


def run_frames(sim, frames: int) -> list[np.ndarray]:
    out = []
    for _ in range(frames):
        sim.advance(1)
        out.append(sim.positions.copy())
    return out


# --- the error controller on a closed form ---------------------------------------------------

def falling_sheet(damping: float) -> dict:
    """A free FEM sheet (no pins, no colliders) under gravity and the scene's drag: every
    point follows x(t) = x0 + g t / gamma - g (1 - exp(-gamma t)) / gamma^2 (gamma > 0),
    x0 + g t^2 / 2 without drag."""
    data = scene_dict(cloth_dict(6, 6, damping=damping), frames_per_sec=60, steps_per_frame=10)
    data["simulation"]["model"] = "fem"
    return data


def closed_form(x0: np.ndarray, g: np.ndarray, gamma: float, t: float) -> np.ndarray:
    drop = t * t / 2 if gamma == 0 else t / gamma - (1.0 - math.exp(-gamma * t)) / gamma**2
    return x0 + g[None, :] * drop


def against_closed_form(damping: float, tolerance: float, frames: int):
    """(largest error in pixels against the closed form over the frames, steps per frame)."""
    sim = pipeline.Simulation(auto(falling_sheet(damping), tolerance))
    st = sim.stepper
    gamma = -math.log(1.0 - sim.system.damping) / sim.system.dt if damping else 0.0
    x0 = sim.model.x0.T.copy()
    g = np.asarray(sim.system.gravity)
    worst = 0.0
    for f in range(1, frames + 1):
        sim.advance(1)
        exact = closed_form(x0, g, gamma, f / 60.0)
        worst = max(worst, screen_distance(st.camera, sim.positions, exact))
    return worst, st.steps_used, st


@pytest.mark.parametrize("damping", [0.0, 1.0])
def test_a_fall_under_drag_is_exact_at_the_fewest_steps(damping):
    # Verlet with the drag integrated exactly (force_dt2), the matching start from rest, and
    # the velocity kept at a change of step, is exact for a constant acceleration under a
    # linear drag: the estimate is zero and the steps drop to the floor. (Before force_dt2,
    # the course's dt^2 carried the terminal velocity too high by about gamma dt / 2, and
    # the damped fall drifted 0.17 px from the closed form over 30 frames.)
    worst, steps, st = against_closed_form(damping, 1.0, 30)
    assert worst < 1e-6
    assert steps[0] == 10 and steps[-1] == st.n_min < 10


def hanging_sheet() -> dict:
    """An FEM sheet hanging from its two top corners, released from flat: a swing with no
    contact, smooth in the step."""
    data = scene_dict(cloth_dict(8, 8, orientation=1, damping=0.2, pinned=[(0, 7), (7, 7)]),
                      frames_per_sec=60, steps_per_frame=10)
    data["simulation"]["model"] = "fem"
    return data


def test_tighter_tolerance_takes_more_steps_and_errs_less():
    # against the same physics converged: 64x the file's steps, the drag rate held fixed
    # (16x is not enough: the course's drag term alone leaves it 0.012 px off)
    frames = 45
    ref_scene = hanging_sheet()
    ref_scene["simulation"]["steps_per_frame"] = 640
    ref_scene["cloth"]["damping"] = (1.0 - (1.0 - 0.002) ** (1.0 / 64)) * 100.0
    reference = run_frames(pipeline.Simulation(ref_scene), frames)
    results = {}
    for tolerance in (0.01, 0.1):
        sim = pipeline.Simulation(auto(hanging_sheet(), tolerance))
        out = run_frames(sim, frames)
        worst = max(screen_distance(sim.stepper.camera, a, b) for a, b in zip(out, reference))
        results[tolerance] = (worst, np.median(sim.stepper.steps_used))
    (tight, steps_tight), (loose, steps_loose) = results[0.01], results[0.1]
    assert steps_tight > steps_loose
    assert tight < loose
    assert tight <= 2 * 0.01 and loose <= 2 * 0.1


def test_at_the_fewest_steps_checks_wait_while_the_error_trend_stays_below_the_target(
        monkeypatch):
    # the estimates (fed in) rise on a line from 0.6 to the target at frame 20; at the fewest
    # steps a check can only ask for more, so the checks thin out by doubling, but no further
    # than the line's crossing: 0, 1 (rise 0.02 / frame: 19 frames of room, doubling: 2),
    # 3 (4), 7 (8), 15 (room (1 - 0.9) / 0.02 = 5), 20
    sim = pipeline.Simulation(auto(hanging_sheet(), 1.0))
    st = sim.stepper
    st.n = st.n_min
    target = st.safety * st.tolerance
    checks = []

    def estimate(n):
        checks.append(st.frame)
        return True, (0.6 + 0.02 * st.frame) * target

    monkeypatch.setattr(st, "_estimate", estimate)
    monkeypatch.setattr(st, "_run", lambda n: True)
    sim.advance(21)
    assert checks == [0, 1, 3, 7, 15, 20]
    assert st.steps_used == [st.n_min] * 21


# --- the classic model's pilot --------------------------------------------------------------

def corner_hung(nw: int = 24) -> dict:
    """A classic cloth held at two corners, no contact: its swing converges in the step at
    first order (the stretch limit acts once per step)."""
    return scene_dict(cloth_dict(nw, nw, ks=5000.0, density=150.0, damping=0.2,
                                 thickness=0.0095, pinned=[(0, 0), (nw - 1, 0)]))


def classic_error_at(data: dict, seconds: float, reference: np.ndarray) -> tuple[float, object]:
    sim = pipeline.Simulation(data, shot_seconds=seconds)
    frames = run_frames(sim, round(seconds * 90))
    return screen_distance(sim.stepper.camera, frames[-1], reference), sim


def test_the_pilot_chooses_the_classic_steps_for_the_tolerance():
    # against the converged physics: 8x the file's steps, the drag rate held fixed
    ref = corner_hung()
    ref["simulation"]["steps_per_frame"] = 240
    ref["cloth"]["damping"] = (1.0 - (1.0 - 0.002) ** (1.0 / 8)) * 100.0
    reference = run_frames(pipeline.Simulation(ref), 90)[-1]
    exact_error = screen_distance(pipeline.Simulation(auto(corner_hung())).stepper.camera,
                                  run_frames(pipeline.Simulation(corner_hung()), 90)[-1],
                                  reference)
    steps, errors = {}, {}
    for tolerance in (0.25, 2.0):
        errors[tolerance], sim = classic_error_at(auto(corner_hung(), tolerance), 1.0, reference)
        pilot = sim.stepper.pilot
        assert pilot["seconds"] == pytest.approx(1.0) and pilot["steps"][:2] == (8, 16)
        steps[tolerance] = sim.stepper.n
        assert errors[tolerance] <= 2 * tolerance, (tolerance, errors, steps)
    assert steps[0.25] > 30 > steps[2.0]  # more than the file's where it must, fewer where not
    assert errors[0.25] < exact_error < errors[2.0]  # exact's 30 steps sit in between


@pytest.mark.parametrize("tolerance, run", [(0.1, 2), (0.5, 1), (3.0, 0)])
def test_a_shot_going_on_from_a_pilot_run_is_the_shot_started_again(tolerance, run):
    # 1.5 s: the pilot's first second is replayed from its run (the third, at the steps its
    # estimate asked for, or the pair's finer or coarser), the rest continues from it
    kept = pipeline.Simulation(auto(corner_hung(12), tolerance), shot_seconds=1.5)
    frames = run_frames(kept, 135)
    pilot = kept.stepper.pilot
    assert pilot["reused"] and kept.stepper.n == pilot["steps"][run]
    assert kept.stepper.steps_used == [kept.stepper.n] * 135
    again = pipeline.Simulation(auto(corner_hung(12), tolerance), shot_seconds=1.5)
    again.stepper.pilot, again.stepper.n = pilot, kept.stepper.n  # no pilot: from the start
    for a, b in zip(frames, run_frames(again, 135)):
        np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(kept.velocities, again.velocities)


def test_a_cloth_too_large_to_keep_its_pilot_runs_starts_again(monkeypatch):
    kept = pipeline.Simulation(auto(corner_hung(12), 0.1), shot_seconds=1.5)
    run_frames(kept, 1)
    assert kept.stepper.pilot["reused"]
    monkeypatch.setattr(controller, "REPLAY_BYTES", 1000)  # under one frame of this cloth
    again = pipeline.Simulation(auto(corner_hung(12), 0.1), shot_seconds=1.5)
    frames = run_frames(again, 135)
    pilot = again.stepper.pilot
    assert not pilot["reused"] and pilot["steps"] == kept.stepper.pilot["steps"]
    assert again.stepper.n == math.ceil(pilot["constant_px"] / (2 * 0.1))
    forced = pipeline.Simulation(auto(corner_hung(12), 0.1), shot_seconds=1.5)
    forced.stepper.pilot, forced.stepper.n = pilot, again.stepper.n  # from the start
    for a, b in zip(frames, run_frames(forced, 135)):
        np.testing.assert_array_equal(a, b)


def test_a_cloth_falling_asleep_while_a_pilot_run_is_replayed_stays_asleep():
    nw = 6
    still = scene_dict(cloth_dict(nw, nw, pinned=[(i, j) for i in range(nw) for j in range(nw)]))
    # a one-second shot: the pilot covers it and hands over its finer run (then 0.5 s more)
    kept = pipeline.Simulation(auto(still), shot_seconds=1.0)
    frames = run_frames(kept, 135)
    assert kept.stepper.pilot["reused"] and kept.stepper.replay is None
    assert kept.stepper.slept > 135 - 90  # asleep before the pilot's second was replayed
    again = pipeline.Simulation(auto(still), shot_seconds=1.0)
    again.stepper.pilot, again.stepper.n = kept.stepper.pilot, kept.stepper.n
    for a, b in zip(frames, run_frames(again, 135)):
        np.testing.assert_array_equal(a, b)
    assert again.stepper.slept == kept.stepper.slept


def test_without_a_shot_length_only_a_run_at_the_steps_chosen_goes_on():
    # an endless shot: a finer run than needed would cost more than starting again (with a
    # 1.5 s shot both go on from a pilot run: the test above)
    for tolerance in (0.1, 0.5):
        sim = pipeline.Simulation(auto(corner_hung(12), tolerance))
        run_frames(sim, 1)
        pilot = sim.stepper.pilot
        assert sim.stepper.n == math.ceil(pilot["constant_px"] / (2 * tolerance))
        assert sim.stepper.n not in pilot["steps"] and not pilot["reused"]


def test_the_pilot_is_skipped_under_contact_and_keeps_the_file_steps():
    data = auto(scene_dict(cloth_dict(10, 10, thickness=0.005, ks=500.0),
                           spheres=[((0.5, -0.3, 0.5), 0.2, 0.3)]))
    sim = pipeline.Simulation(data)
    run_frames(sim, 5)
    assert sim.stepper.pilot is None and sim.stepper.chaotic
    assert sim.stepper.steps_used == [30] * 5
    assert "as the file says: under contact" in "\n".join(sim.plan.lines())


def test_a_steady_wind_gets_the_pilot_and_gusts_keep_the_file_steps():
    # a steady wind neither varies in time nor makes the motion chaotic: the pilot chooses
    # the steps (a tight tolerance: more than the file's) and the cloth may sleep; gusts keep
    # the file's steps and never sleep
    steady = corner_hung(12)
    steady["wind"] = {"velocity": [0.0, 0.0, 3.0]}
    sim = pipeline.Simulation(auto(steady, 0.1))
    run_frames(sim, 1)
    st = sim.stepper
    assert not st.chaotic and st.pilot["steps"][:2] == (8, 16) and st.n > 30
    assert "when at rest" in sim.plan.sleeps
    gusty = json.loads(json.dumps(steady))
    gusty["wind"]["gust"] = 1.0
    sim = pipeline.Simulation(auto(gusty, 0.1))
    run_frames(sim, 3)
    assert sim.stepper.chaotic and sim.stepper.pilot is None
    assert sim.stepper.steps_used == [30] * 3
    lines = "\n".join(sim.plan.lines())
    assert "under contact, self-collision or gusts" in lines and "never: the gusts" in lines


# --- skipping passes changes nothing -------------------------------------------------------

def skipping_pair(data: dict, frames: int):
    """Positions per frame with and without pass skipping, and the first run's Simulation."""
    with_skip = pipeline.Simulation(auto(data))
    without = pipeline.Simulation(auto(data))
    without.stepper.skip_passes = False
    return run_frames(with_skip, frames), run_frames(without, frames), with_skip


def test_collider_skipping_is_bit_identical_and_skips():
    data = scene_dict(cloth_dict(12, 12, thickness=0.005, ks=500.0, density=1.0,
                                 pinned=[(0, 0)]),
                      spheres=[((0.5, 0.2, 0.5), 0.2, 0.3)], planes=[((0, -0.5, 0), (0, 1, 0),
                                                                       0.5)])
    a, b, sim = skipping_pair(data, 60)
    for f, (pa, pb) in enumerate(zip(a, b)):
        assert np.array_equal(pa, pb), f"frame {f + 1} differs"
    assert sim.stepper.skipped_collider_steps > 0


def test_self_collision_skipping_is_bit_identical_and_skips():
    # a vertical cloth falling onto a plane folds onto itself: the pass acts late
    data = scene_dict(cloth_dict(14, 14, thickness=0.02, ks=500.0, density=1.0,
                                 orientation=1), self_collision=True,
                      planes=[((0, -0.3, 0), (0, 1, 0), 0.5)])
    a, b, sim = skipping_pair(data, 90)
    for f, (pa, pb) in enumerate(zip(a, b)):
        assert np.array_equal(pa, pb), f"frame {f + 1} differs"
    counts = sim.system.reach.counts
    assert 0 < counts[1] < counts[0]  # the pass ran, but not on every step


def test_one_system_per_step_count_until_the_simulation_system_changes():
    """system_for hands the stepping kernel one System object per step count (numba types a
    System it has not seen in Python: about 0.6 ms a call, every frame), and a new one, from
    the Simulation's current System, once that is replaced (as arming a Reach does)."""
    data = scene_dict(cloth_dict(12, 12, thickness=0.005, ks=500.0, density=1.0,
                                 pinned=[(0, 0)]), spheres=[((0.5, 0.2, 0.5), 0.2, 0.3)])
    sim = pipeline.Simulation(auto(data))
    run_frames(sim, 3)
    st = sim.stepper
    first = st.system_for(40)
    assert st.system_for(40) is first and first.steps_per_frame == 40
    assert st.system_for(20) is not first and st.system_for(20).steps_per_frame == 20
    sim.system = sim.system._replace(reach=sim.system.reach._replace(
        armed=np.ones(2, dtype=np.uint8)))
    again = st.system_for(40)
    assert again is not first and again.reach is sim.system.reach
    assert (again.dt, again.damping, again.force_dt2) == (first.dt, first.damping,
                                                          first.force_dt2)


# --- sleeping --------------------------------------------------------------------------------

def test_sleeps_at_rest_and_wakes_for_a_keyframe():
    data = scene_dict(cloth_dict(10, 10, ks=500.0, density=1.0, damping=2.0,
                                 pinned=[(0, 0), (9, 0), (0, 9), (9, 9)]),
                      frames_per_sec=30, steps_per_frame=20)
    wake = 2.0
    data["sphere"] = {"origin": [0.5, -1.0, 0.5], "radius": 0.2, "friction": 0.5,
                      "keyframes": [{"time": wake}, {"time": wake + 0.5,
                                                     "translation": [0, 1.9, 0]}]}
    sim = pipeline.Simulation(auto(data))
    st = sim.stepper
    before = run_frames(sim, int(wake * 30))
    assert st.asleep and st.slept > 0, "the cloth came to rest and should sleep"
    asleep_at = before[-1]
    after = run_frames(sim, 30)
    assert not st.asleep or st.frame > (wake + 0.5) * 30
    assert screen_distance(st.camera, after[-1], asleep_at) > 5.0  # the sphere lifted it
    centre = np.array([0.5, 0.9, 0.5])
    # (friction moves a point part of the way back towards where it was: up to a hair
    # inside a curved surface, as in the course's contact rule)
    assert np.min(np.linalg.norm(after[-1] - centre, axis=1)) >= 0.2 - 1e-6


# --- contacts ----------------------------------------------------------------------------------

def box_depth(points: np.ndarray, center, half, rotation) -> float:
    """Largest depth of any point inside the box (0 if none)."""
    q = (points - np.asarray(center)) @ euler_matrix(rotation)
    depth = np.min(np.asarray(half) - np.abs(q), axis=1)
    return float(max(depth.max(), 0.0))


def test_auto_leaves_no_point_inside_a_box():
    data = scene_dict(cloth_dict(25, 25, thickness=0.01), frames_per_sec=90, steps_per_frame=30)
    box = {"center": [0.5, 0.6, 0.5], "half_extents": [0.25, 0.1, 0.25], "rotation": [0, 30, 0],
           "friction": 0.5}
    data["box"] = box
    worst = {}
    for label, scene in (("exact", data), ("auto", auto(data))):
        sim = pipeline.Simulation(scene)
        worst[label] = max(box_depth(p, box["center"], box["half_extents"], box["rotation"])
                           for p in run_frames(sim, 90))
    assert worst["exact"] > 1e-4  # the course order (colliders, then Provot) leaves some in
    assert worst["auto"] == 0.0, worst


# --- a cloth exact cannot run ------------------------------------------------------------------

def test_stiff_fem_cloth_runs_in_auto():
    data = scene_dict(cloth_dict(40, 40, pinned=[(0, 39), (39, 39)]))
    data["simulation"]["model"] = "fem"
    data["cloth"]["fem"] = {"stretch": 3000.0}
    with pytest.warns(StabilityWarning):
        pipeline.Simulation(data)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        sim = pipeline.Simulation(auto(data))
    assert sim.integrator == "verlet"  # implicit Euler would need as many steps, at 40x each
    sim.advance(45)
    assert np.all(np.isfinite(sim.positions))
    assert min(sim.stepper.steps_used) >= sim.stepper.n_min > data["simulation"]["steps_per_frame"]


# --- the plan ----------------------------------------------------------------------------------

def test_plan_is_deterministic_and_says_what_is_modelled(capsys):
    data = auto(scene_dict(cloth_dict(8, 8, orientation=1), self_collision=True,
                           spheres=[((0.5, -2.0, 0.0), 0.2, 0.3)]))
    a = pipeline.Simulation(data).plan.as_dict()
    b = pipeline.Simulation(data).plan.as_dict()
    assert a == b
    assert a["fidelity"] == "auto" and a["integrator"] == "verlet"
    assert "skipped while no point can reach it" in a["colliders"][0]["status"]
    assert a["self_collision"].startswith("on, skipped while")
    exact = pipeline.Simulation(scene_dict(cloth_dict(8, 8))).plan
    assert exact.fidelity == "exact" and exact.steps_per_frame_min == 30


def test_render_plan_command(tmp_path, capsys):
    path = tmp_path / "scene.json"
    path.write_text(json.dumps(scene_dict(cloth_dict(8, 8))))
    assert main(["plan", str(path), "--fidelity", "auto", "--tolerance", "2", "--json"]) == 0
    plan = json.loads(capsys.readouterr().out)
    assert plan["tolerance_px"] == 2.0 and plan["fidelity"] == "auto"
    assert main(["plan", str(path)]) == 0
    assert capsys.readouterr().out.startswith("fidelity exact")
    assert main(["plan", str(tmp_path / "missing.json")]) == 2
    assert main(["plan", str(path), "--tolerance", "-1"]) == 2


def test_render_summary_says_what_auto_used(tmp_path, capsys):
    path = tmp_path / "scene.json"
    path.write_text(json.dumps(scene_dict(cloth_dict(8, 8))))
    out = tmp_path / "x.npz"
    assert main([str(path), "--fidelity", "auto", "--export-npz", str(out),
                     "--frames", "5"]) == 0
    err = capsys.readouterr().err
    # the shot: 5 frames at 30/s, sim frames 0..14 at 90/s; a free fall is exact at any step,
    # and the pilot's runs already cover the shot: the finer is kept
    assert "auto: pilot 8/16 steps/frame over 0.156 s" in err and "steps/frame 16/16/16" in err
    assert "the shot goes on from its run" in err and "336 steps in all" in err
    assert "frames slept" in err and "self-collision passes" in err
    assert out.exists()
