"""Scene loading: the course files, defaults, error messages, overrides, collider order."""
from __future__ import annotations

import copy
import json
import math
import os
import subprocess
import sys
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from pipeline.scene import check as scene_check
from pipeline.scene import INTEGRATORS, SHADERS, Plane, Scene, SceneError, Sphere, apply_overrides, load_scene, scene_schema

ROOT = Path(__file__).resolve().parents[1]
SCENES = ROOT / "scenes"
BAD = Path(__file__).resolve().parent / "bad_scenes"
COURSE = ["pinned2", "pinned4", "sphere", "plane", "selfCollision"]


def raw(name: str) -> dict:
    return json.loads((SCENES / f"{name}.json").read_text())


def error_of(source, overrides=()) -> str:
    with pytest.raises(SceneError) as info:
        load_scene(source, overrides)
    msg = str(info.value)
    assert "\n" not in msg and "Traceback" not in msg, msg
    return msg


# --------------------------------------------------------------------------------------
# Valid scenes
# --------------------------------------------------------------------------------------

@pytest.mark.parametrize("name", COURSE)
def test_course_scenes_load_with_file_values_and_defaults(name):
    s = load_scene(SCENES / f"{name}.json")
    assert isinstance(s, Scene)
    c = s.cloth
    assert (c.width, c.height, c.num_width_points, c.num_height_points) == (1.0, 1.0, 50, 50)
    assert (c.damping, c.density, c.ks, c.thickness) == (0.2, 150.0, 5000.0, 0.0095)
    assert c.enable_structural and c.enable_shearing and c.enable_bending
    assert isinstance(c.num_width_points, int) and isinstance(c.width, float)
    # defaults filled in
    assert s.simulation.frames_per_sec == 90.0 and s.simulation.steps_per_frame == 30
    assert s.simulation.gravity == (0.0, -9.8, 0.0) and s.simulation.integrator == "verlet"
    assert s.simulation.seed == 0 and s.simulation.self_collision == "auto"
    assert s.camera is None
    assert s.light.position == (0.5, 2.0, 2.0) and s.light.intensity == (3.0, 3.0, 3.0)
    r = s.render
    assert (r.shader, r.width, r.height, r.aa) == ("phong", 512, 512, 1)
    assert r.background == (0.2, 0.25, 0.3) and r.params == {}
    assert r.texture is r.height_map is r.cubemap is None
    assert s.source == (SCENES / f"{name}.json").resolve()


def test_course_scene_specifics():
    assert load_scene(SCENES / "pinned2.json").cloth.pinned == ((0, 0), (49, 0))
    assert load_scene(SCENES / "pinned4.json").cloth.pinned == ((0, 0), (0, 49), (49, 0), (49, 49))
    assert load_scene(SCENES / "sphere.json").colliders == (Sphere((0.5, 0.2, 0.5), 0.2, 0.3),)
    assert load_scene(SCENES / "plane.json").colliders == (Plane((0, 0, 0), (0, 1, 0), 0.5),)
    sc = load_scene(str(SCENES / "selfCollision.json"))
    assert sc.cloth.orientation == 1 and sc.self_collision is True
    assert load_scene(SCENES / "plane.json").self_collision is False


@pytest.mark.parametrize("path", sorted(SCENES.glob("*.json")), ids=lambda p: p.name)
def test_every_scene_in_scenes_folder_loads(path):
    load_scene(path)


def test_own_scenes_exercise_the_extensions():
    two = load_scene(SCENES / "two_spheres.json")
    assert [type(c) for c in two.colliders] == [Sphere, Sphere, Plane]
    assert two.camera is not None and two.camera.vfov == 40.0
    curtain = load_scene(SCENES / "curtain.json")
    assert curtain.cloth.orientation == 1 and curtain.simulation.self_collision is True
    top = curtain.cloth.num_height_points - 1
    assert curtain.cloth.pinned == tuple((j, top) for j in range(curtain.cloth.num_width_points))
    assert curtain.render.shader == "toon" and curtain.render.params == {"k_d": (0.8, 0.2, 0.25)}
    assert curtain.simulation.seed == 7 and curtain.camera.up == (0.0, 1.0, 0.0)
    pf = load_scene(SCENES / "planes_first.json")
    assert [type(c) for c in pf.colliders] == [Plane, Plane, Sphere]
    assert set(pf.render.params) == {"k_a", "I_a", "k_s", "p", "k_h", "k_n", "k_d"}
    assert pf.render.params["I_a"] == (1.0, 1.0, 1.0) and pf.render.params["p"] == 64.0


