"""`render plan SCENE.json [--fidelity auto] [--tolerance PX] [--json]`: what will be
modelled and why, before running (pipeline.fidelity.plan.Plan)."""
from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence

from .messages import parse_subcommand
from .options import PROG, Parser, override_arg, positive_float, size_arg
from .render import fidelity_overrides


def build_parser() -> argparse.ArgumentParser:
    p = Parser(prog=f"{PROG} plan", allow_abbrev=False,
                     description="Say what the simulation of SCENE.json will model and why: "
                                 "integrator, steps per frame, which colliders can act, "
                                 "whether self-collision can act, sleeping, the predicted "
                                 "cost against fidelity exact.")
    p.add_argument("scene", metavar="SCENE.json")
    p.add_argument("--fidelity", choices=("exact", "auto"))
    p.add_argument("--contact", choices=("course", "robust"))
    p.add_argument("--tolerance", type=positive_float("tolerance"), metavar="PX")
    p.add_argument("--size", type=size_arg, metavar="WxH",
                   help="the image the tolerance is measured in (default: the scene's)")
    p.add_argument("--set", dest="overrides", action="append", default=[],
                   type=override_arg, metavar="KEY=VALUE")
    p.add_argument("--json", action="store_true", help="the plan as one JSON object")
    return p


def main(argv: Sequence[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    args = parse_subcommand(build_parser(), argv, "plan")
    if isinstance(args, int):
        return args
    from pipeline.scene import load_scene
    from pipeline.simulation import Simulation

    contact = [f"simulation.contact={args.contact}"] if args.contact else []
    scene = load_scene(args.scene, list(args.overrides) + contact + fidelity_overrides(args))
    plan = Simulation(scene).plan
    if args.json:
        print(json.dumps(plan.as_dict(), indent=1))
    else:
        print("\n".join(plan.lines()))
    return 0
