"""numba's on-disk cache: its index stays right when processes save into it at once
(clothjit), a new process loads every renderer kernel from it, and loading leaves
numba's compiler registries alone until something compiles."""
from __future__ import annotations

import multiprocessing
import os
import pickle
import subprocess
import sys

import pytest
from conftest import child_env, scene_path

SAVES = 150


def _save_many(folder: str, worker: int, start) -> None:
    import clothjit  # noqa: F401  (installs the locked save)
    from numba.core.caching import IndexDataCacheFile

    cache = IndexDataCacheFile(folder, "f-1.py311", source_stamp=("stamp", 1))
    start.wait()
    for i in range(SAVES):
        key = (worker, i)
        cache.save(key, pickle.dumps(key))


def _saved(folder: str) -> dict:
    import clothjit  # noqa: F401
    from numba.core.caching import IndexDataCacheFile

    cache = IndexDataCacheFile(folder, "f-1.py311", source_stamp=("stamp", 1))
    return {key: cache.load(key) for key in cache._load_index()}


def test_concurrent_saves_keep_every_entry_and_its_own_data(tmp_path):
    """Two processes save different keys of one function as fast as they can (numba's own
    save loses entries and points keys at each other's data here)."""
    ctx = multiprocessing.get_context("spawn")
    start = ctx.Event()
    procs = [ctx.Process(target=_save_many, args=(str(tmp_path), w, start)) for w in (0, 1)]
    for p in procs:
        p.start()
    start.set()
    for p in procs:
        p.join(60)
        assert p.exitcode == 0
    saved = _saved(str(tmp_path))
    assert len(saved) == 2 * SAVES
    wrong = [key for key, data in saved.items() if pickle.loads(data) != key]
    assert wrong == []


def test_import_shading_does_not_import_numba():
    code = "import sys, pipeline, shading; print('numba' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


_STARTUP = """
import numpy as np, shading
from shading import mesh, raster, renderer
from shading.shaders import REGISTRY, displacement
j = np.tile(np.arange(6.0), 6); i = np.repeat(np.arange(6.0), 6)
pos = np.stack([j / 5, np.ones(36), i / 5], axis=1)
cam = shading.Camera.default_for_cloth(pos, 1, 1, width=16, height=12)
ms = [shading.cloth_mesh(pos, 6, 6, np.array([[0, 1]])), shading.sphere_mesh((0.5, 0.2, 0.5), 0.2)]
for name in shading.SHADERS:
    shading.render(ms, cam, None, name)
kernels = [raster.project, raster.setup_triangles, raster.setup_lines, raster.bin_prims,
           raster.raster_triangles, raster.raster_lines, mesh._normals_tangents,
           renderer._pack_vertices, renderer._pack_prims, displacement._displace]
kernels += [shading.shade.fragment_stage, shading.shade.fetch, shading.shade.begin_row,
            shading.lighting.blinn_phong, shading.lighting.bump_normal,
            shading.textures.sample_cube]
print(sum(len(k.stats.cache_misses) for k in kernels), sum(len(k.stats.cache_hits) for k in kernels))
"""


def test_new_process_loads_every_kernel_from_the_disk_cache():
    """Start-up: every numba kernel the renderer runs is cached on disk (no first-class
    function arguments), so a new process loads them all and compiles nothing."""
    run = lambda: subprocess.run([sys.executable, "-c", _STARTUP], env=child_env(),  # noqa: E731
                                 check=True, capture_output=True, text=True).stdout.split()
    run()  # fills the cache if this is the first use
    misses, hits = (int(v) for v in run())
    assert misses == 0 and hits > 0


_NESTED = """
from clothjit import njit, prange


@njit(cache=True, parallel=True, nogil=True, no_cpython_wrapper=True)
def parallel_add(x):
    for i in prange(x.shape[0]):
        x[i] += 1.0


@njit(cache=True)
def first(x):
    parallel_add(x)


@njit(cache=True)
def second(x):
    parallel_add(x)
"""


