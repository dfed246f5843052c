"""`render`: simulate a scene and write a GIF, MP4, PNG, PNG folder, OBJs or NPZ.

    render SCENE.json --shader phong --out cloth.gif

`main(argv)` returns the exit status: 0 ok, 1 internal failure (including a diverging
simulation, and an output that cannot be written: full disk, I/O error), 2 bad input
(scene, flags, paths, missing texture), 3 `--check` beyond tolerance, 130 / 143 / 129
stopped by SIGINT / SIGTERM / SIGHUP (nothing left behind). Errors are one or two lines on stderr prefixed `render: `;
`--debug` adds the traceback. See docs/cli.md.
"""
from __future__ import annotations

import argparse
import math
import queue
import sys
import threading
import time
import traceback
import warnings
from dataclasses import dataclass, field
from fractions import Fraction
from pathlib import Path
from typing import Sequence

import numpy as np

from . import outputs, signals
from .outputs import OutputError, WriteError
from .progress import bar, progress_enabled, write_line

PROG = "render"
DEFAULT_FPS = {"gif": 25.0, "mp4": 30.0, "png": 25.0, "dir": 25.0, None: 25.0}
DEFAULT_DURATION = 3.0


class UsageError(ValueError):
    """A bad command line (exit status 2); the message is followed by a pointer to --help."""

    help_hint = True


# --------------------------------------------------------------------------- parsing


class _Parser(argparse.ArgumentParser):
    def error(self, message):  # argparse would print usage and exit; we raise instead
        raise UsageError(message)


def _version() -> str:
    try:
        from importlib.metadata import version

        v = version("clothpipe")
    except Exception:  # noqa: BLE001 - not installed: fall back to the package
        from . import __version__ as v
    return f"{PROG} (clothpipe) {v}"


def _shader_names() -> tuple[str, ...]:
    """The shader names, from the scene format's list (pipeline.scene.SHADERS, the same
    names as the renderer's registry: tested), so that --help and --version answer
    without importing the renderer and numba (0.5 s)."""
    from .scene import SHADERS

    return SHADERS


def _positive_float(name):
    def parse(text):
        try:
            v = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
        if not (math.isfinite(v) and v > 0):
            raise argparse.ArgumentTypeError(f"expected a positive number, got {text!r}")
        return v
    parse.__name__ = name
    return parse


def _nonneg_float(text):
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not (math.isfinite(v) and v >= 0):
        raise argparse.ArgumentTypeError(f"expected a number >= 0, got {text!r}")
    return v


def _positive_int(text):
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number, got {text!r}") from None
    if v < 1:
        raise argparse.ArgumentTypeError(f"expected a whole number >= 1, got {text!r}")
    return v


def _int(text):
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number, got {text!r}") from None


def _size(text):
    parts = text.lower().split("x")
    try:
        w, h = (int(p) for p in parts)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected WIDTHxHEIGHT such as 512x512, got {text!r}"
                                         ) from None
    if not (1 <= w <= 16384 and 1 <= h <= 16384):
        raise argparse.ArgumentTypeError(f"expected sizes from 1 to 16384, got {text!r}")
    return w, h


def _override(text):
    if "=" not in text or not text.partition("=")[0].strip():
        raise argparse.ArgumentTypeError(f"expected dotted.key=value, got {text!r}")
    return text


def _scheduler_address(text):
    """tcp://HOST:PORT (the scheme may be left out; tls:// is kept)."""
    from urllib.parse import urlsplit

    addr = text if "://" in text else f"tcp://{text}"
    try:
        parts = urlsplit(addr)
        ok = (parts.scheme in ("tcp", "tls") and bool(parts.hostname)
              and parts.port is not None and parts.path in ("", "/"))
    except ValueError:
        ok = False
    if not ok:
        raise argparse.ArgumentTypeError(f"expected tcp://HOST:PORT, got {text!r}")
    return addr.rstrip("/")


