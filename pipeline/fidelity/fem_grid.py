"""fidelity auto's FEM grid: the coarsest grid whose error on screen stays within the
tolerance, chosen by a pilot on coarser grids, and its positions on the file's grid.

The FEM is in physical units (N/m, kg/m^2), so a coarser grid is the same cloth, and where
the motion converges under refinement its error falls with the cell size. The pilot runs the
shot's first PILOT_SECONDS (or the whole shot, if shorter) on the file's grid halved 1, 2
and 3 times (G1, G2, G3; Simulations of their own under fidelity auto, so each takes its
own steps by error control), side by side, and measures the largest screen distance between
neighbouring grids at the same material points (G3's points, the finer grids sampled there
by the spline below): D32 between G3 and G2, D21 between G2 and G1. Where the grids
converge, halving the cell divides that distance by r = D32 / D21 (1.5-2 measured,
docs/fidelity.md); r below GRID_CONVERGENCE means the grids do not converge here, and the
file's grid stays. Else the distance from G1 to the file's grid, not measured, is taken as
at most D21 (the distances shrink with the cell; a geometric extrapolation, D21 / r, was
measured up to 1.9x short on a swinging sheet, whose finer grids converge more slowly), and
the error of Gk against the file's grid as at most the sum of the distances from Gk down to
it; the shot runs on the coarsest grid whose error that bounds by GRID_TARGET tolerances
(none: the file's grid) and whose cells are at most MAX_CELL_PX on screen (no pilot where
even G1's are more at the start). The pilot's grids cost 1/8, 1/64 and 1/512 of the file's per
simulated second (a quarter of the points per halving, each step twice as long: the
stability limit follows the cell), and the shot goes on from the chosen grid's run (its
frames replayed).

A coarse grid is only possible where every pin of the file's grid is a pin of it: a pin on
one of its grid points, or between two pinned points of one of its rows or columns (a
pinned edge); the file's grid must have at least MIN_POINTS * 2^3 points a side, and no
self-collision (it acts between grid points). Frames are drawn on the file's grid: the
coarse grid's positions through the tensor-product Catmull-Rom spline of its points
(interpolating, exact on linear motion), pinned points where they are pinned, and points the
spline put inside a collider projected out (so no point ends a frame inside one).
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from pipeline.scene import Scene

from .controller import REPLAY_BYTES, REPLAYED, metres_per_pixel, screen_distance

HALVINGS = (1, 2, 3)  # the pilot's grids: the file's grid halved this many times
MIN_POINTS = 7  # the coarsest pilot grid has at least this many points a side
#: D32 / D21 at least this for the grids to count as converging (first order: about 2)
GRID_CONVERGENCE = 1.25
#: the largest cell of a chosen grid on screen, in pixels: a fold on a coarse grid bends at
#: its points, and shading shows it (fem_sheet's 25x25, cells of 4.4 px, draws a beaded
#: crease from a pinned corner that its 49x49, 2.2 px, and the file's grid do not)
MAX_CELL_PX = 3.0
#: the chosen grid's predicted error against the file's grid over the pilot, in
#: tolerances (the error keeps growing after it: 1.5-2x over 3 s, docs/fidelity.md)
GRID_TARGET = 1.0


def coarse_size(n: int, halvings: int) -> int:
    """Points a side of the grid of n points halved `halvings` times (rounded)."""
    return round((n - 1) / 2 ** halvings) + 1


def _on_pins(pins: set, u: float, v: float) -> bool:
    """Whether grid position (u, v) (column, row; fractional between grid points) is a pin
    of `pins` or lies between two pins next to each other on a row or column."""
    on_u, on_v = abs(u - round(u)) < 1e-9, abs(v - round(v)) < 1e-9
    if on_u and on_v:
        return (round(u), round(v)) in pins
    if on_v:
        return {(math.floor(u), round(v)), (math.ceil(u), round(v))} <= pins
    if on_u:
        return {(round(u), math.floor(v)), (round(u), math.ceil(v))} <= pins
    return False


def coarse_pins(pinned, nw: int, nh: int, cw: int, ch: int) -> tuple | None:
    """The pins (column, row) of the cw x ch grid over the same cloth as the file's nw x nh
    grid with pins `pinned`: its points that lie on a pin of the file's grid or between two
    neighbouring ones (a pinned edge). None where that would not hold every pin of the
    file's grid: each must lie on a pin of the coarse grid or between two neighbouring
    ones."""
    fine = {(int(j), int(i)) for j, i in pinned}
    sx, sy = (nw - 1) / (cw - 1), (nh - 1) / (ch - 1)
    coarse = {(j, i) for i in range(ch) for j in range(cw) if _on_pins(fine, j * sx, i * sy)}
    if not all(_on_pins(coarse, j / sx, i / sy) for j, i in fine):
        return None
    return tuple(sorted(coarse, key=lambda p: (p[1], p[0])))


def catmull_rom(n_out: int, n_in: int) -> np.ndarray:
    """(n_out, n_in) weights of the uniform Catmull-Rom spline through n_in samples,
    evaluated at n_out uniform parameters (the ends on the ends). Interpolating; the points
    beyond the ends are extrapolated linearly, so that linear data is reproduced exactly."""
    t = np.linspace(0.0, n_in - 1.0, n_out)
    i = np.clip(np.floor(t).astype(np.int64), 0, n_in - 2)
    s = t - i
    w = np.stack([(-s ** 3 + 2 * s ** 2 - s) / 2, (3 * s ** 3 - 5 * s ** 2 + 2) / 2,
                  (-3 * s ** 3 + 4 * s ** 2 + s) / 2, (s ** 3 - s ** 2) / 2], axis=1)
    padded = np.zeros((n_out, n_in + 2))  # columns: sample -1, 0, ..., n_in
    rows = np.arange(n_out)
    for k in range(4):
        np.add.at(padded, (rows, i + k), w[:, k])
    out = padded[:, 1:-1].copy()
    out[:, 0] += 2.0 * padded[:, 0]  # sample -1 = 2 s0 - s1
    out[:, 1] -= padded[:, 0]
    out[:, -1] += 2.0 * padded[:, -1]  # sample n_in = 2 s_(n-1) - s_(n-2)
    out[:, -2] -= padded[:, -1]
    return out


class Spline:
    """Positions of a cw x ch grid evaluated at the points of an nw x nh grid over the same
    cloth (row-major points, (N, 3) arrays)."""

    def __init__(self, cw: int, ch: int, nw: int, nh: int) -> None:
        self.shape = (ch, cw)
        self.across = catmull_rom(nw, cw)  # (nw, cw)
        self.down = catmull_rom(nh, ch)  # (nh, ch)

    def __call__(self, x: np.ndarray) -> np.ndarray:
        ch, cw = self.shape
        rows = (self.down @ x.reshape(ch, cw * 3)).reshape(-1, cw, 3)
        return (self.across @ rows).reshape(-1, 3)


@dataclass
class GridChoice:
    """The pilot's figures and the grid the shot runs on (`chosen`: None, the file's)."""

    file: tuple[int, int]  # points across and down, as the file says
    grids: list[tuple[int, int]]  # the pilot's: G1, G2, G3
    seconds: float  # simulated by the pilot
    distance_px: tuple[float, float]  # (D32, D21)
    ratio: float  # D32 / D21
    predicted_px: list[float]  # predicted error of G1, G2, G3 against the file's grid
    chosen: tuple[int, int] | None
    cell_px: list[float]  # the largest cell of G1, G2, G3 on screen
    pilot_steps: list[int]  # steps the pilot took on G1, G2, G3

    @property
    def converges(self) -> bool:
        return self.ratio >= GRID_CONVERGENCE

    def text(self) -> str:
        return grid_text(self.as_dict())

    def as_dict(self) -> dict:
        """As JSON has it (ratio None: the grids agree to the pixel, D21 = 0)."""
        ratio = self.ratio if math.isfinite(self.ratio) else None
        return dataclasses.asdict(self) | {"ratio": ratio, "converges": self.converges}


def grid_text(g: dict) -> str:
    """The grid pilot's figures in a few words, from GridChoice.as_dict (the run's summary
    and `render plan`)."""
    grids = "/".join(f"{w}x{h}" for w, h in g["grids"])
    ratio = "inf" if g["ratio"] is None else f"{g['ratio']:.2f}"
    head = (f"grid pilot {grids} over {g['seconds']:.3g} s: distances "
            f"{g['distance_px'][0]:.2g}/{g['distance_px'][1]:.2g} px")
    file = f"the file's {g['file'][0]}x{g['file'][1]}"
    if not g["converges"]:
        return f"{head}, ratio {ratio} < {GRID_CONVERGENCE:g} (not converging): {file}"
    predicted = "/".join(f"{e:.2g}" for e in g["predicted_px"])
    cells = "/".join(f"{c:.2g}" for c in g["cell_px"])
    grid = f"{g['chosen'][0]}x{g['chosen'][1]}" if g["chosen"] else file
    return (f"{head}, ratio {ratio}, predicted error {predicted} px (aim: {GRID_TARGET:g} x "
            f"tolerance), cells {cells} px (at most {MAX_CELL_PX:g}): {grid}")


def pilot_grids(scene: Scene) -> tuple[list[tuple[int, int, tuple]], str]:
    """(the pilot's grids as (points across, down, pins), why none) for an FEM scene."""
    c = scene.cloth
    if scene.self_collision:
        return [], "self-collision acts between grid points"
    grids = []
    for k in HALVINGS:
        cw, ch = coarse_size(c.num_width_points, k), coarse_size(c.num_height_points, k)
        if min(cw, ch) < MIN_POINTS:
            return [], (f"fewer than {MIN_POINTS * 2 ** HALVINGS[-1]} points a side: no room "
                        "for three coarser grids")
        pins = coarse_pins(c.pinned, c.num_width_points, c.num_height_points, cw, ch)
        if pins is None:
            return [], f"a pin of the file's grid is not a pin of the {cw}x{ch} grid"
        grids.append((cw, ch, pins))
    return grids, ""


def coarse_scene(scene: Scene, cw: int, ch: int, pins: tuple) -> Scene:
    """The scene with its cloth on a cw x ch grid."""
    cloth = dataclasses.replace(scene.cloth, num_width_points=cw, num_height_points=ch,
                                pinned=pins)
    return dataclasses.replace(scene, cloth=cloth)


def decide(d32: float, d21: float, tolerance: float,
           cell_px: tuple[float, float, float] = (0.0, 0.0, 0.0),
           ) -> tuple[float, list[float], int | None]:
    """(ratio r = d32 / d21, predicted errors of G1, G2, G3 against the file's grid, the
    index of the coarsest within GRID_TARGET tolerances whose cells are at most MAX_CELL_PX
    on screen (`cell_px`), or None) from the pilot's largest distances between G3 and G2
    and between G2 and G1 (module docstring): where the grids converge, G1 is at most d21
    from the file's grid, and each grid's error at most the sum of the distances below it."""
    ratio = d32 / d21 if d21 > 0.0 else math.inf
    predicted = [d21, 2.0 * d21, 2.0 * d21 + d32]
    if not ratio >= GRID_CONVERGENCE:
        return ratio, predicted, None
    fits = [k for k, (e, cell) in enumerate(zip(predicted, cell_px))
            if e <= GRID_TARGET * tolerance and cell <= MAX_CELL_PX]
    return ratio, predicted, (fits[-1] if fits else None)


def choose_grid(sim, shot_seconds: float | None, pilot_seconds: float):
    """(the pilot's GridChoice or None, the Simulation of the chosen coarse grid from t = 0
    or None, why there was no pilot). `sim` is the file's grid's Simulation under fidelity
    auto (its camera and tolerance are the shot's)."""
    from pipeline.physics.errors import DivergenceError

    Simulation = type(sim)  # the caller's class: this layer sits below it

    scene = sim.scene
    grids, why = pilot_grids(scene)
    if not grids:
        return None, None, why
    camera, c = sim.stepper.camera, scene.cloth
    cell = [max(c.width / (cw - 1), c.height / (ch - 1)) for cw, ch, _ in grids]  # metres
    start = cell[0] / metres_per_pixel(camera, sim.model.x0.T)
    if start > MAX_CELL_PX:  # no grid could be chosen: no pilot
        return None, None, (f"the {grids[0][0]}x{grids[0][1]} grid's cells would be "
                            f"{start:.2g} px on screen at the start, more than {MAX_CELL_PX:g}")
    fps = scene.simulation.frames_per_sec
    frames = max(1, round(pilot_seconds * fps))
    runs = [Simulation(coarse_scene(scene, cw, ch, pins), shot_seconds=shot_seconds,
                       grid=False) for cw, ch, pins in grids]
    (w3, h3, _) = grids[-1]
    samplers = [Spline(cw, ch, w3, h3) for cw, ch, _ in grids[:-1]]
    # each run's state after each frame, to hand the chosen run over to the shot
    keep = frames * sum(getattr(r._state, k).nbytes for r in runs for k in REPLAYED) \
        <= REPLAY_BYTES
    records: list[list] = [[] for _ in runs]
    d32 = d21 = 0.0
    for _ in range(frames):
        try:
            for run, kept in zip(runs, records):
                run.advance(1)
                if keep:
                    kept.append({k: getattr(run._state, k).copy() for k in REPLAYED})
        except DivergenceError as err:
            return None, None, f"the pilot's {run.model.nw}x{run.model.nh} grid diverged ({err})"
        g1, g2 = (f(r.positions) for f, r in zip(samplers, runs))
        g3 = runs[-1].positions
        d32 = max(d32, screen_distance(camera, g3, g2))
        d21 = max(d21, screen_distance(camera, g2, g1))
    # cells on screen where the cloth is nearest the camera, at the start or the pilot's end
    mpp = min(metres_per_pixel(camera, sim.model.x0.T),
              metres_per_pixel(camera, runs[-1].positions))
    cell_px = tuple(m / mpp for m in cell)
    ratio, predicted, k = decide(d32, d21, sim.stepper.tolerance, cell_px)
    chosen = None if k is None else grids[k][:2]
    choice = GridChoice(file=(scene.cloth.num_width_points, scene.cloth.num_height_points),
                        grids=[g[:2] for g in grids], seconds=frames / fps,
                        distance_px=(d32, d21), ratio=ratio, predicted_px=predicted,
                        chosen=chosen, cell_px=list(cell_px),
                        pilot_steps=[r.stepper.steps_total for r in runs])
    if chosen is None:
        return choice, None, ""
    if keep:  # the shot goes on from the pilot's run, its frames replayed
        runs[k].stepper.replay_from_start(records[k])
        return choice, runs[k], ""
    cw, ch, pins = grids[k]
    return choice, Simulation(coarse_scene(scene, cw, ch, pins), shot_seconds=shot_seconds,
                              grid=False), ""


class OnFileGrid:
    """A coarse grid's positions on the file's grid, for drawing (module docstring)."""

    def __init__(self, coarse_model, model, scene: Scene) -> None:
        self.spline = Spline(coarse_model.nw, coarse_model.nh, model.nw, model.nh)
        self.pinned = model.pinned  # (N,) uint8
        self.held = model.pinned != 0
        self.pinned_at = model.x0.T[self.held].copy()
        self.table = None
        if scene.colliders:
            from pipeline.physics.overlap import still_table

            self.table = still_table(scene.colliders, model.n)

    def positions(self, x: np.ndarray, t: float) -> np.ndarray:
        """x (Nc, 3) of the coarse grid at time t -> (N, 3) on the file's grid."""
        out = self.spline(x)
        out[self.held] = self.pinned_at
        if self.table is None:
            return out
        from pipeline.physics.overlap import project_out

        soa = np.ascontiguousarray(out.T)
        project_out(soa, self.pinned, self.table, t)
        return soa.T

    def velocities(self, v: np.ndarray) -> np.ndarray:
        """v (Nc, 3) of the coarse grid -> (N, 3) on the file's grid."""
        out = self.spline(v)
        out[self.held] = 0.0
        return out
