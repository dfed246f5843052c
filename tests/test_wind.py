"""Wind forces (pipeline/physics/wind.py, docs/wind.md): the per-triangle drag and lift law against a
direct evaluation of the formula, the equal split over vertices, the gust field's statistics,
determinism and frozen-turbulence advection, and the closed-form velocity of a sheet
accelerated by a steady wind."""
from __future__ import annotations

import math

import numpy as np
import pytest

from pipeline.scene import Wind
from pipeline.physics.wind import GUST_MODES, add_wind_force, air_velocity, max_wind_speed, pack_wind

RTOL = 2e-6  # the kernel works in float32 per point and per triangle


def cloth_triangles(nw: int, nh: int) -> np.ndarray:
    """The renderer's triangulation (shading/mesh.py cloth_topology): (A, C, B), (B, C, D)."""
    i, j = np.meshgrid(np.arange(nh - 1), np.arange(nw - 1), indexing="ij")
    a = (i * nw + j).ravel()
    tris = np.empty((2 * a.size, 3), dtype=np.int64)
    tris[0::2] = np.stack([a, a + nw, a + 1], axis=1)
    tris[1::2] = np.stack([a + 1, a + nw, a + nw + 1], axis=1)
    return tris


def triangle_force(p: np.ndarray, v_r: np.ndarray, wind: Wind) -> np.ndarray:
    """The force law of docs/wind.md on one triangle p (3, 3) with relative velocity v_r,
    written the long way: area, unit normal, normal and tangential parts, lift direction."""
    c = np.cross(p[1] - p[0], p[2] - p[0])
    area = np.linalg.norm(c) / 2.0
    if area == 0.0:
        return np.zeros(3)
    n = c / np.linalg.norm(c)
    v_n = v_r @ n
    v_t = v_r - v_n * n
    force = -0.5 * wind.air_density * wind.drag * area * abs(v_n) * v_n * n
    if v_n != 0.0 and np.linalg.norm(v_t) > 0.0:
        side = -np.sign(v_n) * n
        lift_dir = side - (side @ v_r) / (v_r @ v_r) * v_r
        lift_dir /= np.linalg.norm(lift_dir)
        force += (0.5 * wind.air_density * wind.lift * area * abs(v_n) * np.linalg.norm(v_t)
                  * lift_dir)
    return force


def reference(x: np.ndarray, v: np.ndarray, t: float, wind: Wind, seed: int, nw: int,
              nh: int) -> tuple[np.ndarray, np.ndarray]:
    """(per-point forces (N, 3), per-triangle forces (T, 3)) from triangle_force, with the
    air velocity of air_velocity averaged over each triangle's vertices."""
    u = air_velocity(pack_wind(wind, seed, nw, nh), x, t)
    f = np.zeros_like(x)
    per_triangle = []
    for tri in cloth_triangles(nw, nh):
        force = triangle_force(x[tri], v[tri].mean(axis=0) - u[tri].mean(axis=0), wind)
        f[tri] += force / 3.0
        per_triangle.append(force)
    return f, np.array(per_triangle)


def kernel(x: np.ndarray, v: np.ndarray, t: float, wind: Wind | None, seed: int, nw: int,
           nh: int, bands: int = 0) -> np.ndarray:
    """add_wind_force on (N, 3) points, returned as (N, 3)."""
    f = np.zeros((3, nw * nh))
    add_wind_force(np.ascontiguousarray(x.T), np.ascontiguousarray(v.T), t,
                   pack_wind(wind, seed, nw, nh, bands), f)
    return f.T


def rotation(rng: np.random.Generator) -> np.ndarray:
    q, r = np.linalg.qr(rng.standard_normal((3, 3)))
    return q * np.sign(np.diag(r))


def sheet(nw: int, nh: int, size: float = 1.0) -> np.ndarray:
    """A flat square sheet in the y = 1 plane, (N, 3) row-major."""
    i, j = np.meshgrid(np.arange(nh), np.arange(nw), indexing="ij")
    return np.stack([j.ravel() * size / (nw - 1), np.ones(nw * nh),
                     i.ravel() * size / (nh - 1)], axis=1)


