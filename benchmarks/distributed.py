"""Dask distributed figures (docs/distributed.md): batch speed-up on local workers, the
cost of a task, and for a long render the share that is simulation and the speed-up
bound it sets (Amdahl).

    python benchmarks/distributed.py [--rounds 2]

1. A batch of 8 variants of scenes/sphere.json (cloth.ks swept), 256x256 GIFs of 2 s:
   `render batch` in this process (as `render` runs: simulation and rendering on separate
   threads) and one numba thread in this process (the work one worker does), against 2
   local Dask workers (one thread each; the cluster started and its kernels loaded
   beforehand: its start-up is printed apart). Runs alternate; the best of --rounds each.
2. The cost of a task: 200 tasks that return at once, submitted together (throughput) and
   one after the other (round trip).
3. A long render (scenes/sphere.json, 1920x1080, --aa 4, 1 s at 30 fps): simulation, render
   and PNG encoding timed apart on one thread; the simulation's share s of the one-process
   work and Amdahl's bound 1 / (s + (1 - s) / N) for N workers; then the same command in
   one process, on the running cluster (--scheduler) and with --workers 2, measured.
Wall times depend on what else the machine runs; CPU seconds (this process, its children
and the workers) show the work each way costs.
"""
from __future__ import annotations

import argparse
import json
import logging
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path
from types import SimpleNamespace

ROOT = Path(__file__).resolve().parents[1]
# This file's name is the package's: run as a script, its folder must not hide `distributed`.
sys.path[:] = [str(ROOT)] + [p for p in sys.path if Path(p or ".").resolve() != ROOT / "benchmarks"]

KS = (500, 1000, 2000, 4000, 6000, 8000, 12000, 16000)


def noop(x):
    return x


def cpu_seconds(pids=()) -> float:
    """CPU time (user + system) of this process, its reaped children and `pids`."""
    import resource

    import psutil

    kids = resource.getrusage(resource.RUSAGE_CHILDREN)
    total = time.process_time() + kids.ru_utime + kids.ru_stime
    for pid in pids:
        t = psutil.Process(pid).cpu_times()
        total += t.user + t.system
    return total


def measured(run, pids=()) -> tuple[float, float]:
    """(wall seconds, CPU seconds of this process, its children and `pids`) of run()."""
    c0, t0 = cpu_seconds(pids), time.perf_counter()
    run()
    return time.perf_counter() - t0, cpu_seconds(pids) - c0


def load() -> str:
    return f"{os.getloadavg()[0]:.2f}"


def run_batch(args, scenes, options) -> float:
    """Run the batch; the mean seconds a scene took where it ran (its task's own time)."""
    from pipeline.cli import batch

    results = [r for _, r in batch.run_batch(args, scenes, options)]
    assert all(r.status == "ok" for r in results), [r.message for r in results]
    return sum(r.seconds for r in results) / len(results)


