"""The scene packed for the kernels: what every integrator steps, and the divergence guard.

`System` is a NamedTuple of flat arrays and numbers (numba passes it to kernels as a
tuple); it joins the cloth model, the colliders and the time step, and holds no state that
changes during a run. Integrators keep their own state arrays.
"""
from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba.core import types
from numba.extending import register_jitable, typeof_impl

from clothjit import KernelPointer, njit
from pipeline.scene import Box, Scene, Sphere

from .colliders import ColliderTable, collide_all, max_surface_speed, pack_colliders
from .collider_contact import robust_colliders
from .contact import RobustContact, pack_contact, robust_contact
from .mesh_contact import pack_meshes
from .constraints import (CandidateMask, candidate_mask, existence_bits, limit_stretch,
                          stretch_limits)
from .fem import FemParams, estimate_omega_max, no_fem
from .forces import (SpringKernels, direction_offsets, fem_internal_forces, gather_order,
                     internal_forces, spring_force_buffer, spring_kernels)
from .mesh_forces import mesh_fem_internal_forces, mesh_internal_forces, mesh_limit_stretch
from .mesh_model import MeshSprings
from .pin_motion import PinMotion, move_pins
from .mesh_wind import MeshWind, add_mesh_wind_force, pack_mesh_wind
from .model import DIRECTION_DI, DIRECTION_DJ, ClothModel, initial_grid
from .reach import Reach, new_reach, reach_check
from .self_collision import (PARALLEL_POINTS as SELF_PARALLEL_POINTS, SelfCollisionScratch,
                             _push_members, self_collide, self_collide_in_chunks)
from .wind import WindParams, add_wind_force, max_wind_speed, pack_wind


class StepKernels(NamedTuple):
    """The kernels every stepping kernel calls through pointers (clothjit.KernelPointer),
    compiled once on their own rather than linked into each integrator's stepping kernel
    (numba optimises a linked callee again in every caller): a stepping kernel compiles in
    about 3.3-3.8 s instead of 4.7-6.5 s (sphere, Verlet, its callees cached).

    A scene with neither wind nor self-collision has None for both passes (and for their
    params), which numba prunes from its stepping kernel. A scene with either has both: the
    one it does not use as an absent pointer (never compiled, never called) and params of
    the same type, so wind, self-collision or both share one stepping kernel per model and
    integrator. (Giving the lean scenes these params too made their stepping kernel compile
    about 1.1 s slower, 3.2-3.7 s against 2.0-2.6 s: numba's compile time grows with the
    arrays the System holds.)

    Both models have the same types here and in the System (the FEM's passes absent in a
    classic System, the springs' in a FEM one), so one stepping kernel per integrator serves
    both: a first FEM scene after the README's compiles 3-4 s less."""

    internal: KernelPointer  # forces.internal_forces (fem_internal_forces with the FEM)
    springs: SpringKernels  # the springs' passes internal_forces calls; absent with the FEM
    collide: KernelPointer  # colliders.collide_all
    stretch: KernelPointer  # constraints.limit_stretch; absent with the FEM (no Provot)
    self_collide: KernelPointer | None  # self_collision.self_collide; absent or None: off
    self_push: KernelPointer | None  # self_collision._push_members, the pass's pushes
    wind: KernelPointer | None  # wind.add_wind_force; absent or None: no wind
    reach: KernelPointer  # reach.reach_check (linked, it was a sixth of every stepping kernel)
    contact: KernelPointer | None = None  # contact.robust_contact; None: the course contact
    robust_colliders: KernelPointer | None = None  # collider_contact.robust_colliders; ditto


