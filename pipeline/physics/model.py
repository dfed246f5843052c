"""The cloth model as flat arrays: data only. The classic mass-spring model (SPEC section 2)
always supplies the grid, pins and springs (the renderer's wireframe and Provot's limit use
them); with `simulation.model` "fem" the model also carries the finite-element data
(pipeline.physics.fem.FemParams), which then replaces the springs' forces and sets the masses.

Points are row-major (row i < nh, column j < nw, index p = i * nw + j). Every point creates
up to six springs towards earlier neighbours, in this order (the *directions*):

    0 structural-left (i, j-1)      1 structural-above (i-1, j)
    2 shearing-upper-left (i-1, j-1) 3 shearing-upper-right (i-1, j+1)
    4 bending-two-left (i, j-2)     5 bending-two-above (i-2, j)

Spring (d, p) joins point p to point p + OFFSET[d]; arrays indexed [d, p] hold its rest
length. Walking p in order and d in order inside gives the SPEC's spring list order.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from pipeline.scene import Cloth, Scene

from .fem import FemParams, build_fem, lumped_masses
from .mesh_model import MeshFem, MeshSprings, MeshTopology, mesh_fem, mesh_springs, topology
from .mesh_model import lumped_masses as mesh_lumped_masses

if TYPE_CHECKING:
    from .pin_motion import PinMotion

DIRECTION_NAMES = ("left", "above", "upper-left", "upper-right", "two-left", "two-above")
DIRECTION_DI = np.array([0, -1, -1, -1, 0, -2], dtype=np.int64)
DIRECTION_DJ = np.array([-1, 0, -1, 1, -2, 0], dtype=np.int64)
STRUCTURAL, SHEARING, BENDING = 0, 1, 2
SPRING_TYPE_NAMES = ("structural", "shearing", "bending")
DIRECTION_TYPE = np.array([STRUCTURAL, STRUCTURAL, SHEARING, SHEARING, BENDING, BENDING])
BENDING_FACTOR = 0.2  # k = 0.2 * ks for bending springs


@dataclass(frozen=True)
class ClothModel:
    """Everything the integrators need about the cloth, and nothing about time stepping.

    positions are stored structure-of-arrays, shape (3, N); `initial_positions` is the usual
    (N, 3) view for users.
    """

    nw: int
    nh: int
    width: float
    height: float
    thickness: float
    mass: float  # of every point of a uniform classic cloth: width * height * density / N
    point_mass: np.ndarray  # (N,) float64: mass (FEM: lumped masses) * mass map multiplier
    damping: float  # the Verlet factor: fraction of velocity lost per step (percent / 100)
    x0: np.ndarray  # (3, N) float64, initial positions
    pinned: np.ndarray  # (N,) uint8, 1 = pinned
    exists: np.ndarray  # (6, N) bool: does spring (d, p) exist
    rest: np.ndarray  # (6, N) float64 rest length (0 where the spring does not exist)
    stiffness: np.ndarray  # (6,) float64 k per direction; 0 where its type is disabled
    spring_enabled_by_type: tuple[bool, bool, bool]
    fem: FemParams | MeshFem | None = None  # the finite-element model; None: classic springs
    # a mesh cloth (cloth.mesh): its faces, uvs and springs; nw = nh = 0 and exists, rest
    # and stiffness are empty then (its springs are mesh.springs)
    mesh: MeshCloth | None = None

    @property
    def n(self) -> int:
        return self.x0.shape[1]

    @property
    def initial_positions(self) -> np.ndarray:
        return self.x0.T

    @property
    def triangles(self) -> np.ndarray:
        """(T, 3) the cloth's triangles: the grid's two per cell (A, C, B), (B, C, D), or
        the mesh's."""
        if self.mesh is not None:
            return self.mesh.topology.triangles
        nw, nh = self.nw, self.nh
        i, j = np.meshgrid(np.arange(nh - 1), np.arange(nw - 1), indexing="ij")
        a = (i * nw + j).ravel()
        return np.stack([np.stack([a, a + nw, a + 1], 1),
                         np.stack([a + 1, a + nw, a + nw + 1], 1)], 1).reshape(-1, 3)

    @property
    def spring_d(self) -> np.ndarray:
        """Direction of every spring, in list order."""
        return np.nonzero(self.exists.T)[1].astype(np.int32)

    @property
    def spring_a(self) -> np.ndarray:
        """Creating point of every spring, in list order (int32)."""
        if self.mesh is not None:
            return self.mesh.springs.a.astype(np.int32)
        return np.nonzero(self.exists.T)[0].astype(np.int32)

    @property
    def spring_b(self) -> np.ndarray:
        """Neighbour point of every spring, in list order (int32)."""
        if self.mesh is not None:
            return self.mesh.springs.b.astype(np.int32)
        p, d = np.nonzero(self.exists.T)
        return (p + DIRECTION_DI[d] * self.nw + DIRECTION_DJ[d]).astype(np.int32)

    @property
    def spring_type(self) -> np.ndarray:
        """0 structural, 1 shearing, 2 bending, in list order."""
        if self.mesh is not None:
            s = self.mesh.springs
            return np.where(np.arange(len(s.a)) < s.structural, STRUCTURAL,
                            BENDING).astype(np.int8)
        return DIRECTION_TYPE[self.spring_d].astype(np.int8)

    @property
    def spring_rest(self) -> np.ndarray:
        if self.mesh is not None:
            return self.mesh.springs.rest
        return self.rest.T[self.exists.T]

    @property
    def spring_enabled(self) -> np.ndarray:
        """Whether each spring (in list order) exerts a force."""
        return np.array(self.spring_enabled_by_type)[self.spring_type]


