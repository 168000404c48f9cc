"""Controller benchmark: wall time and fit of the paper's law and of model-based control, side by side.

Cases: the Fig. 6 device (642 vertices) driven to the cube with 1, 3 and 5 of its IPAMs (each with
the cells around its ends), and the oval/heart design problem's final design (designed here with the
paper's law in every round) driven to both its targets in one batch. Each case runs ``method="paper"``
(minimum of ``repeats``) and ``method="inverse"`` (one run, it takes far longer) in the same process.
"""

from __future__ import annotations

import time
from contextlib import contextmanager

import numpy as np

from warp_shape.controller import ControlSettings, control_many
from warp_shape.controller.history import History
from warp_shape.controller.laws import PaperLaw
from warp_shape.controller import loop as control_loop
from warp_shape.controller.loop import run_law
from warp_shape.controller.observe import Observer
from warp_shape.display import Design
from warp_shape.designer import design
from warp_shape.io.scene_read import load_scene
from warp_shape.sampling import RadialSampler
from warp_shape.scenarios import cube_fig6_design
from warp_shape.simulator import Simulator
from warp_shape.step_plan import StepPlan
from warp_shape.targets import target

__all__ = ["bench_control", "fig6_with_ipams", "CONTROL_COLUMNS", "control_breakdown", "BREAKDOWN_COLUMNS"]

CONTROL_COLUMNS = ["case", "vertices", "ipams", "targets", "paper_s", "inverse_s", "ratio", "paper_objective",
                   "inverse_objective", "paper_mare_mm", "inverse_mare_mm", "plans", "iterations", "world_steps"]


BREAKDOWN_COLUMNS = ["worlds", "vertices", "periods", "period_ms", "device_ms", "step_kernels_ms", "ray_kernels_ms",
                     "host_ms", "host_share", "observe_ms", "stable_step_ms", "law_ms", "record_ms", "other_host_ms"]

#: the phases of a control period timed by ``control_breakdown``: (name, owner, method); the first two
#: are kernels (the step, the radial sampling's rays), the others host work
_PHASES = (("step_kernels", StepPlan, "run"), ("ray_kernels", RadialSampler, "launch"),
           ("observe", Observer, "observe"), ("stable_step", Simulator, "stable_dt"), ("law", PaperLaw, "step"),
           ("record", History, "record"), ("loop", control_loop, "_run"))
_KERNELS = ("step_kernels", "ray_kernels")


@contextmanager
def _timed(phases, clock=time.process_time):
    """Wrap each (name, owner, method) of ``phases`` with ``clock`` (default: the process's CPU time,
    which other jobs on a shared machine do not inflate); yields the {name: seconds} totals, each
    without the time of the timed calls made inside it. Only the outermost phase (the last) counts
    calls made outside every timed call (the others, e.g. the sampling of a setup, run untimed)."""
    totals = {name: 0.0 for name, _, _ in phases}
    stack = []
    originals = [(owner, method, getattr(owner, method)) for _, owner, method in phases]

    outer = phases[-1][0]

    def wrap(name, fn):
        def timed(*args, **kwargs):
            if not stack and name != outer:
                return fn(*args, **kwargs)
            stack.append(0.0)
            t0 = clock()
            try:
                return fn(*args, **kwargs)
            finally:
                dt = clock() - t0
                inner = stack.pop()
                totals[name] += dt - inner
                if stack:
                    stack[-1] += dt
        return timed

    for (name, _, _), (owner, method, fn) in zip(phases, originals):
        setattr(owner, method, wrap(name, fn))
    try:
        yield totals
    finally:
        for owner, method, fn in originals:
            setattr(owner, method, fn)