class System(NamedTuple):
    classic: bool  # the classic mass-spring model (Provot's limit applies), else the FEM
    collision_box: tuple  # (w, h) of the self-collision boxes, m (the third side max(w, h))
    thickness: float
    x0: np.ndarray  # (3, N)
    pinned: np.ndarray  # (N,) uint8
    exist_bits: np.ndarray  # (N + pad,) uint8, bit d = spring (d, p) exists
    limit: np.ndarray  # (6, N) 1.1 * rest
    limit_sq_lo: np.ndarray  # (6, N)
    mass: np.ndarray  # (N,) point masses
    total_mass: float
    gravity: np.ndarray  # (3,)
    dt: float
    damping: float  # fraction of velocity lost per step
    force_dt2: float  # factor of F/m in Verlet's update: dt^2 (the course), see verlet.py
    steps_per_frame: int
    colliders: ColliderTable
    wind: WindParams | MeshWind | None  # still air (`on` False) or None without wind (StepKernels)
    # the finite-element model; a classic System's has no points (fem.no_fem) and its
    # kernels absent, so that both models' Systems have one type (StepKernels)
    fem: FemParams
    # the grid's springs (offsets, gather_order, exists, rest, stiffness): one field, not
    # five (numba's compile time grows with the System's arrays); a mesh cloth's
    # mesh_model.MeshSprings
    springs: tuple
    needs_velocity: bool  # some force depends on the velocity (Verlet then estimates it)
    self_collision: bool  # the scene turns self-collision on
    scratch: tuple | None  # SelfCollisionScratch.as_tuple(), for no points or None when off
    spring_force: np.ndarray  # (6, 3, N + pad) scratch of forces.spring_forces
    mask: CandidateMask  # scratch and passes of constraints.limit_stretch
    slack_speed: float  # speed every point may gain without energy input (m/s), see guard
    reach: Reach  # which passes can act (pipeline.physics.reach); disarmed: all of them
    colliders_last: bool  # colliders after Provot (fidelity auto), else the course order
    pin_motion: PinMotion | None  # a mesh cloth's keyframed pins; None: pins stay put
    contact: RobustContact | None  # robust self-contact (simulation.contact); None: course
    # Provot's limit acts (position_passes): the classic model, except under VBD, whose
    # descent solves the springs' own energy (a projection is no energy: docs/integrators.md)
    stretch_limit: bool = True
    iterations: int = 10  # the VBD integrator's sweeps per step (simulation.iterations)
    friction: float = 0.3  # cloth on cloth (cloth.friction): VBD's self-contact
    kernels: StepKernels | None = None  # set by build_system (step_kernels)


# numba types a kernel's arguments in C when it can fingerprint them (arrays, numbers and
# tuples of them); a System holds KernelPointers (its passes, colliders, wind, FEM), which it
# cannot, so each call from Python typed the whole System in Python: 0.5 ms a call, 0.1-0.2 s
# of the README's warm run. A System's fields never change type, so the last few Systems
# keep their type here (strong references: a NamedTuple takes no weak one).
_SYSTEM_TYPES: dict[int, tuple[System, object]] = {}
_SYSTEM_TYPES_KEPT = 16
COLLIDER_ROUNDS = 2  # alternations of the robust self-contact and colliders in a step


@typeof_impl.register(System)
def _typeof_system(system: System, c):
    kept = _SYSTEM_TYPES.get(id(system))
    if kept is not None and kept[0] is system:
        return kept[1]
    fields = [typeof_impl(v, c) for v in system]
    if any(t is None for t in fields):
        return None
    system_type = types.BaseTuple.from_types(fields, System)
    if len(_SYSTEM_TYPES) >= _SYSTEM_TYPES_KEPT:
        del _SYSTEM_TYPES[next(iter(_SYSTEM_TYPES))]  # the oldest
    _SYSTEM_TYPES[id(system)] = (system, system_type)
    return system_type


