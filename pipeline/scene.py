"""Scene description: typed, validated, with every default filled in.

`load_scene` (below) turns a JSON file or dict into a `Scene`. The dataclasses here are
the only shape the rest of the pipeline sees; nothing downstream reads raw JSON.

Loading goes: read and parse the JSON (duplicate keys and non-finite numbers are
rejected) -> apply command-line overrides ("dotted.key=value") to the raw dict ->
validate with `jsonschema` against `scene_schema.json` (packaged next to this module;
the integrator and shader enums are injected from `INTEGRATORS` and `SHADERS`) ->
semantic checks the schema cannot express -> build the frozen dataclasses.
Every failure is a `SceneError` whose message is one line starting with the file name.
The reference of every key is docs/scene-format.md.

This module must stay light: it imports no numba/numpy (jsonschema is imported lazily).
"""
from __future__ import annotations

import copy
import difflib
import functools
import json
import math
import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

__all__ = [
    "INTEGRATORS", "SHADERS", "RENDER_PARAMS", "SceneError", "Cloth", "Sphere", "Plane", "Box",
    "MeshCollider", "Keyframe", "Collider", "Wind", "FemMaterial", "MODELS", "SimulationSettings", "CameraSettings", "COURSE_CAMERA", "LightSettings", "RenderSettings",
    "Scene", "SceneFile", "load_scene", "apply_overrides", "scene_schema",
]

#: Known integrator names for `simulation.integrator` (the first is the default).
#: The schema's enum is built from this tuple at load time: adding one is one edit here.
INTEGRATORS: tuple[str, ...] = (
    "verlet", "euler", "symplectic-euler", "rk4", "implicit-euler", "xpbd")

#: Cloth models for `simulation.model` (the first is the default).
MODELS: tuple[str, ...] = ("classic", "fem")

#: Known shader names for `render.shader` (schema enum built from this tuple).
SHADERS: tuple[str, ...] = (
    "normal", "wireframe", "diffuse", "phong", "texture", "bump", "displacement", "mirror", "toon",
)

#: Shader constants that `render` may give; stored in `RenderSettings.params` when given.
#: Values: float, or a tuple of 3 floats for the vec3 ones (I_a, k_d).
RENDER_PARAMS: tuple[str, ...] = ("k_a", "I_a", "k_s", "p", "k_h", "k_n", "k_d")
_VEC3_PARAMS = frozenset({"I_a", "k_d"})

Vec3 = tuple[float, float, float]


class SceneError(ValueError):
    """Bad scene input. `str(err)` is the one-line message shown to the user."""


@dataclass(frozen=True)
class FemMaterial:
    """The `cloth.fem` block (docs/fem.md): the finite-element model's material, physical
    units; the defaults are a cotton broadcloth."""

    stretch: float = 300.0  # N/m
    shear: float = 30.0  # N/m
    bending: float = 1e-5  # N m
    density: float = 0.15  # kg/m^2


@dataclass(frozen=True)
class Cloth:
    """The `cloth` block (docs/scene-format.md): a grid of point masses joined by springs."""

    width: float
    height: float
    num_width_points: int
    num_height_points: int
    thickness: float
    orientation: int  # 0 horizontal (y = 1 plane), 1 vertical (z ~ 0 plane)
    damping: float  # percent
    density: float
    ks: float
    enable_structural: bool = True
    enable_shearing: bool = True
    enable_bending: bool = True
    pinned: tuple[tuple[int, int], ...] = ()  # (x_index, y_index) = (column j, row i)
    # Per-point mass multipliers, rows top edge first (see docs/scene-format.md): a tuple of
    # rows of floats, an absolute image path, or None (uniform).
    mass_map: tuple[tuple[float, ...], ...] | Path | None = None
    mass_map_range: tuple[float, float] = (1.0, 2.0)  # image: black, white multipliers
    fem: FemMaterial = FemMaterial()  # used when simulation.model is "fem"


