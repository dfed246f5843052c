"""Does Chebyshev acceleration pay under Vertex Block Descent? Error against the converged
backward Euler step per unit cost, with and without it (issue 44).

    python benchmarks/vbd.py                       # 20x20 and 50x50, 5/10/20/40 sweeps
    python benchmarks/vbd.py --sizes 20 --starts stretched --rhos 0.9,0.95 --plain-first 2

Flags: --sizes, --sweeps (counts), --starts (near-rest, stretched, mid-fall), --rhos,
--plain-first (plain sweeps before the extrapolation starts), --rounds (timed, >= 3).

The case: an FEM sheet 1 m a side, n x n points, pinned at two corners, stretch 3000 N/m
(shear 300 N/m, bending 1e-4 N m, 0.2 kg/m^2, damping 1 %), one step of 1/30 s (one step
per frame at 30 fps), from three starts: `near-rest` (the flat sheet moved by up to 2 mm,
velocities up to 0.1 m/s, as tests/test_vbd.py's perturbed_run), `stretched` (the free
points at 1.6x their distance from the centre, at rest) and `mid-fall` (the flat sheet
after 15 steps, 0.5 s, of the integrator at 40 sweeps: a step as a running scene has them).

The reference: backward Euler's step of the same model solved by Newton's method to
convergence (|step| < 1e-13 m), the Jacobian of the model's own force
(forces.total_force_now) by central differences and a direct sparse solve (scipy), as
tests/test_vbd.py's newton_backward_euler; the columns are found many at once: on the grid an
element spans at most 2 points in i and in j, so the points of a lattice of spacing 5 have
columns with disjoint rows, and perturbing them together gives every column bit for bit as
perturbing each alone. Newton starts from 2000 plain sweeps (20000, 200000 where it does
not converge), so that it finds the minimum the sweeps head for (they lower the incremental
potential), its steps halved until the residual falls (from 200 sweeps on the 50x50
near-rest sheet plain Newton diverged: the Jacobian is indefinite there); it ends
quadratically.

The sweeps: vbd.py's own per-point update (`_update_point`, the colours in
vbd_energy's order) from the step's initial guess (the integrator's `_predict`, run by a
step of 0 sweeps), in a loop of this file that can add the Chebyshev semi-iterative
extrapolation (Wang 2015, as Chen et al. 2024 use it): after sweep k gives x_bar,
x_k = omega_k (x_bar - x_{k-2}) + x_{k-2}, omega = 1 for the first `start` sweeps, then
omega = 2 / (2 - rho^2), then omega_k = 4 / (4 - rho^2 omega_{k-1}). With rho = 0 it is
vbd.descend exactly (checked: the same bits as the integrator's step). Cost: the seconds
of the sweeps, plain and accelerated alternately, over --rounds rounds (medians).

Prints, per size and start: the error max |x - x*| (m) after 5, 10, 20, 40 sweeps, plain
and per (rho, start); then the cost of a sweep with the extrapolation against without.
"""
from __future__ import annotations

import argparse
import statistics
import time

import numpy as np
from numba import njit
from scipy import sparse
from scipy.sparse.linalg import spsolve

from pipeline.cli.bench import Run
from pipeline.physics.forces import total_force_now
from pipeline.physics.integrators.vbd import _update_point
from pipeline.physics.system import drag_gamma

REACH = 2  # an element's points are within REACH of each other in i and in j
SPACING = 2 * REACH + 1  # lattice points this far apart have columns with disjoint rows
EPS = 1e-7  # central differences (as tests/test_vbd.py)
POLISH_SWEEPS = (2000, 20000, 200000)  # plain sweeps before Newton, tried in turn
STARTS = ("near-rest", "stretched", "mid-fall")


def sheet(n: int) -> dict:
    """The case's scene (the module docstring)."""
    return {"cloth": {"width": 1.0, "height": 1.0, "num_width_points": n,
                      "num_height_points": n, "thickness": 0.01, "orientation": 0,
                      "damping": 1.0, "density": 1.0, "ks": 500.0, "enable_structural": True,
                      "enable_shearing": True, "enable_bending": True,
                      "pinned": [[0, 0], [n - 1, 0]],
                      "fem": {"stretch": 3000.0, "shear": 300.0, "bending": 1e-4,
                              "density": 0.2}},
            "simulation": {"model": "fem", "integrator": "vbd", "frames_per_sec": 30,
                           "steps_per_frame": 1, "self_collision": False}}


