"""Integrator benchmark: accuracy against wall-clock time, and the largest stable step.

`main(argv)` (wired as `render bench SCENE.json [--out DIR] [--models classic,fem]`) runs
every part once per cloth model (`simulation.model`: the classic mass-spring model and the
FEM, default both; every integrator runs with either) and writes into DIR:
    <scene>_work_precision.{png,svg,csv}  RMS position error at t = T against a converged
        reference (rk4 at a 16x smaller step than the scene's, checked against 32x), versus
        wall-clock seconds, one line per integrator over a sweep of steps per frame; one
        panel per model, side by side on the same axes (the csv has a `model` column);
    <scene>_reference.json  the references' facts, per model;
    <scene>_stability.{png,svg,csv}  largest stable step versus the stiffness (classic: ks;
        FEM: cloth.fem.stretch, shear kept at the scene's shear/stretch ratio) on a small copy
        of the scene (--stability-grid, default 10x10), found by bisection over trials of
        --stability-time simulated seconds (default STABILITY_TIME), with the
        theoretical explicit limit 2 / omega_max (pipeline.physics.system.stability_limit); one
        panel per model.
The work-precision runs use a copy of the scene at most DEFAULT_GRID points per side unless
--grid says otherwise (--grid 0: the scene's own grid).
See docs/integrators.md for the definitions and the measured results.

Fair comparison rules:
  * every integrator runs the same forces, the same position passes, the same guard;
  * the physical damping stays the same as the step changes: the scene's damping (percent of
    velocity lost per step at the scene's own step dt0) is a drag rate
    gamma = -ln(1 - c) / dt0, and a run at step dt gets c' = 1 - (1 - c)^(dt / dt0) per step
    (Verlet and XPBD use c' directly, the velocity-based methods use gamma);
  * both models run the same scene (grid, pins, gravity, damping, colliders); the FEM reads
    its material from cloth.fem (cloth.ks and cloth.density are ignored) and has no stretch
    limit (Provot applies to the classic springs only);
  * Verlet starts from x_last = x0 + dt^2 a0 / 2 (the Taylor start for v0 = 0) instead of the
    classic x_last = x0, whose first step is O(dt) wrong in velocity and would make the
    method first order (`classic_start=True` keeps the classic start);
  * numba runs on one thread (the machine is shared: threads waiting on busy cores made the
    parallel kernels 10-50x slower and the timings meaningless); JIT compilation is excluded.
"""
from __future__ import annotations

import argparse
import copy
import csv
import json
import math
import sys
import time
import warnings
from dataclasses import replace
from pathlib import Path

import numpy as np

from pipeline.physics.forces import elastic_energy, total_force_now
from pipeline.physics.integrators import state_class
from pipeline.physics.model import DIRECTION_TYPE, build_model
from pipeline.physics.system import System, build_system, damping_at, drag_gamma, stability_limit
from pipeline.run.outputs import atomic_file
from pipeline.scene import INTEGRATORS, MODELS, FemMaterial, Scene, SceneError, load_scene

REFERENCE = "rk4"
REFERENCE_FACTOR = 16  # the reference runs at dt_scene / 16 ...
CHECK_FACTOR = 32  # ... and is checked against dt_scene / 32
STEPS_PER_FRAME_SWEEP = (1, 2, 4, 8, 15, 30, 60, 120)
AUTO_TOLERANCES = (0.5, 1.0, 2.0, 4.0)  # fidelity auto, one work-precision point each (px)
KS_SWEEP = (1e2, 1e3, 1e4, 1e5, 1e6)  # classic model: cloth.ks (N/m)
STRETCH_SWEEP = (3e1, 3e2, 3e3, 3e4)  # FEM: cloth.fem.stretch (N/m), the default 300 inside
DEFAULT_GRID = 30  # work-precision grid (points per side) unless --grid: at most this
STIFFNESS_LABEL = {"classic": "cloth.ks (N/m)",
                   "fem": "cloth.fem.stretch (N/m; shear kept at the scene's shear/stretch)"}