def initial_grid(scene: Scene) -> np.ndarray:
    """Initial positions (3, N) per SPEC section 2 (vertical cloth jittered in z by the seed)."""
    c = scene.cloth
    nw, nh = c.num_width_points, c.num_height_points
    j = np.tile(np.arange(nw, dtype=np.float64), nh)
    i = np.repeat(np.arange(nh, dtype=np.float64), nw)
    x = (c.width * j) / (nw - 1)
    y = (c.height * i) / (nh - 1)
    if c.orientation == 0:
        return np.stack([x, np.ones_like(x), y])
    rng = np.random.default_rng(scene.simulation.seed)
    z = rng.uniform(-0.001, 0.001, size=nw * nh)
    return np.stack([x, y, z])


def build_model(scene: Scene, x0: np.ndarray | None = None) -> ClothModel:
    """Build the classic model of `scene`; `x0` (N, 3) replaces the generated grid if given."""
    c = scene.cloth
    if c.mesh is not None:
        return build_mesh_model(scene, x0)
    nw, nh = c.num_width_points, c.num_height_points
    n = nw * nh
    if x0 is None:
        x = initial_grid(scene)
    else:
        x = np.ascontiguousarray(np.asarray(x0, dtype=np.float64).reshape(n, 3).T)
    pinned = np.zeros(n, dtype=np.uint8)
    for xi, yi in c.pinned:
        pinned[yi * nw + xi] = 1
    ii, jj = np.divmod(np.arange(n), nw)
    exists = np.zeros((6, n), dtype=bool)
    rest = np.zeros((6, n), dtype=np.float64)
    for d in range(6):
        i2, j2 = ii + DIRECTION_DI[d], jj + DIRECTION_DJ[d]
        ok = (i2 >= 0) & (i2 < nh) & (j2 >= 0) & (j2 < nw)
        exists[d] = ok
        p = np.nonzero(ok)[0]
        q = i2[ok] * nw + j2[ok]
        delta = x[:, q] - x[:, p]
        rest[d, p] = np.sqrt(delta[0] * delta[0] + delta[1] * delta[1] + delta[2] * delta[2])
    enabled = (c.enable_structural, c.enable_shearing, c.enable_bending)
    k_type = (c.ks, c.ks, BENDING_FACTOR * c.ks)
    stiffness = np.array(
        [k_type[t] if enabled[t] else 0.0 for t in DIRECTION_TYPE], dtype=np.float64
    )
    mass = ((c.width * c.height) * c.density) / float(n)
    fem = None
    if scene.simulation.model == "fem":
        m = c.fem
        fem = build_fem(nw, nh, c.width, c.height, m.stretch, m.shear, m.bending, m.density)
        base = lumped_masses(fem)
    else:
        base = np.full(n, mass)
    point_mass = base if c.mass_map is None else base * mass_multipliers(c)
    return ClothModel(
        nw=nw,
        nh=nh,
        width=c.width,
        height=c.height,
        thickness=c.thickness,
        mass=mass,
        point_mass=point_mass,
        damping=c.damping / 100.0,
        x0=x,
        pinned=pinned,
        exists=exists,
        rest=rest,
        stiffness=stiffness,
        spring_enabled_by_type=enabled,
        fem=fem,
    )


@dataclass(frozen=True)
class MeshCloth:
    """What a mesh cloth's model holds beyond the grid's fields."""

    source: Path  # the mesh file
    topology: MeshTopology
    springs: MeshSprings  # the classic springs (the wireframe draws them under the FEM too)
    file_index: np.ndarray  # (V,) the point of each vertex line of the file, -1 if unused
    pin_motion: PinMotion | None  # the keyframed pins; None: every pin stays put
    pin_speed: float  # a bound on the keyframed pins' speed, m/s