def _differing_targets(worlds: int) -> list:
    """``worlds`` targets, all different: the four shipped shapes in turn, each scaled a little."""
    base = [target(n) for n in ("cube", "oval", "pear", "heart")]
    return [base[w % 4].scaled(1.0 + 0.002 * (w // 4)) for w in range(worlds)]


def control_breakdown(worlds: int = 64, periods: int = 20, device: str = "cpu", subdivisions: int = 3) -> dict:
    """Where a control period's time goes for ``worlds`` differing worlds (the paper's law driving the
    Fig. 6 device, 642 vertices at ``subdivisions`` 3, to different targets): the kernels (device: the
    step, the radial sampling's rays) against the host work (observation, stable-step estimates, the
    law, the history, the rest of the loop), per period over ``periods`` control periods of the
    control loop (``BREAKDOWN_COLUMNS``; the setup before the loop is not counted). On a CPU device in
    CPU time of this process (the kernels run on the host's core too), on CUDA in wall time ("device":
    the time the host spends launching and waiting for the kernels). The worlds jam cells in the first
    periods (each jam re-estimates the stable step), so more ``periods`` weigh the steady state more."""
    d = cube_fig6_design(subdivisions=subdivisions)
    targets = _differing_targets(worlds)
    settings = ControlSettings(method="paper", max_steps=periods, max_settle_steps=0)
    run_law(d, targets[:1], PaperLaw, device=device, settings=settings.replace(max_steps=2))  # warm up: kernels loaded
    clock = time.process_time if str(device).startswith("cpu") else time.perf_counter
    with _timed(_PHASES, clock) as totals:
        results = run_law(d, targets, PaperLaw, device=device, settings=settings)
    n = max(int(max(r.control_steps for r in results)), 1)
    wall = sum(totals.values())  # the control loop (the setup before it is not a control period's)
    device_s = sum(totals[k] for k in _KERNELS)
    host = wall - device_s
    ms = lambda v: round(1e3 * v / n, 2)  # noqa: E731
    return dict(worlds=worlds, vertices=d.rest.n_vertices, periods=n, period_ms=ms(wall), device_ms=ms(device_s),
                step_kernels_ms=ms(totals["step_kernels"]), ray_kernels_ms=ms(totals["ray_kernels"]), host_ms=ms(host),
                host_share=round(host / wall, 3), observe_ms=ms(totals["observe"]),
                stable_step_ms=ms(totals["stable_step"]), law_ms=ms(totals["law"]), record_ms=ms(totals["record"]),
                other_host_ms=ms(totals["loop"]))


def fig6_with_ipams(n: int, subdivisions: int = 3) -> Design:
    """The Fig. 6 device keeping its first ``n`` IPAMs and the two cells around each one's ends."""
    full = cube_fig6_design(subdivisions=subdivisions)
    d = Design(full.rest, full.material)
    for ip in full.ipams[:n]:
        d.add_ipam(ip.face_a, ip.face_b)
    for cell in full.cells[:2 * n]:
        d.add_cell(cell.faces)
    return d


def _oval_heart_design(device: str) -> tuple[Design, list]:
    sc = load_scene("oval_heart")
    opts = sc.settings["designer"]
    res = design(sc.design.rest, sc.targets, actuators=opts["actuators"], target_names=sc.target_names,
                 cell_radius=opts["cell_radius"], device=device, control_settings=ControlSettings(method="paper"))
    return res.design, list(sc.targets)


def _case(name: str, design: Design, targets: list, device: str, repeats: int) -> dict:
    paper_s = np.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        paper = control_many(design, targets, device=device, method="paper")
        paper_s = min(paper_s, time.perf_counter() - t0)
    t0 = time.perf_counter()
    inverse = control_many(design, targets, device=device, method="inverse")
    inverse_s = time.perf_counter() - t0
    fmt = lambda vals, k=1.0: " ".join(f"{k * v:.4f}" for v in vals)  # noqa: E731
    return dict(case=name, vertices=design.rest.n_vertices, ipams=design.n_ipams, targets=len(targets),
                paper_s=round(paper_s, 2), inverse_s=round(inverse_s, 2), ratio=round(inverse_s / paper_s, 1),
                paper_objective=fmt(r.objective for r in paper),
                inverse_objective=fmt(r.objective for r in inverse),
                paper_mare_mm=fmt((r.mare for r in paper), 1e3), inverse_mare_mm=fmt((r.mare for r in inverse), 1e3),
                plans=" ".join(r.refinement["plan"] if not r.refinement["fell_back"] else "paper(kept)"
                               for r in inverse),
                iterations=" ".join(str(r.refinement["iterations"]) for r in inverse),
                world_steps=sum(r.refinement.get("world_steps", 0) for r in inverse[:1]))


def bench_control(device: str = "cpu", repeats: int = 3, ipam_counts=(1, 3, 5), oval_heart: bool = True) -> list[dict]:
    """One row per case (``CONTROL_COLUMNS``): wall time and fit of both methods."""
    cube = target("cube")
    control_many(fig6_with_ipams(1, 2), [cube], device=device, method="paper")  # warm up: kernels loaded
    rows = [_case(f"fig6 cube, {n} IPAM{'s' if n > 1 else ''}", fig6_with_ipams(n), [cube], device, repeats)
            for n in ipam_counts]
    if oval_heart:
        d, targets = _oval_heart_design(device)
        rows.append(_case("oval_heart final design", d, targets, device, repeats))
    return rows
