"""Vertex Block Descent (Chen, Liu, Yang and Yuksel, "Vertex Block Descent", ACM TOG 43(4),
2024): backward Euler solved by block coordinate descent on its incremental potential.

One step of length h from (x_t, v_t), with gamma = system.drag_rate (the scene's damping):

    G(x) = (1 + h gamma) / (2 h^2) |x - y|_M^2 + E(x),
    y = x_t + (h v_t + h^2 (g + f_ext / m)) / (1 + h gamma),

E the model's elastic energy (pipeline.physics.vbd_energy: the classic springs, or the FEM's
membrane and bending, on the grid or a mesh cloth), M the System's point masses (mass maps
included), f_ext the other forces (wind) evaluated once at the start of the step. grad G = 0
is exactly backward Euler with the drag taken implicitly, (1 + h gamma) M (x - x_t) / h^2 -
M v_t / h = m g + f_ext + f_elastic(x), the equation implicit-euler linearises once per step;
then v = (x - x_t) / h.

The descent: `iterations` sweeps (simulation.iterations, System.iterations); a sweep visits
the points colour by colour (vbd_energy's greedy colouring: no two points of one colour share
an element, so each update reads only other colours' points, and a colour's points can be
updated on the threads in any order: descend_in_chunks), and moves each free point by
the Newton step of its own 3x3 block, -H_p^-1 grad_p G, H_p = (1 + h gamma) m_p / h^2 I + the
positive semi-definite blocks of its elements (vbd_energy's docstring: the gradient is exact,
the blocks projected). An update is skipped where |det H_p| is tiny (the paper's rule; with
the projected blocks H_p is positive definite, so this is only a guard). Optionally
(State.line_search) each step is followed by a backtracking line search on the point's
own terms of G (the elements it touches and its inertia), halving up to LINE_SEARCH_HALVINGS times, else the point stays,
so that every update, hence every sweep, lowers G (to round-off) whatever the start. It is
off by default: on the 50x50 FEM it made a step 1.6x as costly (29 against 18 ms, four
rounds alternately), and on every start tests/test_vbd.py tries (a sheet stretched 1.6x at
FEM stretch 3000 N/m, random positions; one step per frame) the plain projected Newton
steps already lowered G at every sweep, and a sheet stretched to twice its size recovered
as well without it. No Chebyshev acceleration (it would give up that monotony).

Initial guess: the paper's adaptive one, x = x_t + (h v_t + h^2 a~ g^) / (1 + h gamma), a~
the previous step's acceleration (v_t - v_t-1) / h along gravity, clamped to [0, |g|]: a
cloth at rest on its pins starts where it was, not a step's free fall lower (the inertia
guess x = y). Measured (pinned2's FEM at 20x20, one step per frame, t = 1 s, 10 sweeps
against 300): RMS 0.154 m adaptive, 0.150 m from y; lowest point 0.371 and 0.345 m, the
converged 0.570 m. Neither is near convergence there at 10 sweeps (the sheet sags too far:
block descent is slow to carry the pins' support across the sheet); the paper's guess is kept.

Damping: the scene's own, as the drag rate of the other velocity integrators (system.drag_rate,
taken implicitly as implicit-euler does), so a scene means the same damping under every
integrator and VBD converges to the same backward Euler step as implicit Euler solved
exactly. Rayleigh (stiffness-proportional) damping, the paper's, is another model: not used.

Contact (pipeline.physics.vbd_contact, on by default: State.contact_energies): E includes
penalty energies of the colliders (at their pose at the step's end) and of the cloth's
self-contact pairs (found once per step, in `_predict`), each point's block their PSD
k n n^T and their lagged IPC friction; a point's Newton step that would enter a contact
it is outside of is taken again with that contact linearised (vbd_contact.contact_terms).
Self-contact partners are read from a snapshot taken between colours, so a colour's
updates stay independent of their order and of the thread count.

Pins keep their positions; keyframed pins (a mesh cloth's) are moved to their pose at the end
of the step before the descent, so their neighbours are solved against where the hand is.
Provot's stretch limit is off (System.stretch_limit: a projection is no energy, and would
undo the solve); after the descent come the shared position passes (self-collision,
colliders, robust contact) as the guarantee on top, their corrections as velocity changes
(system.corrected_velocities) and the shared guard, as for the other velocity integrators:
with the contact in the descent they have little left to do (docs/integrators.md).
No explicit stability limit (CONDITIONALLY_STABLE False).
"""
from __future__ import annotations

