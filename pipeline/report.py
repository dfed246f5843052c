"""`render report`: one HTML page comparing shaders, times and parameter values side by side.

    render report SCENE.json --out report.html [--shaders all|a,b,c] [--at 0,1.5,3]
                  [--size WxH] [--aa N] [--set k=v ...] [--sweep cloth.ks=500,5000,50000 ...]
                  [--shader NAME] [--gif] [--jobs N]

Two kinds of report:

* Shader report (no --sweep): the scene is simulated once; the simulator frames nearest to
  the chosen times (default 0, mid and end of --duration, 3 s) are rendered with every
  chosen shader. Grid: one row per time, one column per shader.
* Sweep report (one or more --sweep KEY=V1,V2,...): one scene variant per value (the
  product of the sweeps), each simulated once, in parallel processes
  (a multiprocessing pool, --jobs, default os.cpu_count()), rendered with one shader
  (--shader, default the scene's render.shader: phong). One sweep: rows are its values,
  columns the times (default: only the end time). Two sweeps: rows the first, columns the
  second, one grid per time. More sweeps: one such grid per combination of the values of
  the third and later sweeps (a list of grids), per time.

Outputs, all written atomically (temp file beside the target, renamed at the end):
  OUT.html  self-contained: every image embedded as a base64 data URI (one file to copy,
            mail or attach to a CI run; nothing to keep in sync beside it);
  OUT.png   contact sheet of the same grids, labels drawn with Pillow's default font;
  OUT.gif   with --gif: an animated grid of the whole animation (0 to the last time) at a
            small size (--gif-size, default 128x128; --gif-fps, default 10), also embedded
            in the HTML.

A variant whose simulation diverges is shown as a labelled cell carrying the divergence
message (its frames before the blow-up are still shown); the report is still written and
the exit status stays 0 (a warning goes to stderr). Exit status: 0 ok, 1 internal failure,
2 bad input (checked before any simulation; nothing written), 130 interrupted.

Entry points: `add_arguments(parser)` + `run(args)` (for a `render report` sub-command),
`main(argv)` (its own parser). Library use: `build_report(...)`, `simulate_variant(...)`.
"""
from __future__ import annotations

import argparse
import base64
import html
import io
import itertools
import json
import math
import multiprocessing
import os
import sys
import time
import traceback
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

from . import cli as _cli
from . import outputs, signals
from .outputs import OutputError
from .progress import bar, progress_enabled

PROG = "render report"
DEFAULT_DURATION = 3.0
DEFAULT_SIZE = (256, 256)
DEFAULT_GIF_SIZE = (128, 128)
DEFAULT_GIF_FPS = 10.0

# Contact-sheet layout (pixels). See `sheet_size`.
PAD = 6  # gap between cells and around the sheet
LINE_H = 12  # one line of Pillow's default font (size 10)
TITLE_H = LINE_H + 2 * PAD  # band holding a grid's title
CAPTION_H = LINE_H + 2  # one line under each cell (render time, or "diverged")
ROW_LABEL_MIN = 72  # minimum width of the row-label column
BACKGROUND = (255, 255, 255)
INK = (20, 20, 20)
DIVERGED_BG = (90, 30, 30)


# --------------------------------------------------------------------------- arguments


def _times(text: str) -> list[float]:
    items = [s.strip() for s in text.split(",")]
    out = []
    for s in items:
        try:
            v = float(s)
        except ValueError:
            raise argparse.ArgumentTypeError(
                f"expected times in seconds separated by commas such as 0,1.5,3, got {text!r}"
            ) from None
        if not (math.isfinite(v) and v >= 0):
            raise argparse.ArgumentTypeError(f"expected times >= 0 seconds, got {s!r}")
        if v in out:
            raise argparse.ArgumentTypeError(f"time {s} is given twice in {text!r}")
        out.append(v)
    return sorted(out)


def _names(text: str) -> list[str]:
    items = [s.strip() for s in text.split(",")]
    if not text.strip() or any(not s for s in items):
        raise argparse.ArgumentTypeError(f"expected shader names separated by commas, or "
                                         f"'all', got {text!r}")
    return items


def split_values(text: str) -> list[str]:
    """Split "500,5000,[0,1,0],\"a,b\"" at the commas outside brackets and quotes."""
    out, depth, quote, cur, esc = [], 0, False, [], False
    for ch in text:
        if quote:
            cur.append(ch)
            if esc:
                esc = False
            elif ch == "\\":
                esc = True
            elif ch == '"':
                quote = False
            continue
        if ch == '"':
            quote = True
        elif ch in "[{":
            depth += 1
        elif ch in "]}":
            depth -= 1
        elif ch == "," and depth == 0:
            out.append("".join(cur).strip())
            cur = []
            continue
        cur.append(ch)
    out.append("".join(cur).strip())
    return out


@dataclass(frozen=True)
class Sweep:
    """One --sweep: a dotted scene key and the raw text of each value (parsed as JSON by
    the scene loader, like --set)."""

    key: str
    values: tuple[str, ...]

    def override(self, i: int) -> str:
        return f"{self.key}={self.values[i]}"

    def label(self, i: int) -> str:
        return f"{self.key} = {self.values[i]}"


def parse_sweep(text: str) -> Sweep:
    """"cloth.ks=500,5000,50000" -> Sweep("cloth.ks", ("500", "5000", "50000"))."""
    key, eq, vals = text.partition("=")
    key = key.strip()
    parts = key.split(".")
    if not eq or not key or any(not p.strip() for p in parts):
        raise argparse.ArgumentTypeError(
            f"expected --sweep dotted.key=V1,V2,... such as cloth.ks=500,5000,50000, got {text!r}")
    values = split_values(vals)
    if any(not v for v in values):
        raise argparse.ArgumentTypeError(
            f"--sweep {text!r}: empty value (expected values separated by commas)")
    if len(set(values)) != len(values):
        raise argparse.ArgumentTypeError(f"--sweep {text!r}: a value is given twice")
    return Sweep(key, tuple(values))


def _sweep_type(text: str) -> Sweep:
    return parse_sweep(text)


_sweep_type.__name__ = "sweep"


