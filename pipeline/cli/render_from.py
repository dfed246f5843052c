"""`render --from SHOT.npz`: draw again a shot that `--export-npz` recorded, without
simulating it: another shader, size, anti-aliasing, camera, light or look (docs/cli.md).

    render --from shot.npz --out toon.gif --shader toon        # the scene the NPZ records
    render scenes/sphere.json --from shot.npz --out x.png --at 1 --set camera.vfov=25

The scene (the one named, else the one the NPZ records, with the overrides it was loaded
with) gives the colliders, camera, light and render settings, this run's --set on top; the
cloth's positions are the NPZ's, frame by frame, at the NPZ's times (keyframed colliders
posed at each frame's simulator time, as a simulating run draws them). By default the
output frames are the NPZ's; --duration, --frames, --fps and --at choose others, each of
which must be a frame the NPZ holds. The frames are the same bytes as those of the run that
simulated the shot, given the same shader, size, aa and scene. A scene with no camera is
framed over the whole shot that run framed (recorded in the NPZ: framing_*), also when it
drew only part of it (--at, --frames), at any --size; else over the frames the NPZ holds.
"""
from __future__ import annotations

import os
import time
import warnings
from fractions import Fraction
from typing import TYPE_CHECKING

from pipeline.run import outputs
from pipeline.run.errors import UsageError

from .messages import Errors, one_line
from .render import (Plan, open_writers, read_golden, Timers, check_shader, cloth_faces,
                     finish, nearest_sim_frames, npz_meta, output_kind, output_times,
                     scene_overrides, write_frame)

if TYPE_CHECKING:
    import numpy as np

    from pipeline.run.shotfile import Shot
    from pipeline.view.framing import Framing


class FromError(UsageError):
    """A command line `--from` cannot honour (exit status 2, one line)."""

    help_hint = False


#: flags that only steer the simulation, which --from does not run
SIMULATION_FLAGS = (("integrator", "--integrator"), ("fidelity", "--fidelity"),
                    ("tolerance", "--tolerance"), ("contact", "--contact"), ("seed", "--seed"))
#: scene keys that only steer the simulation: --set refuses them with --from
SIMULATION_KEYS = ("simulation", "wind")


def refuse_flags(args) -> None:
    """FromError for a flag that makes no sense when nothing is simulated."""
    for dest, flag in SIMULATION_FLAGS:
        if getattr(args, dest, None) is not None:
            raise FromError(f"{flag}: not with --from (the shot in {args.from_npz} is drawn as "
                            "it was simulated, not simulated again)")
    if getattr(args, "workers", None) is not None or getattr(args, "scheduler", None):
        raise FromError("--workers / --scheduler: not with --from (a recorded shot is drawn "
                        "in this process)")
    for text in args.overrides:
        key = text.partition("=")[0].strip()
        if key.split(".")[0] in SIMULATION_KEYS:
            raise FromError(f"--set {text}: not with --from ({key.split('.')[0]} keys steer "
                            f"the simulation; the shot in {args.from_npz} is not simulated "
                            "again)")
    if args.export_npz and _same_file(args.export_npz, args.from_npz):
        raise FromError(f"--export-npz {args.export_npz}: the file --from reads; write the "
                        "export to another file")


def _same_file(a: str, b: str) -> bool:
    try:
        return os.path.samefile(a, b)
    except OSError:
        return os.path.realpath(a) == os.path.realpath(b)


def run_from(args, err: Errors, t_wall: float) -> int:
    """`render [SCENE] --from SHOT.npz ...`: returns 0, or 3 after a failed --check."""
    from pipeline.run.shotfile import read_shot
    from pipeline.scene import SceneFile, load_scene

    refuse_flags(args)
    kind, out = output_kind(args)
    golden = read_golden(args.check) if args.check else None
    shot = read_shot(args.from_npz)
    if args.scene is not None:  # the scene named, as it is now, and this run's --set
        source, overrides = SceneFile.read(args.scene), scene_overrides(args)
    elif shot.scene is not None:  # the recorded scene and the overrides it was loaded with
        source, overrides = shot.scene, list(shot.overrides) + scene_overrides(args)
    else:
        raise FromError(f"--from {shot.path}: records no scene (written before --export-npz "
                        "recorded it): name the scene it came from, render SCENE.json --from "
                        f"{shot.path} ...")
    with warnings.catch_warnings():
        warnings.simplefilter("default")
        warnings.showwarning = lambda message, category, *a, **k: err.warn(
            one_line(message) if str(message).strip() else category.__name__)
        scene = load_scene(source, overrides)
        from pipeline.run.frames import render_frame, scene_meshes
        from pipeline.simulation import cloth_model

        model = cloth_model(scene)  # the cloth the simulating run drew: edges, seams, camera
    _check_cloth(shot, scene, source, model, scene_meshes)
    plan = plan_from(args, kind, out, scene, shot)
    if args.export_npz:
        from pipeline.run.shotfile import scene_record

        plan.record = scene_record(source, overrides)
    framing, framing_points = framing_from(args, scene, shot, plan)
    writers = open_writers(plan, args)
    try:
        return _draw(args, err, scene, plan, model, shot, writers, golden, framing,
                     framing_points, t_wall, render_frame, scene_meshes)
    except BaseException:
        for writer in writers.values():
            writer.abort()
        raise