@pytest.mark.parametrize("case", range(6))
def test_single_triangle_matches_the_formula(case):
    """A 2 x 2 cloth whose second triangle (B, C, D) is degenerate (D = B): the first one's
    force, split in thirds over A, C, B, in several orientations and flows."""
    rng = np.random.default_rng(case)
    a, b, c = rng.standard_normal((3, 3))
    x = np.array([a, b, c, b]) @ rotation(rng).T + rng.standard_normal(3)
    v = rng.standard_normal((4, 3)) * 3.0
    wind = Wind(velocity=tuple(rng.standard_normal(3) * 2.0), air_density=1.1, drag=1.3,
                lift=0.7)
    expected = triangle_force(x[[0, 2, 1]], v[[0, 2, 1]].mean(axis=0) - wind.velocity, wind)
    f = kernel(x, v, 0.0, wind, 0, 2, 2)
    np.testing.assert_allclose(f[:3], np.tile(expected / 3.0, (3, 1)), rtol=RTOL,
                               atol=RTOL * np.abs(expected).max())
    np.testing.assert_array_equal(f[3], 0.0)


@pytest.mark.parametrize("gust", [0.0, 1.5])
def test_every_point_matches_the_per_triangle_sum(gust):
    """A crumpled 7 x 6 cloth in a gusty wind: each point gets a third of each of its
    (up to six) triangles; the total is the sum over triangles (momentum)."""
    rng = np.random.default_rng(3)
    nw, nh = 7, 6
    x = sheet(nw, nh) + 0.05 * rng.standard_normal((nw * nh, 3))
    v = rng.standard_normal((nw * nh, 3))
    wind = Wind(velocity=(3.0, 0.5, 1.0), drag=1.1, lift=0.6, gust=gust, gust_scale=0.3)
    expected, per_triangle = reference(x, v, 0.37, wind, 4, nw, nh)
    f = kernel(x, v, 0.37, wind, 4, nw, nh)
    scale = np.abs(expected).max()
    np.testing.assert_allclose(f, expected, rtol=RTOL, atol=RTOL * scale)
    np.testing.assert_allclose(f.sum(axis=0), per_triangle.sum(axis=0), rtol=1e-5,
                               atol=1e-5 * scale)


def test_banding_does_not_change_a_bit():
    """The parallel bands recompute their halo rows bit for bit."""
    rng = np.random.default_rng(8)
    nw, nh = 9, 40
    x = sheet(nw, nh) + 0.02 * rng.standard_normal((nw * nh, 3))
    v = rng.standard_normal((nw * nh, 3))
    wind = Wind(velocity=(1.0, 0.0, 2.0), gust=1.0, gust_scale=0.2)
    one = kernel(x, v, 1.3, wind, 2, nw, nh, bands=1)
    for bands in (2, 3, 7):
        np.testing.assert_array_equal(kernel(x, v, 1.3, wind, 2, nw, nh, bands=bands), one)


def test_no_relative_velocity_no_force():
    rng = np.random.default_rng(1)
    x = sheet(5, 4) + 0.1 * rng.standard_normal((20, 3))
    steady = Wind(velocity=(1.0, -2.0, 0.5))
    v = np.tile(steady.velocity, (20, 1))
    np.testing.assert_array_equal(kernel(x, v, 0.0, steady, 0, 5, 4), 0.0)
    gusty = Wind(velocity=(1.0, -2.0, 0.5), gust=2.0)
    v = air_velocity(pack_wind(gusty, 0, 5, 4), x, 0.8)  # the cloth moves with the air
    assert np.abs(kernel(x, v, 0.8, gusty, 0, 5, 4)).max() < 1e-12


def test_degenerate_cloth_or_tiny_flow_gives_zero_not_nan():
    x = np.zeros((9, 3))
    v = np.ones((9, 3))
    np.testing.assert_array_equal(kernel(x, v, 0.0, Wind(velocity=(1.0, 2.0, 3.0)), 0, 3, 3),
                                  0.0)
    x = sheet(3, 3, 1e-3)
    for speed in (1e-30, 1e-20, 1e-17):  # |c|^2 |S|^2 underflows (to subnormal) in float32
        f = kernel(x, np.tile([0.0, speed, speed], (9, 1)), 0.0, Wind(), 0, 3, 3)
        assert np.all(np.isfinite(f)) and np.abs(f).max() < 1e-30


