"""Real signals to a real `render` process, by its pid, at several moments: the exit
status is 128 + the signal, nothing partial is left in the output folder, and no child
process (ffmpeg, report workers) outlives it.

The moment is recognised from outside, never from elapsed time: compiling (the first file
in an empty numba cache), simulating (the output's temporary files exist and the first
frame went out while the simulation is the slow part), rendering (the first numbered PNG
in the temporary folder of a large anti-aliased render), encoding (ffmpeg is running).
"""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from conftest import child_env, cloth_dict, process_alive, scene_dict

SCENE = scene_dict(cloth_dict(12, 12, thickness=0.0095, damping=0.2, density=150.0, ks=5000.0),
                   spheres=[((0.5, 0.2, 0.5), 0.2, 0.3)],
                   planes=[((0, 0, 0), (0, 1, 0), 0.5)])
WAIT = 300  # seconds at most for a moment to come (a first compilation on a busy machine)

pytestmark = pytest.mark.skipif(not os.path.isdir("/proc/self"), reason="needs /proc")


def render_cmd() -> list[str]:
    return [sys.executable, "-c", "import sys; from pipeline.cli import main; "
            "sys.exit(main())"]


def as_from_a_terminal(ignored: tuple = ()):
    """A preexec_fn: SIGINT, SIGTERM and SIGHUP at their defaults, as a terminal starts a
    command, except `ignored` (a shell without job control starts background jobs with
    SIGINT ignored, and render keeps an inherited SIG_IGN, as nohup wants)."""
    def reset() -> None:
        for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
            signal.signal(sig, signal.SIG_IGN if sig in ignored else signal.SIG_DFL)

    return reset


def start_render(args: list[str], ignored: tuple = (), **env) -> subprocess.Popen:
    """`render args`, started as from a terminal (with `ignored` signals ignored)."""
    return subprocess.Popen(render_cmd() + args, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, env=child_env(**env),
                            preexec_fn=as_from_a_terminal(ignored))


def children(pid: int) -> dict[int, str]:
    """{pid: command name} of the live processes whose parent is `pid` (from /proc)."""
    out = {}
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            stat = (entry / "stat").read_text()
        except OSError:
            continue
        name = stat[stat.index("(") + 1: stat.rindex(")")]
        fields = stat[stat.rindex(")") + 2:].split()
        if int(fields[1]) == pid and fields[0] != "Z":
            out[int(entry.name)] = name
    return out


def wait_for(proc: subprocess.Popen, condition, what: str):
    """Poll `condition` until it returns something true (returned); fail if render exits."""
    deadline = time.monotonic() + WAIT
    while not (value := condition()):
        if proc.poll() is not None:
            out, err = proc.communicate()
            pytest.fail(f"render exited ({proc.returncode}) before {what}: {err}")
        if time.monotonic() > deadline:
            proc.kill()
            pytest.fail(f"render never reached: {what}")
        time.sleep(0.02)
    return value


def temp_files(folder: Path, pattern: str) -> list[Path]:
    return [p for p in folder.glob(pattern)]


@pytest.fixture(scope="module")
def warm(tmp_path_factory):
    """One complete run of each output kind, so the kernels are compiled and cached."""
    d = tmp_path_factory.mktemp("warm")
    scene = d / "s.json"
    scene.write_text(json.dumps(SCENE))
    for out in ("a.gif", "a.mp4", "frames/"):
        r = subprocess.run(render_cmd() + [str(scene), "--out", f"{d}/{out}", "--size",
                                           "32x32", "--duration", "0.2", "--aa", "2"],
                           capture_output=True, text=True, env=child_env(), timeout=900)
        assert r.returncode == 0, r.stderr


def stop(proc: subprocess.Popen, sig: int, out_dir: Path, keep: set[str],
         seen: dict[int, str] | None = None) -> dict[int, str]:
    """Send `sig`, wait; check status, message and folder, and that every child seen
    (`seen`, and those alive now) is gone; return those children."""
    kids = {**(seen or {}), **children(proc.pid)}
    os.kill(proc.pid, sig)
    _, err = proc.communicate(timeout=WAIT)
    name = signal.Signals(sig).name
    assert proc.returncode == 128 + sig, err
    assert f"render: interrupted ({name}); no output written" in err
    assert "Traceback" not in err
    assert sorted(p.name for p in out_dir.iterdir()) == sorted(keep)
    for pid, comm in kids.items():
        deadline = time.monotonic() + 30
        while process_alive(pid) and time.monotonic() < deadline:
            time.sleep(0.05)
        assert not process_alive(pid), f"child {comm} ({pid}) still running"
    return kids