@dataclass(frozen=True)
class Keyframe:
    """A collider pose at `time`: offsets from the pose the scene file gives."""

    time: float
    translation: Vec3 = (0.0, 0.0, 0.0)
    rotation: Vec3 = (0.0, 0.0, 0.0)  # Euler angles in degrees, R = Rz Ry Rx


@dataclass(frozen=True)
class Sphere:
    """A `sphere` collider."""

    origin: Vec3
    radius: float
    friction: float
    keyframes: tuple[Keyframe, ...] = ()

    @property
    def pivot(self) -> Vec3:
        """The point keyframe rotations turn about."""
        return self.origin


@dataclass(frozen=True)
class Plane:
    """A `plane` collider."""

    point: Vec3
    normal: Vec3  # as written in the scene (not normalised)
    friction: float
    keyframes: tuple[Keyframe, ...] = ()

    @property
    def pivot(self) -> Vec3:
        return self.point


@dataclass(frozen=True)
class Box:
    """A `box` collider: a solid oriented cuboid."""

    center: Vec3
    half_extents: Vec3
    friction: float
    rotation: Vec3 = (0.0, 0.0, 0.0)  # Euler angles in degrees, R = Rz Ry Rx
    keyframes: tuple[Keyframe, ...] = ()

    @property
    def pivot(self) -> Vec3:
        return self.center


@dataclass(frozen=True)
class MeshCollider:
    """A `mesh` collider: a triangle mesh file placed at R (scale * v) + translation."""

    path: Path  # absolute
    friction: float
    translation: Vec3 = (0.0, 0.0, 0.0)
    rotation: Vec3 = (0.0, 0.0, 0.0)  # Euler angles in degrees, R = Rz Ry Rx
    scale: Vec3 = (1.0, 1.0, 1.0)
    solid: bool = True  # closed solid (watertight) or one-sided surface
    thickness: float = 0.005  # metres kept between points and the surface
    keyframes: tuple[Keyframe, ...] = ()

    @property
    def pivot(self) -> Vec3:
        return self.translation


Collider = Sphere | Plane | Box | MeshCollider


@dataclass(frozen=True)
class Wind:
    """The `wind` block (docs/wind.md): air velocity, aerodynamic coefficients, gusts."""

    velocity: Vec3 = (0.0, 0.0, 0.0)
    air_density: float = 1.225
    drag: float = 1.0
    lift: float = 0.5
    gust: float = 0.0
    gust_scale: float = 1.0
    gust_time: float = 1.0


@dataclass(frozen=True)
class SimulationSettings:
    """The `simulation` block, defaults filled in."""

    frames_per_sec: float = 90.0
    steps_per_frame: int = 30
    gravity: Vec3 = (0.0, -9.8, 0.0)
    model: str = "classic"
    integrator: str = "verlet"
    seed: int = 0
    self_collision: bool | str = "auto"  # True, False or "auto" (on for vertical cloth)
    fidelity: str = "exact"  # "exact" or "auto" (pipeline.fidelity)
    tolerance_px: float = 1.0  # auto: screen-space error a frame may add


#: `"camera": "course"`: the course viewer's camera exactly (SPEC section 4).
COURSE_CAMERA = "course"


@dataclass(frozen=True)
class CameraSettings:
    """The `camera` block (position and target required when the block is given)."""

    position: Vec3
    target: Vec3
    up: Vec3 = (0.0, 1.0, 0.0)
    vfov: float = 35.0  # degrees


@dataclass(frozen=True)
class LightSettings:
    """The `light` block, defaults filled in."""

    position: Vec3 = (0.5, 2.0, 2.0)
    intensity: Vec3 = (3.0, 3.0, 3.0)


