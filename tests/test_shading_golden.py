"""Image regression: every shader on the sphere and selfCollision scenes at frame 0 and
frame 60, 256x256, against tests/golden/*.png (PSNR >= 45 dB, <= 0.1% of pixels off by
more than 8 levels). Bless new goldens with BLESS_GOLDENS=1 (and look at them).

The scenes are drawn with `"camera": "course"` (SPEC 4's course camera): these goldens
test the shaders' pixels, not the default framing (tests/test_camera_framing.py)."""
from __future__ import annotations

from pathlib import Path

import pytest

import shading
from pipeline.run.frames import render_frame
from pipeline.physics.model import build_model
from pipeline.scene import load_scene
from shading.testing import assert_image_close

ROOT = Path(__file__).resolve().parent.parent
GOLDEN = Path(__file__).resolve().parent / "golden"
LATER = 60


@pytest.fixture(scope="module", params=["sphere", "selfCollision"])
def scene_frames(request):
    scene = load_scene(ROOT / "scenes" / f"{request.param}.json", ["camera=course"])
    model = build_model(scene)
    frames = {0: model.initial_positions}
    try:
        from pipeline.simulation import simulate
        frames[LATER] = simulate(scene, LATER)[-1]
    except ImportError:  # simulator not available: frame 0 only
        pass
    return request.param, scene, model, frames


@pytest.mark.parametrize("shader", shading.SHADERS)
@pytest.mark.parametrize("frame", [0, LATER])
def test_golden(scene_frames, shader, frame):
    name, scene, model, frames = scene_frames
    if frame not in frames:
        pytest.skip("simulator not available")
    img = render_frame(scene, frames[frame], model, shader=shader, width=256, height=256, aa=1)
    assert_image_close(img, GOLDEN / f"{name}_f{frame}_{shader}.png",
                       diff_path=ROOT / "tests" / "_failures" / f"{name}_f{frame}_{shader}_diff.png")