import numpy as np

from numba.core import types

from clothjit import KernelPointer, njit, prange

from ..forces import CHUNKS, external_force
from ..pin_motion import move_pins
from ..system import (
    System,
    corrected_velocities,
    drag_rate,
    position_passes,
    step_guard,
)
from ..vbd_contact import (FRICTION_SPEED, contact_terms, find_pairs, start_sides, vbd_contact,
                           with_room)
from ..vbd_energy import _hinge_terms, _spring_terms, _triangle_terms, add_terms, vbd_elements
from .euler import VelocityState

NAME = "vbd"
CONDITIONALLY_STABLE = False
LINE_SEARCH_HALVINGS = 8  # then the point keeps its position for this sweep
SINGULAR = 1e-12  # |det H| below SINGULAR (trace / 3)^3: skip the update (never at m > 0)
ROUND_OFF = 1e-13  # a step whose predicted decrease is below this times |G_p|: no search
# From this many points on, each colour's points are updated in parallel (descend_in_chunks):
# an update costs about half a microsecond, so a colour's share pays for its barrier
PARALLEL_POINTS = 1000


class State(VelocityState):
    """Positions, velocities (and the previous step's, for the adaptive guess), the
    inertial target y and each point's inertia weight, the elements and their colouring
    (vbd_energy.VbdElements, built once per System), the contact terms' data and their
    pair search (vbd_contact.VbdContact, PairSearch) and the step's kernels as pointers."""

    adaptive = True  # the paper's adaptive initial guess; False: x = y
    line_search = False  # see the module docstring
    # the colliders and self-contact as energies in the descent (vbd_contact); False: only
    # the position passes after it (read when the State is made)
    contact_energies = True

    def __init__(self, system: System) -> None:
        super().__init__(system)
        n = self.x.shape[1]
        self.v_previous = np.zeros_like(self.x)
        self.y = np.zeros_like(self.x)
        self.inertia = np.zeros(n)  # (1 + h gamma) m / h^2
        self.pin_start = np.zeros_like(self.x)  # keyframed pins' positions at a step's start
        self.elements = vbd_elements(system)
        self.contact, self.search = vbd_contact(system, self.elements, self.last,
                                                self.contact_energies)
        self.predict = KernelPointer(_predict, (
            self.x, self.v, self.v_previous, self.last, self.force, self.y, self.inertia,
            system.pinned, system.mass, system.gravity, 0.0, 0.0, True, self.contact,
            self.search))
        index = types.int64
        self.sweep = KernelPointer(_sweep, (self.x, self.y, self.inertia, system.pinned,
                                            self.elements, self.contact, index, index, True))
        loop = descend_in_chunks if n >= PARALLEL_POINTS else descend
        self.descend = KernelPointer(loop, (self.x, self.y, self.inertia, system.pinned,
                                            self.elements, self.contact, 0, True, self.sweep))
        self.finish = KernelPointer(_velocities, (self.x, self.last, self.v, self.predicted,
                                                  system.pinned, 0.0))

    def arguments(self, system: System, steps: int, first_step: int) -> tuple:
        """The stepping kernel's arguments."""
        return (system, self.x, self.v, self.v_previous, self.last, self.predicted, self.force,
                self.y, self.inertia, self.pin_start, self.elements, self.contact,
                self.search, self.predict, self.descend, self.sweep, self.finish, steps,
                first_step, self.adaptive, self.line_search)

    def advance(self, system: System, steps: int, first_step: int) -> tuple[int, float, float]:
        done = advance(*self.arguments(system, steps, first_step))
        # for the next steps, if the pairs overflowed
        self.contact, self.search = with_room(self.contact, self.search)
        return done


@njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True, pointer=True)
def _predict(x, v, v_previous, last, force, y, inertia, pinned, mass, gravity, gamma, h,
             adaptive, contact, search):
    """last = x; y and the inertia weights; x = the initial guess (adaptive or y); v_previous
    = v. `force` holds gravity and the other forces at the start of the step. Then the
    step's contact data (vbd_contact): the friction's eps, the points' sides of the planes
    and one-sided meshes, the self-contact pairs."""
    g2 = gravity[0] * gravity[0] + gravity[1] * gravity[1] + gravity[2] * gravity[2]
    g_norm = np.sqrt(g2)
    inv_g = 1.0 / g_norm if g_norm > 0.0 else 0.0
    damp = 1.0 / (1.0 + h * gamma)
    for p in range(x.shape[1]):
        m = mass[p]
        inertia[p] = m / (damp * h * h)
        along = 0.0
        for a in range(3):  # the last step's acceleration along gravity
            along += (v[a, p] - v_previous[a, p]) * gravity[a]
        along = min(max(along * inv_g / h, 0.0), g_norm) * inv_g
        for a in range(3):
            xa = x[a, p]
            last[a, p] = xa
            v_previous[a, p] = v[a, p]
            if pinned[p]:
                y[a, p] = xa
                continue
            y[a, p] = xa + damp * (h * v[a, p] + h * h * force[a, p] / m)
            x[a, p] = (xa + damp * (h * v[a, p] + h * h * along * gravity[a]) if adaptive
                       else y[a, p])
    contact.slip[0] = FRICTION_SPEED * h
    if contact.colliders:
        start_sides(contact, pinned)
    if search is not None and contact.self_on:  # (None: numba prunes the call)
        find_pairs(contact, search, y, pinned)


@njit(cache=True, nogil=True, error_model="numpy", forceinline=True, no_cpython_wrapper=True)
def _local(x, y, inertia, el, cn, p):
    """Point p's terms of G (its inertia, the elements it touches and its contacts, with
    their lagged friction: vbd_contact) as (energy, gradient, Hessian block as (xx, yy, zz,
    xy, xz, yz)), and how far it can move before it can enter another contact."""
    w = inertia[p]
    dx, dy, dz = x[0, p] - y[0, p], x[1, p] - y[1, p], x[2, p] - y[2, p]
    energy = 0.5 * w * (dx * dx + dy * dy + dz * dz)
    gx, gy, gz = w * dx, w * dy, w * dz
    hxx = hyy = hzz = w
    hxy = hxz = hyz = 0.0
    terms = (energy, (gx, gy, gz), (hxx, hyy, hzz, hxy, hxz, hyz))
    rows, incident, corner = el.rows, el.incident, el.corner
    for j in range(rows[p, 0], rows[p, 1]):
        terms = add_terms(terms, _spring_terms(x, el, incident[j], corner[j]))
    for j in range(rows[p, 1], rows[p, 2]):
        terms = add_terms(terms, _triangle_terms(x, el, incident[j], corner[j]))
    for j in range(rows[p, 2], rows[p, 3]):
        terms = add_terms(terms, _hinge_terms(x, el, incident[j], corner[j]))
    if not (cn.colliders or cn.self_on):
        return terms, np.inf
    # a call of its own: without contact the loops above stay as lean as before
    # np.bool_, not a literal: numba compiles a kernel once per literal argument
    _, clear, terms = contact_terms(x, inertia, cn, p, terms, np.bool_(False), 0.0, 0.0, 0.0)
    return terms, clear