@dataclass(frozen=True)
class RenderSettings:
    """The `render` block. Paths are absolute (resolved against the scene file's folder);
    `params` holds only the shader constants the scene gives (floats or 3-tuples)."""

    shader: str = "phong"
    width: int = 512
    height: int = 512
    aa: int = 1
    background: Vec3 = (0.2, 0.25, 0.3)
    texture: Path | None = None  # None: the packaged default
    height_map: Path | None = None
    cubemap: Path | None = None  # folder with posx..negz images
    # Shader constants overriding SPEC section 5 defaults: k_a, I_a, k_s, p, k_h, k_n, ...
    params: dict[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class Scene:
    """A whole validated scene, every default filled in."""

    cloth: Cloth
    colliders: tuple[Collider, ...] = ()  # in the order the scene lists them
    wind: Wind | None = None  # None: no air
    simulation: SimulationSettings = SimulationSettings()
    #: a camera object; COURSE_CAMERA; None: the course direction framing the whole shot
    #: (pipeline.framing)
    camera: CameraSettings | str | None = None
    light: LightSettings = LightSettings()
    render: RenderSettings = RenderSettings()
    source: Path | None = None  # the scene file, when loaded from one

    @property
    def self_collision(self) -> bool:
        """The resolved self-collision switch: "auto" means on for vertical cloth only."""
        sc = self.simulation.self_collision
        return self.cloth.orientation == 1 if sc == "auto" else bool(sc)


# --------------------------------------------------------------------------------------
# Loading
# --------------------------------------------------------------------------------------

_TOP_KEYS = ("cloth", "sphere", "plane", "box", "mesh", "wind", "simulation", "camera", "light",
             "render")
_COLLIDER_KEYS = ("sphere", "plane", "box", "mesh")
_DICT_SOURCE = "<scene>"

PathItem = str | int


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
        raise SceneError(f"{file}: expected a JSON object at top level, got {_show(data)}")

    data, touched = _apply_overrides(data, overrides, file)

    try:
        _check_finite(data, [])
        _validate_schema(data)
        _check_semantics(data)
        _check_files(data, base_dir)
    except _Problem as p:
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


@functools.lru_cache(maxsize=8)
def _schema_and_validator(integrators: tuple[str, ...], shaders: tuple[str, ...]):
    import importlib.resources

    import jsonschema

    if __package__:
        text = importlib.resources.files(__package__).joinpath(
            "scene_schema.json").read_text(encoding="utf-8")
    else:  # this file loaded on its own, not as part of the package
        text = Path(__file__).with_name("scene_schema.json").read_text(encoding="utf-8")
    schema = json.loads(text)
    defs = schema["$defs"]
    defs["simulation"]["properties"]["integrator"]["enum"] = list(integrators)
    defs["simulation"]["properties"]["model"]["enum"] = list(MODELS)
    defs["render"]["properties"]["shader"]["enum"] = list(shaders)
    # the schema's own validity is a test (test_the_schema_is_a_valid_draft_2020_12_schema):
    # checking it here cost every run 0.13 s
    return schema, jsonschema.Draft202012Validator(schema)


def scene_schema() -> dict:
    """The scene JSON Schema (draft 2020-12) as used by `load_scene`, enums filled in."""
    return copy.deepcopy(_schema_and_validator(INTEGRATORS, SHADERS)[0])


# --- reading ------------------------------------------------------------------------------

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
            raise SceneError(f"{file}: {_fmt_path(path + [key])}: duplicate key "
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


# --- overrides ----------------------------------------------------------------------------

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
                if (part.isdigit() and len(path) == 1 and path[0] in _COLLIDER_KEYS
                        and part not in node):
                    data[path[0]] = node = [node]
                else:
                    if last:
                        node[part] = value
                    elif not isinstance(node.get(part), (dict, list)):
                        if part in node:
                            raise bad(f"{_fmt_path(path + [part])} is "
                                      f"{_kind(node[part])}, not an object or a list")
                        node[part] = {}
                        touched.append((path + [part], ov))  # errors inside it are the override's
                    path.append(part)
                    node = node.get(part) if not last else None
                    continue
            if isinstance(node, list):
                if not part.isdigit():
                    raise bad(f"{_fmt_path(path)} is a list: expected a number index, got {part!r}")
                i = int(part)
                if i >= len(node):
                    raise bad(f"{_fmt_path(path + [i])}: index out of range "
                              f"({_fmt_path(path)} has {len(node)} item{'s' * (len(node) != 1)})")
                path.append(i)
                if last:
                    node[i] = value
                elif isinstance(node[i], (dict, list)):
                    node = node[i]
                else:
                    raise bad(f"{_fmt_path(path)} is {_kind(node[i])}, not an object or a list")
            else:
                raise bad(f"{_fmt_path(path)} is {_kind(node)}, not an object or a list")
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


# --- checks -------------------------------------------------------------------------------

class _Problem(Exception):
    """A check failure: `text` is the message after "<file>: ", `path` the key path named."""

    def __init__(self, path: list[PathItem] | None, text: str):
        super().__init__(text)
        self.path = path
        self.text = text


def _check_finite(node: Any, path: list[PathItem]) -> None:
    if isinstance(node, float) and not math.isfinite(node):
        raise _Problem(path, f"{_fmt_path(path)}: expected a finite number, got {_show(node)}")
    if isinstance(node, dict):
        for k, v in node.items():
            _check_finite(v, path + [k])
    elif isinstance(node, list):
        for i, v in enumerate(node):
            _check_finite(v, path + [i])


def _validate_schema(data: dict) -> None:
    schema, validator = _schema_and_validator(INTEGRATORS, SHADERS)
    err = _pick(validator.iter_errors(data), schema)
    if err is not None:
        raise _translate(err, schema)


def _pick(errors, root: dict):
    """The most useful error, as `jsonschema.exceptions.best_match` picks it (the shallowest
    first), with two refinements: an unknown key beats a missing one in the same object
    (a typo causes both, and the unknown-key message carries the "did you mean" hint), and
    for a `oneOf` (collider: object or list) we descend into the branch whose type matches
    the value, instead of giving up when the branches' errors tie."""
    from jsonschema.exceptions import best_match, by_relevance

    key = by_relevance(strong=frozenset({"additionalProperties"}))
    errors = list(errors)
    best = max(errors, key=key, default=None)
    if best is None or best.validator not in ("oneOf", "anyOf"):
        return best_match(errors, key=key)
    # best_match's own descent into a oneOf gives up (or picks the wrong branch) on ties
    while best is not None and best.validator in ("oneOf", "anyOf") and best.context:
        kind = "object" if isinstance(best.instance, dict) else (
            "array" if isinstance(best.instance, list) else None)
        branches = [i for i, sub in enumerate(best.validator_value)
                    if _resolve(sub, root).get("type") == kind]
        sub_errors = [e for e in best.context
                      if e.relative_schema_path and e.relative_schema_path[0] in branches]
        if not sub_errors:
            break
        best = max(sub_errors, key=key)
    return best


def _translate(err, root: dict) -> _Problem:
    """Turn one jsonschema ValidationError into a one-line `_Problem`."""
    path = list(err.absolute_path)
    sch = err.schema if isinstance(err.schema, dict) else {}
    inst = err.instance
    kw = err.validator
    if kw == "additionalProperties" and isinstance(inst, dict):
        allowed = list(sch.get("properties", {}))
        unknown = [k for k in inst if k not in allowed]
        key = unknown[0] if unknown else "?"
        hint = difflib.get_close_matches(str(key), allowed, n=1, cutoff=0.6)
        extra = f"did you mean {hint[0]!r}? " if hint else ""
        where = "at top level" if not path else f"in {_fmt_path(path)}"
        return _Problem(path + [key], f"unknown key {key!r} {where} "
                                      f"({extra}expected one of: {', '.join(allowed)})")
    if kw == "required" and isinstance(inst, dict):
        missing = next((k for k in err.validator_value if k not in inst), "?")
        sub = _resolve(sch.get("properties", {}).get(missing, {}), root)
        what = _describe(sub, root)
        where = _fmt_path(path + [missing])
        return _Problem(path + [missing], f"{where}: missing required key"
                                          + (f" (expected {what})" if what else ""))
    what = _describe(sch, root)
    if not what:
        what = err.message.splitlines()[0][:200]
        return _Problem(path, f"{_fmt_path(path)}: {what}" if path else what)
    if not path:
        return _Problem(path, f"expected {what}, got {_show(inst)}")
    return _Problem(path, f"{_fmt_path(path)}: expected {what}, got {_show(inst)}")


def _resolve(sch: dict, root: dict) -> dict:
    seen = 0
    while isinstance(sch, dict) and "$ref" in sch and seen < 10:
        ref = sch["$ref"]
        if not ref.startswith("#/"):
            break
        target: Any = root
        for part in ref[2:].split("/"):
            target = target[part]
        merged = dict(target)
        merged.update({k: v for k, v in sch.items() if k != "$ref"})
        if "x-expected" in target:  # the referenced definition knows best what it is
            merged["x-expected"] = target["x-expected"]
        sch = merged
        seen += 1
    return sch


def _describe(sch: dict, root: dict) -> str:
    """'a number > 0', 'an integer in [1, 8]', 'one of "a", "b"', ... from a subschema."""
    sch = _resolve(sch, root)
    if "x-expected" in sch:
        return sch["x-expected"]
    if "enum" in sch:
        vals = [json.dumps(v) for v in sch["enum"]]
        return "one of " + ", ".join(vals)
    t = sch.get("type")
    if t in ("number", "integer"):
        base = "a number" if t == "number" else "an integer"
        lo = ("[", sch["minimum"]) if "minimum" in sch else (
            ("(", sch["exclusiveMinimum"]) if "exclusiveMinimum" in sch else None)
        hi = ("]", sch["maximum"]) if "maximum" in sch else (
            (")", sch["exclusiveMaximum"]) if "exclusiveMaximum" in sch else None)
        if lo and hi:
            return f"{base} in {lo[0]}{_num(lo[1])}, {_num(hi[1])}{hi[0]}"
        if lo:
            return f"{base} {'>=' if lo[0] == '[' else '>'} {_num(lo[1])}"
        if hi:
            return f"{base} {'<=' if hi[0] == ']' else '<'} {_num(hi[1])}"
        return base
    if t == "boolean":
        return "true or false"
    if t == "string":
        return "a non-empty string" if sch.get("minLength") else "a string"
    if t == "object":
        return "an object"
    if t == "array":
        return "a list"
    return ""


def _check_semantics(data: dict) -> None:
    """The checks JSON Schema cannot express. `data` already passed the schema."""
    cloth = data["cloth"]
    nw, nh = cloth["num_width_points"], cloth["num_height_points"]
    for i, pin in enumerate(cloth.get("pinned", ())):
        x, y = pin
        path: list[PathItem] = ["cloth", "pinned", i]
        if x >= nw:
            raise _Problem(path, f"{_fmt_path(path)}: {_show(pin)} is out of range: "
                                 f"x_index must be < num_width_points ({_num(nw)})")
        if y >= nh:
            raise _Problem(path, f"{_fmt_path(path)}: {_show(pin)} is out of range: "
                                 f"y_index must be < num_height_points ({_num(nh)})")
    if "plane" in data:
        planes = data["plane"]
        many = isinstance(planes, list)
        for i, pl in enumerate(planes if many else [planes]):
            path = ["plane", i, "normal"] if many else ["plane", "normal"]
            if _norm(pl["normal"]) == 0.0:
                raise _Problem(path, f"{_fmt_path(path)}: expected a non-zero vector, "
                                     f"got {_show(pl['normal'])}")
    for path, obj in _collider_items(data):
        times = [k["time"] for k in obj.get("keyframes", ())]
        for i in range(1, len(times)):
            if not times[i] > times[i - 1]:
                kp = path + ["keyframes", i, "time"]
                raise _Problem(kp, f"{_fmt_path(kp)}: keyframes out of order: expected a time "
                                   f"> {_num(times[i - 1])} (the previous key's), got "
                                   f"{_num(times[i])}")
    rows = cloth.get("mass_map")
    if isinstance(rows, list) and len({len(r) for r in rows}) > 1:
        path = ["cloth", "mass_map"]
        raise _Problem(path, f"{_fmt_path(path)}: expected rows of equal length, got rows of "
                             f"{', '.join(str(n) for n in sorted({len(r) for r in rows}))} values")
    cam = data.get("camera")
    if isinstance(cam, dict):
        pos, tgt = cam["position"], cam["target"]
        view = [float(t) - float(p) for p, t in zip(pos, tgt)]
        if _norm(view) == 0.0:
            raise _Problem(["camera", "target"], f"camera.target: expected a point different "
                                                 f"from camera.position, got {_show(tgt)} (the same)")
        up = cam.get("up", [0, 1, 0])
        if _norm(up) == 0.0:
            raise _Problem(["camera", "up"], f"camera.up: expected a non-zero vector, got {_show(up)}")
        u = [float(c) for c in up]
        cross = [u[1] * view[2] - u[2] * view[1], u[2] * view[0] - u[0] * view[2],
                 u[0] * view[1] - u[1] * view[0]]
        if _norm(cross) <= 1e-9 * _norm(u) * _norm(view):
            where = "camera.up" if "up" in cam else "camera.up (default [0, 1, 0])"
            raise _Problem(["camera", "up"], f"{where}: expected a direction not parallel to "
                                             f"the view direction (target - position = "
                                             f"{_show(view)}), got {_show(up)}")


def _collider_items(data: dict):
    """(key path, raw object) of every collider, in file order."""
    for key in data:
        if key in _COLLIDER_KEYS:
            value = data[key]
            many = isinstance(value, list)
            for i, obj in enumerate(value if many else [value]):
                yield ([key, i] if many else [key]), obj


#: The faces a `render.cubemap` folder holds (shading.textures.CUBE_FACES; not imported
#: from there: this module stays light).
CUBE_FACES = ("posx", "negx", "posy", "negy", "posz", "negz")


def _check_files(data: dict, base_dir: Path) -> None:
    """Every file the scene names must exist and be readable, whatever the shader: mesh
    colliders (readable by trimesh, watertight when solid), an image mass map, the render
    texture and height map (images) and the cube map (a folder of six face images)."""
    for path, obj in _collider_items(data):
        if path[0] == "mesh":
            _check_mesh_file(path + ["path"], _resolve_path(base_dir, obj["path"]),
                             obj.get("solid", True))
    mass_map = data["cloth"].get("mass_map")
    if isinstance(mass_map, str):
        _check_image_file(["cloth", "mass_map"], _resolve_path(base_dir, mass_map))
    render = data.get("render", {})
    for key in ("texture", "height_map"):
        if key in render:
            _check_image_file(["render", key], _resolve_path(base_dir, render[key]))
    if "cubemap" in render:
        _check_cubemap(["render", "cubemap"], _resolve_path(base_dir, render["cubemap"]))


def _check_cubemap(path: list[PathItem], folder: Path) -> None:
    where = _fmt_path(path)
    if not folder.is_dir():
        raise _Problem(path, f"{where}: cube map folder {str(folder)!r} not found (expected a "
                             f"folder holding {', '.join(f + '.png' for f in CUBE_FACES)})")
    for face in CUBE_FACES:
        files = sorted(folder.glob(face + ".*"))
        if not files:
            raise _Problem(path, f"{where}: cube map face {face!r} not found in "
                                 f"{str(folder)!r} (expected {face}.png)")
        _check_image_file(path, files[0])


def _check_mesh_file(path: list[PathItem], file: Path, solid: bool) -> None:
    where = _fmt_path(path)
    if not file.is_file():
        raise _Problem(path, f"{where}: mesh file {str(file)!r} not found")
    import trimesh  # lazily: this module stays light

    try:
        mesh = trimesh.load(file, force="mesh")
    except Exception as e:  # trimesh raises many kinds for unreadable files
        raise _Problem(path, f"{where}: cannot read {str(file)!r} as a mesh "
                             f"(OBJ, STL, PLY, ...): {str(e).splitlines()[0] if str(e) else type(e).__name__}")
    faces = getattr(mesh, "faces", None)
    if faces is None or len(faces) == 0:
        raise _Problem(path, f"{where}: expected a triangle mesh, got no faces in {str(file)!r}")
    if solid and not mesh.is_watertight:
        raise _Problem(path, f"{where}: {str(file)!r} is not watertight (it has holes or "
                             f"open edges): a solid collider needs a closed mesh; set "
                             f'"solid": false to collide with it as a one-sided surface')


def _check_image_file(path: list[PathItem], file: Path) -> None:
    where = _fmt_path(path)
    if not file.is_file():
        raise _Problem(path, f"{where}: image {str(file)!r} not found")
    from PIL import Image, UnidentifiedImageError

    try:
        with Image.open(file) as im:
            im.verify()
    except (OSError, UnidentifiedImageError) as e:
        raise _Problem(path, f"{where}: cannot read {str(file)!r} as an image: {e}")


def _resolve_path(base_dir: Path, value: str) -> Path:
    return Path(os.path.abspath(base_dir / Path(value).expanduser()))


# --- building -----------------------------------------------------------------------------

def _build(data: dict, base_dir: Path, src_path: Path | None) -> Scene:
    c = data["cloth"]
    cloth = Cloth(
        width=float(c["width"]), height=float(c["height"]),
        num_width_points=int(c["num_width_points"]), num_height_points=int(c["num_height_points"]),
        thickness=float(c["thickness"]), orientation=int(c["orientation"]),
        damping=float(c["damping"]), density=float(c["density"]), ks=float(c["ks"]),
        enable_structural=bool(c["enable_structural"]),
        enable_shearing=bool(c["enable_shearing"]),
        enable_bending=bool(c["enable_bending"]),
        pinned=tuple((int(x), int(y)) for x, y in c.get("pinned", ())),
        mass_map=_mass_map(c.get("mass_map"), base_dir),
        mass_map_range=tuple(float(v) for v in c.get("mass_map_range", Cloth.mass_map_range)),
        fem=FemMaterial(**{k: float(v) for k, v in c.get("fem", {}).items()}),
    )
    colliders = [_collider(path[0], obj, base_dir) for path, obj in _collider_items(data)]
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
    )

    cam = data.get("camera")
    camera: CameraSettings | str | None = cam if cam == COURSE_CAMERA else None
    if isinstance(cam, dict):
        camera = CameraSettings(position=_vec3(cam["position"]), target=_vec3(cam["target"]),
                                up=_vec3(cam.get("up", CameraSettings.up)),
                                vfov=float(cam.get("vfov", CameraSettings.vfov)))

    li = data.get("light", {})
    light = LightSettings(position=_vec3(li.get("position", LightSettings.position)),
                          intensity=_vec3(li.get("intensity", LightSettings.intensity)))

    r = data.get("render", {})
    rd = RenderSettings()

    def path_of(key: str) -> Path | None:
        return _resolve_path(base_dir, r[key]) if key in r else None

    params: dict[str, Any] = {}
    for key in RENDER_PARAMS:
        if key in r:
            params[key] = _vec3(r[key]) if key in _VEC3_PARAMS else float(r[key])
    render = RenderSettings(
        shader=str(r.get("shader", rd.shader)), width=int(r.get("width", rd.width)),
        height=int(r.get("height", rd.height)), aa=int(r.get("aa", rd.aa)),
        background=_vec3(r.get("background", rd.background)),
        texture=path_of("texture"), height_map=path_of("height_map"), cubemap=path_of("cubemap"),
        params=params,
    )
    return Scene(cloth=cloth, colliders=tuple(colliders), wind=wind, simulation=simulation,
                 camera=camera, light=light, render=render, source=src_path)


def _mass_map(value, base_dir: Path):
    if value is None:
        return None
    if isinstance(value, str):
        return _resolve_path(base_dir, value)
    return tuple(tuple(float(v) for v in row) for row in value)


def _keyframes(obj: dict) -> tuple[Keyframe, ...]:
    zero = (0.0, 0.0, 0.0)
    return tuple(Keyframe(time=float(k["time"]), translation=_vec3(k.get("translation", zero)),
                          rotation=_vec3(k.get("rotation", zero)))
                 for k in obj.get("keyframes", ()))


def _collider(key: str, obj: dict, base_dir: Path) -> Collider:
    friction, keys = float(obj["friction"]), _keyframes(obj)
    if key == "sphere":
        return Sphere(origin=_vec3(obj["origin"]), radius=float(obj["radius"]),
                      friction=friction, keyframes=keys)
    if key == "plane":
        return Plane(point=_vec3(obj["point"]), normal=_vec3(obj["normal"]), friction=friction,
                     keyframes=keys)
    zero = (0.0, 0.0, 0.0)
    if key == "box":
        return Box(center=_vec3(obj["center"]), half_extents=_vec3(obj["half_extents"]),
                   friction=friction, rotation=_vec3(obj.get("rotation", zero)), keyframes=keys)
    scale = obj.get("scale", 1.0)
    return MeshCollider(
        path=_resolve_path(base_dir, obj["path"]), friction=friction,
        translation=_vec3(obj.get("translation", zero)), rotation=_vec3(obj.get("rotation", zero)),
        scale=_vec3(scale) if isinstance(scale, list) else (float(scale),) * 3,
        solid=bool(obj.get("solid", True)), thickness=float(obj.get("thickness", 0.005)),
        keyframes=keys)


# --- small helpers ------------------------------------------------------------------------

def _vec3(v) -> Vec3:
    return (float(v[0]), float(v[1]), float(v[2]))


def _norm(v) -> float:
    return math.sqrt(sum(float(c) * float(c) for c in v))


def _num(x) -> str:
    if isinstance(x, float) and x.is_integer() and abs(x) < 1e15:
        return str(int(x))
    return json.dumps(x)


def _fmt_path(path: Sequence[PathItem]) -> str:
    """['cloth', 'pinned', 2] -> 'cloth.pinned[2]'; [] -> 'top level'."""
    out = ""
    for p in path:
        if isinstance(p, int):
            out += f"[{p}]"
        else:
            out += f".{p}" if out else str(p)
    return out or "top level"


def _kind(v: Any) -> str:
    if isinstance(v, bool):
        return "a boolean"
    if isinstance(v, (int, float)):
        return "a number"
    if isinstance(v, str):
        return "a string"
    if v is None:
        return "null"
    return type(v).__name__


def _show(v: Any, limit: int = 60) -> str:
    """A short, JSON-spelled rendering of a value for messages (true, NaN, "x", [1, 2])."""
    if isinstance(v, dict):
        return "an object" if v else "an empty object {}"
    if isinstance(v, float) and not math.isfinite(v):
        return "NaN" if math.isnan(v) else ("Infinity" if v > 0 else "-Infinity")
    if isinstance(v, list):
        try:
            s = "[" + ", ".join(_show(x, limit) for x in v) + "]" if len(v) <= limit else ""
        except RecursionError:
            s = ""
        if s and len(s) <= limit and not any(isinstance(x, (dict, list)) and x for x in v):
            return s
        return f"a list of {len(v)} item{'s' * (len(v) != 1)}"
    if isinstance(v, float) and v.is_integer() and abs(v) < 1e15:
        return str(int(v))
    if isinstance(v, (bool, int, float, str)) or v is None:
        s = json.dumps(v)
        return s if len(s) <= limit else s[:limit - 4] + '..."'
    return f"a {type(v).__name__}"