def start_run(n: int, start: str) -> Run:
    """A run at the start state, before its step."""
    run = Run(sheet(n), "vbd")
    state, free = run.state, run.system.pinned == 0
    if start == "near-rest":
        rng = np.random.default_rng(1)
        state.x[:, free] += rng.uniform(-2e-3, 2e-3, (3, int(free.sum())))
        state.v[:, free] = rng.uniform(-0.1, 0.1, (3, int(free.sum())))
    elif start == "stretched":
        centre = state.x.mean(axis=1, keepdims=True)
        state.x[:, free] = (centre + 1.6 * (state.x - centre))[:, free]
        run.system = run.system._replace(slack_speed=1e6)  # the guard: see test_vbd
    else:
        run.system = run.system._replace(iterations=40)
        run.advance(15)
        return run
    state.last[:] = state.x
    return run


def initial_guess(run: Run) -> tuple[np.ndarray, Run]:
    """(x_t, the run after a step of 0 sweeps): its state holds the initial guess in x and
    the step's y and inertia weights."""
    x_t = run.state.x.copy()
    run.system = run.system._replace(iterations=0)
    run.advance(1)
    return x_t, run


@njit(cache=False, nogil=True)
def sweeps(x, y, inertia, pinned, el, iterations, rho, start, before, older):
    """`iterations` sweeps of vbd.descend's updates on x; from sweep start + 1 on each is
    extrapolated by Chebyshev's omega (rho = 0: vbd.descend exactly). before and older:
    scratch of x's shape."""
    order, colours = el.order, el.colour_start
    omega = 1.0
    older[:] = x
    for k in range(1, iterations + 1):
        before[:] = x
        for c in range(colours.shape[0] - 1):
            for i in range(colours[c], colours[c + 1]):
                p = order[i]
                if pinned[p] == 0:
                    _update_point(x, y, inertia, el, p, False)
        if rho == 0.0 or k <= start:
            omega = 1.0
        elif k == start + 1:
            omega = 2.0 / (2.0 - rho * rho)
        else:
            omega = 4.0 / (4.0 - rho * rho * omega)
        if omega != 1.0:
            for p in range(x.shape[1]):
                if pinned[p] == 0:
                    for a in range(3):
                        x[a, p] = omega * (x[a, p] - older[a, p]) + older[a, p]
        older[:] = before


def run_sweeps(run: Run, iterations: int, rho: float, start: int) -> tuple[np.ndarray, float]:
    """(positions after the sweeps, their seconds) from the run's initial guess."""
    s = run.state
    x = s.predicted.copy()  # the guess as the descent saw it (no position pass here anyway)
    t0 = time.perf_counter()
    sweeps(x, s.y, s.inertia, run.system.pinned, s.elements, iterations, rho, start,
           np.empty_like(x), np.empty_like(x))
    return x, time.perf_counter() - t0


def jacobian(x: np.ndarray, force, dofs: np.ndarray, nw: int) -> sparse.csc_matrix:
    """d force / dx on the free dofs, by central differences, SPACING x SPACING lattice
    points of one axis at a time (the module docstring)."""
    n = x.shape[1]
    i, j = np.divmod(np.arange(n), nw)
    slot = np.full(3 * n, -1)
    slot[dofs] = np.arange(len(dofs))
    rows, cols, vals = [], [], []
    for a in range(3):
        for di in range(SPACING):
            for dj in range(SPACING):
                group = np.nonzero((i % SPACING == di) & (j % SPACING == dj))[0]
                group = group[slot[a * n + group] >= 0]
                if not len(group):
                    continue
                plus, minus = x.copy(), x.copy()
                plus[a, group] += EPS
                minus[a, group] -= EPS
                diff = (force(plus) - force(minus)) / (2 * EPS)  # (3, n)
                near = (np.abs(i[None, :] - i[group, None]) <= REACH) & \
                       (np.abs(j[None, :] - j[group, None]) <= REACH)
                for g, q in zip(*np.nonzero(near)):
                    for b in range(3):
                        if slot[b * n + q] >= 0:
                            rows.append(slot[b * n + q])
                            cols.append(slot[a * n + group[g]])
                            vals.append(diff[b, q])
    return sparse.csc_matrix((vals, (rows, cols)), shape=(len(dofs), len(dofs)))