def add_arguments(p: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """Add the report's arguments to `p` (a fresh parser or a `report` sub-parser)."""
    p.add_argument("scene", metavar="SCENE.json", help="scene file (JSON)")
    p.add_argument("--out", "-o", metavar="REPORT.html", required=True,
                   help="the HTML page to write; REPORT.png (contact sheet) and, with --gif, "
                        "REPORT.gif are written beside it")
    p.add_argument("--shaders", type=_names, metavar="all|A,B,...",
                   help="shaders to compare (default: all)")
    p.add_argument("--shader", "-s", type=_names, metavar="NAME",
                   help="the shader of a --sweep report (default: the scene's render.shader, "
                        "phong); without --sweep, the same as --shaders")
    p.add_argument("--at", type=_times, metavar="T1,T2,...",
                   help="times in seconds (default: 0, the middle and the end of --duration; "
                        "for a --sweep report the end only)")
    p.add_argument("--duration", "-d", type=_cli._positive_float("duration"), metavar="S",
                   help=f"seconds of animation (default {DEFAULT_DURATION:g}; with --at: the "
                        "last --at time)")
    p.add_argument("--size", type=_cli._size, metavar="WxH",
                   help=f"size of each image (default {DEFAULT_SIZE[0]}x{DEFAULT_SIZE[1]})")
    p.add_argument("--aa", type=_cli._positive_int, metavar="N",
                   help="anti-aliasing: N x N samples per pixel (default: the scene's, 1)")
    p.add_argument("--set", dest="overrides", action="append", default=[],
                   type=_cli._override, metavar="KEY=VALUE",
                   help="override a scene value (repeatable; VALUE is JSON, else a string)")
    p.add_argument("--sweep", dest="sweeps", action="append", default=[], type=_sweep_type,
                   metavar="KEY=V1,V2,...",
                   help="render one variant per value; the first --sweep goes along rows, the "
                        "second along columns, later ones make one grid per combination")
    p.add_argument("--gif", action="store_true",
                   help="also write REPORT.gif: the whole animation as one animated grid")
    p.add_argument("--gif-size", type=_cli._size, metavar="WxH",
                   help=f"cell size of the GIF grid (default "
                        f"{DEFAULT_GIF_SIZE[0]}x{DEFAULT_GIF_SIZE[1]})")
    p.add_argument("--gif-fps", type=_cli._positive_float("gif-fps"), metavar="F",
                   help=f"frame rate of the GIF grid (default {DEFAULT_GIF_FPS:g}, at most "
                        f"{outputs.GIF_MAX_FPS:g})")
    p.add_argument("--jobs", "-j", type=_cli._positive_int, metavar="N",
                   help="parallel simulations of a sweep (default: os.cpu_count())")
    _cli.add_cluster_options(p)
    p.add_argument("--title", metavar="TEXT", help="page title (default: the scene file name)")
    p.add_argument("--quiet", "-q", action="store_true",
                   help="no progress bars, warnings or summary line")
    p.add_argument("--debug", action="store_true", help="show tracebacks on errors")
    return p


def build_parser() -> argparse.ArgumentParser:
    p = _cli._Parser(
        prog=PROG,
        description="Simulate a scene and write an HTML report comparing shaders, times and "
                    "parameter values side by side, with a contact-sheet PNG beside it.",
        epilog="Exit status: 0 ok (also when a sweep variant diverges: its cells say so), "
               "1 internal failure, 2 bad input, 130 interrupted. See docs/report.md.",
        allow_abbrev=False,
    )
    return add_arguments(p)


# --------------------------------------------------------------------------- planning


@dataclass
class Variant:
    """One scene variant: the sweep overrides that make it and its loaded scene."""

    index: int
    sweep_values: tuple[int, ...]  # value index per sweep
    overrides: tuple[str, ...]  # the sweep's overrides only (after --set)
    label: str  # "cloth.ks = 500, cloth.damping = 0.2" ("" without sweeps)
    scene: object = None


@dataclass
class ReportPlan:
    scene_path: str
    out: Path
    sheet: Path
    gif: Path | None
    shaders: list[str]
    times: list[float]  # requested times (s)
    sim_frames: list[int]  # simulator frame nearest to each time
    sim_fps: float
    width: int
    height: int
    aa: int | None
    overrides: list[str]
    sweeps: list[Sweep]
    variants: list[Variant]
    gif_size: tuple[int, int] = DEFAULT_GIF_SIZE
    gif_fps: float = DEFAULT_GIF_FPS
    gif_times: list[float] = field(default_factory=list)
    gif_frames: list[int] = field(default_factory=list)
    #: simulator frames of the whole shot, 0 to the last time, at `render`'s default rate
    #: (and every needed frame): a scene with no camera is framed over these, as `render`
    #: frames its shot
    shot_frames: list[int] = field(default_factory=list)
    jobs: int = 1
    title: str = ""
    workers: int | None = None  # --workers: simulate on a LocalCluster of this many
    scheduler: str | None = None  # --scheduler: simulate on that Dask cluster
    cluster: str = ""  # where the simulations ran, when on Dask ("2 Dask workers")

    @property
    def needed_frames(self) -> list[int]:
        return sorted(set(self.sim_frames) | set(self.gif_frames))

    @property
    def image_sizes(self) -> list[tuple[int, int]]:
        """The sizes of the cells and of the GIF's frames."""
        return sorted({(self.width, self.height), tuple(self.gif_size)})


def _shader_list(names: list[str] | None, available: Sequence[str]) -> list[str]:
    if names is None or names == ["all"]:
        return list(available)
    out = []
    for n in names:
        if n == "all":
            raise _cli.UsageError("'all' cannot be combined with other shader names")
        if n not in available:
            raise _cli.UsageError(f"unknown shader {n!r} (choose from: {', '.join(available)})")
        if n not in out:
            out.append(n)
    return out


def _output_paths(out: str, gif: bool) -> tuple[Path, Path, Path | None]:
    if not out:
        raise _cli.UsageError("--out: empty path")
    p = Path(out)
    if p.suffix.lower() not in (".html", ".htm"):
        raise _cli.UsageError(f"--out '{out}': expected a file name ending in .html")
    if p.is_dir():
        raise _cli.UsageError(f"--out '{out}': it is a directory")
    parent = p.parent if str(p.parent) else Path(".")
    if not parent.is_dir():
        raise _cli.UsageError(f"--out '{out}': directory '{parent}' does not exist")
    return p, p.with_suffix(".png"), (p.with_suffix(".gif") if gif else None)


def plan_report(args) -> ReportPlan:
    """Check every flag and load every scene variant; raises UsageError / SceneError.

    Nothing is simulated, rendered or written here.
    """
    from shading import SHADERS

    from .scene import load_scene

    out, sheet, gif = _output_paths(args.out, args.gif)
    sweeps: list[Sweep] = list(args.sweeps)
    keys = [s.key for s in sweeps]
    for k in keys:
        if keys.count(k) > 1:
            raise _cli.UsageError(f"--sweep {k}: the same key is swept twice")
    if sweeps:
        if args.shaders is not None:
            raise _cli.UsageError("a --sweep report uses one shader: give --shader NAME, "
                                  "not --shaders")
        if args.shader is not None and len(args.shader) != 1:
            raise _cli.UsageError("a --sweep report uses one shader: give --shader NAME")
    elif args.shader is not None and args.shaders is not None:
        raise _cli.UsageError("give --shaders or --shader, not both")
    if args.gif_fps is not None and args.gif_fps > outputs.GIF_MAX_FPS:
        raise _cli.UsageError(f"--gif-fps {args.gif_fps:g} is too high for a GIF: use at most "
                              f"{outputs.GIF_MAX_FPS:g}")
    if (args.gif_size is not None or args.gif_fps is not None) and not args.gif:
        raise _cli.UsageError("--gif-size and --gif-fps need --gif")
    if args.jobs is not None and _cli.cluster_requested(args):
        raise _cli.UsageError("give --jobs (processes here) or --workers / --scheduler (Dask), "
                              "not both")

    duration = args.duration if args.duration is not None else None
    if args.at is not None:
        times = list(args.at)
        if duration is not None and times[-1] > duration:
            raise _cli.UsageError(f"--at {times[-1]:g} is beyond --duration {duration:g}")
        if duration is None:
            duration = times[-1]
    else:
        duration = DEFAULT_DURATION if duration is None else duration
        times = [0.0, duration / 2, duration] if not sweeps else [duration]

    base = load_scene(args.scene, list(args.overrides))
    if sweeps:
        wanted = args.shader if args.shader is not None else [base.render.shader]
    else:
        wanted = args.shaders if args.shaders is not None else args.shader
    shaders = _shader_list(wanted, tuple(SHADERS))

    variants = []
    combos = itertools.product(*[range(len(s.values)) for s in sweeps]) if sweeps else [()]
    for idx, combo in enumerate(combos):
        ov = tuple(s.override(i) for s, i in zip(sweeps, combo))
        scene = load_scene(args.scene, list(args.overrides) + list(ov)) if ov else base
        label = ", ".join(s.label(i) for s, i in zip(sweeps, combo))
        variants.append(Variant(idx, tuple(combo), ov, label, scene))
    fps_set = {float(v.scene.simulation.frames_per_sec) for v in variants}
    if len(fps_set) != 1:
        raise _cli.UsageError("the variants of a sweep must share simulation.frames_per_sec")
    sim_fps = fps_set.pop()

    width, height = args.size if args.size is not None else DEFAULT_SIZE
    gif_times, gif_frames = [], []
    gif_size = args.gif_size or DEFAULT_GIF_SIZE
    gif_fps = args.gif_fps or DEFAULT_GIF_FPS
    if args.gif:
        n = max(1, round(max(times) * gif_fps))
        ts = _cli.output_times(n, gif_fps)
        gif_times = [float(t) for t in ts]
        gif_frames = _cli.nearest_sim_frames(ts, sim_fps)
    sim_frames = _cli.nearest_sim_frames(times, sim_fps)
    # the shot a scene with no camera is framed over: max(times) seconds as `render`
    # animates them by default (so a cell is the frame `render --at` draws at that time)
    fps = _cli.DEFAULT_FPS["gif"]
    shot = _cli.nearest_sim_frames(_cli.output_times(max(1, round(max(times) * fps)), fps),
                                   sim_fps)
    jobs = args.jobs if args.jobs is not None else (os.cpu_count() or 1)
    return ReportPlan(
        scene_path=os.fspath(args.scene), out=out, sheet=sheet, gif=gif, shaders=shaders,
        times=times, sim_frames=sim_frames, sim_fps=sim_fps,
        width=int(width), height=int(height), aa=args.aa, overrides=list(args.overrides),
        sweeps=sweeps, variants=variants, gif_size=gif_size, gif_fps=gif_fps,
        gif_times=gif_times, gif_frames=gif_frames,
        shot_frames=sorted(set(shot) | set(sim_frames) | set(gif_frames)),
        jobs=max(1, jobs),
        title=args.title or Path(args.scene).name, workers=args.workers,
        scheduler=args.scheduler)


# --------------------------------------------------------------------------- simulating


@dataclass
class VariantRun:
    """What a simulation produced: positions (N, 3) at each wanted frame it reached."""

    positions: dict[int, np.ndarray]
    error: str | None  # divergence message; frames after it are missing
    warnings: list[str]
    seconds: float  # wall time of the simulation
    #: {(width, height): pipeline.framing.Framing} of the shot's frames it reached (a scene
    #: with no camera; empty otherwise)
    framings: dict = field(default_factory=dict)


def simulate_variant(scene_path: str, overrides: Sequence[str], frames: Sequence[int],
                     threads: int | None = None,
                     on_frame: Callable[[], None] | None = None,
                     shot: Sequence[int] = (), sizes: Sequence[tuple[int, int]] = ()
                     ) -> VariantRun:
    """Simulate one variant frame by frame (as `render` does) up to max(frames), keeping a
    copy of the positions at each frame in `frames`, and, for a scene with no camera, the
    framing (pipeline.framing) of the frames in `shot` for each image size in `sizes`.
    Runs in a worker process for sweeps: every argument and the result are picklable (on
    Dask `scene_path` is the file's bytes, a SceneFile). `threads`: numba threads to use
    here (restored afterwards); the results do not depend on it."""
    if threads is None:
        return _simulate(scene_path, overrides, frames, on_frame, shot, sizes)
    from .simulation import numba_threads

    with numba_threads(threads):
        return _simulate(scene_path, overrides, frames, on_frame, shot, sizes)


def _simulate(scene_path, overrides, frames, on_frame, shot, sizes) -> VariantRun:
    from .framing import Framing, framed_points
    from .scene import load_scene
    from .simulation import DivergenceError, Simulation

    t0 = time.perf_counter()
    wanted = sorted(set(int(f) for f in frames))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        scene = load_scene(scene_path, list(overrides))
        sim = Simulation(scene, shot_seconds=wanted[-1] / scene.simulation.frames_per_sec
                         if wanted else None)
    msgs = [str(w.message).splitlines()[0] for w in caught if str(w.message)]
    framed = set(shot) if scene.camera is None else set()
    framings = {tuple(size): Framing(*size) for size in sizes} if framed else {}

    def reached(j: int) -> None:
        if j in framed:
            points = framed_points(scene, sim.positions, j / scene.simulation.frames_per_sec)
            for framing in framings.values():
                framing.add(points)

    positions: dict[int, np.ndarray] = {}
    error = None
    current = 0
    reached(0)
    try:
        for j in wanted:
            while current < j:
                sim.advance(1)
                current += 1
                reached(current)
                if on_frame is not None:
                    on_frame()
            positions[j] = sim.positions.copy()
    except DivergenceError as exc:
        error = str(exc).strip().splitlines()[0]
    return VariantRun(positions, error, msgs, time.perf_counter() - t0, framings)


def _simulate_indexed(task: tuple) -> tuple[int, VariantRun]:
    """simulate_variant in a pool worker, keeping the variant's index with the result."""
    index, *args = task
    return index, simulate_variant(*args)


def run_simulations(plan: ReportPlan, jobs: int | None = None, progress=None
                    ) -> list[VariantRun]:
    """Every variant's simulation: one Dask task each with --workers / --scheduler, else
    in this process when there is one variant or one job, else in a pool of `jobs` spawned
    processes. Results do not depend on where they ran."""
    jobs = plan.jobs if jobs is None else jobs
    frames = plan.needed_frames
    n = len(plan.variants)
    if _cli.cluster_requested(plan):
        return _simulate_on_dask(plan, frames, progress)
    workers = max(1, min(jobs, n))
    if workers == 1:
        runs = []
        for v in plan.variants:
            tick = progress.update if (progress is not None and n == 1) else None
            # one numba thread, as `render` simulates (its "split" pipeline): on a small
            # cloth the kernels' thread barriers cost more than they save
            runs.append(simulate_variant(plan.scene_path, plan.overrides + list(v.overrides),
                                         frames, threads=1, on_frame=tick,
                                         shot=plan.shot_frames, sizes=plan.image_sizes))
            if progress is not None and n > 1:
                progress.update(1)
        return runs
    threads = max(1, (os.cpu_count() or 1) // workers)
    ctx = multiprocessing.get_context("spawn")  # fork after numba threads started is unsafe
    runs: list[VariantRun | None] = [None] * n
    tasks = [(v.index, plan.scene_path, plan.overrides + list(v.overrides), frames, threads,
              None, plan.shot_frames, plan.image_sizes) for v in plan.variants]
    with signals.deferred():  # every worker started and sent its set-up, or none
        pool = ctx.Pool(workers)
    try:
        for index, result in pool.imap_unordered(_simulate_indexed, tasks):
            runs[index] = result
            if progress is not None:
                progress.update(1)
        pool.close()
    finally:
        pool.terminate()  # on an error or a signal: no worker is left running
        pool.join()
    return runs  # type: ignore[return-value]


def _simulate_on_dask(plan: ReportPlan, frames: list[int], progress) -> list[VariantRun]:
    """One task per variant; each ships the scene file's bytes and the overrides."""
    import uuid

    import distributed

    from . import cluster
    from .scene import SceneFile

    scene = SceneFile.read(plan.scene_path)
    runs: list[VariantRun | None] = [None] * len(plan.variants)
    with cluster.connect(plan) as client:
        run = f"clothpipe-report-{uuid.uuid4().hex}"
        futures = {client.submit(simulate_variant, scene, plan.overrides + list(v.overrides),
                                 frames, 1, None, plan.shot_frames, plan.image_sizes,
                                 key=f"{run}-{v.index}"): v.index
                   for v in plan.variants}
        for future in distributed.as_completed(futures, loop=client.loop):
            runs[futures[future]] = future.result()
            if progress is not None:
                progress.update(1)
        plan.cluster = cluster.where(client, plan)
    return runs  # type: ignore[return-value]


# --------------------------------------------------------------------------- grids


@dataclass
class Cell:
    image: np.ndarray  # (H, W, 3) uint8 (a placeholder for a diverged frame)
    caption: str  # full caption (HTML)
    short: str  # one short line under the cell on the contact sheet
    attrs: dict  # data-* attributes of the HTML cell
    error: str | None = None


@dataclass
class Grid:
    title: str
    rows: list[str]  # row labels ("\n" separates lines)
    cols: list[str]  # column labels
    cells: list[list[Cell | None]]


# A grid of keys (variant index, shader, time index or None), from which both the still
# report (time index given) and the GIF (None: the time animates) are built.
KeyGrid = tuple[str, list[str], list[str], list[list[tuple[int, str, int | None]]]]


def _fmt_t(t: float) -> str:
    return f"t = {t:g} s"


def key_grids(plan: ReportPlan, animated: bool = False) -> list[KeyGrid]:
    """The layout of the report: a list of (title, row labels, column labels, keys)."""
    tidx: list[int | None] = [None] if animated else list(range(len(plan.times)))
    grids: list[KeyGrid] = []
    if not plan.sweeps:
        if animated:
            return [("", [plan.title], list(plan.shaders),
                     [[(0, s, None) for s in plan.shaders]])]
        rows = [f"{_fmt_t(plan.times[k])}\nframe {plan.sim_frames[k]}" for k in tidx]
        return [("Shaders", rows, list(plan.shaders),
                 [[(0, s, k) for s in plan.shaders] for k in tidx])]
    shader = plan.shaders[0]
    sw = plan.sweeps
    index = {v.sweep_values: v.index for v in plan.variants}
    row_labels = [f"{sw[0].key}\n= {val}" for val in sw[0].values]
    if len(sw) == 1:
        cols = ["animation" if k is None else _fmt_t(plan.times[k]) for k in tidx]
        keys = [[(index[(i,)], shader, k) for k in tidx] for i in range(len(sw[0].values))]
        return [(f"{sw[0].key} ({shader})", row_labels, cols, keys)]
    col_labels = [f"{sw[1].key}\n= {val}" for val in sw[1].values]
    rest = list(itertools.product(*[range(len(s.values)) for s in sw[2:]]))
    for extra in rest:
        for k in tidx:
            parts = [s.label(i) for s, i in zip(sw[2:], extra)]
            if k is not None:
                parts.append(_fmt_t(plan.times[k]))
            parts.append(shader)
            keys = [[(index[(i, j) + extra], shader, k) for j in range(len(sw[1].values))]
                    for i in range(len(sw[0].values))]
            grids.append((", ".join(parts), row_labels, col_labels, keys))
    return grids


def _font():
    from PIL import ImageFont

    return ImageFont.load_default()


def _text_w(draw, text: str, font) -> float:
    return max((draw.textlength(line, font=font) for line in text.split("\n")), default=0.0)


def _fit(draw, text: str, font, width: float) -> str:
    """Shorten one line with '...' in the middle until it fits `width` pixels."""
    if draw.textlength(text, font=font) <= width:
        return text
    keep = len(text)
    while keep > 2:
        keep -= 1
        a = (keep + 1) // 2
        b = keep - a
        s = text[:a] + "..." + (text[-b:] if b else "")
        if draw.textlength(s, font=font) <= width:
            return s
    return "..."


def _wrap(draw, text: str, font, width: float) -> list[str]:
    lines: list[str] = []
    for para in text.split("\n"):
        cur = ""
        for word in para.split(" "):
            trial = word if not cur else cur + " " + word
            if draw.textlength(trial, font=font) <= width or not cur:
                cur = trial
            else:
                lines.append(cur)
                cur = word
        lines.append(cur)
    return [_fit(draw, ln, font, width) for ln in lines]


def _short(message: str) -> str:
    """"simulation diverged at frame 36, step 1 of 1 (t = 0.4000 s): why; advice" ->
    the part before the first ": " (the whole message stays in the HTML caption)."""
    return message.split(": ", 1)[0]


def diverged_image(message: str, width: int, height: int) -> np.ndarray:
    """A dark red cell with the divergence message written on it (wrapped)."""
    from PIL import Image, ImageDraw

    im = Image.new("RGB", (width, height), DIVERGED_BG)
    d = ImageDraw.Draw(im)
    font = _font()
    text = message if "diverged" in message.lower() else "DIVERGED: " + message
    lines = _wrap(d, text, font, max(8, width - 8))
    for n, line in enumerate(lines[: max(1, (height - 8) // LINE_H)]):
        d.text((4, 4 + n * LINE_H), line, fill=(255, 235, 235), font=font)
    return np.asarray(im)


def row_label_width(grids: Sequence[Grid]) -> int:
    from PIL import Image, ImageDraw

    d = ImageDraw.Draw(Image.new("RGB", (1, 1)))
    font = _font()
    widest = max((_text_w(d, r, font) for g in grids for r in g.rows), default=0.0)
    return max(ROW_LABEL_MIN, int(math.ceil(widest)) + 2 * PAD)


def _header_h(g: Grid) -> int:
    return max((c.count("\n") + 1 for c in g.cols), default=1) * LINE_H + PAD


def sheet_size(grids: Sequence[Grid], width: int, height: int, captions: bool = True
               ) -> tuple[int, int]:
    """(W, H) in pixels of a contact sheet of `grids` with cells of width x height:

        W = L + C * (width + PAD) + PAD      L = row-label column (>= ROW_LABEL_MIN),
                                             C = the most columns of any grid
        H = sum over grids of (TITLE_H + header + R * (height + CAPTION_H + PAD)) + PAD
            header = (lines of the longest column label) * LINE_H + PAD; no CAPTION_H
            without captions (the GIF).
    """
    cols = max(len(g.cols) for g in grids)
    cap = CAPTION_H if captions else 0
    w = row_label_width(grids) + cols * (width + PAD) + PAD
    h = sum(TITLE_H + _header_h(g) + len(g.rows) * (height + cap + PAD) for g in grids) + PAD
    return w, h


class SheetCanvas:
    """The labelled grids drawn once; `compose(images)` pastes cell images into a copy."""

    def __init__(self, grids: Sequence[Grid], width: int, height: int, captions: bool = True,
                 title_suffix: str = ""):
        from PIL import Image, ImageDraw

        self.grids = grids
        self.cw, self.ch = width, height
        self.captions = captions
        self.size = sheet_size(grids, width, height, captions)
        base = Image.new("RGB", self.size, BACKGROUND)
        d = ImageDraw.Draw(base)
        font = _font()
        lw = row_label_width(grids)
        cap = CAPTION_H if captions else 0
        self.slots: list[list[list[tuple[int, int]]]] = []
        self.title_boxes: list[tuple[int, int]] = []
        y = 0
        for g in grids:
            self.title_boxes.append((PAD, y + PAD))
            if g.title:
                d.text((PAD, y + PAD), _fit(d, g.title, font, self.size[0] - 2 * PAD),
                       fill=INK, font=font)
            y += TITLE_H
            hh = _header_h(g)
            for c, label in enumerate(g.cols):
                x0 = lw + c * (width + PAD)
                lines = [_fit(d, ln, font, width + PAD - 2) for ln in label.split("\n")]
                for n, ln in enumerate(lines):
                    tw = d.textlength(ln, font=font)
                    d.text((x0 + (width - tw) / 2, y + n * LINE_H), ln, fill=INK, font=font)
            y += hh
            slots = []
            for r, label in enumerate(g.rows):
                lines = _wrap(d, label, font, lw - 2 * PAD)
                ty = y + (height - len(lines) * LINE_H) / 2
                for n, ln in enumerate(lines):
                    d.text((PAD, ty + n * LINE_H), ln, fill=INK, font=font)
                row = []
                for c in range(len(g.cols)):
                    x0 = lw + c * (width + PAD)
                    row.append((x0, y))
                    cell = g.cells[r][c]
                    if captions and cell is not None and cell.short:
                        s = _fit(d, cell.short, font, width)
                        tw = d.textlength(s, font=font)
                        d.text((x0 + (width - tw) / 2, y + height + 1), s,
                               fill=(170, 20, 20) if cell.error else INK, font=font)
                slots.append(row)
                y += height + cap + PAD
            self.slots.append(slots)
        self.base = base
        self.font = font

    def compose(self, images: Sequence[Sequence[Sequence[np.ndarray | None]]] | None = None,
                title: str | None = None) -> np.ndarray:
        """The sheet with `images[g][r][c]` (default: the grids' cell images) pasted in;
        `title` replaces every grid title (the GIF's running time)."""
        from PIL import Image, ImageDraw

        im = self.base.copy()
        if title is not None:
            d = ImageDraw.Draw(im)
            for (x, y), g in zip(self.title_boxes, self.grids):
                label = f"{g.title}   {title}" if g.title else title
                d.text((x, y), _fit(d, label, self.font, self.size[0] - 2 * PAD), fill=INK,
                       font=self.font)
        for gi, g in enumerate(self.grids):
            for r in range(len(g.rows)):
                for c in range(len(g.cols)):
                    img = (images[gi][r][c] if images is not None
                           else (g.cells[r][c].image if g.cells[r][c] is not None else None))
                    if img is None:
                        continue
                    x, y = self.slots[gi][r][c]
                    im.paste(Image.fromarray(np.ascontiguousarray(img), "RGB"), (x, y))
        return np.asarray(im)


# --------------------------------------------------------------------------- rendering


@dataclass
class Report:
    plan: ReportPlan
    runs: list[VariantRun]
    grids: list[Grid]
    sheet: np.ndarray
    gif_frames: list[np.ndarray]  # composed GIF frames (empty without --gif)
    timings: dict


def _renderer(plan: ReportPlan, runs: Sequence[VariantRun]):
    from .frames import render_frame
    from .model import build_model

    models = {}
    shots = frame_shots(plan, runs)

    def render(vi: int, sim_frame: int, positions: np.ndarray, shader: str, w: int,
               h: int) -> np.ndarray:
        v = plan.variants[vi]
        if vi not in models:
            models[vi] = build_model(v.scene)
        return render_frame(v.scene, positions, models[vi], shader=shader, width=w, height=h,
                            aa=plan.aa, time=sim_frame / plan.sim_fps, shot=shots[w, h])

    return render


def frame_shots(plan: ReportPlan, runs: Sequence[VariantRun]) -> dict:
    """{(width, height): pipeline.framing.Framing} for the cells and the GIF frames: the
    whole shot (plan.shot_frames) of every variant with no camera, framed where it ran, so
    those variants share one view."""
    from .framing import Framing

    shots = {size: Framing(*size) for size in plan.image_sizes}
    for run in runs:
        for size, framing in run.framings.items():
            shots[size].include(framing)
    return shots


def warm_up(plan: ReportPlan) -> None:
    """Render a 16x16 frame with every shader (untimed) so the kernels are compiled before
    the render times are measured, and a broken shader or missing texture fails early."""
    from .frames import render_frame
    from .model import build_model

    v = plan.variants[0]
    model = build_model(v.scene)
    for s in plan.shaders:
        render_frame(v.scene, model.initial_positions.copy(), model, shader=s, width=16,
                     height=16, aa=1)


def build_grids(plan: ReportPlan, runs: Sequence[VariantRun], progress=None) -> list[Grid]:
    """Render every cell of the report (main process; render times measured here)."""
    render = _renderer(plan, runs)
    grids = []
    for title, rows, cols, keys in key_grids(plan):
        cells = []
        for row in keys:
            out_row = []
            for vi, shader, k in row:
                v, run = plan.variants[vi], runs[vi]
                t, j = plan.times[k], plan.sim_frames[k]
                attrs = {"shader": shader, "time": f"{t:g}", "frame": str(j),
                         "sim-time": f"{j / plan.sim_fps:.6g}"}
                if v.label:
                    attrs["variant"] = v.label
                    attrs["overrides"] = json.dumps(list(v.overrides))
                head = (f"{v.label} · " if v.label else "") + f"{shader} · {_fmt_t(t)}"
                if j in run.positions:
                    t0 = time.perf_counter()
                    img = render(vi, j, run.positions[j], shader, plan.width, plan.height)
                    ms = (time.perf_counter() - t0) * 1000
                    attrs["ms"] = f"{ms:.1f}"
                    cell = Cell(img, f"{head} · {ms:.1f} ms/frame", f"{ms:.1f} ms", attrs)
                else:
                    msg = run.error or "not simulated"
                    attrs["diverged"] = "1"
                    cell = Cell(diverged_image(_short(msg), plan.width, plan.height),
                                f"{head} · diverged: {_short(msg)}", "diverged", attrs,
                                error=msg)
                out_row.append(cell)
                if progress is not None:
                    progress.update(1)
            cells.append(out_row)
        grids.append(Grid(title, rows, cols, cells))
    return grids


def build_gif_frames(plan: ReportPlan, runs: Sequence[VariantRun], progress=None
                     ) -> list[np.ndarray]:
    """The animated grid: one composed image per GIF frame (cells plan.gif_size)."""
    render = _renderer(plan, runs)
    gw, gh = plan.gif_size
    layout = key_grids(plan, animated=True)
    grids = [Grid(t, r, c, [[None] * len(c) for _ in r]) for t, r, c, _ in layout]
    canvas = SheetCanvas(grids, gw, gh, captions=False)
    placeholders: dict[int, np.ndarray] = {}
    frames = []
    for t, j in zip(plan.gif_times, plan.gif_frames):
        images = []
        for _, _, _, keys in layout:
            g_imgs = []
            for row in keys:
                r_imgs = []
                for vi, shader, _ in row:
                    run = runs[vi]
                    if j in run.positions:
                        r_imgs.append(render(vi, j, run.positions[j], shader, gw, gh))
                    else:
                        if vi not in placeholders:
                            placeholders[vi] = diverged_image(
                                _short(run.error or "not simulated"), gw, gh)
                        r_imgs.append(placeholders[vi])
                g_imgs.append(r_imgs)
            images.append(g_imgs)
        frames.append(canvas.compose(images, title=f"t = {t:.2f} s"))
        if progress is not None:
            progress.update(1)
    return frames


def build_report(plan: ReportPlan, runs: Sequence[VariantRun] | None = None,
                 show_progress: bool = False) -> Report:
    """Simulate (unless `runs` are given), render every cell and compose the sheets."""
    timings = {}
    t0 = time.perf_counter()
    warm_up(plan)
    timings["warm-up"] = time.perf_counter() - t0
    if runs is None:
        n = len(plan.variants)
        by_frame = n == 1 and not _cli.cluster_requested(plan)  # else one tick per variant
        sim_bar = bar(plan.needed_frames[-1] if by_frame else n, "simulate",
                      "frame" if by_frame else "variant", show_progress, 0)
        t0 = time.perf_counter()
        try:
            runs = run_simulations(plan, progress=sim_bar)
        finally:
            sim_bar.close()
        timings["simulate"] = time.perf_counter() - t0
    n_cells = sum(len(r) * len(c) for _, r, c, _ in key_grids(plan))
    rbar = bar(n_cells + len(plan.gif_times), "render", "image", show_progress, 1)
    try:
        t0 = time.perf_counter()
        grids = build_grids(plan, runs, rbar)
        sheet = SheetCanvas(grids, plan.width, plan.height).compose()
        gif_frames = build_gif_frames(plan, runs, rbar) if plan.gif is not None else []
        timings["render"] = time.perf_counter() - t0
    finally:
        rbar.close()
    return Report(plan, list(runs), grids, sheet, gif_frames, timings)


# --------------------------------------------------------------------------- HTML


def _png_bytes(image: np.ndarray) -> bytes:
    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(image), "RGB").save(buf, format="PNG",
                                                              optimize=False, compress_level=9)
    return buf.getvalue()


def _data_uri(data: bytes, mime: str) -> str:
    return f"data:{mime};base64,{base64.b64encode(data).decode('ascii')}"


_CSS = """
body{font-family:system-ui,-apple-system,"Segoe UI",Roboto,sans-serif;margin:1.5em;
color:#222;background:#fafafa}
h1{font-size:1.4em;margin:0 0 .3em}h2{font-size:1.1em;margin:1.4em 0 .4em}
table.grid{border-collapse:collapse}
table.grid th{font-weight:600;font-size:.85em;padding:.3em .5em;white-space:pre}
table.grid th[scope=row]{text-align:right;vertical-align:middle}
table.grid td{padding:4px;vertical-align:top}
figure{margin:0}figure img{display:block;background:#333}
figcaption{font-size:.75em;color:#444;max-width:var(--w);overflow-wrap:break-word;
margin-top:2px}
figure.diverged figcaption{color:#a01010}
figcaption details{color:#444}figcaption summary{cursor:pointer}
dl.meta{display:grid;grid-template-columns:max-content auto;gap:.15em 1em;font-size:.85em;
margin:.5em 0}dl.meta dt{color:#666}dl.meta dd{margin:0;font-family:monospace}
p.note{font-size:.85em;color:#555}
"""


def render_html(report: Report, sheet_name: str, gif_name: str | None,
                gif_data: bytes | None) -> str:
    plan = report.plan
    esc = html.escape
    cw = plan.width
    out = ["<!DOCTYPE html>", '<html lang="en">', "<head>", '<meta charset="utf-8">',
           '<meta name="viewport" content="width=device-width, initial-scale=1">',
           f"<title>{esc(plan.title)} - render report</title>",
           f"<style>{_CSS}</style>", "</head>", "<body>",
           f"<h1>{esc(plan.title)}</h1>"]
    meta = [("scene", plan.scene_path),
            ("overrides", " ".join(plan.overrides) or "(none)"),
            ("shaders", ", ".join(plan.shaders)),
            ("times (s)", ", ".join(f"{t:g}" for t in plan.times)
             + f"  (simulator frames {', '.join(map(str, plan.sim_frames))} at "
               f"{plan.sim_fps:g} fps)"),
            ("image size", f"{plan.width}x{plan.height}, aa "
                           f"{plan.aa if plan.aa is not None else 'scene default'}")]
    if plan.sweeps:
        for n, s in enumerate(plan.sweeps):
            where = ("rows" if n == 0 else "columns" if n == 1 else "one grid per value")
            meta.append((f"sweep {n + 1} ({where})", f"{s.key} = {', '.join(s.values)}"))
        meta.append(("processes", plan.cluster
                      or str(max(1, min(plan.jobs, len(plan.variants))))))
    for v, run in zip(plan.variants, report.runs):
        name = f"simulation{' ' + v.label if v.label else ''}"
        status = f"{run.seconds:.2f} s" + (f"; diverged: {run.error}" if run.error else "")
        for w in run.warnings:
            status += f"; warning: {w}"
        meta.append((name, status))
    meta.append(("generated", time.strftime("%Y-%m-%d %H:%M:%S")))
    out.append('<dl class="meta">')
    for k, v in meta:
        out.append(f"<dt>{esc(k)}</dt><dd>{esc(v)}</dd>")
    out.append("</dl>")
    out.append(f'<p class="note">Render times are wall-clock milliseconds for one frame in '
               f'this process (kernels compiled beforehand). Contact sheet: '
               f'<a href="{esc(sheet_name)}">{esc(sheet_name)}</a>.</p>')
    for gi, g in enumerate(report.grids):
        out.append(f'<section class="report-grid" data-grid="{gi}">')
        if g.title:
            out.append(f"<h2>{esc(g.title)}</h2>")
        out.append(f'<table class="grid" style="--w:{cw}px">')
        out.append("<thead><tr><th></th>" + "".join(
            f'<th scope="col">{esc(c)}</th>' for c in g.cols) + "</tr></thead><tbody>")
        for r, label in enumerate(g.rows):
            out.append(f'<tr><th scope="row">{esc(label)}</th>')
            for cell in g.cells[r]:
                assert cell is not None
                attrs = " ".join(f'data-{k}="{esc(v)}"' for k, v in cell.attrs.items())
                cls = "cell diverged" if cell.error else "cell"
                uri = _data_uri(_png_bytes(cell.image), "image/png")
                more = (f"<details><summary>why</summary>{esc(cell.error)}</details>"
                        if cell.error and cell.error != _short(cell.error) else "")
                out.append(f'<td><figure class="{cls}" {attrs}>'
                           f'<img src="{uri}" width="{plan.width}" height="{plan.height}" '
                           f'alt="{esc(cell.caption)}">'
                           f"<figcaption>{esc(cell.caption)}{more}</figcaption></figure></td>")
            out.append("</tr>")
        out.append("</tbody></table></section>")
    if gif_data is not None:
        gh, gw = report.gif_frames[0].shape[:2]
        out.append('<section class="animation"><h2>Animation</h2>')
        out.append(f'<p class="note">The whole animation, {len(report.gif_frames)} frames at '
                   f'{plan.gif_fps:g} fps (also in <a href="{esc(gif_name or "")}">'
                   f'{esc(gif_name or "")}</a>).</p>')
        out.append(f'<img class="gif" src="{_data_uri(gif_data, "image/gif")}" width="{gw}" '
                   f'height="{gh}" alt="animated grid">')
        out.append("</section>")
    out += ["</body>", "</html>", ""]
    return "\n".join(out)


class TextWriter(outputs._Atomic):  # noqa: SLF001 - the project's atomic-write base
    """An atomic text (UTF-8) file: temp file beside the target, renamed on commit."""

    def __init__(self, target):
        super().__init__(target)
        self.text: str | None = None

    def _add(self, text: str) -> None:
        self.text = text
        self.count += 1

    def _finish(self) -> None:
        if self.text is None:
            raise RuntimeError("nothing to write")
        with open(self.tmp, "w", encoding="utf-8", newline="\n") as fh:
            fh.write(self.text)


def _open_writers(plan: ReportPlan) -> dict:
    w = {}
    try:
        w["html"] = TextWriter(plan.out)
        w["png"] = outputs.PngWriter(plan.sheet)
        if plan.gif is not None:
            w["gif"] = outputs.GifWriter(plan.gif, fps=plan.gif_fps)
    except BaseException:
        for writer in w.values():
            writer.abort()
        raise
    return w


def write_report(report: Report, writers: dict) -> None:
    """Fill the writers and commit them (HTML last, so it never links to a missing PNG)."""
    plan = report.plan
    writers["png"].add(report.sheet)
    gif_data = None
    if "gif" in writers:
        for frame in report.gif_frames:
            writers["gif"].add(frame)
        writers["gif"].commit()
        gif_data = Path(plan.gif).read_bytes()
    writers["png"].commit()
    writers["html"].add(render_html(report, plan.sheet.name,
                                    plan.gif.name if plan.gif else None, gif_data))
    writers["html"].commit()


# --------------------------------------------------------------------------- entry points


def _execute(args, err) -> int:
    t_wall = time.perf_counter()
    plan = plan_report(args)  # all bad input is reported here, before any work
    writers = _open_writers(plan)
    try:
        report = build_report(plan, show_progress=progress_enabled(args.quiet))
        write_report(report, writers)
    except BaseException:
        for w in writers.values():
            w.abort()
        raise
    for v, run in zip(plan.variants, report.runs):
        where = f"{v.label}: " if v.label else ""
        for w in run.warnings:
            err.warn(f"{where}{w}")
        if run.error:
            err.warn(f"{where}{run.error} (shown in the report)")
    if not args.quiet:
        what = [writers["html"].target, writers["png"].target]
        if "gif" in writers:
            what.append(writers["gif"].target)
        sizes = ", ".join(f"{p} ({_cli._fmt_bytes(p.stat().st_size)})" for p in what)
        n_img = sum(len(g.rows) * len(g.cols) for g in report.grids)
        tm = report.timings
        err.say(f"report: {n_img} image{'s' * (n_img != 1)} {plan.width}x{plan.height}, "
                f"{len(plan.variants)} simulation{'s' * (len(plan.variants) != 1)} -> {sizes}; "
                f"simulate {tm.get('simulate', 0):.2f} s, render {tm.get('render', 0):.2f} s, "
                f"total {time.perf_counter() - t_wall:.2f} s")
    return 0


def run(args) -> int:
    """Run a parsed report command line (from `add_arguments`); returns the exit status."""
    stderr = sys.stderr
    err = _cli._Errors(stderr, quiet=getattr(args, "quiet", False),
                       debug=getattr(args, "debug", False))
    from .scene import SceneError

    try:
        from shading import TextureError
    except Exception:  # noqa: BLE001
        TextureError = OutputError  # noqa: N806

    def fail(status: int, msg: str) -> int:
        if err.debug:
            traceback.print_exc(file=stderr)
        err.say(msg)
        return status

    try:
        return _execute(args, err)
    except _cli.UsageError as exc:
        hint = f"\n{_cli.PROG}: try 'render report --help'" if exc.help_hint else ""
        return fail(2, f"{exc}{hint}")
    except (SceneError, OutputError, TextureError) as exc:
        return fail(2, _cli._one_line(exc))
    except outputs.WriteError as exc:
        return fail(1, str(exc))
    except KeyboardInterrupt as exc:
        return fail(signals.exit_status(exc), _cli.interrupted_message(exc))
    except MemoryError:
        return fail(1, "out of memory; try a smaller --size or fewer shaders or times")
    except Exception as exc:  # noqa: BLE001 - the last line of defence
        hint = "" if err.debug else f"\n{_cli.PROG}: run with --debug for the traceback"
        return fail(1, f"internal error: {type(exc).__name__}: {_cli._one_line(exc)}{hint}")


def main(argv: Sequence[str] | None = None) -> int:
    """`render report ...` with its own parser; returns the exit status."""
    argv = sys.argv[1:] if argv is None else list(argv)
    args = _cli.parse_subcommand(build_parser(), argv, "report")
    return args if isinstance(args, int) else run(args)


if __name__ == "__main__":  # python -m pipeline.report
    sys.exit(main())
