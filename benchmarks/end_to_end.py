"""End-to-end benchmark of `render`, and the GIF palette study.

    python benchmarks/end_to_end.py                  # warm and cold runs, all pipeline modes
    python benchmarks/end_to_end.py --repeat 3 --modes split
    python benchmarks/end_to_end.py --palette-study  # global vs per-frame palette, dithering

End to end: `render scenes/sphere.json --shader phong --out x.gif` (3 s at 25 fps, 512x512)
in a fresh Python process each time, split into simulate / render / encode (from the
command's summary line), with the process's wall time and peak resident memory (ru_maxrss).
Cold = an empty numba cache (NUMBA_CACHE_DIR set to a fresh temporary folder, so every
kernel is compiled); warm = the same cache again, already filled. Note that with
`--pipeline split/overlap` simulate and render overlap, so their sum exceeds the wall time.

Palette study: renders the frames once, then encodes them with each GIF palette strategy
and reports file size, encode time, PSNR, the low-pass error (banding), and flicker.
"""
from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

SUMMARY = re.compile(r"simulate ([\d.]+) s, render ([\d.]+) s, encode ([\d.]+) s, total ([\d.]+) s")


# ------------------------------------------------------------------------------ child


def child(argv: list[str]) -> int:
    """Run the CLI in this process, then report peak memory as JSON on stdout."""
    import resource

    from pipeline.cli import main

    t0 = time.perf_counter()
    code = main(argv)
    wall = time.perf_counter() - t0
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024  # KB -> MB on Linux
    print(json.dumps({"code": code, "wall_in_process": wall, "peak_rss_mb": rss}))
    return code


def run_once(cli_args: list[str], cache_dir: str) -> dict:
    env = dict(os.environ, NUMBA_CACHE_DIR=cache_dir)
    t0 = time.perf_counter()
    r = subprocess.run([sys.executable, __file__, "--child", *cli_args], capture_output=True,
                       text=True, env=env, cwd=ROOT)
    wall = time.perf_counter() - t0
    if r.returncode != 0:
        raise SystemExit(f"render failed ({r.returncode}):\n{r.stderr}")
    info = json.loads(r.stdout.strip().splitlines()[-1])
    m = SUMMARY.search(r.stderr)
    info.update(wall=wall, simulate=float(m[1]), render=float(m[2]), encode=float(m[3]),
                total=float(m[4]))
    return info


def end_to_end(args) -> None:
    out = Path(tempfile.mkdtemp(prefix="e2e-")) / "x.gif"
    base = ["scenes/sphere.json", "--shader", "phong", "--out", str(out),
            "--duration", "3", "--fps", "25", "--size", "512x512"]
    print(f"machine: {os.cpu_count()} cores, load average "
          f"{' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    print(f"{'mode':8} {'cache':5} {'wall':>6} {'in-proc':>7} {'sim':>6} {'render':>6} "
          f"{'encode':>6} {'peak MB':>7} {'GIF MB':>6}")
    for mode in args.modes:
        with tempfile.TemporaryDirectory(prefix="numba-cache-") as cache:
            runs = {"cold": [run_once(base + ["--pipeline", mode], cache)]}
            runs["warm"] = [run_once(base + ["--pipeline", mode], cache)
                            for _ in range(args.repeat)]
        for kind, rs in runs.items():
            best = min(rs, key=lambda r: r["wall"])
            print(f"{mode:8} {kind:5} {best['wall']:6.2f} {best['wall_in_process']:7.2f} "
                  f"{best['simulate']:6.2f} {best['render']:6.2f} {best['encode']:6.2f} "
                  f"{best['peak_rss_mb']:7.0f} {out.stat().st_size / 2**20:6.2f}"
                  + (f"   (best of {len(rs)}; walls "
                     f"{', '.join('%.1f' % r['wall'] for r in rs)})" if len(rs) > 1 else ""))
    print(f"GIF: {out}")


# ------------------------------------------------------------------------------ palette study


