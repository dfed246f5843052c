"""The scene as the pipeline sees it: frozen dataclasses with every default filled in,
and the names the format knows (integrators, models, shaders)."""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

#: Known integrator names for `simulation.integrator` (the first is the default).
#: The schema's enum is built from this tuple at load time: adding one is one edit here.
INTEGRATORS: tuple[str, ...] = (
    "verlet", "euler", "symplectic-euler", "rk4", "implicit-euler", "xpbd", "vbd")


#: Cloth models for `simulation.model` (the first is the default).
MODELS: tuple[str, ...] = ("classic", "fem")


#: Known shader names for `render.shader` (schema enum built from this tuple).
SHADERS: tuple[str, ...] = (
    "normal", "wireframe", "diffuse", "phong", "texture", "bump", "displacement", "mirror", "toon",
)
#: The shaders that draw a mesh's lines, not its triangles: not a collider's own shader.
LINE_SHADERS: tuple[str, ...] = ("wireframe",)


#: Shader constants that `render` may give; stored in `RenderSettings.params` when given.
#: Values: float, or a tuple of 3 floats for the vec3 ones (I_a, k_d).
RENDER_PARAMS: tuple[str, ...] = ("k_a", "I_a", "k_s", "p", "k_h", "k_n", "k_d")


VEC3_PARAMS = frozenset({"I_a", "k_d"})


Vec3 = tuple[float, float, float]


class SceneError(ValueError):
    """Bad scene input. `str(err)` is the one-line message shown to the user."""


@dataclass(frozen=True)
class FemMaterial:
    """The `cloth.fem` block (docs/fem.md): the finite-element model's material, physical
    units; the defaults are a cotton broadcloth."""

    stretch: float = 300.0  # N/m
    shear: float = 30.0  # N/m
    bending: float = 1e-5  # N m
    density: float = 0.15  # kg/m^2


@dataclass(frozen=True)
class Keyframe:
    """A collider pose at `time`: offsets from the pose the scene file gives."""

    time: float
    translation: Vec3 = (0.0, 0.0, 0.0)
    rotation: Vec3 = (0.0, 0.0, 0.0)  # Euler angles in degrees, R = Rz Ry Rx


@dataclass(frozen=True)
class ClothMeshSource:
    """`cloth.mesh` and its placement: a file vertex v goes to R (scale * v) + translation."""

    path: Path  # absolute
    translation: Vec3 = (0.0, 0.0, 0.0)
    rotation: Vec3 = (0.0, 0.0, 0.0)  # Euler angles in degrees, R = Rz Ry Rx
    scale: Vec3 = (1.0, 1.0, 1.0)
    pieces_allowed: bool = False  # `cloth.pieces` "allow": several connected pieces


@dataclass(frozen=True)
class PinSelection:
    """One selection of `cloth.pinned` for a mesh cloth; `key` is where the file wrote it
    (e.g. 'cloth.pinned[2]'), for messages."""

    key: str
    indices: tuple[int, ...] = ()  # file vertex indices, 0-based
    box: tuple[Vec3, Vec3] | None = None  # (lo, hi), world coordinates, bounds included
    group: str | None = None  # an OBJ g/o group (or a PLY vertex attribute)
    keyframes: tuple[Keyframe, ...] = ()


@dataclass(frozen=True)
class Cloth:
    """The `cloth` block (docs/scene-format.md): a grid of point masses joined by springs,
    or (`mesh` set) the points and triangles of a mesh file. A mesh cloth has width =
    height = 0.0, num_width_points = num_height_points = 0, orientation = 0 and
    pinned = (); its pins are `pin_selections`."""

    width: float
    height: float
    num_width_points: int
    num_height_points: int
    thickness: float
    orientation: int  # 0 horizontal (y = 1 plane), 1 vertical (z ~ 0 plane)
    damping: float  # percent
    density: float
    ks: float
    enable_structural: bool = True
    enable_shearing: bool = True
    enable_bending: bool = True
    pinned: tuple[tuple[int, int], ...] = ()  # (x_index, y_index) = (column j, row i)
    # Per-point mass multipliers, rows top edge first (see docs/scene-format.md): a tuple of
    # rows of floats, an absolute image path, or None (uniform).
    mass_map: tuple[tuple[float, ...], ...] | Path | None = None
    mass_map_range: tuple[float, float] = (1.0, 2.0)  # image: black, white multipliers
    fem: FemMaterial = FemMaterial()  # used when simulation.model is "fem"
    friction: float = 0.3  # cloth-on-cloth friction under robust contact
    mesh: ClothMeshSource | None = None  # None: the grid
    pin_selections: tuple[PinSelection, ...] = ()  # a mesh cloth's pins, in file order


@dataclass(frozen=True)
class Sphere:
    """A `sphere` collider."""

    origin: Vec3
    radius: float
    friction: float
    keyframes: tuple[Keyframe, ...] = ()
    color: Vec3 | None = None  # k_d; None: the renderer's default for the kind
    shader: str | None = None  # its own shader; None: the frame's

    @property
    def pivot(self) -> Vec3:
        """The point keyframe rotations turn about."""
        return self.origin


@dataclass(frozen=True)
class Plane:
    """A `plane` collider."""

    point: Vec3
    normal: Vec3  # as written in the scene (not normalised)
    friction: float
    keyframes: tuple[Keyframe, ...] = ()
    color: Vec3 | None = None  # k_d; None: the renderer's default for the kind
    shader: str | None = None  # its own shader; None: the frame's

    @property
    def pivot(self) -> Vec3:
        return self.point