STRAIN_LIMIT = 0.25  # divergence: 99th percentile |strain| of an unconstrained probe step
STABILITY_TIME = 0.5  # seconds simulated per stability trial ...
MAX_STABILITY_STEPS = 20_000  # ... or this many steps if fewer (explicit Euler's tiny steps)
COLORS = {"verlet": "C0", "euler": "C3", "symplectic-euler": "C1", "rk4": "C2",
          "implicit-euler": "C4", "xpbd": "C5", "vbd": "C6"}


# --- building runs ------------------------------------------------------------------------

def scene_data(source) -> dict:
    """The scene's JSON as a dict, after validating it (SceneError names a bad key)."""
    load_scene(source)
    if isinstance(source, dict):
        return copy.deepcopy(source)
    return json.loads(Path(source).read_text())


def resized(data: dict, nw: int, nh: int) -> dict:
    """A copy of the scene dict with an nw x nh cloth; pins keep their relative place."""
    data = copy.deepcopy(data)
    c = data["cloth"]
    ow, oh = c["num_width_points"], c["num_height_points"]
    c["num_width_points"], c["num_height_points"] = nw, nh
    if "pinned" in c:
        c["pinned"] = sorted({(round(x * (nw - 1) / (ow - 1)), round(y * (nh - 1) / (oh - 1)))
                              for x, y in c["pinned"]})
        c["pinned"] = [list(p) for p in c["pinned"]]
    return data


def with_model(data: dict, model: str) -> dict:
    """A copy of the scene dict that runs `model` ("classic" or "fem")."""
    if model not in MODELS:
        raise ValueError(f"unknown model {model!r}: expected one of {', '.join(MODELS)}")
    data = copy.deepcopy(data)
    sim = data.setdefault("simulation", {})
    sim["model"] = model
    return data


def with_stiffness(data: dict, model: str, value: float) -> dict:
    """A copy of the scene dict with the stiffness the stability chart sweeps set to value:
    cloth.ks for the classic model; cloth.fem.stretch for the FEM, with cloth.fem.shear
    scaled alike (the material keeps its shear/stretch ratio; bending and density stay)."""
    data = copy.deepcopy(data)
    cloth = data["cloth"]
    if model == "fem":
        fem = dict(cloth.get("fem", {}))
        material = FemMaterial(**{k: float(v) for k, v in fem.items()})
        fem["shear"] = material.shear * value / material.stretch
        fem["stretch"] = value
        cloth["fem"] = fem
    else:
        cloth["ks"] = value
    return data


def material(data: dict, model: str, swept: bool = False) -> str:
    """The model's material in words, for chart titles (swept: the stiffness is swept)."""
    c = data["cloth"]
    if model == "fem":
        m = FemMaterial(**{k: float(v) for k, v in c.get("fem", {}).items()})
        if swept:
            return (f"FEM: stretch swept, shear {m.shear / m.stretch:g} x stretch, bending "
                    f"{m.bending:g} N m, {m.density:g} kg/m^2")
        return (f"FEM: stretch {m.stretch:g} N/m, shear {m.shear:g} N/m, bending "
                f"{m.bending:g} N m, {m.density:g} kg/m^2")
    if swept:
        return f"classic mass-spring: ks swept, density {c['density']:g} kg/m^2"
    return f"classic mass-spring: ks {c['ks']:g} N/m, density {c['density']:g} kg/m^2"