@pytest.fixture
def scene(tmp_path) -> Path:
    f = tmp_path / "s.json"
    f.write_text(json.dumps(SCENE))
    return f


def test_sigterm_while_compiling(scene, tmp_path):
    cache = tmp_path.parent / (tmp_path.name + "_numba")  # outside the output folder
    cache.mkdir()
    proc = start_render([str(scene), "--out", str(tmp_path / "x.gif"), "--size", "32x32"],
                        NUMBA_CACHE_DIR=str(cache))
    wait_for(proc, lambda: any(p.is_file() for p in cache.rglob("*")), "compiling")
    # a first run compiles in two processes (pipeline/run/warmup.py): the helper must go too
    helper = wait_for(proc, lambda: children(proc.pid), "the compile helper started")
    stop(proc, signal.SIGTERM, tmp_path, {"s.json"}, helper)


def simulate_30_s(scene: Path, tmp_path: Path, *sets: str, ignored: tuple = ()
                  ) -> subprocess.Popen:
    """A long render of `scene` to a GIF, an NPZ and OBJs (slow: 600 steps per frame)."""
    sets = [a for s in ("simulation.steps_per_frame=600",) + sets for a in ("--set", s)]
    return start_render([str(scene), "--out", str(tmp_path / "x.gif"), "--size", "16x16",
                         "--duration", "30", "--export-npz", str(tmp_path / "p.npz"),
                         "--export-obj", str(tmp_path / "objs")] + sets, ignored)


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGHUP])
def test_signal_while_simulating(warm, scene, tmp_path, sig):
    # the course camera: no framing pass, so the GIF's frame spool appears with the first
    # simulated frame
    proc = simulate_30_s(scene, tmp_path, "camera=course")
    wait_for(proc, lambda: temp_files(tmp_path, ".x.gif.*.frames"), "simulating")
    stop(proc, sig, tmp_path, {"s.json"})


def test_a_signal_ignored_by_whoever_started_render_stays_ignored(warm, scene, tmp_path):
    # nohup render ...: a hangup does not stop it; SIGTERM still does, cleanly
    proc = simulate_30_s(scene, tmp_path, "camera=course", ignored=(signal.SIGHUP,))
    wait_for(proc, lambda: temp_files(tmp_path, ".x.gif.*.frames"), "simulating")
    os.kill(proc.pid, signal.SIGHUP)
    time.sleep(1.0)
    assert proc.poll() is None
    stop(proc, signal.SIGTERM, tmp_path, {"s.json"})


def test_signal_while_framing_the_shot(warm, scene, tmp_path):
    # no camera: the whole shot is simulated ahead to frame it (40 s here) before any frame
    # is spooled; the outputs' temporary files exist from the start
    proc = simulate_30_s(scene, tmp_path)
    wait_for(proc, lambda: len(temp_files(tmp_path, ".*.part")) == 3, "outputs opened")
    time.sleep(1.0)
    assert not temp_files(tmp_path, ".x.gif.*.frames")  # still framing
    stop(proc, signal.SIGTERM, tmp_path, {"s.json"})


# the tests below use the course camera, so that frames are drawn and encoded while the shot
# is simulated (without a camera the whole shot is simulated ahead first, to frame it:
# test_signal_while_framing_the_shot)


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_signal_while_rendering(warm, scene, tmp_path, sig):
    proc = start_render([str(scene), "--out", f"{tmp_path}/frames/", "--size", "1024x1024",
                         "--aa", "4", "--duration", "30", "--set", "camera=course"])
    wait_for(proc, lambda: temp_files(tmp_path, ".frames.*.part/frame_00000.png"),
             "rendering")
    stop(proc, sig, tmp_path, {"s.json"})


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM, signal.SIGHUP])
def test_signal_while_encoding_mp4_kills_ffmpeg(warm, scene, tmp_path, sig):
    proc = start_render([str(scene), "--out", str(tmp_path / "x.mp4"), "--size", "256x256",
                         "--duration", "60", "--set", "camera=course"])
    def ffmpeg_running():
        kids = children(proc.pid)
        return kids if any("ffmpeg" in c for c in kids.values()) else None

    seen = wait_for(proc, ffmpeg_running, "encoding (ffmpeg running)")
    kids = stop(proc, sig, tmp_path, {"s.json"}, seen)
    assert any("ffmpeg" in c for c in kids.values())


