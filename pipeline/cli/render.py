"""`render`: simulate a scene and write a GIF, MP4, PNG, PNG folder, OBJs or NPZ.

    render SCENE.json --shader phong --out cloth.gif

`main(argv)` returns the exit status: 0 ok, 1 internal failure (including a diverging
simulation, and an output that cannot be written: full disk, I/O error), 2 bad input
(scene, flags, paths, missing texture), 3 `--check` beyond tolerance, 130 / 143 / 129
stopped by SIGINT / SIGTERM / SIGHUP (nothing left behind). Errors are one or two lines on stderr prefixed `render: `;
`--debug` adds the traceback. See docs/cli.md.
"""
from __future__ import annotations

import math
import queue
import threading
import time
import uuid
import warnings
from dataclasses import dataclass, field
from fractions import Fraction
from pathlib import Path
from typing import Sequence

import numpy as np

from pipeline.run import outputs
from pipeline.run.errors import UsageError
from pipeline.run.outputs import OutputError, WriteError
from pipeline.run.progress import bar, progress_enabled

from .messages import Errors, one_line
from .options import DEFAULT_DURATION, DEFAULT_FPS, cluster_requested, shader_names


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
    # the arrays that record the scene in an --export-npz file (pipeline.run.shotfile)
    record: dict = field(default_factory=dict)

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


def output_kind(args) -> tuple[str | None, Path | None]:
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
    kind, out = output_kind(args)
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
    names = shader_names()
    if shader not in names:
        raise UsageError(f"unknown shader {shader!r} (choose from: {', '.join(names)})")


def scene_overrides(args) -> list[str]:
    """--set, --look, --shadows, --ambient-occlusion, --seed, --integrator, --contact,
    --fidelity, --tolerance and --size as scene overrides."""
    ov = list(args.overrides)
    look = getattr(args, "look", None)
    if look is not None:
        on = "true" if look == "studio" else "false"
        ov += [f"render.shadows={on}", f"render.ambient_occlusion={on}"]
    if getattr(args, "shadows", None):
        ov.append("render.shadows=true")
    if getattr(args, "ambient_occlusion", None):
        ov.append("render.ambient_occlusion=true")
    if args.seed is not None:
        ov.append(f"simulation.seed={args.seed}")
    if args.integrator is not None:
        ov.append(f"simulation.integrator={args.integrator}")
    if getattr(args, "contact", None) is not None:
        ov.append(f"simulation.contact={args.contact}")
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


def fmt_bytes(n: int) -> str:
    for unit in ("B", "KB", "MB", "GB"):
        if n < 1024 or unit == "GB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1024
    return f"{n} B"


class Timers:
    def __init__(self):
        self.compile = 0.0  # a first run's kernel compiling (pipeline.run.warmup)
        self.simulate = 0.0
        self.render = 0.0
        self.encode = 0.0


def write_frame(writers: tuple, img, pos, t_sim: float, scene, model, timers, names,
                scene_meshes):
    """One frame to its outputs (out, obj, npz writers; None where absent): the image, the
    scene's meshes at t_sim, the positions; returns the meshes' names (made once)."""
    out_w, obj_w, npz_w = writers
    if out_w is not None:
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
    return names

def open_writers(plan: Plan, args) -> dict:
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


def read_golden(path: str) -> np.ndarray:
    from PIL import Image, UnidentifiedImageError

    try:
        with Image.open(path) as im:
            return np.asarray(im.convert("RGB"))
    except FileNotFoundError:
        raise UsageError(f"--check: no such file '{path}'") from None
    except (UnidentifiedImageError, OSError) as exc:
        raise UsageError(f"--check: cannot read '{path}' as an image ({exc})") from None