class Run:
    """One integrator on one scene at one step: `state`, `system`, `model`, `scene`.

    `initial_positions` (N, 3) replace the grid (and so the rest lengths); `start_positions`
    (N, 3) only move the points at t = 0 (springs keep the grid's rest lengths)."""

    def __init__(self, scene: Scene | dict | str | Path, integrator: str, *,
                 dt: float | None = None, initial_positions=None, start_positions=None,
                 classic_start: bool = False) -> None:
        self.scene = scene if isinstance(scene, Scene) else load_scene(scene)
        self.scene = replace(self.scene, simulation=replace(self.scene.simulation,
                                                            integrator=integrator))
        self.model = build_model(self.scene, initial_positions)
        system = build_system(self.scene, self.model)
        self.dt0 = system.dt
        if dt is not None:
            # keep the scene's drag rate: c' = 1 - (1 - c)^(dt / dt0)
            dt = float(dt)
            damping = damping_at(system.damping, system.dt, dt)
            system = system._replace(dt=dt, damping=damping, force_dt2=dt * dt)
        self.system: System = system
        self.integrator = integrator
        self.state = state_class(integrator)(system)
        self.steps = 0
        if start_positions is not None:  # (N, 3): start away from rest, springs unchanged
            self.state.x[:] = np.asarray(start_positions, dtype=np.float64).T
            self.state.last[:] = self.state.x
        if integrator == "verlet" and not classic_start:
            force = np.zeros_like(self.state.x)
            total_force_now(self.state.x, np.zeros_like(force), 0.0, system, force)
            free = system.pinned == 0
            h2 = system.dt * system.dt
            # x_-1 = x0 - v0 dt + a0 dt^2 / 2 with v0 = 0
            self.state.last[:, free] = self.state.x[:, free] + (0.5 * h2 / system.mass[free]) * \
                force[:, free]

    def advance(self, steps: int) -> bool:
        """Advance; False when the divergence guard tripped."""
        done, kinetic, _ = self.state.advance(self.system, steps, self.steps)
        self.steps += done
        return done == steps and math.isfinite(kinetic)

    @property
    def x(self) -> np.ndarray:
        return self.state.x

    @property
    def model_name(self) -> str:
        return self.scene.simulation.model

    def cg_iterations(self) -> int | None:
        """CG iterations summed over the steps done (implicit Euler), else None."""
        count = getattr(self.state, "iterations", None)
        return None if count is None else int(count[0])

    def energy(self) -> float:
        """Kinetic + elastic potential (springs or FEM) + gravity potential (J)."""
        s = self.system
        v = self.state.velocity(s)
        kinetic = 0.5 * float(np.sum(s.mass * v * v))
        potential = elastic_energy(self.state.x, s)
        gravity = -float(np.sum(s.mass * s.gravity[:, None] * self.state.x))
        return kinetic + potential + gravity

    def probe_strain(self, compression: bool = False) -> float:
        """99th percentile of |strain| over the force-carrying structural and shearing
        springs after one more step with Provot switched off (the state is not changed):
        the stretch limit hides a blow-up as crumpling, this shows it. FEM model: the same
        grid springs, measured geometrically (every structural and shearing pair, whatever
        the classic enable flags; the FEM has no stretch limit, so the probe step is an
        ordinary step)."""
        state = copy.deepcopy(self.state)
        s = self.system
        free = s._replace(limit=s.limit * 1e6, limit_sq_lo=s.limit_sq_lo * 1e12,
                          spring_force=s.spring_force.copy())
        state.advance(free, 1, self.steps)
        x = state.x
        n = x.shape[1]
        strains = []
        offsets, _, exists, rest, stiffness = s.springs
        for d in range(6):
            if DIRECTION_TYPE[d] == 2 or (s.classic and stiffness[d] == 0.0):
                continue
            p = np.nonzero(exists[d])[0]
            q = p + offsets[d]
            length = np.linalg.norm(x[:, q] - x[:, p], axis=0)
            strains.append(length / rest[d, p] - 1.0)
        if not strains or n == 0:
            return 0.0
        values = np.concatenate(strains)
        values = np.maximum(-values, 0.0) if compression else np.abs(values)
        if not np.all(np.isfinite(values)):
            return math.inf
        return float(np.percentile(values, 99))


def set_threads(count: int = 1) -> None:
    import numba

    numba.set_num_threads(min(count, numba.config.NUMBA_NUM_THREADS))


def rms(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.sum((a - b) ** 2, axis=0))))


def run_until(scene, integrator: str, dt: float, t_end: float, **kw) -> tuple[Run, bool, float]:
    """(run, completed without divergence, wall seconds) for a run to t_end = steps * dt."""
    run = Run(scene, integrator, dt=dt, **kw)
    steps = round(t_end / dt)
    start = time.perf_counter()
    ok = run.advance(steps)
    return run, ok, time.perf_counter() - start


def warm_up(scene) -> None:
    """Compile every integrator of the scene's model (and the probe) on a tiny copy."""
    data = resized(scene_data(scene), 4, 4)
    for name in INTEGRATORS:
        run = Run(data, name)
        run.advance(2)
        run.probe_strain()


# --- (b) work-precision -------------------------------------------------------------------

