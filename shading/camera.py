"""Camera (SPEC section 4): OpenGL look-at + perspective, image size included."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

DEFAULT_VFOV = 35.0
DEFAULT_NEAR = 0.01
DEFAULT_FAR = 100.0


def _unit(v):
    v = np.asarray(v, dtype=np.float64)
    n = np.linalg.norm(v)
    if not np.isfinite(n) or n == 0.0:
        raise ValueError(f"camera vector {v} has zero or non-finite length")
    return v / n


def cross3(a, b) -> np.ndarray:
    """np.cross of two 3-vectors, the same arithmetic, without its overhead (0.1 ms a call:
    the shadow map's views are made every frame)."""
    return np.array([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2],
                     a[0] * b[1] - a[1] * b[0]])


def look_at(eye, target, up) -> np.ndarray:
    """gluLookAt: the view matrix of an eye looking at target."""
    eye = np.asarray(eye, dtype=np.float64)
    f = _unit(np.asarray(target, dtype=np.float64) - eye)
    s = cross3(f, _unit(up))
    if np.linalg.norm(s) < 1e-12:
        raise ValueError("camera up is parallel to the viewing direction")
    s = s / np.linalg.norm(s)
    m = np.eye(4)
    m[0, :3], m[1, :3], m[2, :3] = s, cross3(s, f), -f
    m[:3, 3] = -m[:3, :3] @ eye
    return m


def perspective(vfov: float, aspect: float, near: float, far: float) -> np.ndarray:
    """gluPerspective (vfov in degrees)."""
    f = 1.0 / np.tan(np.radians(vfov) / 2.0)
    m = np.zeros((4, 4))
    m[0, 0] = f / aspect
    m[1, 1] = f
    m[2, 2] = (far + near) / (near - far)
    m[2, 3] = 2.0 * far * near / (near - far)
    m[3, 2] = -1.0
    return m


@dataclass(frozen=True)
class Camera:
    """A pinhole camera, OpenGL conventions (right handed, looks down -z in eye space).

    `width` x `height` is the output image size in pixels (the size lives here, not in
    the render params); vfov is the vertical field of view in degrees.
    """

    eye: tuple = (0.0, 0.0, 3.0)
    target: tuple = (0.0, 0.0, 0.0)
    up: tuple = (0.0, 1.0, 0.0)
    vfov: float = DEFAULT_VFOV
    near: float = DEFAULT_NEAR
    far: float = DEFAULT_FAR
    width: int = 512
    height: int = 512

    def __post_init__(self):
        for k in ("eye", "target", "up"):
            object.__setattr__(self, k, tuple(float(x) for x in getattr(self, k)))
        if int(self.width) < 1 or int(self.height) < 1:
            raise ValueError(f"image size must be positive, got {self.width}x{self.height}")
        object.__setattr__(self, "width", int(self.width))
        object.__setattr__(self, "height", int(self.height))
        if not (0.0 < self.vfov < 180.0):
            raise ValueError(f"vfov must be in (0, 180) degrees, got {self.vfov}")
        if not (0.0 < self.near < self.far):
            raise ValueError(f"need 0 < near < far, got near={self.near} far={self.far}")

    @classmethod
    def default_for_cloth(cls, initial_positions, width_m, height_m, *, width=512,
                          height=512):
        """SPEC 4 default: target (cx, cy/2, cz), eye target + (0, 0, 1.8 max(w, h))."""
        c = np.asarray(initial_positions, dtype=np.float64).reshape(-1, 3).mean(axis=0)
        target = np.array([c[0], c[1] / 2.0, c[2]])
        eye = target + np.array([0.0, 0.0, 1.8 * max(float(width_m), float(height_m))])
        return cls(tuple(eye), tuple(target), (0.0, 1.0, 0.0), DEFAULT_VFOV,
                   DEFAULT_NEAR, DEFAULT_FAR, width, height)

    def with_size(self, width, height) -> "Camera":
        from dataclasses import replace
        return replace(self, width=int(width), height=int(height))

    @property
    def aspect(self) -> float:
        return self.width / self.height

    def view_matrix(self) -> np.ndarray:
        """gluLookAt."""
        return look_at(self.eye, self.target, self.up)

    def projection_matrix(self) -> np.ndarray:
        """gluPerspective."""
        return perspective(self.vfov, self.aspect, self.near, self.far)

    def view_projection(self) -> np.ndarray:
        return self.projection_matrix() @ self.view_matrix()

    def project(self, points) -> np.ndarray:
        """World points (N,3) -> window coordinates (N,3): x right and y down in pixels
        (image row 0 at the top, pixel centres at +0.5), z in [0, 1]."""
        p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        c = np.c_[p, np.ones(len(p))] @ self.view_projection().T
        ndc = c[:, :3] / c[:, 3:4]
        return np.stack([(ndc[:, 0] + 1) * 0.5 * self.width,
                         (1 - ndc[:, 1]) * 0.5 * self.height,
                         (ndc[:, 2] + 1) * 0.5], axis=1)
