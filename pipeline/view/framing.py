"""The framed default camera (SPEC section 4): a scene with no `camera` is seen from the
course viewer's direction (looking down -z, up +y, vfov 35 degrees) from where its whole
shot fits the image.

    framing = Framing(width, height)
    for positions, t in shot:            # every frame the output shows
        framing.add(framed_points(scene, positions, t))
    camera = framing.camera()

What is framed (`framed_points`): the cloth points of every frame, and the colliders where
the cloth touches them: for each cloth point within NEAR_FRACTION x max(cloth width,
height) of a collider's surface, the nearest point of that surface (posed at the frame's
time). That is the sphere's cap under a drape, a box's top, the floor under the cloth;
never a whole infinite plane.

The camera (`Framing.camera`): with a_y = (1 - 2 MARGIN) tan(vfov / 2) and
a_x = a_y width / height, a point p is in the image with the margin when
|p_x - e_x| <= a_x (e_z - p_z) and |p_y - e_y| <= a_y (e_z - p_z). With
X± = max(±p_x + a_x p_z) and Y± = max(±p_y + a_y p_z) over every framed point, the
nearest eye that frames them all is
    e_z = max((X+ + X-) / (2 a_x), (Y+ + Y-) / (2 a_y), max p_z + 2 near),
    e_x = (X+ - X-) / 2,   e_y = (Y+ - Y-) / 2,
looking at (e_x, e_y, (min p_z + max p_z) / 2); far = max(100, 2 (e_z - min p_z)) so a
long fall is not clipped. A flat shot, its points spanning less height than FLAT times
their depth (a cloth lying on the floor the whole shot), would put the eye at its own
height, edge on (an empty image): it is framed as if it spanned FLAT times its depth,
from its lowest point up (Y+ from a point that high over its nearest point), so the eye
looks at it from above. Eight running maxima hold the whole shot: no frame is kept.

What the camera at another image size needs (`Framing(..., record=True).points()`, which
`render --export-npz` records for `render --from`): only a_x depends on the size, so one
point holding each of the other maxima is enough, and X+ and X- need only the points that
beat in x (or -x) every point at least as high (z) before them: x + a_x z never decreases
with x or z, rounding included, so a point matched or beaten in both holds no maximum that
another does not, whatever a_x. The few dozen points kept give the eight maxima of every
point of the shot, bit for bit, at any size (and the same vfov).
"""
from __future__ import annotations

import math
from collections.abc import Iterable

import numpy as np

from pipeline.physics.colliders import collider_pose, euler_matrix
from pipeline.physics.colliders.mesh import distance_grid
from pipeline.scene import Box, CameraSettings, MeshCollider, Plane, Scene, Sphere
from shading.camera import DEFAULT_FAR, DEFAULT_NEAR, DEFAULT_VFOV, Camera

MARGIN = 0.04  # of the image's width and height, kept clear on each side
NEAR_FRACTION = 0.1  # of the cloth's size: a collider surface this near the cloth is framed
#: a shot whose framed points span less height than this share of their depth (a cloth
#: lying on the floor) is framed as if it were that high, from its lowest point up: the
#: eye rises above it instead of seeing it edge on
FLAT = 0.25


