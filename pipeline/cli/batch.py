"""`render batch A.json B.json ... | DIR --out-dir OUT [--format gif|mp4|png] [...]`.

One output per scene, named after it (OUT/A.gif for A.json; GIF unless --format), each
rendered exactly as `render A.json --out OUT/A.gif [flags]` would; one after another in
this process, or as one Dask task per scene with --workers N | --scheduler ADDR. A task
ships the scene file's bytes and the flags, and sends the finished file's bytes back: the
client writes every output (atomically) as its task ends. A scene that fails (bad input,
divergence, a worker dying three times) is a row of the table printed at the end while
the others are still rendered. Exit status: 0 all rendered, 1 any scene failed, 2 a bad
command line (nothing rendered), 130 / 143 / 129 stopped by a signal (outputs already
finished are kept, nothing partial is left).
"""
from __future__ import annotations

import argparse
import contextlib
import io
import sys
import tempfile
import time
import traceback
import uuid
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from pipeline.run import outputs
from pipeline.run.errors import UsageError
from pipeline.run.progress import bar, progress_enabled

from .messages import Errors, failure, interrupted_message, one_line, parse_subcommand
from .options import (PROG, RENDER_OPTIONS, Parser, add_cluster_options, add_render_options,
                      cluster_requested, shader_names)
from .options import build_parser as render_parser
from .render import check_shader, fmt_bytes, frame_times, output_kind, run

FORMATS = ("gif", "mp4", "png")


def build_parser() -> argparse.ArgumentParser:
    shaders = ", ".join(shader_names())
    p = Parser(
        prog=f"{PROG} batch", allow_abbrev=False,
        description="Render many scenes, one output per scene named after it (OUT/A.gif for "
                    "A.json), optionally on Dask workers; a table of the results at the end.",
        epilog="Exit status: 0 every scene rendered, 1 a scene failed (see the table), 2 bad "
               "command line, 130 / 143 / 129 stopped by a signal. See docs/distributed.md.")
    p.add_argument("inputs", nargs="+", metavar="SCENE.json|DIR",
                   help="scene files, or folders whose *.json files are scenes")
    p.add_argument("--out-dir", required=True, metavar="OUT",
                   help="folder for the outputs (created if missing; its parent must exist)")
    p.add_argument("--format", choices=FORMATS, default="gif",
                   help="output type of every scene (default gif)")
    add_render_options(p, shaders)
    add_cluster_options(p)
    p.add_argument("--quiet", "-q", action="store_true",
                   help="no progress bar or warnings (the table is still printed)")
    p.add_argument("--debug", action="store_true", help="show tracebacks on errors")
    return p


# --------------------------------------------------------------------------- one scene


@dataclass
class Result:
    """How one scene went; `data` is the output file's bytes when it was rendered."""

    name: str  # the scene file as given
    frames: int
    seconds: float
    status: str  # "ok", "bad input" or "failed"
    message: str = ""
    data: bytes | None = None
    warnings: list[str] = field(default_factory=list)


def render_args(name: str, target: Path, options: dict) -> argparse.Namespace:
    """The `render` command line for one scene: `name --out target` plus `options`
    (values of pipeline.cli.options.RENDER_OPTIONS)."""
    args = render_parser().parse_args(["--out", str(target), "--quiet", "--", name])
    for key, value in options.items():
        setattr(args, key, value)
    return args


def render_scene(scene, fmt: str, options: dict, one_thread: bool = False) -> Result:
    """Render `scene` (a SceneFile) as `render` does, into a temporary file, and return
    the file's bytes. `one_thread`: simulate and render one after the other on one
    numba thread (a Dask worker runs one task per core)."""
    from clothjit import numba_threads

    t0 = time.perf_counter()
    log = io.StringIO()
    err = Errors(log, quiet=False, debug=False)  # collects the warnings
    with tempfile.TemporaryDirectory(prefix="clothpipe-batch-") as tmp:
        args = render_args(scene.name, Path(tmp) / f"out.{fmt}", options)
        frames = len(frame_times(args, fmt))
        try:
            if one_thread:
                args.pipeline = "serial"
                with numba_threads(1):
                    run(args, err, source=scene)
            else:
                run(args, err, source=scene)
            data, status, message = Path(args.out).read_bytes(), "ok", ""
        except Exception as exc:  # noqa: BLE001 - every failure becomes a row of the table
            code, message = failure(exc)
            data, status = None, "bad input" if code == 2 else "failed"
    prefix = f"{PROG}: warning: "
    notes = [ln[len(prefix):] for ln in log.getvalue().splitlines() if ln.startswith(prefix)]
    return Result(scene.name, frames, time.perf_counter() - t0, status,
                  message.splitlines()[0] if message else "", data, notes)


# --------------------------------------------------------------------------- the batch


def scene_files(inputs: Sequence[str]) -> list[Path]:
    """Files as given, folders as their *.json files (sorted); UsageError for an empty
    folder."""
    out = []
    for text in inputs:
        p = Path(text)
        if p.is_dir():
            found = sorted(f for f in p.glob("*.json") if f.is_file())
            if not found:
                raise UsageError(f"{text}: no .json scene files in this folder")
            out += found
        else:
            out.append(p)
    return out


def output_paths(scenes: Sequence[Path], out_dir: Path, fmt: str) -> list[Path]:
    """OUT/<scene name>.<fmt> per scene; UsageError when two scenes would share one."""
    seen: dict[Path, Path] = {}
    for s in scenes:
        target = out_dir / f"{s.stem}.{fmt}"
        if target in seen:
            raise UsageError(f"{seen[target]} and {s} would both write {target}")
        seen[target] = s
    return list(seen)


