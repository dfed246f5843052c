"""A mesh cloth (`cloth.mesh`) through every command: `render` (GIF, --export-npz,
--export-obj), `render plan` and fidelity auto, `render report --sweep`, `render batch`, bad
input, `render bench`. The Dask paths are in test_distributed.py. Tiny meshes, tiny images,
a fifth of a second."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from pipeline.cli import batch, main, report
from test_mesh_cloth import mesh_scene

SMALL = ["--size", "32x32", "--duration", "0.2", "--quiet"]


def tube_obj(folder: Path, around: int = 8, along: int = 5, radius: float = 0.15,
             length: float = 0.6) -> Path:
    """A horizontal open tube (axis x) whose uvs wrap once around it: a uv seam along the
    points at angle 0 (u = 0 on one side, u = 1 on the other). Its first ring of faces is
    the group `band0`, the others `rest`."""
    theta = 2.0 * np.pi * np.arange(around) / around
    lines = [f"v {length * i / (along - 1)!r} {0.6 + radius * float(np.cos(t))!r} "
             f"{radius * float(np.sin(t))!r}" for i in range(along) for t in theta]
    lines += [f"vt {j / around!r} {i / (along - 1)!r}"
              for i in range(along) for j in range(around + 1)]

    def corner(i: int, j: int) -> str:
        return f"{i * around + j % around + 1}/{i * (around + 1) + j + 1}"

    for i in range(along - 1):
        lines.append("g band0" if i == 0 else "g rest")
        for j in range(around):
            a, b, c, d = corner(i, j), corner(i, j + 1), corner(i + 1, j + 1), corner(i + 1, j)
            lines += [f"f {a} {b} {c}", f"f {a} {c} {d}"]
    path = folder / "tube.obj"
    path.write_text("\n".join(lines) + "\n")
    return path


def write_mesh_scene(folder: Path, name: str = "tube", **changes) -> Path:
    """A scene beside its mesh, naming it by a path relative to the scene's folder; pinned
    by the group `band0`. `changes`: block__key=value."""
    obj = tube_obj(folder)
    scene = mesh_scene(obj)
    scene["cloth"].update(mesh=obj.name, pinned={"group": "band0"})
    scene["simulation"]["steps_per_frame"] = 20
    for key, value in changes.items():
        block, _, item = key.partition("__")
        scene.setdefault(block, {})[item] = value
    path = folder / f"{name}.json"
    path.write_text(json.dumps(scene))
    return path


def obj_arrays(path: Path) -> dict[str, np.ndarray]:
    """The v, vt, vn and f (v/vt/vn index triples) of an OBJ written by --export-obj."""
    rows: dict[str, list] = {"v": [], "vt": [], "vn": [], "f": []}
    for line in path.read_text().splitlines():
        tag, *fields = line.split()
        if tag == "f":
            rows["f"].append([[int(k) for k in c.split("/")] for c in fields])
        elif tag in rows:
            rows[tag].append([float(v) for v in fields])
    return {k: np.array(v) for k, v in rows.items()}


def test_render_writes_a_mesh_cloths_gif_npz_and_obj_as_drawn(tmp_path, capsys):
    """The NPZ has the welded points, their faces and the uvs per face corner (the seam
    split); each OBJ carries the cloth as it is drawn: a vertex per (point, uv), so the
    seam's points twice with their two uvs, the normals welded across the seam."""
    import shading
    from PIL import Image

    from pipeline import Simulation, load_scene
    from pipeline.run.frames import cloth_seams

    scene = write_mesh_scene(tmp_path)
    rc = main([str(scene), "--out", str(tmp_path / "t.gif"), "--export-npz",
               str(tmp_path / "t.npz"), "--export-obj", str(tmp_path / "objs")] + SMALL)
    assert rc == 0, capsys.readouterr().err
    sim = Simulation(load_scene(scene))
    topo, n = sim.model.mesh.topology, sim.model.n
    data = np.load(tmp_path / "t.npz")
    frames = len(data["times"])
    assert n == 40 and frames == 5 and data["positions"].shape == (frames, n, 3)
    with Image.open(tmp_path / "t.gif") as gif:
        assert gif.n_frames == frames and gif.size == (32, 32)
    assert np.array_equal(data["faces"], topo.triangles) and data["faces"].dtype == np.int32
    assert np.array_equal(data["face_uv"], topo.corner_uv) and data["face_uv"].shape == (64, 3, 2)
    assert np.array_equal(data["uv"], topo.point_uv) and data["grid"].tolist() == [0, 0]
    assert {0.0, 1.0} <= set(data["face_uv"][..., 0].ravel().tolist())  # both sides of the seam
    assert np.array_equal(data["positions"][0], sim.positions)
    sim.advance(int(data["sim_frames"][-1]))
    assert np.array_equal(data["positions"][-1], sim.positions)
    objs = sorted((tmp_path / "objs").glob("*.obj"))
    assert len(objs) == frames and objs[0].read_text().count("\no ") == 1  # the cloth alone
    seams = cloth_seams(sim.model)
    drawn = shading.seamed_cloth_mesh(data["positions"][-1], seams)
    obj = obj_arrays(objs[-1])
    assert len(seams.point) == n + 5  # the seam's five points drawn twice
    assert np.allclose(obj["v"], drawn.positions, rtol=1e-8, atol=1e-9)
    assert np.allclose(obj["vt"], drawn.uvs, atol=1e-9)
    assert np.allclose(obj["vn"], drawn.normals, atol=1e-8)
    f = obj["f"]
    assert np.array_equal(f[..., 0], f[..., 1]) and np.array_equal(f[..., 0], f[..., 2])
    assert np.array_equal(f[..., 0] - 1, drawn.triangles)
    twice = seams.point[n:]
    first = [int(np.flatnonzero(seams.point == p)[0]) for p in twice]
    assert np.array_equal(obj["v"][first], obj["v"][n:])  # one place ...
    assert np.array_equal(obj["vn"][first], obj["vn"][n:])  # ... one normal ...
    assert not np.allclose(obj["vt"][first], obj["vt"][n:])  # ... two uvs


