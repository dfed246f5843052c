"""A shot written by `render --export-npz`, read back by `render --from` (docs/cli.md).

    arrays = scene_record(SceneFile.read("scene.json"), overrides)  # added to the export
    arrays |= framing_record(framing.points(), plan.shot_frames)     # a framed shot's camera
    shot = read_shot("shot.npz")   # UsageError naming the file and what it expected
    shot.positions[k], shot.times[k], shot.sim_frames[k], shot.scene, shot.overrides
    shot.framing_of(shot_frames)   # the recorded framing of exactly that shot, or None

The export's arrays (`pipeline.run.outputs.NpzWriter`): positions (F, N, 3) float64,
times (F,) output times, sim_frames / sim_times (F,) the simulator frames shown, faces
(T, 3) int32, uv (N, 2), face_uv (T, 3, 2) for a mesh cloth, grid (nh, nw), fps, sim_fps,
steps_per_frame; since npz_format 2 also the scene it came from: scene_name (the path as
given), scene_folder (the absolute folder its relative file names are resolved against),
scene_json (the file's bytes, uint8) and scene_overrides (the run's --set and the flags
that became overrides, in order); and when the scene has no camera and images were drawn,
what framed them (pipeline.view.framing): framing_frames (S,) the simulator frames of the
whole shot framed (more than those recorded when --at or a subset was drawn) and
framing_points (K, 3) the framed points that hold its camera at any image size. Without
them (an older file, or an export without images) --from frames the frames the file holds.
Every array is plain numeric or unicode: np.load reads it without allow_pickle, and readers
of the older keys are unaffected.
"""
from __future__ import annotations

import os
import zipfile
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from pipeline.scene import SceneFile

from .errors import UsageError

#: 1: positions, times, sim_frames, sim_times, faces, uv, grid, fps, sim_fps,
#: steps_per_frame (face_uv for a mesh cloth); 2: and the scene (scene_*), npz_format, and
#: for a framed shot framing_* (optional: read when present)
NPZ_FORMAT = 2

#: what `render --from` needs of any export, old or new
REQUIRED = ("positions", "times", "sim_frames", "fps", "sim_fps")


class ShotFileError(UsageError):
    """A file given to --from that is not a usable --export-npz file (exit status 2)."""

    help_hint = False


@dataclass(frozen=True)
class Shot:
    """A shot read from an --export-npz file; `path` as given (named in messages)."""

    path: str
    positions: np.ndarray  # (F, N, 3) float64
    times: np.ndarray  # (F,) float64: output frame times (s)
    sim_frames: np.ndarray  # (F,) int64: the simulator frame each shows
    fps: float
    sim_fps: float
    faces: np.ndarray | None  # (T, 3) the cloth's triangles, when recorded
    scene: SceneFile | None  # the scene it came from (npz_format >= 2), else None
    overrides: tuple[str, ...]  # the overrides that scene was loaded with
    framing_frames: np.ndarray | None  # (S,) int64: the simulator frames of the shot framed
    framing_points: np.ndarray | None  # (K, 3) float64: the points holding its camera

    @property
    def points(self) -> int:
        return self.positions.shape[1]

    def frame_of(self, sim_frame: int) -> int | None:
        """The index of the first frame showing simulator frame `sim_frame`, or None."""
        hits = np.flatnonzero(self.sim_frames == sim_frame)
        return int(hits[0]) if len(hits) else None

    def framing_of(self, shot_frames: Sequence[int]) -> np.ndarray | None:
        """The recorded points (K, 3) framing a shot of exactly these simulator frames
        (ascending), or None: none recorded, or recorded for another shot."""
        if self.framing_frames is None or list(self.framing_frames) != list(shot_frames):
            return None
        return self.framing_points

    def describe(self) -> str:
        """'75 frames at 25 fps, t = 0 to 2.96 s, simulator frames 0 to 266 at 90 Hz'."""
        n = len(self.times)
        return (f"{n} frame{'s' * (n != 1)} at {self.fps:g} fps, t = {self.times[0]:g} to "
                f"{self.times[-1]:g} s, simulator frames {self.sim_frames[0]} to "
                f"{self.sim_frames[-1]} at {self.sim_fps:g} Hz")


def scene_record(scene: SceneFile, overrides: Sequence[str]) -> dict[str, np.ndarray]:
    """The arrays that record the scene a shot came from (added to the export)."""
    return {
        "npz_format": np.int64(NPZ_FORMAT),
        "scene_name": np.array(scene.name, dtype=str),
        "scene_folder": np.array(scene.folder, dtype=str),
        "scene_json": np.frombuffer(bytes(scene.data), dtype=np.uint8).copy(),
        "scene_overrides": np.array(list(overrides), dtype=str).reshape(-1),
    }


