"""Checking a scene's raw JSON: the JSON Schema (`schema.json`, its integrator and shader
enums filled in from pipeline.scene.types), the semantic checks a schema cannot express, and
the files the scene names; each failure a one-line message naming the key."""
from __future__ import annotations

import copy
import difflib
import functools
import json
import math
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from .types import COLLIDER_KEYS, INTEGRATORS, LINE_SHADERS, MODELS, SHADERS

PathItem = str | int


@functools.lru_cache(maxsize=8)
def _schema_and_validator(integrators: tuple[str, ...], shaders: tuple[str, ...]):
    import importlib.resources

    import jsonschema

    if __package__:
        text = importlib.resources.files(__package__).joinpath(
            "schema.json").read_text(encoding="utf-8")
    else:  # this file loaded on its own, not as part of the package
        text = Path(__file__).with_name("schema.json").read_text(encoding="utf-8")
    schema = json.loads(text)
    defs = schema["$defs"]
    defs["simulation"]["properties"]["integrator"]["enum"] = list(integrators)
    defs["simulation"]["properties"]["model"]["enum"] = list(MODELS)
    defs["render"]["properties"]["shader"]["enum"] = list(shaders)
    for kind in ("sphere", "plane", "box", "mesh"):  # a collider's own: triangles only
        defs[kind]["properties"]["shader"]["enum"] = [s for s in shaders
                                                      if s not in LINE_SHADERS]
    # the schema's own validity is a test (test_the_schema_is_a_valid_draft_2020_12_schema):
    # checking it here cost every run 0.13 s
    return schema, jsonschema.Draft202012Validator(schema)


def scene_schema() -> dict:
    """The scene JSON Schema (draft 2020-12) as used by `load_scene`, enums filled in."""
    return copy.deepcopy(_schema_and_validator(INTEGRATORS, SHADERS)[0])


class Problem(Exception):
    """A check failure: `text` is the message after "<file>: ", `path` the key path named."""

    def __init__(self, path: list[PathItem] | None, text: str):
        super().__init__(text)
        self.path = path
        self.text = text


def check_finite(node: Any, path: list[PathItem]) -> None:
    if isinstance(node, float) and not math.isfinite(node):
        raise Problem(path, f"{fmt_path(path)}: expected a finite number, got {show(node)}")
    if isinstance(node, dict):
        for k, v in node.items():
            check_finite(v, path + [k])
    elif isinstance(node, list):
        for i, v in enumerate(node):
            check_finite(v, path + [i])


def validate_schema(data: dict) -> None:
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


def _translate(err, root: dict) -> Problem:
    """Turn one jsonschema ValidationError into a one-line `Problem`."""
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
        where = "at top level" if not path else f"in {fmt_path(path)}"
        return Problem(path + [key], f"unknown key {key!r} {where} "
                                      f"({extra}expected one of: {', '.join(allowed)})")
    if kw == "required" and isinstance(inst, dict):
        missing = next((k for k in err.validator_value if k not in inst), "?")
        sub = _resolve(sch.get("properties", {}).get(missing, {}), root)
        what = _describe(sub, root)
        where = fmt_path(path + [missing])
        return Problem(path + [missing], f"{where}: missing required key"
                                          + (f" (expected {what})" if what else ""))
    what = _describe(sch, root)
    if not what:
        what = err.message.splitlines()[0][:200]
        return Problem(path, f"{fmt_path(path)}: {what}" if path else what)
    if not path:
        return Problem(path, f"expected {what}, got {show(inst)}")
    return Problem(path, f"{fmt_path(path)}: expected {what}, got {show(inst)}")


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


#: the keys of a grid cloth that a mesh cloth takes from its file
GRID_ONLY_KEYS = ("width", "height", "num_width_points", "num_height_points", "orientation")
#: the keys that place a mesh cloth (meaningless for a grid)
MESH_ONLY_KEYS = ("translation", "rotation", "scale", "pieces")