def framing_from(args, scene, shot: Shot,
                 plan: Plan) -> tuple[Framing | None, np.ndarray | None]:
    """The Framing of a scene with no camera drawn to images (else None), and the points an
    --export-npz records of it (else None): the NPZ's record when it framed this very shot
    (its run framed all of it, the frames it did not keep too), else the NPZ's frames of
    the shot (plan_from made sure it holds them)."""
    if scene.camera is not None:
        return None, None
    recorded = shot.framing_of(plan.shot_frames)
    if plan.kind is None:
        return None, recorded  # nothing drawn: an export keeps the record
    from pipeline.view.framing import Framing, framed_points

    if recorded is not None:
        framing = Framing(plan.width, plan.height)
        framing.add(recorded)
        return framing, recorded
    framing = Framing(plan.width, plan.height, record=bool(args.export_npz))
    for j in plan.shot_frames:
        framing.add(framed_points(scene, shot.positions[shot.frame_of(j)], j / plan.sim_fps))
    return framing, framing.points() if args.export_npz else None


def _check_cloth(shot, scene, source, model, scene_meshes) -> None:
    """FromError when the scene's cloth is not the NPZ's (points, then triangles)."""
    name = source.name
    if model.n != shot.points:
        raise FromError(f"--from {shot.path}: holds a cloth of {shot.points} points, but the "
                        f"cloth of {name} has {model.n}: expected the scene (and --set) the "
                        "shot was simulated with")
    if shot.faces is not None:
        faces = cloth_faces(scene, model, scene_meshes)["faces"]
        if shot.faces.shape != faces.shape or not (shot.faces == faces).all():
            raise FromError(f"--from {shot.path}: its cloth's triangles are not those of the "
                            f"cloth of {name}: expected the scene (and --set) the shot was "
                            "simulated with")


def plan_from(args, kind, out, scene, shot) -> Plan:
    """The frames to draw: the NPZ's own, or those --duration / --frames / --fps / --at
    ask for (the same as a simulating run's), each of which the NPZ must hold."""
    fps = args.fps if args.fps is not None else shot.fps
    if kind == "gif" and fps > outputs.GIF_MAX_FPS:
        raise FromError(f"--from {shot.path}: its {fps:g} fps is too high for a GIF (at most "
                        f"{outputs.GIF_MAX_FPS:g}): give --fps, or write an .mp4")
    sim_fps = shot.sim_fps
    if args.fps is None and args.duration is None and args.frames is None:
        times = [float(t) for t in shot.times]  # the NPZ's frames, at its times
        frames = [int(j) for j in shot.sim_frames]
        # of the shot that was framed, when recorded (a --at run drew one frame of it)
        animation = (list(frames) if shot.framing_frames is None
                     else [int(j) for j in shot.framing_frames])
        if kind == "png":
            if args.at is not None:
                t = Fraction(args.at).limit_denominator(1000000)
                times, frames = [float(t)], nearest_sim_frames([t], sim_fps)
            else:
                times, frames = times[-1:], frames[-1:]
    else:  # as a simulating run: k / fps, the NPZ's length unless --duration / --frames
        n = args.frames if args.frames is not None else max(1, round(
            (args.duration if args.duration is not None else len(shot.times) / shot.fps) * fps))
        anim_times = output_times(n, fps)
        animation = nearest_sim_frames(anim_times, sim_fps)
        chosen = anim_times
        if kind == "png":
            chosen = [Fraction(args.at).limit_denominator(1000000) if args.at is not None
                      else anim_times[-1]]
        times, frames = [float(t) for t in chosen], nearest_sim_frames(chosen, sim_fps)
    shot_frames = sorted(set(animation) | set(frames))
    # framed over the NPZ's frames unless it records the framing of this very shot
    framed_here = (scene.camera is None and kind is not None
                   and shot.framing_of(shot_frames) is None)
    needed = shot_frames if framed_here else sorted(set(frames))
    for j in needed:
        if shot.frame_of(j) is None:
            t = j / sim_fps
            raise FromError(f"--from {shot.path}: holds no frame at t = {t:.4g} s (simulator "
                            f"frame {j}); it holds {shot.describe()}: choose --at, "
                            "--duration, --frames or --fps within those")
    shader = args.shader if args.shader is not None else scene.render.shader
    check_shader(shader)
    width, height = args.size if args.size is not None else (scene.render.width,
                                                             scene.render.height)
    aa = args.aa if args.aa is not None else scene.render.aa
    return Plan(kind=kind, out=out, fps=fps, out_times=times, sim_frames=frames,
                shot_frames=shot_frames, sim_fps=sim_fps, shader=shader, width=int(width),
                height=int(height), aa=int(aa))


def _draw(args, err, scene, plan, model, shot, writers, golden, framing, framing_points,
          t_wall, render_frame, scene_meshes) -> int:
    """Draw, export and encode every planned frame from the NPZ's positions (an export
    records `framing_points`, when given)."""
    timers = Timers()
    out_w, obj_w, npz_w = (writers.get(key) for key in ("out", "obj", "npz"))
    names = None
    from pipeline.run.progress import bar, progress_enabled

    out_bar = bar(len(plan.sim_frames), "render", "frame", progress_enabled(args.quiet))
    try:
        for j in plan.sim_frames:
            pos = shot.positions[shot.frame_of(j)]
            t_sim = j / plan.sim_fps  # keyframed colliders are drawn there, as when simulated
            img = None
            if out_w is not None:
                t0 = time.perf_counter()
                img = render_frame(scene, pos, model, shader=plan.shader, width=plan.width,
                                   height=plan.height, aa=plan.aa, time=t_sim, shot=framing)
                timers.render += time.perf_counter() - t0
            names = write_frame((out_w, obj_w, npz_w), img, pos, t_sim, scene, model, timers,
                                names, scene_meshes)
            out_bar.update(1)
    finally:
        out_bar.close()
    if npz_w is not None:
        npz_w.set_meta(**npz_meta(plan, scene, model, scene_meshes, framing_points))
    return finish(args, err, plan, writers, golden, timers, t_wall,
                  [f"drawn from {shot.path}: {shot.describe()}; nothing simulated"])
