"""Output writers: GIF, MP4, PNG, PNG folder, OBJ per frame, NPZ.

Every writer is atomic: it writes into a temporary file (or folder) beside its target
and renames it into place in `commit()`. `abort()` (called on any error, including
KeyboardInterrupt) removes everything the writer created, so a failed run never leaves a
partial output behind. Writers are opened before the simulation starts, which also
proves the target directory is writable.

Writers that take images stream them: `add(image)` encodes (MP4, PNG, folder) or spools
(GIF) the frame at once, so peak memory does not grow with the number of frames.

Life cycle, for every writer:

    w = GifWriter(path, fps=25)      # validates the path, creates the temp file
    w.add(frame)                     # (H, W, 3) uint8, in output-frame order
    ...
    w.commit()                       # finalises and renames into place
    # or, on any failure:  w.abort()
"""
from __future__ import annotations

import contextlib
import errno
import io
import math
import os
import re
import shutil
import subprocess
import tempfile
import threading
from collections import deque
from concurrent.futures import ThreadPoolExecutor
from fractions import Fraction
from pathlib import Path
from typing import Sequence

import numpy as np

__all__ = [
    "OutputError",
    "WriteError",
    "atomic_file",
    "OUTPUT_KINDS",
    "classify_output",
    "gif_delays_cs",
    "GifWriter",
    "Mp4Writer",
    "PngWriter",
    "FolderWriter",
    "ObjWriter",
    "NpzWriter",
    "write_png",
    "write_obj",
    "diff_image",
]

OUTPUT_KINDS = ("gif", "mp4", "png", "dir")
FRAME_NAME = "frame_{:05d}"
_FRAME_RE = re.compile(r"^frame_\d{5,}\.(png|obj)$")
GIF_MAX_FPS = 50.0


class OutputError(ValueError):
    """A bad output path or option (exit status 2). `str(err)` is a one-line message."""


class WriteError(Exception):
    """An output could not be written (full disk, I/O error...; exit status 1).

    `str(err)` is one line naming the reason and the file the user asked for:
    "no space left on device writing /abs/x.gif"."""

    def __init__(self, target: str | os.PathLike, reason: str):
        self.target = Path(os.path.abspath(os.fspath(target)))
        self.reason = reason
        super().__init__(f"{reason} writing {self.target}")

    @classmethod
    def from_oserror(cls, target: str | os.PathLike, exc: OSError) -> "WriteError":
        reason = exc.strerror or (os.strerror(exc.errno) if exc.errno else str(exc)) or "error"
        return cls(target, reason[:1].lower() + reason[1:])


@contextlib.contextmanager
def _writing(target: Path):
    """Turn an OSError raised while writing `target` (or its temporary) into a WriteError."""
    try:
        yield
    except OSError as exc:
        raise WriteError.from_oserror(target, exc) from exc


@contextlib.contextmanager
def atomic_file(target: str | os.PathLike):
    """`with atomic_file("x.csv") as tmp: write tmp` - written beside the target, renamed
    into place at the end, removed on any error or interrupt; OSError -> WriteError."""
    target = Path(target)
    tmp = _tempfile_beside(target)
    try:
        with _writing(target):
            yield tmp
            os.replace(tmp, target)
    except BaseException:
        _remove(tmp)
        raise


# --------------------------------------------------------------------------- paths


def classify_output(path: str | os.PathLike) -> tuple[str, Path]:
    """Return (kind, Path) for an --out argument; kind is one of OUTPUT_KINDS.

    A path ending in a separator, or naming an existing folder, is a folder of PNGs;
    otherwise the extension decides (.gif, .mp4, .png, case-insensitive).
    """
    text = os.fspath(path)
    if not text:
        raise OutputError("empty output path")
    p = Path(text)
    if text.endswith(("/", os.sep)) or p.is_dir():
        return "dir", p
    ext = p.suffix.lower()
    if ext in (".gif", ".mp4", ".png"):
        return ext[1:], p
    raise OutputError(
        f"cannot write '{text}': unknown output type '{ext or '(no extension)'}' "
        "(use .gif, .mp4, .png, or a folder path ending in '/')"
    )