def test_sigterm_stops_report_workers(warm, scene, tmp_path):
    proc = start_render(["report", str(scene), "--out", str(tmp_path / "r.html"), "--shader",
                         "phong", "--sweep", "cloth.ks=1000,2000", "--jobs", "2", "--duration",
                         "60", "--size", "32x32", "--set", "simulation.steps_per_frame=300"])
    def workers_running():
        kids = children(proc.pid)
        return kids if len(kids) >= 2 and temp_files(tmp_path, ".r.*.part") else None

    seen = wait_for(proc, workers_running, "simulating in worker processes")
    kids = stop(proc, signal.SIGTERM, tmp_path, {"s.json"}, seen)
    assert len(kids) >= 2


# While numba compiles or loads a kernel, LLVM calls back into Python through ctypes
# (llvmlite's object cache), and an exception raised in a ctypes callback is printed and
# dropped: the signal was lost, or LLVM went on with a half-set buffer and crashed (CI,
# 2026-11-24: test_signal_while_rendering ended in SIGSEGV). This child sends itself the
# signal from inside that callback, so the handler runs there every time.
SIGNAL_IN_LLVM_CALLBACK = """
import os, signal, sys, time
from numba import njit
from numba.core.codegen import CPUCodeLibrary
from pipeline.run.signals import Terminated, exit_status, handled

hook = CPUCodeLibrary._object_getbuffer_hook.__func__
sent = []

def signalling_hook(cls, ll_module):
    if not sent:
        sent.append(os.getpid())
        os.kill(os.getpid(), signal.SIGNUM)
        for _ in range(100000):  # Python code: the handler runs here, inside the callback
            pass
    return hook(cls, ll_module)

CPUCodeLibrary._object_getbuffer_hook = classmethod(signalling_hook)

@njit
def twice(x):
    return 2.0 * x

with handled():
    try:
        value = twice(1.0)
        print("compiled", value, flush=True)
        time.sleep(10)  # the deferred signal ends this at once
        print("finished", flush=True)
    except Terminated as exc:
        print("stopped", exc.signum, file=sys.stderr, flush=True)
        sys.exit(exit_status(exc))
"""


# A kernel's entry point unboxing a first-class function argument (a KernelPointer) calls
# numba.core.serialize._numba_unpickle, then _get_wrapper_address, unchecked: a signal whose
# handler ran in the first became "TypeError: _get_wrapper_address() missing 1 required
# positional argument" (a run of the suite, 2026-11-25). This child's _numba_unpickle, a
# function of numba's module as the real one is, sends the signal and runs Python code, so
# the handler runs there every time.
SIGNAL_WHILE_UNBOXING_A_POINTER = """
import os, signal, sys, time
import numpy as np
import numba.core.serialize as serialize
from clothjit import KernelPointer, njit
from pipeline.run.signals import Terminated, exit_status, handled

SOURCE = '''
def _numba_unpickle(address, bytedata, hashed):
    if SENT and not SENT[0]:
        SENT[0] = True
        os.kill(os.getpid(), signal.SIGNUM)
        for _ in range(100000):  # Python code: the handler runs here, mid-unboxing
            pass
    return REAL(address, bytedata, hashed)
'''
serialize.REAL, serialize.SENT = serialize._numba_unpickle, []
serialize.os, serialize.signal = os, signal
exec(compile(SOURCE, serialize.__file__, "exec"), vars(serialize))


@njit(cache=True, nogil=True, no_cpython_wrapper=True, pointer=True)
def add_one(x):
    x[0] += 1.0


@njit(cache=True)
def call(kernel, x):
    kernel(x)


x = np.zeros(1)
pointer = KernelPointer(add_one, (x,))
call(pointer, x)  # compiled; numba looks _numba_unpickle up on its first use: ours


def act():
    serialize.SENT.append(False)
    call(pointer, x)
    return x[0]
"""

# The end of a child that defines act() (what runs when the signal comes, returning what
# to print) and waits for the signal after it.
UNTIL_THE_SIGNAL = """
with handled():
    try:
        print("called", act(), flush=True)
        time.sleep(10)  # the signal, deferred or sent again, ends this at once
        print("finished", flush=True)
    except Terminated as exc:
        print("stopped", exc.signum, file=sys.stderr, flush=True)
        sys.exit(exit_status(exc))
"""


