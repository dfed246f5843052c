"""The layering of pyproject.toml's import-linter contracts holds, and bites: a module that
imports upwards, or one added outside every layer, fails `lint-imports` (run by .ci/run)."""
from __future__ import annotations

import os
import shutil
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
LINT = shutil.which("lint-imports")
pytestmark = pytest.mark.skipif(LINT is None, reason="import-linter is not installed")


def lint(tree: Path) -> subprocess.CompletedProcess:
    env = dict(os.environ, PYTHONPATH=str(tree))  # the copy's packages, not the installed ones
    return subprocess.run([LINT, "--no-cache"], cwd=tree, env=env, capture_output=True,
                          text=True, timeout=120)


@pytest.fixture(scope="module")
def tree(tmp_path_factory) -> Path:
    """A copy of the source packages and pyproject.toml."""
    root = tmp_path_factory.mktemp("tree")
    for package in ("pipeline", "shading", "clothjit"):
        shutil.copytree(ROOT / package, root / package,
                        ignore=shutil.ignore_patterns("__pycache__"))
    shutil.copy(ROOT / "pyproject.toml", root / "pyproject.toml")
    return root


def test_the_tree_keeps_every_contract(tree):
    result = lint(tree)
    assert result.returncode == 0, result.stdout + result.stderr
    assert "0 broken" in result.stdout


@pytest.mark.parametrize("path, source, broken", [
    # the physics importing the command line
    ("pipeline/physics/upwards.py", "from pipeline.cli import options\n",
     "pipeline.physics is not allowed to import pipeline.cli"),
    # the renderer importing the simulator
    ("shading/upwards.py", "import pipeline.physics.forces\n",
     "shading is not allowed to import pipeline"),
    # the rasteriser importing lighting
    ("shading/raster_lit.py", "from shading import lighting\n",
     "not allowed to import shading.lighting"),
    # a module beside the layers, in no layer at all
    ("pipeline/stray.py", "X = 1\n", "pipeline.stray"),
])
def test_a_module_at_the_wrong_layer_fails(tree, path, source, broken):
    module = tree / path
    module.write_text(source)
    try:
        if path == "shading/raster_lit.py":  # give it a layer: the rasteriser's
            text = (tree / "pyproject.toml").read_text()
            text = text.replace('"raster | mesh', '"raster | raster_lit | mesh')
            (tree / "pyproject.toml").write_text(text)
        result = lint(tree)
    finally:
        module.unlink()
        shutil.copy(ROOT / "pyproject.toml", tree / "pyproject.toml")
    assert result.returncode != 0
    assert broken in result.stdout + result.stderr, result.stdout + result.stderr