def build_mesh_model(scene: Scene, x0: np.ndarray | None = None) -> ClothModel:
    """The model of a mesh cloth (cloth.mesh); `x0` (N, 3) replaces the file's points (the
    rest shape stays the file's)."""
    from .cloth_mesh import load_cloth_mesh, pinned_points
    from .mesh_forces import with_rest_angles
    from .pin_motion import max_pin_speed, pin_motion, posed

    c = scene.cloth
    mesh = load_cloth_mesh(c.mesh)
    rest_points = np.asarray(mesh.points, dtype=np.float64)
    n = len(rest_points)
    x = np.ascontiguousarray(rest_points.T if x0 is None
                             else np.asarray(x0, dtype=np.float64).reshape(n, 3).T)
    topo = topology(rest_points, mesh.triangles, mesh.corner_uv, mesh.has_uv)
    springs = mesh_springs(rest_points, topo, c.ks, c.enable_structural, c.enable_bending)
    fem = None
    if scene.simulation.model == "fem":
        m = c.fem
        fem = with_rest_angles(mesh_fem(rest_points, topo, m.stretch, m.shear, m.bending),
                               np.ascontiguousarray(rest_points.T))
        base = mesh_lumped_masses(rest_points, topo.triangles, m.density)
    else:
        base = mesh_lumped_masses(rest_points, topo.triangles, c.density)
    point_mass = base if c.mass_map is None else base * uv_mass_multipliers(c, topo.point_uv)
    extent = np.sort(np.ptp(rest_points, axis=0))[::-1]
    source = str(scene.source) if getattr(scene, "source", None) else "scene"
    moving = [(pinned_points(mesh, (sel,), source).astype(bool), sel.keyframes)
              for sel in c.pin_selections if sel.keyframes]
    motion = pin_motion(rest_points, moving)
    if motion is not None and x0 is None:
        posed(motion, x, 0.0)
    return ClothModel(
        nw=0, nh=0, width=float(extent[0]), height=float(extent[1]), thickness=c.thickness,
        mass=float(base.mean()), point_mass=point_mass, damping=c.damping / 100.0, x0=x,
        pinned=pinned_points(mesh, c.pin_selections, source),
        exists=np.zeros((6, 0), dtype=bool), rest=np.zeros((6, 0)),
        stiffness=np.zeros(6), spring_enabled_by_type=(c.enable_structural, False,
                                                       c.enable_bending),
        fem=fem, mesh=MeshCloth(source=mesh.path, topology=topo, springs=springs,
                                file_index=mesh.file_index, pin_motion=motion,
                                pin_speed=max_pin_speed(motion, moving, rest_points)))


def uv_mass_multipliers(cloth: Cloth, point_uv: np.ndarray) -> np.ndarray:
    """(N,) multipliers of a mesh cloth's point masses from an image `cloth.mass_map`,
    sampled bilinearly at each point's uv (the image's top row at v = 1)."""
    from PIL import Image

    with Image.open(cloth.mass_map) as im:
        grey = np.asarray(im.convert("F"), dtype=np.float64) / 255.0
    lo, hi = cloth.mass_map_range
    values = lo + np.clip(grey, 0.0, 1.0) * (hi - lo)
    rows, cols = values.shape
    r = np.clip((1.0 - point_uv[:, 1]) * (rows - 1), 0.0, rows - 1)
    q = np.clip(point_uv[:, 0] * (cols - 1), 0.0, cols - 1)
    r0, q0 = np.minimum(r.astype(int), max(rows - 2, 0)), np.minimum(q.astype(int), max(cols - 2, 0))
    r1, q1 = np.minimum(r0 + 1, rows - 1), np.minimum(q0 + 1, cols - 1)
    wr, wq = r - r0, q - q0
    top = values[r0, q0] * (1 - wq) + values[r0, q1] * wq
    bottom = values[r1, q0] * (1 - wq) + values[r1, q1] * wq
    return top * (1 - wr) + bottom * wr


def mass_multipliers(cloth: Cloth) -> np.ndarray:
    """(N,) multipliers of the point mass from `cloth.mass_map`, row-major like the points.

    The map's first row is the top edge of the cloth (the row with the largest y_index); a
    map of another size than the grid is resampled bilinearly (corners on corners). An image
    is read as greyscale g in [0, 1] and mapped to lo + g (hi - lo), (lo, hi) =
    `cloth.mass_map_range`.
    """
    if isinstance(cloth.mass_map, Path):
        from PIL import Image

        with Image.open(cloth.mass_map) as im:
            grey = np.asarray(im.convert("F"), dtype=np.float64) / 255.0
        lo, hi = cloth.mass_map_range
        rows = lo + np.clip(grey, 0.0, 1.0) * (hi - lo)
    else:
        rows = np.array(cloth.mass_map, dtype=np.float64)
    grid = _resample(rows, cloth.num_height_points, cloth.num_width_points)
    return np.ascontiguousarray(grid[::-1].ravel())


def _resample(values: np.ndarray, rows: int, cols: int) -> np.ndarray:
    """Bilinear resampling of a 2-D array to (rows, cols), corner samples on corners."""
    if values.shape == (rows, cols):
        return values.copy()

    def axis(n_out: int, n_in: int):
        pos = np.linspace(0.0, n_in - 1.0, n_out)
        i0 = np.minimum(np.floor(pos).astype(int), max(n_in - 2, 0))
        i1 = np.minimum(i0 + 1, n_in - 1)
        return i0, i1, pos - i0

    r0, r1, wr = axis(rows, values.shape[0])
    c0, c1, wc = axis(cols, values.shape[1])
    top = values[r0][:, c0] * (1 - wc) + values[r0][:, c1] * wc
    bottom = values[r1][:, c0] * (1 - wc) + values[r1][:, c1] * wc
    return top * (1 - wr)[:, None] + bottom * wr[:, None]