def add_render_options(p: argparse.ArgumentParser, shaders: str) -> None:
    """The options that say what to render, shared by `render` and `render batch`."""
    p.add_argument("--shader", "-s", metavar="NAME",
                   help=f"shader (default: the scene's render.shader, else phong): {shaders}")
    length = p.add_mutually_exclusive_group()
    length.add_argument("--duration", "-d", type=_positive_float("duration"), metavar="S",
                        help=f"seconds of animation (default {DEFAULT_DURATION:g})")
    length.add_argument("--frames", "-n", type=_positive_int, metavar="N",
                        help="number of output frames (instead of --duration)")
    p.add_argument("--fps", type=_positive_float("fps"), metavar="F",
                   help="output frame rate (default 25 for GIF, PNG and folders; 30 for MP4; "
                        "at most 50 for GIF)")
    p.add_argument("--size", type=_size, metavar="WxH",
                   help="image size in pixels (default: the scene's render size, 512x512)")
    p.add_argument("--aa", type=_positive_int, metavar="N",
                   help="anti-aliasing: N x N samples per pixel (default: the scene's, 1)")
    p.add_argument("--seed", type=_int, metavar="N",
                   help="random seed (same as --set simulation.seed=N)")
    p.add_argument("--integrator", metavar="NAME",
                   help="integrator (same as --set simulation.integrator=NAME)")
    p.add_argument("--fidelity", choices=("exact", "auto"),
                   help="exact (default): every step as the scene says; auto: model no more "
                        "than the scene needs, within --tolerance pixels per frame (same as "
                        "--set simulation.fidelity=...; see 'render plan')")
    p.add_argument("--tolerance", type=_positive_float("tolerance"), metavar="PX",
                   help="with --fidelity auto: the error in pixels a frame may add (default 1; "
                        "same as --set simulation.tolerance_px=PX)")
    p.add_argument("--set", dest="overrides", action="append", default=[], type=_override,
                   metavar="KEY=VALUE",
                   help="override a scene value, e.g. --set cloth.ks=8000 --set "
                        "sphere.0.radius=0.3 (repeatable; VALUE is JSON, else a string)")


#: The destinations of `add_render_options` (what `render batch` hands each scene's run).
RENDER_OPTIONS = ("shader", "duration", "frames", "fps", "size", "aa", "seed", "integrator",
                  "fidelity", "tolerance", "overrides")


def add_cluster_options(p: argparse.ArgumentParser) -> None:
    """--workers N | --scheduler ADDR: run on Dask distributed (docs/distributed.md)."""
    g = p.add_mutually_exclusive_group()
    g.add_argument("--workers", type=_positive_int, metavar="N",
                   help="run on N Dask worker processes started on this machine (a "
                        "distributed.LocalCluster, closed at the end)")
    g.add_argument("--scheduler", type=_scheduler_address, metavar="tcp://HOST:PORT",
                   help="run on the Dask cluster whose scheduler listens at this address "
                        "(started with 'dask scheduler'; see docs/distributed.md)")


def cluster_requested(args) -> bool:
    """True when --workers or --scheduler was given (only then is `distributed` imported)."""
    return args.workers is not None or args.scheduler is not None


def build_parser() -> argparse.ArgumentParser:
    shaders = ", ".join(_shader_names())
    import textwrap

    def para(*texts):
        return "\n\n".join(textwrap.fill(t, 79) for t in texts)

    p = _Parser(
        prog=PROG,
        description=para("Simulate a cloth scene and render it to a GIF, MP4, PNG or a folder "
                         "of PNGs; optionally export meshes (OBJ) and positions (NPZ)."),
        epilog=para(
            f"shaders: {shaders}.",
            "Output type from --out: .gif, .mp4, .png (one frame), or a folder (a path ending "
            "in '/' or an existing folder: numbered PNGs). Output frame k shows the simulated "
            "state at t = k / fps (the simulator frame nearest to t).",
            "Exit status: 0 ok, 1 internal failure, diverging simulation or an output that "
            "cannot be written (full disk), 2 bad input, 3 --check beyond tolerance, "
            "130 / 143 / 129 stopped by SIGINT / SIGTERM / SIGHUP (nothing is left behind).",
            "With --workers N or --scheduler ADDR the simulation runs as one Dask task and "
            "the frames are rasterised in chunks by the workers (docs/distributed.md).",
            "Subcommands: 'render batch A.json B.json --out-dir OUT' renders many scenes; "
            "'render report SCENE.json --out report.html' compares shaders and "
            "parameter sweeps side by side (also reached with --shader all or an .html "
            "output; see 'render report --help'); 'render bench SCENE.json --out DIR' charts "
            "the integrators' accuracy against speed and their stability limits; 'render plan "
            "SCENE.json --fidelity auto' says what will be modelled and why."),
        formatter_class=argparse.RawDescriptionHelpFormatter,
        allow_abbrev=False,
    )
    p.add_argument("scene", metavar="SCENE.json", help="scene file (JSON)")
    p.add_argument("--out", "-o", metavar="PATH",
                   help="output: NAME.gif, NAME.mp4, NAME.png or DIR/ (numbered PNGs)")
    add_render_options(p, shaders)
    p.add_argument("--at", type=_nonneg_float, metavar="S",
                   help="with a .png output: the time in seconds of the frame to write "
                        "(default: the last output frame)")
    p.add_argument("--export-obj", metavar="DIR",
                   help="also write one OBJ per output frame into DIR (an 'o' group per object)")
    p.add_argument("--export-npz", metavar="FILE",
                   help="also write positions of every output frame, faces, uv and times")
    p.add_argument("--check", metavar="GOLDEN.png",
                   help="with a .png output: compare with GOLDEN.png; exit 3 beyond tolerance "
                        "and write OUT.diff.png beside the output")
    p.add_argument("--quiet", "-q", action="store_true",
                   help="no progress bars, warnings or summary line")
    p.add_argument("--debug", action="store_true", help="show tracebacks on errors")
    add_cluster_options(p)
    # Benchmarking switch (hidden): how simulation and rendering share the cores.
    p.add_argument("--pipeline", choices=("auto", "serial", "overlap", "split"), default="auto",
                   help=argparse.SUPPRESS)
    p.add_argument("--version", action="version", version=_version())
    return p


