"""Generate the packaged default textures (committed PNGs; rerun to regenerate):

  cloth.png        256x256 woven cloth: two-colour plain weave with thread shading
  height.png       256x256 height map of the same weave (red = green = blue = height)
  cubemap/{posx,negx,posy,negy,posz,negz}.png   128x128 faces: sky above, ground below,
                   horizon on the side faces, each face labelled (+X, -X, ...) with a
                   marker in its first-row / first-column corner (top left of the image)
                   so orientation mistakes are visible.

Usage: python textures/make_textures.py [output folder, default: this folder]
"""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw, ImageFont

N = 256
THREADS = 16  # threads per texture side (wraps seamlessly)


def weave(n=N, k=THREADS):
    x = (np.arange(n) + 0.5) / n * k
    u, v = np.meshgrid(x, x)  # u along columns, v along rows
    iu, iv = np.floor(u).astype(int), np.floor(v).astype(int)
    fu, fv = u - iu, v - iv
    warp_on_top = (iu + iv) % 2 == 0  # plain weave
    # thread profile: rounded across the thread, arching along it
    across_warp = np.sin(np.pi * fu) ** 0.5
    across_weft = np.sin(np.pi * fv) ** 0.5
    arch_warp = 0.6 + 0.4 * np.sin(np.pi * fv)
    arch_weft = 0.6 + 0.4 * np.sin(np.pi * fu)
    h = np.where(warp_on_top, across_warp * arch_warp, across_weft * arch_weft)
    warp = np.array([0.75, 0.18, 0.16])
    weft = np.array([0.95, 0.85, 0.55])
    base = np.where(warp_on_top[..., None], warp, weft)
    # a coarser check every 4 threads makes tiling / uv direction visible
    check = ((iu // 4 + iv // 4) % 2 == 0)[..., None]
    col = base * (0.55 + 0.45 * h[..., None]) * np.where(check, 1.0, 0.8)
    return col, h


def gradient_face(size, kind):
    t = (np.arange(size) + 0.5) / size  # 0 at the first row
    sky_top, sky_hor = np.array([0.15, 0.35, 0.85]), np.array([0.7, 0.85, 1.0])
    gnd_hor, gnd_bot = np.array([0.45, 0.55, 0.25]), np.array([0.3, 0.2, 0.1])
    if kind == "side":
        rows = np.where((t < 0.5)[:, None],
                        sky_top + (sky_hor - sky_top) * (t / 0.5)[:, None],
                        gnd_hor + (gnd_bot - gnd_hor) * ((t - 0.5) / 0.5)[:, None])
        img = np.repeat(rows[:, None, :], size, axis=1)
    else:
        img = np.broadcast_to(sky_top if kind == "top" else gnd_bot, (size, size, 3)).copy()
    return img


def cube_faces(size=128):
    faces = {"posx": ("side", "+X", (255, 60, 60)), "negx": ("side", "-X", (120, 0, 0)),
             "posy": ("top", "+Y", (60, 255, 60)), "negy": ("bottom", "-Y", (0, 120, 0)),
             "posz": ("side", "+Z", (80, 80, 255)), "negz": ("side", "-Z", (0, 0, 130))}
    try:
        font = ImageFont.load_default(size=size // 3)
    except TypeError:
        font = ImageFont.load_default()
    out = {}
    for name, (kind, label, col) in faces.items():
        im = Image.fromarray(np.round(gradient_face(size, kind) * 255).astype(np.uint8))
        d = ImageDraw.Draw(im)
        d.text((size // 2, size // 2), label, fill=(255, 255, 255), font=font, anchor="mm",
               stroke_width=2, stroke_fill=(0, 0, 0))
        m = size // 8  # corner marker at row 0, column 0 (t = 0, s = 0)
        d.rectangle([0, 0, m, m], fill=col)
        out[name] = im
    return out


def main(folder=None):
    folder = Path(folder) if folder else Path(__file__).resolve().parent
    (folder / "cubemap").mkdir(parents=True, exist_ok=True)
    col, h = weave()
    Image.fromarray(np.round(np.clip(col, 0, 1) * 255).astype(np.uint8)).save(
        folder / "cloth.png", optimize=True)
    g = np.round(np.clip(h, 0, 1) * 255).astype(np.uint8)
    Image.fromarray(np.stack([g, g, g], axis=-1)).save(folder / "height.png", optimize=True)
    for name, im in cube_faces().items():
        im.save(folder / "cubemap" / f"{name}.png", optimize=True)


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else None)
