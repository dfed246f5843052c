"""What a run will model and why (`render plan`, `Simulation.plan`), and fidelity auto's
choice of integrator: the figures the controller, the pilots and pipeline.physics.reach
give, in one record."""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field

from pipeline.scene import Scene

from .controller import (CHECK_COST, COARSE_RATIO, IMPLICIT_COST, PILOT_SECONDS, PILOT_STEPS,
                         SLEEP_TIME, STABILITY_MARGIN, gusty, metres_per_pixel, pilot_text,
                         wake_time)


@dataclass
class Plan:
    """What `fidelity` will model and why (`render plan`, `Simulation.plan`)."""

    fidelity: str
    model: str  # "classic" or "fem"
    integrator: str
    steps_per_frame_exact: int
    steps_per_frame_min: int  # auto: the stability floor (x2 for the error estimate)
    steps_per_frame_start: int
    steps_per_frame_max: int
    tolerance_px: float | None
    metres_per_px: float | None  # at the cloth's nearest point, the scene's camera
    image_height: int
    stability_limit_s: float
    self_collision: str
    colliders: list[dict] = field(default_factory=list)
    sleeps: str = ""
    predicted_cost: float = 1.0  # steps (x points, on a coarse grid) per frame against exact's
    reasons: list[str] = field(default_factory=list)
    pilot: dict | None = None  # auto, classic model: the pilot's figures once it has run
    chaotic: bool = False  # auto, classic model with contact or gusts: the file's steps
    grid: tuple[int, int] = (0, 0)  # points across and down: the file's
    #: auto, FEM: the grid pilot's figures (pipeline.fidelity.fem_grid.GridChoice.as_dict), or why
    #: there is no pilot (grid_reason)
    grid_choice: dict | None = None
    grid_reason: str = ""
    #: a mesh cloth (cloth.mesh): {"file", "points", "triangles"}; None for the grid
    mesh: dict | None = None
    #: how the integrator solves a step, where that is a choice (VBD's sweeps), else ""
    solver: str = ""
    #: where Provot's limit may stop (keyframed pins under robust contact), else ""
    stretch_limit: str = ""

    def as_dict(self) -> dict:
        return asdict(self)

    def lines(self) -> list[str]:
        """The plan as text, one fact a line."""
        out = [f"fidelity {self.fidelity}: integrator {self.integrator}"
               + (f" ({self.solver})" if self.solver else "")]
        if self.fidelity == "exact":
            out.append(f"steps per frame {self.steps_per_frame_exact} (as the file says)")
        else:
            out.append(f"tolerance {self.tolerance_px:g} px = {self.metres_per_px * 1e3:.3g} mm at "
                       f"the cloth's nearest point ({self.image_height} px high image)")
            if self.pilot is not None:
                out.append(f"steps per frame {self.steps_per_frame_start} for the whole shot "
                           f"(exact: {self.steps_per_frame_exact}), {pilot_text(self.pilot)} (the "
                           "classic model's stretch limit acts once per step, so the step "
                           "count is fixed for the shot; docs/fidelity.md)")
            elif self.model == "classic" and self.chaotic:
                out.append(f"steps per frame {self.steps_per_frame_start}, as the file says: "
                           "under contact, self-collision or gusts the classic model's motion "
                           "depends on the step chaotically, so more steps buy no accuracy "
                           "(docs/fidelity.md)")
            elif self.model == "classic":
                out.append(f"steps per frame (at least {self.steps_per_frame_min}; exact: "
                           f"{self.steps_per_frame_exact}): chosen for the whole shot by a "
                           f"pilot run of the first {PILOT_SECONDS:g} s at two step counts, "
                           "and a third at the steps they ask for where that is more: the "
                           "classic model's stretch limit acts once per step, so the step "
                           "count is fixed for the shot (docs/fidelity.md)")
            else:
                out.append(f"steps per frame {self.steps_per_frame_min}.."
                           f"{self.steps_per_frame_max}, starting at "
                           f"{self.steps_per_frame_start} (exact: {self.steps_per_frame_exact}),"
                           " chosen per frame by step doubling")
        if self.mesh is not None:
            out.append(self._mesh_line())
        elif self.fidelity == "auto" and self.model == "fem":
            out.append(self._grid_line())
        out.append(f"self-collision: {self.self_collision}")
        if self.stretch_limit:
            out.append(f"stretch limit: {self.stretch_limit}")
        for c in self.colliders:
            out.append(f"collider {c['name']}: {c['status']}")
        if self.sleeps:
            out.append(f"sleep: {self.sleeps}")
        if self.fidelity == "auto" and self.model == "classic" and not (self.pilot or
                                                                          self.chaotic):
            n1 = max(PILOT_STEPS, self.steps_per_frame_min)
            out.append(f"predicted cost: set by the pilot, which itself costs {3 * n1} steps "
                       f"per frame over its {PILOT_SECONDS:g} s, plus its third run's where it "
                       "checks the convergence (the shot goes on from a pilot run where that "
                       "is cheaper); nothing while asleep")
        elif self.fidelity == "auto" and self.grid_choice and self.grid_choice["chosen"]:
            w, h = self.grid_choice["chosen"]
            out.append(f"predicted cost: {self.predicted_cost:.2f}x exact's (steps x points, on "
                       f"the {w}x{h} grid) at the start (error estimates included), after the "
                       "grid pilot; nothing while asleep")
        elif self.fidelity == "auto":
            out.append(f"predicted cost: {self.predicted_cost:.2f}x exact's steps at the start "
                       f"(error estimates included), nothing while asleep")
        out.extend(self.reasons)
        return out

    def _mesh_line(self) -> str:
        """The plan's line on a mesh cloth (in place of the FEM grid's)."""
        m = self.mesh
        line = f"mesh: {m['points']} points, {m['triangles']} triangles from {m['file']}"
        if self.fidelity == "auto" and self.model == "fem":
            line += f" (no FEM grid pilot: {self.grid_reason})"
        return line

    def _grid_line(self) -> str:
        """The plan's line on the FEM grid (fidelity auto)."""
        from .fem_grid import grid_text

        g = self.grid_choice
        if g is None:
            return (f"FEM grid: the file's {self.grid[0]}x{self.grid[1]}, no grid pilot: "
                    f"{self.grid_reason}")
        drawn = " (frames drawn on the file's grid)" if g["chosen"] else ""
        return f"FEM grid by a {grid_text(g)}{drawn}"


