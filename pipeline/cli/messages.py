"""What the command line says on stderr: warnings and errors prefixed `render: `, the
exit status and one-line message for an exception, a sub-command's arguments or status."""
from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from pipeline.run import signals
from pipeline.run.errors import UsageError
from pipeline.run.outputs import OutputError, WriteError
from pipeline.run.progress import write_line

from .options import PROG


class Errors:
    def __init__(self, stream, quiet: bool, debug: bool):
        self.stream = stream
        self.quiet = quiet
        self.debug = debug

    def say(self, msg: str) -> None:
        try:
            write_line(f"{PROG}: {msg}", self.stream)
        except OSError:  # stderr gone (its terminal hung up): the exit status remains
            pass

    def warn(self, msg: str) -> None:
        if not self.quiet:
            self.say(f"warning: {msg}")


def interrupted_message(exc: KeyboardInterrupt, outcome: str = "no output written") -> str:
    """'interrupted (SIGTERM); no output written'."""
    name = str(exc) if isinstance(exc, signals.Terminated) else "SIGINT"
    return f"interrupted ({name}); {outcome}"


def failure(exc: BaseException) -> tuple[int, str]:
    """The exit status and message (one line, two for a bad command line) for an exception
    out of a run: 2 bad input, 1 divergence, a write error or an internal failure,
    128 + N stopped by signal N."""
    from pipeline.physics.errors import DivergenceError
    from pipeline.scene import SceneError

    try:
        from shading import TextureError
    except Exception:  # noqa: BLE001
        TextureError = OutputError  # noqa: N806 - never raised, keeps isinstance valid
    if isinstance(exc, UsageError):
        return 2, str(exc) + (f"\n{PROG}: try 'render --help'" if exc.help_hint else "")
    if isinstance(exc, (SceneError, OutputError, TextureError)):
        return 2, one_line(exc)
    if isinstance(exc, (DivergenceError, WriteError)):
        return 1, one_line(exc)
    if isinstance(exc, KeyboardInterrupt):
        return signals.exit_status(exc), interrupted_message(exc)
    if isinstance(exc, MemoryError):
        return 1, "out of memory; try a smaller --size, --aa or fewer frames"
    return 1, f"internal error: {type(exc).__name__}: {one_line(exc)}"


def one_line(exc: BaseException) -> str:
    text = str(exc).strip()
    return text.splitlines()[0] if text else type(exc).__name__


def parse_subcommand(parser: argparse.ArgumentParser, argv: Sequence[str], name: str):
    """A subcommand's arguments, or the exit status when there is nothing to run: 2 after
    one line naming what is wrong, 0 after --help."""
    err = Errors(sys.stderr, quiet=False, debug="--debug" in argv)
    try:
        return parser.parse_args(argv)
    except UsageError as exc:
        err.say(str(exc))
        err.say(f"try 'render {name} --help'")
        return 2
    except SystemExit as exc:  # --help
        return int(exc.code or 0)
