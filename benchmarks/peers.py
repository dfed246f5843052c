"""Our simulator beside NVIDIA Warp and Taichi on the course scene pinned2, in one run.

    python benchmarks/peers.py                          # grids 50, 100, 200; 3 rounds
    python benchmarks/peers.py --sizes 50,100 --rounds 5 --threads 1
    python benchmarks/peers.py --peers taichi,warp,taichi-colored --precision f32
    python benchmarks/peers.py --vbd --threads 1 --rounds 4   # VBD against NVIDIA Newton

Flags: --sizes (grids), --rounds (>= 3), --threads (numba threads for ours, Taichi's
cpu_max_num_threads; Warp's CPU launches use one thread), --peers (taichi, warp,
taichi-colored; under --vbd newton, newton-no-self-contact), --precision (the peers' f64,
the default, or f32), --venv and --peer-python (where the peers' environment is made, and by
which Python), --vbd and --frames (the VBD case below, frames a round, default 60).

The VBD case (--vbd, issue 44): NVIDIA Newton's cloth_hanging example (HANGING below: 65 x
33 points, 0.1 m cells, the left edge pinned, 10 substeps x 10 iterations per 1/60 s frame)
run by Newton's own SolverVBD (newton 1.8.0 from PyPI with warp-lang 1.19.0, in the same
venv; on the CPU, float32, one thread), with its self-contact on as the example has it
(`newton`) and off (`newton-no-self-contact`), against the same scene rebuilt as our FEM
cloth under `"integrator": "vbd"` (hanging_scene says how each number maps, and what does
not), without self-collision (`ours`), with the course's self-collision
(`ours+self-collision`) and with the robust contact (`ours+robust`). Every run is --frames
frames from the start, warm (its untimed first run includes Newton's compile, ~35-90 s on
a cold Warp cache), alternately, --rounds rounds; printed: frames per second (median, best
round), where each cloth is (its lowest point above the ground, its largest distance to
Newton's), and ours / Newton's frame rate for every pair. The two are different models
(Newton's membrane is Stable Neo-Hookean with strain-rate damping, its contact a penalty
inside the descent), so the distances say how alike the motion is, not an error.

The case: scenes/pinned2.json (a cloth pinned at two corners; structural, shearing and
bending springs; Verlet with damping; Provot's stretch limit at 10 %) rescaled to each grid
the way benchmarks/sim.py does (num_width_points = num_height_points = size, the pins moved
to the same corners), one simulated second each: frames_per_sec 90 x steps_per_frame 30 =
2700 steps.

- ours: the project's public API (`pipeline.Simulation(scene).advance(90)`) in this process,
  on `--threads` numba threads, float64, the SPEC's exact model.
- taichi, warp: the same model written in each library (the part of this file headed "the
  model" says how), run by workers in a virtual environment of their own, made on first use
  with `python -m venv` and pip under ~/.cache/clothpipe-peers/venv, so that the project's
  environment is never touched. A peer that cannot be installed or started is reported as
  `skipped: <reason>` and the rest goes on.
- taichi-colored (not run by default): Taichi with Provot's springs in parallel groups of one
  direction and colour, an order other than the SPEC's.

Every timed run is warm: ours and each worker first make one untimed run of the same
simulated second (its wall time, compile included, is the column `warm-up s`), and each
worker stays alive for its case's rounds. Each round runs ours, then each peer in turn, so
that load from other work on the machine falls on all of them alike.

What it prints: the versions, thread counts and precisions used; then per grid and
simulator the median and the min over the rounds of the seconds per simulated second, the
steps per second (from the median), the warm-up seconds and the largest distance between its
final positions and ours. Those distances check that a peer runs the same model; the
untimed runs also give them after frames 1, 10, 20, ..., 90 (a different model parts from
ours within the first frames; round-off parts at ~1e-16 m and grows, at times by orders of
magnitude at once where the cloth can fold one way or the other). Float64 peers agree to
round-off (1e-10 m or less for the first 40 frames; at the end 2e-13 m at 50x50, 2e-8 m
at 100x100, 1.2e-3 m at 200x200, where one such fold near frame 45 took it from 1e-10 m to
5e-3 m). Flagged: above 1e-9 m at frame 10, or above 1e-3 m at the end. Float32 peers part
from the first frame, 1e-5 m after one, 1 mm after ten, up to 2 cm mid-run, 7-11 mm at the
end, Taichi and Warp alike: a step's gravity increment, 1.3e-6 m, is only ~10 units in
float32's last place at 1 m, so x' = x + (x - x_last) + a dt^2 rounds it off step after step
(flagged above 5e-3 m at frame 10 or 2e-2 m at the end). Float32 was at most ~10 % faster
here, hence float64 by default. Then per grid the ratio best peer / ours of the medians and
of the mins (the project's target: >= 2, ours at least twice as fast as the best peer). With
taichi-colored, it also runs the C++ reference (../shared/reference/cs184_ref) in the same
coloured order and prints its distance to ours and to the peer: the peer's distance to ours
is the order's, not an error.

On a machine shared with other busy processes, numba's parallel kernels (--threads 2 on two
cores) can slow down several times over, much more than Taichi's; compare --threads 1.
"""
# No `from __future__ import annotations`: Taichi and Warp read the kernels' annotations.
import argparse
import itertools
import json
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
import traceback
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np  # the only import outside the standard library: the workers need it too

from sim import scene_dict  # benchmarks/sim.py (standard library only at import)

ROOT = Path(__file__).resolve().parent.parent
SCENE = ROOT / "scenes" / "pinned2.json"
REFERENCE = ROOT.parent / "shared" / "reference" / "cs184_ref"
DEFAULT_VENV = Path.home() / ".cache" / "clothpipe-peers" / "venv"
# versions checked on this project's machine (Python 3.11, x86-64): both have wheels there
PACKAGES = {"taichi": "taichi==1.7.4", "warp": "warp-lang==1.19.0",
            "taichi-colored": "taichi==1.7.4", "newton": "newton==1.8.0",
            "newton-no-self-contact": "newton==1.8.0"}
# installed with the package, so that pip keeps the venv's Warp (newton asks warp-lang>=1.17)
WITH = {"newton==1.8.0": ["warp-lang==1.19.0"]}
NEWTON_PEERS = ("newton", "newton-no-self-contact")  # --vbd's peers
PINNED2_PEERS = ("taichi", "warp", "taichi-colored")  # the pinned2 case's
PEERS = (*PINNED2_PEERS, *NEWTON_PEERS)
# the largest distance to ours, after a simulated second, of a peer that runs the same model
AGREEMENT = {"f64": 1e-3, "f32": 2e-2}  # m; float32: see the module docstring
# the largest distance to ours after 10 frames (1/9 s) of a peer that runs the same model
EARLY_AGREEMENT = {"f64": 1e-9, "f32": 5e-3}
IMPORT_RETRIES, IMPORT_WAIT = 3, 60.0  # the package's modules may be moving (see load_ours)