def build_system(scene: Scene, model: ClothModel) -> System:
    sim = scene.simulation
    mesh = model.mesh
    limit, limit_sq_lo = stretch_limits(model.rest if mesh is None else mesh.springs.rest[None])
    dt = (1.0 / sim.frames_per_sec) / sim.steps_per_frame
    either = scene.wind is not None or scene.self_collision  # see StepKernels
    limit_acts = stretch_limit_acts(scene, model.fem is None)
    centre = model.x0.mean(axis=1)
    offsets, order = direction_offsets(model.nw), gather_order(model.nw)
    extent = max([float(np.linalg.norm(np.subtract(c.pivot, centre))) for c in scene.colliders]
                 + [0.0]) + math.hypot(model.width, model.height)
    system = System(
        classic=model.fem is None,
        collision_box=collision_box(model),
        thickness=model.thickness,
        x0=model.x0,
        pinned=model.pinned,
        exist_bits=existence_bits(model.exists),
        limit=limit,
        limit_sq_lo=limit_sq_lo,
        mass=model.point_mass,
        total_mass=float(model.point_mass.sum()),
        gravity=np.array(sim.gravity, dtype=np.float64),
        dt=dt,
        damping=model.damping,
        force_dt2=dt * dt,
        steps_per_frame=int(sim.steps_per_frame),
        colliders=pack_colliders(scene.colliders, model.n),
        wind=(None if not either else pack_wind(scene.wind, sim.seed, model.nw, model.nh)
              if mesh is None else
              pack_mesh_wind(scene.wind, sim.seed, mesh.topology.triangles, model.n)),
        fem=model.fem if model.fem is not None else no_fem(),
        springs=((offsets, order, model.exists, model.rest, model.stiffness) if mesh is None
                 else mesh.springs),
        needs_velocity=scene.wind is not None,
        self_collision=bool(scene.self_collision) and sim.contact != "robust",
        scratch=(SelfCollisionScratch(model.n if scene.self_collision else 0).as_tuple()
                 if either else None),
        spring_force=(spring_force_buffer(model.n, model.nw) if mesh is None
                      else np.zeros((1, 3, len(mesh.springs.a)))),
        mask=candidate_mask(model.n, present=limit_acts and mesh is None),
        slack_speed=slack_speed(model.thickness, sim.frames_per_sec, scene.self_collision)
        # a moving surface can throw a point at up to twice its own speed (a bounce)
        + max_wind_speed(scene.wind) + 2.0 * max_surface_speed(scene.colliders, extent)
        + (0.0 if mesh is None else mesh.pin_speed),
        reach=new_reach(model.n),
        colliders_last=False,
        pin_motion=None if mesh is None else mesh.pin_motion,
        contact=robust_contact_of(scene, model),
        stretch_limit=limit_acts,
        iterations=int(sim.iterations),
        friction=float(scene.cloth.friction),
    )
    return system._replace(kernels=step_kernels(system))


def stretch_limit_acts(scene: Scene, classic: bool) -> bool:
    """Whether Provot's limit runs: on the classic model, except under the VBD integrator
    (its descent minimises the springs' energy; a projection after it is no energy and
    would undo the solve). Fidelity auto picks its own integrator (never VBD): the limit acts."""
    sim = scene.simulation
    return classic and not (sim.integrator == "vbd" and sim.fidelity != "auto")


def _self_collision_pointers(s: System, field) -> tuple[KernelPointer, KernelPointer]:
    """The self-collision pass (its boxes on the threads from SELF_PARALLEL_POINTS points)
    and the pushes it runs over runs of boxes."""
    present = s.self_collision
    push = KernelPointer(_push_members, (field, s.pinned, s.thickness, s.steps_per_frame,
                                         s.scratch, types.int64, types.int64), present=present)
    loop = (self_collide_in_chunks if s.x0.shape[1] >= SELF_PARALLEL_POINTS else
            self_collide)
    return KernelPointer(loop, (field, s.pinned, *s.collision_box, s.thickness,
                                s.steps_per_frame, s.scratch, push), present=present), push


