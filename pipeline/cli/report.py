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

Entry points: `report_plan.add_arguments(parser)` + `run(args)` (for a `render report`
sub-command), `main(argv)` (its own parser). Library use: `build_report(...)` here,
`report_runs.simulate_variant(...)`. The command line and plan are in report_plan, the
simulations in report_runs, the contact sheet in report_sheet, the page in report_html.
"""
from __future__ import annotations

import itertools
import json
import sys
import time
import traceback
from pathlib import Path
from typing import Sequence

import numpy as np

from pipeline.run import outputs, signals
from pipeline.run.errors import UsageError
from pipeline.run.outputs import OutputError
from pipeline.run.progress import bar, progress_enabled

from .messages import Errors, interrupted_message, one_line, parse_subcommand
from .options import PROG, cluster_requested
from .render import fmt_bytes
from .report_html import render_html
from .report_plan import ReportPlan, build_parser, plan_report
from .report_runs import VariantRun, run_simulations, shared_simulations
from .report_sheet import Cell, Grid, Report, SheetCanvas, diverged_image, short_message

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


def _renderer(plan: ReportPlan, runs: Sequence[VariantRun]):
    from pipeline.physics.model import build_model
    from pipeline.run.frames import render_frame

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
    """{(width, height): pipeline.view.framing.Framing} for the cells and the GIF frames: the
    whole shot (plan.shot_frames) of every variant with no camera, framed where it ran, so
    those variants share one view."""
    from pipeline.view.framing import Framing

    shots = {size: Framing(*size) for size in plan.image_sizes}
    for run in runs:
        for size, framing in run.framings.items():
            shots[size].include(framing)
    return shots


def warm_up(plan: ReportPlan) -> None:
    """Render a 16x16 frame with every shader under each of the variants' render settings
    (untimed), so that every kernel the cells use (the shadows' and occlusion's in a sweep
    that turns them on) is compiled or loaded before the render times are measured, and a
    broken shader or missing texture fails early."""
    from pipeline.physics.model import build_model
    from pipeline.run.frames import render_frame

    seen = set()
    for v in plan.variants:
        key = repr(v.scene.render)
        if key in seen:
            continue
        seen.add(key)
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
                    cell = Cell(diverged_image(short_message(msg), plan.width, plan.height),
                                f"{head} · diverged: {short_message(msg)}", "diverged", attrs,
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
                                short_message(run.error or "not simulated"), gw, gh)
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
        n = len(shared_simulations(plan.variants)[0])
        by_frame = n == 1 and not cluster_requested(plan)  # else one tick per simulation
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
        sizes = ", ".join(f"{p} ({fmt_bytes(p.stat().st_size)})" for p in what)
        n_img = sum(len(g.rows) * len(g.cols) for g in report.grids)
        n_sim = len(shared_simulations(plan.variants)[0])
        tm = report.timings
        err.say(f"report: {n_img} image{'s' * (n_img != 1)} {plan.width}x{plan.height}, "
                f"{n_sim} simulation{'s' * (n_sim != 1)} -> {sizes}; "
                f"simulate {tm.get('simulate', 0):.2f} s, render {tm.get('render', 0):.2f} s, "
                f"total {time.perf_counter() - t_wall:.2f} s")
    return 0


def run(args) -> int:
    """Run a parsed report command line (from `add_arguments`); returns the exit status."""
    stderr = sys.stderr
    err = Errors(stderr, quiet=getattr(args, "quiet", False),
                       debug=getattr(args, "debug", False))
    from pipeline.scene import SceneError

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
    except UsageError as exc:
        hint = f"\n{PROG}: try 'render report --help'" if exc.help_hint else ""
        return fail(2, f"{exc}{hint}")
    except (SceneError, OutputError, TextureError) as exc:
        return fail(2, one_line(exc))
    except outputs.WriteError as exc:
        return fail(1, str(exc))
    except KeyboardInterrupt as exc:
        return fail(signals.exit_status(exc), interrupted_message(exc))
    except MemoryError:
        return fail(1, "out of memory; try a smaller --size or fewer shaders or times")
    except Exception as exc:  # noqa: BLE001 - the last line of defence
        hint = "" if err.debug else f"\n{PROG}: run with --debug for the traceback"
        return fail(1, f"internal error: {type(exc).__name__}: {one_line(exc)}{hint}")


def main(argv: Sequence[str] | None = None) -> int:
    """`render report ...` with its own parser; returns the exit status."""
    argv = sys.argv[1:] if argv is None else list(argv)
    args = parse_subcommand(build_parser(), argv, "report")
    return args if isinstance(args, int) else run(args)


if __name__ == "__main__":  # python -m pipeline.cli.report
    sys.exit(main())

