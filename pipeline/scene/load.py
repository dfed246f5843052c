"""Loading a scene: JSON (or a dict) and command-line overrides to a checked `Scene`.

Loading goes: read and parse the JSON (duplicate keys and non-finite numbers are
rejected) -> apply command-line overrides ("dotted.key=value") to the raw dict ->
validate against `schema.json` and the semantic checks the schema cannot express
(pipeline.scene.check) -> build the frozen dataclasses (pipeline.scene.types).
Every failure is a `SceneError` whose message is one line starting with the file name.
"""
from __future__ import annotations

import json
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from .check import (PathItem, Problem, check_cloth_form, check_files, check_finite,
                    check_semantics, collider_items, fmt_path, kind_of, pin_items, resolve_path,
                    show, validate_schema)
from .types import (COLLIDER_KEYS, COURSE_CAMERA, RENDER_PARAMS, VEC3_PARAMS, Box, CameraSettings,
                    Cloth, ClothMeshSource, Collider, FemMaterial, Keyframe, LightSettings,
                    MeshCollider, PinSelection, Plane, RenderSettings, Scene, SceneError,
                    SimulationSettings, Sphere, Vec3, Wind)

_TOP_KEYS = ("cloth", "sphere", "plane", "box", "mesh", "wind", "simulation", "camera", "light",
             "render")




_DICT_SOURCE = "<scene>"


@dataclass(frozen=True)
class SceneFile:
    """A scene file read into memory, to be loaded in another process or on another machine
    exactly as from the file: `name` is the path as given (named in messages), `folder` the
    absolute folder its relative file references are resolved against, `data` its bytes."""

    name: str
    folder: str
    data: bytes

    @classmethod
    def read(cls, path: str | os.PathLike) -> "SceneFile":
        name = os.fsdecode(os.fspath(path))
        return cls(name, os.path.dirname(os.path.abspath(name)), _read_bytes(name))


def load_scene(source: str | os.PathLike | dict | SceneFile,
               overrides: Sequence[str] = ()) -> Scene:
    """Read, check and build a `Scene`.

    `source` is a path to a JSON scene file, a `SceneFile` (the same file's bytes, read
    earlier or elsewhere), or an already-parsed dict (it is not modified; messages then
    name the file "<scene>" and relative paths in `render` are relative to the current
    directory). `overrides` are "dotted.key=value"
    strings applied to the raw data before validation (see `apply_overrides`).

    Raises `SceneError` with a one-line message
    "<file>: <key path>: expected <what>, got <what was there>" on any bad input.
    """
    if isinstance(source, dict):
        file = _DICT_SOURCE
        data: Any = _copy_json(source)
        base_dir = Path.cwd()
        src_path = None
    elif isinstance(source, SceneFile):
        file = source.name
        data = _parse_json(source.data, file)
        base_dir = Path(source.folder)
        src_path = base_dir / os.path.basename(file)
    elif isinstance(source, (str, os.PathLike)):
        file = os.fsdecode(os.fspath(source))
        data = _parse_json(_read_bytes(file), file)
        src_path = Path(os.path.abspath(file))
        base_dir = src_path.parent
    else:
        raise SceneError(f"{_DICT_SOURCE}: expected a path to a JSON file or a dict, "
                         f"got {type(source).__name__}")

    if not isinstance(data, dict):
        raise SceneError(f"{file}: expected a JSON object at top level, got {show(data)}")

    data, touched = _apply_overrides(data, overrides, file)

    try:
        check_finite(data, [])
        check_cloth_form(data)
        validate_schema(data)
        check_semantics(data)
        check_files(data, base_dir)
    except Problem as p:
        raise SceneError(f"{file}: {p.text}{_blame(p.path, touched)}") from None

    return _build(data, base_dir, src_path)


def apply_overrides(data: dict, overrides: Sequence[str], file: str = _DICT_SOURCE) -> dict:
    """Return a copy of the raw scene `data` with "dotted.key=value" overrides applied.

    The value is parsed as JSON when possible (`500`, `false`, `[0,1,3]`, `"x"`), else
    kept as a string (`render.shader=toon`). A number in the path indexes a list
    (`sphere.1.radius=0.3`); index 0 also addresses a collider given as a single object.
    Missing objects along the path are created (and then validated like the rest, so a
    typo becomes an "unknown key" error). Raises `SceneError` for a malformed override.
    """
    return _apply_overrides(_copy_json(data), overrides, file)[0]


