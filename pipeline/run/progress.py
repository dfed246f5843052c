"""Progress bars on stderr (tqdm), and a no-op bar when they are off."""
from __future__ import annotations

import os
import sys


def write_line(line: str, stream) -> None:
    """Print `line` on `stream`. Bars shown there (tqdm) are cleared first and drawn again
    below it: printed as is, a message went on after a bar on its line ("... 12/12 [00:18<
    00:00, 1.59s/kernel]render: warning: ...")."""
    tqdm = sys.modules.get("tqdm")  # bars exist only once tqdm is imported (`bar`, `counter`)
    if tqdm is not None and stream is sys.stderr:
        tqdm.tqdm.write(line, file=stream)
        stream.flush()
    else:
        print(line, file=stream, flush=True)


class _NullBar:
    def update(self, n: int = 1) -> None:
        pass

    def close(self) -> None:
        pass


def progress_enabled(quiet: bool, stream=None) -> bool:
    """Bars are shown only on an interactive stderr and never with --quiet."""
    stream = sys.stderr if stream is None else stream
    if quiet:
        return False
    try:
        return bool(stream.isatty())
    except (AttributeError, ValueError):
        return False


class _Bar:
    """A tqdm bar that leaves the cursor at column 0 when it closes: tqdm blanks its line
    but leaves the cursor at the end of the blanks, so the next message began there and
    wrapped ("...   r" / "ender: 75 frames ...")."""

    def __init__(self, bar) -> None:
        self._bar = bar

    def update(self, n: int = 1) -> None:
        self._bar.update(n)

    def close(self) -> None:
        self._bar.close()
        sys.stderr.write("\r")
        sys.stderr.flush()


def bar(total: int, desc: str, unit: str, enabled: bool, position: int = 0):
    """A tqdm bar with rate and ETA on stderr, or a no-op bar."""
    if not enabled:
        return _NullBar()
    from tqdm import tqdm

    return _Bar(tqdm(total=total, desc=desc, unit=unit, position=position, leave=False,
                     file=sys.stderr, smoothing=0.1, **_size(sys.stderr),
                     bar_format="{desc:<9} {percentage:3.0f}%|{bar}| {n_fmt}/{total_fmt} "
                                "[{elapsed}<{remaining}, {rate_fmt}]"))


def counter(desc: str, unit: str, enabled: bool):
    """A tqdm count with no known total (items done and time elapsed), or a no-op bar."""
    if not enabled:
        return _NullBar()
    from tqdm import tqdm

    return _Bar(tqdm(desc=desc, unit=unit, leave=False, file=sys.stderr, **_size(sys.stderr),
                     bar_format="{desc:<9} {n_fmt} {unit}s [{elapsed}]"))


def _size(stream) -> dict:
    """tqdm's screen size: the terminal's, followed as it changes, or 80 x 24 on a terminal
    that reports 0 x 0 (a pseudo-terminal nobody sized, as `script` without a terminal of
    its own gives: tqdm drew nothing there, every bar being outside the screen)."""
    try:
        size = os.get_terminal_size(stream.fileno())
    except (AttributeError, OSError, ValueError):  # not a real terminal: tqdm finds out
        return {"dynamic_ncols": True}
    if size.columns > 0 and size.lines > 0:
        return {"dynamic_ncols": True}
    return {"ncols": size.columns or 80, "nrows": size.lines or 24}
