"""Regenerate the mass-map images of this folder.

    python scenes/maps/make_maps.py

hem.png   45 x 45 greyscale: black with a white border 2 pixels wide. With
          `"mass_map": "maps/hem.png", "mass_map_range": [1, 4]` on a 45 x 45 cloth
          (scenes/tablecloth.json), the two outermost rows and columns of points are 4 times
          as heavy as the rest: a weighted hem.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
from PIL import Image

HERE = Path(__file__).resolve().parent


def hem(size: int = 45, border: int = 2) -> np.ndarray:
    image = np.full((size, size), 255, dtype=np.uint8)
    image[border:-border, border:-border] = 0
    return image


def main() -> None:
    Image.fromarray(hem(), mode="L").save(HERE / "hem.png", optimize=True)
    print("hem.png")


if __name__ == "__main__":
    main()
