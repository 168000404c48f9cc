"""Quasi-static settle: the equilibrium of the current controls, on every world at once.

Where a run only holds its controls until the membrane is at rest, the rest state is a minimum of
the potential energy (springs, bending, gas p_atm V - n R T ln V, actuators) at the held controls
and jam state; ``StaticSettle`` finds it with limited-memory BFGS in Warp kernels
(``kernels.equilibrium``) instead of integrating the damped motion there. One iteration is one force
evaluation through the step's own fused force kernels (at zero velocity, so dampers vanish) and one
update kernel; the iterations are captured into a graph where the device allows it and the host looks
at the per-world flags between them. docs/equilibria.md describes the method, where it is valid and
what it costs.

Guards, as in a step: a trial point with non-finite forces, a vertex beyond the blow-up region or no
chamber (volume <= 0) is rejected and a shorter step taken; a world whose step shrinks to nothing
stalls, and a start that is not a valid state is reported. ``Simulator.settle_static`` raises
``SimulationError`` for those worlds, and for a settled membrane that passes through itself.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import warp as wp

from warp_shape.kernels import equilibrium as ke

from .forces import eval_actuators, eval_hinges
from .model import Control, Model, State
from .physics.pressure import eval_pressure_gradient
from .step_plan import create_overloads

__all__ = ["StaticSettle", "Equilibrium", "FORCE_TOLERANCE", "MAX_ITERATIONS", "MEMORY", "STATUS_NAMES"]

#: converged when every vertex's residual force is below this (N), per precision: float32 forces of the
#: Fig. 6 device round at a few 1e-6 N (a residual of 1e-5 N leaves the shape within 1 um of the minimum)
FORCE_TOLERANCE = {"float32": 1.0e-5, "float64": 1.0e-7}
#: force evaluations a settle may take before it gives up on the worlds still iterating
MAX_ITERATIONS = 3000
#: history pairs of the L-BFGS iteration
MEMORY = 8
#: sufficient-decrease constant c1 of the line search
SUFFICIENT_DECREASE = 1.0e-4
#: most a vertex moves in one iteration, as a fraction of the device's size
MAX_MOVE = 0.02
#: a step whose largest vertex move is below this fraction of the device's size stalls
MIN_MOVE = 1.0e-12
#: accepted steps without the residual halving after which a world stops where it is (its rounding floor)
PATIENCE = 200
#: iterations between two looks at the flags where reading them costs a copy (GPU)
CHECK_EVERY = 10

STATUS_NAMES = {0: "not converged", 1: "converged", 2: "stalled (no step lowers the energy)",
                3: "invalid start (non-finite forces or no chamber)",
                4: "stopped at the rounding floor (the residual stopped falling above the tolerance)"}


@dataclass
class Equilibrium:
    """What a static settle did, per world: ``status`` (W,) int (see STATUS_NAMES), ``evaluations``
    (W,) force evaluations, ``residual`` (W,) largest vertex force at the end (N), ``energy_change``
    (W,) estimated potential energy change (J, <= 0), and ``iterations``: the batch's force evaluations."""

    status: np.ndarray
    evaluations: np.ndarray
    residual: np.ndarray
    energy_change: np.ndarray
    iterations: int

    @property
    def converged(self) -> np.ndarray:
        """(W,) bool: the residual force is below the tolerance, or it stopped falling above it (the
        precision's rounding floor, status 4)."""
        return (self.status == 1) | (self.status == 4)