def _parent_dir(target: Path) -> Path:
    parent = target.parent if str(target.parent) else Path(".")
    if not parent.exists():
        raise OutputError(f"cannot write '{target}': directory '{parent}' does not exist")
    if not parent.is_dir():
        raise OutputError(f"cannot write '{target}': '{parent}' is not a directory")
    return parent


def _check_file_target(target: Path) -> Path:
    if target.is_dir():
        raise OutputError(f"cannot write '{target}': it is a directory")
    return _parent_dir(target)


def _umask() -> int:
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def _tempfile_beside(target: Path) -> Path:
    parent = _check_file_target(target)
    try:
        fd, name = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".part", dir=parent)
    except OSError as exc:
        raise OutputError(f"cannot write '{target}': {exc.strerror or exc}") from None
    os.close(fd)
    os.chmod(name, 0o666 & ~_umask())  # mkstemp makes 0600; outputs get the usual mode
    return Path(name)


def _tempdir_beside(target: Path) -> Path:
    target = Path(os.fspath(target).rstrip("/" + os.sep) or ".")
    if target.exists() and not target.is_dir():
        raise OutputError(f"cannot write folder '{target}': a file of that name exists")
    parent = _parent_dir(target)
    try:
        name = tempfile.mkdtemp(prefix=f".{target.name}.", suffix=".part", dir=parent)
    except OSError as exc:
        raise OutputError(f"cannot write '{target}': {exc.strerror or exc}") from None
    os.chmod(name, 0o777 & ~_umask())
    return Path(name)


def _remove(path: Path | None) -> None:
    if path is None:
        return
    try:
        if path.is_dir() and not path.is_symlink():
            shutil.rmtree(path, ignore_errors=True)
        else:
            path.unlink(missing_ok=True)
    except OSError:
        pass


def _commit_dir(tmp: Path, target: Path) -> None:
    """Move a finished temp folder into place.

    New or empty target: one rename. Existing folder with files: our frame files
    (frame_NNNNN.png / .obj) from an earlier run are removed, the new ones moved in one
    by one (each an atomic rename); other files in the folder are left alone.
    """
    target = Path(os.fspath(target).rstrip("/" + os.sep) or ".")
    if not target.exists():
        os.rename(tmp, target)
        return
    if target.is_dir() and not any(target.iterdir()):
        target.rmdir()
        os.rename(tmp, target)
        return
    new = {p.name for p in tmp.iterdir()}
    for old in target.iterdir():
        if _FRAME_RE.match(old.name) and old.name not in new and old.is_file():
            old.unlink()
    for name in sorted(new):
        os.replace(tmp / name, target / name)
    tmp.rmdir()


class _Atomic:
    """Base: a temporary path beside the target, renamed on commit, removed on abort."""

    is_dir = False

    def __init__(self, target: str | os.PathLike):
        self.target = Path(target)
        self.tmp: Path | None = (
            _tempdir_beside(self.target) if self.is_dir else _tempfile_beside(self.target)
        )
        self.count = 0
        self.closed = False

    def _add(self, *items) -> None:  # write one frame; subclasses override
        raise NotImplementedError

    def _finish(self) -> None:  # write trailers; subclasses override
        pass

    def _close_handles(self) -> None:  # release files/processes; subclasses override
        pass

    def add(self, *items) -> None:
        """Add one frame; an OSError becomes a WriteError naming the target."""
        with _writing(self.target):
            self._add(*items)

    def commit(self) -> Path:
        if self.closed:
            raise RuntimeError("writer already closed")
        try:
            with _writing(self.target):
                self._finish()
                self._close_handles()
                assert self.tmp is not None
                if self.is_dir:
                    _commit_dir(self.tmp, self.target)
                else:
                    os.replace(self.tmp, self.target)
            self.tmp = None
        except BaseException:
            self.abort()
            raise
        self.closed = True
        return self.target

    def abort(self) -> None:
        if self.closed:
            return
        self.closed = True
        try:
            self._close_handles()
        except BaseException:  # noqa: BLE001 - cleanup must not mask the original error
            pass
        _remove(self.tmp)
        self.tmp = None

    def __enter__(self):
        return self

    def __exit__(self, exc_type, exc, tb):
        if exc_type is None:
            if not self.closed:
                self.commit()
        else:
            self.abort()
        return False

    @property
    def nbytes(self) -> int:
        """Size on disk of the committed output (files: bytes; folders: sum)."""
        p = self.target
        if p.is_dir():
            return sum(f.stat().st_size for f in p.iterdir() if f.is_file())
        return p.stat().st_size if p.exists() else 0