def check_cloth_form(data: dict) -> None:
    """A cloth is a grid or a mesh, not both: the grid keys are refused together with
    `cloth.mesh`, the mesh's placement keys without it. Made before the schema, so that the
    message says which key is out of place (and not what the other form would need)."""
    cloth = data.get("cloth")
    if not isinstance(cloth, dict):
        return
    if "mesh" in cloth:
        for key in GRID_ONLY_KEYS:
            if key in cloth:
                path: list[PathItem] = ["cloth", key]
                raise Problem(path, f"{fmt_path(path)}: not allowed together with cloth.mesh "
                                     f"(a mesh cloth takes its size and shape from the file; "
                                     f"place it with translation, rotation and scale)")
    else:
        for key in MESH_ONLY_KEYS:
            if key in cloth:
                path = ["cloth", key]
                raise Problem(path, f"{fmt_path(path)}: only allowed together with cloth.mesh "
                                     f"(it places a mesh cloth; a grid cloth is given by width, "
                                     f"height, num_width_points, num_height_points and "
                                     f"orientation)")


def check_semantics(data: dict) -> None:
    """The checks JSON Schema cannot express. `data` already passed the schema."""
    cloth = data["cloth"]
    if "mesh" in cloth:
        _check_mesh_cloth(cloth)
        pins = ()
        nw = nh = 0
    else:
        pins = cloth.get("pinned", ())
        nw, nh = cloth["num_width_points"], cloth["num_height_points"]
    for i, pin in enumerate(pins):
        x, y = pin
        path: list[PathItem] = ["cloth", "pinned", i]
        if x >= nw:
            raise Problem(path, f"{fmt_path(path)}: {show(pin)} is out of range: "
                                 f"x_index must be < num_width_points ({_num(nw)})")
        if y >= nh:
            raise Problem(path, f"{fmt_path(path)}: {show(pin)} is out of range: "
                                 f"y_index must be < num_height_points ({_num(nh)})")
    if "plane" in data:
        planes = data["plane"]
        many = isinstance(planes, list)
        for i, pl in enumerate(planes if many else [planes]):
            path = ["plane", i, "normal"] if many else ["plane", "normal"]
            if _norm(pl["normal"]) == 0.0:
                raise Problem(path, f"{fmt_path(path)}: expected a non-zero vector, "
                                     f"got {show(pl['normal'])}")
    for path, obj in collider_items(data):
        _check_keyframe_order(path, obj)
    rows = cloth.get("mass_map")
    if isinstance(rows, list) and len({len(r) for r in rows}) > 1:
        path = ["cloth", "mass_map"]
        raise Problem(path, f"{fmt_path(path)}: expected rows of equal length, got rows of "
                             f"{', '.join(str(n) for n in sorted({len(r) for r in rows}))} values")
    cam = data.get("camera")
    if isinstance(cam, dict):
        pos, tgt = cam["position"], cam["target"]
        view = [float(t) - float(p) for p, t in zip(pos, tgt)]
        if _norm(view) == 0.0:
            raise Problem(["camera", "target"], f"camera.target: expected a point different "
                                                 f"from camera.position, got {show(tgt)} (the same)")
        up = cam.get("up", [0, 1, 0])
        if _norm(up) == 0.0:
            raise Problem(["camera", "up"], f"camera.up: expected a non-zero vector, got {show(up)}")
        u = [float(c) for c in up]
        cross = [u[1] * view[2] - u[2] * view[1], u[2] * view[0] - u[0] * view[2],
                 u[0] * view[1] - u[1] * view[0]]
        if _norm(cross) <= 1e-9 * _norm(u) * _norm(view):
            where = "camera.up" if "up" in cam else "camera.up (default [0, 1, 0])"
            raise Problem(["camera", "up"], f"{where}: expected a direction not parallel to "
                                             f"the view direction (target - position = "
                                             f"{show(view)}), got {show(up)}")