def _check_out_dir(text: str) -> Path:
    p = Path(text)
    if p.exists() and not p.is_dir():
        raise UsageError(f"--out-dir '{text}': a file of that name exists")
    parent = p.parent if str(p.parent) else Path(".")
    if not p.exists() and not parent.is_dir():
        raise UsageError(f"--out-dir '{text}': directory '{parent}' does not exist")
    return p


def run_batch(args, scenes: Sequence[Path], options: dict) -> Iterator[tuple[int, Result]]:
    """(index, Result) of every scene as each finishes; on Dask with --workers or
    --scheduler (one task per scene), else one after another here."""
    from pipeline.scene import SceneError, SceneFile

    files = {}
    for i, path in enumerate(scenes):
        try:
            files[i] = SceneFile.read(path)
        except SceneError as exc:
            yield i, Result(str(path), 0, 0.0, "bad input", one_line(exc))
    if not cluster_requested(args):
        for i, scene in files.items():
            yield i, render_scene(scene, args.format, options)
        return
    import distributed

    from pipeline.cluster import client as cluster

    with cluster.connect(args) as client:
        run = f"clothpipe-batch-{uuid.uuid4().hex}"
        futures = {client.submit(render_scene, scene, args.format, options, True,
                                 key=f"{run}-{i}"): i for i, scene in files.items()}
        for future in distributed.as_completed(futures, loop=client.loop):
            i = futures.pop(future)
            try:
                yield i, future.result()
            except Exception as exc:  # noqa: BLE001 - e.g. KilledWorker: a row, not a stop
                yield i, Result(files[i].name, 0, 0.0, "failed",
                                f"{type(exc).__name__}: {one_line(exc)}")


def table(results: Sequence[Result], seconds: float, where: str) -> str:
    """The summary: one row per scene (scene, frames, seconds, size, status), then totals."""
    rows = [("scene", "frames", "seconds", "size", "status")]
    for r in results:
        size = fmt_bytes(len(r.data)) if r.data is not None else "-"
        status = r.status + (f": {r.message}" if r.message else "")
        rows.append((r.name, str(r.frames) if r.data is not None else "-",
                     f"{r.seconds:.2f}" if r.seconds else "-", size, status))
    widths = [max(len(row[c]) for row in rows) for c in range(4)]
    lines = ["  ".join([row[0].ljust(widths[0])] + [row[c].rjust(widths[c]) for c in (1, 2, 3)]
                       + [row[4]]) for row in rows]
    ok = sum(r.status == "ok" for r in results)
    lines.append(f"{len(results)} scene{'s' * (len(results) != 1)}: {ok} ok, "
                 f"{len(results) - ok} failed; {seconds:.2f} s {where}")
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    args = parse_subcommand(build_parser(), argv, "batch")
    if isinstance(args, int):
        return args
    err = Errors(sys.stderr, quiet=args.quiet, debug=args.debug)
    options = {key: getattr(args, key) for key in RENDER_OPTIONS}
    try:
        scenes = scene_files(args.inputs)
        out_dir = _check_out_dir(args.out_dir)
        targets = output_paths(scenes, out_dir, args.format)
        if args.shader is not None:
            check_shader(args.shader)
        output_kind(render_args("x.json", out_dir / f"x.{args.format}", options))
    except (UsageError, outputs.OutputError) as exc:
        err.say(str(exc))
        err.say("try 'render batch --help'")
        return 2
    created = not out_dir.exists()
    out_dir.mkdir(exist_ok=True)
    results: list[Result | None] = [None] * len(scenes)
    t0 = time.perf_counter()
    progress = bar(len(scenes), "render", "scene", progress_enabled(args.quiet))
    try:
        with contextlib.closing(run_batch(args, scenes, options)) as done:
            for i, result in done:
                results[i] = _write(result, targets[i])
                for w in result.warnings:
                    err.warn(f"{result.name}: {w}")
                progress.update(1)
    except (Exception, KeyboardInterrupt) as exc:  # a signal, no cluster, a bug
        if created and not any(out_dir.iterdir()):
            out_dir.rmdir()
        status, msg = failure(exc)
        if isinstance(exc, KeyboardInterrupt):
            kept = sum(r is not None and r.status == "ok" for r in results)
            msg = interrupted_message(exc, f"{kept} finished output{'s' * (kept != 1)} "
                                                "kept, nothing partial written")
        if args.debug:
            traceback.print_exc(file=sys.stderr)
        err.say(msg)
        return status
    finally:
        progress.close()
    where = "in this process"
    if args.workers is not None:
        where = f"on {args.workers} local Dask worker{'s' * (args.workers != 1)}"
    elif args.scheduler is not None:
        where = f"on the Dask cluster at {args.scheduler}"
    print(table(results, time.perf_counter() - t0, where), flush=True)
    return 0 if all(r.status == "ok" for r in results) else 1


def _write(result: Result, target: Path) -> Result:
    """Write a rendered scene's bytes to `target` atomically; a write error fails it."""
    if result.data is None:
        return result
    try:
        with outputs.atomic_file(target) as tmp:
            tmp.write_bytes(result.data)
    except outputs.WriteError as exc:
        result.status, result.message, result.data = "failed", str(exc), None
    return result