def test_flat_sheet_moving_along_its_normal_gets_pure_drag():
    """Total force -1/2 rho C_D A |v| v n, no sideways (lift) component."""
    nw = nh = 6
    size = 0.8
    wind = Wind(air_density=1.2, drag=1.4, lift=0.9)
    for speed in (-3.0, 0.5):  # falling, rising
        v = np.tile([0.0, speed, 0.0], (nw * nh, 1))
        total = kernel(sheet(nw, nh, size), v, 0.0, wind, 0, nw, nh).sum(axis=0)
        drag = -0.5 * wind.air_density * wind.drag * size**2 * abs(speed) * speed
        np.testing.assert_allclose(total, [0.0, drag, 0.0], rtol=RTOL, atol=RTOL * abs(drag))


@pytest.mark.parametrize("degrees", [0.0, 15.0, 45.0, 70.0, 90.0])
def test_lift_is_perpendicular_to_the_flow(degrees):
    """A tilted flat sheet in a steady wind: the force minus the drag along n is
    perpendicular to v_r, of size 1/2 rho C_L A |v_n| |v_t| (zero at 0 and 90 degrees), on
    the side of -sign(v_n) n."""
    nw = nh = 5
    size, speed = 0.6, 4.0
    wind_dir = np.array([math.cos(math.radians(degrees)), -math.sin(math.radians(degrees)), 0.0])
    wind = Wind(velocity=tuple(speed * wind_dir), drag=1.0, lift=0.8)
    total = kernel(sheet(nw, nh, size), np.zeros((nw * nh, 3)), 0.0, wind, 0, nw, nh).sum(axis=0)
    n = np.array([0.0, 1.0, 0.0])
    v_r = -speed * wind_dir
    v_n = v_r @ n
    area = size**2
    lift = total - (-0.5 * wind.air_density * wind.drag * area * abs(v_n) * v_n * n)
    expected_size = 0.5 * wind.air_density * wind.lift * area * abs(v_n) * np.linalg.norm(
        v_r - v_n * n)
    scale = 0.5 * wind.air_density * area * speed**2
    assert abs(lift @ v_r) <= 1e-5 * scale * speed
    assert np.linalg.norm(lift) == pytest.approx(expected_size, abs=1e-5 * scale)
    if degrees in (0.0, 90.0):
        assert np.linalg.norm(lift) <= 1e-5 * scale
    else:
        assert lift @ (-np.sign(v_n) * n) > 0.0


def test_disabled_wind_adds_nothing():
    f = np.full((3, 12), 7.0)
    add_wind_force(np.zeros((3, 12)), np.ones((3, 12)), 0.0, pack_wind(None, 0, 4, 3), f)
    np.testing.assert_array_equal(f, 7.0)
    assert max_wind_speed(None) == 0.0


def test_gusts_are_deterministic_per_seed():
    rng = np.random.default_rng(0)
    points = rng.uniform(-3.0, 3.0, (200, 3))
    wind = Wind(velocity=(1.0, 0.0, 0.0), gust=1.0)
    a = air_velocity(pack_wind(wind, 11, 4, 4), points, 2.5)
    np.testing.assert_array_equal(air_velocity(pack_wind(wind, 11, 4, 4), points, 2.5), a)
    assert np.abs(air_velocity(pack_wind(wind, 12, 4, 4), points, 2.5) - a).max() > 0.1
    v = rng.standard_normal((16, 3))
    x = sheet(4, 4)
    np.testing.assert_array_equal(kernel(x, v, 2.5, wind, 11, 4, 4),
                                  kernel(x, v, 2.5, wind, 11, 4, 4))


WINDY = Wind(velocity=(2.0, 0.0, 1.0), gust=1.5, gust_scale=0.4, gust_time=0.7)


def gusts(wind: Wind, seed: int, points: np.ndarray, t: float) -> np.ndarray:
    return air_velocity(pack_wind(wind, seed, 4, 4), points, t) - np.array(wind.velocity)


def test_gust_statistics():
    """Mean zero and rms `gust` per component over a large region, bounded by
    max_wind_speed."""
    rng = np.random.default_rng(5)
    for seed in range(3):
        g = gusts(WINDY, seed, rng.uniform(-40.0, 40.0, (20000, 3)), rng.uniform(0.0, 100.0))
        assert np.abs(g.mean(axis=0)).max() < 0.05 * WINDY.gust
        np.testing.assert_allclose(np.sqrt((g**2).mean(axis=0)), WINDY.gust, rtol=0.03)
        assert np.linalg.norm(g + WINDY.velocity, axis=1).max() <= max_wind_speed(WINDY)