def _check_keyframe_order(path: list[PathItem], obj: dict) -> None:
    times = [k["time"] for k in obj.get("keyframes", ())]
    for i in range(1, len(times)):
        if not times[i] > times[i - 1]:
            kp = path + ["keyframes", i, "time"]
            raise Problem(kp, f"{fmt_path(kp)}: keyframes out of order: expected a time "
                               f"> {_num(times[i - 1])} (the previous key's), got "
                               f"{_num(times[i])}")


PIN_FORMS = ("indices", "box", "group")


def pin_items(cloth: dict):
    """(key path, raw item) of every selection of a mesh cloth's `pinned`, in file order:
    a lone object is the path ['cloth', 'pinned'], list items ['cloth', 'pinned', i]."""
    pinned = cloth.get("pinned")
    if isinstance(pinned, dict):
        yield ["cloth", "pinned"], pinned
    elif isinstance(pinned, list):
        for i, item in enumerate(pinned):
            yield ["cloth", "pinned", i], item


def _check_mesh_cloth(cloth: dict) -> None:
    if isinstance(cloth.get("mass_map"), list):
        path: list[PathItem] = ["cloth", "mass_map"]
        raise Problem(path, f"{fmt_path(path)}: a list of rows is for a grid cloth only: "
                             f"expected an image path for a mesh cloth (sampled by the "
                             f"mesh's uv)")
    for path, item in pin_items(cloth):
        if not isinstance(item, dict):
            continue
        forms = [k for k in PIN_FORMS if k in item]
        if len(forms) != 1:
            got = "none of them" if not forms else " and ".join(forms)
            raise Problem(path, f"{fmt_path(path)}: expected exactly one of indices, box, "
                                 f"group, got {got}")
        if "box" in item:
            lo, hi = item["box"]
            for axis in range(3):
                if lo[axis] > hi[axis]:
                    bp = path + ["box"]
                    box = "[" + ", ".join("[" + ", ".join(_num(c) for c in p) + "]"
                                          for p in (lo, hi)) + "]"
                    raise Problem(bp, f"{fmt_path(bp)}: expected [lo, hi] with lo <= hi in "
                                       f"every axis, got {box} ({'xyz'[axis]}: "
                                       f"{_num(lo[axis])} > {_num(hi[axis])})")
        _check_keyframe_order(path, item)


def collider_items(data: dict):
    """(key path, raw object) of every collider, in file order."""
    for key in data:
        if key in COLLIDER_KEYS:
            value = data[key]
            many = isinstance(value, list)
            for i, obj in enumerate(value if many else [value]):
                yield ([key, i] if many else [key]), obj


#: The faces a `render.cubemap` folder holds (shading.textures.CUBE_FACES; not imported
#: from there: this module stays light).
CUBE_FACES = ("posx", "negx", "posy", "negy", "posz", "negz")


def check_files(data: dict, base_dir: Path) -> None:
    """Every file the scene names must exist and be readable, whatever the shader: a mesh
    cloth and mesh colliders (readable by trimesh; a collider watertight when solid; a
    cloth's own checks, manifold, one piece, ..., come when it is built, in
    pipeline.physics.cloth_mesh), an image mass map, the render texture and height map
    (images) and the cube map (a folder of six face images)."""
    cloth_mesh = data["cloth"].get("mesh")
    if cloth_mesh is not None:
        _check_mesh_file(["cloth", "mesh"], resolve_path(base_dir, cloth_mesh), False)
    for path, obj in collider_items(data):
        if path[0] == "mesh":
            _check_mesh_file(path + ["path"], resolve_path(base_dir, obj["path"]),
                             obj.get("solid", True))
    mass_map = data["cloth"].get("mass_map")
    if isinstance(mass_map, str):
        _check_image_file(["cloth", "mass_map"], resolve_path(base_dir, mass_map))
    render = data.get("render", {})
    for key in ("texture", "height_map"):
        if key in render:
            _check_image_file(["render", key], resolve_path(base_dir, render[key]))
    if "cubemap" in render:
        _check_cubemap(["render", "cubemap"], resolve_path(base_dir, render["cubemap"]))