def test_dict_source_is_not_modified_and_tuples_are_accepted():
    d = raw("sphere")
    before = copy.deepcopy(d)
    s = load_scene(d, ["cloth.ks=1", "sphere.0.radius=0.5"])
    assert d == before and s.cloth.ks == 1.0 and s.colliders[0].radius == 0.5
    d["camera"] = {"position": (0, 1, 3), "target": (0, 0, 0)}
    assert load_scene(d).camera.position == (0.0, 1.0, 3.0)
    assert load_scene(d).source is None


def test_integer_valued_floats_are_accepted_as_integers():
    d = raw("pinned2")
    d["cloth"]["num_width_points"] = 50.0
    d["cloth"]["pinned"] = [[49.0, 0]]
    s = load_scene(d)
    assert s.cloth.num_width_points == 50 and type(s.cloth.num_width_points) is int
    assert s.cloth.pinned == ((49, 0),) and type(s.cloth.pinned[0][0]) is int


def test_self_collision_auto_and_explicit():
    d = raw("pinned2")
    assert load_scene(d).self_collision is False
    assert load_scene(d, ["cloth.orientation=1"]).self_collision is True
    assert load_scene(d, ["simulation.self_collision=true"]).self_collision is True
    v = load_scene(d, ["cloth.orientation=1", "simulation.self_collision=false"])
    assert v.simulation.self_collision is False and v.self_collision is False


TEXTURES = ROOT / "textures"


def _texture_files(folder: Path, *names: str) -> None:
    """Copies of the packaged texture at folder/name, and the packaged cube map at
    folder/cube."""
    import shutil

    for name in names:
        (folder / name).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy(TEXTURES / "cloth.png", folder / name)
    shutil.copytree(TEXTURES / "cubemap", folder / "cube", dirs_exist_ok=True)


def test_render_paths_resolve_against_the_scene_folder(tmp_path, monkeypatch):
    d = raw("plane")
    d["render"] = {"shader": "texture", "texture": "tex/cloth.png",
                   "height_map": str(tmp_path / "abs.png"), "cubemap": "../cube"}
    (tmp_path / "sub").mkdir()
    _texture_files(tmp_path, "sub/tex/cloth.png", "abs.png", "tex/cloth.png")
    f = tmp_path / "sub" / "scene.json"
    f.write_text(json.dumps(d))
    r = load_scene(f).render
    assert r.texture == tmp_path / "sub" / "tex" / "cloth.png"
    assert r.height_map == tmp_path / "abs.png"
    assert r.cubemap == tmp_path / "cube"
    assert all(p.is_absolute() for p in (r.texture, r.height_map, r.cubemap))
    # from a dict: relative to the current directory
    monkeypatch.chdir(tmp_path / "sub")
    r2 = load_scene(d).render
    assert r2.texture == tmp_path / "sub" / "tex" / "cloth.png"


@pytest.mark.parametrize("shader", ["phong", "texture", "mirror"])
@pytest.mark.parametrize("key, value, expected", [
    ("texture", "nowhere.png", "render.texture: image '{dir}/nowhere.png' not found"),
    ("height_map", "nowhere.png", "render.height_map: image '{dir}/nowhere.png' not found"),
    ("texture", "scene.json", "render.texture: cannot read '{dir}/scene.json' as an image"),
    ("cubemap", "nowhere", "render.cubemap: cube map folder '{dir}/nowhere' not found"),
    ("cubemap", "half", "render.cubemap: cube map face 'negx' not found in '{dir}/half'"),
])
def test_missing_or_unreadable_render_files_fail_at_load(tmp_path, shader, key, value,
                                                          expected):
    d = raw("plane")
    d["render"] = {"shader": shader, key: value}
    _texture_files(tmp_path, "half/posx.png")
    f = tmp_path / "scene.json"
    f.write_text(json.dumps(d))
    with pytest.raises(SceneError) as e:
        load_scene(f)
    assert str(e.value).startswith(f"{f}: " + expected.format(dir=tmp_path))