# --------------------------------------------------------------------------- planning


@dataclass
class Plan:
    kind: str | None  # gif, mp4, png, dir, or None (exports only)
    out: Path | None
    fps: float
    out_times: list[float]  # output frame times (s)
    sim_frames: list[int]  # simulator frame shown by each output frame
    shot_frames: list[int]  # simulator frames of the whole shot, ascending (the framing's)
    sim_fps: float
    shader: str
    width: int
    height: int
    aa: int
    overrides: list[str] = field(default_factory=list)

    @property
    def shot_seconds(self) -> float:
        """How long the shot is simulated (its last simulator frame's time)."""
        return self.shot_frames[-1] / self.sim_fps


def nearest_sim_frames(times: Sequence[Fraction | float], sim_fps: float) -> list[int]:
    """Simulator frame nearest to each time t: floor(t * sim_fps + 1/2) (ties go later)."""
    r = Fraction(sim_fps).limit_denominator(1000000)
    return [math.floor(Fraction(t) * r + Fraction(1, 2)) for t in times]


def output_times(n: int, fps: float) -> list[Fraction]:
    r = Fraction(fps).limit_denominator(1000000)
    return [Fraction(k) / r for k in range(n)]


def _output_kind(args) -> tuple[str | None, Path | None]:
    """Flag-only checks of the outputs, done before anything is read."""
    kind = None
    out = None
    if args.out is not None:
        kind, out = outputs.classify_output(args.out)
    elif not (args.export_obj or args.export_npz):
        raise UsageError("nothing to write: give --out (and/or --export-obj / --export-npz)")
    if args.at is not None and kind != "png":
        raise UsageError("--at needs a .png output")
    if args.check is not None and kind != "png":
        raise UsageError("--check needs a .png output")
    if args.export_npz and Path(args.export_npz).suffix.lower() != ".npz":
        raise UsageError(f"--export-npz '{args.export_npz}': expected a file name ending in .npz")
    fps = args.fps if args.fps is not None else DEFAULT_FPS[kind]
    if kind == "gif" and fps > outputs.GIF_MAX_FPS:
        raise UsageError(f"--fps {fps:g} is too high for a GIF (delays are counted in 10 ms and "
                         f"browsers slow delays under 20 ms to 100 ms): use at most "
                         f"{outputs.GIF_MAX_FPS:g}, or an .mp4")
    return kind, out


def animation_times(args, kind: str | None) -> list[Fraction]:
    """The times (s) of every frame of the animation args describe (a PNG shows one)."""
    fps = args.fps if args.fps is not None else DEFAULT_FPS[kind]
    n = args.frames if args.frames is not None else max(
        1, round((args.duration if args.duration is not None else DEFAULT_DURATION) * fps))
    return output_times(n, fps)


def frame_times(args, kind: str | None,
                animation: list[Fraction] | None = None) -> list[Fraction]:
    """The output frames' times (s) that args ask for, for an output of `kind`, from the
    animation's (animation_times, computed here unless given)."""
    times = animation if animation is not None else animation_times(args, kind)
    if kind == "png":  # one frame: the last output frame, or the one --at names
        times = [Fraction(args.at).limit_denominator(1000000) if args.at is not None
                 else times[-1]]
    return times