def step_kernels(s: System) -> StepKernels:
    """Pointers to the System's passes, typed as the stepping kernels call them."""
    field = types.float64[:, ::1]  # positions, last positions, forces: (3, N)
    classic = s.classic
    mesh = isinstance(s.springs, MeshSprings)
    grid = spring_tuple(s.x0.shape[1]) if mesh else s.springs
    offsets, order, exists, rest, stiffness = grid
    springs = spring_kernels(  # a mesh cloth's are absent, typed as an empty grid's
        offsets, exists, rest, stiffness, spring_force_buffer(0, 0) if mesh else s.spring_force,
        order, s.mass, s.gravity, classic and not mesh)
    internal = ((mesh_internal_forces if classic else mesh_fem_internal_forces) if mesh
                else (internal_forces if classic else fem_internal_forces))
    self_collide, self_push = (None, None) if s.scratch is None else \
        _self_collision_pointers(s, field)
    return StepKernels(
        internal=KernelPointer(internal, (
            field, s.fem, s.springs, s.mass, s.gravity, s.spring_force, springs, field)),
        springs=springs,
        collide=KernelPointer(collide_all, (field, field, s.pinned, s.colliders, 0.0, 0.0)),
        stretch=KernelPointer(mesh_limit_stretch if mesh else limit_stretch, (
            field, s.springs, s.exist_bits, s.limit, s.limit_sq_lo, s.pinned, s.mask),
            present=s.stretch_limit),
        self_collide=self_collide, self_push=self_push,
        wind=None if s.wind is None else KernelPointer(
            add_mesh_wind_force if mesh else add_wind_force, (field, field, 0.0, s.wind, field),
            present=s.wind.on),
        reach=KernelPointer(reach_check, (field, s.reach, s.colliders.active, s.thickness)),
        contact=None if s.contact is None else KernelPointer(robust_contact,
                                                             (field, field, s.contact)),
        robust_colliders=None if s.contact is None else KernelPointer(
            robust_colliders, (field, field, s.contact, s.colliders), types.int64))


def spring_tuple(n: int) -> tuple:
    """The grid's springs tuple (System.springs) of a cloth of n points and no springs."""
    return (direction_offsets(0), gather_order(0), np.zeros((6, n), dtype=bool),
            np.zeros((6, n)), np.zeros(6))


def collision_box(model: ClothModel) -> tuple[float, float]:
    """(w, h) of the self-collision boxes (SPEC section 2): 3 width / num_width_points and
    3 height / num_height_points for the grid, 3 x the mean rest edge length for a mesh."""
    if model.mesh is not None:
        side = 3.0 * model.mesh.topology.mean_edge
        return side, side
    return (3.0 * model.width) / model.nw, (3.0 * model.height) / model.nh


def robust_contact_of(scene: Scene, model: ClothModel) -> RobustContact | None:
    """The packed robust contact when the scene asks for it (its self-contact part when
    self-collision is on; its mesh colliders' triangles)."""
    if scene.simulation.contact != "robust":
        return None
    if model.mesh is None:  # the rest shape, whatever positions the run starts from
        rest = initial_grid(scene)
    else:
        from .cloth_mesh import load_cloth_mesh

        rest = np.ascontiguousarray(np.asarray(load_cloth_mesh(scene.cloth.mesh).points).T)
    return pack_contact(scene.cloth.thickness, scene.cloth.friction, model.triangles, rest,
                        model.point_mass, model.pinned, self_on=bool(scene.self_collision),
                        meshes=pack_meshes(scene.colliders, model.n),
                        solids=any(type(c) in (Sphere, Box) for c in scene.colliders))


def slack_speed(thickness: float, frames_per_sec: float, self_collision: bool) -> float:
    """Speed a point may reach without gravity doing work (collision and constraint pushes).

    A self-collision push moves a point by up to 2 * thickness / steps_per_frame in one step
    of dt, i.e. at up to 2 * thickness * frames_per_sec; 0.5 m/s covers the small position
    corrections of collider projection and the stretch limit. build_system adds the other
    energy sources: the fastest wind and the fastest moving collider surface.
    """
    return 0.5 + (2.0 * thickness * frames_per_sec if self_collision else 0.0)


GUARD_FACTOR = 2.0


# The guard's and the passes' kernels take the System's fields, not the System: a kernel
# that takes the System compiles again for each of its types (wind, self-collision), and
# its Python entry point alone (unboxing every array of the System) costs about 0.5 s to
# compile.
# Those that must see the System (forces.total_force too) are inlined into the
# integrator's stepping kernel.


