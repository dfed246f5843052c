"""`render report`'s command line and its plan: the variants (the product of the sweeps),
the times, the shaders, the output paths; every check before any simulation."""
from __future__ import annotations

import argparse
import itertools
import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

from pipeline.run import outputs
from pipeline.run.errors import UsageError

from .options import (DEFAULT_FPS, Parser, add_cluster_options, cluster_requested, override_arg,
                      positive_float, positive_int, size_arg)
from .render import nearest_sim_frames, output_times

PROG = "render report"


DEFAULT_DURATION = 3.0


DEFAULT_SIZE = (256, 256)


DEFAULT_GIF_SIZE = (128, 128)


DEFAULT_GIF_FPS = 10.0


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
    p.add_argument("--duration", "-d", type=positive_float("duration"), metavar="S",
                   help=f"seconds of animation (default {DEFAULT_DURATION:g}; with --at: the "
                        "last --at time)")
    p.add_argument("--size", type=size_arg, metavar="WxH",
                   help=f"size of each image (default {DEFAULT_SIZE[0]}x{DEFAULT_SIZE[1]})")
    p.add_argument("--aa", type=positive_int, metavar="N",
                   help="anti-aliasing: N x N samples per pixel (default: the scene's, 1)")
    p.add_argument("--set", dest="overrides", action="append", default=[],
                   type=override_arg, metavar="KEY=VALUE",
                   help="override a scene value (repeatable; VALUE is JSON, else a string)")
    p.add_argument("--sweep", dest="sweeps", action="append", default=[], type=_sweep_type,
                   metavar="KEY=V1,V2,...",
                   help="render one variant per value; the first --sweep goes along rows, the "
                        "second along columns, later ones make one grid per combination")
    p.add_argument("--gif", action="store_true",
                   help="also write REPORT.gif: the whole animation as one animated grid")
    p.add_argument("--gif-size", type=size_arg, metavar="WxH",
                   help=f"cell size of the GIF grid (default "
                        f"{DEFAULT_GIF_SIZE[0]}x{DEFAULT_GIF_SIZE[1]})")
    p.add_argument("--gif-fps", type=positive_float("gif-fps"), metavar="F",
                   help=f"frame rate of the GIF grid (default {DEFAULT_GIF_FPS:g}, at most "
                        f"{outputs.GIF_MAX_FPS:g})")
    p.add_argument("--jobs", "-j", type=positive_int, metavar="N",
                   help="parallel simulations of a sweep (default: os.cpu_count())")
    add_cluster_options(p)
    p.add_argument("--title", metavar="TEXT", help="page title (default: the scene file name)")
    p.add_argument("--quiet", "-q", action="store_true",
                   help="no progress bars, warnings or summary line")
    p.add_argument("--debug", action="store_true", help="show tracebacks on errors")
    return p


def build_parser() -> argparse.ArgumentParser:
    p = Parser(
        prog=PROG,
        description="Simulate a scene and write an HTML report comparing shaders, times and "
                    "parameter values side by side, with a contact-sheet PNG beside it.",
        epilog="Exit status: 0 ok (also when a sweep variant diverges: its cells say so), "
               "1 internal failure, 2 bad input, 130 interrupted. See docs/report.md.",
        allow_abbrev=False,
    )
    return add_arguments(p)


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
            raise UsageError("'all' cannot be combined with other shader names")
        if n not in available:
            raise UsageError(f"unknown shader {n!r} (choose from: {', '.join(available)})")
        if n not in out:
            out.append(n)
    return out


def _output_paths(out: str, gif: bool) -> tuple[Path, Path, Path | None]:
    if not out:
        raise UsageError("--out: empty path")
    p = Path(out)
    if p.suffix.lower() not in (".html", ".htm"):
        raise UsageError(f"--out '{out}': expected a file name ending in .html")
    if p.is_dir():
        raise UsageError(f"--out '{out}': it is a directory")
    parent = p.parent if str(p.parent) else Path(".")
    if not parent.is_dir():
        raise UsageError(f"--out '{out}': directory '{parent}' does not exist")
    return p, p.with_suffix(".png"), (p.with_suffix(".gif") if gif else None)


def plan_report(args) -> ReportPlan:
    """Check every flag and load every scene variant; raises UsageError / SceneError.

    Nothing is simulated, rendered or written here.
    """
    from pipeline.scene import load_scene
    from shading import SHADERS

    out, sheet, gif = _output_paths(args.out, args.gif)
    sweeps: list[Sweep] = list(args.sweeps)
    keys = [s.key for s in sweeps]
    for k in keys:
        if keys.count(k) > 1:
            raise UsageError(f"--sweep {k}: the same key is swept twice")
    if sweeps:
        if args.shaders is not None:
            raise UsageError("a --sweep report uses one shader: give --shader NAME, "
                                  "not --shaders")
        if args.shader is not None and len(args.shader) != 1:
            raise UsageError("a --sweep report uses one shader: give --shader NAME")
    elif args.shader is not None and args.shaders is not None:
        raise UsageError("give --shaders or --shader, not both")
    if args.gif_fps is not None and args.gif_fps > outputs.GIF_MAX_FPS:
        raise UsageError(f"--gif-fps {args.gif_fps:g} is too high for a GIF: use at most "
                              f"{outputs.GIF_MAX_FPS:g}")
    if (args.gif_size is not None or args.gif_fps is not None) and not args.gif:
        raise UsageError("--gif-size and --gif-fps need --gif")
    if args.jobs is not None and cluster_requested(args):
        raise UsageError("give --jobs (processes here) or --workers / --scheduler (Dask), "
                              "not both")

    duration = args.duration if args.duration is not None else None
    if args.at is not None:
        times = list(args.at)
        if duration is not None and times[-1] > duration:
            raise UsageError(f"--at {times[-1]:g} is beyond --duration {duration:g}")
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
        raise UsageError("the variants of a sweep must share simulation.frames_per_sec")
    sim_fps = fps_set.pop()

    width, height = args.size if args.size is not None else DEFAULT_SIZE
    gif_times, gif_frames = [], []
    gif_size = args.gif_size or DEFAULT_GIF_SIZE
    gif_fps = args.gif_fps or DEFAULT_GIF_FPS
    if args.gif:
        n = max(1, round(max(times) * gif_fps))
        ts = output_times(n, gif_fps)
        gif_times = [float(t) for t in ts]
        gif_frames = nearest_sim_frames(ts, sim_fps)
    sim_frames = nearest_sim_frames(times, sim_fps)
    # the shot a scene with no camera is framed over: max(times) seconds as `render`
    # animates them by default (so a cell is the frame `render --at` draws at that time)
    fps = DEFAULT_FPS["gif"]
    shot = nearest_sim_frames(output_times(max(1, round(max(times) * fps)), fps),
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

