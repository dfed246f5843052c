"""A bad command line: the one error of a run that is neither the scene's nor an output's."""
from __future__ import annotations


class UsageError(ValueError):
    """A bad command line (exit status 2); the message is followed by a pointer to --help."""

    help_hint = True