@njit(cache=True, nogil=True, no_cpython_wrapper=True)
def motion_summary(x, previous, x0, mass, g):
    """(all finite, sum over points of m |x - previous|^2, sum over points of m * the drop
    along g since t = 0) for the guard; `previous` is the state one step earlier, x0 the
    state at t = 0."""
    g_norm = np.sqrt(g[0] * g[0] + g[1] * g[1] + g[2] * g[2])
    finite = True
    moved_sq = drop = 0.0
    for p in range(x.shape[1]):
        m = mass[p]
        for a in range(3):
            v = x[a, p] - previous[a, p]
            moved_sq += m * (v * v)
            drop += m * ((x[a, p] - x0[a, p]) * g[a])
    finite = np.isfinite(moved_sq) and np.isfinite(drop)
    return finite, moved_sq, drop / g_norm if g_norm > 0.0 else 0.0


@njit(cache=True, nogil=True, no_cpython_wrapper=True)
def energy_guard(mv_sq_sum, mass_drop, g, total_mass, slack_speed):
    """Kinetic-energy bound of the divergence guard: returns (kinetic energy, bound) in J.

    No physical run gains more kinetic energy than gravity has done work on it, apart from
    the energy sources counted in `slack_speed`: the springs start at rest length, damping
    only removes energy, so
        KE(t) <= |g| * max(0, sum of m_p * drop of p along g since t = 0).
    The guard allows GUARD_FACTOR times that (velocities are finite-difference estimates)
    plus M * slack_speed**2 / 2 (M the cloth's mass) for collision and constraint pushes,
    wind and moving colliders. `mv_sq_sum` is the sum of m |v|^2 over the points,
    `mass_drop` the sum of m * drop, g the gravity, total_mass and slack_speed the System's.
    """
    g_norm = np.sqrt(g[0] * g[0] + g[1] * g[1] + g[2] * g[2])
    kinetic = 0.5 * mv_sq_sum
    bound = (GUARD_FACTOR * g_norm * max(mass_drop, 0.0)
             + 0.5 * total_mass * slack_speed**2)
    return kinetic, bound


def stability_limit(model: ClothModel, samples: int = 181) -> tuple[float, float]:
    """(omega_max, dt_max): highest angular frequency of the cloth and the largest stable
    step of the damped Verlet update for it.

    FEM model: omega_max from fem.estimate_omega_max (power iteration on the flat rest
    sheet, mass map included). Classic model:

    omega_max**2 is the largest eigenvalue of M^-1 K for the infinite lattice with the
    cloth's spacing (a finite cloth's eigenvalues lie below it): for a plane wave with phase
    theta per grid step, each spring direction e (lattice offset o, stiffness k) contributes
    (k / m) * 2 (1 - cos(theta . o)) * e e^T to the 3x3 dynamical matrix; we take its largest
    eigenvalue over a grid of theta in [0, pi] x [-pi, pi] (the maximum for square cells is
    8 ks / m at theta = (pi, 0)). Damped Verlet x' = x + (1 - c)(x - x_last) + a dt^2 is stable
    for omega dt < sqrt(2 (2 - c)), i.e. dt_max = sqrt(2 (2 - c)) / omega_max (~ 2 / omega_max).
    With a mass map, m is the lightest point's mass: M^-1 K has no eigenvalue above
    lambda_max(K) / m_min, so the limit stays on the safe side (tight when the light points
    fill a region larger than a wavelength, as a uniform cloth with a heavier hem does).
    """
    keep = math.sqrt(2.0 * (2.0 - model.damping))
    if model.mesh is not None:
        omega_max = mesh_omega_max(model)
        return omega_max, (keep / omega_max if omega_max > 0.0 else math.inf)
    if model.fem is not None:
        omega_max = estimate_omega_max(model.fem, model.point_mass)
        return omega_max, (keep / omega_max if omega_max > 0.0 else math.inf)
    light = float(model.point_mass.min())  # the lightest point bounds the frequencies
    sx = model.width / (model.nw - 1)
    sy = model.height / (model.nh - 1)
    tx = np.linspace(0.0, math.pi, samples)
    ty = np.linspace(-math.pi, math.pi, 2 * samples - 1)
    theta_x, theta_y = np.meshgrid(tx, ty, indexing="ij")
    # every spring lies in the cloth's plane: the dynamical matrix is [[a, b], [b, c]] there
    # (its third row and column are zero) and its largest eigenvalue has a closed form
    a = np.zeros(theta_x.shape)
    b = np.zeros(theta_x.shape)
    c = np.zeros(theta_x.shape)
    for d in range(6):
        k = model.stiffness[d]
        if k == 0.0:
            continue
        oj, oi = DIRECTION_DJ[d], DIRECTION_DI[d]
        ex, ey = oj * sx, oi * sy
        norm = math.hypot(ex, ey)
        ex, ey = ex / norm, ey / norm
        weight = (k / light) * 2.0 * (1.0 - np.cos(theta_x * oj + theta_y * oi))
        a += weight * (ex * ex)
        b += weight * (ex * ey)
        c += weight * (ey * ey)
    largest = 0.5 * (a + c) + np.hypot(0.5 * (a - c), b)
    omega_max = math.sqrt(max(float(largest.max()), 0.0))
    if omega_max == 0.0:
        return 0.0, math.inf
    return omega_max, keep / omega_max


