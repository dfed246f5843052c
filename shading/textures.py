"""Texture loading (cached per path) and numba sampling helpers (SPEC section 5).

Images become float64 (h, w, 3) arrays of 8-bit values / 255; the first image row is
v = 0, texel centres at ((i + 0.5) / w, (j + 0.5) / h), bilinear in floating point.
A cube map is (6, s, s, 3) in the order posx, negx, posy, negy, posz, negz.
"""
from __future__ import annotations

import math
import threading
from pathlib import Path

import numpy as np
from clothjit import STAGE, njit

CUBE_FACES = ("posx", "negx", "posy", "negy", "posz", "negz")
DEFAULT_TEXTURE = "cloth.png"
DEFAULT_HEIGHT_MAP = "height.png"
DEFAULT_CUBEMAP = "cubemap"
_EXTS = (".png", ".jpg", ".jpeg", ".bmp", ".tga", ".tif", ".tiff")


class TextureError(Exception):
    """A texture / height map / cube map that is missing or unreadable (path in message)."""


_cache: dict = {}
_lock = threading.Lock()


def packaged_textures_dir() -> Path:
    """Folder of the packaged default textures: the repository's `textures/`, installed as
    the data package `shading.default_textures` (see pyproject.toml)."""
    try:
        from importlib.resources import files

        return Path(str(files("shading.default_textures")))
    except ModuleNotFoundError:  # running from a source tree that was never installed
        return Path(__file__).resolve().parent.parent / "textures"


def _read_rgb(path: Path) -> np.ndarray:
    from PIL import Image, UnidentifiedImageError
    try:
        with Image.open(path) as im:
            im.load()
            if im.mode in ("I;16", "I;16B", "I;16L", "I", "F"):
                arr = np.asarray(im, dtype=np.float64)
                arr = arr / (65535.0 if im.mode.startswith("I;16") else max(arr.max(), 1.0))
                arr = np.repeat(arr[:, :, None], 3, axis=2)
                return np.ascontiguousarray(arr)
            arr = np.asarray(im.convert("RGB"), dtype=np.float64) / 255.0
    except FileNotFoundError:
        raise TextureError(f"texture file not found: {path}") from None
    except IsADirectoryError:
        raise TextureError(f"texture path is a folder, expected an image: {path}") from None
    except (UnidentifiedImageError, OSError, ValueError) as e:
        raise TextureError(f"cannot read texture image {path}: {e}") from None
    if arr.shape[0] < 1 or arr.shape[1] < 1:
        raise TextureError(f"texture image is empty: {path}")
    return np.ascontiguousarray(arr)


def _key(path) -> Path:
    p = Path(path)
    try:
        return p.resolve()
    except OSError:
        return p.absolute()


def load_texture(path) -> np.ndarray:
    """(h, w, 3) float64 in [0, 1]; cached per resolved path (arrays are read-only)."""
    key = ("tex", _key(path))
    with _lock:
        if key in _cache:
            return _cache[key]
    arr = _read_rgb(Path(path))
    arr.flags.writeable = False
    with _lock:
        _cache[key] = arr
    return arr


def _face_file(folder: Path, face: str) -> Path:
    for ext in _EXTS:
        p = folder / (face + ext)
        if p.is_file():
            return p
    return folder / (face + ".png")


def load_cubemap(folder) -> np.ndarray:
    """(6, s, s, 3) float64 from `folder`/{posx,negx,posy,negy,posz,negz}.png."""
    folder = Path(folder)
    key = ("cube", _key(folder))
    with _lock:
        if key in _cache:
            return _cache[key]
    if not folder.is_dir():
        raise TextureError(f"cube map folder not found: {folder} "
                           f"(expected {', '.join(f + '.png' for f in CUBE_FACES)})")
    faces = [_read_rgb(_face_file(folder, f)) for f in CUBE_FACES]
    s = faces[0].shape
    for f, a in zip(CUBE_FACES, faces):
        if a.shape != s or a.shape[0] != a.shape[1]:
            raise TextureError(f"cube map faces in {folder} must be square and of one size; "
                               f"{f} is {a.shape[1]}x{a.shape[0]}, posx {s[1]}x{s[0]}")
    arr = np.ascontiguousarray(np.stack(faces))
    arr.flags.writeable = False
    with _lock:
        _cache[key] = arr
    return arr


def clear_cache():
    with _lock:
        _cache.clear()
        _defaults.clear()


_defaults: dict = {}


