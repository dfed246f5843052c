"""Regenerate the gallery: every shader on every course scene, and the showcase scenes of the
newer features (wind, box and mesh colliders, keyframes, mass maps), as small looping GIFs.

    python renders/make_gallery.py                        # all of it (a few minutes on 2 cores)
    python renders/make_gallery.py showcase               # only the showcase scenes
    python renders/make_gallery.py flag bowl              # only these scenes
    python renders/make_gallery.py sphere --shaders phong normal

Positional names (or `--scenes`) choose the scenes: a scene file name in scenes/ without
`.json`, or `course` / `showcase` for a whole group; no name means every scene. Only the
chosen scenes' GIFs are rewritten; renders/README.md always lists every GIF present.

Course scenes (pinned2, pinned4, sphere, plane, selfCollision): every shader, 2 s at 20 fps,
160x160. Showcase scenes (SHOWCASE below): phong plus one shader that suits the scene, at
their own duration (long enough for the motion: the flag flying, the sphere moving), 20 fps,
224x224. `--shaders`, `--duration` and `--size` override those defaults for every chosen
scene.

Writes renders/<scene>_<shader>.gif (the same GIF writer as `render`) and renders/README.md.
Each scene is simulated once; its frames are then drawn with every shader. The output frame
at time t = k / fps shows the simulator frame nearest to t, and keyframed colliders are drawn
at that frame's time, and a scene with no camera is framed over the whole GIF
(pipeline.view.framing), exactly as `render` does, so `render scenes/<scene>.json --shader
<shader> --duration <d> --fps 20 --size <n>x<n> --aa 1 --out x.gif` produces the same GIF.
The total is checked against a budget (12 MB) so the committed gallery stays small.
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
COURSE_SIZE, COURSE_DURATION = 160, 2.0
# scene: (duration in s, shaders, what it shows)
SHOWCASE = {
    "flag": (4.0, ("phong", "texture"),
             "a flag pinned along its left edge to a `box` pole, flying in a gusty `wind`"),
    "tablecloth": (3.0, ("phong", "normal"),
                   "a cloth with a heavier hem (`mass_map` image) dropped on a table made of "
                   "five `box` colliders: it drapes over the edges"),
    "bowl": (3.0, ("phong", "mirror"),
             "a cloth falling into a concave `mesh` collider, scenes/meshes/bowl.obj"),
    "moving_sphere": (4.0, ("phong", "toon"),
                      "a cloth draped over a sphere that then slides sideways (`keyframes`); "
                      "friction 1 carries the cloth along"),
    "round_tablecloth": (3.0, ("phong", "texture"),
                         "a round tablecloth from a mesh file (`cloth.mesh`, "
                         "scenes/meshes/tablecloth.obj) dropped on a round table (a `mesh` "
                         "collider)"),
    "swallowtail": (4.0, ("phong", "texture"),
                    "a swallowtail flag from a mesh file, pinned by its `hoist` group, in wind"),
    "skirt": (6.0, ("phong", "normal"),
              "a skirt (an open cone from a mesh file) pinned at its waist by keyframed pins "
              "that turn it, over a turning sphere"),
    "tshirt": (3.0, ("phong", "texture"),
               "a T-shirt (body and sleeves from one mesh file) settling on a torso-shaped "
               "`mesh` collider"),
}
SHOWCASE_SIZE = 224
GROUPS = {"course": COURSE_SCENES, "showcase": tuple(SHOWCASE)}
BUDGET = 12 * 2**20


def main(argv=None) -> int:
    import shading
    from pipeline import Simulation, load_scene
    from pipeline.cli.render import nearest_sim_frames, output_times
    from pipeline.run.frames import render_frame
    from pipeline.view.framing import frame_shot
    from pipeline.run.outputs import GifWriter

    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("names", nargs="*", metavar="SCENE",
                   help="scenes to render (file names in scenes/ without .json, or 'course', "
                        "'showcase'); default: all")
    p.add_argument("--scenes", nargs="+", default=[], help="same as the positional names")
    p.add_argument("--shaders", nargs="+", default=None,
                   help="default: every shader for course scenes, two for showcase scenes")
    p.add_argument("--size", type=int, default=None,
                   help=f"pixels (default {COURSE_SIZE}, showcase {SHOWCASE_SIZE})")
    p.add_argument("--duration", type=float, default=None,
                   help=f"seconds (default {COURSE_DURATION:g}, showcase: per scene)")
    p.add_argument("--fps", type=float, default=20.0)
    p.add_argument("--out", type=Path, default=HERE)
    args = p.parse_args(argv)
    names = []
    for name in args.names + args.scenes or list(COURSE_SCENES + tuple(SHOWCASE)):
        names.extend(GROUPS.get(name, (name,)))
    names = list(dict.fromkeys(names))
    missing = [n for n in names if not (ROOT / "scenes" / f"{n}.json").is_file()]
    if missing:
        p.error(f"no scene file scenes/<name>.json for: {', '.join(missing)}")
    unknown = [s for s in args.shaders or () if s not in shading.SHADERS]
    if unknown:
        p.error(f"unknown shader(s) {', '.join(unknown)}; one of {', '.join(shading.SHADERS)}")
    try:  # small kernels on a busy machine run faster on one thread (see docs/cli.md)
        import numba

        numba.set_num_threads(1)
    except Exception:  # noqa: BLE001
        pass

    made: dict[tuple[str, str], Path] = {}
    for name in names:
        duration, shaders, _ = SHOWCASE.get(name, (COURSE_DURATION, shading.SHADERS, ""))
        duration = args.duration if args.duration is not None else duration
        shaders = args.shaders or shaders
        size = args.size or (SHOWCASE_SIZE if name in SHOWCASE else COURSE_SIZE)
        n = max(1, round(duration * args.fps))
        t0 = time.perf_counter()
        scene = load_scene(ROOT / "scenes" / f"{name}.json")
        sim_fps = scene.simulation.frames_per_sec
        sim = Simulation(scene)
        states, current = [], 0
        for j in nearest_sim_frames(output_times(n, args.fps), sim_fps):
            sim.advance(j - current)
            current = j
            states.append((sim.positions.copy(), j / sim_fps))
        t_sim = time.perf_counter() - t0
        shot = frame_shot(scene, states, size, size) if scene.camera is None else None
        for shader in shaders:
            t1 = time.perf_counter()
            path = args.out / f"{name}_{shader}.gif"
            with GifWriter(path, fps=args.fps) as gif:
                for pos, t in states:
                    gif.add(render_frame(scene, pos, sim.model, shader=shader, width=size,
                                         height=size, aa=1, time=t, shot=shot))
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
    """renders/README.md: tables of every <scene>_<shader>.gif present (not only new ones)."""
    import shading

    made = dict(made)
    for sc in COURSE_SCENES + tuple(SHOWCASE):
        for sh in shading.SHADERS:
            f = args.out / f"{sc}_{sh}.gif"
            if f.exists():
                made.setdefault((sc, sh), f)
    others = tuple(s for s, _ in made if s not in COURSE_SCENES and s not in SHOWCASE)
    course = [s for s in dict.fromkeys(COURSE_SCENES + others) if any(k[0] == s for k in made)]
    shaders = [sh for sh in shading.SHADERS if any(k == (s, sh) for s in course for k in made)]
    lines = [
        "# Gallery",
        "",
        "Regenerate with `python renders/make_gallery.py` (all of it), "
        "`python renders/make_gallery.py showcase` (the showcase only) or "
        "`python renders/make_gallery.py SCENE ...`; see its docstring for options.",
        "",
    ]
    showcase = [s for s in SHOWCASE if any(k[0] == s for k in made)]
    if showcase:
        lines += [
            "## Showcase",
            "",
            "Wind, box and mesh colliders, keyframed colliders and mass maps "
            f"(scene files in [`scenes/`](../scenes/), keys in "
            f"[`docs/scene-format.md`](../docs/scene-format.md)): {args.fps:g} fps, "
            f"{SHOWCASE_SIZE}x{SHOWCASE_SIZE}, looping, phong and one other shader each.",
            "",
        ]
        rows = []
        for s in showcase:
            duration, _, what = SHOWCASE[s]
            cells = [f"![{s} {sh}]({made[s, sh].name})" for sh in shading.SHADERS
                     if (s, sh) in made]
            cells.sort(key=lambda c: "phong" not in c)  # phong first
            rows.append((f"[`{s}`](../scenes/{s}.json)", f"{what}; {duration:g} s", *cells))
        width = max(len(r) for r in rows)
        lines.append("| scene | shows |" + " |" * (width - 2))
        lines.append("|---" * width + "|")
        lines += ["| " + " | ".join(r + ("",) * (width - len(r))) + " |" for r in rows]
        lines.append("")
    if course:
        lines += [
            "## Every shader on the course scenes",
            "",
            f"{COURSE_DURATION:g} s at {args.fps:g} fps, {COURSE_SIZE}x{COURSE_SIZE}, looping.",
            "",
            "| shader | " + " | ".join(course) + " |",
            "|---" * (len(course) + 1) + "|",
        ]
        for sh in shaders:
            cells = [f"![{s} {sh}]({made[s, sh].name})" if (s, sh) in made else ""
                     for s in course]
            lines.append(f"| {sh} | " + " | ".join(cells) + " |")
    (args.out / "README.md").write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    sys.exit(main())