# =================================================================================== the model
# Runs in the peers' venv (taichi, warp-lang, numpy): nothing from the project.
#
# What both peers compute is SPEC section 2 as the reference cs184_ref does: springs in SPEC
# order (points row-major; per point structural-left, structural-above, shearing-upper-left,
# shearing-upper-right, bending-two-left, bending-two-above), rest length = initial distance;
# per step (1) gravity + Hooke (k = ks, bending 0.2 ks), (2) Verlet
# x' = x + (1 - damping/100)(x - x_last) + F/m dt^2 with pins fixed, (5) Provot: a spring
# longer than 1.1 rest is shortened to 1.1 rest, half to each end, all to the free end if one
# is pinned, nothing if both are. No colliders, no self-collision (pinned2 has none).
#
# How (as a user of each library would write it for speed on a CPU):
# - forces and Verlet are one parallel loop over the grid points: each point gathers the force
#   of its (up to 12) incident springs from the grid stencil, so no atomics and a sum in a
#   fixed order. (Tried in Taichi on this machine, under load: a loop over springs with
#   atomic adds was 2-6x slower, a loop over springs into a buffer followed by a gather
#   1.5-2x slower.) The new positions go to the second slot of a (2, N) buffer, the slot of
#   x_last, which only the same point reads; the slots swap every step.
# - taichi: Provot is the SPEC's Gauss-Seidel walk of the spring list in order, a serialised
#   loop (`ti.loop_config(serialize=True)`) in the same kernel as the points' loop: one
#   kernel launch per step.
# - taichi-colored: Provot walks the springs grouped by direction (6) and colour (2), SPEC order
#   inside a group; a group's springs share no point, so each group is one parallel loop.
#   This is the reference's `provot_order colored`: a valid order, but not the SPEC's, and
#   the cloth ends millimetres to centimetres away from the SPEC's after a simulated second.
# - warp: Warp runs a CPU launch on one thread, so a parallel Provot would buy nothing there:
#   Provot is the Gauss-Seidel walk in one launch of dim 1. The two launches of a step are
#   recorded once per buffer slot (`record_cmd=True`) and replayed: on a CPU that stands in
#   for a CUDA graph and cuts Python's cost per launch.

# (di, dj) from a spring's first point to its second, in SPEC order; 0-1 structural,
# 2-3 shearing, 4-5 bending
OFFSETS = ((0, -1), (-1, 0), (-1, -1), (-1, 1), (0, -2), (-2, 0))
STRETCH_LIMIT = 1.1