def test_a_kernel_compiled_over_a_cached_parallel_kernel_loads_in_a_new_process(tmp_path):
    """numba#8578: `second`, compiled while `parallel_add` came from the cache, is cached
    without the hook that starts numba's threads; a new process loading it first crashed
    (segfault) until clothjit started the threads on import. Each call a new process
    on one cache, as three `render` runs are."""
    (tmp_path / "nested_kernels.py").write_text(_NESTED)
    env = child_env(NUMBA_CACHE_DIR=str(tmp_path / "cache"))
    env["PYTHONPATH"] = os.pathsep.join([str(tmp_path)] + [p for p in [env.get("PYTHONPATH")] if p])
    for call in ("first", "second", "second"):
        code = (f"import numpy as np, nested_kernels as k; x = np.zeros(4); k.{call}(x); "
                "print(x.sum())")
        run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                             env=env, cwd=tmp_path, timeout=300)
        assert (run.returncode, run.stdout.strip()) == (0, "4.0"), (call, run.stderr[-500:])


_POINTER = """
import pickle, sys
import numpy as np
from clothjit import KernelPointer, njit, prange


@njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True, pointer=True)
def add_range(x, k, lo, hi):
    for i in range(lo, hi):
        x[i] += k * i


@njit(cache=True, nogil=True, parallel=True)
def add_all(x, k, kernel):
    for c in prange(4):
        kernel(x, k, c * x.shape[0] // 4, (c + 1) * x.shape[0] // 4)


x = np.zeros(10)
pointer = KernelPointer(add_range, (x, 0.5, np.int64(0), np.int64(0)))
if sys.argv[1] == "pickled":
    pointer = pickle.loads(pickle.dumps(pointer))
add_all(x, 0.5, pointer)
direct = np.zeros(10)
add_range.py_func(direct, 0.5, 0, 10)
print(np.array_equal(x, direct), sum(add_all.stats.cache_misses.values()),
      sum(add_range.stats.cache_misses.values()), sum(add_all.stats.cache_hits.values()))
"""


def test_a_kernel_pointer_calls_the_kernel_and_both_load_from_the_cache(tmp_path):
    """KernelPointer: the kernel called through it computes what Python computes; the
    caller (typed by the pointer's signature) and the kernel are cached like any kernel, so
    a new process compiles neither; a pickled pointer (sent to the compile helper) works."""
    (tmp_path / "pointer_kernels.py").write_text(_POINTER)
    env = child_env(NUMBA_CACHE_DIR=str(tmp_path / "cache"))
    outputs = []
    for how in ("plain", "pickled", "plain"):
        run = subprocess.run([sys.executable, str(tmp_path / "pointer_kernels.py"), how],
                             capture_output=True, text=True, env=env, cwd=tmp_path, timeout=300)
        assert run.returncode == 0, run.stderr[-500:]
        outputs.append(run.stdout.split())
    assert outputs[0] == ["True", "1", "1", "0"]  # compiled both
    assert outputs[1] == outputs[2] == ["True", "0", "0", "1"]  # loaded both


def _add_one(x):
    x[0] += 1.0


def _call_if(on, kernel, x):
    if on:
        kernel(x)
    return x[0]


def test_an_absent_kernel_pointer_has_the_present_ones_type_and_is_never_compiled():
    """KernelPointer(present=False), for a pass a scene does not use: typed as the pointer
    to the kernel, so its caller compiles once for both; the kernel is not compiled for it,
    and a pickled one (sent to the compile helper, a Dask worker) stays absent."""
    import numpy as np
    from clothjit import KernelPointer, njit

    add_one = njit(nogil=True, no_cpython_wrapper=True, pointer=True)(_add_one)
    call_if = njit(_call_if)
    x = np.zeros(2)
    absent = KernelPointer(add_one, (x,), present=False)
    assert call_if(False, absent, x) == 0.0
    assert not add_one.overloads  # never compiled
    copy = pickle.loads(pickle.dumps(absent))
    assert not copy.present and copy.numba_type == absent.numba_type
    present = KernelPointer(add_one, (x,))
    assert present.numba_type == absent.numba_type
    assert call_if(True, present, x) == 1.0 and x[0] == 1.0
    assert len(call_if.overloads) == 1  # one compile served both


def test_only_pointer_kernels_get_a_c_wrapper():
    """njit writes numba's C wrapper (the address a KernelPointer calls) only for the kernels
    declared pointer=True: the others compile without it, and a KernelPointer to one is
    refused with a message naming it."""
    import numpy as np
    from clothjit import KernelPointer, njit

    x = np.zeros(2)
    plain = njit(nogil=True)(_add_one)
    with pytest.raises(TypeError, match=r"_add_one has no C wrapper.*pointer=True"):
        KernelPointer(plain, (x,))
    plain(x)
    assert "cfunc." not in next(iter(plain.overloads.values())).library.get_llvm_str()
    pointed = njit(nogil=True, pointer=True)(_add_one)
    assert njit(_call_if)(True, KernelPointer(pointed, (x,)), x) == 2.0
    assert "cfunc." in next(iter(pointed.overloads.values())).library.get_llvm_str()