def _check_image(image: np.ndarray, shape: tuple[int, int] | None) -> np.ndarray:
    image = np.asarray(image)
    if image.dtype != np.uint8 or image.ndim != 3 or image.shape[2] != 3:
        raise ValueError(f"expected an (H, W, 3) uint8 image, got {image.dtype} {image.shape}")
    if shape is not None and image.shape[:2] != shape:
        raise ValueError(f"frame size changed from {shape} to {image.shape[:2]}")
    return np.ascontiguousarray(image)


# --------------------------------------------------------------------------- PNG


def write_png(path: str | os.PathLike, image: np.ndarray, compress_level: int = 6) -> None:
    """Write one RGB PNG (not atomic by itself: use PngWriter for that)."""
    from PIL import Image

    Image.fromarray(_check_image(image, None), "RGB").save(
        path, format="PNG", compress_level=compress_level
    )


class PngWriter(_Atomic):
    """A single PNG. `add` keeps only the latest image; `commit` writes it."""

    def __init__(self, target):
        super().__init__(target)
        self.image: np.ndarray | None = None

    def _add(self, image: np.ndarray) -> None:
        self.image = _check_image(image, None).copy()
        self.count += 1

    def _finish(self) -> None:
        if self.image is None:
            raise RuntimeError("no frame was rendered")
        write_png(self.tmp, self.image)


class FolderWriter(_Atomic):
    """Numbered PNGs frame_00000.png, frame_00001.png, ... in a folder."""

    is_dir = True

    def __init__(self, target, compress_level: int = 6):
        super().__init__(target)
        self.shape = None
        self.compress_level = compress_level

    def _add(self, image: np.ndarray) -> None:
        image = _check_image(image, self.shape)
        self.shape = image.shape[:2]
        write_png(self.tmp / (FRAME_NAME.format(self.count) + ".png"), image, self.compress_level)
        self.count += 1


# --------------------------------------------------------------------------- MP4


