"""Wind: aerodynamic drag and lift on every cloth triangle in a gusty air field (docs/wind.md).

Per triangle (area A, unit normal n, v_r = mean vertex velocity - air velocity, v_n = v_r . n,
v_t = v_r - v_n n):
    drag  F_D = -1/2 rho C_D A |v_n| v_n n
    lift  F_L = 1/2 rho C_L A |v_n| |v_t| l = -1/2 rho C_L A v_n (|v_r| n - (v_n / |v_r|) v_r)
with l the unit vector normal to v_r, in the plane of n and v_r, on the side of -sign(v_n) n;
each vertex gets a third. With c = (2nd - 1st) x (3rd - 1st) (|c| = 2A), S = the sum of the
three vertex relative velocities (= 3 v_r), s = S . c and y = 1 / (|c| |S|), a vertex gets
    (rho / 108) [-(s |S|^2 y) (C_D |s| y + C_L) c + C_L s^2 y S],
one reciprocal square root per triangle, zero (not NaN) when c or S vanishes.

The air velocity is the base wind plus GUST_MODES seeded plane waves advected with it
(frozen turbulence) whose phases also drift (evolving gusts), evaluated once per point; a
triangle takes the mean over its vertices.

The kernel is one parallel loop over bands of point rows. A band computes the positions and
relative velocities of its rows plus a halo row, the forces of the cells touching its rows,
then gathers them on its points: no other synchronisation, and halo work is recomputed bit
for bit, so the result does not depend on the banding. Per-point and per-triangle values are
float32 (twice the SIMD width; forces to ~1e-6 relative), positions taken relative to the
cloth's first point; the gust phases are computed, and the forces added to f, in float64.
"""
from __future__ import annotations

import math
from typing import NamedTuple

import numba
import numpy as np
from numba.core import types
from numba.np.unsafe.ndarray import to_fixed_tuple

from clothjit import KernelPointer, njit, prange

GUST_MODES = 8  # plane waves in the gust field
WAVE_MEAN_SQUARE = 8.0 / 15.0  # mean of wave(theta)^2 over a period
MIN_BAND_ROWS = 16  # rows per band at least (a band recomputes up to two halo rows)
_SEED_STREAM = 0x57494E44  # "WIND": the gusts' own random stream for a scene seed
_FAST = {"contract"}  # fused multiply-adds
_F0, _F1, _F2, _FHALF = np.float32(0.0), np.float32(1.0), np.float32(2.0), np.float32(0.5)


class WindParams(NamedTuple):
    """The wind packed for the kernels. `phase`, `point` and `tri` are scratch (one
    WindParams per simulation); the band count is point.shape[0]. Still air: `on` False,
    empty scratch and the band pointer absent, of the same numba type as a wind's (a scene
    with self-collision and no wind shares the stepping kernel of one with wind: see
    system.StepKernels)."""

    on: bool
    gusty: bool
    nw: int
    nh: int
    velocity: np.ndarray  # (3,) base wind U, m/s
    drag: float  # rho C_D / 108
    lift: float  # rho C_L / 108
    modes: np.ndarray  # (8, GUST_MODES) rows k_x, k_y, k_z (turns per metre), 8 a_x, 8 a_y,
    #                    8 a_z (m/s), phase at t = 0 (turns), its rate f - k . U (turns per s)
    phase: np.ndarray  # (GUST_MODES,) float32: phase now at the origin x[:, 0], in [0, 1)
    point: np.ndarray  # (bands, 6, (rows + 2) nw) float32: v - u, then x - x[:, 0]
    tri: np.ndarray  # (bands, 2, 3, (rows + 2) nw + 1) float32: per-vertex triangle forces
    band: KernelPointer | None = None  # _band for these params (pack_wind); None inside it


def pack_wind(wind, seed: int, nw: int, nh: int, bands: int = 0) -> WindParams:
    """The scene's `Wind` for an nw x nh cloth, gusts seeded by `seed`; still air (`on`
    False) without wind. `bands`: work items of the parallel loop (0: one per thread,
    MIN_BAND_ROWS rows at least)."""
    w = _still_air(nw, nh) if wind is None else _moving_air(wind, seed, nw, nh, bands)
    field = types.float64[:, ::1]  # positions, velocities and forces: (3, N)
    return w._replace(band=KernelPointer(_band, (field, field, w, field, np.int64(0)),
                                         present=w.on))