def work_precision(scene, t_end: float = 1.0, sweep=STEPS_PER_FRAME_SWEEP,
                   integrators=INTEGRATORS, log=print,
                   auto_tolerances=AUTO_TOLERANCES) -> tuple[list[dict], dict]:
    """Rows (model, integrator, steps_per_frame, dt, error, seconds, ok, ...) and reference
    facts, for the scene's model."""
    base = Run(scene, REFERENCE)
    model = base.model_name
    fps = base.scene.simulation.frames_per_sec
    dt0 = base.dt0
    ref, ok_ref, sec_ref = run_until(scene, REFERENCE, dt0 / REFERENCE_FACTOR, t_end)
    chk, ok_chk, sec_chk = run_until(scene, REFERENCE, dt0 / CHECK_FACTOR, t_end)
    if not (ok_ref and ok_chk):
        raise RuntimeError("the reference diverged")
    info = {"model": model, "t_end": t_end, "dt_scene": dt0, "reference_dt": dt0 / REFERENCE_FACTOR,
            "reference_check_rms": rms(ref.x, chk.x), "reference_seconds": sec_ref,
            "check_seconds": sec_chk}
    log(f"[{model}] reference {REFERENCE} dt={dt0 / REFERENCE_FACTOR:.3g}s ({sec_ref:.1f}s wall); "
        f"RMS difference to dt/{CHECK_FACTOR}: {info['reference_check_rms']:.3g} m")
    rows = []
    for name in integrators:
        for spf in sweep:
            dt = 1.0 / fps / spf
            run, ok, seconds = run_until(scene, name, dt, t_end)
            error = rms(run.x, ref.x) if ok else math.nan
            strain = run.probe_strain() if ok else math.inf
            crumpled = strain > STRAIN_LIMIT
            cg = run.cg_iterations()
            cg_per_step = cg / run.steps if cg is not None and run.steps else math.nan
            rows.append({"model": model, "integrator": name, "steps_per_frame": spf, "dt": dt,
                         "rms_error": error, "seconds": seconds, "ok": ok and not crumpled,
                         "guard_ok": ok, "probe_strain_p99": strain,
                         "cg_iterations_per_step": cg_per_step})
            log(f"  {model:7s} {name:17s} spf={spf:4d} dt={dt:.3g} error={error:.3g} m "
                f"time={seconds:.3f}s guard={'ok' if ok else 'TRIPPED'} "
                f"strain99={strain:.3f}{' CRUMPLED' if crumpled else ''}"
                f"{f' cg/step={cg_per_step:.1f}' if cg is not None else ''}")
    for tolerance in auto_tolerances:
        rows.append(auto_point(scene, tolerance, t_end, ref.x, model))
        r = rows[-1]
        log(f"  {model:7s} auto {tolerance:g} px   spf={r['steps_per_frame']:4d} (median) "
            f"error={r['rms_error']:.3g} m time={r['seconds']:.3f}s")
    return rows, info


def auto_point(scene, tolerance: float, t_end: float, reference: np.ndarray, model: str) -> dict:
    """One work-precision row of fidelity auto at `tolerance` px (integrator "auto")."""
    from pipeline.physics.errors import DivergenceError
    from pipeline.simulation import Simulation

    data = copy.deepcopy(scene_data(scene))
    data.setdefault("simulation", {}).update(fidelity="auto", tolerance_px=tolerance)
    sim = Simulation(data, shot_seconds=t_end)
    frames = round(t_end * sim.scene.simulation.frames_per_sec)
    start = time.perf_counter()
    try:
        sim.advance(frames)
        ok = True
    except DivergenceError:
        ok = False
    seconds = time.perf_counter() - start
    used = sim.stepper.steps_used or [0]
    return {"model": model, "integrator": "auto", "steps_per_frame": int(np.median(used)),
            "dt": math.nan, "rms_error": rms(sim._state.x, reference) if ok else math.nan,
            "seconds": seconds, "ok": ok, "guard_ok": ok, "probe_strain_p99": math.nan,
            "cg_iterations_per_step": math.nan, "tolerance_px": tolerance}


# --- stability ------------------------------------------------------------------------------

