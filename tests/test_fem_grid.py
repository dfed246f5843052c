"""fidelity auto's FEM grid (pipeline.fidelity.fem_grid): the spline that carries a coarse grid's
positions to the file's grid, the pins a coarse grid can hold, the decision from the
pilot's distances, and the grid pilot on a sheet that converges under refinement."""
from __future__ import annotations

import json

import numpy as np
import pytest

from conftest import SCENES
from pipeline import Simulation
from pipeline.fidelity.fem_grid import GRID_CONVERGENCE, GRID_TARGET, MAX_CELL_PX, OnFileGrid, Spline, catmull_rom, coarse_pins, decide, pilot_grids
from pipeline.fidelity.controller import screen_distance
from pipeline.physics.model import build_model
from pipeline.scene import load_scene


def test_the_spline_interpolates_and_reproduces_quadratics_inside():
    t, fine = np.linspace(0.0, 1.0, 17), np.linspace(0.0, 1.0, 65)
    w = catmull_rom(65, 17)
    assert np.allclose(w.sum(axis=1), 1.0, rtol=0, atol=1e-15)
    assert np.array_equal(w[::4], np.eye(17))  # nested: the coarse points themselves
    assert np.allclose(w @ (3.0 * t - 1.0), 3.0 * fine - 1.0, rtol=0, atol=1e-14)  # linear
    inside = slice(4, -4)  # off the end cells, whose outer points are extrapolated linearly
    assert np.allclose((w @ t ** 2)[inside], fine[inside] ** 2, rtol=0, atol=1e-14)
    # smooth data: third order inside (the error falls 8x per halving of the cell)
    errors = []
    for n in (9, 17, 33):
        grid = np.linspace(0.0, 1.0, n)
        errors.append(np.abs(catmull_rom(257, n) @ np.sin(3 * grid)
                             - np.sin(3 * np.linspace(0.0, 1.0, 257)))[32:-32].max())
    assert errors[0] / errors[1] > 7 and errors[1] / errors[2] > 7


def test_the_spline_carries_an_affine_sheet_exactly():
    """A coarse grid moved by a rotation and a translation lands on the fine grid moved
    the same way (the spline is exact on linear data, and separable)."""
    def sheet(nw, nh):
        j, i = np.meshgrid(np.linspace(0, 1.5, nw), np.linspace(0, 1.0, nh))
        return np.stack([j.ravel(), i.ravel(), np.zeros(nw * nh)], axis=1)

    c, s = np.cos(0.7), np.sin(0.7)
    move = np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])
    shift = np.array([0.3, -0.2, 1.1])
    got = Spline(13, 9, 49, 33)(sheet(13, 9) @ move.T + shift)
    assert np.allclose(got, sheet(49, 33) @ move.T + shift, rtol=0, atol=1e-13)


def test_a_coarse_grid_holds_corner_and_edge_pins_and_no_other():
    corners = [(0, 0), (96, 0)]
    assert coarse_pins(corners, 97, 97, 49, 49) == ((0, 0), (48, 0))
    edge = [(j, 96) for j in range(97)]
    assert coarse_pins(edge, 97, 97, 25, 25) == tuple((j, 24) for j in range(25))
    assert coarse_pins(edge, 97, 97, 30, 30) == tuple((j, 29) for j in range(30))  # unnested
    assert coarse_pins([(0, 0), (96, 0), (48, 48)], 97, 97, 13, 13) == ((0, 0), (12, 0),
                                                                         (6, 6))
    assert coarse_pins([(0, 0), (3, 0)], 97, 97, 49, 49) is None  # between two unpinned
    assert coarse_pins([(0, 0), (3, 5)], 97, 97, 49, 49) is None  # off every grid line


def test_no_pilot_where_a_coarse_grid_cannot_be_the_same_cloth():
    swing = load_scene(SCENES / "swing.json")
    assert pilot_grids(swing) == ([], "fewer than 56 points a side: no room for three "
                                      "coarser grids")
    sheet = load_scene(SCENES / "fem_sheet.json", ["simulation.self_collision=true"])
    assert pilot_grids(sheet)[1] == "self-collision acts between grid points"
    sim = Simulation(load_scene(SCENES / "swing.json", ["simulation.fidelity=auto"]))
    assert sim.coarse is None and sim.grid_choice is None
    assert "no grid pilot: fewer than 56 points" in "\n".join(sim.plan.lines())