def _plan(args, scene) -> Plan:
    kind, out = _output_kind(args)
    fps = args.fps if args.fps is not None else DEFAULT_FPS[kind]
    animation = animation_times(args, kind)
    times = frame_times(args, kind, animation)
    sim_fps = float(scene.simulation.frames_per_sec)
    shot = nearest_sim_frames(animation, sim_fps)
    sim_frames = nearest_sim_frames(times, sim_fps)
    shader = args.shader if args.shader is not None else scene.render.shader
    check_shader(shader)
    width, height = args.size if args.size is not None else (scene.render.width,
                                                             scene.render.height)
    aa = args.aa if args.aa is not None else scene.render.aa
    return Plan(kind=kind, out=out, fps=fps, out_times=[float(t) for t in times],
                sim_frames=sim_frames, shot_frames=sorted(set(shot) | set(sim_frames)),
                sim_fps=sim_fps, shader=shader, width=int(width), height=int(height),
                aa=int(aa))


def check_shader(shader: str) -> None:
    """UsageError for a shader name that does not exist."""
    names = _shader_names()
    if shader not in names:
        raise UsageError(f"unknown shader {shader!r} (choose from: {', '.join(names)})")


def scene_overrides(args) -> list[str]:
    """--set, --seed, --integrator, --fidelity, --tolerance and --size as scene overrides."""
    ov = list(args.overrides)
    if args.seed is not None:
        ov.append(f"simulation.seed={args.seed}")
    if args.integrator is not None:
        ov.append(f"simulation.integrator={args.integrator}")
    return ov + fidelity_overrides(args)


def fidelity_overrides(args) -> list[str]:
    """--fidelity, --tolerance and --size as scene overrides (auto's tolerance is in pixels
    of the image rendered)."""
    ov = []
    if args.fidelity is not None:
        ov.append(f"simulation.fidelity={args.fidelity}")
    if args.tolerance is not None:
        ov.append(f"simulation.tolerance_px={args.tolerance!r}")
    if getattr(args, "size", None) is not None:
        ov += [f"render.width={args.size[0]}", f"render.height={args.size[1]}"]
    return ov


# --------------------------------------------------------------------------- running


class _Errors:
    def __init__(self, stream, quiet: bool, debug: bool):
        self.stream = stream
        self.quiet = quiet
        self.debug = debug

    def say(self, msg: str) -> None:
        try:
            write_line(f"{PROG}: {msg}", self.stream)
        except OSError:  # stderr gone (its terminal hung up): the exit status remains
            pass

    def warn(self, msg: str) -> None:
        if not self.quiet:
            self.say(f"warning: {msg}")


def _fmt_bytes(n: int) -> str:
    for unit in ("B", "KB", "MB", "GB"):
        if n < 1024 or unit == "GB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1024
    return f"{n} B"


class _Timers:
    def __init__(self):
        self.compile = 0.0  # a first run's kernel compiling (pipeline.warmup)
        self.simulate = 0.0
        self.render = 0.0
        self.encode = 0.0


def _open_writers(plan: Plan, args) -> dict:
    """Create every output's temp file/folder now: proves the paths are writable."""
    w = {}
    try:
        if plan.kind == "gif":
            w["out"] = outputs.GifWriter(plan.out, fps=plan.fps)
        elif plan.kind == "mp4":
            w["out"] = outputs.Mp4Writer(plan.out, fps=plan.fps)
        elif plan.kind == "png":
            w["out"] = outputs.PngWriter(plan.out)
        elif plan.kind == "dir":
            w["out"] = outputs.FolderWriter(plan.out)
        if args.export_obj:
            w["obj"] = outputs.ObjWriter(args.export_obj)
        if args.export_npz:
            w["npz"] = outputs.NpzWriter(args.export_npz)
    except BaseException:
        for writer in w.values():
            writer.abort()
        raise
    return w


def _read_golden(path: str) -> np.ndarray:
    from PIL import Image, UnidentifiedImageError

    try:
        with Image.open(path) as im:
            return np.asarray(im.convert("RGB"))
    except FileNotFoundError:
        raise UsageError(f"--check: no such file '{path}'") from None
    except (UnidentifiedImageError, OSError) as exc:
        raise UsageError(f"--check: cannot read '{path}' as an image ({exc})") from None