@njit(cache=True, nogil=True, error_model="numpy", forceinline=True, no_cpython_wrapper=True)
def _newton(g, h):
    """(whether the block h is regular, the step -h^-1 g)."""
    xx, yy, zz, xy, xz, yz = h
    c00 = yy * zz - yz * yz  # cofactors of the symmetric block
    c01 = xz * yz - xy * zz
    c02 = xy * yz - xz * yy
    det = xx * c00 + xy * c01 + xz * c02
    scale = (xx + yy + zz) / 3.0
    if not abs(det) > SINGULAR * scale * scale * scale:
        return False, 0.0, 0.0, 0.0
    c11 = xx * zz - xz * xz
    c12 = xy * xz - xx * yz
    c22 = xx * yy - xy * xy
    inv = 1.0 / det
    return (True, -(c00 * g[0] + c01 * g[1] + c02 * g[2]) * inv,
            -(c01 * g[0] + c11 * g[1] + c12 * g[2]) * inv,
            -(c02 * g[0] + c12 * g[1] + c22 * g[2]) * inv)


@njit(cache=True, nogil=True, error_model="numpy", _nrt=False, forceinline=True,
      no_cpython_wrapper=True)
def _update_point(x, y, inertia, el, cn, p, line_search):
    """One Newton step of point p on its own terms of G (taken again with the contacts the
    step would enter, linearised: vbd_contact.contact_terms), with the line search."""
    terms, clear = _local(x, y, inertia, el, cn, p)
    energy, g, h = terms
    ok, sx, sy, sz = _newton(g, h)
    if not ok:
        return
    if sx * sx + sy * sy + sz * sz >= clear * clear:  # it may enter a contact
        entering, _, (_, g, h) = contact_terms(x, inertia, cn, p, terms, np.bool_(True), sx,
                                               sy, sz)
        if entering:  # h only gained positive semi-definite blocks: still regular
            sx, sy, sz = _newton(g, h)[1:]
    px, py, pz = x[0, p], x[1, p], x[2, p]
    x[0, p], x[1, p], x[2, p] = px + sx, py + sy, pz + sz
    # the quadratic model's decrease; under round-off of G_p, no test can tell (it would
    # halve the step to nothing near convergence): accepted
    decrease = -0.5 * (g[0] * sx + g[1] * sy + g[2] * sz)
    if not line_search or decrease <= ROUND_OFF * abs(energy):
        return
    step = 1.0
    for _ in range(LINE_SEARCH_HALVINGS + 1):
        if _local(x, y, inertia, el, cn, p)[0][0] <= energy:
            return
        step *= 0.5
        x[0, p], x[1, p], x[2, p] = px + step * sx, py + step * sy, pz + step * sz
    x[0, p], x[1, p], x[2, p] = px, py, pz


@njit(cache=True, nogil=True, error_model="numpy", _nrt=False, no_cpython_wrapper=True,
      pointer=True)
def _sweep(x, y, inertia, pinned, el, cn, lo, hi, line_search):
    """Newton steps of the free points order[lo:hi] of one colour, in that order (they share
    no element, and read contact partners from the colour's snapshot: any order gives the
    same bits)."""
    order = el.order
    for i in range(lo, hi):
        p = order[i]
        if pinned[p] == 0:
            _update_point(x, y, inertia, el, cn, p, line_search)


@njit(cache=True, nogil=True, error_model="numpy", forceinline=True, no_cpython_wrapper=True)
def _snapshot(x, cn, order, lo, hi):
    """The self-contact's snapshot of the points order[lo:hi] (vbd_contact: what the next
    colours' updates read of their partners)."""
    if cn.self_on:
        for i in range(lo, hi):
            p = order[i]
            for a in range(3):
                cn.snapshot[a, p] = x[a, p]


@njit(cache=True, nogil=True, error_model="numpy", _nrt=False, no_cpython_wrapper=True,
      pointer=True)