def framing_record(points: np.ndarray, shot_frames: Sequence[int]) -> dict[str, np.ndarray]:
    """The arrays that record the framing of a shot of a scene with no camera (added to the
    export): `points` from Framing(..., record=True).points(), the shot's simulator frames."""
    return {"framing_frames": np.array(list(shot_frames), dtype=np.int64),
            "framing_points": np.asarray(points, dtype=np.float64).reshape(-1, 3)}


def read_shot(path: str | os.PathLike) -> Shot:
    """Read an --export-npz file; ShotFileError (one line naming the file and what was
    expected) for a missing, unreadable or malformed one."""
    name = os.fsdecode(os.fspath(path))

    def bad(what: str) -> ShotFileError:
        return ShotFileError(f"--from {name}: {what}")

    if not os.path.exists(name):
        raise bad("no such file (expected an .npz written by render --export-npz)")
    if os.path.isdir(name):
        raise bad("is a folder (expected an .npz written by render --export-npz)")
    try:
        with open(name, "rb"):
            pass
    except OSError as exc:
        raise bad(f"cannot be read ({exc.strerror or exc})") from None
    if not zipfile.is_zipfile(name):
        raise bad("is not an .npz file (expected an .npz written by render --export-npz)")
    try:
        with np.load(name, allow_pickle=False) as data:
            arrays = {key: data[key] for key in data.files}
    except (OSError, ValueError, EOFError, zipfile.BadZipFile, KeyError) as exc:
        reason = (exc.strerror if isinstance(exc, OSError) and exc.strerror
                  else str(exc).strip().splitlines()[0] if str(exc).strip()
                  else type(exc).__name__)
        raise bad(f"cannot be read as an .npz written by render --export-npz ({reason})"
                  ) from None
    missing = [key for key in REQUIRED if key not in arrays]
    if missing:
        raise bad(f"expected an .npz written by render --export-npz, with "
                  f"{', '.join(REQUIRED)}; it has no {', '.join(missing)}")
    pos = arrays["positions"]
    if pos.ndim != 3 or pos.shape[2] != 3 or pos.shape[0] < 1 or pos.shape[1] < 1 \
            or pos.dtype.kind not in "fi":
        raise bad(f"positions: expected numbers shaped (frames >= 1, points, 3), got "
                  f"{pos.dtype} {pos.shape}")
    n = pos.shape[0]
    for key in ("times", "sim_frames"):
        a = arrays[key]
        if a.shape != (n,) or a.dtype.kind not in ("fi" if key == "times" else "iu"):
            raise bad(f"{key}: expected {n} {'numbers' if key == 'times' else 'whole numbers'}"
                      f" (one per frame of positions), got {a.dtype} {a.shape}")
    fps, sim_fps = (_positive(arrays[key], key, bad) for key in ("fps", "sim_fps"))
    if not np.all(np.isfinite(pos)):
        raise bad("positions: expected finite numbers, found NaN or infinity")
    scene = None
    overrides: tuple[str, ...] = ()
    if "scene_json" in arrays:
        try:
            scene = SceneFile(str(arrays["scene_name"][()]), str(arrays["scene_folder"][()]),
                              arrays["scene_json"].astype(np.uint8).tobytes())
            overrides = tuple(str(s) for s in arrays.get("scene_overrides", np.array([], str)))
        except (KeyError, ValueError, TypeError, IndexError):
            raise bad("scene_name, scene_folder, scene_json: expected the scene record of "
                      "render --export-npz") from None
    framing_frames, framing_points = _framing(arrays, bad)
    faces = arrays.get("faces")
    return Shot(name, np.ascontiguousarray(pos, dtype=np.float64),
                np.asarray(arrays["times"], np.float64),
                np.asarray(arrays["sim_frames"], np.int64), fps, sim_fps,
                None if faces is None else np.asarray(faces), scene, overrides,
                framing_frames, framing_points)


def _framing(arrays: dict, bad) -> tuple[np.ndarray | None, np.ndarray | None]:
    """(framing_frames, framing_points) when recorded, else (None, None)."""
    if "framing_frames" not in arrays and "framing_points" not in arrays:
        return None, None
    frames, points = arrays.get("framing_frames"), arrays.get("framing_points")
    if frames is None or points is None or frames.ndim != 1 or not len(frames) \
            or frames.dtype.kind not in "iu" or points.ndim != 2 or points.shape[1] != 3 \
            or not len(points) or points.dtype.kind != "f" or not np.all(np.isfinite(points)):
        raise bad("framing_frames, framing_points: expected the framing record of render "
                  "--export-npz: simulator frames (S,) and finite points (K, 3)")
    return np.asarray(frames, np.int64), np.asarray(points, np.float64)


def _positive(a: np.ndarray, key: str, bad) -> float:
    try:
        v = float(np.asarray(a).reshape(()))
    except (TypeError, ValueError):
        v = float("nan")
    if not (np.isfinite(v) and v > 0):
        raise bad(f"{key}: expected one positive number, got {np.asarray(a).tolist()!r}")
    return v