def test_schema_enums_come_from_the_module_tuples(monkeypatch):
    schema = scene_schema()
    props = schema["$defs"]
    assert props["simulation"]["properties"]["integrator"]["enum"] == list(INTEGRATORS)
    assert props["render"]["properties"]["shader"]["enum"] == list(SHADERS)
    assert "leapfrog" not in INTEGRATORS
    d = raw("plane")
    assert "simulation.integrator" in error_of(d, ["simulation.integrator=leapfrog"])
    monkeypatch.setattr(scene_check, "INTEGRATORS", INTEGRATORS + ("leapfrog",))
    assert load_scene(d, ["simulation.integrator=leapfrog"]).simulation.integrator == "leapfrog"


def test_the_schema_is_a_valid_draft_2020_12_schema():
    import jsonschema

    jsonschema.Draft202012Validator.check_schema(scene_schema())
    broken = scene_schema()
    broken["$defs"]["simulation"]["properties"]["integrator"]["enum"] = "verlet"
    with pytest.raises(jsonschema.SchemaError):
        jsonschema.Draft202012Validator.check_schema(broken)


def test_every_schema_property_is_described_and_documented():
    doc = (ROOT / "docs" / "scene-format.md").read_text()
    schema = scene_schema()
    blocks = dict(schema["$defs"], top=schema)
    for name, block in blocks.items():
        for key, sub in block.get("properties", {}).items():
            assert sub.get("description"), f"{name}.{key} has no description"
            assert f"`{key}`" in doc, f"{name}.{key} is not in docs/scene-format.md"


def test_loading_does_not_import_numba():
    # the scene package and the package root it loads through: no numba, numpy or renderer
    code = ("import sys; from pipeline.scene import load_scene; "
            "load_scene('scenes/curtain.json'); "
            "bad = [n for n in ('numba', 'numpy', 'shading', 'clothjit', 'pipeline.physics') "
            "if n in sys.modules]; "
            "assert not bad, bad")
    subprocess.run([sys.executable, "-c", code], cwd=ROOT, check=True)


# --------------------------------------------------------------------------------------
# Broken files: one message, starting with the file, naming the key
# --------------------------------------------------------------------------------------