def run(args, err: Errors, source=None) -> int:
    """Render for parsed `args`; returns 0, or 3 after a failed --check, and raises on
    failure (`failure` gives the exit status and message). `source` is the scene when it
    is not read from args.scene (a `SceneFile`, as `render batch` ships it). With
    --workers / --scheduler the frames are rendered on Dask (pipeline.cluster.farm)."""
    t_wall = time.perf_counter()
    from pipeline.scene import SceneFile, load_scene

    if getattr(args, "from_npz", None) is not None:  # draw a recorded shot: no simulation
        from .render_from import run_from

        return run_from(args, err, t_wall)
    if source is None and args.scene is None:
        raise UsageError("give the scene: render SCENE.json --out ... (or --from SHOT.npz)")
    output_kind(args)
    on_cluster = cluster_requested(args)
    if on_cluster and (args.export_obj or args.export_npz):
        raise UsageError("--export-obj and --export-npz are not available with --workers or "
                         "--scheduler")
    golden = read_golden(args.check) if args.check else None
    overrides = scene_overrides(args)
    with warnings.catch_warnings():
        # Python warnings (e.g. StabilityWarning) become one line "render: warning: ...".
        warnings.simplefilter("default")
        warnings.showwarning = lambda message, category, *a, **k: err.warn(
            one_line(message) if str(message).strip() else category.__name__)
        if source is None:  # an NPZ export records the scene file's bytes as read
            source = (SceneFile.read(args.scene) if on_cluster or args.export_npz
                      else args.scene)
        scene = load_scene(source, overrides)
        plan = _plan(args, scene)
        if args.export_npz:
            from pipeline.run.shotfile import scene_record

            plan.record = scene_record(source if isinstance(source, SceneFile)
                                       else SceneFile.read(source), overrides)
        from pipeline.view.framing import Framing

        # a scene with no camera is framed over the whole shot: simulated ahead (_ahead);
        # an NPZ export records what frames it, for render --from (any --size)
        framing = (Framing(plan.width, plan.height, record=bool(args.export_npz))
                   if scene.camera is None and plan.kind is not None else None)
        writers = open_writers(plan, args)
        try:
            if on_cluster:
                return render_on_cluster(args, err, source, overrides, plan, writers, golden,
                                         framing, t_wall)
            from pipeline.run.frames import render_frame, scene_meshes
            from pipeline.run.warmup import FirstRun, RenderJob
            from pipeline.simulation import Simulation

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
    timers = Timers()
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
        img = None
        if out_w is not None:
            if k == 0 and first_img is not None:
                img, first_img = first_img, None
            else:
                img = render(pos, t_sim)
        names = write_frame((out_w, obj_w, npz_w), img, pos, t_sim, scene, model, timers,
                            names, scene_meshes)
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
        npz_w.set_meta(**npz_meta(plan, scene, model, scene_meshes,
                                  None if framing is None else framing.points()))
    timers.encode += time.perf_counter() - t0
    notes = [sim.stepper.summary_text()] if sim.stepper is not None else []
    if sim.system.contact is not None:
        from pipeline.physics.contact import contact_summary

        notes.append(contact_summary(sim.system.contact, sim.system.steps_per_frame))
    if sim.limit_stop is not None:
        notes.append(sim.limit_stop.note)
    return finish(args, err, plan, writers, golden, timers, t_wall, notes)


def npz_meta(plan: Plan, scene, model, scene_meshes,
             framing_points: np.ndarray | None = None) -> dict:
    """The --export-npz arrays besides the positions (pipeline.run.shotfile); with
    `framing_points` (pipeline.view.framing.Framing.points), the framing of plan's shot."""
    from pipeline.run.shotfile import framing_record

    spf = scene.simulation.steps_per_frame
    framing = ({} if framing_points is None
               else framing_record(framing_points, plan.shot_frames))
    return {
        "times": np.array(plan.out_times, np.float64),
        "sim_frames": np.array(plan.sim_frames, np.int64),
        "sim_times": np.array([j / plan.sim_fps for j in plan.sim_frames], np.float64),
        **cloth_faces(scene, model, scene_meshes),
        "grid": np.array([model.nh, model.nw], np.int64),
        "fps": np.float64(plan.fps), "sim_fps": np.float64(plan.sim_fps),
        "steps_per_frame": np.int64(spf), **plan.record, **framing,
    }


def cloth_faces(scene, model, scene_meshes) -> dict:
    """The NPZ export's faces and uvs: the grid's triangles and point uvs; a mesh cloth's
    triangles of its points, a uv per point and per face corner (seams split them)."""
    if model.mesh is not None:
        topo = model.mesh.topology
        return {"faces": np.asarray(topo.triangles, np.int32), "uv": topo.point_uv,
                "face_uv": topo.corner_uv}
    cloth = scene_meshes(scene, model.initial_positions, model)[0]
    return {"faces": np.asarray(cloth.triangles, np.int32),
            "uv": np.asarray(cloth.uvs, np.float64)}


