"""The finite-element cloth kernels (pipeline/physics/fem.py) against finite differences of the
energy, closed-form energies of simple deformations, and dense linear algebra.

Every expected value comes from outside the kernel under test: a central difference of
`fem_energy` (itself checked against closed forms below), a closed-form energy or force, or
numpy's dense eigenvalues. Grids stay small so the dense checks are cheap.
"""
from __future__ import annotations

import math
import zlib

import numba
import numpy as np
import pytest

from pipeline.physics import fem

# (k_stretch, k_shear, k_bend) of the four energy combinations
STRETCH, SHEAR, BEND = (120.0, 0.0, 0.0), (0.0, 45.0, 0.0), (0.0, 0.0, 0.35)
ALL = (120.0, 45.0, 0.35)
COMBOS = {"stretch": STRETCH, "shear": SHEAR, "bend": BEND, "all": ALL}
# (nw, nh, width, height): non-square cells; 6 x 18 has 17 cell rows, i.e. 8 parallel bands
GRIDS = [(5, 4, 1.0, 0.7), (7, 6, 0.6, 1.3), (6, 18, 0.5, 1.5)]
TINY_GRIDS = [(2, 2, 0.4, 0.3), (3, 2, 0.5, 0.2), (2, 3, 0.3, 0.6)]
# in-plane scale of the deformed states: compressed, stretched, anisotropic
STATES = {"compressed": (0.75, 0.8), "stretched": (1.25, 1.15), "mixed": (1.2, 0.8)}


def make(grid, k, density=1.0):
    nw, nh, width, height = grid
    return fem.build_fem(nw, nh, width, height, *k, density)


def spacing(p):
    return min(p.width / (p.nw - 1), p.height / (p.nh - 1))


def deformed(p, state, seed, jitter=0.15, lift=0.3):
    """The rest sheet scaled in-plane per `state`, then every point moved at random by
    about `jitter` (in plane) and `lift` (out of plane) times the grid spacing."""
    rng = np.random.default_rng(seed)
    x = p.x_rest.copy()
    su, sv = STATES[state]
    x[0] *= su
    x[1] *= sv
    h = spacing(p)
    x[:2] += jitter * h * rng.standard_normal((2, x.shape[1]))
    x[2] += lift * h * rng.standard_normal(x.shape[1])
    return x


def force(x, p):
    f = np.zeros_like(x)
    fem.add_fem_forces(x, p, f)
    return f


def product(kernel, x, p, y):
    out = np.full_like(x, np.nan)  # the kernels must overwrite out
    kernel(x, p, np.ascontiguousarray(y), out)
    return out


def energy_gradient_fd(x, p, h=1e-6):
    """Central difference of fem_energy, coordinate by coordinate."""
    g = np.zeros_like(x)
    xp = x.copy()
    for a in range(3):
        for i in range(x.shape[1]):
            xp[a, i] = x[a, i] + h
            ep = fem.fem_energy(xp, p)
            xp[a, i] = x[a, i] - h
            em = fem.fem_energy(xp, p)
            xp[a, i] = x[a, i]
            g[a, i] = (ep - em) / (2.0 * h)
    return g


def dense(kernel, x, p):
    """The 3N x 3N matrix of a product kernel (index a * N + p), column by column."""
    n = x.size
    m = np.zeros((n, n))
    for c in range(n):
        y = np.zeros(n)
        y[c] = 1.0
        m[:, c] = product(kernel, x, p, y.reshape(x.shape)).ravel()
    return m


def rotation(axis, angle):
    """Rodrigues' rotation matrix."""
    k = np.asarray(axis, dtype=float)
    k /= np.linalg.norm(k)
    kx = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + math.sin(angle) * kx + (1.0 - math.cos(angle)) * kx @ kx


def rel(a, b):
    return np.linalg.norm(a - b) / np.linalg.norm(b)


# --- 1. force = -grad E -----------------------------------------------------------------------


@pytest.mark.parametrize("combo", COMBOS)
@pytest.mark.parametrize("grid", GRIDS + TINY_GRIDS)
@pytest.mark.parametrize("state", STATES)
def test_force_is_minus_energy_gradient(combo, grid, state):
    p = make(grid, COMBOS[combo])
    x = deformed(p, state, seed=zlib.crc32(repr((combo, grid, state)).encode()))
    f = force(x, p)
    assert np.linalg.norm(f) > 0.0
    assert rel(f, -energy_gradient_fd(x, p)) < 1e-6


