"""Time integrators: one internal step from a state into another with the control held (RK4,
semi-implicit), ``solver.step(state_in, state_out, control, dt)`` as in Newton."""

from __future__ import annotations

import numpy as np
import warp as wp

from warp_shape.kernels import integrate as ki

from .errors import SimulationError
from .forces import eval_actuators, eval_hinges
from .model import Control, Model, State
from .physics import Launch
from .physics.damping import eval_init_step
from .simulation_settings import SimulationSettings

__all__ = ["Solver", "RK4Solver", "SemiImplicitSolver", "make_solver", "blowup_error", "BlowupWatch", "INTEGRATORS",
           "BLOWUP_CODES"]

#: the status codes the step kernels write (kernels/integrate.flag_blowup), worst first
BLOWUP_CODES = {4: "positions became non-finite", 3: "velocities became non-finite",
                2: "positions ran away (a vertex left the region around the device)",
                1: "speeds ran away (a vertex crossed the device in one internal step)"}


class Solver:
    """Advances a state by one internal step with the control held constant, for states of ``worlds``
    worlds of ``model``. Stateless over states: ``step(state_in, state_out, control, dt)`` reads
    state_in and writes state_out's positions and velocities; the solver owns only scratch (forces,
    volumes, RK4 stage points) and the blow-up codes ``status``."""

    name = "base"
    # dt_stable = stability_constant / (omega_max + gamma_max)
    stability_constant = 1.0

    def __init__(self, model: Model, worlds: int, paper_bending: bool = False):
        self.model = model
        self.paper_bending = paper_bending
        W, V = worlds, model.n_vertices
        dev = model.device
        self.fg = wp.zeros((2, W, V), dtype=model.vec3, device=dev)  # forces without pressure; dV/dx
        self.f, self.gradv = self.fg[0], self.fg[1]  # (W, V) views
        self.volume = wp.zeros((W, 4), dtype=wp.float64, device=dev)  # volume at each stage point
        # blow-up bounds, checked by the kernel that writes the new state
        rest = model.host.rest_vertices
        center = rest.mean(axis=0)
        self.size = float(2.0 * np.linalg.norm(rest - center, axis=1).max())  # m
        self.x_bound = float(np.linalg.norm(center) + 50.0 * self.size)  # |x| beyond this (m) is a blow-up
        self.rest_x_bound = self.x_bound
        self.status = wp.zeros(W, dtype=wp.int32, device=dev)  # (W,) worst blow-up code since last cleared

    def recenter(self, x: np.ndarray) -> bool:
        """Move the blow-up region with positions x (W, V, 3) set by the user (a rigid move far from the
        rest place is no blow-up); True when the bound changed (a prepared step must be rebuilt)."""
        far = float(np.linalg.norm(x.mean(axis=1), axis=1).max()) + 50.0 * self.size
        bound = max(self.rest_x_bound, far)
        changed = bound != self.x_bound
        self.x_bound = bound
        return changed

    def check_args(self, h: float) -> list:
        """Blow-up bounds for internal step h: |x| and |v| (one mesh size per step)."""
        return [self.model.scalar(self.x_bound), self.model.scalar(self.size / h)]

    def pressure_args(self) -> list:
        """R T (J/mol) and p_atm (Pa) as the kernels take them."""
        m = self.model
        return [wp.float64(m.gas_rt), wp.float64(m.atmospheric_pressure)]

    def launcher(self, launch: Launch | None) -> Launch:
        """``launch``, or a direct launch on the model's device when None."""
        if launch is not None:
            return launch
        return lambda kernel, dim, inputs: wp.launch(kernel, dim, inputs, device=self.model.device)

    def begin(self, state_in: State, launch: Launch):
        """Start the first force evaluation of a step at state_in."""
        eval_init_step(self.model, state_in.xv, self.fg, self.volume, launch)

    def forces(self, state_in: State, control: Control, xv, x, v, slot: int, launch: Launch):
        """Accumulate every force family but pressure (applied by the stage kernel) at xv = (x, v),
        with state_in's jam fields: the fused hinge pass, then each actuator family."""
        eval_hinges(self.model, state_in, xv, self.fg, self.volume, slot, launch, self.paper_bending)
        eval_actuators(self.model, state_in, control, x, v, self.f, launch)

    def prepare(self, state_in: State, state_out: State) -> None:
        """Check the pair of states; state_out takes state_in's jam fields (a step does not change them).
        ``state_out is state_in`` steps in place (the state is not kept)."""
        if state_in.worlds != self.status.shape[0] or state_out.worlds != state_in.worlds:
            raise ValueError(f"this solver steps states of {self.status.shape[0]} worlds, got {state_in.worlds} "
                             f"and {state_out.worlds}")
        if not state_out.shares_jam(state_in):
            state_out.share_jam(state_in)

    def step(self, state_in: State, state_out: State, control: Control, dt: float,
             launch: Launch | None = None):  # pragma: no cover - abstract
        raise NotImplementedError