def _read_bytes(file: str) -> bytes:
    try:
        with open(file, "rb") as fh:
            return fh.read()
    except OSError as e:
        raise SceneError(f"{file}: cannot read: {e.strerror or e}") from None


def _parse_json(raw: bytes, file: str) -> Any:
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError as e:
        raise SceneError(f"{file}: not valid JSON: not UTF-8 text "
                         f"(byte {e.start}: {e.reason})") from None
    dups: dict[int, str] = {}

    def pairs_hook(pairs):
        d = {}
        for k, v in pairs:
            if k in d and id(d) not in dups:
                dups[id(d)] = k
            d[k] = v
        return d

    try:
        data = json.loads(text, object_pairs_hook=pairs_hook)
    except json.JSONDecodeError as e:
        raise SceneError(f"{file}: not valid JSON: line {e.lineno} column {e.colno}: {e.msg}") from None
    except RecursionError:
        raise SceneError(f"{file}: not valid JSON: nested too deeply") from None
    if dups:
        where = _find_dict(data, dups, [])
        if where is not None:
            path, key = where
            raise SceneError(f"{file}: {fmt_path(path + [key])}: duplicate key "
                             f"(given more than once in the same object)")
    return data


def _find_dict(node: Any, ids: dict[int, str], path: list) -> tuple[list, str] | None:
    if isinstance(node, dict):
        if id(node) in ids:
            return path, ids[id(node)]
        items = node.items()
    elif isinstance(node, list):
        items = enumerate(node)
    else:
        return None
    for k, v in items:
        found = _find_dict(v, ids, path + [k])
        if found is not None:
            return found
    return None


def _copy_json(node: Any) -> Any:
    """Deep copy of JSON-like data; tuples become lists (handy for dicts built in Python)."""
    if isinstance(node, dict):
        return {k: _copy_json(v) for k, v in node.items()}
    if isinstance(node, (list, tuple)):
        return [_copy_json(v) for v in node]
    return node


def _apply_overrides(data: dict, overrides: Sequence[str], file: str
                     ) -> tuple[dict, list[tuple[list[PathItem], str]]]:
    """Apply overrides in place on `data` (already a private copy). Returns the data and
    the (path, override) pairs, so later errors can name the override responsible."""
    if isinstance(overrides, str):  # a lone string would otherwise be split into chars
        overrides = [overrides]
    touched: list[tuple[list[PathItem], str]] = []
    for ov in overrides:
        def bad(why: str) -> SceneError:
            return SceneError(f"{file}: override {ov!r}: {why}")

        if not isinstance(ov, str):
            raise SceneError(f"{file}: override {ov!r}: expected a string 'dotted.key=value'")
        if "=" not in ov:
            raise bad("expected 'dotted.key=value', got no '='")
        key, _, text = ov.partition("=")
        parts = [p.strip() for p in key.strip().split(".")]
        if not key.strip() or any(not p for p in parts):
            raise bad(f"expected 'dotted.key=value', got an empty key in {key.strip()!r}")
        try:
            value = json.loads(text)
        except (ValueError, RecursionError):
            value = text
        node: Any = data
        path: list[PathItem] = []
        for n, part in enumerate(parts):
            last = n == len(parts) - 1
            if isinstance(node, dict):
                # a collider given as one object is addressed like a list of one
                if (part.isdigit() and len(path) == 1 and path[0] in COLLIDER_KEYS
                        and part not in node):
                    data[path[0]] = node = [node]
                else:
                    if last:
                        node[part] = value
                    elif not isinstance(node.get(part), (dict, list)):
                        if part in node:
                            raise bad(f"{fmt_path(path + [part])} is "
                                      f"{kind_of(node[part])}, not an object or a list")
                        node[part] = {}
                        touched.append((path + [part], ov))  # errors inside it are the override's
                    path.append(part)
                    node = node.get(part) if not last else None
                    continue
            if isinstance(node, list):
                if not part.isdigit():
                    raise bad(f"{fmt_path(path)} is a list: expected a number index, got {part!r}")
                i = int(part)
                if i >= len(node):
                    raise bad(f"{fmt_path(path + [i])}: index out of range "
                              f"({fmt_path(path)} has {len(node)} item{'s' * (len(node) != 1)})")
                path.append(i)
                if last:
                    node[i] = value
                elif isinstance(node[i], (dict, list)):
                    node = node[i]
                else:
                    raise bad(f"{fmt_path(path)} is {kind_of(node[i])}, not an object or a list")
            else:
                raise bad(f"{fmt_path(path)} is {kind_of(node)}, not an object or a list")
        touched.append((path, ov))
    return data, touched


