"""`render report`'s contact sheet: grids of cells with their labels and captions drawn
with Pillow's default font, and the placeholder of a diverged variant."""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from .report_plan import ReportPlan
from .report_runs import VariantRun

# Contact-sheet layout (pixels). See `sheet_size`.
PAD = 6  # gap between cells and around the sheet


LINE_H = 12  # one line of Pillow's default font (size 10)


TITLE_H = LINE_H + 2 * PAD  # band holding a grid's title


CAPTION_H = LINE_H + 2  # one line under each cell (render time, or "diverged")


ROW_LABEL_MIN = 72  # minimum width of the row-label column


BACKGROUND = (255, 255, 255)


INK = (20, 20, 20)


DIVERGED_BG = (90, 30, 30)


@dataclass
class Cell:
    image: np.ndarray  # (H, W, 3) uint8 (a placeholder for a diverged frame)
    caption: str  # full caption (HTML)
    short: str  # one short line under the cell on the contact sheet
    attrs: dict  # data-* attributes of the HTML cell
    error: str | None = None


@dataclass
class Grid:
    title: str
    rows: list[str]  # row labels ("\n" separates lines)
    cols: list[str]  # column labels
    cells: list[list[Cell | None]]


def _font():
    from PIL import ImageFont

    return ImageFont.load_default()


def _text_w(draw, text: str, font) -> float:
    return max((draw.textlength(line, font=font) for line in text.split("\n")), default=0.0)


def _fit(draw, text: str, font, width: float) -> str:
    """Shorten one line with '...' in the middle until it fits `width` pixels."""
    if draw.textlength(text, font=font) <= width:
        return text
    keep = len(text)
    while keep > 2:
        keep -= 1
        a = (keep + 1) // 2
        b = keep - a
        s = text[:a] + "..." + (text[-b:] if b else "")
        if draw.textlength(s, font=font) <= width:
            return s
    return "..."


def _wrap(draw, text: str, font, width: float) -> list[str]:
    lines: list[str] = []
    for para in text.split("\n"):
        cur = ""
        for word in para.split(" "):
            trial = word if not cur else cur + " " + word
            if draw.textlength(trial, font=font) <= width or not cur:
                cur = trial
            else:
                lines.append(cur)
                cur = word
        lines.append(cur)
    return [_fit(draw, ln, font, width) for ln in lines]


def short_message(message: str) -> str:
    """"simulation diverged at frame 36, step 1 of 1 (t = 0.4000 s): why; advice" ->
    the part before the first ": " (the whole message stays in the HTML caption)."""
    return message.split(": ", 1)[0]