def run(args, err: _Errors, source=None) -> int:
    """Render for parsed `args`; returns 0, or 3 after a failed --check, and raises on
    failure (`failure` gives the exit status and message). `source` is the scene when it
    is not read from args.scene (a `SceneFile`, as `render batch` ships it). With
    --workers / --scheduler the frames are rendered on Dask (pipeline.farm)."""
    t_wall = time.perf_counter()
    from .scene import SceneFile, load_scene

    _output_kind(args)
    on_cluster = cluster_requested(args)
    if on_cluster and (args.export_obj or args.export_npz):
        raise UsageError("--export-obj and --export-npz are not available with --workers or "
                         "--scheduler")
    golden = _read_golden(args.check) if args.check else None
    overrides = scene_overrides(args)
    with warnings.catch_warnings():
        # Python warnings (e.g. StabilityWarning) become one line "render: warning: ...".
        warnings.simplefilter("default")
        warnings.showwarning = lambda message, category, *a, **k: err.warn(
            _one_line(message) if str(message).strip() else category.__name__)
        if source is None:
            source = SceneFile.read(args.scene) if on_cluster else args.scene
        scene = load_scene(source, overrides)
        plan = _plan(args, scene)
        from .framing import Framing

        # a scene with no camera is framed over the whole shot: simulated ahead (_ahead)
        framing = (Framing(plan.width, plan.height)
                   if scene.camera is None and plan.kind is not None else None)
        writers = _open_writers(plan, args)
        try:
            if on_cluster:
                from . import farm

                return farm.execute(args, err, source, overrides, plan, writers, golden,
                                    framing, t_wall)
            from .frames import render_frame, scene_meshes
            from .simulation import Simulation
            from .warmup import FirstRun, RenderJob

            show = progress_enabled(args.quiet)
            render_job = ((lambda model: RenderJob(scene, model, plan.shader, plan.aa))
                          if plan.kind else None)
            # A first run on this machine compiles the kernels, in two processes when it can.
            with FirstRun(scene.simulation.integrator, render_job,
                          err.say if show else None, show, scene) as first:
                sim = Simulation(scene, shot_seconds=plan.shot_seconds, prepare=first.start)
                first.finish(sim)
            return _execute(args, err, scene, plan, sim, writers, golden,
                            render_frame, scene_meshes, framing, t_wall, first.seconds)
        except BaseException:
            for writer in writers.values():
                writer.abort()
            raise


def _execute(args, err, scene, plan, sim, writers, golden, render_frame, scene_meshes,
             framing, t_wall, compile_seconds) -> int:
    """The render of `run` once the Simulation is built and its kernels compiled (in
    `compile_seconds`)."""
    timers = _Timers()
    model = sim.model
    out_w = writers.get("out")
    obj_w = writers.get("obj")
    npz_w = writers.get("npz")
    render_kw = dict(shader=plan.shader, width=plan.width, height=plan.height, aa=plan.aa,
                     shot=framing)
    names = None

    def render(pos, t_sim=0.0):
        t0 = time.perf_counter()
        img = render_frame(scene, pos, model, time=t_sim, **render_kw)
        timers.render += time.perf_counter() - t0
        return img

    show = progress_enabled(args.quiet)
    timers.compile = compile_seconds
    timers.simulate = sim.grid_seconds  # fidelity auto's FEM grid pilot, run while building
    # Render the initial state before simulating: a missing texture or a broken shader
    # fails now, not after the simulation (a framed shot's camera is known only after it:
    # a small frame then).
    first_img = None
    needs_first = plan.kind is not None and plan.sim_frames[0] == 0 and framing is None
    if plan.kind is not None:
        if needs_first:
            first_img = render(sim.positions.copy())
        else:
            t0 = time.perf_counter()
            render_frame(scene, sim.positions.copy(), model, shader=plan.shader, width=16,
                         height=16, aa=1)
            timers.render += time.perf_counter() - t0

    n_out = len(plan.sim_frames)
    sim_bar = bar(plan.shot_frames[-1] if framing else plan.sim_frames[-1], "simulate",
                  "frame", show, 0)
    out_bar = bar(n_out, "render", "frame", show, 1)

    def consume(k, pos):
        nonlocal names, first_img
        t_sim = plan.sim_frames[k] / plan.sim_fps  # keyframed colliders are drawn there
        if out_w is not None:
            if k == 0 and first_img is not None:
                img, first_img = first_img, None
            else:
                img = render(pos, t_sim)
            t0 = time.perf_counter()
            out_w.add(img)
            timers.encode += time.perf_counter() - t0
        t0 = time.perf_counter()
        if obj_w is not None:
            meshes = scene_meshes(scene, pos, model, t_sim)
            if names is None:
                names = outputs.mesh_names(meshes, scene)
            obj_w.add(meshes, names)
        if npz_w is not None:
            npz_w.add(pos)
        timers.encode += time.perf_counter() - t0
        out_bar.update(1)

    mode = _pipeline_mode(args.pipeline, framed=framing is not None)
    frames = (_simulate(sim, plan.sim_frames, timers, sim_bar) if framing is None else
              _ahead(sim, plan, scene, framing, timers, sim_bar))
    try:
        if mode == "serial":
            for k, pos in frames:
                consume(k, pos)
        else:
            _pipelined(frames, consume, depth=queue_depth(sim.positions.nbytes),
                       threads_per_stage=1 if mode == "split" else None)
    finally:
        sim_bar.close()
        out_bar.close()

    t0 = time.perf_counter()
    if npz_w is not None:
        cloth = scene_meshes(scene, sim.positions.copy(), model)[0]
        spf = scene.simulation.steps_per_frame
        npz_w.set_meta(
            times=np.array(plan.out_times, np.float64),
            sim_frames=np.array(plan.sim_frames, np.int64),
            sim_times=np.array([j / plan.sim_fps for j in plan.sim_frames], np.float64),
            faces=np.asarray(cloth.triangles, np.int32),
            uv=np.asarray(cloth.uvs, np.float64),
            grid=np.array([model.nh, model.nw], np.int64),
            fps=np.float64(plan.fps), sim_fps=np.float64(plan.sim_fps),
            steps_per_frame=np.int64(spf),
        )
    timers.encode += time.perf_counter() - t0
    notes = [sim.stepper.summary_text()] if sim.stepper is not None else []
    return finish(args, err, plan, writers, golden, timers, t_wall, notes)