BAD_TABLE = [
    ("not_json.json", "not valid JSON: line 1 column 1"),
    ("empty.json", "not valid JSON"),
    ("truncated.json", "not valid JSON: line 5"),
    ("trailing_comma.json", "not valid JSON: line 4"),
    ("not_utf8.json", "not valid JSON"),
    ("top_level_list.json", "expected a JSON object at top level"),
    ("unknown_top_key.json", "unknown key 'clth' at top level (did you mean 'cloth'?"),
    ("typo_in_cloth.json", "unknown key 'widht' in cloth (did you mean 'width'?"),
    ("missing_cloth.json", "cloth: missing required key"),
    ("missing_ks.json", "cloth.ks: missing required key"),
    ("width_negative.json", "cloth.width: expected a number > 0, got -1"),
    ("ks_is_bool.json", "cloth.ks: expected a number >= 0, got true"),
    ("bool_is_number.json", "cloth.enable_shearing: expected true or false, got 1"),
    ("density_string.json", "cloth.density: expected a number > 0, got \"150\""),
    ("nan.json", "cloth.density: expected a finite number, got NaN"),
    ("infinity.json", "cloth.damping: expected a finite number, got Infinity"),
    ("huge_number.json", "cloth.ks: expected a finite number"),
    ("duplicate_key.json", "cloth.ks: duplicate key"),
    ("num_points_float.json", "cloth.num_width_points: expected an integer"),
    ("num_points_one.json", "cloth.num_height_points: expected an integer in [2,"),
    ("thickness_negative.json", "cloth.thickness: expected a number >= 0"),
    ("damping_over_100.json", "cloth.damping: expected a number in [0, 100], got 150"),
    ("orientation_2.json", "cloth.orientation: expected 0 (horizontal) or 1 (vertical), got 2"),
    ("pinned_out_of_range.json",
     "cloth.pinned[2]: [60, 0] is out of range: x_index must be < num_width_points (10)"),
    ("pinned_y_out_of_range.json",
     "cloth.pinned[0]: [0, 8] is out of range: y_index must be < num_height_points (8)"),
    ("pinned_not_pair.json", "cloth.pinned[0]: expected a pair of integers"),
    ("pinned_negative.json", "cloth.pinned[0][1]: expected an integer >= 0"),
    ("sphere_radius_zero.json", "sphere.radius: expected a number > 0, got 0"),
    ("sphere_list_missing_friction.json", "sphere[1].friction: missing required key"),
    ("sphere_is_number.json", "sphere: expected a sphere object or a list of sphere objects"),
    ("sphere_origin_short.json", "sphere.origin: expected a list of 3 numbers"),
    ("plane_zero_normal.json", "plane.normal: expected a non-zero vector"),
    ("plane_friction_over_1.json", "plane.friction: expected a number in [0, 1], got 1.5"),
    ("plane_typo.json", "unknown key 'norml' in plane (did you mean 'normal'?"),
    ("integrator_unknown.json", "simulation.integrator: expected one of \"verlet\""),
    ("steps_per_frame_zero.json", "simulation.steps_per_frame: expected an integer >= 1"),
    ("steps_per_frame_float.json", "simulation.steps_per_frame: expected an integer >= 1, got 2.5"),
    ("iterations_zero.json", "simulation.iterations: expected an integer >= 1, got 0"),
    ("iterations_float.json", "simulation.iterations: expected an integer >= 1, got 2.5"),
    ("frames_per_sec_negative.json", "simulation.frames_per_sec: expected a number > 0"),
    ("seed_negative.json", "simulation.seed: expected an integer >= 0, got -1"),
    ("self_collision_yes.json", "simulation.self_collision: expected true, false or \"auto\""),
    ("simulation_unknown_key.json", "unknown key 'fps' in simulation"),
    ("gravity_two_components.json", "simulation.gravity: expected a list of 3 numbers"),
    ("camera_missing_target.json", "camera.target: missing required key"),
    ("camera_same_position.json", "camera.target: expected a point different from camera.position"),
    ("camera_up_zero.json", "camera.up: expected a non-zero vector"),
    ("camera_up_parallel.json", "camera.up (default [0, 1, 0]): expected a direction not parallel"),
    ("camera_vfov_180.json", "camera.vfov: expected a number in (0, 180), got 180"),
    ("light_intensity_negative.json", "light.intensity[0]: expected a number >= 0, got -1"),
    ("render_width_too_big.json", "render.width: expected an integer in [1, 8192], got 9000"),
    ("render_aa_zero.json", "render.aa: expected an integer in [1, 8], got 0"),
    ("render_shader_unknown.json", "render.shader: expected one of \"normal\""),
    ("render_background_negative.json", "render.background[2]: expected a number >= 0"),
    ("render_texture_number.json", "render.texture: expected a file path"),
    ("render_param_bool.json", "render.k_s: expected a number >= 0, got false"),
    ("mesh_file_missing.json", "mesh.path: mesh file '"),
    ("mesh_not_watertight.json", "mesh[1].path: '"),
    ("mesh_not_a_mesh.json", "mesh.path: cannot read '"),
    ("mesh_scale_negative.json", "mesh.scale: expected a number > 0 or a list of 3 numbers > 0"),
    ("keyframes_out_of_order.json",
     "sphere.keyframes[2].time: keyframes out of order: expected a time > 2 (the previous "
     "key's), got 1.5"),
    ("keyframe_unknown_key.json", "unknown key 'position' in plane.keyframes[0]"),
    ("keyframes_empty.json", "plane.keyframes: expected a non-empty list of keyframe objects"),
    ("box_half_extent_zero.json", "box.half_extents[1]: expected a number > 0, got 0"),
    ("box_missing_center.json", "box[1].center: missing required key"),
    ("wind_typo.json", "unknown key 'velocty' in wind (did you mean 'velocity'?"),
    ("wind_density_negative.json", "wind.air_density: expected a number >= 0, got -1"),
    ("mass_map_ragged.json", "cloth.mass_map: expected rows of equal length"),
    ("mass_map_zero.json", "cloth.mass_map[0][1]: expected a number > 0, got 0"),
    ("mass_map_image_missing.json", "cloth.mass_map: image '"),
    ("mass_map_not_an_image.json", "cloth.mass_map: cannot read '"),
    ("model_unknown.json",
     'simulation.model: expected one of "classic", "fem", got "finite-element"'),
    ("fem_stretch_zero.json", "cloth.fem.stretch: expected a number > 0, got 0"),
    ("fem_typo.json", "unknown key 'bend' in cloth.fem (did you mean 'bending'?"),
]


