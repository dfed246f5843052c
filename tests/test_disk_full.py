"""A real full disk: a small tmpfs (mounted when running as root), filled up, then every
output kind written to it: exit 1, one line naming the file and the reason, nothing left."""
from __future__ import annotations

import json
import os
import subprocess
from pathlib import Path

import pytest
from conftest import cloth_dict, scene_dict

from pipeline.cli import main

SCENE = scene_dict(cloth_dict(12, 12, thickness=0.0095, damping=0.2, density=150.0, ks=5000.0),
                   spheres=[((0.5, 0.2, 0.5), 0.2, 0.3)])
RUN = ["--size", "128x128", "--duration", "0.4", "--quiet"]


@pytest.fixture
def full_disk(tmp_path):
    """A 300 kB tmpfs with a filler file taking all its space but what the file system
    keeps for itself; yields the mount point."""
    if not hasattr(os, "geteuid") or os.geteuid() != 0:
        pytest.skip("mounting a tmpfs needs root")
    mnt = tmp_path / "small"
    mnt.mkdir()
    r = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=300k", "tmpfs", str(mnt)],
                       capture_output=True, text=True)
    if r.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs: {r.stderr.strip()}")
    try:
        fd = os.open(mnt / "filler", os.O_WRONLY | os.O_CREAT)
        try:
            while os.write(fd, b"\0" * 4096):
                pass
        except OSError:
            pass
        finally:
            os.close(fd)
        yield mnt
    finally:
        subprocess.run(["umount", str(mnt)], check=True)


@pytest.fixture
def scene(tmp_path) -> Path:
    f = tmp_path / "s.json"
    f.write_text(json.dumps(SCENE))
    return f


@pytest.mark.parametrize("args, target", [
    (["--out", "{d}/x.gif"], "x.gif"),
    (["--out", "{d}/x.mp4"], "x.mp4"),
    (["--out", "{d}/x.png"], "x.png"),
    (["--out", "{d}/frames/"], "frames"),
    (["--export-obj", "{d}/objs"], "objs"),
    (["--export-npz", "{d}/p.npz"], "p.npz"),
    (["report", "--out", "{d}/r.html", "--shaders", "phong", "--at", "0"], "r"),
])
def test_full_disk(full_disk, scene, capsys, args, target):
    args = [a.format(d=full_disk) for a in args]
    if args[0] == "report":
        argv = ["report", str(scene)] + args[1:] + ["--size", "64x64", "--quiet"]
    else:
        argv = [str(scene)] + args + RUN
    code = main(argv)
    err = capsys.readouterr().err
    assert code == 1, err
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith(f"render: no space left on device writing {full_disk}/{target}")
    assert "internal error" not in err
    assert sorted(p.name for p in full_disk.iterdir()) == ["filler"]