def test_force_accumulates_into_f():
    p = make(GRIDS[0], ALL)
    x = deformed(p, "mixed", seed=3)
    f0 = np.random.default_rng(4).standard_normal(x.shape)
    f = f0.copy()
    fem.add_fem_forces(x, p, f)
    assert np.allclose(f - f0, force(x, p), rtol=0, atol=1e-12 * np.abs(f0).max())


def test_bending_smooth_through_flat():
    """Out-of-plane wiggles far smaller than the difference step: the stencil crosses theta
    = 0 on every hinge, so a kink (|theta|, or a branch cut of the angle) would show."""
    p = make((7, 6, 0.6, 1.3), BEND)
    x = deformed(p, "mixed", seed=5, lift=0.0)
    x[2] = 1e-8 * spacing(p) * np.random.default_rng(6).standard_normal(x.shape[1])
    f = force(x, p)
    assert np.linalg.norm(f) > 0.0
    assert rel(f, -energy_gradient_fd(x, p, h=1e-6)) < 1e-6


# --- 2. exact Jacobian product ----------------------------------------------------------------


@pytest.mark.parametrize("combo", COMBOS)
@pytest.mark.parametrize("grid", GRIDS[:2] + TINY_GRIDS[:1])
@pytest.mark.parametrize("state", STATES)
def test_jacobian_product_matches_force_difference(combo, grid, state):
    p = make(grid, COMBOS[combo])
    x = deformed(p, state, seed=11)
    rng = np.random.default_rng(12)
    for _ in range(2):
        y = rng.standard_normal(x.shape)
        h = 1e-6
        fd = (force(x + h * y, p) - force(x - h * y, p)) / (2.0 * h)
        assert rel(product(fem.fem_jacobian_product, x, p, y), fd) < 1e-6


@pytest.mark.parametrize("kernel", [fem.fem_jacobian_product, fem.fem_filtered_jacobian_product])
@pytest.mark.parametrize("state", STATES)
def test_jacobian_products_symmetric(kernel, state):
    p = make(GRIDS[1], ALL)
    x = deformed(p, state, seed=13)
    rng = np.random.default_rng(14)
    for _ in range(3):
        y1, y2 = rng.standard_normal(x.shape), rng.standard_normal(x.shape)
        k1, k2 = product(kernel, x, p, y1), product(kernel, x, p, y2)
        scale = np.linalg.norm(y2) * np.linalg.norm(k1)
        assert abs(np.vdot(y2, k1) - np.vdot(y1, k2)) < 1e-10 * scale


# --- 3. filtered product ----------------------------------------------------------------------


@pytest.mark.parametrize("grid", GRIDS[:2])
def test_filtered_equals_exact_at_rest(grid):
    p = make(grid, ALL)
    y = np.random.default_rng(21).standard_normal(p.x_rest.shape)
    exact = product(fem.fem_jacobian_product, p.x_rest, p, y)
    assert rel(product(fem.fem_filtered_jacobian_product, p.x_rest, p, y), exact) < 1e-12
    # and the rest-state product is the force difference (the filtered one is exact there)
    h = 1e-6
    fd = (force(p.x_rest + h * y, p) - force(p.x_rest - h * y, p)) / (2.0 * h)
    assert rel(exact, fd) < 1e-6


@pytest.mark.parametrize("combo", COMBOS)
@pytest.mark.parametrize("state", STATES)
def test_filtered_negative_semidefinite(combo, state):
    p = make((5, 4, 1.0, 0.7), COMBOS[combo])
    x = deformed(p, state, seed=22, jitter=0.3, lift=0.5)
    kf = dense(fem.fem_filtered_jacobian_product, x, p)
    k = dense(fem.fem_jacobian_product, x, p)
    scale = np.abs(k).max()
    assert np.abs(kf - kf.T).max() < 1e-12 * scale
    assert np.linalg.eigvalsh(kf).max() < 1e-10 * scale
    if state == "compressed" or combo in ("shear", "bend"):  # the filter matters here
        assert np.linalg.eigvalsh(0.5 * (k + k.T)).max() > 1e-3 * scale
    rng = np.random.default_rng(23)
    for _ in range(5):  # the matrix-free quadratic form, on a bigger grid
        q = make(GRIDS[2], COMBOS[combo])
        xq = deformed(q, state, seed=24, jitter=0.3, lift=0.5)
        y = rng.standard_normal(xq.shape)
        ky = product(fem.fem_filtered_jacobian_product, xq, q, y)
        assert np.vdot(y, ky) <= 1e-12 * np.linalg.norm(y) * np.linalg.norm(ky)


# --- 4. diagonal ------------------------------------------------------------------------------