@dataclass(frozen=True)
class Box:
    """A `box` collider: a solid oriented cuboid."""

    center: Vec3
    half_extents: Vec3
    friction: float
    rotation: Vec3 = (0.0, 0.0, 0.0)  # Euler angles in degrees, R = Rz Ry Rx
    keyframes: tuple[Keyframe, ...] = ()
    color: Vec3 | None = None  # k_d; None: the renderer's default for the kind
    shader: str | None = None  # its own shader; None: the frame's

    @property
    def pivot(self) -> Vec3:
        return self.center


@dataclass(frozen=True)
class MeshCollider:
    """A `mesh` collider: a triangle mesh file placed at R (scale * v) + translation."""

    path: Path  # absolute
    friction: float
    translation: Vec3 = (0.0, 0.0, 0.0)
    rotation: Vec3 = (0.0, 0.0, 0.0)  # Euler angles in degrees, R = Rz Ry Rx
    scale: Vec3 = (1.0, 1.0, 1.0)
    solid: bool = True  # closed solid (watertight) or one-sided surface
    thickness: float = 0.005  # metres kept between points and the surface
    keyframes: tuple[Keyframe, ...] = ()
    color: Vec3 | None = None  # k_d; None: the renderer's default for the kind
    shader: str | None = None  # its own shader; None: the frame's

    @property
    def pivot(self) -> Vec3:
        return self.translation


Collider = Sphere | Plane | Box | MeshCollider


@dataclass(frozen=True)
class Wind:
    """The `wind` block (docs/wind.md): air velocity, aerodynamic coefficients, gusts."""

    velocity: Vec3 = (0.0, 0.0, 0.0)
    air_density: float = 1.225
    drag: float = 1.0
    lift: float = 0.5
    gust: float = 0.0
    gust_scale: float = 1.0
    gust_time: float = 1.0


@dataclass(frozen=True)
class SimulationSettings:
    """The `simulation` block, defaults filled in."""

    frames_per_sec: float = 90.0
    steps_per_frame: int = 30
    gravity: Vec3 = (0.0, -9.8, 0.0)
    model: str = "classic"
    integrator: str = "verlet"
    seed: int = 0
    self_collision: bool | str = "auto"  # True, False or "auto" (on for vertical cloth)
    fidelity: str = "exact"  # "exact" or "auto" (pipeline.fidelity.controller)
    tolerance_px: float = 1.0  # auto: screen-space error a frame may add
    contact: str = "course"  # "course" or "robust" (pipeline.physics.contact)
    iterations: int = 10  # the "vbd" integrator's sweeps per step (the others ignore it)


#: `"camera": "course"`: the course viewer's camera exactly (SPEC section 4).
#: the scene keys that hold colliders, in the order the file lists kinds
COLLIDER_KEYS = ("sphere", "plane", "box", "mesh")

COURSE_CAMERA = "course"


@dataclass(frozen=True)
class CameraSettings:
    """The `camera` block (position and target required when the block is given)."""

    position: Vec3
    target: Vec3
    up: Vec3 = (0.0, 1.0, 0.0)
    vfov: float = 35.0  # degrees


@dataclass(frozen=True)
class LightSettings:
    """The `light` block, defaults filled in."""

    position: Vec3 = (0.5, 2.0, 2.0)
    intensity: Vec3 = (3.0, 3.0, 3.0)
    radius: float = 0.02  # metres: the penumbra of soft shadows (render.shadows)


@dataclass(frozen=True)
class RenderSettings:
    """The `render` block. Paths are absolute (resolved against the scene file's folder);
    `params` holds only the shader constants the scene gives (floats or 3-tuples)."""

    shader: str = "phong"
    width: int = 512
    height: int = 512
    aa: int = 1
    background: Vec3 = (0.2, 0.25, 0.3)
    texture: Path | None = None  # None: the packaged default
    height_map: Path | None = None
    cubemap: Path | None = None  # folder with posx..negz images
    shadows: bool = False  # shadow-mapped soft shadows (shading/shadow.py)
    ambient_occlusion: bool = False  # screen-space ambient occlusion (shading/occlusion.py)
    # Shader constants overriding SPEC section 5 defaults: k_a, I_a, k_s, p, k_h, k_n, ...
    params: dict[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class Scene:
    """A whole validated scene, every default filled in."""

    cloth: Cloth
    colliders: tuple[Collider, ...] = ()  # in the order the scene lists them
    wind: Wind | None = None  # None: no air
    simulation: SimulationSettings = SimulationSettings()
    #: a camera object; COURSE_CAMERA; None: the course direction framing the whole shot
    #: (pipeline.view.framing)
    camera: CameraSettings | str | None = None
    light: LightSettings = LightSettings()
    render: RenderSettings = RenderSettings()
    source: Path | None = None  # the scene file, when loaded from one

    @property
    def self_collision(self) -> bool:
        """The resolved self-collision switch: "auto" means on for a vertical grid cloth and
        for a mesh cloth, off for a horizontal grid cloth."""
        sc = self.simulation.self_collision
        if sc != "auto":
            return bool(sc)
        return self.cloth.orientation == 1 or self.cloth.mesh is not None

