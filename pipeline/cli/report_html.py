"""`render report`'s HTML page: one self-contained file, every image a data URI."""
from __future__ import annotations

import base64
import html
import io
import time

import numpy as np

from .report_sheet import Report, short_message


def _png_bytes(image: np.ndarray) -> bytes:
    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(image), "RGB").save(buf, format="PNG",
                                                              optimize=False, compress_level=9)
    return buf.getvalue()


def _data_uri(data: bytes, mime: str) -> str:
    return f"data:{mime};base64,{base64.b64encode(data).decode('ascii')}"


_CSS = """
body{font-family:system-ui,-apple-system,"Segoe UI",Roboto,sans-serif;margin:1.5em;
color:#222;background:#fafafa}
h1{font-size:1.4em;margin:0 0 .3em}h2{font-size:1.1em;margin:1.4em 0 .4em}
table.grid{border-collapse:collapse}
table.grid th{font-weight:600;font-size:.85em;padding:.3em .5em;white-space:pre}
table.grid th[scope=row]{text-align:right;vertical-align:middle}
table.grid td{padding:4px;vertical-align:top}
figure{margin:0}figure img{display:block;background:#333}
figcaption{font-size:.75em;color:#444;max-width:var(--w);overflow-wrap:break-word;
margin-top:2px}
figure.diverged figcaption{color:#a01010}
figcaption details{color:#444}figcaption summary{cursor:pointer}
dl.meta{display:grid;grid-template-columns:max-content auto;gap:.15em 1em;font-size:.85em;
margin:.5em 0}dl.meta dt{color:#666}dl.meta dd{margin:0;font-family:monospace}
p.note{font-size:.85em;color:#555}
"""


def render_html(report: Report, sheet_name: str, gif_name: str | None,
                gif_data: bytes | None) -> str:
    plan = report.plan
    esc = html.escape
    cw = plan.width
    out = ["<!DOCTYPE html>", '<html lang="en">', "<head>", '<meta charset="utf-8">',
           '<meta name="viewport" content="width=device-width, initial-scale=1">',
           f"<title>{esc(plan.title)} - render report</title>",
           f"<style>{_CSS}</style>", "</head>", "<body>",
           f"<h1>{esc(plan.title)}</h1>"]
    meta = [("scene", plan.scene_path),
            ("overrides", " ".join(plan.overrides) or "(none)"),
            ("shaders", ", ".join(plan.shaders)),
            ("times (s)", ", ".join(f"{t:g}" for t in plan.times)
             + f"  (simulator frames {', '.join(map(str, plan.sim_frames))} at "
               f"{plan.sim_fps:g} fps)"),
            ("image size", f"{plan.width}x{plan.height}, aa "
                           f"{plan.aa if plan.aa is not None else 'scene default'}")]
    if plan.sweeps:
        for n, s in enumerate(plan.sweeps):
            where = ("rows" if n == 0 else "columns" if n == 1 else "one grid per value")
            meta.append((f"sweep {n + 1} ({where})", f"{s.key} = {', '.join(s.values)}"))
        meta.append(("processes", plan.cluster
                      or str(max(1, min(plan.jobs, len(plan.variants))))))
    for v, run in zip(plan.variants, report.runs):
        name = f"simulation{' ' + v.label if v.label else ''}"
        status = f"{run.seconds:.2f} s" + (f"; diverged: {run.error}" if run.error else "")
        for w in run.warnings:
            status += f"; warning: {w}"
        meta.append((name, status))
    meta.append(("generated", time.strftime("%Y-%m-%d %H:%M:%S")))
    out.append('<dl class="meta">')
    for k, v in meta:
        out.append(f"<dt>{esc(k)}</dt><dd>{esc(v)}</dd>")
    out.append("</dl>")
    out.append(f'<p class="note">Render times are wall-clock milliseconds for one frame in '
               f'this process (kernels compiled beforehand). Contact sheet: '
               f'<a href="{esc(sheet_name)}">{esc(sheet_name)}</a>.</p>')
    for gi, g in enumerate(report.grids):
        out.append(f'<section class="report-grid" data-grid="{gi}">')
        if g.title:
            out.append(f"<h2>{esc(g.title)}</h2>")
        out.append(f'<table class="grid" style="--w:{cw}px">')
        out.append("<thead><tr><th></th>" + "".join(
            f'<th scope="col">{esc(c)}</th>' for c in g.cols) + "</tr></thead><tbody>")
        for r, label in enumerate(g.rows):
            out.append(f'<tr><th scope="row">{esc(label)}</th>')
            for cell in g.cells[r]:
                assert cell is not None
                attrs = " ".join(f'data-{k}="{esc(v)}"' for k, v in cell.attrs.items())
                cls = "cell diverged" if cell.error else "cell"
                uri = _data_uri(_png_bytes(cell.image), "image/png")
                more = (f"<details><summary>why</summary>{esc(cell.error)}</details>"
                        if cell.error and cell.error != short_message(cell.error) else "")
                out.append(f'<td><figure class="{cls}" {attrs}>'
                           f'<img src="{uri}" width="{plan.width}" height="{plan.height}" '
                           f'alt="{esc(cell.caption)}">'
                           f"<figcaption>{esc(cell.caption)}{more}</figcaption></figure></td>")
            out.append("</tr>")
        out.append("</tbody></table></section>")
    if gif_data is not None:
        gh, gw = report.gif_frames[0].shape[:2]
        out.append('<section class="animation"><h2>Animation</h2>')
        out.append(f'<p class="note">The whole animation, {len(report.gif_frames)} frames at '
                   f'{plan.gif_fps:g} fps (also in <a href="{esc(gif_name or "")}">'
                   f'{esc(gif_name or "")}</a>).</p>')
        out.append(f'<img class="gif" src="{_data_uri(gif_data, "image/gif")}" width="{gw}" '
                   f'height="{gh}" alt="animated grid">')
        out.append("</section>")
    out += ["</body>", "</html>", ""]
    return "\n".join(out)

