"""Course contact against robust contact, side by side (issue 43): frames of selfCollision
and the 80x80 drape under each mode, with the edge-triangle crossing count of the
independent checker (benchmarks/crossings.py) and the free points inside a collider and
cloth edges through one (benchmarks/collider_crossings.py) under every image.

    python benchmarks/contact_sheet.py                       # writes renders/report/contact.png
    python benchmarks/contact_sheet.py --out sheet.png --size 200

Each scene is simulated once per mode (simulation.contact=course, robust) to its last time;
the frames at the sheet's times are drawn with phong by one camera per scene, framed over
every drawn frame of both modes (pipeline.view.framing), so the two rows differ only by the
contact. The crossing count is the checker's: every cloth edge against every triangle that
shares no vertex with it.
"""
from __future__ import annotations

import argparse
import importlib.util
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(ROOT))

#: scene name of benchmarks/contact.py -> the times (s) the sheet shows
TIMES = {"selfCollision": (0.6, 1.0, 1.4, 2.5), "drape": (1.5, 2.2, 3.0)}
MODES = ("course", "robust")


def _contact():
    """benchmarks/contact.py, loaded by path (see its _load)."""
    spec = importlib.util.spec_from_file_location("contact_bench", HERE / "contact.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules["contact_bench"] = module
    spec.loader.exec_module(module)
    return module


def shots(name: str, bench) -> dict:
    """{mode: (scene, model, [(time, positions)])} for one scene."""
    from pipeline import Simulation

    build = bench.SCENES[name][0]
    out = {}
    for mode in MODES:
        scene, _ = bench.load_with_contact(build(), mode)
        Simulation(scene).advance(1)  # kernels from the cache (or compiled): untimed
        sim = Simulation(scene)
        fps = scene.simulation.frames_per_sec
        frames = []
        t0 = time.perf_counter()
        for t in TIMES[name]:
            sim.advance(round(t * fps) - round(sim.time * fps))
            frames.append((t, sim.positions.copy()))
        out[mode] = (scene, sim.model, frames)
        print(f"{name}, {mode}: simulated {TIMES[name][-1]:g} s in "
              f"{time.perf_counter() - t0:.1f} s", flush=True)
    return out


def sheet(size: int) -> np.ndarray:
    from PIL import Image, ImageDraw

    from pipeline.run.frames import render_frame
    from pipeline.view.framing import Framing, framed_points

    bench = _contact()
    count = bench._crossings.edge_triangle_crossings
    cap = 48  # caption strip under each image, pixels
    blocks = []
    for name in TIMES:
        runs = shots(name, bench)
        framing = Framing(size, size)
        for scene, _, frames in runs.values():
            for t, pos in frames:
                framing.add(framed_points(scene, pos, t))
        rows = []
        for mode, (scene, model, frames) in runs.items():
            cells = []
            for t, pos in frames:
                img = render_frame(scene, pos, model, shader="phong", width=size, height=size,
                                   aa=2, time=t, shot=framing)
                n = count(pos, model.triangles)
                v = bench.collider_violations(pos, bench.unique_edges(model.triangles),
                                              scene.colliders, t, model.pinned)
                inside = sum(len(c["inside"]) for c in v["colliders"])
                through = sum(len(c["edges"]) for c in v["colliders"])
                cell = Image.new("RGB", (size, size + cap), "white")
                cell.paste(Image.fromarray(img), (0, 0))
                draw = ImageDraw.Draw(cell)
                draw.text((6, size + 3), f"{name}, {mode}, t = {t:g} s", fill="black")
                draw.text((6, size + 18), f"{n} edge-triangle crossings",
                          fill="black" if n == 0 else (190, 0, 0))
                draw.text((6, size + 33), f"colliders: {inside} points in, {through} edges "
                          "through", fill="black" if inside + through == 0 else (190, 0, 0))
                cells.append(np.asarray(cell))
                print(f"  {name} {mode} t={t:g}: {n} crossings, {inside} points inside and "
                      f"{through} edges through colliders", flush=True)
            rows.append(np.concatenate(cells, axis=1))
        blocks.append(np.concatenate(rows, axis=0))
    width = max(b.shape[1] for b in blocks)
    padded = [np.pad(b, ((0, 8), (0, width - b.shape[1]), (0, 0)), constant_values=255)
              for b in blocks]
    return np.concatenate(padded, axis=0)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=ROOT / "renders" / "report" / "contact.png")
    ap.add_argument("--size", type=int, default=240, help="pixels a side of each image")
    a = ap.parse_args(argv)
    from PIL import Image

    Image.fromarray(sheet(a.size)).save(a.out, optimize=True)
    print(f"wrote {a.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