def mesh_omega_max(model: ClothModel, iterations: int = 60) -> float:
    """omega_max of a mesh cloth: power iteration on M^-1 K at rest, K y from central
    differences of the mesh's forces (pipeline.physics.mesh_forces), pins ignored as the
    grid's lattice bound ignores them. The estimate approaches the largest eigenvalue from
    below, so it is raised by 5 %."""
    from .mesh_forces import mesh_fem_forces, mesh_spring_forces

    x0 = np.ascontiguousarray(model.x0)
    mass, gravity = model.point_mass, np.zeros(3)
    plus, minus = np.zeros_like(x0), np.zeros_like(x0)
    buffer = np.zeros((3, len(model.mesh.springs.a)))

    def forces(x, out):
        if model.fem is None:
            mesh_spring_forces(x, model.mesh.springs, mass, gravity, buffer, out)
        else:
            mesh_fem_forces(x, model.fem, mass, gravity, out)

    y = np.random.default_rng(0).standard_normal(x0.shape)
    eps = 1e-6 * model.mesh.topology.mean_edge
    lam = 0.0
    for _ in range(iterations):
        y /= np.linalg.norm(y)
        forces(x0 + eps * y, plus)
        forces(x0 - eps * y, minus)
        ky = -(plus - minus) / (2.0 * eps) / mass  # M^-1 K y, K = -df/dx
        lam = float(np.sum(y * ky))
        y = ky
    return 1.05 * math.sqrt(max(lam, 0.0))


@register_jitable(inline="always")
def drag_gamma(damping: float, dt: float) -> float:
    """The drag rate gamma (1/s) of losing the fraction `damping` of the velocity per step of
    dt: -ln(1 - damping) / dt, 0 without damping. Plain Python when called from Python,
    inlined when a kernel calls it (drag_rate)."""
    if damping <= 0.0:
        return 0.0
    return -math.log(1.0 - damping) / dt


def damping_at(damping: float, dt0: float, dt: float) -> float:
    """The fraction per step of dt that keeps the drag rate of `damping` per step of dt0:
    1 - (1 - damping)^(dt / dt0)."""
    return 1.0 - (1.0 - damping) ** (dt / dt0)


# --- passes and guard shared by every integrator --------------------------------------------


@njit(cache=True, nogil=True, inline="always")
def drag_rate(system):
    """The scene's damping as a drag rate gamma (1/s): dv/dt = -gamma v loses exactly the
    fraction `system.damping` of the velocity over one step of `system.dt`, as the Verlet
    update does: gamma = -ln(1 - damping) / dt."""
    return drag_gamma(system.damping, system.dt)


