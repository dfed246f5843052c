"""The simulator and the README's command on a busy machine: numba's default threads against
one thread, with 0, 1 and 2 CPU-bound processes running beside them (issue 40).

    python benchmarks/load.py                    # every case and load, 5 runs each
    python benchmarks/load.py --quick            # pinned2 50x50 and the README command only
    python benchmarks/load.py --runs 7 --cases 200,readme --loads 0,2
    python benchmarks/load.py --config passive:OMP_WAIT_POLICY=passive
    PYTHONPATH=/path/to/clone NUMBA_CACHE_DIR=/tmp/nc-clone python benchmarks/load.py

Everything is measured in fresh subprocesses, through the public API and the `render`
command only: a simulator case imports `pipeline`, builds the scene with
`pipeline.load_scene` (scenes/pinned2.json resized to the case's grid, its pins moved with it,
as benchmarks/sim.py does), advances one frame (loads the kernels from numba's cache) and times
`pipeline.Simulation(scene).advance(frames)`; the README case runs
`render scenes/sphere.json --shader phong --out <tmp>/cloth.gif` and reads `simulate` and
`total` from its summary line, and its wall time. The environment is passed on (so PYTHONPATH
and NUMBA_CACHE_DIR choose the tree and the cache), plus each configuration's variables:
`1` is NUMBA_NUM_THREADS=1, `default` adds nothing, and `--config LABEL:VAR=VALUE,...` adds
more (a policy to compare; several allowed).

Loads: `quiet` (nothing started), `1 busy`, `2 busy`: that many `python -c "while True:
pass"` processes, started by this script before the row's runs and killed after them (always:
also on Ctrl-C or SIGTERM); with `--late S`, started S seconds after each run's process
instead and killed when it ends (load that begins during a run). Other work on the machine is not controlled: the load average is
printed at the start and end of each row. Within a row, each round runs every case once per
configuration, the configurations in an order rotated every round, so that they share
conditions; one warm-up run per case and configuration (untimed; it fills an empty cache)
comes first.

Prints one table: a line per load, case and measure (`sim s` for a simulator case; `simulate`,
`total` and `wall` for the README command), a column per configuration with the median and the
range (min-max) of --runs runs, and the ratio of each configuration's median to that of `1`
(the issue's target: at most 1.2 under load, and no slower than today when quiet). `same` says
whether every run's final positions (simulator cases) or output GIF (README) were
byte-identical across the configurations and runs of that row.
"""
from __future__ import annotations

import argparse
import hashlib
import json
import os
import re
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from sim import scene_dict  # benchmarks/sim.py: a course scene resized, pins moved along

ROOT = Path(__file__).resolve().parent.parent
SIM_FRAMES = {50: 90, 100: 60, 200: 20}  # simulator frames per run (~0.3-0.6 s quiet, 2 cores)
LOADS = {0: "quiet", 1: "1 busy", 2: "2 busy"}
BUSY = "while True: pass"
SUMMARY = re.compile(r"simulate ([0-9.]+) s, render ([0-9.]+) s, encode ([0-9.]+) s, "
                     r"total ([0-9.]+) s")

SIM_CODE = r"""
import hashlib, json, sys, time
import pipeline
raw = json.loads(sys.argv[1]); frames = int(sys.argv[2])
scene = pipeline.load_scene(raw)
pipeline.Simulation(scene).advance(1)  # kernels loaded from the cache (or compiled)
sim = pipeline.Simulation(scene)
t0 = time.perf_counter()
sim.advance(frames)
seconds = time.perf_counter() - t0
import numba
digest = hashlib.sha1(sim.positions.tobytes()).hexdigest()[:12]
print(json.dumps(dict(seconds=seconds, digest=digest, layer=numba.threading_layer(),
                      threads=numba.get_num_threads(), module=pipeline.__file__)))
"""