def correlation(a: np.ndarray, b: np.ndarray) -> float:
    return float((a * b).mean() / np.sqrt((a * a).mean() * (b * b).mean()))


def test_gusts_are_correlated_over_gust_scale_and_gust_time():
    """Averaged over seeds: the correlation at distance r is close to exp(-r^2 / (2 l^2))
    (l = gust_scale), and at lag dt in the frame moving with the wind to
    exp(-dt^2 / (2 T^2)) (T = gust_time)."""
    rng = np.random.default_rng(6)
    l, T, u = WINDY.gust_scale, WINDY.gust_time, np.array(WINDY.velocity)

    def mean_corr(shift_x, dt):
        values = []
        for seed in range(20):
            p = rng.uniform(-20.0, 20.0, (1000, 3))
            d = rng.standard_normal((1000, 3))
            d /= np.linalg.norm(d, axis=1, keepdims=True)
            values.append(correlation(gusts(WINDY, seed, p, 1.0),
                                      gusts(WINDY, seed, p + shift_x * d + u * dt, 1.0 + dt)))
        return np.mean(values)

    assert mean_corr(0.1 * l, 0.0) > 0.97  # smooth
    assert 0.45 < mean_corr(l, 0.0) < 0.8  # exp(-1/2) = 0.61
    assert abs(mean_corr(4.0 * l, 0.0)) < 0.15
    assert mean_corr(0.0, 0.1 * T) > 0.97
    assert 0.4 < mean_corr(0.0, T) < 0.8
    assert abs(mean_corr(0.0, 4.0 * T)) < 0.2


def test_frozen_gusts_are_carried_by_the_wind():
    """With a very long gust_time the field only moves with the base wind:
    u(x + U dt, t + dt) = u(x, t)."""
    frozen = Wind(velocity=(3.0, -1.0, 2.0), gust=1.0, gust_scale=0.5, gust_time=1e9)
    rng = np.random.default_rng(7)
    p = rng.uniform(-2.0, 2.0, (500, 3))
    w = pack_wind(frozen, 3, 4, 4)
    before = air_velocity(w, p, 10.0)
    for dt in (0.01, 0.5, 3.0):
        after = air_velocity(w, p + dt * np.array(frozen.velocity), 10.0 + dt)
        np.testing.assert_allclose(after, before, atol=2e-5 * frozen.gust)
    assert np.abs(air_velocity(w, p, 10.5) - before).max() > 0.1  # but it does move


def test_sheet_pushed_by_a_steady_wind_follows_the_closed_form():
    """A free rigid flat sheet facing a wind U (no gravity, no damping), from rest:
    v(t) = U - 1 / (1/U + k t) with k = rho C_D A / (2 M). Integrated with RK4 on
    add_wind_force; all points move together."""
    nw = nh = 4
    size, mass, speed = 0.5, 0.05, 5.0
    wind = Wind(velocity=(0.0, speed, 0.0), air_density=1.2, drag=1.1, lift=0.5)
    w = pack_wind(wind, 0, nw, nh)
    x = np.ascontiguousarray(sheet(nw, nh, size).T)
    f = np.zeros_like(x)

    def accel(vy):
        f[:] = 0.0
        v = np.zeros_like(x)
        v[1] = vy
        add_wind_force(x, v, 0.0, w, f)
        assert np.abs(f[[0, 2]]).max() <= 1e-6 * np.abs(f[1]).max()  # no sideways force
        return f[1].sum() / mass

    k = wind.air_density * wind.drag * size**2 / (2.0 * mass)
    dt, vy = 0.002, 0.0
    for step in range(1, 501):
        k1 = accel(vy)
        k2 = accel(vy + 0.5 * dt * k1)
        k3 = accel(vy + 0.5 * dt * k2)
        k4 = accel(vy + dt * k3)
        vy += dt * (k1 + 2.0 * k2 + 2.0 * k3 + k4) / 6.0
        if step % 100 == 0:
            exact = speed - 1.0 / (1.0 / speed + k * step * dt)
            assert vy == pytest.approx(exact, rel=1e-5)


def test_max_wind_speed_bounds_the_modes():
    wind = Wind(velocity=(3.0, 4.0, 0.0), gust=2.0)
    assert max_wind_speed(wind) == pytest.approx(5.0 + 2.0 * math.sqrt(3 * GUST_MODES * 15 / 8))
    assert max_wind_speed(Wind(velocity=(3.0, 4.0, 0.0))) == 5.0
