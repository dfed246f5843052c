"""First run against later runs: `render` with an empty numba cache, then with it filled.

    python benchmarks/cold_start.py                 # the README's command, then each feature
    python benchmarks/cold_start.py --only readme   # just the README's command
    PYTHONPATH=/path/to/old/tree python benchmarks/cold_start.py --only readme   # before

Each case runs `render` in a fresh process (stderr not a terminal, so no bars) and reads its
summary line: compile (when the run says it compiled), simulate, render, encode, and the
process's wall time; `import` is `python -c "import pipeline, shading"` on its own.

Cases, in order, against ONE cache folder, so that each shows what its feature adds:
  readme     render scenes/sphere.json --shader phong --out x.gif  (cold, then warm)
  fem        scenes/swing.json (the finite-element model)
  wind       scenes/flag.json
  mesh       scenes/bowl.json (a mesh collider)
  self-collision  scenes/selfCollision.json (a plane, self-collision)
  robust     the same under --contact robust, its first 0.2 s (robust contact's kernels)
  <integ>    scenes/pinned2.json with each integrator but Verlet
  <shader>   scenes/sphere.json with each shader but phong
Every case is run cold (its first run on this cache) and then warm. Speeds vary 1.5-2x on
this machine from minute to minute: compare trees by running both in one sitting.
"""
from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
#: the tree measured: PYTHONPATH's first entry, else this one. Children run in a fresh
#: scratch folder with it first on sys.path: run from ROOT, `python -m` and `-c` put the
#: working folder ahead of PYTHONPATH and measured this tree whatever PYTHONPATH said.
TREE = (os.environ.get("PYTHONPATH") or str(ROOT)).split(os.pathsep)[0]
PHASE = re.compile(r"(compile|simulate|render|encode|total) ([\d.]+) s")
INTEGRATORS = ("euler", "symplectic-euler", "rk4", "implicit-euler", "xpbd")
SHADERS = ("normal", "wireframe", "diffuse", "texture", "bump", "displacement", "mirror",
           "toon")


def cases() -> list[tuple[str, list[str]]]:
    readme = ["scenes/sphere.json", "--shader", "phong"]
    out = [("readme", readme), ("fem", ["scenes/swing.json"]), ("wind", ["scenes/flag.json"]),
           ("mesh", ["scenes/bowl.json"]), ("self-collision", ["scenes/selfCollision.json"]),
           ("robust", ["scenes/selfCollision.json", "--contact", "robust", "--duration", "0.2"])]
    out += [(name, ["scenes/pinned2.json", "--set", f'simulation.integrator="{name}"'])
            for name in INTEGRATORS]
    out += [(name, ["scenes/sphere.json", "--shader", name]) for name in SHADERS]
    return out


def run(argv: list[str], cache: str, out: Path) -> dict[str, float]:
    env = dict(os.environ, NUMBA_CACHE_DIR=cache, PYTHONPATH=TREE)
    argv = [str(ROOT / a) if a.startswith("scenes/") else a for a in argv]
    start = time.perf_counter()
    proc = subprocess.run([sys.executable, "-m", "pipeline.cli", *argv, "--out", str(out)],
                          cwd=out.parent, env=env, capture_output=True, text=True)
    wall = time.perf_counter() - start
    if proc.returncode != 0:
        raise SystemExit(f"render {' '.join(argv)} failed:\n{proc.stderr}")
    # the summary line (under robust contact a line on the contact follows it)
    summary = next(line for line in reversed(proc.stderr.splitlines()) if "simulate" in line)
    phases = {k: float(v) for k, v in PHASE.findall(summary)}
    phases.setdefault("compile", 0.0)
    phases["wall"] = wall
    return phases


def import_seconds(folder: str, repeat: int = 3) -> float:
    best = float("inf")
    for _ in range(repeat):
        start = time.perf_counter()
        subprocess.run([sys.executable, "-c", "import pipeline, shading"], cwd=folder,
                       env=dict(os.environ, PYTHONPATH=TREE), check=True)
        best = min(best, time.perf_counter() - start)
    return best


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--only", nargs="*", help="case names (default: all)")
    args = ap.parse_args()
    chosen = [c for c in cases() if not args.only or c[0] in args.only]
    print(f"# {time.strftime('%Y-%m-%d %H:%M')}, {os.cpu_count()} cores, python "
          f"{sys.version.split()[0]}; tree {TREE}")
    with tempfile.TemporaryDirectory(prefix="cold-start-") as tmp:
        print(f"import pipeline, shading: {import_seconds(tmp):.2f} s (best of 3, fresh "
              "processes)")
        print(f"{'case':<17} {'':<5} {'wall':>6} {'compile':>8} {'simulate':>9} "
              f"{'render':>7} {'encode':>7}")
        cache = os.path.join(tmp, "numba")
        for name, argv in chosen:
            for label in ("cold", "warm"):
                p = run(argv, cache, Path(tmp) / f"{name}.gif")
                print(f"{name:<17} {label:<5} {p['wall']:6.1f} {p['compile']:8.1f} "
                      f"{p['simulate']:9.2f} {p['render']:7.2f} {p['encode']:7.2f}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