def run(cmd: list[str], env: dict, cwd, late: tuple[int, float] | None
        ) -> subprocess.CompletedProcess:
    """subprocess.run; with `late` = (n, seconds), n busy processes start that long after the
    command does and are killed when it ends (load that begins during a run)."""
    if not late or not late[0]:
        return subprocess.run(cmd, env=env, cwd=cwd, capture_output=True, text=True)
    proc = subprocess.Popen(cmd, env=env, cwd=cwd, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    try:
        out, err = proc.communicate(timeout=late[1])
    except subprocess.TimeoutExpired:
        with Busy(late[0], settle=0.0):
            out, err = proc.communicate()
    return subprocess.CompletedProcess(cmd, proc.returncode, out, err)


def run_sim(size: int, frames: int, env: dict, tmp: str,
            late: tuple[int, float] | None = None) -> dict:
    # run in an empty folder: `python -c` puts its working directory first on sys.path, and
    # this tree's packages would shadow those PYTHONPATH chooses
    out = run([sys.executable, "-c", SIM_CODE, json.dumps(scene_dict("pinned2.json", size)), str(frames)],
              env, tmp, late)
    if out.returncode:
        raise RuntimeError(f"simulator case {size}x{size} failed:\n{out.stderr[-2000:]}")
    r = json.loads(out.stdout.strip().splitlines()[-1])
    return {"sim s": r["seconds"], "digest": r["digest"], "layer": r["layer"],
            "threads": r["threads"], "module": r["module"]}


def render_command() -> list[str]:
    """The `render` console script beside this Python (or on PATH)."""
    here = Path(sys.executable).with_name("render")
    if here.exists():
        return [str(here)]
    import shutil

    found = shutil.which("render")
    if found is None:
        raise SystemExit("load.py: no `render` command (pip install the project first)")
    return [found]


def run_readme(env: dict, tmp: str, late: tuple[int, float] | None = None) -> dict:
    out_gif = os.path.join(tmp, "cloth.gif")
    cmd = render_command() + ["scenes/sphere.json", "--shader", "phong", "--out", out_gif]
    t0 = time.perf_counter()
    out = run(cmd, env, ROOT, late)
    wall = time.perf_counter() - t0
    if out.returncode:
        raise RuntimeError(f"render failed:\n{out.stderr[-2000:]}")
    m = SUMMARY.search(out.stderr)
    if m is None:
        raise RuntimeError(f"no summary line in render's output:\n{out.stderr[-2000:]}")
    with open(out_gif, "rb") as fh:
        digest = hashlib.sha1(fh.read()).hexdigest()[:12]
    return {"simulate": float(m.group(1)), "total": float(m.group(4)), "wall": wall,
            "digest": digest}


class Busy:
    """n CPU-bound Python processes, killed on exit from the block whatever happens."""

    def __init__(self, n: int, settle: float = 0.5):
        self.n, self.settle, self.procs = n, settle, []

    def __enter__(self):
        for _ in range(self.n):
            self.procs.append(subprocess.Popen([sys.executable, "-c", BUSY]))
        if self.n:
            time.sleep(self.settle)  # let them get going
        return self

    def __exit__(self, *exc):
        for p in self.procs:
            p.kill()
        for p in self.procs:
            p.wait()
        self.procs = []
        return False


def parse_config(text: str) -> tuple[str, dict]:
    label, _, assignments = text.partition(":")
    env = {}
    for item in filter(None, assignments.split(",")):
        key, eq, value = item.partition("=")
        if not eq:
            raise SystemExit(f"load.py: --config {text!r}: expected LABEL:VAR=VALUE,...")
        env[key.strip()] = value
    return label, env


def loadavg() -> str:
    with open("/proc/loadavg") as fh:
        return " ".join(fh.read().split()[:4])


def fmt(values: list[float]) -> str:
    return f"{statistics.median(values):6.2f} ({min(values):.2f}-{max(values):.2f})"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=5, help="timed runs per cell (default 5)")
    ap.add_argument("--cases", default=None,
                    help="comma list of 50, 100, 200 (pinned2 grids) and readme "
                         "(default: all; --quick: 50,readme)")
    ap.add_argument("--loads", default="0,1,2",
                    help="comma list of busy-process counts (default 0,1,2)")
    ap.add_argument("--config", action="append", default=[], metavar="LABEL:VAR=VALUE,...",
                    help="another configuration: these variables added to the environment")
    ap.add_argument("--no-default", action="store_true",
                    help="leave out the `default` configuration (keep `1` and --config)")
    ap.add_argument("--frames", default=None,
                    help="simulator frames per run as 50=90,100=60,200=20 (the defaults)")
    ap.add_argument("--quick", action="store_true",
                    help="pinned2 50x50 and the README command only (still --runs runs)")
    ap.add_argument("--json", default=None, help="also write every run's figures here")
    ap.add_argument("--late", type=float, default=None, metavar="S",
                    help="start each row's busy processes S seconds after each run's process "
                         "(load that begins during a run), not before the row")
    args = ap.parse_args()

    cases = (args.cases or ("50,readme" if args.quick else "50,100,200,readme")).split(",")
    frames = dict(SIM_FRAMES)
    for item in filter(None, (args.frames or "").split(",")):
        k, _, v = item.partition("=")
        frames[int(k)] = int(v)
    configs = [("1", {"NUMBA_NUM_THREADS": "1"})]
    if not args.no_default:
        configs.append(("default", {}))
    configs += [parse_config(c) for c in args.config]
    loads = [int(x) for x in args.loads.split(",")]

    # SIGTERM ends the script like Ctrl-C, through the `finally` that kills the busy processes
    signal.signal(signal.SIGTERM, lambda *_: (_ for _ in ()).throw(KeyboardInterrupt()))

    def env_of(extra: dict) -> dict:
        return {**os.environ, **extra}

    results: dict = {}  # (load, case, config) -> list of run dicts
    print(f"# benchmarks/load.py, {time.strftime('%Y-%m-%d %H:%M')}, {os.cpu_count()} cores "
          f"(affinity {len(os.sched_getaffinity(0))}), load {loadavg()}, runs {args.runs}, "
          f"NUMBA_NUM_THREADS={os.environ.get('NUMBA_NUM_THREADS', '(unset)')}, "
          f"PYTHONPATH={os.environ.get('PYTHONPATH', '(unset)')}, "
          f"NUMBA_CACHE_DIR={os.environ.get('NUMBA_CACHE_DIR', '(unset)')}", flush=True)
    for label, extra in configs:
        print(f"#   config {label}: {' '.join(f'{k}={v}' for k, v in extra.items()) or '-'}")
    try:
        with tempfile.TemporaryDirectory() as tmp:
            for load in loads:
                late = (load, args.late) if args.late is not None else None
                with Busy(0 if late else load):
                    start = loadavg()
                    for case in cases:  # warm-up (fills an empty cache), untimed
                        for label, extra in configs:
                            r = (run_readme(env_of(extra), tmp) if case == "readme" else
                                 run_sim(int(case), frames[int(case)], env_of(extra), tmp))
                            if case != "readme" and load == loads[0]:
                                print(f"#   {label}: {r['module']}, layer {r['layer']}, "
                                      f"{r['threads']} threads ({LOADS.get(load)})",
                                      flush=True)
                    for rnd in range(args.runs):
                        order = configs[rnd % len(configs):] + configs[:rnd % len(configs)]
                        for case in cases:
                            for label, extra in order:
                                r = (run_readme(env_of(extra), tmp, late) if case == "readme"
                                     else run_sim(int(case), frames[int(case)], env_of(extra),
                                                  tmp, late))
                                results.setdefault((load, case, label), []).append(r)
                                shown = ("simulate", "total", "wall") if case == "readme" \
                                    else ("sim s",)
                                print(f"#     {LOADS.get(load, load)} {case} {label}: "
                                      + " ".join(f"{k} {r[k]:.2f}" for k in shown)
                                      + f" {r['digest']}", file=sys.stderr, flush=True)
                        print(f"#   {LOADS.get(load, f'{load} busy')}: round {rnd + 1}/"
                              f"{args.runs} done", file=sys.stderr, flush=True)
                    print(f"# {LOADS.get(load, f'{load} busy')}: load average {start} at the "
                          f"start, {loadavg()} at the end (the busy processes included)",
                          flush=True)
    except KeyboardInterrupt:
        print("load.py: interrupted (busy processes killed)", file=sys.stderr)
        if not results:
            raise SystemExit(130)

    labels = [label for label, _ in configs]
    head = (f"{'load':7s} {'case':16s} {'measure':8s} "
            + " ".join(f"{label + ' s (range)':>21s}" for label in labels)
            + "".join(f" {label + '/1':>10s}" for label in labels[1:]) + "  same")
    print(head)
    for load in loads:
        for case in cases:
            name = "README command" if case == "readme" else f"pinned2 {case}x{case}"
            measures = ("simulate", "total", "wall") if case == "readme" else ("sim s",)
            runs = {label: results.get((load, case, label), []) for label in labels}
            if not all(runs.values()):
                continue
            digests = {r["digest"] for rs in runs.values() for r in rs}
            for k, measure in enumerate(measures):
                vals = {label: [r[measure] for r in rs] for label, rs in runs.items()}
                base = statistics.median(vals["1"])
                line = (f"{LOADS.get(load, f'{load} busy'):7s} {name:16s} {measure:8s} "
                        + " ".join(f"{fmt(vals[label]):>21s}" for label in labels)
                        + "".join(f" {statistics.median(vals[label]) / base:10.2f}"
                                  for label in labels[1:]))
                if k == 0:
                    line += "  " + ("yes" if len(digests) == 1 else f"NO ({len(digests)})")
                print(line, flush=True)
    if args.json:
        with open(args.json, "w") as fh:
            json.dump([{"load": load, "case": case, "config": label, "runs": rs}
                       for (load, case, label), rs in results.items()], fh, indent=1)


if __name__ == "__main__":
    main()