def test_points_inside_a_collider_on_the_files_grid_are_projected_out():
    """A coarse sheet cutting through a sphere: on the file's grid every free point ends
    outside the sphere (distance to its centre at least the radius), and the points that
    were outside stay exactly where the spline put them."""
    data = json.loads((SCENES / "fem_sheet.json").read_text())
    data["cloth"].update(num_width_points=33, num_height_points=33, pinned=[])
    data["sphere"] = {"origin": [0.5, 0.85, 0.5], "radius": 0.3, "friction": 0.3}
    scene = load_scene(data)
    fine = build_model(scene)  # the flat sheet at y = 1: it cuts the sphere's top
    coarse = build_model(load_scene({**data, "cloth": {**data["cloth"],
                                                         "num_width_points": 5,
                                                         "num_height_points": 5}}))
    to_file = OnFileGrid(coarse, fine, scene)
    raw = to_file.spline(coarse.x0.T)
    centre = np.array([0.5, 0.85, 0.5])
    inside = np.linalg.norm(raw - centre, axis=1) < 0.3
    assert 50 < inside.sum() < raw.shape[0]
    out = to_file.positions(coarse.x0.T, 0.0)
    assert np.linalg.norm(out - centre, axis=1).min() >= 0.3 - 1e-12
    assert np.array_equal(out[~inside], raw[~inside])


def test_the_decision_bounds_each_grids_error_by_the_distances_below_it():
    """Distances shrinking with the cell (r = 2): G1 is at most d21 from the file's grid,
    G2 at most d21 + d21, G3 at most that plus d32; the coarsest within GRID_TARGET
    tolerances is chosen, none where no grid fits or the grids do not converge (r below
    GRID_CONVERGENCE)."""
    ratio, predicted, k = decide(4.0, 2.0, 1.0)
    assert ratio == 2.0 and predicted == [2.0, 4.0, 8.0]
    assert decide(4.0, 2.0, 2.0 / GRID_TARGET)[2] == 0
    assert decide(4.0, 2.0, 4.0 / GRID_TARGET)[2] == 1
    assert decide(4.0, 2.0, 8.0 / GRID_TARGET)[2] == 2
    assert decide(4.0, 2.0, 1.99 / GRID_TARGET)[2] is None
    # cells over MAX_CELL_PX on screen are not chosen, whatever their error
    assert decide(4.0, 2.0, 8.0 / GRID_TARGET, (1.0, 2.0, 1.01 * MAX_CELL_PX))[2] == 1
    assert decide(4.0, 2.0, 8.0 / GRID_TARGET, (1.01 * MAX_CELL_PX,) * 3)[2] is None
    slow = 0.99 * GRID_CONVERGENCE
    assert decide(slow * 0.1, 0.1, 100.0)[2] is None  # close, but not converging
    assert decide(0.0, 0.0, 1.0)[2] == 2  # the grids agree: the coarsest


@pytest.fixture(scope="module")
def sheet():
    """A 57 x 57 FEM sheet held at two corners, about 70 px wide on screen."""
    data = json.loads((SCENES / "fem_sheet.json").read_text())
    data["cloth"].update(num_width_points=57, num_height_points=57, pinned=[[0, 0], [56, 0]])
    data["simulation"].update(fidelity="auto", tolerance_px=1.0, steps_per_frame=60)
    data["camera"]["position"] = [0.5, 1.2, 12.0]
    return data