class Model:
    """The cloth as float64 arrays (each peer casts them to its precision)."""

    def __init__(self, spec: dict, init: np.ndarray) -> None:
        self.nw, self.nh = int(spec["nw"]), int(spec["nh"])
        self.n = self.nw * self.nh
        self.x0 = np.ascontiguousarray(init, dtype=np.float64).reshape(self.n, 3)
        self.pinned = np.zeros(self.n, dtype=np.int32)
        for x, y in spec["pinned"]:
            self.pinned[y * self.nw + x] = 1
        self.mass = spec["width"] * spec["height"] * spec["density"] / self.n
        self.dt = 1.0 / spec["frames_per_sec"] / spec["steps_per_frame"]
        self.dt2 = self.dt * self.dt
        self.keep = 1.0 - spec["damping"] / 100.0
        self.gravity = np.asarray(spec["gravity"], dtype=np.float64)
        self.steps_per_frame = int(spec["steps_per_frame"])
        structural, shearing, bending = spec["enable"]
        ks = spec["ks"]
        # stiffness per direction, 0 for a disabled type (its springs still take part in Provot)
        self.k = np.array([ks * structural] * 2 + [ks * shearing] * 2 + [0.2 * ks * bending] * 2,
                          dtype=np.float64)
        self._springs()

    def _springs(self) -> None:
        """rest (6, N): rest length of spring (d, p) from point p (0 where there is none);
        a, b, direction, limit, colour: the spring list in SPEC order."""
        i, j = np.divmod(np.arange(self.n), self.nw)
        exists = np.zeros((self.n, 6), dtype=bool)
        other = np.zeros((self.n, 6), dtype=np.int64)
        for d, (di, dj) in enumerate(OFFSETS):
            exists[:, d] = (i + di >= 0) & (j + dj >= 0) & (j + dj < self.nw)
            other[:, d] = (i + di) * self.nw + (j + dj)
        p, d = np.nonzero(exists)  # C order: point-major, direction-minor, i.e. SPEC order
        self.a, self.b, self.direction = p, other[p, d], d
        rest = np.linalg.norm(self.x0[self.b] - self.x0[self.a], axis=1)
        self.rest = np.zeros((6, self.n))
        self.rest[d, p] = rest
        self.limit = STRETCH_LIMIT * rest
        ip, jp = i[p], j[p]
        # the reference's colours: springs of one direction and colour share no point
        self.colour = np.select([d == 0, d <= 3, d == 4],
                                [(jp - 1) % 2, (ip - 1) % 2, ((jp - 2) // 2) % 2],
                                ((ip - 2) // 2) % 2)

    def coloured_order(self) -> tuple[np.ndarray, list[int]]:
        """Spring indices grouped by (direction, colour), SPEC order inside a group, and the
        13 group boundaries: the reference's `provot_order colored`."""
        key = self.direction * 2 + self.colour
        order = np.lexsort((np.arange(len(key)), key))
        return order, np.searchsorted(key[order], np.arange(13)).tolist()


class TaichiPeer:
    """The model in Taichi on its CPU arch; `coloured`: the parallel Provot."""

    def __init__(self, threads: int, precision: str, coloured: bool) -> None:
        import taichi as ti

        self.ti, self.threads, self.coloured = ti, threads, coloured
        self.real = ti.f32 if precision == "f32" else ti.f64
        self.np_real = np.float32 if precision == "f32" else np.float64
        # fast_math off: Taichi's default fast math moved the float64 cloth by 1.3 mm at
        # 100x100 after a simulated second (2e-8 m without it), at no measurable cost here
        ti.init(arch=ti.cpu, cpu_max_num_threads=threads, default_fp=self.real,
                fast_math=False, log_level=ti.WARN)

    def info(self) -> dict:
        provot = ("parallel loops over 12 groups (direction, colour)" if self.coloured
                  else "Gauss-Seidel, a serialised loop")
        return {"version": "taichi " + ".".join(map(str, self.ti.__version__)),
                "threads": f"arch cpu, cpu_max_num_threads={self.threads}", "provot": provot}

    def setup(self, m: Model) -> None:
        ti, real, npr = self.ti, self.real, self.np_real
        vec = ti.types.vector(3, real)
        nw, nh, n = m.nw, m.nh, m.n
        self.m = m
        self.pos = pos = vec.field(shape=(2, n))
        pinned, rest = ti.field(ti.i32, shape=n), ti.field(real, shape=(6, n))
        pinned.from_numpy(m.pinned)
        rest.from_numpy(m.rest.astype(npr))
        order, bounds = ((m.coloured_order()) if self.coloured
                         else (np.arange(len(m.a)), [0, len(m.a)]))
        groups = tuple(itertools.pairwise(bounds))
        count = len(order)
        sa, sb = ti.field(ti.i32, shape=count), ti.field(ti.i32, shape=count)
        lim = ti.field(real, shape=count)
        sa.from_numpy(m.a[order].astype(np.int32))
        sb.from_numpy(m.b[order].astype(np.int32))
        lim.from_numpy(m.limit[order].astype(npr))
        # the scene's numbers as compile-time constants, as Taichi's own examples do
        k = tuple(float(v) for v in m.k)
        weight = tuple(float(v * m.mass) for v in m.gravity)
        keep, scale = float(m.keep), float(m.dt2 / m.mass)
        coloured = self.coloured

        @ti.func
        def pull(xp, cur: ti.i32, q: ti.i32, k_d: ti.template(), r):
            """Hooke's force on a point at xp from its spring to point q, of rest length r."""
            d = pos[cur, q] - xp
            length = d.norm()
            f = vec(0.0, 0.0, 0.0)
            if length > 0.0:
                f = d * (k_d * (length - r) / length)
            return f

        @ti.func
        def shorten(cur: ti.i32, s: ti.i32):
            """Provot on spring s, positions in slot cur."""
            a, b = sa[s], sb[s]
            pa, pb = pinned[a], pinned[b]
            if pa == 0 or pb == 0:
                d = pos[cur, b] - pos[cur, a]
                length = d.norm()
                if length > lim[s]:
                    c = (d / length) * (length - lim[s])
                    if pa == 0 and pb == 0:
                        pos[cur, a] += 0.5 * c
                        pos[cur, b] -= 0.5 * c
                    elif pa != 0:
                        pos[cur, b] -= c
                    else:
                        pos[cur, a] += c

        @ti.kernel
        def substep(cur: ti.i32):
            """One step from pos[cur] = x (pos[1 - cur] = x_last) to pos[1 - cur] = x'."""
            for i, j in ti.ndrange(nh, nw):  # (1) forces and (2) Verlet, parallel
                p = i * nw + j
                x = pos[cur, p]
                new = x
                if pinned[p] == 0:
                    f = vec(weight[0], weight[1], weight[2])
                    for d in ti.static(range(6)):
                        di, dj = ti.static(OFFSETS[d])
                        if ti.static(k[d] != 0.0):
                            # p is the first point of its spring d, whose second is at +offset
                            if i + di >= 0 and 0 <= j + dj < nw:
                                f += pull(x, cur, p + di * nw + dj, k[d], rest[d, p])
                            # and the second point of spring d of the point at -offset
                            if i - di < nh and 0 <= j - dj < nw:
                                q = p - di * nw - dj
                                f += pull(x, cur, q, k[d], rest[d, q])
                    new = x + keep * (x - pos[1 - cur, p]) + f * scale
                pos[1 - cur, p] = new
            if ti.static(coloured):  # (5) Provot
                for g in ti.static(range(len(groups))):  # one parallel loop per group
                    for s in range(groups[g][0], groups[g][1]):
                        shorten(1 - cur, s)
            else:
                ti.loop_config(serialize=True)  # the SPEC's walk: one thread, in order
                for s in range(count):
                    shorten(1 - cur, s)

        self._substep = substep
        self.reset()

    def reset(self) -> None:
        self.pos.from_numpy(np.stack([self.m.x0, self.m.x0]).astype(self.np_real))
        self.cur = 0

    def run(self, steps: int) -> None:
        substep, cur = self._substep, self.cur
        for _ in range(steps):
            substep(cur)
            cur = 1 - cur
        self.cur = cur
        self.ti.sync()

    def positions(self) -> np.ndarray:
        return self.pos.to_numpy()[self.cur].astype(np.float64)


def warp_kernels(wp: Any, real: Any, vec: Any) -> tuple[Any, Any]:
    """The two kernels of a step at one precision (a closure: Warp builds a module for each)."""

    @wp.func
    def pull(pos: wp.array2d(dtype=vec), cur: int, xp: vec, q: int, k: real, r: real):
        """Hooke's force on a point at xp from its spring to point q, of rest length r."""
        d = pos[cur, q] - xp
        length = wp.length(d)
        if length > real(0.0):
            return d * (k * (length - r) / length)
        return vec(real(0.0), real(0.0), real(0.0))

    @wp.kernel(module="unique")
    def points(pos: wp.array2d(dtype=vec), rest: wp.array2d(dtype=real),
               pinned: wp.array(dtype=wp.int32), k: wp.array(dtype=real), cur: int, nw: int,
               nh: int, weight: vec, keep: real, scale: real):
        """(1) forces and (2) Verlet of point (i, j): pos[cur] = x -> pos[1 - cur] = x'."""
        i, j = wp.tid()
        p = i * nw + j
        x = pos[cur, p]
        if pinned[p] != 0:
            pos[1 - cur, p] = x
            return
        f = weight
        for d in range(6):  # constant trip count: Warp unrolls it
            di = 0
            dj = 0
            if d == 0:
                dj = -1
            elif d == 1:
                di = -1
            elif d == 2:
                di = -1
                dj = -1
            elif d == 3:
                di = -1
                dj = 1
            elif d == 4:
                dj = -2
            else:
                di = -2
            # p is the first point of its spring d, whose second is at +offset ...
            if i + di >= 0 and j + dj >= 0 and j + dj < nw:
                f += pull(pos, cur, x, p + di * nw + dj, k[d], rest[d, p])
            # ... and the second point of spring d of the point at -offset
            if i - di < nh and j - dj >= 0 and j - dj < nw:
                q = p - di * nw - dj
                f += pull(pos, cur, x, q, k[d], rest[d, q])
        pos[1 - cur, p] = x + keep * (x - pos[1 - cur, p]) + f * scale

    @wp.kernel(module="unique")
    def provot(pos: wp.array2d(dtype=vec), sa: wp.array(dtype=wp.int32),
               sb: wp.array(dtype=wp.int32), lim: wp.array(dtype=real),
               pinned: wp.array(dtype=wp.int32), cur: int, count: int):
        """(5) Provot, the SPEC's Gauss-Seidel walk of the springs in order (dim 1)."""
        for s in range(count):
            a = sa[s]
            b = sb[s]
            pa = pinned[a]
            pb = pinned[b]
            if pa == 0 or pb == 0:
                d = pos[cur, b] - pos[cur, a]
                length = wp.length(d)
                if length > lim[s]:
                    c = (d / length) * (length - lim[s])
                    if pa == 0 and pb == 0:
                        pos[cur, a] = pos[cur, a] + real(0.5) * c
                        pos[cur, b] = pos[cur, b] - real(0.5) * c
                    elif pa != 0:
                        pos[cur, b] = pos[cur, b] - c
                    else:
                        pos[cur, a] = pos[cur, a] + c

    return points, provot


class WarpPeer:
    """The model in Warp on its CPU device (there is no CUDA here)."""

    def __init__(self, threads: int, precision: str) -> None:
        import warp as wp

        wp.config.quiet = True
        wp.config.enable_backward = False  # no gradients wanted: compile the forward only
        wp.init()
        self.wp = wp
        self.np_real = np.float32 if precision == "f32" else np.float64
        self.real = wp.float32 if precision == "f32" else wp.float64
        self.vec = wp.vec3f if precision == "f32" else wp.vec3d
        self.points, self.provot = warp_kernels(wp, self.real, self.vec)

    def info(self) -> dict:
        return {"version": "warp-lang " + self.wp.__version__,
                "threads": "device cpu, 1 thread (Warp runs a CPU launch on one thread)",
                "provot": "Gauss-Seidel, one launch of dim 1"}

    def setup(self, m: Model) -> None:
        wp, real, vec, npr = self.wp, self.real, self.vec, self.np_real
        self.m = m
        with wp.ScopedDevice("cpu"):
            self.pos = wp.zeros((2, m.n), dtype=vec)
            rest = wp.array(m.rest.astype(npr), dtype=real)
            pinned = wp.array(m.pinned, dtype=wp.int32)
            k = wp.array(m.k.astype(npr), dtype=real)
            sa = wp.array(m.a.astype(np.int32), dtype=wp.int32)
            sb = wp.array(m.b.astype(np.int32), dtype=wp.int32)
            lim = wp.array(m.limit.astype(npr), dtype=real)
            weight = vec(*(m.gravity * m.mass))
            self.launches = []  # [cur] = (points, Provot), recorded once, replayed every step
            for cur in (0, 1):
                pts = wp.launch(self.points, dim=(m.nh, m.nw),
                                inputs=[self.pos, rest, pinned, k, cur, m.nw, m.nh, weight,
                                        real(m.keep), real(m.dt2 / m.mass)], record_cmd=True)
                prv = wp.launch(self.provot, dim=1,
                                inputs=[self.pos, sa, sb, lim, pinned, 1 - cur, len(m.a)],
                                record_cmd=True)
                self.launches.append((pts, prv))
            self._arrays = (rest, pinned, k, sa, sb, lim)  # the recorded launches use them
        self.reset()

    def reset(self) -> None:
        x0 = np.stack([self.m.x0, self.m.x0]).astype(self.np_real)
        self.pos.assign(self.wp.array(x0, dtype=self.vec, device="cpu"))
        self.cur = 0

    def run(self, steps: int) -> None:
        launches, cur = self.launches, self.cur
        for _ in range(steps):
            pts, prv = launches[cur]
            pts.launch()
            prv.launch()
            cur = 1 - cur
        self.cur = cur
        self.wp.synchronize_device("cpu")

    def positions(self) -> np.ndarray:
        return self.pos.numpy()[self.cur].astype(np.float64)


# Newton's cloth_hanging example (newton/examples/cloth/example_cloth_hanging.py in newton
# 1.8.0), the numbers of its `vbd` branch as written there: a 64 x 32 cell grid (65 x 33
# points) of 0.1 m cells at z = 4, turned 90 degrees about z, its left edge (33 points)
# fixed; 0.1 kg a point; membrane tri_ke (mu) and tri_ka (lambda) with damping tri_kd;
# bending edge_ke per unit edge length; a ground plane under a soft contact; Newton's default
# gravity, -9.81 m/s^2 along z; 10 substeps of 10 iterations per 1/60 s frame; SolverVBD with
# self-contact on.
HANGING = {"dim_x": 64, "dim_y": 32, "cell": 0.1, "height": 4.0, "mass": 0.1,
           "tri_ke": 1.0e3, "tri_ka": 1.0e3, "tri_kd": 1.0e2, "edge_ke": 1.0e1,
           "edge_kd": 0.0, "particle_radius": 0.05, "soft_contact_ke": 1.0e2,
           "soft_contact_kd": 1.0e2, "soft_contact_mu": 1.0, "self_contact_margin": 0.02,
           "self_contact_gap": 0.01, "fps": 60, "steps_per_frame": 10, "iterations": 10,
           "gravity": 9.81}


class NewtonPeer:
    """Newton's own SolverVBD on its cloth_hanging scene (HANGING), built and stepped as the
    example does (a frame's substeps captured once as a graph and replayed), without a
    viewer; `self_contact` as the example (on) or off."""

    def __init__(self, self_contact: bool) -> None:
        import newton
        import warp as wp

        wp.config.quiet = True
        wp.init()
        self.wp, self.newton, self.self_contact = wp, newton, self_contact

    def info(self) -> dict:
        contact = (f"self-contact on (margin {HANGING['self_contact_margin']} m, gap "
                   f"{HANGING['self_contact_gap']} m)" if self.self_contact else "self-contact off")
        return {"version": f"newton {self.newton.__version__}, warp-lang {self.wp.__version__}",
                "threads": "device cpu, 1 thread (Warp runs a CPU launch on one thread)",
                "provot": f"none (SolverVBD, {contact})"}

    def setup(self, spec: dict) -> None:
        self.spec = spec
        self.reset()

    def reset(self) -> None:
        """A new model, solver and captured frame: Newton's solver keeps state between steps
        (previous positions, contact lists), so the run starts exactly as the first did."""
        wp, newton, c = self.wp, self.newton, self.spec
        with wp.ScopedDevice("cpu"):
            builder = newton.ModelBuilder()
            builder.add_ground_plane()
            builder.add_cloth_grid(
                pos=wp.vec3(0.0, 0.0, c["height"]),
                rot=wp.quat_from_axis_angle(wp.vec3(0.0, 0.0, 1.0), wp.pi * 0.5),
                vel=wp.vec3(0.0, 0.0, 0.0), dim_x=c["dim_x"], dim_y=c["dim_y"],
                cell_x=c["cell"], cell_y=c["cell"], mass=c["mass"], fix_left=True,
                edge_ke=c["edge_ke"], edge_kd=c["edge_kd"],
                particle_radius=c["particle_radius"], tri_ke=c["tri_ke"], tri_ka=c["tri_ka"],
                tri_kd=c["tri_kd"])
            builder.color(include_bending=True)
            self.model = model = builder.finalize()
            model.soft_contact_ke = c["soft_contact_ke"]
            model.soft_contact_kd = c["soft_contact_kd"]
            model.soft_contact_mu = c["soft_contact_mu"]
            self.solver = newton.solvers.SolverVBD(
                model=model, iterations=c["iterations"],
                particle_enable_self_contact=self.self_contact,
                particle_self_contact_margin=c["self_contact_margin"],
                particle_self_contact_gap=c["self_contact_gap"])
            self.states = [model.state(), model.state()]
            self.control = model.control()
            self.pipeline = newton.CollisionPipeline(model)
            self.contacts = self.pipeline.contacts()
            with wp.ScopedCapture() as capture:
                self._frame()
            self.graph = capture.graph

    def _frame(self) -> None:
        """A frame's substeps, as the example's simulate() (an even count: state 0 ends as
        the frame's result, as the graph replays it)."""
        dt = 1.0 / self.spec["fps"] / self.spec["steps_per_frame"]
        for _ in range(self.spec["steps_per_frame"]):
            s0, s1 = self.states
            s0.clear_forces()
            self.pipeline.collide(s0, self.contacts)
            self.solver.step(s0, s1, self.control, self.contacts, dt)
            self.states = [s1, s0]

    def run(self, steps: int) -> None:
        frames, rest = divmod(steps, self.spec["steps_per_frame"])
        if rest:
            raise ValueError(f"{steps} steps: not whole frames")
        for _ in range(frames):
            self.wp.capture_launch(self.graph)
        self.wp.synchronize_device("cpu")

    def positions(self) -> np.ndarray:
        """(N, 3) in our frame: Newton's z up to our y, its grid rows and columns to our z
        and x (Newton's point (X, Y, Z) is ours (Y, Z - height + 1, -X); the point order is
        the same), so our cloth lies at y = 1 like a horizontal grid cloth."""
        q = self.states[0].particle_q.numpy().astype(np.float64)
        return np.stack([q[:, 1], q[:, 2] - self.spec["height"] + 1.0, -q[:, 0]], axis=1)


def make_peer(name: str, threads: int, precision: str) -> TaichiPeer | WarpPeer | NewtonPeer:
    if name in NEWTON_PEERS:
        return NewtonPeer(self_contact=name == "newton")
    if name == "warp":
        return WarpPeer(threads, precision)
    return TaichiPeer(threads, precision, coloured=name == "taichi-colored")


def serve(name: str, threads: int, precision: str) -> None:
    """The worker: answer one JSON line per request line on stdin, until `quit` or EOF.

    {"op": "info"} -> versions, threads;
    {"op": "setup", "model": {...}, "init": npy, "frames": F, "trace": [f, ...], "path": npy}
    -> {"warmup_s"}: builds, compiles and runs F frames (the untimed run), saving the
    positions after frames f to path, (len(trace), N, 3) float64;
    {"op": "run", "steps": S} -> {"seconds"}: S steps from the initial state;
    {"op": "save", "path": npy} -> {}: the current positions, (N, 3) float64;
    {"op": "quit"}. Any failure -> {"error": "..."}, its traceback on stderr."""
    # the replies keep the real stdout; the libraries' banners and logs go to stderr
    replies = os.fdopen(os.dup(1), "w", buffering=1)
    os.dup2(2, 1)

    def reply(obj: dict) -> None:
        replies.write(json.dumps(obj) + "\n")

    try:
        peer = make_peer(name, threads, precision)
    except Exception as exc:  # noqa: BLE001  (the driver shows it as the skip reason)
        traceback.print_exc()
        reply({"error": f"{type(exc).__name__}: {exc}"})
        return
    for line in sys.stdin:
        msg = json.loads(line)
        try:
            op = msg["op"]
            if op == "info":
                reply({"python": platform.python_version(), "precision": precision,
                       **peer.info()})
            elif op == "setup":
                spec = msg["model"]
                trace, snapshots = set(msg["trace"]), []
                t0 = time.perf_counter()
                peer.setup(spec if name in NEWTON_PEERS else Model(spec, np.load(msg["init"])))
                for frame in range(1, int(msg["frames"]) + 1):
                    peer.run(int(spec["steps_per_frame"]))
                    if frame in trace:
                        snapshots.append(peer.positions())
                warmup = time.perf_counter() - t0
                np.save(msg["path"], np.array(snapshots))
                reply({"warmup_s": warmup})
            elif op == "run":
                peer.reset()
                t0 = time.perf_counter()
                peer.run(int(msg["steps"]))
                reply({"seconds": time.perf_counter() - t0})
            elif op == "save":
                np.save(msg["path"], peer.positions())
                reply({})
            elif op == "quit":
                reply({})
                return
            else:
                reply({"error": f"unknown op {op!r}"})
        except Exception as exc:  # noqa: BLE001
            traceback.print_exc()
            reply({"error": f"{type(exc).__name__}: {exc}"})


# ================================================================================== the driver
# Runs in the project's environment.

class PeerError(RuntimeError):
    """A peer could not be installed, started or run; str() is the reason printed."""


def ensure_venv(venv: Path, python: str, peers: list[str], log: Path) -> dict[str, str]:
    """Create the peers' venv if needed and install each peer's package (pinned, PACKAGES)
    where it is missing; {peer: why it is skipped} for those that cannot be had."""
    vpy = venv / "bin" / "python"
    skipped: dict[str, str] = {}
    with log.open("a") as out:
        if not vpy.exists():
            venv.parent.mkdir(parents=True, exist_ok=True)
            made = subprocess.run([python, "-m", "venv", str(venv)], stdout=out, stderr=out,
                                  check=False)
            if made.returncode != 0:
                return {p: f"cannot create a venv with {python} (see {log})" for p in peers}
        for spec in ["numpy"] + sorted({PACKAGES[p] for p in peers}):
            name, _, version = spec.partition("==")
            have = subprocess.run(
                [str(vpy), "-c", f"import importlib.metadata as m; print(m.version({name!r}))"],
                capture_output=True, text=True, check=False)
            if have.returncode == 0 and (not version or have.stdout.strip() == version):
                continue
            print(f"installing {spec} into {venv} ...", file=sys.stderr, flush=True)
            got = subprocess.run([str(vpy), "-m", "pip", "install", "-q", spec,
                                  *WITH.get(spec, [])],
                                 capture_output=True, text=True, check=False)
            out.write(got.stdout + got.stderr)
            if got.returncode != 0:
                errors = [ln for ln in got.stderr.splitlines() if ln.startswith("ERROR")]
                why = f"pip install {spec} failed: " + (errors[-1] if errors else f"see {log}")
                for p in peers:
                    if spec in (PACKAGES[p], "numpy"):
                        skipped.setdefault(p, why)
    return skipped


class PeerProcess:
    """One peer's worker (this file run by the venv's python) and its line protocol."""

    def __init__(self, vpy: Path, name: str, threads: int, precision: str, log: Path) -> None:
        self.name, self.log = name, log
        self.stderr = log.open("a")
        self.proc = subprocess.Popen(
            [str(vpy), str(Path(__file__).resolve()), "--worker", name, "--threads",
             str(threads), "--precision", precision],
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=self.stderr, text=True)

    def ask(self, **msg: Any) -> dict:
        try:
            self.proc.stdin.write(json.dumps(msg) + "\n")
            self.proc.stdin.flush()
            line = self.proc.stdout.readline()
        except BrokenPipeError:
            line = ""
        if not line:
            raise PeerError(f"worker exited (status {self.proc.poll()}, see {self.log})")
        answer = json.loads(line)
        if "error" in answer:
            raise PeerError(answer["error"])
        return answer

    def close(self) -> None:
        if self.proc.poll() is None:
            try:
                self.ask(op="quit")
            except PeerError:
                pass
        try:
            self.proc.wait(timeout=30)
        except subprocess.TimeoutExpired:
            self.proc.kill()  # our own child, by its handle
            self.proc.wait()
        self.stderr.close()


def load_ours() -> tuple[Any, Any]:
    """(Simulation, load_scene) from the public API, retried while another checkout step
    moves the package's modules (an import can fail half-way, so its modules are dropped)."""
    for attempt in range(IMPORT_RETRIES):
        before = set(sys.modules)
        try:
            from pipeline import Simulation, load_scene

            Simulation(scene_dict("pinned2.json", 5)).advance(1)  # imports the simulator's modules too
            return Simulation, load_scene
        except ImportError as exc:
            if attempt == IMPORT_RETRIES - 1:
                raise
            print(f"import failed ({exc}); retrying in {IMPORT_WAIT:g} s", file=sys.stderr)
            for name in set(sys.modules) - before:
                del sys.modules[name]
            time.sleep(IMPORT_WAIT)
    raise AssertionError("unreachable")


def model_spec(raw: dict, scene: Any) -> dict:
    """What the workers need of the scene: the cloth as written, the simulation settings
    as our loader resolved them (defaults included)."""
    c, s = raw["cloth"], scene.simulation
    return {"nw": c["num_width_points"], "nh": c["num_height_points"], "width": c["width"],
            "height": c["height"], "density": c["density"], "ks": c["ks"],
            "damping": c["damping"], "pinned": c.get("pinned", []),
            "enable": [bool(c["enable_structural"]), bool(c["enable_shearing"]),
                       bool(c["enable_bending"])],
            "gravity": [float(g) for g in s.gravity],
            "frames_per_sec": float(s.frames_per_sec), "steps_per_frame": int(s.steps_per_frame)}


def coloured_reference(raw: dict, x0: np.ndarray, frames: int) -> np.ndarray | None:
    """The C++ reference's final positions with Provot in the coloured order, or None."""
    if not REFERENCE.is_dir():
        return None
    sys.path.insert(0, str(REFERENCE))
    try:
        import cs184_ref

        return cs184_ref.simulate(raw, frames, init_positions=x0, last_only=True,
                                  provot_order="colored")[0]
    except Exception as exc:  # noqa: BLE001  (a calibration line only: say why it is missing)
        print(f"(C++ reference not run: {exc})", file=sys.stderr)
        return None


class Case(NamedTuple):
    """One grid's measurements."""

    size: int
    frames: int
    steps: int
    sim_seconds: float
    times: dict[str, list[float]]  # seconds of each timed run: "ours" and each peer that ran
    warmups: dict[str, float]  # seconds of the untimed run, compile included
    finals: dict[str, np.ndarray]  # (N, 3) after the last timed run
    trace_frames: list[int]
    traces: dict[str, np.ndarray]  # (len(trace_frames), N, 3) from the untimed run
    raw: dict
    x0: np.ndarray


def start_workers(peers: list[str], skipped: dict[str, str], vpy: Path, args: Any,
                  request: dict, tmp: Path, log: Path, infos: dict[str, dict]
                  ) -> tuple[dict[str, PeerProcess], dict[str, float], dict[str, np.ndarray]]:
    """A warm worker per peer not skipped (its untimed run done), its warm-up seconds and
    trace; a peer that fails joins `skipped`."""
    workers, warmups, traces = {}, {}, {}
    for p in peers:
        if p in skipped:
            continue
        worker = PeerProcess(vpy, p, args.threads, args.precision, log)
        path = tmp / f"trace-{p}.npy"
        try:
            infos.setdefault(p, worker.ask(op="info"))
            warmups[p] = worker.ask(op="setup", path=str(path), **request)["warmup_s"]
            traces[p] = np.load(path)
            workers[p] = worker
        except PeerError as exc:
            skipped[p] = str(exc)
            worker.close()
    return workers, warmups, traces


def measure(size: int, peers: list[str], skipped: dict[str, str], vpy: Path, args: Any,
            ours: tuple[Any, Any], tmp: Path, log: Path, infos: dict[str, dict]) -> Case:
    """The untimed runs, then `args.rounds` rounds of ours and each peer in turn, then the
    final positions of each."""
    Simulation, load_scene = ours
    raw = scene_dict("pinned2.json", size)
    scene = load_scene(raw)
    frames = round(scene.simulation.frames_per_sec)
    steps = frames * scene.simulation.steps_per_frame
    trace_frames = sorted({1, *range(10, frames + 1, 10), frames})
    # untimed, a whole run: a kernel may be compiled (or loaded from numba's cache) at its
    # first use in mid-run, e.g. at the first spring Provot shortens
    t0 = time.perf_counter()
    sim = Simulation(scene)
    x0 = sim.positions.copy()
    trace = []
    for frame in range(1, frames + 1):
        sim.advance(1)
        if frame in trace_frames:
            trace.append(sim.positions.copy())
    warmups = {"ours": time.perf_counter() - t0}
    traces = {"ours": np.array(trace)}
    init = tmp / f"init{size}.npy"
    np.save(init, x0)
    request = {"model": model_spec(raw, scene), "init": str(init), "frames": frames,
               "trace": trace_frames}
    workers, peer_warmups, peer_traces = start_workers(peers, skipped, vpy, args, request,
                                                       tmp, log, infos)
    warmups.update(peer_warmups)
    traces.update(peer_traces)
    times: dict[str, list[float]] = {"ours": [], **{p: [] for p in workers}}
    for _ in range(args.rounds):
        sim = Simulation(scene)  # built outside the timing, as benchmarks/sim.py does
        t0 = time.perf_counter()
        sim.advance(frames)
        times["ours"].append(time.perf_counter() - t0)
        run_peers(workers, times, skipped, steps)
    finals = {"ours": sim.positions.copy(), **collect_finals(workers, times, skipped, tmp, size)}
    return Case(size, frames, steps, steps * sim.dt, times, warmups, finals, trace_frames,
                traces, raw, x0)


def run_peers(workers: dict[str, PeerProcess], times: dict[str, list[float]],
              skipped: dict[str, str], steps: int) -> None:
    """One timed run of `steps` steps from the initial state by each worker, in turn; a
    worker that fails is closed and dropped (with its times)."""
    for p, worker in list(workers.items()):
        try:
            times[p].append(worker.ask(op="run", steps=steps)["seconds"])
        except PeerError as exc:
            skipped[p] = str(exc)
            worker.close()
            del workers[p], times[p]


def collect_finals(workers: dict[str, PeerProcess], times: dict[str, list[float]],
                   skipped: dict[str, str], tmp: Path, tag: object) -> dict[str, np.ndarray]:
    """Each worker's current positions (N, 3); then the workers are closed."""
    finals = {}
    for p, worker in workers.items():
        path = tmp / f"{p}{tag}.npy"
        try:
            worker.ask(op="save", path=str(path))
            finals[p] = np.load(path)
        except PeerError as exc:
            skipped[p] = str(exc)
            del times[p]
        worker.close()
    return finals


def distance(a: np.ndarray, b: np.ndarray) -> float:
    """The largest distance between corresponding points (the last axis is xyz)."""
    return float(np.sqrt(((a - b) ** 2).sum(axis=-1)).max())


def row(grid: str, who: str, case: Case, dist: float | None, note: str = "") -> str:
    times = case.times[who]
    med, low = statistics.median(times), min(times)
    d = "-" if dist is None else f"{dist:.2e}"
    return (f"{grid:9s} {who:15s} {med / case.sim_seconds:9.3f} {low / case.sim_seconds:9.3f} "
            f"{case.steps / med:9.0f} {case.warmups[who]:9.2f} {d:>11s}{note}")


def judge(case: Case, peer: str, precision: str) -> str:
    """'' when the peer agrees with ours, else a note saying how it does not. A different
    model parts from ours within the first frames; round-off parts at ~1e-16 m and grows, and
    can grow by orders of magnitude at once where the cloth could fold either way."""
    final = distance(case.finals[peer], case.finals["ours"])
    if final <= AGREEMENT[precision]:
        return ""
    if peer == "taichi-colored":
        return " (Provot's order differs)"
    early = distance(case.traces[peer][1], case.traces["ours"][1])  # at frame 10
    if early > EARLY_AGREEMENT[precision]:
        return f" (> {EARLY_AGREEMENT[precision]:g} m at frame 10: NOT the same model?)"
    return f" (> {AGREEMENT[precision]:g} m, grown from round-off: see the trace)"


def report(case: Case, peers: list[str], skipped: dict[str, str], precision: str) -> str:
    """Print the case's rows, its ratio line, the peers' traces and (taichi-colored) the
    coloured reference; returns the ratio line ('' when no peer ran)."""
    grid = f"{case.size}x{case.size}"
    ours = case.finals["ours"]
    print(row(grid, "ours", case, None))
    for p in peers:
        if p not in case.finals:
            print(f"{grid:9s} {p:15s} skipped: {skipped.get(p, 'not run')}")
            continue
        print(row(grid, p, case, distance(case.finals[p], ours), judge(case, p, precision)))
    ran = [p for p in peers if p in case.finals]
    line = ""
    if ran:
        parts = []
        for label, stat in (("median", statistics.median), ("min", min)):
            best = min(ran, key=lambda p: stat(case.times[p]))
            ratio = stat(case.times[best]) / stat(case.times["ours"])
            parts.append((ratio, f"{ratio:.2f}x by {label} ({best})"))
        verdict = "met" if min(r for r, _ in parts) >= 2 else "NOT met"
        line = (f"{grid}: best peer / ours = {', '.join(t for _, t in parts)}; "
                f"target >= 2x: {verdict}")
        print(line)
        print(f"{grid:9s} |x - ours| (m) after frame "
              + " ".join(f"{f:>7d}" for f in case.trace_frames) + "  (untimed runs)")
        for p in ran:
            dists = [distance(a, b) for a, b in zip(case.traces[p], case.traces["ours"])]
            print(f"{'':9s} {p:26s} " + " ".join(f"{d:7.0e}" for d in dists))
    if "taichi-colored" in case.finals:
        ref = coloured_reference(case.raw, case.x0, case.frames)
        if ref is not None:
            to_ours = np.linalg.norm(ref - ours, axis=1).max()
            to_peer = np.linalg.norm(ref - case.finals["taichi-colored"], axis=1).max()
            print(f"{grid}: C++ reference with Provot in the coloured order: "
                  f"{to_ours:.2e} m from ours, {to_peer:.2e} m from taichi-colored")
    sys.stdout.flush()
    return line


# ============================================================ the VBD case (--vbd), the driver
# Newton's cloth_hanging (HANGING) as our FEM cloth under `vbd`, against Newton's SolverVBD.

# our runs: (name, simulation.self_collision, simulation.contact)
OUR_VBD_RUNS = (("ours", False, "course"), ("ours+self-collision", True, "course"),
                ("ours+robust", True, "robust"))


def uniform_mass_map(nw: int, nh: int) -> list[list[float]]:
    """`cloth.mass_map` rows (top row first) that turn the FEM's lumped masses (a third of
    each adjacent triangle's area) into one mass for every point, as Newton's grid has:
    6 / (the point's triangles), on the FEM's triangles (A, C, B), (B, C, D) of each cell."""
    count = np.zeros((nh, nw))
    for corners in (((0, 0), (1, 0), (0, 1)), ((0, 1), (1, 0), (1, 1))):
        for di, dj in corners:
            count[di:nh - 1 + di, dj:nw - 1 + dj] += 1
    return (6.0 / count)[::-1].tolist()


def hanging_scene(self_collision: bool, contact: str) -> dict:
    """HANGING as our scene: the FEM (a triangle membrane with dihedral bending, as Newton's
    cloth; the classic model is springs), its stiffnesses from Newton's at small strain:
    Newton's Stable Neo-Hookean membrane (mu = tri_ke, lambda = tri_ka) is mu eps:eps +
    lambda / 2 tr(eps)^2 there, so stretch = 2 mu + lambda (strain along u, v held) and
    shear = mu; Newton's bending 0.5 edge_ke |e| theta^2 is ours D |e|^2 / (2 (A1 + A2))
    theta^2 with D = edge_ke * cell on the grid's axis hinges (the diagonal ones are sqrt 2
    stiffer in ours). Every point 0.1 kg (a mass map over the FEM's lumped masses). Our
    horizontal cloth lies at y = 1, so the ground (Newton's z = 0) is at y = 1 - height, raised
    by Newton's particle radius (its ground contact holds points that far above it). Not
    matched: Newton's damping (tri_kd: strain-rate damping of the membrane; ours none,
    `damping` 0), its penalty ground contact (ours the plane collider, friction 1 for mu 1)
    and its self-contact (ours: see OUR_VBD_RUNS; thickness = gap / 2, points 2 * thickness
    apart)."""
    c = HANGING
    nw, nh = c["dim_x"] + 1, c["dim_y"] + 1
    width, height = c["dim_x"] * c["cell"], c["dim_y"] * c["cell"]
    density = c["mass"] / c["cell"] ** 2
    cloth = {"width": width, "height": height, "num_width_points": nw, "num_height_points": nh,
             "thickness": c["self_contact_gap"] / 2, "orientation": 0, "damping": 0.0,
             "density": density, "ks": 1000.0, "enable_structural": True,
             "enable_shearing": True, "enable_bending": True,
             "pinned": [[0, i] for i in range(nh)], "mass_map": uniform_mass_map(nw, nh),
             "fem": {"stretch": 2 * c["tri_ke"] + c["tri_ka"], "shear": c["tri_ke"],
                     "bending": c["edge_ke"] * c["cell"], "density": density}}
    ground = 1.0 - c["height"] + c["particle_radius"]
    return {"cloth": cloth,
            "plane": {"point": [0.0, ground, 0.0], "normal": [0.0, 1.0, 0.0],
                      "friction": min(1.0, c["soft_contact_mu"])},
            "simulation": {"model": "fem", "integrator": "vbd", "iterations": c["iterations"],
                           "frames_per_sec": c["fps"], "steps_per_frame": c["steps_per_frame"],
                           "gravity": [0.0, -c["gravity"], 0.0],
                           "self_collision": self_collision, "contact": contact}}


class VbdCase(NamedTuple):
    """The VBD case's measurements (as Case's fields of the same names)."""

    frames: int
    times: dict[str, list[float]]
    warmups: dict[str, float]
    finals: dict[str, np.ndarray]
    trace_frames: list[int]
    traces: dict[str, np.ndarray]


def traced_run(sim: Any, frames: int, trace_frames: list[int]) -> np.ndarray:
    """Advance `frames` frames; the positions after each of trace_frames."""
    trace = []
    for frame in range(1, frames + 1):
        sim.advance(1)
        if frame in trace_frames:
            trace.append(sim.positions.copy())
    return np.array(trace)


def measure_vbd(peers: list[str], skipped: dict[str, str], vpy: Path, args: Any,
                simulation: Any, tmp: Path, log: Path, infos: dict[str, dict]) -> VbdCase:
    """Untimed runs of each of our runs and each peer, then `args.rounds` rounds of each in
    turn, `args.frames` frames from the start each."""
    frames = args.frames
    trace_frames = sorted({1, frames // 2, frames})
    scenes = {name: hanging_scene(sc, contact) for name, sc, contact in OUR_VBD_RUNS}
    warmups, traces = {}, {}
    for name, scene in scenes.items():
        t0 = time.perf_counter()
        traces[name] = traced_run(simulation(scene), frames, trace_frames)
        warmups[name] = time.perf_counter() - t0
    request = {"model": HANGING, "frames": frames, "trace": trace_frames}
    workers, peer_warmups, peer_traces = start_workers(peers, skipped, vpy, args, request,
                                                       tmp, log, infos)
    warmups.update(peer_warmups)
    traces.update(peer_traces)
    times: dict[str, list[float]] = {name: [] for name in [*scenes, *workers]}
    finals = {}
    for _ in range(args.rounds):
        for name, scene in scenes.items():
            sim = simulation(scene)  # built outside the timing
            t0 = time.perf_counter()
            sim.advance(frames)
            times[name].append(time.perf_counter() - t0)
            finals[name] = sim.positions.copy()
        run_peers(workers, times, skipped, frames * HANGING["steps_per_frame"])
    finals.update(collect_finals(workers, times, skipped, tmp, "vbd"))
    return VbdCase(frames, times, warmups, finals, trace_frames, traces)


def report_vbd(case: VbdCase, peers: list[str], skipped: dict[str, str]) -> None:
    """Frames per second of each run (median and best round), its warm-up, where the cloth
    is (its lowest point above the ground, its distance to Newton's), then ours / Newton's."""
    ground = 1.0 - HANGING["height"]
    reference = case.finals.get(NEWTON_PEERS[0])
    print(f"{'simulator':24s} {'frames/s':>9s} {'best':>9s} {'warm-up s':>9s} "
          f"{'lowest m':>9s} {'|x - newton|':>12s}")
    for name in [r[0] for r in OUR_VBD_RUNS] + peers:
        if name not in case.finals:
            print(f"{name:24s} skipped: {skipped.get(name, 'not run')}")
            continue
        t = case.times[name]
        d = "-" if reference is None else f"{distance(case.finals[name], reference):.2e}"
        print(f"{name:24s} {case.frames / statistics.median(t):9.3f} {case.frames / min(t):9.3f} "
              f"{case.warmups[name]:9.2f} {case.finals[name][:, 1].min() - ground:9.3f} "
              f"{d:>12s}")
    ran = [p for p in peers if p in case.finals]
    if not ran:
        return
    print("ours / Newton, frames per second: median (best round)")
    print(f"{'':24s}" + "".join(f" {p:>24s}" for p in ran))
    for name, _, _ in OUR_VBD_RUNS:
        cells = []
        for p in ran:
            med = statistics.median(case.times[p]) / statistics.median(case.times[name])
            cells.append(f"{med:.2f}x ({min(case.times[p]) / min(case.times[name]):.2f}x)")
        print(f"{name:24s}" + "".join(f" {c:>24s}" for c in cells))
    print(f"{'|x - newton| (m) after frame':34s}"
          + " ".join(f"{f:>8d}" for f in case.trace_frames) + "  (untimed runs)")
    for name in [r[0] for r in OUR_VBD_RUNS] + ran[1:]:
        if reference is not None and name in case.traces:
            dists = [distance(a, b) for a, b in zip(case.traces[name], case.traces[ran[0]])]
            print(f"  {name:32s}" + " ".join(f"{d:8.2e}" for d in dists))
    sys.stdout.flush()


def main_vbd(args: Any, peers: list[str], skipped: dict[str, str], vpy: Path,
             simulation: Any, log: Path) -> None:
    """--vbd: the header lines, the case, the report."""
    c = HANGING
    print(f"VBD against Newton: its cloth_hanging rebuilt ({c['dim_x'] + 1} x {c['dim_y'] + 1} "
          f"points, {c['cell']} m cells, left edge pinned), {args.frames} frames of "
          f"1/{c['fps']} s from the start, {c['steps_per_frame']} steps x {c['iterations']} "
          f"iterations a frame, {args.rounds} rounds alternately; ours: the FEM under vbd "
          "(benchmarks/peers.py hanging_scene)")
    infos: dict[str, dict] = {}
    with tempfile.TemporaryDirectory(prefix="clothpipe-peers-") as tmp:
        case = measure_vbd(peers, skipped, vpy, args, simulation, Path(tmp), log, infos)
    for p in peers:
        info = infos.get(p)
        print(f"  {p}: skipped: {skipped.get(p, 'not run')}" if info is None else
              f"  {p}: {info['version']}, Python {info['python']} (venv), {info['threads']}, "
              f"float32, {info['provot']}")
    report_vbd(case, peers, skipped)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default="50,100,200", help="grids, comma-separated")
    ap.add_argument("--rounds", type=int, default=3, help="timed rounds (>= 3)")
    ap.add_argument("--threads", type=int, default=os.cpu_count() or 1,
                    help="numba threads for ours, cpu_max_num_threads for Taichi")
    ap.add_argument("--peers", help="comma-separated, of "
                    f"{', '.join(PEERS)} (default taichi,warp; with --vbd newton's two)")
    ap.add_argument("--vbd", action="store_true",
                    help="the VBD case: Newton's cloth_hanging against Newton's SolverVBD")
    ap.add_argument("--frames", type=int, default=60, help="--vbd: frames a round")
    ap.add_argument("--precision", choices=["f64", "f32"], default="f64",
                    help="the peers' floating point (ours is float64)")
    ap.add_argument("--venv", type=Path, default=DEFAULT_VENV, help="the peers' venv")
    ap.add_argument("--peer-python", default=sys.executable,
                    help="the Python that creates the peers' venv")
    ap.add_argument("--worker", choices=PEERS, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.worker:
        serve(args.worker, args.threads, args.precision)
        return
    sizes = [int(s) for s in args.sizes.split(",")]
    default = ",".join(NEWTON_PEERS) if args.vbd else "taichi,warp"
    peers = [p.strip() for p in (args.peers or default).split(",") if p.strip()]
    unknown = set(peers) - set(NEWTON_PEERS if args.vbd else PINNED2_PEERS)
    if unknown or args.rounds < 3 or args.frames < 1:
        ap.error(f"unknown peers {sorted(unknown)}" if unknown else
                 "--rounds must be >= 3" if args.rounds < 3 else "--frames must be >= 1")

    # numba reads its thread count at import: more than the default needs it set first
    os.environ.setdefault("NUMBA_NUM_THREADS", str(max(args.threads, os.cpu_count() or 1)))
    log = Path(tempfile.gettempdir()) / "clothpipe-peers.log"
    skipped = ensure_venv(args.venv, args.peer_python, peers, log)
    vpy = args.venv / "bin" / "python"

    import importlib.metadata

    import numba

    ours = load_ours()
    numba.set_num_threads(min(args.threads, numba.config.NUMBA_NUM_THREADS))
    if args.vbd:
        print(f"  ours: clothpipe {importlib.metadata.version('clothpipe')}, numba "
              f"{numba.__version__}, numba threads {numba.get_num_threads()}, float64")
        main_vbd(args, peers, skipped, vpy, ours[0], log)
        return
    print(f"peers benchmark: {SCENE.relative_to(ROOT)}, {args.rounds} rounds, "
          f"{os.cpu_count()} cores; peers in {args.venv}; worker logs in {log}")
    print(f"  ours: clothpipe {importlib.metadata.version('clothpipe')}, numba "
          f"{numba.__version__}, Python {platform.python_version()}, numba threads "
          f"{numba.get_num_threads()} ({numba.threading_layer()} layer), float64, Provot: "
          "Gauss-Seidel (the SPEC's)")
    infos: dict[str, dict] = {}
    summary = []
    with tempfile.TemporaryDirectory(prefix="clothpipe-peers-") as tmp:
        for size in sizes:
            case = measure(size, peers, skipped, vpy, args, ours, Path(tmp), log, infos)
            if size == sizes[0]:
                for p in peers:
                    info = infos.get(p)
                    print(f"  {p}: skipped: {skipped.get(p, 'not run')}" if info is None else
                          f"  {p}: {info['version']}, Python {info['python']} (venv), "
                          f"{info['threads']}, {info['precision']}, Provot: {info['provot']}")
                print(f"one simulated second = {case.frames} frames x "
                      f"{case.steps // case.frames} steps = {case.steps} steps; median and min: "
                      "seconds per simulated second over the rounds; steps/s from the median; "
                      "|x - ours|: max distance (m) to our final positions")
                print(f"{'grid':9s} {'simulator':15s} {'median':>9s} {'min':>9s} "
                      f"{'steps/s':>9s} {'warm-up s':>9s} {'|x - ours|':>11s}")
            summary.append(report(case, peers, skipped, args.precision))
    if len([s for s in summary if s]) > 1:
        print("summary:")
        for line in filter(None, summary):
            print("  " + line)


if __name__ == "__main__":
    main()