def _blame(path: list[PathItem] | None, touched: list[tuple[list[PathItem], str]]) -> str:
    if path is None:
        return ""
    for opath, ov in reversed(touched):
        n = min(len(opath), len(path))
        if list(opath[:n]) == list(path[:n]):
            return f" (from override {ov!r})"
    return ""


def _build(data: dict, base_dir: Path, src_path: Path | None) -> Scene:
    cloth = _cloth(data["cloth"], base_dir)
    colliders = [_collider(path[0], obj, base_dir) for path, obj in collider_items(data)]
    wind = None
    if "wind" in data:
        w, wd = data["wind"], Wind()
        wind = Wind(velocity=_vec3(w.get("velocity", wd.velocity)),
                    **{k: float(w.get(k, getattr(wd, k))) for k in
                       ("air_density", "drag", "lift", "gust", "gust_scale", "gust_time")})

    s = data.get("simulation", {})
    d = SimulationSettings()
    simulation = SimulationSettings(
        frames_per_sec=float(s.get("frames_per_sec", d.frames_per_sec)),
        steps_per_frame=int(s.get("steps_per_frame", d.steps_per_frame)),
        gravity=_vec3(s.get("gravity", d.gravity)),
        model=str(s.get("model", d.model)),
        integrator=str(s.get("integrator", d.integrator)),
        seed=int(s.get("seed", d.seed)),
        self_collision=s.get("self_collision", d.self_collision),
        fidelity=str(s.get("fidelity", d.fidelity)),
        tolerance_px=float(s.get("tolerance_px", d.tolerance_px)),
        contact=str(s.get("contact", d.contact)),
        iterations=int(s.get("iterations", d.iterations)),
    )

    cam = data.get("camera")
    camera: CameraSettings | str | None = cam if cam == COURSE_CAMERA else None
    if isinstance(cam, dict):
        camera = CameraSettings(position=_vec3(cam["position"]), target=_vec3(cam["target"]),
                                up=_vec3(cam.get("up", CameraSettings.up)),
                                vfov=float(cam.get("vfov", CameraSettings.vfov)))

    li = data.get("light", {})
    light = LightSettings(position=_vec3(li.get("position", LightSettings.position)),
                          intensity=_vec3(li.get("intensity", LightSettings.intensity)),
                          radius=float(li.get("radius", LightSettings.radius)))

    r = data.get("render", {})
    rd = RenderSettings()

    def path_of(key: str) -> Path | None:
        return resolve_path(base_dir, r[key]) if key in r else None

    params: dict[str, Any] = {}
    for key in RENDER_PARAMS:
        if key in r:
            params[key] = _vec3(r[key]) if key in VEC3_PARAMS else float(r[key])
    render = RenderSettings(
        shader=str(r.get("shader", rd.shader)), width=int(r.get("width", rd.width)),
        height=int(r.get("height", rd.height)), aa=int(r.get("aa", rd.aa)),
        background=_vec3(r.get("background", rd.background)),
        texture=path_of("texture"), height_map=path_of("height_map"), cubemap=path_of("cubemap"),
        shadows=bool(r.get("shadows", rd.shadows)),
        ambient_occlusion=bool(r.get("ambient_occlusion", rd.ambient_occlusion)), params=params,
    )
    return Scene(cloth=cloth, colliders=tuple(colliders), wind=wind, simulation=simulation,
                 camera=camera, light=light, render=render, source=src_path)


