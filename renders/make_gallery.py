"""Regenerate the gallery: every shader on every course scene, as small looping GIFs.

    python renders/make_gallery.py            # all of it (a few minutes on 2 cores)
    python renders/make_gallery.py --scenes sphere --shaders phong normal

Writes renders/<scene>_<shader>.gif (2 s at 20 fps, 160x160 by default, the same GIF
writer as `render`) and renders/README.md, a page showing them as a table. Each scene is
simulated once; its frames are then drawn with every shader. The output frame at time
t = k / fps shows the simulator frame nearest to t, exactly as `render` does, so
`render scenes/<scene>.json --shader <shader> --duration 2 --fps 20 --size 160x160
--out x.gif` produces the same GIF. The total is checked against a budget (8 MB) so the
committed gallery stays small.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(ROOT))

COURSE_SCENES = ("pinned2", "pinned4", "sphere", "plane", "selfCollision")
BUDGET = 8 * 2**20


def main(argv=None) -> int:
    import shading
    from pipeline import Simulation, load_scene
    from pipeline.cli import nearest_sim_frames, output_times
    from pipeline.frames import render_frame
    from pipeline.outputs import GifWriter

    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--scenes", nargs="+", default=list(COURSE_SCENES))
    p.add_argument("--shaders", nargs="+", default=list(shading.SHADERS))
    p.add_argument("--size", type=int, default=160)
    p.add_argument("--duration", type=float, default=2.0)
    p.add_argument("--fps", type=float, default=20.0)
    p.add_argument("--out", type=Path, default=HERE)
    args = p.parse_args(argv)
    try:  # small kernels on a busy machine run faster on one thread (see docs/cli.md)
        import numba

        numba.set_num_threads(1)
    except Exception:  # noqa: BLE001
        pass

    n = max(1, round(args.duration * args.fps))
    made: dict[tuple[str, str], Path] = {}
    for name in args.scenes:
        t0 = time.perf_counter()
        scene = load_scene(ROOT / "scenes" / f"{name}.json")
        sim = Simulation(scene)
        states, current = [], 0
        for j in nearest_sim_frames(output_times(n, args.fps), scene.simulation.frames_per_sec):
            sim.advance(j - current)
            current = j
            states.append(sim.positions.copy())
        t_sim = time.perf_counter() - t0
        for shader in args.shaders:
            t1 = time.perf_counter()
            path = args.out / f"{name}_{shader}.gif"
            with GifWriter(path, fps=args.fps) as gif:
                for pos in states:
                    gif.add(render_frame(scene, pos, sim.model, shader=shader,
                                         width=args.size, height=args.size, aa=1))
            made[name, shader] = path
            print(f"{path.relative_to(ROOT) if path.is_relative_to(ROOT) else path}: "
                  f"{path.stat().st_size / 1024:.0f} KB "
                  f"(simulate {t_sim:.1f} s, render+encode {time.perf_counter() - t1:.1f} s)",
                  flush=True)
            t_sim = 0.0

    write_index(args, made)
    total = sum(f.stat().st_size for f in args.out.glob("*.gif"))
    print(f"gallery total {total / 2**20:.2f} MB in {args.out}")
    if total > BUDGET:
        print(f"over the {BUDGET / 2**20:.0f} MB budget: use a smaller --size or --fps",
              file=sys.stderr)
        return 1
    return 0


def write_index(args, made) -> None:
    """renders/README.md: a table of every <scene>_<shader>.gif present (not only new ones)."""
    import shading

    made = dict(made)
    for sc in COURSE_SCENES + tuple(args.scenes):
        for sh in shading.SHADERS:
            f = args.out / f"{sc}_{sh}.gif"
            if f.exists():
                made.setdefault((sc, sh), f)
    order = list(dict.fromkeys(COURSE_SCENES + tuple(args.scenes)))
    scenes = [s for s in order if any(k[0] == s for k in made)]
    shaders = [sh for sh in shading.SHADERS if any(k[1] == sh for k in made)]
    lines = [
        "# Gallery",
        "",
        f"Every shader on the course scenes: {args.duration:g} s at {args.fps:g} fps, "
        f"{args.size}x{args.size}, looping. Regenerate with `python renders/make_gallery.py` "
        "(see its docstring for options).",
        "",
        "| shader | " + " | ".join(scenes) + " |",
        "|---" * (len(scenes) + 1) + "|",
    ]
    for sh in shaders:
        cells = [f"![{s} {sh}]({made[s, sh].name})" if (s, sh) in made else "" for s in scenes]
        lines.append(f"| {sh} | " + " | ".join(cells) + " |")
    (args.out / "README.md").write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    sys.exit(main())