def finish(args, err: Errors, plan: Plan, writers: dict, golden, timers: Timers,
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
            what.append(f"{out_w.target} ({fmt_bytes(out_w.nbytes)})")
        for key in ("obj", "npz"):
            if key in writers:
                what.append(f"{writers[key].target} ({fmt_bytes(writers[key].nbytes)})")
        n_out = len(plan.sim_frames)
        size = f" {plan.width}x{plan.height} {plan.shader}" if out_w is not None else ""
        compile_text = f"compile {timers.compile:.2f} s, " if timers.compile else ""
        err.say(f"{n_out} frame{'s' if n_out != 1 else ''}{size} -> {', '.join(what)}; "
                f"{compile_text}simulate {timers.simulate:.2f} s, render {timers.render:.2f} s, "
                f"encode {timers.encode:.2f} s, total {time.perf_counter() - t_wall:.2f} s")
        for line in notes:
            err.say(line)
    return status


def _simulate(sim, frames: Sequence[int], timers: Timers, sim_bar):
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


def _ahead(sim, plan: Plan, scene, framing, timers: Timers, sim_bar):
    """Simulate the whole shot before anything is drawn: every frame of it goes to
    `framing` (pipeline.view.framing), the frames to draw to a temporary file (memory stays
    flat however long the shot; nothing is left behind). Then yield (k, positions) of the
    output frames, as _simulate does."""
    import tempfile

    from pipeline.view.framing import framed_points

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
    from clothjit import numba_threads

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

        from clothjit import THREADS

        if threads_per_stage is not None:
            numba.set_num_threads(threads_per_stage)
        while True:
            item = q.get()
            if item is done or stop.is_set():
                return
            if simulated.is_set() and threads_per_stage is not None:
                # the frames left are drawn on every free core (the image does not depend on it)
                numba.set_num_threads(THREADS)
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


def _check(args, err: Errors, out_w, golden: np.ndarray) -> int:
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
        msg = one_line(exc) if str(exc).strip() else "images differ"
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


def render_on_cluster(args, err, scene_file, overrides, plan, writers, golden, framing,
            t_wall) -> int:
    """`render` with --workers / --scheduler: write plan's frames into writers["out"];
    `framing` (pipeline.view.framing) when the scene has no camera."""
    import distributed

    from pipeline.cluster import client as cluster
    from pipeline.cluster.farm import (DEPTH_PER_THREAD, Shot, chunk_size, frame_shot_here,
                                       next_chunk, simulate_shot)

    timers = Timers()
    out_w = writers["out"]
    view = dict(shader=plan.shader, width=plan.width, height=plan.height, aa=plan.aa)
    if framing is not None:
        t0 = time.perf_counter()
        view["shot"] = frame_shot_here(scene_file, overrides, plan)
        timers.simulate += time.perf_counter() - t0
    with cluster.connect(args) as client:
        threads = cluster.worker_threads(client)
        run = f"clothpipe-{uuid.uuid4().hex}"
        shot = Shot(scene_file, tuple(overrides), list(plan.sim_frames), plan.sim_fps,
                    view, chunk_size(len(plan.sim_frames), threads),
                    DEPTH_PER_THREAD * threads, run)
        queue = distributed.Queue(f"{run}-chunks", client=client)
        stop = distributed.Event(f"{run}-stop", client=client)
        sim = client.submit(simulate_shot, shot, key=f"{run}-simulate")
        out_bar = bar(len(plan.sim_frames), "render", "frame", progress_enabled(args.quiet))
        try:
            for k in range(len(shot.chunks())):
                images, seconds = next_chunk(queue, sim, shot, k).result()
                timers.render += seconds
                t0 = time.perf_counter()
                for image in images:
                    out_w.add(image)
                timers.encode += time.perf_counter() - t0
                out_bar.update(len(images))
            result = sim.result()
        except BaseException:
            stop.set()  # the simulation stops at its next chunk; the rest is released
            raise
        finally:
            out_bar.close()
            queue.close()
        timers.simulate += result.seconds
        notes = [f"on {cluster.where(client, args)}, {len(shot.chunks())} render tasks of "
                 f"up to {shot.chunk} frames (render time summed over the workers)"]
    for w in result.warnings:
        err.warn(w)
    return finish(args, err, plan, writers, golden, timers, t_wall, notes + result.notes)