def _cloth(c: dict, base_dir: Path) -> Cloth:
    common = dict(
        thickness=float(c["thickness"]), damping=float(c["damping"]),
        density=float(c["density"]), ks=float(c["ks"]),
        enable_structural=bool(c.get("enable_structural", True)),
        enable_shearing=bool(c.get("enable_shearing", True)),
        enable_bending=bool(c.get("enable_bending", True)),
        mass_map=_mass_map(c.get("mass_map"), base_dir),
        mass_map_range=tuple(float(v) for v in c.get("mass_map_range", Cloth.mass_map_range)),
        fem=FemMaterial(**{k: float(v) for k, v in c.get("fem", {}).items()}),
        friction=float(c.get("friction", Cloth.friction)),
    )
    if "mesh" not in c:
        return Cloth(
            width=float(c["width"]), height=float(c["height"]),
            num_width_points=int(c["num_width_points"]),
            num_height_points=int(c["num_height_points"]), orientation=int(c["orientation"]),
            pinned=tuple((int(x), int(y)) for x, y in c.get("pinned", ())), **common)
    zero = (0.0, 0.0, 0.0)
    scale = c.get("scale", 1.0)
    source = ClothMeshSource(
        path=resolve_path(base_dir, c["mesh"]), translation=_vec3(c.get("translation", zero)),
        rotation=_vec3(c.get("rotation", zero)),
        scale=_vec3(scale) if isinstance(scale, list) else (float(scale),) * 3,
        pieces_allowed=c.get("pieces", "refuse") == "allow")
    pins = []
    for path, item in pin_items(c):
        key = fmt_path(path)
        if isinstance(item, dict):
            pins.append(PinSelection(
                key=key, indices=tuple(int(i) for i in item.get("indices", ())),
                box=(_vec3(item["box"][0]), _vec3(item["box"][1])) if "box" in item else None,
                group=str(item["group"]) if "group" in item else None,
                keyframes=_keyframes(item)))
        else:  # a bare vertex index: a selection of its own, named by its place in the list
            pins.append(PinSelection(key=key, indices=(int(item),)))
    return Cloth(width=0.0, height=0.0, num_width_points=0, num_height_points=0, orientation=0,
                 mesh=source, pin_selections=tuple(pins), **common)


def _mass_map(value, base_dir: Path):
    if value is None:
        return None
    if isinstance(value, str):
        return resolve_path(base_dir, value)
    return tuple(tuple(float(v) for v in row) for row in value)


def _keyframes(obj: dict) -> tuple[Keyframe, ...]:
    zero = (0.0, 0.0, 0.0)
    return tuple(Keyframe(time=float(k["time"]), translation=_vec3(k.get("translation", zero)),
                          rotation=_vec3(k.get("rotation", zero)))
                 for k in obj.get("keyframes", ()))


def _collider(key: str, obj: dict, base_dir: Path) -> Collider:
    friction, keys = float(obj["friction"]), _keyframes(obj)
    look = {"color": _vec3(obj["color"]) if "color" in obj else None,
            "shader": str(obj["shader"]) if "shader" in obj else None}
    if key == "sphere":
        return Sphere(origin=_vec3(obj["origin"]), radius=float(obj["radius"]),
                      friction=friction, keyframes=keys, **look)
    if key == "plane":
        return Plane(point=_vec3(obj["point"]), normal=_vec3(obj["normal"]), friction=friction,
                     keyframes=keys, **look)
    zero = (0.0, 0.0, 0.0)
    if key == "box":
        return Box(center=_vec3(obj["center"]), half_extents=_vec3(obj["half_extents"]),
                   friction=friction, rotation=_vec3(obj.get("rotation", zero)), keyframes=keys,
                   **look)
    scale = obj.get("scale", 1.0)
    return MeshCollider(
        path=resolve_path(base_dir, obj["path"]), friction=friction,
        translation=_vec3(obj.get("translation", zero)), rotation=_vec3(obj.get("rotation", zero)),
        scale=_vec3(scale) if isinstance(scale, list) else (float(scale),) * 3,
        solid=bool(obj.get("solid", True)), thickness=float(obj.get("thickness", 0.005)),
        keyframes=keys, **look)


def _vec3(v) -> Vec3:
    return (float(v[0]), float(v[1]), float(v[2]))