def batch_figures(folder: Path, address: str, pids: list[int], rounds: int) -> None:
    from pipeline.cli import batch

    base = json.loads((ROOT / "scenes" / "sphere.json").read_text())
    scenes = []
    for ks in KS:
        data = json.loads(json.dumps(base))
        data["cloth"]["ks"] = ks
        path = folder / f"sphere_ks{ks}.json"
        path.write_text(json.dumps(data))
        scenes.append(path)
    parsed = batch.build_parser().parse_args(
        [str(p) for p in scenes] + ["--out-dir", str(folder / "out"), "--size", "256x256",
                                    "--duration", "2"])
    options = {k: getattr(parsed, k) for k in batch._cli.RENDER_OPTIONS}
    serial = SimpleNamespace(format="gif", workers=None, scheduler=None)
    dask = SimpleNamespace(format="gif", workers=None, scheduler=address)
    from pipeline.scene import SceneFile

    run_batch(serial, scenes[:1], options)  # kernels loaded here
    run_batch(dask, scenes[:2], options)  # and in both workers

    def one_thread() -> float:
        results = [batch.render_scene(SceneFile.read(p), "gif", options, one_thread=True)
                   for p in scenes]
        assert all(r.status == "ok" for r in results)
        return sum(r.seconds for r in results) / len(results)

    runs = {"serial": lambda: run_batch(serial, scenes, options), "one thread": one_thread,
            "dask": lambda: run_batch(dask, scenes, options)}
    times: dict[str, list[tuple[float, float]]] = {k: [] for k in runs}
    inside: dict[str, list[float]] = {k: [] for k in runs}
    loads = [load()]
    for _ in range(rounds):
        for name, run in runs.items():
            times[name].append(measured(lambda: inside[name].append(run()), pids))
            loads.append(load())
    best = {k: min(v) for k, v in times.items()}
    print(f"\n## Batch: 8 variants of sphere.json (cloth.ks {KS[0]}..{KS[-1]}), 256x256 GIF, "
          f"2 s at 25 fps (best of {rounds}, runs alternated)\n")
    print("| run | wall s | CPU s (client + workers) | a scene inside its task, s | "
          "2 workers' speed-up |")
    print("|---|---:|---:|---:|---:|")
    for name, label in (("serial", "this process, as `render` (2 threads)"),
                        ("one thread", "this process, one numba thread"),
                        ("dask", "2 local Dask workers (1 thread each)")):
        wall, cpu = best[name]
        ratio = "" if name == "dask" else f"{wall / best['dask'][0]:.2f}x"
        print(f"| {label} | {wall:.2f} | {cpu:.2f} | {min(inside[name]):.2f} | {ratio} |")
    print("\n(a scene inside its task: the mean time one scene took where it ran, best run; "
          "on the workers it grows when the two of them do not each get a core)")
    print("\nall runs (wall s / CPU s): " + "; ".join(
        f"{k}: {', '.join(f'{w:.2f}/{c:.2f}' for w, c in v)}" for k, v in times.items()))
    print(f"load average (1 min) before and after each run: {', '.join(loads)}")