def backward_euler(run: Run, x_t: np.ndarray, v_t: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Backward Euler's step from (x_t, v_t), Newton's method from x (the module
    docstring): (1 + h gamma) M (x - x_t) - h M v_t - h^2 F(x) = 0 on the free points; each
    step halved until |residual| falls (a Newton step always lowers it for a small enough
    length), as the Jacobian can be indefinite on a stretched or buckling sheet."""
    s = run.system
    h, gamma = s.dt, drag_gamma(s.damping, s.dt)
    n = x.shape[1]
    free = np.nonzero(s.pinned == 0)[0]
    dofs = np.concatenate([free + a * n for a in range(3)])
    mass = np.tile(s.mass, 3)[dofs]

    def force(at: np.ndarray) -> np.ndarray:
        f = np.zeros_like(at)
        total_force_now(at, np.zeros_like(at), 0.0, s, f)
        return f

    def residual(at: np.ndarray) -> np.ndarray:
        return ((1 + h * gamma) * mass * (at - x_t).ravel()[dofs]
                - h * mass * v_t.ravel()[dofs] - h * h * force(at).ravel()[dofs])

    x = x.copy()
    r = residual(x)
    for _ in range(60):
        system = sparse.diags((1 + h * gamma) * mass) - h * h * jacobian(
            x, force, dofs, run.scene.cloth.num_width_points)
        step = spsolve(system.tocsc(), -r)
        if np.abs(step).max() < 1e-13:
            return x
        for _ in range(40):
            trial = x.copy()
            trial.ravel()[dofs] += step
            r_trial = residual(trial)
            if np.linalg.norm(r_trial) < np.linalg.norm(r):
                break
            step *= 0.5
        x, r = trial, r_trial
    raise RuntimeError("Newton did not converge")


def converged(run: Run, x_t: np.ndarray, v_t: np.ndarray) -> np.ndarray:
    """The reference x*: Newton from POLISH_SWEEPS plain sweeps, then from 10x as many
    where it did not converge."""
    for count in POLISH_SWEEPS:
        try:
            return backward_euler(run, x_t, v_t, run_sweeps(run, count, 0.0, 0)[0])
        except RuntimeError:
            print(f"(Newton from {count} sweeps did not converge)")
    raise RuntimeError("no reference")


def check_plain_is_vbd(run: Run, n: int, start: str) -> None:
    """This file's sweeps at rho = 0 give the integrator's own step bit for bit."""
    mine, _ = run_sweeps(run, 10, 0.0, 0)
    own = start_run(n, start)
    own.system = own.system._replace(iterations=10)
    own.advance(1)
    assert np.array_equal(own.state.predicted, mine), "the harness is not vbd.descend"


def case(n: int, start: str, counts: list[int], rhos: list[float], firsts: list[int],
         rounds: int) -> None:
    """Print one size and start's errors and costs."""
    run = start_run(n, start)
    v_t = run.state.v.copy()
    x_t, run = initial_guess(run)
    check_plain_is_vbd(run, n, start)
    t0 = time.perf_counter()
    reference = converged(run, x_t, v_t)
    moved = np.abs(reference - x_t).max()
    print(f"\n{n}x{n} {start}: the converged step moves points up to {moved:.3e} m "
          f"(reference {time.perf_counter() - t0:.1f} s); max |x - x*| (m) after k sweeps")
    variants = [(0.0, 0)] + [(r, f) for r in rhos for f in firsts]
    print(f"{'':22s}" + "".join(f"{k:>10d}" for k in counts))
    for rho, first in variants:
        label = "plain" if rho == 0.0 else f"rho {rho:g}, from sweep {first + 1}"
        errors = [np.abs(run_sweeps(run, k, rho, first)[0] - reference).max() for k in counts]
        print(f"  {label:20s}" + "".join(f"{e:10.2e}" for e in errors))
    k = max(counts)
    plain, fast = [], []
    for _ in range(rounds):  # alternately
        plain.append(run_sweeps(run, k, 0.0, 0)[1])
        fast.append(run_sweeps(run, k, rhos[0], firsts[0])[1])
    print(f"  {k} sweeps: plain {1e3 * statistics.median(plain):.2f} ms, accelerated "
          f"{1e3 * statistics.median(fast):.2f} ms (medians of {rounds}; ratio "
          f"{statistics.median(f / p for f, p in zip(fast, plain)):.3f})")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default="20,50", help="points a side, comma-separated")
    ap.add_argument("--sweeps", default="5,10,20,40", help="sweep counts")
    ap.add_argument("--rhos", default="0.9,0.95,0.8", help="Chebyshev rho values")
    ap.add_argument("--plain-first", default="2,1",
                    help="plain sweeps before the extrapolation, comma-separated")
    ap.add_argument("--starts", default=",".join(STARTS), help="the step's start states")
    ap.add_argument("--rounds", type=int, default=7, help="timed rounds (>= 3)")
    args = ap.parse_args()
    counts = [int(v) for v in args.sweeps.split(",")]
    rhos = [float(v) for v in args.rhos.split(",")]
    firsts = [int(v) for v in args.plain_first.split(",")]
    starts = args.starts.split(",")
    if args.rounds < 3 or not all(0.0 < r < 1.0 for r in rhos) or set(starts) - set(STARTS):
        ap.error(f"--rounds must be >= 3, every rho in (0, 1), starts of {', '.join(STARTS)}")
    for n in (int(v) for v in args.sizes.split(",")):
        for start in starts:
            case(n, start, counts, rhos, firsts, args.rounds)


if __name__ == "__main__":
    main()