class SemiImplicitSolver(Solver):
    """Symplectic Euler: first order, one force evaluation per step."""

    name = "semi_implicit"
    stability_constant = 1.9  # omega h < 2 for the undamped oscillator

    def step(self, state_in: State, state_out: State, control: Control, dt: float, launch: Launch | None = None):
        """One internal step ``dt`` (s) from state_in into state_out (see ``Solver``)."""
        m, launch = self.model, self.launcher(launch)
        self.prepare(state_in, state_out)
        W, V = state_in.x.shape
        self.begin(state_in, launch)
        self.forces(state_in, control, state_in.xv, state_in.x, state_in.v, 0, launch)
        launch(ki.integrate_semi_implicit_fused, (W * V,),
               [m.inv_mass, *self.pressure_args(), m.scalar(dt), W, V, *self.check_args(dt), control.air,
                self.fg, self.volume, state_in.xv, state_out.xv, self.status])


class RK4Solver(Solver):
    """Classical explicit fourth-order Runge-Kutta (the paper's reference integrator)."""

    name = "rk4"
    stability_constant = 2.5  # RK4 reaches |lambda h| ~ 2.8 on both axes

    def __init__(self, model: Model, worlds: int, paper_bending: bool = False):
        super().__init__(model, worlds, paper_bending)
        _, W, V = self.fg.shape
        # one (4, W, V) buffer (one kernel argument): the next stage point (x, v), then the weighted slope sums
        self.scratch = wp.zeros((4, W, V), dtype=model.vec3, device=model.device)
        self.stage_xv, self.acc = self.scratch[0:2], self.scratch[2:4]  # (2, W, V) views
        self.xs, self.vs = self.scratch[0], self.scratch[1]

    def step(self, state_in: State, state_out: State, control: Control, dt: float, launch: Launch | None = None):
        """One internal step ``dt`` (s) from state_in into state_out (see ``Solver``)."""
        m, launch = self.model, self.launcher(launch)
        self.prepare(state_in, state_out)
        W, V = state_in.x.shape
        hs = m.scalar(dt)
        self.begin(state_in, launch)
        for stage in range(4):
            if stage == 0:
                self.forces(state_in, control, state_in.xv, state_in.x, state_in.v, stage, launch)
            else:
                self.forces(state_in, control, self.stage_xv, self.xs, self.vs, stage, launch)
            launch(ki.rk4_stage_fused, (W * V,),
                   [m.inv_mass, m.scalar(m.viscous_damping), *self.pressure_args(), hs, stage, W, V,
                    *self.check_args(dt), control.air, self.volume, state_in.xv, self.fg, state_out.xv,
                    self.scratch, self.status])


INTEGRATORS = {"rk4": RK4Solver, "semi_implicit": SemiImplicitSolver}