def choose_integrator(scene: Scene, dt_max: float) -> tuple[str, list[str]]:
    """The cheaper of Verlet at its stability floor and implicit Euler at the steps the file
    gives (the accuracy its author found enough: implicit Euler has no floor, but it is first
    order and damps, and needs at least as many steps for the same error), with why."""
    sim = scene.simulation
    frame_dt = 1.0 / sim.frames_per_sec
    floor = math.ceil(frame_dt / (STABILITY_MARGIN * dt_max)) if math.isfinite(dt_max) else 1
    if sim.model != "classic":  # the FEM's error estimate runs a coarser pass too
        floor = math.ceil(COARSE_RATIO * floor)
    floor = max(2, floor)
    implicit = IMPLICIT_COST[sim.model] * sim.steps_per_frame
    why = (f"Verlet needs >= {floor} steps per frame for stability (dt_max {dt_max:.3g} s); "
           f"implicit Euler at the file's {sim.steps_per_frame} would cost about "
           f"{implicit:.0f} Verlet steps per frame")
    return ("implicit-euler" if implicit < floor else "verlet"), [why]


def make_plan(sim) -> Plan:
    """The plan of a Simulation (auto or exact)."""
    scene = sim.scene
    s = scene.simulation
    auto = sim.stepper is not None
    points = sim.model.x0.T
    colliders = []
    for c, obj in enumerate(scene.colliders):
        name = f"{type(obj).__name__.lower()} {c}"
        if not auto:
            status = "on every step"
        elif obj.keyframes:
            status = "keyframed: on every step"
        else:
            from pipeline.physics.reach import clearance

            gap = clearance(obj, points)
            status = (f"{gap:.3g} m from the cloth at t = 0: skipped while no point can reach it "
                      "(checked every step)" if gap > 0 else
                      "touching the cloth at t = 0: on while it can act")
        if sim.system.contact is not None:  # robust contact
            status += ("; robust: no point path and no triangle through it" if
                       type(obj).__name__ in ("Sphere", "Box") else
                       "; robust: each point kept on the side it came from" if
                       type(obj).__name__ == "Plane" else
                       "; robust: no point path and no edge through its triangles")
        colliders.append({"name": name, "status": status})
    if sim.system.contact is not None and sim.system.contact.self_on:
        self_collision = ("robust contact on every step: point-triangle and edge-edge pairs "
                          f"kept {scene.cloth.thickness:g} m apart, continuous collision "
                          "detection and a fail-safe (the cloth never passes through itself)")
    elif not sim.system.self_collision:
        self_collision = "off" + (" (horizontal cloth)" if s.self_collision == "auto" else "")
    elif auto:
        self_collision = ("on, skipped while no two points can come within 2 x thickness "
                          f"({2 * scene.cloth.thickness:g} m; checked every step)")
    else:
        self_collision = "on every step"
    plan = Plan(fidelity=s.fidelity, model=s.model, integrator=sim.integrator,
                steps_per_frame_exact=s.steps_per_frame, steps_per_frame_min=s.steps_per_frame,
                steps_per_frame_start=s.steps_per_frame, steps_per_frame_max=s.steps_per_frame,
                tolerance_px=None, metres_per_px=None, image_height=scene.render.height,
                stability_limit_s=sim.dt_max, self_collision=self_collision,
                colliders=colliders, grid=(sim.model.nw, sim.model.nh),
                grid_choice=None if sim.grid_choice is None else sim.grid_choice.as_dict(),
                grid_reason=sim.grid_reason)
    if sim.integrator == "vbd":
        plan.solver = (f"Vertex Block Descent, {sim.system.iterations} sweeps per step"
                       + ("; no stretch limit: Provot's is no energy" if sim.model.fem is None
                          else ""))
    if sim.limit_watch is not None:
        plan.stretch_limit = ("Provot's, stopped if the keyframed pins pull two points beyond "
                              "its reach (no state keeps it then; robust contact comes first)")
    mesh = sim.model.mesh
    if mesh is not None:
        plan.mesh = {"file": str(mesh.source), "points": int(sim.model.n),
                     "triangles": int(len(mesh.topology.triangles))}
        plan.grid_reason = plan.grid_reason or "a mesh cloth has no grid to coarsen"
    if auto:
        st = sim.stepper
        plan.steps_per_frame_min, plan.steps_per_frame_start = st.n_min, st.n
        plan.steps_per_frame_max, plan.tolerance_px = st.n_max, st.tolerance
        plan.metres_per_px = metres_per_pixel(st.camera, points)
        plan.pilot, plan.chaotic = st.pilot, st.chaotic and not st.adaptive
        plan.predicted_cost = (CHECK_COST if st.adaptive else 1.0) * st.n / s.steps_per_frame
        if sim.coarse is not None:  # fewer points too
            plan.predicted_cost *= sim.coarse.model.n / sim.model.n
        wake = wake_time(scene, 0.0)
        plan.sleeps = ("never: the gusts vary in time" if gusty(scene) else
                       "when at rest for " f"{SLEEP_TIME:g} s" + (
                           "" if wake is None else " outside the keyframed motion"))
        plan.reasons = sim.integrator_reasons
    return plan

