"""The explicit stability limit `pipeline.physics.system.stability_limit(model)` -> (omega_max, dt_max).

Checked three independent ways: (a) analytically for square cells (omega_max^2 = 8 ks / m),
(b) against the eigenvalues of the finite lattice's stiffness matrix K, built here with numpy
from the SPEC's spring list (a finite cloth with free edges has its largest eigenvalue of
K / m below the infinite lattice's, and close to it), (c) by running the simulator just below
and just above dt_max, and (d) the damped-Verlet bound dt_max = sqrt(2 (2 - c)) / omega_max
from the roots of the recurrence's characteristic polynomial.
"""
from __future__ import annotations

import math
import warnings

import numpy as np
import pytest

from pipeline import DivergenceError, StabilityWarning, load_scene
from pipeline.physics.model import build_model
from pipeline.simulation import Simulation
from pipeline.physics.system import stability_limit

from conftest import cloth_dict, scene_dict, spring_pairs

pytestmark = pytest.mark.usefixtures("serial_numba")

BENDING = 0.2  # SPEC: k = 0.2 ks for bending springs


def _model(cloth: dict):
    return build_model(load_scene(scene_dict(cloth)))


def _stiffness_matrix(cloth: dict) -> tuple[np.ndarray, float]:
    """(K (3N x 3N), point mass) of the cloth at rest, from the SPEC text: every enabled
    spring between p and q with unit direction e and stiffness k adds k e e^T to the (p, p)
    and (q, q) blocks and -k e e^T to the (p, q) and (q, p) blocks. Horizontal grid at
    (width j/(nw-1), 1, height i/(nh-1))."""
    nw, nh = cloth["num_width_points"], cloth["num_height_points"]
    n = nw * nh
    i, j = np.divmod(np.arange(n), nw)
    x = np.stack([cloth["width"] * j / (nw - 1), np.ones(n), cloth["height"] * i / (nh - 1)], 1)
    ks = cloth["ks"]
    k_of = {0: ks if cloth["enable_structural"] else 0.0,
            1: ks if cloth["enable_shearing"] else 0.0,
            2: BENDING * ks if cloth["enable_bending"] else 0.0}
    K = np.zeros((3 * n, 3 * n))
    for p, q, kind in spring_pairs(nw, nh):
        k = k_of[kind]
        if k == 0.0:
            continue
        e = x[q] - x[p]
        e /= np.linalg.norm(e)
        block = k * np.outer(e, e)
        sp, sq = slice(3 * p, 3 * p + 3), slice(3 * q, 3 * q + 3)
        K[sp, sp] += block
        K[sq, sq] += block
        K[sp, sq] -= block
        K[sq, sp] -= block
    mass = cloth["width"] * cloth["height"] * cloth["density"] / n
    return K, mass


def test_square_cells_closed_form():
    """Square cells, all springs: the plane wave with phase pi per step along x, 0 along y,
    gives structural-x 4k (2(1 - cos pi) = 4), structural-y 0, the two shearing springs
    4k * (e e^T summed = I) and bending 0 (phase 2 pi): 4k xx + 4k I, largest 8 ks / m."""
    cloth = cloth_dict(12, 12, width=1.0, height=1.0, ks=5000.0, density=150.0, damping=0.2)
    omega, dt_max = stability_limit(_model(cloth))
    m = 1.0 * 1.0 * 150.0 / 144
    assert omega ** 2 == pytest.approx(8 * 5000.0 / m, rel=1e-12)
    c = 0.2 / 100
    assert dt_max == pytest.approx(math.sqrt(2 * (2 - c)) / omega, rel=1e-12)