def make_solver(integrator: str, model: Model, worlds: int = 1, paper_bending: bool = False) -> Solver:
    """The solver for an integrator name ('rk4', 'semi_implicit' and the aliases SimulationSettings
    accepts) for states of ``worlds`` worlds of ``model``; unknown names raise ``DesignError``."""
    key = SimulationSettings(integrator=integrator).integrator
    return INTEGRATORS[key](model, worlds, paper_bending)


def blowup_error(status: np.ndarray, step: int, time: float, h: float, dt_stable: float) -> SimulationError:
    """The error for the worst blow-up code in status (W,) (see BLOWUP_CODES), found after output step
    ``step`` at time ``time`` (s) with internal step h (s) and stable estimate dt_stable (s)."""
    w = int(np.argmax(status))
    safe = 0.5 * min(dt_stable, h)
    what = BLOWUP_CODES[int(status[w])]
    within = (" (within the estimate of the state it was made at: the state changed faster than the estimate "
              "followed, e.g. a violent motion at very high pressure; automatic substeps retry such steps "
              "shorter)") if h <= dt_stable else ""
    return SimulationError(
        f"simulation blew up at output step {step} (t = {time:.6g} s, world {w}): "
        f"{what} with internal step {h:.4g} s; stable estimate "
        f"{dt_stable:.4g} s{within}. Try a smaller step, e.g. dt = {safe:.3g} s with substeps=1, "
        f"or check the inputs (air, pressures, stiffness) for extreme values",
        step=step, quantity=what.split(" ")[0], safe_dt=safe, world=w)


class BlowupWatch:
    """Finds the first output step after which a world's blow-up code (``status`` (W,), written by
    the step kernels) became nonzero, with no host copy per step where the codes live on a GPU.

    Immediate (the default on CPU, where the host reads the codes in place): ``after_step`` looks at
    the codes after every output step. Deferred (the default on a GPU): ``after_step`` replays one
    recorded launch of ``stamp_blowup_kernel``, which notes on the device, per world, the first step
    with a nonzero code; ``poll`` copies those notes (2 W integers) to the host, and is called where
    the host waits for the device anyway (before a re-estimate of the stable step, at the end of
    ``Simulator.step``). Both return None or (step, codes): the first such output step and the (W,)
    codes at that step (zero in the worlds still sane then). Reporting clears the watch.
    """

    def __init__(self, status: wp.array, deferred: bool | None = None):
        self.status = status
        self.deferred = (not status.device.is_cpu) if deferred is None else bool(deferred)
        self.pending = False  # deferred: stamps launched since the last poll
        if self.deferred:
            W, dev = status.shape[0], status.device
            self.first_step = wp.full(W, -1, dtype=wp.int32, device=dev)  # (W,) -1 while sane
            self.first_code = wp.zeros(W, dtype=wp.int32, device=dev)  # (W,)
            self.stamp = wp.launch(ki.stamp_blowup_kernel, W, [0, status, self.first_step, self.first_code],
                                   device=dev, record_cmd=True)
        else:
            self.codes = status.numpy()  # on CPU: the device array itself, read in place

    def after_step(self, step: int):
        """Note output step ``step``; immediate mode reports a blow-up now."""
        if self.deferred:
            self.stamp.set_param_at_index(0, int(step))
            self.stamp.launch()
            self.pending = True
            return None
        if not self.codes.any():
            return None
        codes = self.codes.copy()
        self.status.zero_()
        return int(step), codes

    def reset(self) -> None:
        """Forget every code and note (the state they described was restored)."""
        self.status.zero_()
        if self.deferred:
            self.pending = False
            self.first_step.fill_(-1)
            self.first_code.zero_()

    def poll(self):
        """Report the first blow-up noted since the last report (deferred mode copies the notes)."""
        if not (self.deferred and self.pending):
            return None
        self.pending = False
        first = self.first_step.numpy()
        if not (first >= 0).any():
            return None
        step = int(first[first >= 0].min())
        codes = np.where(first == step, self.first_code.numpy(), 0)
        self.status.zero_()
        self.first_step.fill_(-1)
        self.first_code.zero_()
        return step, codes
