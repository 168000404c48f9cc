"""How one internal step is launched: a captured graph, recorded launches or direct launches."""

from __future__ import annotations

import numpy as np
import warp as wp

from .simulation_settings import LAUNCH_MODES

__all__ = ["StepPlan", "Checkpoint", "create_overloads"]


def create_overloads(launches) -> None:
    """Create the overload of every generic kernel among ``launches`` ((kernel, dim, inputs)) before any
    of them is launched, so that each module they use is built once with all of them (a Warp module
    compiles every overload it has when loaded, and a launch that adds one rebuilds it; the cost with a
    cold cache: docs/performance.md). An overload that exists already is left as it is (no rebuild)."""
    for kernel, _, inputs in launches:
        if kernel.is_generic:
            wp.overload(kernel, kernel.infer_argument_types(inputs))


class StepPlan:
    """One internal step of a solver between two states, prepared for replay in both directions.

    ``build(solver, h, states, control)`` records the launches of ``solver.step(states[0], states[1],
    control, h)`` and of the step back (their kernel names: those of one step); with mode ``"graph"``
    it captures each direction into a graph (a captured graph binds its arrays, so one per
    direction; recorded launches where capture is not supported), with ``"record"`` it keeps the
    recorded launches and with ``"direct"`` it launches the solver's kernels anew every step.
    ``run(count)`` takes that many internal steps, each from the current state (``states[parity]``)
    into the other, so a step never overwrites the state it starts from; ``parity`` says which
    state holds the latest step.
    """

    def __init__(self, device: str, mode: str = "graph"):
        if mode not in LAUNCH_MODES:
            raise ValueError(f"launch mode must be one of {LAUNCH_MODES}, got {mode!r}")
        self.device = device
        self.mode = mode
        self.kind = None  # what build() prepared: "graph", "record" or "direct"; None before
        self.h = None  # the internal step (s) the plan was built for
        self.kernel_names: list[str] = []  # kernel names launched by one internal step
        self.parity = 0  # the index in ``states`` of the current state
        self.solver = None
        self.states: tuple = ()
        self.control = None
        self.commands: list = [[], []]  # per direction: the recorded launches of states[p] -> states[1 - p]
        self.graphs: list = [None, None]

    @property
    def built(self) -> bool:
        """Whether build() has prepared a plan."""
        return self.kind is not None

    def invalidate(self) -> None:
        """Forget the prepared plan (its launch arguments changed); the next use rebuilds it."""
        self.kind = None

    def direct(self, kernel, dim, inputs):
        """Launch a kernel now on the plan's device (the ``launch`` callable of direct mode)."""
        wp.launch(kernel, dim, inputs, device=self.device)

    def _record(self, solver, h: float, state_in, state_out, control) -> tuple[list, list]:
        launches: list = []
        solver.step(state_in, state_out, control, h, lambda *launch: launches.append(launch))
        create_overloads(launches)  # each module of the step loads once with them all
        return ([kernel.key for kernel, _, _ in launches],
                [wp.launch(kernel, dim, inputs, device=self.device, record_cmd=True) for kernel, dim, inputs in launches])

    def _capture(self, cmds: list):
        with wp.ScopedCapture(device=self.device, force_module_load=False) as capture:
            for cmd in cmds:
                cmd.launch()
        return capture.graph

    def build(self, solver, h: float, states: tuple | None = None, control=None) -> None:
        """Prepare the launches of one internal step ``h`` (s) of ``solver`` between ``states`` (a pair
        of states of its model) under ``control`` (both: those of the last build when None)."""
        a, b = states if states is not None else self.states
        control = control if control is not None else self.control
        names, forward = self._record(solver, h, a, b, control)
        _, back = self._record(solver, h, b, a, control)
        self.solver, self.h, self.kernel_names = solver, h, names
        self.states, self.control = (a, b), control
        self.commands, self.graphs, self.kind = [forward, back], [None, None], "record"
        if self.mode == "direct":
            self.kind = "direct"
        elif self.mode == "graph":
            try:
                self.graphs = [self._capture(forward), self._capture(back)]
                self.kind = "graph"
            except Exception:  # capture unsupported here: recorded launches are the next best
                self.graphs, self.kind = [None, None], "record"

    def run(self, count: int) -> None:
        """Take ``count`` internal steps, each from the current state into the other."""
        p = self.parity
        if self.kind == "graph":
            graphs = self.graphs
            for _ in range(count):
                wp.capture_launch(graphs[p])
                p = self.parity = 1 - p
        elif self.kind == "record":
            commands = self.commands
            for _ in range(count):
                for cmd in commands[p]:
                    cmd.launch()
                p = self.parity = 1 - p
        else:
            st = self.states
            for _ in range(count):
                self.solver.step(st[p], st[1 - p], self.control, self.h, self.direct)
                p = self.parity = 1 - p


class Checkpoint:
    """The last good state of a simulator: a copy of what a step changes (positions and velocities,
    ``xv``) and the host values that go with it (counters).

    ``save`` copies on the device (no host transfer; on CPU a plain memory copy of the array's own
    memory), ``restore`` copies back and returns the host values saved with it. ``current`` is True
    while the copy equals the state (a save, until the state is changed).
    """

    def __init__(self, xv: wp.array):
        self.xv = wp.clone(xv)
        self.cpu = xv.device.is_cpu
        # on CPU both arrays are host memory: numpy views of them copy without a launch
        self.kept_view = self.xv.numpy() if self.cpu else None
        self.views: list = []  # (array, its numpy view) of every array saved or restored (CPU)
        self.host: dict = {}
        self.current = False

    def _view(self, xv: wp.array):
        for arr, view in self.views:
            if arr is xv:
                return view
        self.views.append((xv, xv.numpy()))
        return self.views[-1][1]

    def save(self, xv: wp.array, host: dict) -> None:
        """Keep ``xv`` (copied on its device) and ``host`` (a dict of plain values)."""
        if self.cpu:
            np.copyto(self.kept_view, self._view(xv))
        else:
            wp.copy(self.xv, xv)
        self.host = dict(host)
        self.current = True

    def restore(self, xv: wp.array) -> dict:
        """Copy the kept state back into ``xv``; return the host values kept with it."""
        if self.cpu:
            np.copyto(self._view(xv), self.kept_view)
        else:
            wp.copy(xv, self.xv)
        self.current = True
        return dict(self.host)
