"""Shared benchmark helpers: minimum-of-repeats timers and the Fig. 6 device in its stiffest state."""

from __future__ import annotations

import time

import numpy as np

from warp_shape.simulator import Simulator

__all__ = ["min_time_per_step", "min_time_per_call", "min_time", "jammed_fig6"]


def min_time_per_step(step, seconds: float, repeats: int, probe: int = 1) -> float:
    """Minimum wall time of one ``step(n)`` call per step, over ``repeats`` runs of about ``seconds``."""
    t0 = time.perf_counter()
    step(probe)
    per = max((time.perf_counter() - t0) / probe, 1e-6)
    n = max(probe, int(seconds / per))
    best = float("inf")
    for _ in range(repeats):
        t0 = time.perf_counter()
        step(n)
        best = min(best, (time.perf_counter() - t0) / n)
    return best


def min_time_per_call(call, device, seconds: float, repeats: int) -> float:
    """Minimum wall time of one call of ``call`` (e.g. a graph replay), over repeats of about
    ``seconds``, synchronizing ``device`` around each timed loop."""
    import warp as wp

    call()
    wp.synchronize_device(device)
    t0 = time.perf_counter()
    for _ in range(5):
        call()
    wp.synchronize_device(device)
    n = max(10, int(seconds / max((time.perf_counter() - t0) / 5, 1e-7)))
    best = float("inf")
    for _ in range(repeats):
        t0 = time.perf_counter()
        for _ in range(n):
            call()
        wp.synchronize_device(device)
        best = min(best, (time.perf_counter() - t0) / n)
    return best


def min_time(fn, repeats: int, enough: float = 5.0) -> float:
    """Minimum wall time of ``repeats`` calls; stops repeating once one call takes ``enough`` s."""
    best = np.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
        if best > enough:
            break
    return best


def jammed_fig6(design, device, integrator, precision, dt=1e-3, substeps=None, launch_mode="graph", air_scale=1.3,
                worlds=1, reestimate_every=None):
    """The Fig. 6 device inflated (air x ``air_scale``), every cell jammed, IPAMs at 20 kPa: its stiffest
    state, in ``worlds`` identical worlds; ``reestimate_every`` None keeps the Simulator's default."""
    more = {} if reestimate_every is None else dict(reestimate_every=reestimate_every)
    sim = Simulator(design, device=device, integrator=integrator, precision=precision, dt=dt, substeps=substeps,
                    launch_mode=launch_mode, worlds=worlds, **more)
    sim.air_moles = sim.air_moles * air_scale
    for c in range(design.n_cells):
        sim.jam(c)
    if design.n_ipams:
        sim.ipam_pressures = np.full(design.n_ipams, 20e3)
    return sim