def test_mesh_file_messages_say_what_is_wrong():
    assert error_of(str(BAD / "mesh_not_watertight.json")).endswith(
        "open_bowl.obj' is not watertight (it has holes or open edges): a solid collider "
        'needs a closed mesh; set "solid": false to collide with it as a one-sided surface')
    assert "no_such_mesh.obj' not found" in error_of(str(BAD / "mesh_file_missing.json"))


def test_bad_table_covers_every_bad_file():
    assert sorted(name for name, _ in BAD_TABLE) == sorted(p.name for p in BAD.iterdir())
    assert len(BAD_TABLE) >= 21


@pytest.mark.parametrize("name, expected", BAD_TABLE, ids=[n for n, _ in BAD_TABLE])
def test_bad_scene(name, expected):
    path = str(BAD / name)
    msg = error_of(path)
    assert msg.startswith(f"{path}: "), msg
    assert expected in msg, msg


def test_bad_scene_relative_path_is_named_as_given(monkeypatch):
    monkeypatch.chdir(ROOT)
    msg = error_of(os.path.join("tests", "bad_scenes", "width_negative.json"))
    assert msg == "tests/bad_scenes/width_negative.json: cloth.width: expected a number > 0, got -1"


def test_missing_file_and_directory(tmp_path):
    missing = str(tmp_path / "nope.json")
    assert error_of(missing) == f"{missing}: cannot read: No such file or directory"
    assert error_of(tmp_path).startswith(f"{tmp_path}: cannot read: ")


def test_dict_source_messages_name_scene():
    d = raw("plane")
    d["cloth"]["width"] = -1
    assert error_of(d) == "<scene>: cloth.width: expected a number > 0, got -1"
    assert error_of(42).startswith("<scene>: expected a path")  # type: ignore[arg-type]


def test_top_level_errors_are_preferred_and_unknown_beats_missing():
    d = raw("plane")
    d["clth"] = d.pop("cloth")
    msg = error_of(d)
    assert msg.startswith("<scene>: unknown key 'clth' at top level (did you mean 'cloth'?")
    assert ("expected one of: cloth, sphere, plane, box, mesh, wind, simulation, camera, light, "
            "render") in msg


# --------------------------------------------------------------------------------------
# Overrides
# --------------------------------------------------------------------------------------