def _check_cubemap(path: list[PathItem], folder: Path) -> None:
    where = fmt_path(path)
    if not folder.is_dir():
        raise Problem(path, f"{where}: cube map folder {str(folder)!r} not found (expected a "
                             f"folder holding {', '.join(f + '.png' for f in CUBE_FACES)})")
    for face in CUBE_FACES:
        files = sorted(folder.glob(face + ".*"))
        if not files:
            raise Problem(path, f"{where}: cube map face {face!r} not found in "
                                 f"{str(folder)!r} (expected {face}.png)")
        _check_image_file(path, files[0])


def _check_mesh_file(path: list[PathItem], file: Path, solid: bool) -> None:
    where = fmt_path(path)
    if not file.is_file():
        raise Problem(path, f"{where}: mesh file {str(file)!r} not found")
    import trimesh  # lazily: this module stays light

    try:
        mesh = trimesh.load(file, force="mesh")
    except Exception as e:  # trimesh raises many kinds for unreadable files
        raise Problem(path, f"{where}: cannot read {str(file)!r} as a mesh "
                             f"(OBJ, STL, PLY, ...): {str(e).splitlines()[0] if str(e) else type(e).__name__}")
    faces = getattr(mesh, "faces", None)
    if faces is None or len(faces) == 0:
        raise Problem(path, f"{where}: expected a triangle mesh, got no faces in {str(file)!r}")
    if solid and not mesh.is_watertight:
        raise Problem(path, f"{where}: {str(file)!r} is not watertight (it has holes or "
                             f"open edges): a solid collider needs a closed mesh; set "
                             f'"solid": false to collide with it as a one-sided surface')


def _check_image_file(path: list[PathItem], file: Path) -> None:
    where = fmt_path(path)
    if not file.is_file():
        raise Problem(path, f"{where}: image {str(file)!r} not found")
    from PIL import Image, UnidentifiedImageError

    try:
        with Image.open(file) as im:
            im.verify()
    except (OSError, UnidentifiedImageError) as e:
        raise Problem(path, f"{where}: cannot read {str(file)!r} as an image: {e}")


def resolve_path(base_dir: Path, value: str) -> Path:
    return Path(os.path.abspath(base_dir / Path(value).expanduser()))


def _norm(v) -> float:
    return math.sqrt(sum(float(c) * float(c) for c in v))


def _num(x) -> str:
    if isinstance(x, float) and x.is_integer() and abs(x) < 1e15:
        return str(int(x))
    return json.dumps(x)


def fmt_path(path: Sequence[PathItem]) -> str:
    """['cloth', 'pinned', 2] -> 'cloth.pinned[2]'; [] -> 'top level'."""
    out = ""
    for p in path:
        if isinstance(p, int):
            out += f"[{p}]"
        else:
            out += f".{p}" if out else str(p)
    return out or "top level"


def kind_of(v: Any) -> str:
    if isinstance(v, bool):
        return "a boolean"
    if isinstance(v, (int, float)):
        return "a number"
    if isinstance(v, str):
        return "a string"
    if v is None:
        return "null"
    return type(v).__name__


def show(v: Any, limit: int = 60) -> str:
    """A short, JSON-spelled rendering of a value for messages (true, NaN, "x", [1, 2])."""
    if isinstance(v, dict):
        return "an object" if v else "an empty object {}"
    if isinstance(v, float) and not math.isfinite(v):
        return "NaN" if math.isnan(v) else ("Infinity" if v > 0 else "-Infinity")
    if isinstance(v, list):
        try:
            s = "[" + ", ".join(show(x, limit) for x in v) + "]" if len(v) <= limit else ""
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