def finish(args, err: _Errors, plan: Plan, writers: dict, golden, timers: _Timers,
           t_wall: float, notes: Sequence[str] = ()) -> int:
    """Commit every output, then --check, the H.264 padding warning, the summary line and
    `notes` (lines after it); returns 0 or 3 (--check beyond tolerance)."""
    t0 = time.perf_counter()
    for writer in writers.values():
        writer.commit()
    timers.encode += time.perf_counter() - t0
    out_w = writers.get("out")
    status = 0
    if golden is not None:
        status = _check(args, err, out_w, golden)

    if isinstance(out_w, outputs.Mp4Writer) and out_w.padded:
        (h, w), (ph, pw) = out_w.shape, out_w.padded_shape
        err.warn(f"{w}x{h} padded to {pw}x{ph} for H.264 yuv420p (even sizes only; the last "
                 "row/column is repeated, nothing is rescaled)")
    if not args.quiet:
        what = []
        if out_w is not None:
            what.append(f"{out_w.target} ({_fmt_bytes(out_w.nbytes)})")
        for key in ("obj", "npz"):
            if key in writers:
                what.append(f"{writers[key].target} ({_fmt_bytes(writers[key].nbytes)})")
        n_out = len(plan.sim_frames)
        size = f" {plan.width}x{plan.height} {plan.shader}" if out_w is not None else ""
        compile_text = f"compile {timers.compile:.2f} s, " if timers.compile else ""
        err.say(f"{n_out} frame{'s' if n_out != 1 else ''}{size} -> {', '.join(what)}; "
                f"{compile_text}simulate {timers.simulate:.2f} s, render {timers.render:.2f} s, "
                f"encode {timers.encode:.2f} s, total {time.perf_counter() - t_wall:.2f} s")
        for line in notes:
            err.say(line)
    return status


def _simulate(sim, frames: Sequence[int], timers: _Timers, sim_bar):
    """Advance the simulation through `frames` (ascending simulator frames); yield
    (k, positions copy) at each frames[k]."""
    current = 0
    for k, j in enumerate(frames):
        while current < j:
            t0 = time.perf_counter()
            sim.advance(1)
            timers.simulate += time.perf_counter() - t0
            current += 1
            sim_bar.update(1)
        yield k, sim.positions.copy()


def _ahead(sim, plan: Plan, scene, framing, timers: _Timers, sim_bar):
    """Simulate the whole shot before anything is drawn: every frame of it goes to
    `framing` (pipeline.framing), the frames to draw to a temporary file (memory stays
    flat however long the shot; nothing is left behind). Then yield (k, positions) of the
    output frames, as _simulate does."""
    import tempfile

    from .framing import framed_points

    drawn = set(plan.sim_frames)
    with tempfile.TemporaryFile() as spool:
        offsets = {}
        for k, pos in _simulate(sim, plan.shot_frames, timers, sim_bar):
            j = plan.shot_frames[k]
            framing.add(framed_points(scene, pos, j / plan.sim_fps))
            if j in drawn:
                offsets[j] = spool.tell()
                spool.write(pos.tobytes())
        for k, j in enumerate(plan.sim_frames):
            pos = np.empty(sim.positions.shape)
            spool.seek(offsets[j])
            spool.readinto(pos)
            yield k, pos