class Mp4Writer(_Atomic):
    """H.264 / yuv420p MP4, frames streamed to the stdin of imageio-ffmpeg's ffmpeg, run as
    our own child process: `abort` kills it and waits for it.

    yuv420p needs even width and height: an odd size is padded by one row/column that
    repeats the last one (edge padding), never rescaled. `padded` tells whether it was.
    """

    def __init__(self, target, fps: float = 30.0, crf: int = 18, preset: str = "medium"):
        if not (fps > 0 and math.isfinite(fps)):
            raise OutputError(f"bad frame rate {fps} for MP4")
        super().__init__(target)
        self.fps = fps
        self.crf = crf
        self.preset = preset
        self._proc: subprocess.Popen | None = None
        self.shape = None
        self.padded_shape = None

    @property
    def padded(self) -> bool:
        return self.shape is not None and self.shape != self.padded_shape

    def _start(self, h: int, w: int) -> None:
        import imageio_ffmpeg

        ph, pw = h + (h & 1), w + (w & 1)
        self.padded_shape = (ph, pw)
        fps = Fraction(self.fps).limit_denominator(100000)
        cmd = [imageio_ffmpeg.get_ffmpeg_exe(), "-y", "-f", "rawvideo", "-vcodec", "rawvideo",
               "-s", f"{pw}x{ph}", "-pix_fmt", "rgb24", "-r", str(fps), "-i", "-",
               "-vcodec", "libx264", "-pix_fmt", "yuv420p", "-v", "error",
               "-crf", str(self.crf), "-preset", self.preset, "-movflags", "+faststart",
               "-f", "mp4", str(self.tmp)]
        # Its own session: a Ctrl-C at the terminal reaches only us, and we stop it.
        self._proc = subprocess.Popen(cmd, stdin=subprocess.PIPE, stdout=subprocess.DEVNULL,
                                      stderr=subprocess.PIPE, start_new_session=True)
        self._stderr = []
        self._reader = threading.Thread(target=self._read_stderr, name="ffmpeg-stderr",
                                        daemon=True)
        self._reader.start()

    def _read_stderr(self) -> None:
        for line in self._proc.stderr:
            self._stderr.append(line.decode("utf-8", "replace").strip())

    def _failed(self, exc: BaseException | None) -> OSError:
        """The error to report when ffmpeg stopped taking frames or failed: its reason
        when ffmpeg names a system error (e.g. no space left on device)."""
        self._proc.wait()
        self._reader.join()
        text = " ".join(self._stderr)
        for code in (errno.ENOSPC, errno.EDQUOT, errno.EFBIG, errno.EROFS, errno.EIO,
                     errno.EACCES):
            if os.strerror(code) in text:
                return OSError(code, os.strerror(code))
        last = self._stderr[-1] if self._stderr else (str(exc) if exc else "")
        return OSError(errno.EIO, f"ffmpeg failed (exit status {self._proc.returncode}"
                                  f"{': ' + last if last else ''})")

    def _add(self, image: np.ndarray) -> None:
        image = _check_image(image, self.shape)
        if self._proc is None:
            self.shape = image.shape[:2]
            self._start(*self.shape)
        if self.padded:
            ph, pw = self.padded_shape
            image = np.pad(image, ((0, ph - image.shape[0]), (0, pw - image.shape[1]), (0, 0)),
                           mode="edge")
        try:
            self._proc.stdin.write(np.ascontiguousarray(image).tobytes())
        except BrokenPipeError as exc:
            raise self._failed(exc) from None
        self.count += 1

    def _finish(self) -> None:
        if self._proc is None:
            raise RuntimeError("no frame was rendered")
        try:
            self._proc.stdin.close()  # ffmpeg finishes the file and exits
        except BrokenPipeError:
            pass
        if self._proc.wait() != 0:
            raise self._failed(None)
        self._reader.join()
        self._proc.stderr.close()
        self._proc = None

    def _close_handles(self) -> None:
        """On abort: kill ffmpeg and wait for it (no process is left behind)."""
        proc, self._proc = self._proc, None
        if proc is not None:
            proc.kill()
            proc.wait()
            for pipe in (proc.stdin, proc.stderr):
                try:
                    pipe.close()
                except OSError:
                    pass


# --------------------------------------------------------------------------- GIF


def gif_delays_cs(n: int, fps: float) -> list[int]:
    """Per-frame GIF delays in centiseconds (GIF's unit) for n frames at fps.

    Frame k is shown from round(100 k / fps) to round(100 (k+1) / fps) cs, so the delays
    add up to the exact duration (to 10 ms) even when 100/fps is not an integer:
    30 fps gives 3, 4, 3, 3, 4, 3, ... cs.
    """
    r = Fraction(fps).limit_denominator(100000)
    edges = [math.floor(Fraction(100 * k) / r + Fraction(1, 2)) for k in range(n + 1)]
    return [max(1, b - a) for a, b in zip(edges[:-1], edges[1:])]