@njit(cache=True, nogil=True, inline="always")
def position_passes(x, last, system, t_start):
    """Steps 3-5 of the classic order on the free points of x (3, N), after an integrator's
    update from the start-of-step positions `last` (at time t_start) over one step:
    self-collision (when enabled), the colliders in scene order (friction measured from
    `last`), then Provot's stretch limit (classic model only: the FEM's own stretch
    stiffness bounds its strain; not under VBD: System.stretch_limit). With
    `colliders_last` (fidelity auto) the colliders come
    after Provot, so no point ends a step inside a collider. Passes that pipeline.physics.reach
    proves idle are skipped."""
    s = system
    k = s.kernels
    move_pins(x, last, s.pin_motion, t_start + s.dt)
    k.reach(x, s.reach, s.colliders.active, s.thickness)
    box_w, box_h = s.collision_box
    _self_collision_pass(x, s.pinned, box_w, box_h, s.thickness, s.steps_per_frame, s.scratch,
                         k.self_collide, k.self_push, s.self_collision, s.reach.self_on,
                         s.reach.counts)
    if not s.colliders_last:
        k.collide(x, last, s.pinned, s.colliders, t_start, t_start + s.dt)
    if s.stretch_limit:  # the FEM's stretch pointer is absent (VBD's too)
        k.stretch(x, s.springs, s.exist_bits, s.limit, s.limit_sq_lo, s.pinned, s.mask)
    if s.colliders_last:
        k.collide(x, last, s.pinned, s.colliders, t_start, t_start + s.dt)
    _contact_pass(x, last, s.contact, k.contact, s.colliders, k.robust_colliders)


@njit(cache=True, nogil=True, no_cpython_wrapper=True)
def _contact_pass(x, x0, contact, robust, colliders, robust_colliders):
    if robust is None:  # numba prunes the pass (the course contact)
        return
    robust(x, x0, contact)
    # the colliders' pass may move points into the cloth, and the self-contact's fail-safe
    # (back to x0) into a moving collider: alternate while either moves something, the
    # colliders last (a point inside a collider is never left)
    for _ in range(COLLIDER_ROUNDS):
        if robust_colliders(x, x0, contact, colliders) == 0 or not contact.self_on:
            return
        robust(x, x0, contact)
    robust_colliders(x, x0, contact, colliders)


@njit(cache=True, nogil=True, no_cpython_wrapper=True)
def _self_collision_pass(x, pinned, box_w, box_h, thickness, steps_per_frame, scratch,
                         self_collide, push, on, self_on, counts):
    # `self_collide` is None (numba prunes the pass) or absent (never compiled: 5 s on a
    # first run) when the scene turns self-collision off (`on` False)
    if self_collide is not None and on and self_on[0]:
        counts[1] += 1
        self_collide(x, pinned, box_w, box_h, thickness, steps_per_frame, scratch, push)


@njit(cache=True, nogil=True, no_cpython_wrapper=True)
def corrected_velocities(x, predicted, v, pinned, dt):
    """v += (x - predicted) / dt for every free point: the position passes' correction as a
    velocity change, on top of the integrator's own end-of-step velocity."""
    for p in range(x.shape[1]):
        if pinned[p]:
            continue
        for a in range(3):
            v[a, p] += (x[a, p] - predicted[a, p]) / dt


@njit(cache=True, nogil=True, inline="always")
def step_guard(x, last, system):
    """The shared divergence guard after one step from `last` to x: (ok, kinetic, bound),
    with velocities estimated as (x - last) / dt, exactly as the Verlet integrator does."""
    s = system
    finite, v_sq, drop = motion_summary(x, last, s.x0, s.mass, s.gravity)
    kinetic, bound = energy_guard(v_sq / (s.dt * s.dt), drop, s.gravity, s.total_mass,
                                  s.slack_speed)
    return finite and kinetic <= bound, kinetic, bound