def _still_air(nw: int, nh: int) -> WindParams:
    """Params of no wind, of the same numba type as a wind's (empty scratch; pack_wind sets
    the band, absent)."""
    return WindParams(False, False, nw, nh, np.zeros(3), 0.0, 0.0,
                      np.zeros((8, GUST_MODES), order="F"),  # as _moving_air's vstack
                      np.zeros(GUST_MODES, np.float32), np.zeros((1, 6, 0), np.float32),
                      np.zeros((1, 2, 3, 0), np.float32))


def _moving_air(wind, seed: int, nw: int, nh: int, bands: int) -> WindParams:
    """Params of the scene's wind, its gusts seeded by `seed` (pack_wind sets the band)."""
    bands = bands or max(1, min(numba.config.NUMBA_NUM_THREADS, nh // MIN_BAND_ROWS))
    rows = -(-nh // bands)
    velocity = np.array(wind.velocity, dtype=np.float64)
    rng = np.random.default_rng((seed, _SEED_STREAM))
    wavevector = rng.standard_normal((GUST_MODES, 3)) / (2.0 * math.pi * wind.gust_scale)
    frequency = rng.standard_normal(GUST_MODES) / (2.0 * math.pi * wind.gust_time)
    phase0 = rng.random(GUST_MODES)
    amplitude = rng.standard_normal((GUST_MODES, 3))
    amplitude *= 8.0 * wind.gust / np.sqrt(WAVE_MEAN_SQUARE * (amplitude**2).sum(axis=0))
    modes = np.vstack([wavevector.T, amplitude.T, phase0, frequency - wavevector @ velocity])
    rho = wind.air_density
    return WindParams(
        True, wind.gust > 0.0, nw, nh, velocity, rho * wind.drag / 108.0,
        rho * wind.lift / 108.0, modes, np.zeros(GUST_MODES, np.float32),
        np.zeros((bands, 6, (rows + 2) * nw), np.float32),
        np.zeros((bands, 2, 3, (rows + 2) * nw + 1), np.float32))


def max_wind_speed(wind) -> float:
    """A bound on |air velocity| anywhere, any time: |U| + sqrt(3 M / (8/15)) gust, since
    |wave| <= 1 and sum_m |a_mc| <= sqrt(M sum_m a_mc^2) = sqrt(M / (8/15)) gust."""
    if wind is None:
        return 0.0
    return (float(np.linalg.norm(wind.velocity))
            + math.sqrt(3.0 * GUST_MODES / WAVE_MEAN_SQUARE) * wind.gust)


@njit(cache=True, nogil=True, no_cpython_wrapper=True)
def _set_phases(w, t, o0, o1, o2):
    """w.phase = the phases of the modes at time t at the origin o."""
    md = w.modes
    for k in range(GUST_MODES):
        phase = md[6, k] + md[7, k] * t + md[0, k] * o0 + md[1, k] * o1 + md[2, k] * o2
        w.phase[k] = phase - np.floor(phase)


@njit(cache=True, nogil=True, no_cpython_wrapper=True)
def _mode_tuples(w):
    """The modes as tuples: values, not memory, so the per-point loop over the (unrolled)
    modes needs no aliasing checks and vectorises."""
    md = w.modes
    return (to_fixed_tuple(w.phase, GUST_MODES), to_fixed_tuple(md[0], GUST_MODES),
            to_fixed_tuple(md[1], GUST_MODES), to_fixed_tuple(md[2], GUST_MODES),
            to_fixed_tuple(md[3], GUST_MODES), to_fixed_tuple(md[4], GUST_MODES),
            to_fixed_tuple(md[5], GUST_MODES))


@njit(cache=True, nogil=True, error_model="numpy", fastmath=_FAST, inline="always")
def _gust(px, py, pz, modes):
    """The gust velocity (float32) at the offset (px, py, pz) (float32) from the origin of
    the phases; `modes` from _mode_tuples."""
    phase, kx, ky, kz, ax, ay, az = modes
    gx = gy = gz = _F0
    for k in range(GUST_MODES):
        theta = (phase[k] + np.float32(kx[k]) * px + np.float32(ky[k]) * py
                 + np.float32(kz[k]) * pz)
        u = theta - np.floor(theta + _FHALF)
        s = u - _F2 * u * np.abs(u)  # wave(theta) / 8
        gx += np.float32(ax[k]) * s
        gy += np.float32(ay[k]) * s
        gz += np.float32(az[k]) * s
    return gx, gy, gz


@njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True)
def _positions(x, lo, hi, point):
    """point[3:6, :hi - lo] = x - x[:, 0] at the points [lo, hi), float32."""
    m = hi - lo
    for a in range(3):
        src, dst, oa = x[a, lo:hi], point[3 + a, :m], x[a, 0]
        for i in range(m):
            dst[i] = src[i] - oa


@njit(cache=True, nogil=True, error_model="numpy", fastmath=_FAST, no_cpython_wrapper=True)
def _relative(v, lo, hi, w, point):
    """point[0:3, :hi - lo] = v - air velocity at the points [lo, hi) (positions set)."""
    m = hi - lo
    vx, vy, vz = v[0, lo:hi], v[1, lo:hi], v[2, lo:hi]
    ox, oy, oz = point[0, :m], point[1, :m], point[2, :m]
    ux, uy, uz = w.velocity[0], w.velocity[1], w.velocity[2]
    if not w.gusty:
        for i in range(m):
            ox[i] = vx[i] - ux
            oy[i] = vy[i] - uy
            oz[i] = vz[i] - uz
        return
    px, py, pz = point[3, :m], point[4, :m], point[5, :m]
    modes = _mode_tuples(w)
    for i in range(m):  # all float32: twice the SIMD width of the loop below
        ox[i], oy[i], oz[i] = _gust(px[i], py[i], pz[i], modes)
    for i in range(m):
        ox[i] = np.float32(vx[i] - ux) - ox[i]
        oy[i] = np.float32(vy[i] - uy) - oy[i]
        oz[i] = np.float32(vz[i] - uz) - oz[i]


@njit(cache=True, nogil=True, error_model="numpy", fastmath=_FAST, inline="always")
def _triangle(ex, ey, ez, gx, gy, gz, sx, sy, sz, drag, lift):
    """Per-vertex force (float32) of a triangle with edges e, g from its first vertex
    (c = e x g) and summed relative velocity S."""
    cx, cy, cz = ey * gz - ez * gy, ez * gx - ex * gz, ex * gy - ey * gx
    s = sx * cx + sy * cy + sz * cz
    cc = cx * cx + cy * cy + cz * cz
    ss = sx * sx + sy * sy + sz * sz
    q = cc * ss
    y = _F1 / np.sqrt(q) if q > _F0 else _F0
    sy_ = s * y
    along_c = -(s * ss * y) * (drag * np.abs(sy_) + lift)
    along_s = lift * s * sy_
    return along_c * cx + along_s * sx, along_c * cy + along_s * sy, along_c * cz + along_s * sz


@njit(cache=True, nogil=True, error_model="numpy", fastmath=_FAST, no_cpython_wrapper=True)
def _triangles(point, i1, i2, i3, m, drag, lift, out, t0):
    """out[:, t0 + j] = per-vertex force of the triangle of points (i1 + j, i2 + j, i3 + j),
    j < m, indices into the band's `point` rows."""
    ax_, ay_, az_ = point[3, i1:i1 + m], point[4, i1:i1 + m], point[5, i1:i1 + m]
    bx_, by_, bz_ = point[3, i2:i2 + m], point[4, i2:i2 + m], point[5, i2:i2 + m]
    cx_, cy_, cz_ = point[3, i3:i3 + m], point[4, i3:i3 + m], point[5, i3:i3 + m]
    wax, way, waz = point[0, i1:i1 + m], point[1, i1:i1 + m], point[2, i1:i1 + m]
    wbx, wby, wbz = point[0, i2:i2 + m], point[1, i2:i2 + m], point[2, i2:i2 + m]
    wcx, wcy, wcz = point[0, i3:i3 + m], point[1, i3:i3 + m], point[2, i3:i3 + m]
    fx, fy, fz = out[0, t0:t0 + m], out[1, t0:t0 + m], out[2, t0:t0 + m]
    for j in range(m):
        fx[j], fy[j], fz[j] = _triangle(
            bx_[j] - ax_[j], by_[j] - ay_[j], bz_[j] - az_[j],
            cx_[j] - ax_[j], cy_[j] - ay_[j], cz_[j] - az_[j],
            wax[j] + wbx[j] + wcx[j], way[j] + wby[j] + wcy[j], waz[j] + wbz[j] + wcz[j],
            drag, lift)


@njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True)
def _gather(tri, f, lo, hi, t0, nw):
    """f[:, lo:hi] += the forces of the (up to six) triangles at each point; the cell with
    corner A = p is at tri[:, :, p - lo + t0] (zero where there is no cell)."""
    m = hi - lo
    u = t0 - nw
    for a in range(3):
        out = f[a, lo:hi]
        below, below_l = tri[0, a, t0:t0 + m], tri[0, a, t0 - 1:t0 - 1 + m]
        below_l1 = tri[1, a, t0 - 1:t0 - 1 + m]
        above, above1 = tri[0, a, u:u + m], tri[1, a, u:u + m]
        above1_l = tri[1, a, u - 1:u - 1 + m]
        for j in range(m):
            out[j] += below[j] + below_l[j] + below_l1[j] + above[j] + above1[j] + above1_l[j]


@njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True, pointer=True)
def _band(x, v, w, f, band):
    """The wind forces on the point rows of one band."""
    nw, nh, bands = w.nw, w.nh, w.point.shape[0]
    r0, r1 = band * nh // bands, (band + 1) * nh // bands
    if r0 == r1:
        return
    a0, a1 = max(r0 - 1, 0), min(r1 + 1, nh)  # rows whose points are needed
    c1 = min(r1, nh - 1)  # the cells of rows [a0, c1) touch the band's points
    lo, hi = a0 * nw, a1 * nw
    point, tri = w.point[band], w.tri[band]
    _positions(x, lo, hi, point)
    _relative(v, lo, hi, w, point)
    t0 = nw + 1  # cell with corner A = p at tri[:, :, p - lo + t0], after nw + 1 zeros
    m = (c1 - a0) * nw - 1  # the last column's cells wrap around: zeroed below
    if m > 0:
        drag, lift = np.float32(w.drag), np.float32(w.lift)
        zero, one = np.int64(0), np.int64(1)  # not literals: one compile of _triangles
        _triangles(point, zero, nw, one, m, drag, lift, tri[0], t0)  # (A, C, B)
        _triangles(point, one, nw, nw + one, m, drag, lift, tri[1], t0)  # (B, C, D)
        for t in range(t0 + nw - 1, t0 + m, nw):
            for a in range(3):
                tri[0, a, t] = 0.0
                tri[1, a, t] = 0.0
    _gather(tri, f, r0 * nw, r1 * nw, t0 + (r0 - a0) * nw, nw)