def render_frames(scene_path: str, shader: str, n: int, size: int) -> list[np.ndarray]:
    from pipeline import Simulation, load_scene
    from pipeline.cli.render import nearest_sim_frames, output_times
    from pipeline.run.frames import render_frame

    scene = load_scene(scene_path)
    sim = Simulation(scene)
    frames, cur = [], 0
    for j in nearest_sim_frames(output_times(n, 25), scene.simulation.frames_per_sec):
        sim.advance(j - cur)
        cur = j
        frames.append(render_frame(scene, sim.positions.copy(), sim.model, shader=shader,
                                   width=size, height=size))
    return frames


def _blur(x: np.ndarray, sigma: float = 1.5) -> np.ndarray:
    r = int(3 * sigma)
    k = np.exp(-0.5 * (np.arange(-r, r + 1) / sigma) ** 2)
    k /= k.sum()
    for axis in (0, 1):
        x = np.apply_along_axis(lambda v: np.convolve(np.pad(v, r, mode="edge"), k, "valid"),
                                axis, x)
    return x


def gif_frames(path: Path) -> list[np.ndarray]:
    from PIL import Image

    out = []
    with Image.open(path) as im:
        for i in range(im.n_frames):
            im.seek(i)
            out.append(np.asarray(im.convert("RGB")))
    return out


def palette_study(args) -> None:
    from pipeline.run.outputs import GifWriter

    tmp = Path(tempfile.mkdtemp(prefix="palette-"))
    for shader in args.shaders:
        frames = render_frames(args.scene, shader, args.frames, args.size)
        print(f"\n{args.scene}, shader {shader}, {len(frames)} frames {args.size}x{args.size}")
        print(f"{'palette':8} {'dither':6} {'size KB':>8} {'encode s':>8} {'PSNR dB':>8} "
              f"{'lowpass':>8} {'max lp':>7} {'flicker %':>9}")
        src = np.stack(frames).astype(np.float64)
        static = np.all(src[1:] == src[:-1], axis=-1)  # pixels unchanged in the source
        for palette in ("global", "frame"):
            for dither in (("none", "fs", "stable") if palette == "global" else ("none", "fs")):
                path = tmp / f"{shader}-{palette}-{dither}.gif"
                t0 = time.perf_counter()
                with GifWriter(path, fps=25, palette=palette, dither=dither) as w:
                    for f in frames:
                        w.add(f)
                enc = time.perf_counter() - t0
                got = np.stack(gif_frames(path)).astype(np.float64)
                err = got - src
                mse = np.mean(err ** 2)
                psnr = 10 * np.log10(255 ** 2 / mse) if mse > 0 else float("inf")
                idx = np.linspace(0, len(frames) - 1, min(8, len(frames))).astype(int)
                lp = np.stack([_blur(err[i].mean(axis=-1)) for i in idx])
                lp_rms, lp_max = np.sqrt(np.mean(lp ** 2)), np.abs(lp).max()
                changed = np.any(got[1:] != got[:-1], axis=-1)
                flicker = 100 * (changed & static).sum() / max(1, static.sum())
                print(f"{palette:8} {dither:6} {path.stat().st_size / 1024:8.0f} "
                      f"{enc:8.2f} {psnr:8.2f} {lp_rms:8.3f} {lp_max:7.2f} {flicker:9.2f}")
    print(f"\nGIFs in {tmp}")


def main() -> int:
    if len(sys.argv) > 1 and sys.argv[1] == "--child":
        return child(sys.argv[2:])
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--repeat", type=int, default=3, help="warm runs per mode (best is shown)")
    p.add_argument("--modes", nargs="+", default=["serial", "overlap", "split"],
                   choices=["serial", "overlap", "split", "auto"])
    p.add_argument("--palette-study", action="store_true")
    p.add_argument("--scene", default="scenes/sphere.json")
    p.add_argument("--shaders", nargs="+", default=["phong", "normal", "texture"])
    p.add_argument("--frames", type=int, default=75)
    p.add_argument("--size", type=int, default=512)
    args = p.parse_args()
    os.chdir(ROOT)
    if args.palette_study:
        palette_study(args)
    else:
        end_to_end(args)
    return 0


if __name__ == "__main__":
    sys.exit(main())