def is_stable(data: dict, integrator: str, dt: float, t_end: float = STABILITY_TIME,
              strain_limit: float = STRAIN_LIMIT) -> bool:
    """Stable: the shared energy guard never trips over t_end (at least 8 steps, at most
    MAX_STABILITY_STEPS), and at
    t_end / 2 and t_end the unconstrained probe step (Provot off) keeps the 99th percentile
    |strain| of the structural and shearing springs below `strain_limit` (STRAIN_LIMIT, 2.5
    times Provot's cap: a blow-up that the stretch limit turns into crumpling shows there;
    the first steps' transient, e.g. of a huge implicit step, is not judged). The FEM has no
    cap: its probe step is an ordinary step, and the same 0.25 bounds its strain (a huge
    implicit step's overshoot in the middle of the fall counts as a failure too). A classic
    cloth run without Provot's limit (VBD) gets its own bound: own_strain_limit."""
    run = Run(data, integrator, dt=dt)
    total = min(max(round(t_end / dt), 8), MAX_STABILITY_STEPS)
    if not run.advance(total // 2) or run.probe_strain() > strain_limit:
        return False
    return run.advance(total - total // 2) and run.probe_strain() <= strain_limit


def own_strain_limit(data: dict, integrator: str, dt: float,
                     t_end: float = STABILITY_TIME) -> float:
    """The strain bound of a run at step dt: STRAIN_LIMIT, plus, on a classic cloth run
    without Provot's limit (VBD: the springs' energy alone), the strain the same run
    reaches at the small step dt: a soft cloth without the limit stretches that far by
    itself (a 10x10 pinned2 of 100 N/m springs: 99th-percentile strain 2.1), and only strain
    beyond it is a blow-up. math.inf where that run itself diverges (the search then reports
    '<')."""
    run = Run(data, integrator, dt=dt)
    if not run.system.classic or run.system.stretch_limit:
        return STRAIN_LIMIT
    if not run.advance(min(max(round(t_end / dt), 8), MAX_STABILITY_STEPS)):
        return math.inf
    return STRAIN_LIMIT + run.probe_strain()


def largest_stable_step(data: dict, integrator: str, lo: float, hi: float,
                        iterations: int = 6, t_end: float = STABILITY_TIME,
                        strain_limit: float = STRAIN_LIMIT) -> tuple[float, str]:
    """Largest stable step in [lo, hi]: scan up from lo by factors of 2 to the first
    unstable step, then bisect (in log dt) between it and the last stable one, so the answer
    is the first failure (stability need not be monotone in dt: a few huge steps can pass).
    Returns (dt, note): note '' , '>=' (stable up to hi) or '<' (unstable at lo). Each
    trial simulates t_end seconds (is_stable)."""
    if not is_stable(data, integrator, lo, t_end, strain_limit):
        return lo, "<"
    stable = lo
    while True:
        trial = min(2.0 * stable, hi)
        if not is_stable(data, integrator, trial, t_end, strain_limit):
            unstable = trial
            break
        if trial >= hi:
            return hi, ">="
        stable = trial
    for _ in range(iterations):
        mid = math.sqrt(stable * unstable)
        if is_stable(data, integrator, mid, t_end, strain_limit):
            stable = mid
        else:
            unstable = mid
    return stable, ""


def stability(scene, grid: int = 10, ks_values=None, integrators=INTEGRATORS,
              log=print, t_end: float = STABILITY_TIME) -> list[dict]:
    """Largest stable step per integrator and stiffness for the scene's model: ks_values are
    cloth.ks (classic; default KS_SWEEP) or cloth.fem.stretch (FEM; default STRETCH_SWEEP,
    see with_stiffness); each trial simulates t_end seconds."""
    rows = []
    data0 = resized(scene_data(scene), grid, grid)
    model = data0.get("simulation", {}).get("model", "classic")
    if ks_values is None:
        ks_values = STRETCH_SWEEP if model == "fem" else KS_SWEEP
    for ks in ks_values:
        data = with_stiffness(data0, model, ks)
        probe = Run(data, "verlet")
        omega, dt_verlet = stability_limit(probe.model)
        dt_theory = 2.0 / omega
        gamma = drag_gamma(probe.system.damping, probe.dt0)
        dt_euler = 2.0 * gamma / (gamma * gamma + omega * omega)
        frame_dt = 1.0 / probe.scene.simulation.frames_per_sec
        for name in integrators:
            lo = dt_theory / 16 if name != "euler" else min(dt_theory, dt_euler) / 4
            hi = dt_theory * (200 if name in ("implicit-euler", "xpbd") else 16)
            if name == "vbd":  # no explicit limit: searched up to one step per frame
                hi = max(hi, frame_dt)
            t0 = time.perf_counter()
            limit = own_strain_limit(data, name, lo, t_end)
            dt, note = largest_stable_step(data, name, lo, hi, t_end=t_end, strain_limit=limit)
            rows.append({"model": model, "integrator": name, "stiffness": ks,
                         "dt_stable": dt, "bound": note, "strain_limit": limit,
                         "frame_dt": frame_dt,
                         "omega_max": omega, "dt_theory": dt_theory,
                         "dt_verlet_damped": dt_verlet, "dt_euler_theory": dt_euler,
                         "ratio": dt / dt_theory})
            log(f"  {model:7s} k={ks:8.0f} {name:17s} dt_stable {note}{dt:.4g} s = {dt / dt_theory:.3g} x "
                f"2/omega_max ({dt_theory:.4g} s; omega_max {omega:.4g}) "
                f"[{time.perf_counter() - t0:.1f}s]")
    return rows


# --- charts ---------------------------------------------------------------------------------

def write_csv(path: Path, rows: list[dict]) -> None:
    with atomic_file(path) as tmp, tmp.open("w", newline="") as fh:
        fields = list(dict.fromkeys(k for r in rows for k in r))  # auto rows add a column
        writer = csv.DictWriter(fh, fieldnames=fields)
        writer.writeheader()
        writer.writerows(rows)


def _models(rows) -> list[str]:
    present = {r["model"] for r in rows}
    return [m for m in MODELS if m in present]


def _panels(count: int, sharex: bool = True):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, count, figsize=(6.6 * count, 5.6), sharex=sharex, sharey=True,
                             squeeze=False)
    return plt, fig, list(axes[0])


def _save(plt, fig, stem: Path) -> None:
    for ext in ("png", "svg"):
        with atomic_file(stem.with_suffix("." + ext)) as tmp:
            fig.savefig(tmp, dpi=130, format=ext)
    plt.close(fig)


def chart_work_precision(rows, infos: dict, title: str, stem: Path,
                         subtitles: dict | None = None) -> None:
    """One panel per model (shared axes: the same scene, so errors and times compare)."""
    models = _models(rows)
    plt, fig, axes = _panels(len(models))
    for model, ax in zip(models, axes):
        info = infos[model]
        failed = []
        for name in INTEGRATORS:
            pts = [r for r in rows if r["integrator"] == name and r["model"] == model]
            good = [r for r in pts if r["ok"]]
            if good:
                ax.loglog([r["seconds"] for r in good], [r["rms_error"] for r in good], "o-",
                          color=COLORS[name], label=name)
                for r in good:
                    ax.annotate(str(r["steps_per_frame"]), (r["seconds"], r["rms_error"]),
                                fontsize=6, xytext=(3, 3), textcoords="offset points")
            bad = [r for r in pts if not r["ok"] and math.isfinite(r["rms_error"])]
            if bad:
                ax.loglog([r["seconds"] for r in bad], [r["rms_error"] for r in bad], "x",
                          color=COLORS[name], ms=7)
            tripped = [str(r["steps_per_frame"]) for r in pts if not r["guard_ok"]]
            if tripped:
                failed.append(f"{name} {','.join(tripped)}")
        auto = [r for r in rows if r["integrator"] == "auto" and r["model"] == model and r["ok"]]
        if auto:
            ax.loglog([r["seconds"] for r in auto], [r["rms_error"] for r in auto], "*",
                      color="black", ms=9, label="fidelity auto (label: tolerance px)")
            for r in auto:
                ax.annotate(f"{r['tolerance_px']:g}", (r["seconds"], r["rms_error"]),
                            fontsize=6, xytext=(3, -8), textcoords="offset points")
        ax.axhline(info["reference_check_rms"], color="gray", ls=":", lw=1,
                   label="reference uncertainty (16x vs 32x)")
        ax.set_xlabel("wall-clock seconds for the run (one thread)")
        ax.set_ylabel(f"RMS position error at t = {info['t_end']:g} s (m)")
        ax.set_title((subtitles or {}).get(model, model), fontsize=9)
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8, loc="lower left")
        if failed:
            ax.text(0.99, 0.01, "diverged (guard), steps/frame:\n" + "\n".join(failed),
                    transform=ax.transAxes, ha="right", va="bottom", fontsize=7,
                    bbox={"facecolor": "white", "alpha": 0.8, "lw": 0})
    fig.suptitle(title, fontsize=10)
    fig.text(0.01, 0.005, "labels: steps per frame; x: guard ok but crumpled "
             f"(probe strain p99 > {STRAIN_LIMIT})", fontsize=7)
    fig.tight_layout(rect=(0, 0.02, 1, 1))
    _save(plt, fig, stem)