@pytest.mark.parametrize("model", ["classic", "fem"])
def test_plan_and_fidelity_auto_of_a_mesh_cloth(tmp_path, capsys, model):
    """`render plan` names the mesh instead of a grid (the FEM: no grid pilot, and why);
    fidelity auto renders it."""
    scene = write_mesh_scene(tmp_path, simulation__model=model)
    assert main(["plan", str(scene), "--fidelity", "auto"]) == 0
    lines = capsys.readouterr().out.splitlines()
    mesh = [line for line in lines if line.startswith("mesh: ")]
    assert mesh and mesh[0].startswith("mesh: 40 points, 64 triangles from "
                                       f"{tmp_path / 'tube.obj'}")
    assert ("(no FEM grid pilot: a mesh cloth has no grid to coarsen)" in mesh[0]) == (
        model == "fem")
    assert not any("grid" in line for line in lines if line not in mesh), lines
    assert lines[0].startswith("fidelity auto: integrator ")
    assert main(["plan", str(scene), "--fidelity", "auto", "--json"]) == 0
    plan = json.loads(capsys.readouterr().out)
    assert plan["mesh"] == {"file": str(tmp_path / "tube.obj"), "points": 40, "triangles": 64}
    assert plan["grid_choice"] is None and plan["grid"] == [0, 0]
    assert main(["plan", str(scene)]) == 0
    assert "mesh: 40 points" in capsys.readouterr().out
    out = tmp_path / "auto.gif"
    rc = main([str(scene), "--out", str(out), "--fidelity", "auto", "--size", "32x32",
               "--duration", "0.2"])
    err = capsys.readouterr().err
    assert rc == 0 and out.stat().st_size > 0, err
    assert "render: auto: " in err and "Traceback" not in err