_LOAD_THEN_COMPILE = """
import sys
import numpy as np
from clothjit import njit


@njit(cache=True)
def ramp(n):
    return np.arange(n) * 0.5  # allocates: the runtime (NRT) must be set up


if sys.argv[1] == "later":
    ramp(4)  # from the cache: the registries stay unloaded
    loaded = "numba.np.arraymath" in sys.modules

    @njit  # compiled here, over the loaded kernel: the registries load now
    def total(n):
        return ramp(n).sum()

    print(loaded, total(4), ramp(3).sum())
else:
    print(ramp(4).sum())
"""


def test_a_process_loads_from_the_cache_then_compiles(tmp_path):
    """Loading a kernel from the cache skips numba's registry refresh (clothjit) but sets
    up the runtime, so a loaded kernel that allocates runs; a kernel compiled later in the
    same process, calling it, compiles and runs (the registries load then)."""
    (tmp_path / "load_then_compile.py").write_text(_LOAD_THEN_COMPILE)
    env = child_env(NUMBA_CACHE_DIR=str(tmp_path / "cache"))
    outputs = []
    for when in ("first", "later"):
        run = subprocess.run([sys.executable, str(tmp_path / "load_then_compile.py"), when],
                             capture_output=True, text=True, env=env, cwd=tmp_path, timeout=300)
        assert run.returncode == 0, run.stderr[-500:]
        outputs.append(run.stdout.split())
    assert outputs == [["3.0"], ["False", "3.0", "1.5"]]



_COMPILE_WITHOUT_SCIPY_LINALG = """
import sys
import numpy as np
from clothjit import njit

first = njit(lambda x: x + 1)(1)  # numba's first compile: it imports numba.np.arraymath
import numba.np.arraymath

before = "scipy.linalg" in sys.modules
product = njit(lambda a: np.dot(a, a))(np.array([[1.0, 2.0], [3.0, 4.0]]))  # BLAS
print(first, before, numba.np.arraymath._HAVE_BLAS, "scipy.linalg" in sys.modules,
      product.tolist())
"""


def test_a_compile_imports_scipy_linalg_only_for_a_kernel_that_calls_blas():
    """numba's first compile in a process imports numba.np.arraymath, whose BLAS check
    imports scipy.linalg (0.3 s); clothjit skips that check (BLAS counted as there), and
    a kernel calling np.dot still gets numba's check, scipy.linalg, and the right product."""
    run = subprocess.run([sys.executable, "-c", _COMPILE_WITHOUT_SCIPY_LINALG],
                         capture_output=True, text=True, env=child_env(), timeout=300)
    assert run.returncode == 0, run.stderr[-500:]
    assert run.stdout.strip().split(maxsplit=4) == ["2", "False", "True", "True",
                                            "[[7.0, 10.0], [15.0, 22.0]]"]

_WARM_RENDER = """
import sys
from pipeline.cli import main
status = main(sys.argv[1:])
print(status, sorted(m for m in ("numba.np.arraymath", "numba.np.linalg", "scipy.linalg",
                                  "numba.core.inline_closurecall") if m in sys.modules))
"""


def test_a_warm_render_loads_no_compiler_registries(tmp_path):
    """The README's command, warm: every kernel comes from the cache, and neither numba's
    registries (numba.np.arraymath, numba.np.linalg) nor scipy.linalg, which their BLAS
    check imports, are loaded (0.5-0.7 s of a warm run), nor numba's inliner (clothjit
    patches it on the first compile only). Fails if a kernel of the command calls one of
    numba's numpy functions implemented there (np.sum, np.any: reach.py)."""
    args = [str(scene_path("sphere")), "--shader", "phong", "--out", str(tmp_path / "a.gif"),
            "--duration", "0.2", "--size", "48x48", "--quiet"]
    for _ in range(2):  # the first fills the cache if this is the first use
        run = subprocess.run([sys.executable, "-c", _WARM_RENDER, *args], capture_output=True,
                             text=True, env=child_env(), timeout=600)
        assert run.returncode == 0, run.stderr[-500:]
    assert run.stdout.strip() == "0 []"