def task_overhead(client, n: int = 200) -> None:
    t0 = time.perf_counter()
    client.gather(client.map(noop, range(n), pure=False))
    batch = (time.perf_counter() - t0) / n
    t0 = time.perf_counter()
    for i in range(n // 4):
        client.submit(noop, i, pure=False).result()
    trip = (time.perf_counter() - t0) / (n // 4)
    print("\n## Cost of a task (2 local workers)\n")
    print(f"- {n} empty tasks submitted together: {batch * 1000:.2f} ms per task")
    print(f"- one after the other (submit, wait for the result): {trip * 1000:.2f} ms per task")


def long_render(folder: Path, address: str, pids: list[int], rounds: int) -> None:
    import numpy as np

    from pipeline import cli
    from pipeline.cli.render import nearest_sim_frames, output_times
    from pipeline.run.frames import render_frame
    from pipeline.run.outputs import FolderWriter
    from pipeline.scene import load_scene
    from pipeline.simulation import Simulation
    from clothjit import numba_threads

    scene_path = ROOT / "scenes" / "sphere.json"
    w, h, aa, fps, seconds = 1920, 1080, 4, 30.0, 1.0
    scene = load_scene(scene_path)
    times = output_times(round(seconds * fps), fps)
    sim_frames = nearest_sim_frames(times, float(scene.simulation.frames_per_sec))
    best = {"simulate": [], "render": [], "encode": []}
    with numba_threads(1):
        for _ in range(rounds):
            sim = Simulation(scene)
            t0 = time.perf_counter()
            positions, current = [], 0
            for j in sim_frames:
                if j > current:
                    sim.advance(j - current)
                    current = j
                positions.append(sim.positions.copy())
            best["simulate"].append(time.perf_counter() - t0)
            t0 = time.perf_counter()
            images = [render_frame(scene, p, sim.model, shader="phong", width=w, height=h, aa=aa,
                                   time=j / scene.simulation.frames_per_sec)
                      for p, j in zip(positions, sim_frames)]
            best["render"].append(time.perf_counter() - t0)
            t0 = time.perf_counter()
            with FolderWriter(folder / "frames") as out:
                for image in images:
                    out.add(np.asarray(image))
            best["encode"].append(time.perf_counter() - t0)
            shutil.rmtree(folder / "frames")
    sim_s, ren_s, enc_s = (min(best[k]) for k in ("simulate", "render", "encode"))
    total = sim_s + ren_s + enc_s
    s = sim_s / total
    s_seq = (sim_s + enc_s) / total
    print(f"\n## Long render: sphere.json, {w}x{h}, --aa {aa}, {seconds:g} s at {fps:g} fps "
          f"({len(sim_frames)} frames), one thread, best of {rounds}\n")
    print(f"- simulate {sim_s:.2f} s, render {ren_s:.2f} s, encode (PNG) {enc_s:.2f} s")
    print(f"- simulation share s = {s:.3f}; with the client's encoding (also sequential) "
          f"{s_seq:.3f}")
    print("\n| workers N | Amdahl bound 1 / (s + (1 - s) / N) | with encoding sequential too |")
    print("|---:|---:|---:|")
    for n in (1, 2, 4, 8, 16, 32, 64):
        print(f"| {n} | {1 / (s + (1 - s) / n):.2f} | {1 / (s_seq + (1 - s_seq) / n):.2f} |")
    print(f"\n(as N grows the bound tends to 1/s = {1 / s:.1f}, or {1 / s_seq:.1f} with "
          "encoding)")

    flags = [str(scene_path), "--size", f"{w}x{h}", "--aa", str(aa), "--duration",
             str(seconds), "--fps", str(fps), "--quiet"]
    variants = {"one process (`render`, its default 2 threads)": [],
                "`--scheduler`: the 2 running workers, kernels loaded": ["--scheduler", address],
                "`--workers 2`: a new LocalCluster (start-up, kernels loaded)": ["--workers", "2"]}
    runs: dict[str, list[tuple[float, float]]] = {k: [] for k in variants}
    loads = [load()]
    for _ in range(rounds):
        for name, extra in variants.items():
            out = folder / "shot"

            def shot(extra=extra, out=out):
                assert cli.main(flags + ["--out", f"{out}/"] + extra) == 0

            runs[name].append(measured(shot, pids))
            shutil.rmtree(out)
            loads.append(load())
    print(f"\nMeasured, the whole command `render ... --out frames/` (best of {rounds}, "
          "alternated):\n")
    print("| run | wall s | CPU s (client + workers) | speed-up |")
    print("|---|---:|---:|---:|")
    first = min(runs[next(iter(runs))])[0]
    for name, values in runs.items():
        wall, cpu = min(values)
        print(f"| {name} | {wall:.2f} | {cpu:.2f} | {first / wall:.2f}x |")
    print(f"\nload average (1 min) before and after each run: {', '.join(loads)}")


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--rounds", type=int, default=2)
    args = p.parse_args()
    from distributed import Client, LocalCluster

    print(f"# benchmarks/distributed.py, {time.strftime('%Y-%m-%d %H:%M')}, {os.cpu_count()} "
          f"cores, load average {os.getloadavg()[0]:.2f} at the start")
    with tempfile.TemporaryDirectory(prefix="clothpipe-bench-") as tmp:
        folder = Path(tmp)
        t0 = time.perf_counter()
        with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                          dashboard_address=None, silence_logs=logging.ERROR) as cluster, \
                Client(cluster, set_as_default=False) as client:
            print(f"\nLocalCluster of 2 worker processes started in "
                  f"{time.perf_counter() - t0:.2f} s")
            pids = list(client.run(os.getpid).values())
            batch_figures(folder, cluster.scheduler_address, pids, args.rounds)
            task_overhead(client)
            long_render(folder, cluster.scheduler_address, pids, args.rounds)


if __name__ == "__main__":
    main()