@pytest.mark.parametrize(
    "cloth",
    [
        cloth_dict(12, 12, width=1.0, height=1.0, ks=5000.0, density=150.0),
        cloth_dict(10, 14, width=1.0, height=0.6, ks=300.0, density=2.0),  # non-square cells
        cloth_dict(12, 9, width=0.5, height=1.0, ks=1000.0, density=7.0, shearing=False),
        cloth_dict(12, 12, ks=100.0, structural=False, shearing=False),  # bending only
        cloth_dict(11, 12, width=1.2, height=0.9, ks=100.0, bending=False),
    ],
    ids=["square-all", "nonsquare-all", "no-shearing", "bending-only", "no-bending"],
)
def test_finite_lattice_eigenvalues_lie_just_below_omega_max(cloth):
    """x^T K_finite x <= x^T K_infinite x for x extended by zeros (the infinite lattice only
    adds springs, each of non-negative energy), so the finite cloth's largest eigenvalue of
    K / m is at most omega_max^2; a 12-point-wide cloth comes within 10% of it."""
    K, m = _stiffness_matrix(cloth)
    # at rest every spring lies in the cloth's plane (y = 1): the y rows and columns of K
    # are zero (no out-of-plane stiffness), so the spectrum is that of the in-plane part
    # (x, z) plus zeros; the smaller matrix also keeps LAPACK off its threaded path
    y = np.arange(1, K.shape[0], 3)
    assert not K[y].any() and not K[:, y].any()
    xz = np.setdiff1d(np.arange(K.shape[0]), y)
    lam = np.linalg.eigvalsh(K[np.ix_(xz, xz)] / m).max()
    omega, _ = stability_limit(_model(cloth))
    assert lam <= omega ** 2 * (1 + 1e-9)
    assert lam >= 0.9 * omega ** 2


def test_no_springs_means_no_limit():
    cloth = cloth_dict(4, 4, structural=False, shearing=False, bending=False)
    assert stability_limit(_model(cloth)) == (0.0, math.inf)


@pytest.mark.parametrize("damping", [0.0, 0.2, 5.0])
def test_dt_max_is_the_damped_verlet_bound(damping):
    """One mode of frequency w under x' = x + (1 - c)(x - x_last) - w^2 dt^2 x has the
    characteristic polynomial z^2 - (2 - c - (w dt)^2) z + (1 - c): both roots are inside
    the unit circle just below dt_max, and one is outside just above it."""
    cloth = cloth_dict(8, 8, ks=2000.0, density=100.0, damping=damping)
    omega, dt_max = stability_limit(_model(cloth))
    c = damping / 100

    def spectral_radius(dt):
        h = (omega * dt) ** 2
        return np.abs(np.roots([1.0, -(2.0 - c - h), 1.0 - c])).max()

    assert spectral_radius(dt_max * (1 - 1e-6)) <= 1.0 + 1e-12
    assert spectral_radius(dt_max * (1 + 1e-6)) > 1.0


def _perturbation_run(factor: float, steps: int, rng) -> tuple[float, list[float], bool]:
    """Run a free 12x12 cloth (no gravity, pins, colliders or damping) at dt = factor *
    dt_max from rest plus a 1e-9 m random displacement (given to x and x_last alike, so no
    initial velocity). Returns (initial amplitude, amplitude after each 10 steps, whether
    the divergence guard stopped the run)."""
    cloth = cloth_dict(12, 12, width=1.0, height=1.0, ks=5000.0, density=150.0, damping=0.0)
    _, dt_max = stability_limit(_model(cloth))
    scene = scene_dict(cloth, gravity=(0.0, 0.0, 0.0), frames_per_sec=1.0 / (factor * dt_max),
                       steps_per_frame=1)
    if factor > 1:
        with pytest.warns(StabilityWarning):
            sim = Simulation(scene)
    else:
        with warnings.catch_warnings():
            warnings.simplefilter("error", StabilityWarning)
            sim = Simulation(scene)
    assert sim.dt == pytest.approx(factor * dt_max, rel=1e-12)
    x0 = np.array(sim._state.x, copy=True)
    delta = rng.uniform(-1e-9, 1e-9, size=x0.shape)
    sim._state.x[...] = x0 + delta
    sim._state.last[...] = x0 + delta
    start = np.abs(sim._state.x - x0).max()
    amplitudes = []
    tripped = False
    for _ in range(steps // 10):
        try:
            sim.step(10)
        except DivergenceError:
            tripped = True
        amplitudes.append(float(np.abs(sim._state.x - x0).max()))
        if tripped:
            break
    return start, amplitudes, tripped


def test_simulator_is_stable_just_below_dt_max(rng):
    start, amplitudes, tripped = _perturbation_run(0.9, 2000, rng)
    assert not tripped
    assert len(amplitudes) == 200
    assert max(amplitudes) <= 10 * start, max(amplitudes) / start


def test_simulator_blows_up_just_above_dt_max(rng):
    start, amplitudes, tripped = _perturbation_run(1.1, 2000, rng)
    # grows by orders of magnitude (and the guard stops it once the speed is unphysical)
    assert max(amplitudes) >= 1e4 * start, max(amplitudes) / start