def descend(x, y, inertia, pinned, el, cn, iterations, line_search, sweep):
    """`iterations` sweeps of block coordinate descent on G over the free points, colour by
    colour (vbd_energy.VbdElements' colouring); `sweep` the _sweep pointer. The snapshot
    of the contact partners is taken of every point first, then of each colour once swept."""
    colours, order = el.colour_start, el.order
    _snapshot(x, cn, order, 0, order.shape[0])
    for _ in range(iterations):
        for c in range(colours.shape[0] - 1):
            sweep(x, y, inertia, pinned, el, cn, colours[c], colours[c + 1], line_search)
            _snapshot(x, cn, order, colours[c], colours[c + 1])


@njit(cache=True, nogil=True, parallel=True, no_cpython_wrapper=True, pointer=True)
def descend_in_chunks(x, y, inertia, pinned, el, cn, iterations, line_search, sweep):
    """descend with each colour's points in CHUNKS parts on the threads: one barrier per
    colour, after about PARALLEL_POINTS / colours updates of half a microsecond each (the
    snapshot taken between the colours, on one thread)."""
    colours, order = el.colour_start, el.order
    _snapshot(x, cn, order, 0, order.shape[0])
    for _ in range(iterations):
        for c in range(colours.shape[0] - 1):
            lo, hi = colours[c], colours[c + 1]
            for k in prange(CHUNKS):
                sweep(x, y, inertia, pinned, el, cn, lo + (k * (hi - lo)) // CHUNKS,
                      lo + ((k + 1) * (hi - lo)) // CHUNKS, line_search)
            _snapshot(x, cn, order, lo, hi)


@njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True, pointer=True)
def _velocities(x, last, v, predicted, pinned, h):
    """v = (x - x_t) / h on the free points (backward Euler's); predicted = x, before the
    position passes (system.corrected_velocities)."""
    for p in range(x.shape[1]):
        free = pinned[p] == 0
        for a in range(3):
            if free:
                v[a, p] = (x[a, p] - last[a, p]) / h
            predicted[a, p] = x[a, p]


@njit(cache=True, nogil=True, no_cpython_wrapper=True)
def _restore_pins(last, start, motion):
    """The keyframed pins' last positions back to the step's start (position_passes moved
    them again and took their last positions from there)."""
    if motion is None:
        return
    for i in range(motion.point.shape[0]):
        p = motion.point[i]
        for a in range(3):
            last[a, p] = start[a, p]


@njit(cache=True, nogil=True, inline="always")
def _collider_poses(table, contact, t_start, t_end):
    """The keyframed colliders' poses at the step's start and end, for the descent's
    contact (the colliders' pass computes the same again: colliders.collide_all)."""
    if contact.colliders:
        for n in table.key_count:  # the poses pointer is absent without keyframes
            if n:
                table.poses(table.keys, table.key_count, table.pose, t_start, t_end)
                return


@njit(cache=True, nogil=True)
def advance(s, x, v, v_previous, last, predicted, force, y, inertia, pin_start, elements,
            contact, search, predict, descend_, sweep, finish, steps, first_step, adaptive,
            line_search):
    """Run `steps` steps; returns (steps done, kinetic energy, bound) like verlet.advance."""
    gamma = drag_rate(s)
    kinetic = bound = 0.0
    for step in range(steps):
        t = (first_step + step) * s.dt
        external_force(x, v, t, s.mass, s.gravity, s.wind, s.kernels.wind, force)
        _collider_poses(s.colliders, contact, t, t + s.dt)
        predict(x, v, v_previous, last, force, y, inertia, s.pinned, s.mass, s.gravity, gamma,
                s.dt, adaptive, contact, search)
        move_pins(x, pin_start, s.pin_motion, t + s.dt)  # the hand where the step ends
        descend_(x, y, inertia, s.pinned, elements, contact, s.iterations, line_search, sweep)
        finish(x, last, v, predicted, s.pinned, s.dt)
        position_passes(x, last, s, t)
        _restore_pins(last, pin_start, s.pin_motion)
        corrected_velocities(x, predicted, v, s.pinned, s.dt)
        ok, kinetic, bound = step_guard(x, last, s)
        if not ok:
            return step + 1, kinetic, bound
    return steps, kinetic, bound