@pytest.mark.parametrize("combo", COMBOS)
@pytest.mark.parametrize("state", STATES)
def test_jacobian_diagonal_matches_filtered_matrix(combo, state):
    p = make((4, 3, 0.9, 0.5), COMBOS[combo])
    x = deformed(p, state, seed=31, jitter=0.3, lift=0.5)
    kf = dense(fem.fem_filtered_jacobian_product, x, p)
    d = np.full_like(x, np.nan)
    fem.fem_jacobian_diagonal(x, p, d)
    assert np.all(d >= 0.0)
    assert np.abs(d.ravel() + np.diag(kf)).max() < 1e-12 * np.abs(kf).max()


# --- 5. rigid motions -------------------------------------------------------------------------


@pytest.mark.parametrize("grid", GRIDS[:2])
def test_rigid_motion_of_rest_sheet_is_free(grid):
    p = make(grid, ALL)
    r = rotation((0.3, -1.1, 0.7), 2.1)
    x = r @ p.x_rest + np.array([[0.4], [-1.7], [2.3]])
    h = spacing(p)
    force_scale = p.k_stretch * h + p.k_shear * h + p.k_bend / h
    energy_scale = (p.k_stretch + p.k_shear) * p.width * p.height + p.k_bend
    assert np.abs(force(x, p)).max() < 1e-12 * force_scale
    assert abs(fem.fem_energy(x, p)) < 1e-24 * energy_scale
    assert abs(fem.fem_energy(p.x_rest, p)) < 1e-24 * energy_scale  # R^-1 is rounded
    assert np.abs(force(p.x_rest, p)).max() < 1e-12 * force_scale


@pytest.mark.parametrize("state", STATES)
def test_rigid_motion_of_deformed_sheet(state):
    p = make(GRIDS[1], ALL)
    x = deformed(p, state, seed=41)
    r = rotation((-0.5, 0.2, 0.9), -0.8)
    t = np.array([[1.1], [0.3], [-0.6]])
    xr = r @ x + t
    e, er = fem.fem_energy(x, p), fem.fem_energy(xr, p)
    assert e > 0.0 and abs(er - e) < 1e-12 * e
    assert rel(force(xr, p), r @ force(x, p)) < 1e-12
    y = np.random.default_rng(42).standard_normal(x.shape)
    for kernel in (fem.fem_jacobian_product, fem.fem_filtered_jacobian_product):
        assert rel(product(kernel, xr, p, r @ y), r @ product(kernel, x, p, y)) < 1e-11


# --- 6. uniform stretch and shear -------------------------------------------------------------


@pytest.mark.parametrize("s", [1.2, 0.85])
@pytest.mark.parametrize("axis", [0, 1])
def test_uniform_stretch(s, axis):
    """x = s u (or y = s v): every triangle has |w| = s along that axis, so E = area
    k_stretch (s - 1)^2 / 2. Interior points are in equilibrium; with x_p = s u_p, -dE/ds =
    sum_p f_p . u_p = width * (net x-force of the right column) (the left column has u = 0),
    so that net force is -k_stretch (s - 1) height: the membrane tension times the edge."""
    nw, nh, width, height = 9, 7, 1.3, 0.8
    ks = 200.0
    p = fem.build_fem(nw, nh, width, height, ks, 37.0, 0.5, 1.0)
    x = p.x_rest.copy()
    x[axis] *= s
    area = width * height
    assert fem.fem_energy(x, p) == pytest.approx(area * ks * (s - 1.0) ** 2 / 2.0, rel=1e-12)
    f = force(x, p).reshape(3, nh, nw)
    tol = 1e-12 * ks
    if axis == 0:
        edge, other, interior = f[:, :, -1], f[:, :, 0], f[:, :, 1:-1]
        length = height
    else:
        edge, other, interior = f[:, -1, :], f[:, 0, :], f[:, 1:-1, :]
        length = width
    assert edge[axis].sum() == pytest.approx(-ks * (s - 1.0) * length, rel=1e-12)
    assert other[axis].sum() == pytest.approx(ks * (s - 1.0) * length, rel=1e-12)
    assert np.abs(interior).max() < tol
    assert np.abs(f.sum(axis=(1, 2))).max() < tol  # no net force
    # the edge's tension is uniform: half-weight at its two corners (their tributary length)
    per_length = -ks * (s - 1.0) * length / (edge.shape[1] - 1)
    assert np.allclose(edge[axis, 1:-1], per_length, rtol=1e-12)
    assert np.allclose(edge[axis, [0, -1]], per_length / 2.0, rtol=1e-12)