def test_the_pilot_chooses_a_coarse_grid_that_stays_within_the_tolerance(sheet):
    """The grids converge on this sheet (a pinned FEM sheet: docs/fidelity.md): the pilot
    runs the first second on 29x29, 15x15 and 8x8 and picks the coarsest whose predicted
    error is within GRID_TARGET tolerances and cells within MAX_CELL_PX; the shot on it, drawn on the file's grid, lands
    within twice the tolerance of the file's grid (auto's steps, at a tenth of the
    tolerance) at 0.5 s and 1 s, pins where they are pinned."""
    auto = Simulation(sheet, shot_seconds=1.0)
    choice = auto.grid_choice
    assert choice.grids == [(29, 29), (15, 15), (8, 8)]
    assert choice.ratio >= GRID_CONVERGENCE
    assert auto.coarse is not None and choice.chosen == (auto.coarse.model.nw,) * 2
    k = choice.grids.index(choice.chosen)
    assert choice.predicted_px[k] <= GRID_TARGET * 1.0 and choice.cell_px[k] <= MAX_CELL_PX
    assert all(e > GRID_TARGET or c > MAX_CELL_PX  # the coarsest that fits
               for e, c in zip(choice.predicted_px[k + 1:], choice.cell_px[k + 1:]))
    tight = {**sheet, "simulation": {**sheet["simulation"], "tolerance_px": 0.1}}
    reference = Simulation(tight, shot_seconds=1.0, grid=False)
    assert reference.coarse is None and reference.model.n == 57 * 57
    camera = auto.stepper.camera
    for _ in range(2):
        auto.advance(30)
        reference.advance(30)
        got = auto.positions
        assert got.shape == (57 * 57, 3)
        assert np.array_equal(got[[0, 56]], reference.positions[[0, 56]])
        assert screen_distance(camera, got, reference.positions) <= 2.0
    text = auto.stepper.summary_text()
    assert text.startswith("auto: grid pilot 29x29/15x15/8x8 over 1 s: ") and (
        f": {choice.chosen[0]}x{choice.chosen[1]}, steps/frame" in text)


def test_no_pilot_where_even_the_finest_coarse_grid_would_show_its_cells(sheet):
    """Close to the camera the 29x29 grid's cells are more than MAX_CELL_PX on screen: no
    grid could be chosen, so no pilot runs (and none of its cost)."""
    close = {**sheet, "camera": {**sheet["camera"], "position": [0.5, 1.2, 2.0]}}
    sim = Simulation(close, shot_seconds=1.0)
    assert sim.grid_choice is None and sim.coarse is None
    assert sim.grid_reason.startswith("the 29x29 grid's cells would be ")
    assert sim.grid_reason.endswith(f" px on screen at the start, more than {MAX_CELL_PX:g}")
    assert float(sim.grid_reason.split()[6]) > MAX_CELL_PX


def test_the_grid_plan_is_deterministic(sheet):
    a, b = (Simulation(sheet, shot_seconds=1.0).plan.as_dict() for _ in range(2))
    assert a == b and a["grid_choice"]["chosen"] is not None


def test_render_says_which_grid_it_ran_on(tmp_path, capsys):
    """`render --fidelity auto` on the FEM sheet in a 32x32 image: the pilot covers the
    shot (its last frame drawn at 10/60 s), every grid's cells are under a pixel, and the
    summary names the grid."""
    from pipeline.cli import main

    out = tmp_path / "sheet.gif"
    code = main([str(SCENES / "fem_sheet.json"), "--fidelity", "auto", "--duration", "0.2",
                 "--size", "32x32", "--aa", "1", "--out", str(out)])
    err = capsys.readouterr().err.splitlines()
    assert code == 0 and out.stat().st_size > 0
    assert err[-1].startswith("render: auto: grid pilot 49x49/25x25/13x13 over 0.167 s: ")
    assert ": 13x13, steps/frame " in err[-1]


def test_the_shot_goes_on_from_the_pilots_run_bit_for_bit(sheet):
    """The chosen grid's pilot run is handed over: its frames replayed, then stepped on; the
    same states, steps and times as the same grid's Simulation from t = 0, frame by frame,
    through the pilot's second and half a second past it."""
    from pipeline.fidelity.fem_grid import coarse_scene

    auto = Simulation(sheet, shot_seconds=1.5)
    assert auto.stepper.replay is not None and auto.stepper.frame == 0  # handed over
    w, h = auto.grid_choice.chosen
    scene = load_scene(sheet)
    fresh = Simulation(coarse_scene(scene, w, h, coarse_pins(scene.cloth.pinned, 57, 57, w, h)),
                       shot_seconds=1.5, grid=False)
    for _ in range(90):
        auto.advance(1)
        fresh.advance(1)
        assert np.array_equal(auto._state.x, fresh._state.x)
        assert np.array_equal(auto._state.last, fresh._state.last)
        assert auto.time == fresh.time
    assert auto.stepper.steps_used == fresh.stepper.steps_used
