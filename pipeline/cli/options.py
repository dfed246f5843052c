"""The `render` command line: its parser, the option types (each naming what it expects),
and the options `render batch` and `render report` share with it."""
from __future__ import annotations

import argparse
import math

from pipeline.run.errors import UsageError

PROG = "render"


DEFAULT_FPS = {"gif": 25.0, "mp4": 30.0, "png": 25.0, "dir": 25.0, None: 25.0}


DEFAULT_DURATION = 3.0


class Parser(argparse.ArgumentParser):
    def error(self, message):  # argparse would print usage and exit; we raise instead
        raise UsageError(message)


def version_text() -> str:
    try:
        from importlib.metadata import version

        v = version("clothpipe")
    except Exception:  # noqa: BLE001 - not installed: fall back to the package
        from . import __version__ as v
    return f"{PROG} (clothpipe) {v}"


def shader_names() -> tuple[str, ...]:
    """The shader names, from the scene format's list (pipeline.scene.SHADERS, the same
    names as the renderer's registry: tested), so that --help and --version answer
    without importing the renderer and numba (0.5 s)."""
    from pipeline.scene import SHADERS

    return SHADERS


def positive_float(name):
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


def nonneg_float(text):
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not (math.isfinite(v) and v >= 0):
        raise argparse.ArgumentTypeError(f"expected a number >= 0, got {text!r}")
    return v


def positive_int(text):
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number, got {text!r}") from None
    if v < 1:
        raise argparse.ArgumentTypeError(f"expected a whole number >= 1, got {text!r}")
    return v


def int_arg(text):
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number, got {text!r}") from None


def size_arg(text):
    parts = text.lower().split("x")
    try:
        w, h = (int(p) for p in parts)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected WIDTHxHEIGHT such as 512x512, got {text!r}"
                                         ) from None
    if not (1 <= w <= 16384 and 1 <= h <= 16384):
        raise argparse.ArgumentTypeError(f"expected sizes from 1 to 16384, got {text!r}")
    return w, h


def override_arg(text):
    if "=" not in text or not text.partition("=")[0].strip():
        raise argparse.ArgumentTypeError(f"expected dotted.key=value, got {text!r}")
    return text


def scheduler_address(text):
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
    length.add_argument("--duration", "-d", type=positive_float("duration"), metavar="S",
                        help=f"seconds of animation (default {DEFAULT_DURATION:g})")
    length.add_argument("--frames", "-n", type=positive_int, metavar="N",
                        help="number of output frames (instead of --duration)")
    p.add_argument("--fps", type=positive_float("fps"), metavar="F",
                   help="output frame rate (default 25 for GIF, PNG and folders; 30 for MP4; "
                        "at most 50 for GIF)")
    p.add_argument("--size", type=size_arg, metavar="WxH",
                   help="image size in pixels (default: the scene's render size, 512x512)")
    p.add_argument("--aa", type=positive_int, metavar="N",
                   help="anti-aliasing: N x N samples per pixel (default: the scene's, 1)")
    p.add_argument("--shadows", action="store_true", default=None,
                   help="soft shadows from the light (same as --set render.shadows=true; "
                        "light.radius sets the softness)")
    p.add_argument("--ambient-occlusion", action="store_true", default=None,
                   help="darken folds and contact (same as --set "
                        "render.ambient_occlusion=true)")
    p.add_argument("--look", choices=("course", "studio"),
                   help="studio: shadows and ambient occlusion; course: neither (the SPEC 5 "
                        "shaders exactly)")
    p.add_argument("--seed", type=int_arg, metavar="N",
                   help="random seed (same as --set simulation.seed=N)")
    p.add_argument("--integrator", metavar="NAME",
                   help="integrator (same as --set simulation.integrator=NAME)")
    p.add_argument("--contact", choices=("course", "robust"),
                   help="the cloth's self-contact: course (default, SPEC section 2) or robust "
                        "(never passes through itself; same as --set simulation.contact=...)")
    p.add_argument("--fidelity", choices=("exact", "auto"),
                   help="exact (default): every step as the scene says; auto: model no more "
                        "than the scene needs, within --tolerance pixels per frame (same as "
                        "--set simulation.fidelity=...; see 'render plan')")
    p.add_argument("--tolerance", type=positive_float("tolerance"), metavar="PX",
                   help="with --fidelity auto: the error in pixels a frame may add (default 1; "
                        "same as --set simulation.tolerance_px=PX)")
    p.add_argument("--set", dest="overrides", action="append", default=[], type=override_arg,
                   metavar="KEY=VALUE",
                   help="override a scene value, e.g. --set cloth.ks=8000 --set "
                        "sphere.0.radius=0.3 (repeatable; VALUE is JSON, else a string)")