@pytest.mark.parametrize("k", [(0.0, 70.0, 0.0), (150.0, 70.0, 0.2)])
@pytest.mark.parametrize("gamma", [0.2, -0.35])
def test_simple_shear(k, gamma):
    """x = u + gamma v: w_u = (1, 0, 0), w_v = (gamma, 1, 0), so per unit area the shear
    energy is k_shear gamma^2 / 2 and the stretch energy k_stretch (sqrt(1 + gamma^2) - 1)^2
    / 2 (the sheet stays flat: no bending)."""
    width, height = 1.3, 0.8
    p = fem.build_fem(9, 7, width, height, *k, 1.0)
    x = p.x_rest.copy()
    x[0] += gamma * x[1]
    ks, kh = k[0], k[1]
    expected = width * height / 2.0 * (ks * (math.sqrt(1.0 + gamma ** 2) - 1.0) ** 2
                                       + kh * gamma ** 2)
    assert fem.fem_energy(x, p) == pytest.approx(expected, rel=1e-12)


def test_symmetric_shear_energy():
    """F = [[1, g], [g, 1]] (pure shear): w_u . w_v = 2 g, |w_u| = |w_v| = sqrt(1 + g^2)."""
    width, height, g = 0.7, 1.1, 0.15
    p = fem.build_fem(6, 8, width, height, 90.0, 40.0, 0.0, 1.0)
    x = p.x_rest.copy()
    x[0], x[1] = p.x_rest[0] + g * p.x_rest[1], p.x_rest[1] + g * p.x_rest[0]
    expected = width * height / 2.0 * (2.0 * 90.0 * (math.sqrt(1.0 + g * g) - 1.0) ** 2
                                       + 40.0 * (2.0 * g) ** 2)
    assert fem.fem_energy(x, p) == pytest.approx(expected, rel=1e-12)


# --- 7. bending -------------------------------------------------------------------------------


def fold(p, axis, line, angle):
    """The rest sheet folded by `angle` along the grid line u = u[line] (axis 0: column
    index `line`) or v = v[line] (axis 1: row index): isometric, the membrane unstrained."""
    x = p.x_rest.copy()
    n = p.nw if axis == 0 else p.nh
    c = x[axis].max() * line / (n - 1)
    d = x[axis] - c
    beyond = d > 0.0
    x[axis] = np.where(beyond, c + d * math.cos(angle), x[axis])
    x[2] = np.where(beyond, d * math.sin(angle), 0.0)
    return x


@pytest.mark.parametrize("axis", [0, 1])
@pytest.mark.parametrize("angle", [math.pi / 2, math.pi])
def test_fold_along_grid_line_costs_no_membrane_energy(axis, angle):
    p = fem.build_fem(7, 6, 0.9, 1.2, 150.0, 60.0, 0.0, 1.0)
    x = fold(p, axis, 3, angle)
    assert fem.fem_energy(x, p) < 1e-24
    assert np.abs(force(x, p)).max() < 1e-12 * 150.0


@pytest.mark.parametrize("axis", [0, 1])
def test_right_angle_fold_bending_energy(axis):
    """A 90 degree fold along a grid line: only the hinges on that line bend, by pi / 2.
    Along a column the hinges are vertical edges (length dy, both triangles of area
    dx dy / 2), f = dy / (2 dx), and there are nh - 1 of them: E = k_bend (nh - 1) dy / (2 dx)
    (pi / 2)^2; likewise along a row."""
    nw, nh, width, height, kb = 7, 6, 0.9, 1.2, 0.4
    p = fem.build_fem(nw, nh, width, height, 150.0, 60.0, kb, 1.0)
    dx, dy = width / (nw - 1), height / (nh - 1)
    x = fold(p, axis, 3, math.pi / 2)
    if axis == 0:
        expected = kb * (nh - 1) * dy / (2.0 * dx) * (math.pi / 2) ** 2
    else:
        expected = kb * (nw - 1) * dx / (2.0 * dy) * (math.pi / 2) ** 2
    assert fem.fem_energy(x, p) == pytest.approx(expected, rel=1e-12)


def cylinder(p, axis, radius):
    """The rest sheet rolled (isometrically) onto a cylinder of `radius` whose axis runs
    along the other grid direction."""
    x = p.x_rest.copy()
    s = x[axis].copy()
    x[axis] = radius * np.sin(s / radius)
    x[2] = radius * (1.0 - np.cos(s / radius))
    return x


