"""Image comparison for tests, with goldens that can be blessed.

    assert_image_close(img, "tests/golden/x.png")

fails (AssertionError naming the PSNR, the share of pixels off by more than
`max_level_diff` levels and the diff image path, and writing an amplified diff PNG) when
PSNR < min_psnr or more than max_fraction of the pixels differ by more than
max_level_diff in some channel.

Blessing: with the environment variable BLESS_GOLDENS=1, a missing or failing golden
*path* is (re)written from `actual` instead of failing:  BLESS_GOLDENS=1 pytest tests/
"""
from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np


def _load(p) -> np.ndarray:
    from PIL import Image
    with Image.open(p) as im:
        return np.asarray(im.convert("RGB"))


def psnr(a: np.ndarray, b: np.ndarray) -> float:
    mse = np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2)
    return math.inf if mse == 0 else 10.0 * math.log10(255.0 ** 2 / mse)


def blessing() -> bool:
    return os.environ.get("BLESS_GOLDENS", "") not in ("", "0")


def _save(img, p):
    from PIL import Image
    Path(p).parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(np.ascontiguousarray(img, dtype=np.uint8)).save(p)


def assert_image_close(actual, golden_path_or_array, *, max_level_diff=8, max_fraction=0.001,
                       min_psnr=45.0, diff_path=None):
    actual = np.asarray(actual)
    if actual.dtype != np.uint8 or actual.ndim != 3 or actual.shape[2] != 3:
        raise AssertionError(f"expected an (H, W, 3) uint8 image, got {actual.dtype} "
                             f"{actual.shape}")
    is_path = isinstance(golden_path_or_array, (str, os.PathLike))
    if is_path:
        gp = Path(golden_path_or_array)
        if not gp.exists():
            if blessing():
                _save(actual, gp)
                return
            raise AssertionError(f"golden image {gp} does not exist "
                                 f"(run with BLESS_GOLDENS=1 to create it)")
        golden = _load(gp)
    else:
        golden = np.asarray(golden_path_or_array)
    if golden.shape != actual.shape:
        if is_path and blessing():
            _save(actual, gp)
            return
        raise AssertionError(f"image shape {actual.shape} != golden shape {golden.shape}")
    d = np.abs(actual.astype(np.int16) - golden.astype(np.int16))
    off = float(np.mean(d.max(axis=2) > max_level_diff))
    p = psnr(actual, golden)
    if p >= min_psnr and off <= max_fraction:
        return
    if is_path and blessing():
        _save(actual, gp)
        return
    if diff_path is None:
        base = Path(gp) if is_path else Path("image")
        diff_path = Path(os.environ.get("DIFF_DIR", "tests/_failures")) / (base.stem + "_diff.png")
    diff_path = Path(diff_path)
    amp = np.clip(d.astype(np.int32) * 8, 0, 255).astype(np.uint8)
    _save(np.concatenate([actual, golden, amp], axis=1), diff_path)
    raise AssertionError(
        f"image differs from {'golden ' + str(gp) if is_path else 'the expected array'}: "
        f"PSNR {p:.2f} dB (min {min_psnr}), {off * 100:.3f}% of pixels off by more than "
        f"{max_level_diff} levels (max {max_fraction * 100:.3f}%); diff image (actual | "
        f"golden | 8x difference): {diff_path}")