def chart_stability(rows, title: str, stem: Path, subtitles: dict | None = None) -> None:
    """One panel per model: largest stable step versus the model's stiffness."""
    models = _models(rows)
    plt, fig, axes = _panels(len(models), sharex=False)  # different stiffness scales
    offsets = {name: 1.0 + 0.03 * (i - 2.5) for i, name in enumerate(INTEGRATORS)}
    for model, ax in zip(models, axes):
        mine = [r for r in rows if r["model"] == model]
        ks = sorted({r["stiffness"] for r in mine})
        theory = [next(r["dt_theory"] for r in mine if r["stiffness"] == k) for k in ks]
        euler_theory = [next(r["dt_euler_theory"] for r in mine if r["stiffness"] == k)
                        for k in ks]
        ax.loglog(ks, theory, "k--", lw=1.5, label="2 / omega_max (stability_limit)")
        ax.loglog(ks, euler_theory, "k:", lw=1,
                  label="explicit Euler: 2 gamma / (gamma^2 + omega^2)")
        ax.axhline(mine[0]["frame_dt"], color="0.5", ls="-.", lw=1, label="one step per frame")
        for name in INTEGRATORS:
            pts = sorted((r for r in mine if r["integrator"] == name),
                         key=lambda r: r["stiffness"])
            if not pts:
                continue
            xs = [r["stiffness"] * offsets[name] for r in pts]
            ax.loglog(xs, [r["dt_stable"] for r in pts], "o-", color=COLORS[name], label=name)
            for r, x in zip(pts, xs):
                if r["bound"]:
                    ax.annotate(r["bound"], (x, r["dt_stable"]), fontsize=8,
                                color=COLORS[name], xytext=(4, -3), textcoords="offset points")
        ax.set_xlabel(STIFFNESS_LABEL[model])
        ax.set_ylabel("largest stable step (s)")
        ax.set_title((subtitles or {}).get(model, model), fontsize=9)
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8)
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    _save(plt, fig, stem)