class Framing:
    """What a framed camera of a width x height image must show, accumulated frame by
    frame as eight running maxima (order-independent: the same points give the same camera
    whatever their order)."""

    def __init__(self, width: int, height: int, vfov: float = DEFAULT_VFOV,
                 record: bool = False) -> None:
        self.width, self.height, self.vfov = int(width), int(height), float(vfov)
        self.a_y = (1.0 - 2.0 * MARGIN) * math.tan(math.radians(self.vfov) / 2.0)
        self.a_x = self.a_y * self.width / self.height
        self._max = np.full(8, -np.inf)  # X+, X-, Y+, Y-, max z, -min z, max y, -min y
        # with `record`, the points that may hold a maximum at some image size (`points`)
        self._held = np.empty((0, 3)) if record else None

    def add(self, points: np.ndarray) -> None:
        """Frame these points (N, 3) too."""
        p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        if not len(p):
            return
        x, y, z = p[:, 0], p[:, 1], p[:, 2]
        ax, ay = self.a_x * z, self.a_y * z
        self._max = np.maximum(self._max, [np.max(x + ax), np.max(ax - x), np.max(y + ay),
                                           np.max(ay - y), np.max(z), np.max(-z),
                                           np.max(y), np.max(-y)])
        if self._held is not None:
            self._held = self._holders(np.concatenate([self._held, p]))

    def include(self, other: Framing) -> None:
        """Frame what `other` (the same image size and field of view) frames too."""
        if (other.width, other.height, other.vfov) != (self.width, self.height, self.vfov):
            raise ValueError("framings of different images cannot be combined")
        self._max = np.maximum(self._max, other._max)
        if self._held is not None:  # and what it holds (it must record too)
            self._held = self._holders(np.concatenate([self._held, other.points()]))

    def _holders(self, p: np.ndarray) -> np.ndarray:
        """The points of p (N >= 1, 3) that hold a maximum of `add` at this a_y and any a_x:
        one holding each maximum but X+ and X-, and, in order of z, highest first, the first
        and each that beats in x (or -x) every point before it. (A point holding X+ may not
        be one of those, but the first point reaching as far in x and z as it is, and holds
        X+ too: one before it beating it in x would reach as far.)"""
        x, y, z = p[:, 0], p[:, 1], p[:, 2]
        order = np.argsort(-z)
        stair = np.zeros(len(p), dtype=bool)
        stair[0] = True
        for u in (x[order], -x[order]):
            stair[1:] |= u[1:] > np.maximum.accumulate(u)[:-1]
        ay = self.a_y * z
        tops = [np.argmax(v) for v in (y + ay, ay - y, z, -z, y, -y)]
        return p[np.union1d(order[stair], tops)]

    def points(self) -> np.ndarray:
        """Points (K, 3) among those added that hold every maximum at any image size: a
        Framing of any size that adds them alone gives the camera, to the bit, that adding
        every point gives (needs record=True)."""
        if self._held is None:
            raise ValueError("this framing records no points: Framing(..., record=True)")
        return self._held.copy()

    def camera(self) -> Camera:
        """The nearest camera looking down -z (up +y) that frames every point added."""
        x_plus, x_minus, y_plus, y_minus, z_max, z_min, y_max, y_min = (
            self._max * [1, 1, 1, 1, 1, -1, 1, -1])
        if not np.isfinite(z_max):
            raise ValueError("nothing to frame: no points were added")
        lift = FLAT * (z_max - z_min) - (y_max - y_min)
        if lift > 0.0:  # a flat shot, seen edge on from its own height: frame it from above
            y_plus = max(y_plus, y_max + lift + self.a_y * z_max)
        e_z = max((x_plus + x_minus) / (2.0 * self.a_x), (y_plus + y_minus) / (2.0 * self.a_y),
                  z_max + 2.0 * DEFAULT_NEAR)
        e_x, e_y = (x_plus - x_minus) / 2.0, (y_plus - y_minus) / 2.0
        return Camera(eye=(e_x, e_y, e_z), target=(e_x, e_y, (z_min + z_max) / 2.0),
                      up=(0.0, 1.0, 0.0), vfov=self.vfov, near=DEFAULT_NEAR,
                      far=max(DEFAULT_FAR, 2.0 * (e_z - z_min)), width=self.width,
                      height=self.height)