def diverged_image(message: str, width: int, height: int) -> np.ndarray:
    """A dark red cell with the divergence message written on it (wrapped)."""
    from PIL import Image, ImageDraw

    im = Image.new("RGB", (width, height), DIVERGED_BG)
    d = ImageDraw.Draw(im)
    font = _font()
    text = message if "diverged" in message.lower() else "DIVERGED: " + message
    lines = _wrap(d, text, font, max(8, width - 8))
    for n, line in enumerate(lines[: max(1, (height - 8) // LINE_H)]):
        d.text((4, 4 + n * LINE_H), line, fill=(255, 235, 235), font=font)
    return np.asarray(im)


def row_label_width(grids: Sequence[Grid]) -> int:
    from PIL import Image, ImageDraw

    d = ImageDraw.Draw(Image.new("RGB", (1, 1)))
    font = _font()
    widest = max((_text_w(d, r, font) for g in grids for r in g.rows), default=0.0)
    return max(ROW_LABEL_MIN, int(math.ceil(widest)) + 2 * PAD)


def _header_h(g: Grid) -> int:
    return max((c.count("\n") + 1 for c in g.cols), default=1) * LINE_H + PAD


def sheet_size(grids: Sequence[Grid], width: int, height: int, captions: bool = True
               ) -> tuple[int, int]:
    """(W, H) in pixels of a contact sheet of `grids` with cells of width x height:

        W = L + C * (width + PAD) + PAD      L = row-label column (>= ROW_LABEL_MIN),
                                             C = the most columns of any grid
        H = sum over grids of (TITLE_H + header + R * (height + CAPTION_H + PAD)) + PAD
            header = (lines of the longest column label) * LINE_H + PAD; no CAPTION_H
            without captions (the GIF).
    """
    cols = max(len(g.cols) for g in grids)
    cap = CAPTION_H if captions else 0
    w = row_label_width(grids) + cols * (width + PAD) + PAD
    h = sum(TITLE_H + _header_h(g) + len(g.rows) * (height + cap + PAD) for g in grids) + PAD
    return w, h


class SheetCanvas:
    """The labelled grids drawn once; `compose(images)` pastes cell images into a copy."""

    def __init__(self, grids: Sequence[Grid], width: int, height: int, captions: bool = True,
                 title_suffix: str = ""):
        from PIL import Image, ImageDraw

        self.grids = grids
        self.cw, self.ch = width, height
        self.captions = captions
        self.size = sheet_size(grids, width, height, captions)
        base = Image.new("RGB", self.size, BACKGROUND)
        d = ImageDraw.Draw(base)
        font = _font()
        lw = row_label_width(grids)
        cap = CAPTION_H if captions else 0
        self.slots: list[list[list[tuple[int, int]]]] = []
        self.title_boxes: list[tuple[int, int]] = []
        y = 0
        for g in grids:
            self.title_boxes.append((PAD, y + PAD))
            if g.title:
                d.text((PAD, y + PAD), _fit(d, g.title, font, self.size[0] - 2 * PAD),
                       fill=INK, font=font)
            y += TITLE_H
            hh = _header_h(g)
            for c, label in enumerate(g.cols):
                x0 = lw + c * (width + PAD)
                lines = [_fit(d, ln, font, width + PAD - 2) for ln in label.split("\n")]
                for n, ln in enumerate(lines):
                    tw = d.textlength(ln, font=font)
                    d.text((x0 + (width - tw) / 2, y + n * LINE_H), ln, fill=INK, font=font)
            y += hh
            slots = []
            for r, label in enumerate(g.rows):
                lines = _wrap(d, label, font, lw - 2 * PAD)
                ty = y + (height - len(lines) * LINE_H) / 2
                for n, ln in enumerate(lines):
                    d.text((PAD, ty + n * LINE_H), ln, fill=INK, font=font)
                row = []
                for c in range(len(g.cols)):
                    x0 = lw + c * (width + PAD)
                    row.append((x0, y))
                    cell = g.cells[r][c]
                    if captions and cell is not None and cell.short:
                        s = _fit(d, cell.short, font, width)
                        tw = d.textlength(s, font=font)
                        d.text((x0 + (width - tw) / 2, y + height + 1), s,
                               fill=(170, 20, 20) if cell.error else INK, font=font)
                slots.append(row)
                y += height + cap + PAD
            self.slots.append(slots)
        self.base = base
        self.font = font

    def compose(self, images: Sequence[Sequence[Sequence[np.ndarray | None]]] | None = None,
                title: str | None = None) -> np.ndarray:
        """The sheet with `images[g][r][c]` (default: the grids' cell images) pasted in;
        `title` replaces every grid title (the GIF's running time)."""
        from PIL import Image, ImageDraw

        im = self.base.copy()
        if title is not None:
            d = ImageDraw.Draw(im)
            for (x, y), g in zip(self.title_boxes, self.grids):
                label = f"{g.title}   {title}" if g.title else title
                d.text((x, y), _fit(d, label, self.font, self.size[0] - 2 * PAD), fill=INK,
                       font=self.font)
        for gi, g in enumerate(self.grids):
            for r in range(len(g.rows)):
                for c in range(len(g.cols)):
                    img = (images[gi][r][c] if images is not None
                           else (g.cells[r][c].image if g.cells[r][c] is not None else None))
                    if img is None:
                        continue
                    x, y = self.slots[gi][r][c]
                    im.paste(Image.fromarray(np.ascontiguousarray(img), "RGB"), (x, y))
        return np.asarray(im)


@dataclass
class Report:
    plan: ReportPlan
    runs: list[VariantRun]
    grids: list[Grid]
    sheet: np.ndarray
    gif_frames: list[np.ndarray]  # composed GIF frames (empty without --gif)
    timings: dict