# --- entry point ----------------------------------------------------------------------------

def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="render bench", description=__doc__.split("\n")[0])
    parser.add_argument("scene", help="scene JSON")
    parser.add_argument("--out", default="renders/bench", help="output folder")
    parser.add_argument("--models", default=",".join(MODELS),
                        help="cloth models to compare, comma-separated (default: "
                             f"{','.join(MODELS)}); each runs the integrators scenes accept with it")
    parser.add_argument("--grid", type=int, default=None,
                        help="cloth points per side for the work-precision runs (default: the "
                             f"scene's, at most {DEFAULT_GRID}; 0: the scene's own)")
    parser.add_argument("--stability-grid", type=int, default=10,
                        help="cloth points per side for the stability search (default 10)")
    parser.add_argument("--time", type=float, default=1.0, help="simulated seconds (default 1)")
    parser.add_argument("--sweep", default=",".join(map(str, STEPS_PER_FRAME_SWEEP)),
                        help="steps per frame to try, comma-separated")
    parser.add_argument("--ks", default=",".join(f"{k:g}" for k in KS_SWEEP),
                        help="classic model: ks values of the stability search, comma-separated")
    parser.add_argument("--stretch", default=",".join(f"{k:g}" for k in STRETCH_SWEEP),
                        help="FEM: cloth.fem.stretch values of the stability search, "
                             "comma-separated (shear scaled alike)")
    parser.add_argument("--stability-time", type=float, default=STABILITY_TIME,
                        help="simulated seconds of each stability trial (default "
                             f"{STABILITY_TIME:g}; shorter is quicker and may pass a slow "
                             "blow-up)")
    parser.add_argument("--skip-stability", action="store_true")
    parser.add_argument("--skip-work-precision", action="store_true")
    args = parser.parse_args(argv)
    models = [m.strip() for m in args.models.split(",") if m.strip()]
    unknown = [m for m in models if m not in MODELS]
    if unknown or not models:
        parser.error(f"--models: unknown model {', '.join(unknown) or '(none)'}; expected "
                     f"a comma-separated list of {', '.join(MODELS)}")
    args.models = [m for m in MODELS if m in models]
    if not args.stability_time > 0:  # also NaN
        parser.error(f"--stability-time: expected seconds > 0, got {args.stability_time:g}")

    set_threads(1)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # StabilityWarning is expected for the large steps
        return _bench(args)