def framed_points(scene: Scene, positions: np.ndarray, time: float = 0.0) -> np.ndarray:
    """The cloth points (N, 3) of one frame and the nearest collider surface points of those
    within NEAR_FRACTION of the cloth's size of a collider (colliders posed at `time`)."""
    pos = np.asarray(positions, dtype=np.float64).reshape(-1, 3)
    near = NEAR_FRACTION * cloth_size(scene, pos)
    parts = [pos]
    for c in scene.colliders:
        rot, shift = collider_pose(c, time)
        pivot = np.asarray(c.pivot, dtype=np.float64)
        rest = (pos - pivot - shift) @ rot + pivot  # the points in the collider's rest frame
        distance, surface = _nearest_on(c, rest)
        close = np.abs(distance) <= near
        parts.append((surface[close] - pivot) @ rot.T + pivot + shift)
    return np.concatenate(parts)


def _nearest_on(c, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(distance (N,) to the surface of collider `c` at rest, nearest surface points (N, 3))
    of points p (N, 3)."""
    if isinstance(c, Sphere):
        d = p - np.asarray(c.origin)
        r = np.linalg.norm(d, axis=1)
        unit = d / np.where(r > 0.0, r, 1.0)[:, None]
        return r - c.radius, np.asarray(c.origin) + c.radius * unit
    if isinstance(c, Plane):
        n = np.asarray(c.normal, dtype=np.float64)
        n = n / np.linalg.norm(n)
        s = (p - np.asarray(c.point)) @ n
        return s, p - s[:, None] * n
    if isinstance(c, Box):
        return _nearest_on_box(c, p)
    if isinstance(c, MeshCollider):  # through its distance grid: FAR outside the grid's box
        distance, gradient = distance_grid(c).evaluate(p)
        return distance, p - distance[:, None] * gradient
    raise TypeError(f"unknown collider {type(c).__name__}")


def _nearest_on_box(c: Box, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    rot = euler_matrix(c.rotation)
    h = np.asarray(c.half_extents, dtype=np.float64)
    q = (p - np.asarray(c.center)) @ rot  # box coordinates
    clamped = np.clip(q, -h, h)
    outside = np.linalg.norm(q - clamped, axis=1)
    depth = h - np.abs(q)  # inside: the distance to each face pair
    axis = np.argmin(depth, axis=1)
    inside = outside == 0.0
    rows = np.nonzero(inside)[0]
    clamped[rows, axis[rows]] = np.copysign(h[axis[rows]], q[rows, axis[rows]])
    distance = np.where(inside, -depth[np.arange(len(q)), axis], outside)
    return distance, clamped @ rot.T + np.asarray(c.center)


def frame_shot(scene: Scene, frames: Iterable[tuple[np.ndarray, float]], width: int,
               height: int) -> Framing:
    """The framing of a width x height image of `frames`, (positions, time) pairs."""
    framing = Framing(width, height)
    for positions, t in frames:
        framing.add(framed_points(scene, positions, t))
    return framing


def default_camera(scene: Scene, initial_positions, width: int, height: int,
                   shot: Framing | None = None) -> Camera:
    """The camera of a width x height image of `scene` (SPEC 4): its `camera` object; the
    course camera for "camera": "course"; for a scene with no camera, the camera framing
    `shot`, or the course camera when no shot is given."""
    cs: CameraSettings | str | None = scene.camera
    if isinstance(cs, CameraSettings):
        return Camera(tuple(cs.position), tuple(cs.target), tuple(cs.up), float(cs.vfov),
                      width=width, height=height)
    if cs is None and shot is not None:
        if (shot.width, shot.height) != (width, height):
            raise ValueError(f"the shot was framed for {shot.width}x{shot.height}, "
                             f"not {width}x{height}")
        return shot.camera()
    size = cloth_size(scene, initial_positions)
    return Camera.default_for_cloth(initial_positions, size, size, width=width, height=height)


def cloth_size(scene: Scene, positions) -> float:
    """max(width, height) of the grid cloth; for a mesh cloth, the largest side of the
    bounding box of `positions` (N, 3) (the initial ones, for the course camera)."""
    if scene.cloth.mesh is None:
        return max(scene.cloth.width, scene.cloth.height)
    return float(np.ptp(np.asarray(positions, dtype=np.float64).reshape(-1, 3), axis=0).max())