def resolve(kind: str, value):
    """Array for a texture slot: `value` is None (packaged default), a path or an array."""
    if value is None:  # the packaged defaults: looked up once (no file system per frame)
        a = _defaults.get(kind)
        if a is None:
            a = _defaults[kind] = _resolve(kind, None)
        return a
    return _resolve(kind, value)


def _resolve(kind: str, value):
    if value is not None and not isinstance(value, (str, Path)):
        a = np.ascontiguousarray(value, dtype=np.float64)
        want = 4 if kind == "cubemap" else 3
        if a.ndim != want or a.shape[-1] != 3:
            raise TextureError(f"{kind} array must have shape {'(6,s,s,3)' if want == 4 else '(h,w,3)'}")
        a = a.view()
        a.flags.writeable = False  # one numba type for every texture
        return a
    if kind == "cubemap":
        return load_cubemap(value if value is not None
                            else packaged_textures_dir() / DEFAULT_CUBEMAP)
    default = DEFAULT_TEXTURE if kind == "texture" else DEFAULT_HEIGHT_MAP
    return load_texture(value if value is not None else packaged_textures_dir() / default)


# --------------------------------------------------------------------------- sampling

@njit(cache=True, inline="always")
def bilinear(img, u, v, repeat):
    """Bilinear sample of img (h, w, 3) at (u, v); repeat=True wraps, False clamps."""
    h = img.shape[0]
    w = img.shape[1]
    x = u * w - 0.5
    y = v * h - 0.5
    xf = math.floor(x)
    yf = math.floor(y)
    fx = x - xf
    fy = y - yf
    i0, j0 = np.int64(xf), np.int64(yf)
    i1, j1 = i0 + 1, j0 + 1
    # Wrap or clamp written out, not a helper: numba's inliner copies a helper's IR at every
    # call (4 per sample, 12 for bump: most of its first compile).
    if repeat:  # the modulo only when needed: an integer division
        if i0 < 0 or i1 >= w:
            i0, i1 = i0 % w, i1 % w
        if j0 < 0 or j1 >= h:
            j0, j1 = j0 % h, j1 % h
    else:
        i0, i1 = min(max(i0, 0), w - 1), min(max(i1, 0), w - 1)
        j0, j1 = min(max(j0, 0), h - 1), min(max(j1, 0), h - 1)
    w00 = (1.0 - fx) * (1.0 - fy)
    w10 = fx * (1.0 - fy)
    w01 = (1.0 - fx) * fy
    w11 = fx * fy
    r = w00 * img[j0, i0, 0] + w10 * img[j0, i1, 0] + w01 * img[j1, i0, 0] + w11 * img[j1, i1, 0]
    g = w00 * img[j0, i0, 1] + w10 * img[j0, i1, 1] + w01 * img[j1, i0, 1] + w11 * img[j1, i1, 1]
    b = w00 * img[j0, i0, 2] + w10 * img[j0, i1, 2] + w01 * img[j1, i0, 2] + w11 * img[j1, i1, 2]
    return (r, g, b)


@njit(cache=True, inline="always")
def cube_face_st(d):
    """OpenGL cube-map face selection: (face index posx..negz, s, t) for direction d."""
    x, y, z = d
    ax, ay, az = abs(x), abs(y), abs(z)
    if ax >= ay and ax >= az:
        if x >= 0.0:
            return 0, (-z / ax + 1.0) * 0.5, (-y / ax + 1.0) * 0.5
        return 1, (z / ax + 1.0) * 0.5, (-y / ax + 1.0) * 0.5
    if ay >= az:
        if y >= 0.0:
            return 2, (x / ay + 1.0) * 0.5, (z / ay + 1.0) * 0.5
        return 3, (x / ay + 1.0) * 0.5, (-z / ay + 1.0) * 0.5
    if z >= 0.0:
        return 4, (x / az + 1.0) * 0.5, (-y / az + 1.0) * 0.5
    return 5, (-x / az + 1.0) * 0.5, (-y / az + 1.0) * 0.5


@njit(**STAGE, no_cpython_wrapper=True)
def sample_cube(cube, d):
    """Cube map (6, s, s, 3) along direction d: bilinear within the face, clamped."""
    if d[0] == 0.0 and d[1] == 0.0 and d[2] == 0.0:
        return (0.0, 0.0, 0.0)
    f, s, t = cube_face_st(d)
    return bilinear(cube[f], s, t, False)