def test_report_sweeps_a_mesh_cloth(tmp_path, capsys):
    """Two sweeps (the stiffness and the model) over a mesh cloth: four cells, a GIF grid."""
    scene = write_mesh_scene(tmp_path)
    rc = report.main([str(scene), "--out", str(tmp_path / "r.html"), "--sweep",
                      "cloth.ks=200,2000", "--sweep", "simulation.model=classic,fem",
                      "--at", "0.2", "--size", "32x32", "--gif", "--gif-size", "24x24",
                      "--jobs", "1", "--quiet"])
    assert rc == 0, capsys.readouterr().err
    html = (tmp_path / "r.html").read_text()
    assert html.count('src="data:image/png;base64,') == 4 and "simulation diverged" not in html
    assert (tmp_path / "r.png").stat().st_size > 0 and (tmp_path / "r.gif").stat().st_size > 0


def test_batch_renders_mesh_cloths_as_render_does(tmp_path, capsys):
    folder = tmp_path / "scenes"
    folder.mkdir()
    write_mesh_scene(folder, "a")
    write_mesh_scene(folder, "b", simulation__model="fem")
    rc = batch.main([str(folder), "--out-dir", str(tmp_path / "out"), "--size", "32x32",
                     "--duration", "0.2", "-q"])
    table = capsys.readouterr().out
    assert rc == 0 and table.splitlines()[-1].startswith("2 scenes: 2 ok, 0 failed"), table
    for name in ("a", "b"):
        ref = tmp_path / f"ref_{name}.gif"
        assert main([str(folder / f"{name}.json"), "--out", str(ref)] + SMALL) == 0
        assert (tmp_path / "out" / f"{name}.gif").read_bytes() == ref.read_bytes()


@pytest.mark.parametrize("change,expected", [
    ({"mesh": "missing.obj"}, "cloth.mesh: mesh file '{t}/missing.obj' not found"),
    ({"pinned": {"group": "waist"}},
     "cloth.pinned: no group 'waist' in tube.obj (its groups: 'band0', 'rest')"),
])
@pytest.mark.parametrize("command", ["render", "plan", "report"])
def test_bad_mesh_input_is_one_line_exit_2_and_no_output(tmp_path, capsys, change, expected,
                                                         command):
    scene = write_mesh_scene(tmp_path)
    data = json.loads(scene.read_text())
    data["cloth"].update(change)
    scene.write_text(json.dumps(data))
    before = sorted(tmp_path.rglob("*"))
    argv = {"render": [str(scene), "--out", str(tmp_path / "x.gif")] + SMALL[:-1],
            "plan": ["plan", str(scene), "--fidelity", "auto"],
            "report": ["report", str(scene), "--out", str(tmp_path / "x.html"), "--sweep",
                       "cloth.ks=200,2000", "--jobs", "1"]}[command]
    rc = main(argv)
    captured = capsys.readouterr()
    assert rc == 2, captured.err
    assert captured.err.count("\n") == 1 and captured.err.startswith("render: ")
    assert expected.format(t=tmp_path) in captured.err
    assert sorted(tmp_path.rglob("*")) == before


def test_bench_refuses_a_mesh_cloth_in_one_line(tmp_path, capsys):
    """`render bench` compares integrators on resized grids (implicit Euler and XPBD among
    them, which do not step a mesh): a mesh cloth is bad input, and nothing is written."""
    scene = write_mesh_scene(tmp_path)
    before = sorted(tmp_path.rglob("*"))
    rc = main(["bench", str(scene), "--out", str(tmp_path / "bench")])
    err = capsys.readouterr().err
    assert rc == 2 and err.count("\n") == 1 and "cloth.mesh" in err, err
    assert sorted(tmp_path.rglob("*")) == before
