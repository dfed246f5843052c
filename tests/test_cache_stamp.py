"""A cached kernel is recompiled when a clothpipe file its file imports changes, not only its
own file (numba's stamp: clothjit/cache_stamp.py), and loaded from the cache otherwise."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from conftest import child_env

import pipeline
from clothjit import cache_stamp

# A child process: track the tiny package, call its kernel, print the result and the
# functions numba compiled (numba's compile event: none when loaded from the cache).
CHILD = """
import json, sys
from numba.core import event
from clothjit import cache_stamp

compiled = []

class Compiles(event.Listener):
    def on_start(self, ev):
        compiled.append(ev.data["dispatcher"].py_func.__name__)

    def on_end(self, ev):
        pass

event.register("numba:compile", Compiles())
sys.path.insert(0, sys.argv[1])
cache_stamp.track(sys.argv[1] + "/tiny")
from tiny.a import kernel
print(json.dumps([kernel(1.0), compiled]))
"""

B = """from clothjit import njit


@njit(cache=True)
def value():
    return {}
"""

A = """from clothjit import njit

from .b import value


@njit(cache=True)
def kernel(x):
    return x + value()
"""


def _package(root: Path) -> Path:
    tiny = root / "tiny"
    tiny.mkdir()
    (tiny / "__init__.py").write_text("")
    (tiny / "a.py").write_text(A)
    (tiny / "b.py").write_text(B.format("1.0"))
    return tiny


def _run(root: Path) -> tuple[float, list[str]]:
    env = child_env(NUMBA_CACHE_DIR=str(root / "numba-cache"))
    out = subprocess.run([sys.executable, "-c", CHILD, str(root)], env=env, check=True,
                         capture_output=True, text=True, timeout=300)
    result, compiled = json.loads(out.stdout.strip().splitlines()[-1])
    return result, compiled


def test_a_changed_helper_file_recompiles_its_caller(tmp_path):
    tiny = _package(tmp_path)
    assert _run(tmp_path) == (2.0, ["kernel", "value"])  # cold: both compiled
    assert _run(tmp_path) == (2.0, [])  # nothing changed: loaded from the cache
    (tiny / "b.py").write_text(B.format("5.0"))  # only the helper's file
    result, compiled = _run(tmp_path)
    assert (result, "kernel" in compiled) == (6.0, True)  # numba alone: 2.0, stale
    assert _run(tmp_path) == (6.0, [])


def test_import_closure_of_the_real_package():
    physics = Path(pipeline.__file__).resolve().parent / "physics"
    closure = cache_stamp.import_closure(str(physics / "integrators" / "vbd.py"))
    for name in ("integrators/vbd.py", "vbd_contact.py", "system.py", "forces.py"):
        assert str(physics / name) in closure  # itself, relative imports, transitively
    assert str(Path(cache_stamp.__file__).resolve().parent / "__init__.py") in closure
    assert not any("numba" in Path(f).parts or "numpy" in Path(f).parts for f in closure)
    assert str(physics / "integrators" / "vbd.py") not in cache_stamp.import_closure(
        str(physics / "vbd_contact.py"))


def test_tiny_package_closure_and_untracked_files(tmp_path):
    tiny = _package(tmp_path)
    assert cache_stamp._module_name(str(tiny / "a.py")) is None  # not tracked yet
    try:
        cache_stamp.track(str(tiny))
        closure = cache_stamp.import_closure(str(tiny / "a.py"))
        jit = Path(cache_stamp.__file__).resolve().parent
        assert {str((tiny / n).resolve()) for n in ("a.py", "b.py")} == {
            f for f in closure if Path(f).parent != jit}  # not __init__.py: not imported
    finally:
        cache_stamp.untrack(str(tiny))
