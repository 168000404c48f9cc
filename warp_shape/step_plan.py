"""How one internal step is launched: a captured graph, recorded launches or direct launches."""

from __future__ import annotations

import numpy as np
import warp as wp

from .settings import LAUNCH_MODES

__all__ = ["StepPlan", "Checkpoint"]


class StepPlan:
    """One internal step of a solver, prepared for replay.

    ``build(solver, h)`` records the launches of ``solver.step(h, launch)`` (and their kernel names);
    with mode ``"graph"`` it captures them into a graph (recorded launches where capture is not
    supported), with ``"record"`` it keeps the recorded launches and with ``"direct"`` it launches
    the solver's kernels anew every step. ``run(count)`` takes that many internal steps.
    """

    def __init__(self, device: str, mode: str = "graph"):
        if mode not in LAUNCH_MODES:
            raise ValueError(f"launch mode must be one of {LAUNCH_MODES}, got {mode!r}")
        self.device = device
        self.mode = mode
        self.kind = None  # what build() prepared: "graph", "record" or "direct"; None before
        self.h = None  # the internal step (s) the plan was built for
        self.kernel_names: list[str] = []  # kernel names launched by one internal step
        self.solver = None
        self.commands: list = []
        self.graph = None

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

    def build(self, solver, h: float) -> None:
        """Prepare the launches of one internal step ``h`` (s) of ``solver``."""
        names: list[str] = []
        cmds: list = []

        def record(kernel, dim, inputs):
            names.append(kernel.key)
            cmds.append(wp.launch(kernel, dim, inputs, device=self.device, record_cmd=True))

        solver.step(h, record)
        self.solver, self.h, self.kernel_names = solver, h, names
        self.commands, self.graph, self.kind = cmds, None, "record"
        if self.mode == "direct":
            self.kind = "direct"
        elif self.mode == "graph":
            try:
                with wp.ScopedCapture(device=self.device, force_module_load=False) as capture:
                    for cmd in cmds:
                        cmd.launch()
                self.graph, self.kind = capture.graph, "graph"
            except Exception:  # capture unsupported here: recorded launches are the next best
                self.kind = "record"

    def run(self, count: int) -> None:
        """Take ``count`` internal steps."""
        if self.kind == "graph":
            for _ in range(count):
                wp.capture_launch(self.graph)
        elif self.kind == "record":
            for _ in range(count):
                for cmd in self.commands:
                    cmd.launch()
        else:
            for _ in range(count):
                self.solver.step(self.h, self.direct)


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
        self.views = (xv.numpy(), self.xv.numpy()) if self.cpu else None
        self.host: dict = {}
        self.current = False

    def save(self, xv: wp.array, host: dict) -> None:
        """Keep ``xv`` (copied on its device) and ``host`` (a dict of plain values)."""
        if self.cpu:
            np.copyto(self.views[1], self.views[0])
        else:
            wp.copy(self.xv, xv)
        self.host = dict(host)
        self.current = True

    def restore(self, xv: wp.array) -> dict:
        """Copy the kept state back into ``xv``; return the host values kept with it."""
        if self.cpu:
            np.copyto(self.views[0], self.views[1])
        else:
            wp.copy(xv, self.xv)
        self.current = True
        return dict(self.host)