def _bench(args) -> int:
    out = Path(args.out)
    created = not out.exists()
    out.mkdir(parents=True, exist_ok=True)
    try:
        return _bench_into(args, out)
    except BaseException:
        if created and not any(out.iterdir()):  # stopped before writing: leave no trace
            out.rmdir()
        raise


def _bench_into(args, out: Path) -> int:
    """The benchmark proper; every file is written atomically (outputs.atomic_file)."""
    data = scene_data(args.scene)
    name = Path(args.scene).stem
    c = data["cloth"]
    if "mesh" in c:
        raise SceneError(f"{args.scene}: cloth.mesh: render bench runs grid cloths only (it "
                         "resizes the grid and runs every integrator; implicit Euler and "
                         "XPBD do not step a mesh cloth yet)")
    nw, nh = c["num_width_points"], c["num_height_points"]
    if args.grid is None:
        grid = (min(nw, DEFAULT_GRID), min(nh, DEFAULT_GRID))
    else:
        grid = (args.grid, args.grid) if args.grid else (nw, nh)
    if grid != (nw, nh):
        data = resized(data, *grid)
    size = f"{grid[0]}x{grid[1]}"
    per_model = {m: with_model(data, m) for m in args.models}
    subtitles = {m: material(d, m) for m, d in per_model.items()}
    t0 = time.perf_counter()
    for model in args.models:
        warm_up(per_model[model])
    print(f"compiled in {time.perf_counter() - t0:.1f}s")
    if not args.skip_work_precision:
        t1 = time.perf_counter()
        sweep = tuple(int(v) for v in args.sweep.split(","))
        print(f"work-precision on {name} ({size}), t = {args.time} s, models "
              f"{', '.join(args.models)}")
        rows, infos = [], {}
        for model in args.models:
            model_rows, infos[model] = work_precision(per_model[model], args.time, sweep)
            rows += model_rows
        stem = out / f"{name}_work_precision"
        write_csv(stem.with_suffix(".csv"), rows)
        with atomic_file(out / f"{name}_reference.json") as tmp:
            tmp.write_text(json.dumps(infos, indent=2) + "\n")
        chart_work_precision(rows, infos, f"{name} ({size}, damping {c['damping']}%): error "
                             f"at t = {args.time:g} s vs {REFERENCE} at dt/{REFERENCE_FACTOR}",
                             stem, subtitles)
        print(f"work-precision took {time.perf_counter() - t1:.1f}s")
    if not args.skip_stability:
        t1 = time.perf_counter()
        g = args.stability_grid
        print(f"stability on {name} ({g}x{g})")
        sweeps = {"classic": args.ks, "fem": args.stretch}
        rows = []
        for model in args.models:
            rows += stability(per_model[model], g,
                              tuple(float(k) for k in sweeps[model].split(",")),
                              t_end=args.stability_time)
        stem = out / f"{name}_stability"
        write_csv(stem.with_suffix(".csv"), rows)
        chart_stability(rows, f"{name} ({g}x{g}): largest stable step over "
                        f"{args.stability_time:g} s (guard + probe strain p99 < {STRAIN_LIMIT}; VBD on the "
                        f"classic springs, without Provot: < its own stretch + {STRAIN_LIMIT})",
                        stem,
                        {m: material(d, m, swept=True) for m, d in per_model.items()})
        print(f"stability took {time.perf_counter() - t1:.1f}s")
    print(f"done in {time.perf_counter() - t0:.1f}s; wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