def test_overrides_set_values_of_every_type(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    _texture_files(tmp_path, "my texture.png")
    s = load_scene(SCENES / "sphere.json", [
        "cloth.ks=500", "simulation.self_collision=false", "camera.position=[0,1,3]",
        "camera.target=[0.5,0,0.5]", "render.shader=toon", "sphere.0.radius=0.3",
        f"render.texture={tmp_path}/my texture.png", "light.intensity=[1, 2, 3]", "cloth.pinned=[[0,0]]",
    ])
    assert s.cloth.ks == 500.0 and s.simulation.self_collision is False
    assert s.camera.position == (0.0, 1.0, 3.0) and s.render.shader == "toon"
    assert s.colliders[0].radius == 0.3 and s.render.texture.name == "my texture.png"
    assert s.light.intensity == (1.0, 2.0, 3.0) and s.cloth.pinned == ((0, 0),)


def test_overrides_index_lists_and_value_may_contain_equals(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    _texture_files(tmp_path, "a=b.png")
    d = raw("sphere")
    d["sphere"] = [d["sphere"], {"origin": [0, 0, 0], "radius": 0.1, "friction": 0}]
    s = load_scene(d, ["sphere.1.radius=0.25", "sphere.0.origin.1=0.5", "render.texture=a=b.png"])
    assert s.colliders[1].radius == 0.25 and s.colliders[0].origin == (0.5, 0.5, 0.5)
    assert s.render.texture.name == "a=b.png"
    assert apply_overrides(d, ["cloth.ks=1"])["cloth"]["ks"] == 1 and d["cloth"]["ks"] == 5000.0


@pytest.mark.parametrize("override, expected", [
    ("cloth.ks", "override 'cloth.ks': expected 'dotted.key=value'"),
    ("=5", "override '=5': expected 'dotted.key=value'"),
    ("cloth..ks=5", "override 'cloth..ks=5'"),
    ("cloth.ks.x=5", "override 'cloth.ks.x=5': cloth.ks is a number"),
    ("sphere.3.radius=1", "override 'sphere.3.radius=1': sphere[3]: index out of range"),
    ("cloth.pinned.x=1", "override 'cloth.pinned.x=1': cloth.pinned is a list"),
])
def test_malformed_overrides(override, expected):
    d = raw("sphere")
    d["cloth"]["pinned"] = [[0, 0]]
    msg = error_of(d, [override])
    assert msg.startswith("<scene>: ") and expected in msg, msg


@pytest.mark.parametrize("override, expected", [
    ("cloth.kss=500", "unknown key 'kss' in cloth (did you mean 'ks'?"),
    ("rendr.shader=toon", "unknown key 'rendr' at top level (did you mean 'render'?"),
    ("cloth.ks=-5", "cloth.ks: expected a number >= 0, got -5"),
    ("cloth.ks=NaN", "cloth.ks: expected a finite number, got NaN"),
    ("render.shader=cartoon", "render.shader: expected one of"),
    ("camera.position=[0,1,3]", "camera.target: missing required key"),
])
def test_overrides_are_validated_like_the_file(override, expected):
    msg = error_of(SCENES / "sphere.json", [override])
    assert msg.startswith(f"{SCENES / 'sphere.json'}: ") and expected in msg, msg
    assert msg.endswith(f"(from override {override!r})"), msg


def test_file_errors_are_not_blamed_on_unrelated_overrides():
    msg = error_of(str(BAD / "width_negative.json"), ["cloth.ks=1"])
    assert "override" not in msg


# --------------------------------------------------------------------------------------
# Collider order
# --------------------------------------------------------------------------------------

def test_collider_order_follows_the_file(tmp_path):
    cloth = raw("plane")["cloth"]
    sph = [{"origin": [0, 0, 0], "radius": r, "friction": 0.1} for r in (0.1, 0.2)]
    pl = [{"point": [0, y, 0], "normal": [0, 1, 0], "friction": 0.2} for y in (0.0, -1.0)]
    text = json.dumps({"plane": pl, "cloth": cloth, "sphere": sph})
    (tmp_path / "a.json").write_text(text)
    cs = load_scene(tmp_path / "a.json").colliders
    assert [(type(c).__name__, getattr(c, "radius", None) or c.point[1]) for c in cs] == [
        ("Plane", 0.0), ("Plane", -1.0), ("Sphere", 0.1), ("Sphere", 0.2)]
    cs = load_scene({"sphere": sph[1], "cloth": cloth, "plane": pl[0]}).colliders
    assert cs == (Sphere((0, 0, 0), 0.2, 0.1), Plane((0, 0, 0), (0, 1, 0), 0.2))
    assert load_scene(raw("selfCollision")).colliders == (Plane((0, 0, 0), (0, 1, 0), 0.5),)


# --------------------------------------------------------------------------------------
# Property-based: mutations of a valid scene are caught, valid random scenes load
# --------------------------------------------------------------------------------------

FULL = raw("two_spheres")
FULL["cloth"]["pinned"] = [[0, 0], [39, 39]]
FULL["render"].update({"shader": "bump", "texture": str(ROOT / "textures" / "cloth.png"), "k_a": 0.1, "k_d": [1, 1, 1],
                       "background": [0.1, 0.1, 0.1]})
FULL["simulation"].update({"integrator": "verlet", "seed": 3, "gravity": [0, -9.8, 0],
                          "iterations": 10})
load_scene(FULL)  # the base of the mutations is valid

REQUIRED = {
    (): ["cloth"],
    ("cloth",): ["width", "height", "num_width_points", "num_height_points", "thickness",
                 "orientation", "damping", "density", "ks", "enable_structural",
                 "enable_shearing", "enable_bending"],
    ("sphere", 0): ["origin", "radius", "friction"],
    ("sphere", 1): ["origin", "radius", "friction"],
    ("plane",): ["point", "normal", "friction"],
    ("camera",): ["position", "target"],
}
# keys whose value must be > 0 or >= 0 (a negative number is always wrong)
NON_NEGATIVE = [
    ("cloth", k) for k in ("width", "height", "num_width_points", "num_height_points",
                           "thickness", "damping", "density", "ks")
] + [("sphere", 0, "radius"), ("sphere", 1, "friction"), ("plane", "friction"),
     ("simulation", "frames_per_sec"), ("simulation", "steps_per_frame"), ("simulation", "seed"),
     ("simulation", "iterations"),
     ("camera", "vfov"), ("render", "width"), ("render", "aa"), ("render", "k_a"),
     ("render", "background", 1), ("render", "k_d", 0), ("light", "intensity", 2),
     ("cloth", "pinned", 1, 0)]


def leaves(node, path=()):
    """Every scalar and every list-of-numbers path of a scene."""
    if isinstance(node, dict):
        for k, v in node.items():
            yield from leaves(v, path + (k,))
    elif isinstance(node, list) and node and all(isinstance(x, (dict, list)) for x in node):
        for i, v in enumerate(node):
            yield from leaves(v, path + (i,))
    else:
        yield path, node
        if isinstance(node, list):
            for i, v in enumerate(node):
                yield path + (i,), v


LEAVES = list(leaves(FULL))
OBJECT_PATHS = [(), ("cloth",), ("sphere", 0), ("sphere", 1), ("plane",), ("simulation",),
                ("camera",), ("light",), ("render",)]


def get(d, path):
    for p in path:
        d = d[p]
    return d


def fmt(path) -> str:
    return scene_check.fmt_path(list(path))


SCHEMA = scene_schema()


def allowed_keys(parent) -> set:
    block = SCHEMA if not parent else SCHEMA["$defs"][parent[0]]
    return set(block["properties"])


def wrong_values(value):
    if isinstance(value, bool):
        return [0, 1, "true", None, [True]]
    if isinstance(value, (int, float)):
        return ["1", True, False, None, {}, [value]]
    if isinstance(value, str):
        return [5, True, None, [value], {}]
    return [5, "x", True, None, {}, value[:2] if len(value) > 2 else value + value + value]


mutation = st.one_of(
    st.tuples(st.just("drop"), st.sampled_from(
        [(parent, key) for parent, keys in REQUIRED.items() for key in keys])),
    st.tuples(st.just("type"), st.sampled_from(LEAVES).flatmap(
        lambda leaf: st.tuples(st.just(leaf[0]), st.sampled_from(wrong_values(leaf[1]))))),
    st.tuples(st.just("nonfinite"), st.tuples(
        st.sampled_from([p for p, v in LEAVES if isinstance(v, (int, float))
                         and not isinstance(v, bool)]),
        st.sampled_from([math.nan, math.inf, -math.inf]))),
    st.tuples(st.just("negative"), st.tuples(
        st.sampled_from(NON_NEGATIVE),
        st.one_of(st.integers(-10**6, -1), st.floats(-1e6, -1e-6)))),
    st.tuples(st.just("unknown"), st.tuples(
        st.sampled_from(OBJECT_PATHS),
        st.text(min_size=1, max_size=12), st.sampled_from([1, "x", None, [1], {}])))
)


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(mutation)
def test_mutated_scene_is_rejected_naming_the_key(mut):
    d = copy.deepcopy(FULL)
    kind, args = mut
    if kind == "drop":
        parent, key = args
        del get(d, parent)[key]
        named = fmt(parent + (key,))
    elif kind in ("type", "nonfinite", "negative"):
        path, value = args
        get(d, path[:-1])[path[-1]] = value
        named = fmt(path)
    else:
        parent, key, value = args
        obj = get(d, parent)
        if key in allowed_keys(parent):
            return
        obj[key] = value
        named = f"unknown key {key!r}"
    msg = error_of(d)
    assert msg.startswith("<scene>: "), msg
    assert named in msg, (mut, msg)


@st.composite
def valid_scenes(draw):
    nw = draw(st.integers(2, 80))
    nh = draw(st.integers(2, 80))
    pos = st.floats(1e-3, 1e3)
    pins = draw(st.lists(st.tuples(st.integers(0, nw - 1), st.integers(0, nh - 1)), max_size=8))
    cloth = {
        "width": draw(pos), "height": draw(pos), "num_width_points": nw, "num_height_points": nh,
        "thickness": draw(st.floats(0, 1)), "orientation": draw(st.sampled_from([0, 1])),
        "damping": draw(st.floats(0, 100)), "density": draw(pos), "ks": draw(st.floats(0, 1e6)),
        "enable_structural": draw(st.booleans()), "enable_shearing": draw(st.booleans()),
        "enable_bending": draw(st.booleans()), "pinned": [list(p) for p in pins],
    }
    vec = st.lists(st.floats(-10, 10), min_size=3, max_size=3)
    d = {"cloth": cloth}
    spheres = draw(st.lists(st.fixed_dictionaries(
        {"origin": vec, "radius": pos, "friction": st.floats(0, 1)}), max_size=3))
    if spheres:
        d["sphere"] = spheres if len(spheres) > 1 or draw(st.booleans()) else spheres[0]
    if draw(st.booleans()):
        d["plane"] = {"point": draw(vec), "normal": [0, 1, draw(st.floats(-1, 1))],
                      "friction": draw(st.floats(0, 1))}
    d["simulation"] = draw(st.fixed_dictionaries({}, optional={
        "frames_per_sec": pos, "steps_per_frame": st.integers(1, 100),
        "gravity": vec, "integrator": st.sampled_from(INTEGRATORS), "seed": st.integers(0, 2**32),
        "self_collision": st.sampled_from([True, False, "auto"]), "iterations": st.integers(1, 50)}))
    d["render"] = draw(st.fixed_dictionaries({}, optional={
        "shader": st.sampled_from(SHADERS), "width": st.integers(1, 8192),
        "aa": st.integers(1, 8), "k_s": st.floats(0, 10), "k_h": st.floats(-1, 1)}))
    return d


@settings(max_examples=150, deadline=None)
@given(valid_scenes())
def test_valid_random_scenes_load(d):
    s = load_scene(d)
    c = d["cloth"]
    assert s.cloth.num_width_points == c["num_width_points"] and s.cloth.width == c["width"]
    assert s.cloth.pinned == tuple(tuple(p) for p in c["pinned"])
    n_sph = len(d["sphere"]) if isinstance(d.get("sphere"), list) else int("sphere" in d)
    assert len(s.colliders) == n_sph + ("plane" in d)
    assert s.simulation.steps_per_frame == d["simulation"].get("steps_per_frame", 30)
    assert s.simulation.iterations == d["simulation"].get("iterations", 10)
    assert s.render.shader == d["render"].get("shader", "phong")
    assert set(s.render.params) == set(d["render"]) & {"k_s", "k_h"}


def test_a_collider_look_loads_and_a_line_shader_is_refused():
    d = raw("sphere")
    d["sphere"].update(color=[0.9, 0.3, 0.2], shader="toon")
    s = load_scene(d)
    assert (s.colliders[0].color, s.colliders[0].shader) == ((0.9, 0.3, 0.2), "toon")
    assert load_scene(raw("sphere")).colliders[0].shader is None
    d["sphere"]["shader"] = "wireframe"
    msg = error_of(d)
    assert "sphere" in msg and "shader" in msg and "wireframe" in msg, msg