def _palette_from_pixels(pixels: np.ndarray, colors: int = 256, kmeans: int = 0) -> np.ndarray:
    """Median-cut palette (colors, 3) uint8 for an (M, 3) uint8 pixel sample."""
    from PIL import Image

    pixels = np.ascontiguousarray(pixels.reshape(-1, 1, 3))
    im = Image.fromarray(pixels, "RGB").quantize(colors, method=Image.Quantize.MEDIANCUT,
                                                 kmeans=kmeans)
    pal = np.array(im.getpalette()[: 3 * colors], np.uint8).reshape(-1, 3)
    used = np.unique(np.asarray(im))
    return pal[used]


def _quantize(image: np.ndarray, palette: np.ndarray, dither: bool) -> np.ndarray:
    """Map an RGB image onto a palette -> (H, W) uint8 indices (Pillow's mapping)."""
    from PIL import Image

    pal_im = Image.new("P", (1, 1))
    flat = np.zeros((256, 3), np.uint8)
    flat[: len(palette)] = palette
    # Unused entries repeat colour 0 so the mapper never picks a bogus black.
    flat[len(palette):] = palette[0]
    pal_im.putpalette(flat.tobytes())
    q = Image.fromarray(image, "RGB").quantize(
        palette=pal_im, dither=Image.Dither.FLOYDSTEINBERG if dither else Image.Dither.NONE)
    idx = np.array(q, np.uint8)
    idx[idx >= len(palette)] = 0  # padding entries are copies of colour 0
    return idx