class StaticSettle:
    """Buffers and launches of the L-BFGS settle for states of ``worlds`` worlds of ``model``.

    ``x_bound``: |x| beyond this (m) is a runaway (the step's blow-up bound); ``size``: the device's
    size (m), scaling the largest and the smallest move of one iteration; ``paper_bending``: refused,
    since eq. (9)'s forces are no energy's gradient and have no equilibrium to find."""

    def __init__(self, model: Model, worlds: int, x_bound: float, size: float, memory: int = MEMORY):
        self.model, self.worlds, self.memory = model, int(worlds), int(memory)
        self.x_bound, self.size = float(x_bound), float(size)
        W, V, dev, vec = self.worlds, model.n_vertices, model.device, model.vec3
        self.xv = wp.zeros((2, W, V), dtype=vec, device=dev)  # trial point, zero velocities
        self.fg = wp.zeros((2, W, V), dtype=vec, device=dev)  # forces, dV/dx at the trial point
        self.volume = wp.zeros((W, 1), dtype=wp.float64, device=dev)
        self.x0 = wp.zeros((W, V), dtype=vec, device=dev)
        self.g0 = wp.zeros((W, V), dtype=vec, device=dev)
        self.d = wp.zeros((W, V), dtype=vec, device=dev)
        self.precond = wp.zeros((W, V), dtype=model.scalar, device=dev)
        self.hist_s = wp.zeros((self.memory, W, V), dtype=vec, device=dev)
        self.hist_y = wp.zeros((self.memory, W, V), dtype=vec, device=dev)
        self.rho = wp.zeros((self.memory, W), dtype=wp.float64, device=dev)
        self.coef = wp.zeros((self.memory, W), dtype=wp.float64, device=dev)
        self.flags = wp.zeros((W, ke.N_FLAGS), dtype=wp.int32, device=dev)
        self.scalars = wp.zeros((W, ke.N_SCALARS), dtype=wp.float64, device=dev)
        self.cpu = wp.get_device(dev).is_cpu
        self._flags_view = self.flags.numpy() if self.cpu else None  # host memory: read in place
        self._plans: dict = {}  # (id(state), id(control), tolerance) -> prepared iteration
        self._overloads_made = False

    def _launch(self, kernel, dim, inputs):
        wp.launch(kernel, dim, inputs, device=self.model.device)

    def _iteration(self, state: State, control: Control, tolerance: float, launch) -> None:
        """One iteration: the force at every trial point, then the update kernel."""
        m, W, V = self.model, self.worlds, self.model.n_vertices
        eval_hinges(m, state, self.xv, self.fg, self.volume, 0, launch, False)
        eval_actuators(m, state, control, self.xv[0], self.xv[1], self.fg[0], launch)
        eval_pressure_gradient(m, control, self.fg, self.volume, 0, launch)
        launch(ke.lbfgs_iterate_kernel, (W,),
               [V, self.memory, wp.float64(tolerance), wp.float64(MAX_MOVE * self.size),
                wp.float64(MIN_MOVE * self.size), wp.float64(self.x_bound), wp.float64(SUFFICIENT_DECREASE), PATIENCE,
                int(all(f.rigid_invariant for f in m.families)),
                self.precond, self.volume, self.fg, self.xv, self.x0, self.g0, self.d, self.hist_s, self.hist_y,
                self.rho, self.coef, self.flags, self.scalars])

    def _plan(self, state: State, control: Control, tolerance: float):
        """The iteration prepared for replay: a captured graph where possible, else recorded launches."""
        key = (id(state), id(control), float(tolerance), self.x_bound)
        if key in self._plans:
            return self._plans[key]
        cmds = []
        dev = self.model.device
        self._iteration(state, control, tolerance,
                        lambda k, dim, inputs: cmds.append(wp.launch(k, dim, inputs, device=dev, record_cmd=True)))
        run = None
        try:
            with wp.ScopedCapture(device=dev, force_module_load=False) as capture:
                for c in cmds:
                    c.launch()
            graph = capture.graph
            run = lambda: wp.capture_launch(graph)  # noqa: E731
        except Exception:  # capture unsupported here: the recorded launches
            run = lambda: [c.launch() for c in cmds]  # noqa: E731
        if len(self._plans) >= 4:  # a simulator alternates between two states: keep a few
            self._plans.clear()
        self._plans[key] = run
        return run

    def solve(self, state: State, control: Control, tolerance: float | None = None,
              max_iterations: int = MAX_ITERATIONS) -> Equilibrium:
        """Minimise every world's potential energy at its controls and jam state from ``state``'s
        positions; writes the minimum into ``state.x`` and zeroes ``state.v``. ``tolerance``: the
        residual force (N) of a converged world (None: ``FORCE_TOLERANCE`` of the model's precision)."""
        m, W, V = self.model, self.worlds, self.model.n_vertices
        tolerance = FORCE_TOLERANCE[m.precision] if tolerance is None else float(tolerance)
        if state.worlds != W:
            raise ValueError(f"this settle holds {W} worlds, got a state of {state.worlds}")
        start = (ke.lbfgs_start_kernel, (W, V), [state.x, self.xv, self.fg, self.volume, self.flags, self.scalars])
        precondition = [(ke.diagonal_stiffness_kernel, (W, m.n_edges), [m.hinges, state.edge, self.precond])]
        for fam in m.families:  # each family's part of the diagonal
            fam.diagonal_stiffness(m, state, self.precond, lambda *launch: precondition.append(launch), control=control)
        precondition.append((ke.invert_diagonal_kernel, (W, V), [m.scalar(self._stiffness_floor()), self.precond]))
        if not self._overloads_made:  # every module of the solve loads once with all its overloads
            iteration = []
            self._iteration(state, control, tolerance, lambda *launch: iteration.append(launch))
            create_overloads([start] + precondition + iteration)
            self._overloads_made = True
        self._launch(*start)
        wp.copy(self.x0, state.x)
        self.d.zero_()
        self.precond.zero_()
        for launch in precondition:
            self._launch(*launch)
        run = self._plan(state, control, tolerance)
        done = 0
        while done < max_iterations:
            n = 1 if self.cpu else min(CHECK_EVERY, max_iterations - done)
            for _ in range(n):
                run()
            done += n
            flags = self._flags_view if self.cpu else self.flags.numpy()
            if not flags[:, ke.F_ACTIVE].any():
                break
        wp.copy(state.x, self.x0)
        state.v.zero_()
        flags, sc = self.flags.numpy(), self.scalars.numpy()
        return Equilibrium(status=flags[:, ke.F_STATUS].copy(), evaluations=flags[:, ke.F_EVALS].copy(),
                           residual=sc[:, ke.S_FMAX].copy(), energy_change=sc[:, ke.S_DE].copy(), iterations=done)

    def _stiffness_floor(self) -> float:
        """Least diagonal stiffness given to a vertex (N/m): a millionth of the mean edge stiffness."""
        return 1e-6 * float(np.mean(self.model.host.edge_stiffness)) + 1e-300