@pytest.mark.parametrize("axis", [0, 1])
def test_cylinder_bending_energy(axis):
    """Rolled along u, the points of a column lie on one ruling: each cell is planar, only
    the (n_u - 2) (n_v - 1) interior hinges between columns bend, each by theta = du / R,
    with f = dv / (2 du): E = k_bend (n_u - 2) (n_v - 1) dv du / (2 R^2) = (k_bend / (2 R^2))
    area (n_u - 2) / (n_u - 1). The continuum energy k_bend / (2 R^2) area is reached as the
    grid is refined; the missing strip is 1 / (n_u - 1) of it (3.4 % at 30 points, hence 5 %).
    """
    kb, radius, width, height = 0.2, 0.5, 1.3, 0.8
    continuum = kb / (2.0 * radius ** 2) * width * height
    for n, tol in ((10, None), (30, 0.05)):
        p = fem.build_fem(n, n + 3, width, height, 0.0, 0.0, kb, 1.0)
        n_u = p.nw if axis == 0 else p.nh
        e = fem.fem_energy(cylinder(p, axis, radius), p)
        assert e == pytest.approx(continuum * (n_u - 2) / (n_u - 1), rel=1e-9)
        if tol is not None:
            assert e == pytest.approx(continuum, rel=tol)


def test_atan2_matches_numpy():
    rng = np.random.default_rng(51)
    pts = [(0.0, 1.0), (0.0, -1.0), (1.0, 0.0), (-1.0, 0.0), (0.0, 0.0), (1.0, 1.0),
           (-1.0, -1.0), (2.0, 3.0), (1e-300, 1.0), (1.0, 1e-300)]
    scale = 10.0 ** rng.integers(-8, 8, (2000, 1))
    pts += [tuple(v) for v in rng.standard_normal((2000, 2)) * scale]
    for y, x in pts:
        expected = math.atan2(y, x)
        assert abs(fem._atan2(y, x) - expected) <= 4.0 * np.spacing(abs(expected)) + 1e-320


# --- 8. masses --------------------------------------------------------------------------------


@pytest.mark.parametrize("grid", GRIDS + TINY_GRIDS)
def test_lumped_masses(grid):
    nw, nh, width, height = grid
    density = 0.37
    p = fem.build_fem(nw, nh, width, height, 1.0, 1.0, 1.0, density)
    m = fem.lumped_masses(p)
    assert m.shape == (nw * nh,) and np.all(m > 0.0)
    assert m.sum() == pytest.approx(density * width * height, rel=1e-13)
    cell = width / (nw - 1) * height / (nh - 1)
    assert np.allclose(m.reshape(nh, nw)[1:-1, 1:-1], density * cell, rtol=1e-13)


# --- 9. highest frequency ---------------------------------------------------------------------


def test_estimate_omega_max():
    p = fem.build_fem(6, 5, 1.0, 0.8, 100.0, 50.0, 0.02, 2.0)
    m = fem.lumped_masses(p)
    # -K at rest by central differences of the force (the force is checked against the energy)
    n = p.x_rest.size
    k = np.zeros((n, n))
    h = 1e-6
    for c in range(n):
        y = np.zeros(n)
        y[c] = h
        y = y.reshape(p.x_rest.shape)
        k[:, c] = ((force(p.x_rest + y, p) - force(p.x_rest - y, p)) / (2.0 * h)).ravel()
    s = np.tile(1.0 / np.sqrt(m), 3)
    a = -(s[:, None] * k * s[None, :])
    omega = math.sqrt(np.linalg.eigvalsh(0.5 * (a + a.T)).max())
    estimate = fem.estimate_omega_max(p, m)
    assert estimate == pytest.approx(omega, rel=0.01)
    assert estimate <= omega * (1.0 + 1e-6)  # a Rayleigh quotient: from below


# --- 10. determinism --------------------------------------------------------------------------


@pytest.mark.skipif(numba.config.NUMBA_NUM_THREADS < 2, reason="needs 2 threads")
def test_bit_identical_across_thread_counts():
    p = fem.build_fem(23, 40, 0.9, 1.6, 120.0, 45.0, 0.35, 1.0)  # 39 cell rows: 16 bands
    x = deformed(p, "mixed", seed=61)
    y = np.random.default_rng(62).standard_normal(x.shape)
    before = numba.get_num_threads()
    results = []
    try:
        for threads in (1, 2, 1):
            numba.set_num_threads(threads)
            d = np.empty_like(x)
            fem.fem_jacobian_diagonal(x, p, d)
            results.append((force(x, p), product(fem.fem_jacobian_product, x, p, y),
                            product(fem.fem_filtered_jacobian_product, x, p, y), d))
    finally:
        numba.set_num_threads(before)
    for other in results[1:]:
        for a, b in zip(results[0], other):
            assert np.array_equal(a, b)