def _changed(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(H, W) bool: where two (H, W) or (H, W, 3) uint8 arrays differ (fast for RGB)."""
    if a.ndim == 2:
        return a != b
    x = a ^ b
    return (x[..., 0] | x[..., 1] | x[..., 2]) != 0


def _lzw_frame(indices: np.ndarray, palette: np.ndarray, box, delay_cs: int,
               local_palette: bool) -> bytes:
    """GIF graphic control extension + image descriptor (+ local table) + LZW data.

    Pillow's public `GifImagePlugin.getdata` does the LZW coding of one frame.
    """
    from PIL import GifImagePlugin, Image

    x0, y0, x1, y1 = box
    sub = np.ascontiguousarray(indices[y0:y1, x0:x1])
    im = Image.fromarray(sub, "P")
    pal = np.zeros((1 << max(1, math.ceil(math.log2(max(2, len(palette))))), 3), np.uint8)
    pal[: len(palette)] = palette
    im.putpalette(pal.tobytes())
    # Delays are given in ms to Pillow, which stores int(ms / 10) cs.
    chunks = GifImagePlugin.getdata(im, offset=(x0, y0), duration=delay_cs * 10,
                                    disposal=1, include_color_table=local_palette,
                                    interlace=False)
    return b"".join(chunks)


def _gif_header(width: int, height: int, palette: np.ndarray | None, loop: int = 0) -> bytes:
    out = bytearray(b"GIF89a")
    out += width.to_bytes(2, "little") + height.to_bytes(2, "little")
    if palette is not None:
        bits = max(1, math.ceil(math.log2(max(2, len(palette)))))
        table = np.zeros((1 << bits, 3), np.uint8)
        table[: len(palette)] = palette
        out += bytes([0x80 | 0x70 | (bits - 1), 0, 0]) + table.tobytes()
    else:
        out += bytes([0x70, 0, 0])
    # NETSCAPE2.0 application extension: loop count (0 = forever).
    out += b"!\xff\x0bNETSCAPE2.0\x03\x01" + loop.to_bytes(2, "little") + b"\x00"
    return bytes(out)


class GifWriter(_Atomic):
    """Animated GIF, looping forever, delays in 10 ms units summing to the duration.

    palette="global" (default): one 256-colour palette for the whole animation
    (median cut refined by 3 k-means passes) built from a sample of 8192 pixels of every
    frame; frames are spooled to a raw temporary file beside the target (H*W*3 bytes
    per frame, on disk, not in memory) and quantised in a second pass at commit.
    palette="frame": an adaptive palette per frame (local colour tables), one pass.

    dither="stable" (default): Floyd-Steinberg error diffusion, made temporally stable:
    a pixel whose rendered colour did not change since the previous frame keeps its
    previous palette index, so static parts never shimmer. "fs": plain Floyd-Steinberg
    on every frame; "none": nearest colour. See docs/cli.md for the measurements.

    Frames after the first are stored as the rectangle that changed since the previous
    frame (disposal "do not dispose"); an unchanged frame is kept as a 1x1 rectangle so
    the frame count and every delay stay exactly as requested.
    """

    SAMPLE_PER_FRAME = 8192  # pixels per frame fed to the palette builder
    SAMPLE_CAP = 1 << 20  # at most this many sampled pixels in memory (3 MB)
    KMEANS = 3
    QUANTIZE_AHEAD = 4  # frames quantised ahead of the one being written

    def __init__(self, target, fps: float = 25.0, palette: str = "global",
                 dither: str = "stable", loop: int = 0):
        if palette not in ("global", "frame"):
            raise ValueError("palette must be 'global' or 'frame'")
        if dither not in ("stable", "fs", "none"):
            raise ValueError("dither must be 'stable', 'fs' or 'none'")
        if not (0 < fps <= GIF_MAX_FPS):
            raise OutputError(
                f"--fps {fps:g} is not possible for a GIF: delays are counted in 10 ms and "
                f"browsers slow delays under 20 ms to 100 ms; use at most {GIF_MAX_FPS:g}")
        super().__init__(target)
        self.fps = fps
        self.palette_mode = palette
        self.dither = dither
        self.loop = loop
        self.shape = None
        self._fh = open(self.tmp, "wb")
        self._spool_path: Path | None = None
        self._spool = None
        self._samples: list[np.ndarray] = []
        self._n_samples = 0
        self._decimate = 1
        self._prev_rgb: np.ndarray | None = None
        self._prev_src: np.ndarray | None = None
        self._prev_idx: np.ndarray | None = None
        self._delays: list[int] = []
        self._rng = np.random.default_rng(0)

    # frame-palette mode writes frames as they come; the delay of frame k is only known
    # from its index, so delays are computed for a growing n (prefix-stable).
    def _delay(self, k: int) -> int:
        r = Fraction(self.fps).limit_denominator(100000)
        a = math.floor(Fraction(100 * k) / r + Fraction(1, 2))
        b = math.floor(Fraction(100 * (k + 1)) / r + Fraction(1, 2))
        return max(1, b - a)

    def _sample(self, image: np.ndarray) -> np.ndarray:
        flat = image.reshape(-1, 3)
        if len(flat) <= self.SAMPLE_PER_FRAME:
            return flat.copy()
        step = len(flat) / self.SAMPLE_PER_FRAME
        idx = (np.arange(self.SAMPLE_PER_FRAME) * step).astype(np.int64)
        return flat[idx]

    def _add(self, image: np.ndarray) -> None:
        image = _check_image(image, self.shape)
        if self.shape is None:
            self.shape = image.shape[:2]
            if self.palette_mode == "frame":
                self._fh.write(_gif_header(self.shape[1], self.shape[0], None, self.loop))
        if self.palette_mode == "global":
            if self._spool is None:
                fd, name = tempfile.mkstemp(prefix=f".{self.target.name}.", suffix=".frames",
                                            dir=self.tmp.parent)
                self._spool_path = Path(name)
                self._spool = os.fdopen(fd, "wb")
            self._spool.write(image.tobytes())
            self._samples.append(self._sample(image)[:: self._decimate])
            self._n_samples += len(self._samples[-1])
            if self._n_samples > self.SAMPLE_CAP:
                # Keep memory flat for long animations: halve every frame's share.
                self._samples = [np.concatenate(self._samples)[::2]]
                self._n_samples = len(self._samples[0])
                self._decimate *= 2
        else:
            pal = _palette_from_pixels(image, kmeans=self.KMEANS)  # the whole frame
            self._emit(image, pal, local=True)
        self.count += 1

    def _emit(self, image: np.ndarray, palette: np.ndarray, local: bool,
              idx: np.ndarray | None = None) -> None:
        """Write one frame; `idx`: its quantised indices, if already computed."""
        if idx is None:
            idx = _quantize(image, palette, self.dither != "none")
        if self.dither == "stable" and not local:
            if self._prev_idx is not None:
                same = ~_changed(image, self._prev_src)
                idx[same] = self._prev_idx[same]
            self._prev_src, self._prev_idx = image, idx
        # Global palette: entries are unique, so equal indices mean equal colours.
        key = palette[idx] if local else idx
        h, w = idx.shape
        if self._prev_rgb is None:
            box = (0, 0, w, h)
        else:
            changed = _changed(key, self._prev_rgb)
            rows = np.flatnonzero(changed.any(axis=1))
            if len(rows) == 0:
                box = (0, 0, 1, 1)  # unchanged: a 1x1 rectangle keeps the frame and delay
            else:
                cols = np.flatnonzero(changed.any(axis=0))
                box = (int(cols[0]), int(rows[0]), int(cols[-1]) + 1, int(rows[-1]) + 1)
        k = len(self._delays)
        self._delays.append(self._delay(k))
        self._fh.write(_lzw_frame(idx, palette, box, self._delays[-1], local))
        self._prev_rgb = key

    def _finish(self) -> None:
        if self.count == 0:
            raise RuntimeError("no frame was rendered")
        if self.palette_mode == "global":
            self._spool.close()
            pal = _palette_from_pixels(np.concatenate(self._samples), kmeans=self.KMEANS)
            self._samples = []
            h, w = self.shape
            self._fh.write(_gif_header(w, h, pal, self.loop))
            frame_bytes = h * w * 3
            dither = self.dither != "none"
            # Pillow quantises without the GIL: QUANTIZE_AHEAD frames are quantised in
            # threads while the frames before them are written, in order
            with open(self._spool_path, "rb") as spool, \
                    ThreadPoolExecutor(min(2, os.cpu_count() or 1)) as pool:
                pending: deque = deque()
                for k in range(self.count + self.QUANTIZE_AHEAD):
                    if k < self.count:
                        buf = spool.read(frame_bytes)
                        image = np.frombuffer(buf, np.uint8).reshape(h, w, 3).copy()
                        pending.append((image, pool.submit(_quantize, image, pal, dither)))
                    if k >= self.QUANTIZE_AHEAD:
                        image, idx = pending.popleft()
                        self._emit(image, pal, local=False, idx=idx.result())
            _remove(self._spool_path)
            self._spool_path = None
        self._fh.write(b";")
        self._fh.close()

    def _close_handles(self) -> None:
        for fh in (self._fh, self._spool):
            if fh is not None and not fh.closed:
                fh.close()
        _remove(self._spool_path)
        self._spool_path = None


# --------------------------------------------------------------------------- meshes


def _obj_text(meshes: Sequence, names: Sequence[str]) -> str:
    """One OBJ text: every mesh its own `o` group with v, vt, vn and f v/vt/vn."""
    out = io.StringIO()
    out.write("# clothpipe frame: v, vt, vn exactly as rendered\n")
    base = 1
    for mesh, name in zip(meshes, names):
        pos = np.asarray(mesh.positions, np.float64).reshape(-1, 3)
        nrm = np.asarray(mesh.normals, np.float64).reshape(-1, 3)
        uv = np.asarray(mesh.uvs, np.float64).reshape(-1, 2)
        tri = np.asarray(mesh.triangles, np.int64).reshape(-1, 3)
        out.write(f"o {name}\n")
        np.savetxt(out, pos, fmt="v %.9g %.9g %.9g")
        np.savetxt(out, uv, fmt="vt %.9g %.9g")
        np.savetxt(out, nrm, fmt="vn %.9g %.9g %.9g")
        f = np.repeat(tri + base, 3, axis=1)
        np.savetxt(out, f, fmt="f %d/%d/%d %d/%d/%d %d/%d/%d")
        base += len(pos)
    return out.getvalue()


def mesh_names(meshes: Sequence, scene=None) -> list[str]:
    """Group names: a mesh's own `name` if it has one, else cloth, sphere_i, plane_i.

    Meshes come as the cloth, then the spheres, then the planes (pipeline.run.frames order).
    """
    names = [getattr(m, "name", None) for m in meshes]
    if all(isinstance(n, str) and n for n in names) and len(set(names)) == len(names):
        return names
    generated = ["cloth"]
    if scene is not None:
        from pipeline.scene import Plane, Sphere

        spheres = sum(isinstance(c, Sphere) for c in scene.colliders)
        planes = sum(isinstance(c, Plane) for c in scene.colliders)
        generated += [f"sphere_{i}" for i in range(spheres)]
        generated += [f"plane_{i}" for i in range(planes)]
    if len(generated) != len(meshes):
        generated = ["cloth"] + [f"object_{i}" for i in range(1, len(meshes))]
    return generated


def write_obj(path: str | os.PathLike, meshes: Sequence, names: Sequence[str]) -> None:
    with open(path, "w", encoding="ascii", newline="\n") as fh:
        fh.write(_obj_text(meshes, names))


class ObjWriter(_Atomic):
    """One OBJ per output frame (frame_00000.obj, ...) in a folder."""

    is_dir = True

    def _add(self, meshes: Sequence, names: Sequence[str]) -> None:
        write_obj(self.tmp / (FRAME_NAME.format(self.count) + ".obj"), meshes, names)
        self.count += 1


class NpzWriter(_Atomic):
    """Positions of every output frame plus faces, uv and times, in one .npz.

    Arrays: positions (F, N, 3) float64, times (F,) output times in seconds,
    sim_times (F,) times of the simulator frames shown, sim_frames (F,) their indices,
    faces (T, 3) int32 cloth triangles, uv (N, 2) float64, grid (2,) = (nh, nw), (0, 0)
    for a mesh cloth, which also has face_uv (T, 3, 2), the uv of each face corner; and
    what `render` adds by set_meta: fps, sim_fps, steps_per_frame and the scene record
    that `render --from` reads (pipeline.run.shotfile: npz_format, scene_*, framing_*).
    Positions are kept in memory (N * 24 bytes per frame) until commit.
    """

    def __init__(self, target):
        super().__init__(target)
        self.positions: list[np.ndarray] = []

    def _add(self, positions: np.ndarray) -> None:
        self.positions.append(np.array(positions, np.float64, copy=True).reshape(-1, 3))
        self.count += 1

    def set_meta(self, **arrays) -> None:
        self.meta = arrays

    def _finish(self) -> None:
        arrays = {"positions": np.stack(self.positions) if self.positions
                  else np.zeros((0, 0, 3))}
        arrays.update(getattr(self, "meta", {}))
        with open(self.tmp, "wb") as fh:  # a file object: numpy adds no ".npz" suffix
            np.savez_compressed(fh, **arrays)


# --------------------------------------------------------------------------- --check


def diff_image(actual: np.ndarray, expected: np.ndarray, gain: float = 8.0) -> np.ndarray:
    """|actual - expected| per channel, times `gain`, clipped: black where identical."""
    a = np.asarray(actual, np.int16)
    b = np.asarray(expected, np.int16)
    if a.shape != b.shape:
        h, w = max(a.shape[0], b.shape[0]), max(a.shape[1], b.shape[1])
        out = np.full((h, w, 3), 255, np.uint8)  # white: no counterpart
        hh, ww = min(a.shape[0], b.shape[0]), min(a.shape[1], b.shape[1])
        out[:hh, :ww] = diff_image(a[:hh, :ww], b[:hh, :ww], gain)
        return out
    return np.clip(np.abs(a - b) * gain, 0, 255).astype(np.uint8)