#: The destinations of `add_render_options` (what `render batch` hands each scene's run).
RENDER_OPTIONS = ("shader", "duration", "frames", "fps", "size", "aa", "shadows",
                  "ambient_occlusion", "look", "seed", "integrator", "contact", "fidelity",
                  "tolerance", "overrides")


def add_cluster_options(p: argparse.ArgumentParser) -> None:
    """--workers N | --scheduler ADDR: run on Dask distributed (docs/distributed.md)."""
    g = p.add_mutually_exclusive_group()
    g.add_argument("--workers", type=positive_int, metavar="N",
                   help="run on N Dask worker processes started on this machine (a "
                        "distributed.LocalCluster, closed at the end)")
    g.add_argument("--scheduler", type=scheduler_address, metavar="tcp://HOST:PORT",
                   help="run on the Dask cluster whose scheduler listens at this address "
                        "(started with 'dask scheduler'; see docs/distributed.md)")


def cluster_requested(args) -> bool:
    """True when --workers or --scheduler was given (only then is `distributed` imported)."""
    return args.workers is not None or args.scheduler is not None


def build_parser() -> argparse.ArgumentParser:
    shaders = ", ".join(shader_names())
    import textwrap

    def para(*texts):
        return "\n\n".join(textwrap.fill(t, 79) for t in texts)

    p = Parser(
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
            "'render --from shot.npz --out x.gif --shader toon' draws again a shot that "
            "--export-npz recorded, without simulating it again.",
            "Subcommands: 'render batch A.json B.json --out-dir OUT' renders many scenes; "
            "'render report SCENE.json --out report.html' compares shaders and "
            "parameter sweeps side by side (also reached with --shader all or an .html "
            "output; see 'render report --help'); 'render bench SCENE.json --out DIR' charts "
            "the integrators' accuracy against speed and their stability limits; 'render plan "
            "SCENE.json --fidelity auto' says what will be modelled and why."),
        formatter_class=argparse.RawDescriptionHelpFormatter,
        allow_abbrev=False,
    )
    p.add_argument("scene", metavar="SCENE.json", nargs="?",
                   help="scene file (JSON); with --from, the scene the NPZ records when left "
                        "out")
    p.add_argument("--out", "-o", metavar="PATH",
                   help="output: NAME.gif, NAME.mp4, NAME.png or DIR/ (numbered PNGs)")
    add_render_options(p, shaders)
    p.add_argument("--at", type=nonneg_float, metavar="S",
                   help="with a .png output: the time in seconds of the frame to write "
                        "(default: the last output frame)")
    p.add_argument("--export-obj", metavar="DIR",
                   help="also write one OBJ per output frame into DIR (an 'o' group per object)")
    p.add_argument("--export-npz", metavar="FILE",
                   help="also write positions of every output frame, faces, uv, times and "
                        "the scene (what --from reads)")
    p.add_argument("--from", dest="from_npz", metavar="SHOT.npz",
                   help="render the shot an --export-npz file holds, without simulating: "
                        "another --shader, --size, --aa or --set camera/light/render value; "
                        "its frames and times by default")
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
    p.add_argument("--version", action="version", version=version_text())
    return p


