"""Simulation speed benchmark: steps per second of the Fig. 6 device, Warp beside the NumPy baseline.

Timings on shared machines are noisy: compare rows measured in one run and report the minimum of
repeats."""

from __future__ import annotations

import ctypes
import gc
import time

from warp_shape.scenarios import cube_fig6_design

from .common import jammed_fig6, min_time_per_step
from .numpy_baseline import NumpyMembrane

__all__ = ["bench_sim", "format_rows", "keep_numpy_temporaries_on_heap", "rate", "BENCH_COLUMNS"]

BENCH_COLUMNS = ["vertices", "integrator", "precision", "steps_per_s", "us_per_step", "ns_per_vertex_step",
                 "vertex_steps_per_s", "launches_per_step", "numpy_steps_per_s", "speedup_vs_numpy"]


def keep_numpy_temporaries_on_heap() -> str:
    """Stop glibc from mapping and unmapping every large NumPy temporary; returns what was set.

    glibc serves allocations above its mmap threshold (128 KiB at start, raised only after such a
    block is freed) with fresh mappings, so each NumPy temporary of a mesh above ~2k vertices is
    page-faulted in again on every use. Whether the threshold has been raised depends on the
    process's allocation history, which made the NumPy baseline bimodal (up to 1.7x slower by
    chance). A fixed 32 MiB threshold (glibc's maximum) keeps those blocks on the heap for the rest
    of the process, giving NumPy its best and a steady time."""
    try:
        libc = ctypes.CDLL("libc.so.6")
        m_trim_threshold, m_mmap_threshold = -1, -3
        if libc.mallopt(m_mmap_threshold, 32 << 20) and libc.mallopt(m_trim_threshold, 1 << 30):
            return "glibc mmap threshold 32 MiB"
    except (OSError, AttributeError):
        pass
    return "default"


def rate(x: float) -> float:
    """A rate for the tables: one decimal from 100 up, four significant digits below."""
    return round(x, 1) if x >= 100 else float(f"{x:.4g}")


def _ns(x: float) -> float:
    """Nanoseconds for the tables: two decimals from 10 up, four significant digits below."""
    return round(x, 2) if x >= 10 else float(f"{x:.4g}")


def _time_cases(cases: list, repeats: int) -> list[float]:
    """Best time per step of each (key, sim, step, window) case over alternating rounds."""
    best = [float("inf")] * len(cases)
    for _ in range(max(1, repeats)):
        for c, (_, _, step, window) in enumerate(cases):
            best[c] = min(best[c], min_time_per_step(step, window, 1))
    return best


def _world_rows(design, device, integrator, h, worlds, precisions, launch_modes, nm, windows, repeats,
                reestimate_every, extra) -> list[dict]:
    """Rows of one integrator at ``worlds`` worlds (NumPy, one world, timed alongside when ``nm``)."""
    V = design.rest.n_vertices
    win, np_win = windows
    cases = [("numpy", None, nm.step, np_win)] if nm is not None else []
    for precision in precisions:
        for mode in launch_modes:
            sim = jammed_fig6(design, device, integrator, precision, dt=h, substeps=1, launch_mode=mode,
                              worlds=worlds, reestimate_every=reestimate_every)
            sim.step(2)  # build the plan, compile, warm caches
            cases.append(((precision, mode), sim, sim.step, win))
    best = _time_cases(cases, repeats)
    np_per = best[0] if nm is not None else None
    rows = []
    for (key, sim, _, _), per_step in zip(cases, best):
        if sim is None:
            continue
        precision, mode = key
        rows.append(dict(
            vertices=V, worlds=worlds, integrator=sim.integrator, precision=precision, launch_mode=mode,
            device=sim.device, steps_per_s=rate(1.0 / per_step), us_per_step=round(per_step * 1e6, 2),
            ns_per_vertex_step=_ns(per_step * 1e9 / (V * worlds)),
            vertex_steps_per_s=round(V * worlds / per_step), launches_per_step=len(sim.step_kernels),
            internal_dt=h, numpy_steps_per_s=None if np_per is None else round(1.0 / np_per, 2),
            speedup_vs_numpy=None if np_per is None else round(worlds * np_per / per_step, 1), **extra))
    return rows


def bench_sim(device: str = "cpu", subdivisions=(3, 4, 5, 6), integrators=("rk4", "semi_implicit"),
              precisions=("float32", "float64"), repeats: int = 3, seconds: float = 0.3,
              launch_modes=("graph",), numpy: bool = True, numpy_seconds: float = 0.3, worlds=(1,),
              reestimate_every: int | None = None) -> list[dict]:
    """Internal steps per second of the Fig. 6 device (all force families, cells jammed), Warp beside
    the vectorized NumPy float64 implementation (``numpy_baseline.NumpyMembrane``) at the same internal step.

    Each row: vertices, worlds (copies of the device stepped as one batch), integrator, precision,
    launch_mode, device, steps_per_s (batch steps), us_per_step, ns_per_vertex_step and
    vertex_steps_per_s (vertices x worlds x steps per second: for RK4 rows, vertex-RK4-steps/s),
    launches_per_step, internal_dt (0.9 x the stable estimate), estimate_ms (one stable-step estimate
    of one world on the host), numpy_steps_per_s (one world) and speedup_vs_numpy (Warp / NumPy
    vertex-steps per second; None when numpy=False) and numpy_allocator. NumPy and Warp are timed in
    alternating rounds and each keeps its best round, so the ratio compares the two under the same
    machine load; NumPy's large temporaries are kept on the heap (``keep_numpy_temporaries_on_heap``)
    so that it is measured at its best. Timing windows shrink with the mesh size (the 40962-vertex
    NumPy rows are timed over a few steps). ``reestimate_every`` None keeps the Simulator's periodic
    stable-step re-estimate (host work, per world); 0 leaves it out to time the step kernels alone."""
    allocator = keep_numpy_temporaries_on_heap() if numpy else "default"
    rows = []
    for sub in subdivisions:
        design = cube_fig6_design(subdivisions=sub)
        V = design.rest.n_vertices
        scale = max(min(1.0, 2562.0 / V) ** 0.5, 0.25)  # shorter windows on large meshes
        for integrator in integrators:
            probe = jammed_fig6(design, device, integrator, "float64")
            t0 = time.perf_counter()
            h = 0.9 * probe.stable_dt()
            estimate_ms = (time.perf_counter() - t0) * 1e3
            nm = None
            if numpy:
                nm = NumpyMembrane.from_simulator(probe)
                nm.h = h
            extra = dict(estimate_ms=round(estimate_ms, 2), numpy_allocator=allocator)
            for w in worlds:
                rows += _world_rows(design, device, integrator, h, int(w), precisions, launch_modes, nm,
                                    (seconds * scale, numpy_seconds * scale), repeats, reestimate_every, extra)
                gc.collect()  # free one batch's device arrays before the next is built
    return rows


def format_rows(rows: list[dict], columns: list[str]) -> str:
    """A plain-text table of ``rows`` (dicts) with the given columns, right-aligned."""
    widths = {c: max(len(c), *(len(str(r.get(c, ""))) for r in rows)) for c in columns}
    lines = ["  ".join(c.rjust(widths[c]) for c in columns), "  ".join("-" * widths[c] for c in columns)]
    for r in rows:
        lines.append("  ".join(str(r.get(c, "")).rjust(widths[c]) for c in columns))
    return "\n".join(lines)
