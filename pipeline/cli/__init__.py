"""The `render` command and its sub-commands: `entry` (main, dispatch), `options` (the
parser), `render` (a render), `messages` (exit statuses and one-line errors), `plan`,
`report` (with `report_plan`, `report_runs`, `report_sheet`, `report_html`), `bench`,
`batch`.

The top layer: may import every other layer.
"""
from .entry import main

__all__ = ["main"]