def _stopped_child(tmp_path, source: str, sig, **env: str) -> str:
    """Run `source` + UNTIL_THE_SIGNAL (SIGNUM: `sig`); it must stop by the signal, within 8 s,
    printing nothing else; returns its stdout."""
    (tmp_path / "child.py").write_text((source + UNTIL_THE_SIGNAL).replace(
        "SIGNUM", signal.Signals(sig).name))
    t0 = time.monotonic()
    proc = subprocess.run([sys.executable, str(tmp_path / "child.py")], capture_output=True,
                          text=True, env=child_env(**env), timeout=WAIT,
                          preexec_fn=as_from_a_terminal())
    assert proc.returncode == 128 + sig, proc.stderr
    assert "called" in proc.stdout and "finished" not in proc.stdout, proc.stdout
    assert proc.stderr.strip() == f"stopped {int(sig)}", proc.stderr
    assert time.monotonic() - t0 < 8
    return proc.stdout


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGHUP])
def test_signal_while_unboxing_a_kernel_pointer_is_deferred(tmp_path, sig):
    stdout = _stopped_child(tmp_path, SIGNAL_WHILE_UNBOXING_A_POINTER, sig,
                            NUMBA_CACHE_DIR=str(tmp_path / "cache"))
    assert "called 2.0" in stdout  # the call ran whole, then the signal stopped the sleep


# The signal's handler running inside a weakref callback (as it once did in importlib's
# module-lock callback during a render): Python prints and drops an exception raised there,
# and the run went on to its end.
SIGNAL_IN_A_WEAKREF_CALLBACK = """
import os, signal, sys, time, weakref
from pipeline.run.signals import Terminated, exit_status, handled


class Thing:
    pass


def callback(ref):
    os.kill(os.getpid(), signal.SIGNUM)
    for _ in range(100000):  # Python code: the handler runs here, inside the callback
        pass


def act():
    thing = Thing()
    ref = weakref.ref(thing, callback)
    del thing  # the callback runs, and the handler in it
    return ""
"""


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_a_signal_dropped_in_a_weakref_callback_is_sent_again(tmp_path, sig):
    _stopped_child(tmp_path, SIGNAL_IN_A_WEAKREF_CALLBACK, sig)


# `render report` starting its worker pool, with a SIGTERM sent to itself just after the
# first worker process is spawned and before the pool writes it its set-up: the worker would
# read an empty pipe and print a traceback, unless the signal waits for the pool to start.
SIGNAL_WHILE_STARTING_WORKERS = """
import os, signal, sys
import multiprocessing.util as util
from pipeline.cli import main

spawn = util.spawnv_passfds
sent = []

def spawn_then_signal(path, args, passfds):
    pid = spawn(path, args, passfds)
    if not sent and "spawn_main" in " ".join(map(str, args)):
        sent.append(pid)
        print(pid, flush=True)
        os.kill(os.getpid(), signal.SIGTERM)
        for _ in range(100000):  # Python code: the handler runs here, mid-start
            pass
    return pid

util.spawnv_passfds = spawn_then_signal
sys.exit(main(sys.argv[1:]))
"""


def test_sigterm_while_report_workers_start_waits_for_them(warm, scene, tmp_path):
    proc = subprocess.run([sys.executable, "-c", SIGNAL_WHILE_STARTING_WORKERS, "report",
                           str(scene), "--out", str(tmp_path / "r.html"), "--shader", "phong",
                           "--sweep", "cloth.ks=1000,2000", "--jobs", "2", "--size", "32x32"],
                          capture_output=True, text=True, env=child_env(), timeout=WAIT,
                          preexec_fn=as_from_a_terminal())
    assert proc.returncode == 128 + signal.SIGTERM, proc.stderr
    assert "render: interrupted (SIGTERM); no output written" in proc.stderr
    assert "Traceback" not in proc.stderr and "EOFError" not in proc.stderr, proc.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s.json"]
    worker = int(proc.stdout.split()[0])
    deadline = time.monotonic() + 30
    while process_alive(worker) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert not process_alive(worker)


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_signal_inside_an_llvm_callback_is_deferred_not_lost(tmp_path, sig):
    proc = subprocess.run([sys.executable, "-c", SIGNAL_IN_LLVM_CALLBACK.replace(
        "SIGNUM", signal.Signals(sig).name)], capture_output=True, text=True,
        env=child_env(NUMBA_CACHE_DIR=str(tmp_path)), timeout=WAIT,
        preexec_fn=as_from_a_terminal())
    assert proc.returncode == 128 + sig, proc.stderr
    # the signal waited for LLVM to return, then stopped the run (in numba's Python code
    # or in the sleep, whichever it found)
    assert "finished" not in proc.stdout, proc.stdout
    assert "Exception ignored" not in proc.stderr, proc.stderr
    assert proc.stderr.strip() == f"stopped {int(sig)}", proc.stderr