@njit(cache=True, nogil=True, parallel=True, no_cpython_wrapper=True)
def _all_bands(x, v, band, w, f):
    for b in prange(w.point.shape[0]):
        band(x, v, w, f, np.int64(b))


@njit(cache=True, nogil=True, pointer=True)
def add_wind_force(x, v, t, w, f):
    """f += the aerodynamic force at positions x, velocities v (3, N), time t (s), for a
    wind that is `on`. The stepping kernels call it through System.kernels.wind, and it
    calls _band through w.band (clothjit.KernelPointer): linked in, numba optimised their
    code again in every stepping kernel (and _band's in the parallel loop, four times).
    Still air (`on` False: its band pointer is absent) adds nothing."""
    if not w.on:
        return
    _set_phases(w, t, x[0, 0], x[1, 0], x[2, 0])
    band, bands = w.band, WindParams(*w[:-1], None)  # _band takes the params without it
    if w.point.shape[0] == 1:
        band(x, v, bands, f, np.int64(0))  # no thread launch for a single band
    else:
        _all_bands(x, v, band, bands, f)


@njit(cache=True, nogil=True)
def _air_points(w, x, t, out):
    ux, uy, uz = w.velocity[0], w.velocity[1], w.velocity[2]
    _set_phases(w, t, x[0, 0], x[1, 0], x[2, 0])
    modes = _mode_tuples(w)
    for p in range(x.shape[1]):
        gx = gy = gz = _F0
        if w.gusty:
            gx, gy, gz = _gust(np.float32(x[0, p] - x[0, 0]), np.float32(x[1, p] - x[1, 0]),
                               np.float32(x[2, p] - x[2, 0]), modes)
        out[0, p], out[1, p], out[2, p] = ux + gx, uy + gy, uz + gz


def air_velocity(w: WindParams, points: np.ndarray, t: float) -> np.ndarray:
    """The air velocity u(x, t), (M, 3), at points (M, 3). The gusts are evaluated as the
    kernel does for a cloth whose first point is points[0] (bit for bit then)."""
    x = np.ascontiguousarray(np.asarray(points, dtype=np.float64).reshape(-1, 3).T)
    out = np.empty_like(x)
    _air_points(w, x, float(t), out)
    return out.T.copy()
