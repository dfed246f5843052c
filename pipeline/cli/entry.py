"""`render`'s entry point: signals handled, `render NAME ...` dispatched to a sub-command
(report, bench, plan, batch), a bad command line and any failure turned into one message
and an exit status."""
from __future__ import annotations

import sys
import traceback
from typing import Sequence

from pipeline.run import signals
from pipeline.run.errors import UsageError
from pipeline.run.outputs import WriteError

from .messages import Errors, failure, interrupted_message, one_line
from .options import PROG, build_parser
from .render import run

SUBCOMMANDS = {  # `render NAME ...` runs the module's main(argv)
    "report": "pipeline.cli.report",  # shaders and parameter sweeps side by side (HTML + PNG)
    "bench": "pipeline.cli.bench",  # integrators: work-precision and stability charts
    "plan": "pipeline.cli.plan",  # what fidelity exact or auto will model, and why
    "batch": "pipeline.cli.batch",  # many scenes, one output each (optionally on Dask)
}


def _wants_report(argv: Sequence[str]) -> bool:
    """`render SCENE --shader all ...` or an .html output means `render report`."""
    pairs = zip(argv, list(argv[1:]) + [""])
    return any((a in ("--shader", "-s") and b == "all") or a in ("--shader=all", "-sall")
               or (a in ("--out", "-o") and b.lower().endswith(".html"))
               or (a.startswith("--out=") and a.lower().endswith(".html")) for a, b in pairs)


def _run_subcommand(name: str, argv: Sequence[str]) -> int:
    import importlib

    from pipeline.scene import SceneError

    err = Errors(sys.stderr, quiet=False, debug="--debug" in argv)
    try:
        return importlib.import_module(SUBCOMMANDS[name]).main(list(argv))
    except SceneError as exc:
        err.say(one_line(exc))
        return 2
    except WriteError as exc:
        err.say(str(exc))
        return 1
    except KeyboardInterrupt as exc:
        err.say(interrupted_message(exc))
        return signals.exit_status(exc)


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the `render` console script; returns the exit status.
    SIGINT, SIGTERM and SIGHUP stop it cleanly (pipeline.run.signals): exit 128 + signal."""
    with signals.handled():
        return _main(argv)


def _main(argv: Sequence[str] | None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    if not {"-h", "--help", "--version"} & set(argv):  # those need no numba
        from clothjit import threads_setting_error

        problem = threads_setting_error()
        if problem is not None:
            Errors(sys.stderr, quiet=False, debug=False).say(problem)
            return 2
    if argv and argv[0] in SUBCOMMANDS:
        return _run_subcommand(argv[0], argv[1:])
    if _wants_report(argv):
        return _run_subcommand("report", argv)
    stderr = sys.stderr
    debug = "--debug" in argv
    err = Errors(stderr, quiet=False, debug=debug)
    try:
        args = build_parser().parse_args(argv)
    except UsageError as exc:
        err.say(str(exc))
        err.say("try 'render --help'")
        return 2
    except SystemExit as exc:  # --help, --version
        return int(exc.code or 0)
    err.quiet = args.quiet
    try:
        return run(args, err)
    except (Exception, KeyboardInterrupt) as exc:
        if args.debug:
            traceback.print_exc(file=stderr)
        status, msg = failure(exc)
        if msg.startswith("internal error") and not args.debug:
            msg += f"\n{PROG}: run with --debug for the traceback"
        err.say(msg)
        return status