def _pipeline_mode(requested: str, framed: bool = False) -> str:
    """serial, overlap (simulate and render at once, each kernel on all cores) or split
    (each stage's numba kernels on one thread). `auto`: split, but overlap for a `framed`
    shot, simulated whole before its first frame is drawn, so the stages never run at
    once and each may use every core. Concurrent parallel kernels need a thread-safe
    numba threading layer (omp, tbb): with workqueue, run serially."""
    mode = requested if requested != "auto" else "overlap" if framed else "split"
    if mode != "serial":
        try:
            import numba

            if numba.threading_layer() == "workqueue":
                return "serial"
        except (ImportError, ValueError):  # no parallel kernel has run: nothing to fear
            pass
    return mode


QUEUE_BYTES = 32 << 20  # positions the simulation may run ahead of the drawing


def queue_depth(frame_bytes: int) -> int:
    """Frames of positions queued between the stages: QUEUE_BYTES of them, at least 4, so a
    simulation faster than the drawing ends early and frees its cores (_run_pipeline)."""
    return max(4, QUEUE_BYTES // max(1, frame_bytes))


def _pipelined(frames, consume, depth: int = 4, threads_per_stage: int | None = None) -> None:
    """Simulate in this thread while a worker thread renders and encodes earlier frames.

    Output is identical to the serial order: one worker, frames consumed in order.
    A queue of at most `depth` frames keeps memory flat; an error in either thread stops
    both. threads_per_stage: numba threads for each stage's parallel kernels (thread-local);
    once the last frame is queued, the worker draws the rest on every core.
    """
    if threads_per_stage is None:
        _run_pipeline(frames, consume, depth, threads_per_stage)
        return
    from .simulation import numba_threads

    with numba_threads(threads_per_stage):
        _run_pipeline(frames, consume, depth, threads_per_stage)


def _run_pipeline(frames, consume, depth, threads_per_stage) -> None:
    q: queue.Queue = queue.Queue(maxsize=depth)
    stop = threading.Event()
    simulated = threading.Event()  # every frame is queued: the simulation's cores are free
    failure: list[BaseException] = []
    done = object()

    def worker():
        import numba

        if threads_per_stage is not None:
            numba.set_num_threads(threads_per_stage)
        while True:
            item = q.get()
            if item is done or stop.is_set():
                return
            if simulated.is_set() and threads_per_stage is not None:
                # the frames left are drawn on every core (the image does not depend on it)
                numba.set_num_threads(numba.config.NUMBA_NUM_THREADS)
            try:
                consume(*item)
            except BaseException as exc:  # noqa: BLE001 - handed to the main thread
                failure.append(exc)
                stop.set()
                return

    t = threading.Thread(target=worker, name="render-encode", daemon=True)
    t.start()

    def put(item):
        while True:
            if failure:
                return False
            try:
                q.put(item, timeout=0.1)
                return True
            except queue.Full:
                if not t.is_alive():
                    return False

    try:
        for item in frames:
            if not put(item):
                break
        simulated.set()
        put(done)
        t.join()
    except BaseException:
        stop.set()
        try:  # wake the worker and let it finish the frame it is on
            while True:
                q.get_nowait()
        except queue.Empty:
            pass
        try:
            q.put_nowait(done)
        except queue.Full:
            pass
        t.join()
        raise
    if failure:
        raise failure[0]


def _check(args, err: _Errors, out_w, golden: np.ndarray) -> int:
    """Compare the PNG with the golden image; 3 and a diff image beside it when too far."""
    import inspect

    from shading.testing import assert_image_close

    image = out_w.image
    diff_path = out_w.target.with_name(out_w.target.stem + ".diff.png")
    _remove_quietly(diff_path)  # a diff from an earlier failing run would mislead
    kwargs = {}
    if "diff_path" in inspect.signature(assert_image_close).parameters:
        kwargs["diff_path"] = diff_path
    try:
        assert_image_close(image, golden, **kwargs)
    except AssertionError as exc:
        msg = _one_line(exc) if str(exc).strip() else "images differ"
        if not diff_path.exists():
            try:
                with outputs.PngWriter(diff_path) as dw:
                    dw.add(outputs.diff_image(image, golden))
                msg += f"; difference image (x8): {diff_path}"
            except (OSError, OutputError, WriteError):
                pass
        err.say(f"--check {args.check}: {msg}")
        return 3
    return 0


def _remove_quietly(path: Path) -> None:
    try:
        path.unlink()
    except OSError:
        pass


# --------------------------------------------------------------------------- main


SUBCOMMANDS = {  # `render NAME ...` runs the module's main(argv)
    "report": "pipeline.report",  # shaders and parameter sweeps side by side (HTML + PNG)
    "bench": "pipeline.bench",  # integrators: work-precision and stability charts
    "plan": "pipeline.plan",  # what fidelity exact or auto will model, and why
    "batch": "pipeline.batch",  # many scenes, one output each (optionally on Dask)
}


def _wants_report(argv: Sequence[str]) -> bool:
    """`render SCENE --shader all ...` or an .html output means `render report`."""
    pairs = zip(argv, list(argv[1:]) + [""])
    return any((a in ("--shader", "-s") and b == "all") or a in ("--shader=all", "-sall")
               or (a in ("--out", "-o") and b.lower().endswith(".html"))
               or (a.startswith("--out=") and a.lower().endswith(".html")) for a, b in pairs)


def parse_subcommand(parser: argparse.ArgumentParser, argv: Sequence[str], name: str):
    """A subcommand's arguments, or the exit status when there is nothing to run: 2 after
    one line naming what is wrong, 0 after --help."""
    err = _Errors(sys.stderr, quiet=False, debug="--debug" in argv)
    try:
        return parser.parse_args(argv)
    except UsageError as exc:
        err.say(str(exc))
        err.say(f"try 'render {name} --help'")
        return 2
    except SystemExit as exc:  # --help
        return int(exc.code or 0)


def _run_subcommand(name: str, argv: Sequence[str]) -> int:
    import importlib

    from .scene import SceneError

    err = _Errors(sys.stderr, quiet=False, debug="--debug" in argv)
    try:
        return importlib.import_module(SUBCOMMANDS[name]).main(list(argv))
    except SceneError as exc:
        err.say(_one_line(exc))
        return 2
    except WriteError as exc:
        err.say(str(exc))
        return 1
    except KeyboardInterrupt as exc:
        err.say(interrupted_message(exc))
        return signals.exit_status(exc)


def interrupted_message(exc: KeyboardInterrupt, outcome: str = "no output written") -> str:
    """'interrupted (SIGTERM); no output written'."""
    name = str(exc) if isinstance(exc, signals.Terminated) else "SIGINT"
    return f"interrupted ({name}); {outcome}"


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the `render` console script; returns the exit status.
    SIGINT, SIGTERM and SIGHUP stop it cleanly (pipeline.signals): exit 128 + signal."""
    with signals.handled():
        return _main(argv)


def _main(argv: Sequence[str] | None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    if argv and argv[0] in SUBCOMMANDS:
        return _run_subcommand(argv[0], argv[1:])
    if _wants_report(argv):
        return _run_subcommand("report", argv)
    stderr = sys.stderr
    debug = "--debug" in argv
    err = _Errors(stderr, quiet=False, debug=debug)
    try:
        args = build_parser().parse_args(argv)
    except UsageError as exc:
        err.say(str(exc))
        err.say("try 'render --help'")
        return 2
    except SystemExit as exc:  # --help, --version
        return int(exc.code or 0)
    err.quiet = args.quiet
    try:
        return run(args, err)
    except (Exception, KeyboardInterrupt) as exc:
        if args.debug:
            traceback.print_exc(file=stderr)
        status, msg = failure(exc)
        if msg.startswith("internal error") and not args.debug:
            msg += f"\n{PROG}: run with --debug for the traceback"
        err.say(msg)
        return status


def failure(exc: BaseException) -> tuple[int, str]:
    """The exit status and message (one line, two for a bad command line) for an exception
    out of a run: 2 bad input, 1 divergence, a write error or an internal failure,
    128 + N stopped by signal N."""
    from .scene import SceneError
    from .simulation import DivergenceError

    try:
        from shading import TextureError
    except Exception:  # noqa: BLE001
        TextureError = OutputError  # noqa: N806 - never raised, keeps isinstance valid
    if isinstance(exc, UsageError):
        return 2, str(exc) + (f"\n{PROG}: try 'render --help'" if exc.help_hint else "")
    if isinstance(exc, (SceneError, OutputError, TextureError)):
        return 2, _one_line(exc)
    if isinstance(exc, (DivergenceError, WriteError)):
        return 1, _one_line(exc)
    if isinstance(exc, KeyboardInterrupt):
        return signals.exit_status(exc), interrupted_message(exc)
    if isinstance(exc, MemoryError):
        return 1, "out of memory; try a smaller --size, --aa or fewer frames"
    return 1, f"internal error: {type(exc).__name__}: {_one_line(exc)}"


def _one_line(exc: BaseException) -> str:
    text = str(exc).strip()
    return text.splitlines()[0] if text else type(exc).__name__


if __name__ == "__main__":  # python -m pipeline.cli
    sys.exit(main())
