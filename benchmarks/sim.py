"""Simulation speed benchmark: steps per second of the Fig. 6 device, Warp beside the NumPy baseline.

Timings on shared machines are noisy: compare rows measured in one run and report the minimum of
repeats."""

from __future__ import annotations

import ctypes
import time

from warp_shape.scenarios import cube_fig6_design

from .common import jammed_fig6, min_time_per_step
from .numpy_baseline import NumpyMembrane

__all__ = ["bench_sim", "format_rows", "keep_numpy_temporaries_on_heap", "BENCH_COLUMNS"]

BENCH_COLUMNS = ["vertices", "integrator", "precision", "steps_per_s", "us_per_step", "ns_per_vertex_step",
                 "launches_per_step", "numpy_steps_per_s", "speedup_vs_numpy"]


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


def bench_sim(device: str = "cpu", subdivisions=(3, 4, 5, 6), integrators=("rk4", "semi_implicit"),
              precisions=("float32", "float64"), repeats: int = 3, seconds: float = 0.3,
              launch_modes=("graph",), numpy: bool = True, numpy_seconds: float = 0.3) -> list[dict]:
    """Internal steps per second of the Fig. 6 device (all force families, cells jammed), Warp beside
    the vectorized NumPy float64 implementation (``numpy_baseline.NumpyMembrane``) at the same internal step.

    Each row: vertices, integrator, precision, launch_mode, device, steps_per_s, us_per_step,
    ns_per_vertex_step, launches_per_step, internal_dt (0.9 x the stable estimate), estimate_ms (one
    stable-step estimate on the host), numpy_steps_per_s and speedup_vs_numpy (Warp / NumPy steps per
    second; None when numpy=False) and numpy_allocator. NumPy and Warp are timed in alternating
    rounds and each keeps its best round, so the ratio compares the two under the same machine load;
    NumPy's large temporaries are kept on the heap (``keep_numpy_temporaries_on_heap``) so that it is
    measured at its best. Timing windows shrink with
    the mesh size (the 40962-vertex NumPy rows are timed over a few steps)."""
    allocator = keep_numpy_temporaries_on_heap() if numpy else "default"
    rows = []
    for sub in subdivisions:
        design = cube_fig6_design(subdivisions=sub)
        V = design.rest.n_vertices
        scale = min(1.0, 2562.0 / V) ** 0.5  # shorter windows on large meshes
        win, np_win = seconds * max(scale, 0.25), numpy_seconds * max(scale, 0.25)
        for integrator in integrators:
            probe = jammed_fig6(design, device, integrator, "float64")
            t0 = time.perf_counter()
            h = 0.9 * probe.stable_dt()
            estimate_ms = (time.perf_counter() - t0) * 1e3
            # every timed case, NumPy first; the rounds interleave them so that a slow spell of a
            # shared machine hits all of them alike, and each keeps its best round
            cases = []
            if numpy:
                nm = NumpyMembrane.from_simulator(probe)
                nm.h = h
                cases.append(("numpy", None, nm.step, np_win))
            for precision in precisions:
                for mode in launch_modes:
                    sim = jammed_fig6(design, device, integrator, precision, dt=h, substeps=1, launch_mode=mode)
                    sim.step(2)  # build the plan, compile, warm caches
                    cases.append(((precision, mode), sim, sim.step, win))
            best = [float("inf")] * len(cases)
            for _ in range(max(1, repeats)):
                for c, (_, _, step, window) in enumerate(cases):
                    best[c] = min(best[c], min_time_per_step(step, window, 1))
            np_per = best[0] if numpy else None
            for (key, sim, _, _), per_step in zip(cases, best):
                if sim is None:
                    continue
                precision, mode = key
                rows.append(dict(
                    vertices=V, integrator=sim.integrator, precision=precision, launch_mode=mode,
                    device=sim.device, steps_per_s=round(1.0 / per_step, 1),
                    us_per_step=round(per_step * 1e6, 2), ns_per_vertex_step=round(per_step * 1e9 / V, 2),
                    launches_per_step=len(sim.step_kernels), internal_dt=h, estimate_ms=round(estimate_ms, 2),
                    numpy_steps_per_s=None if np_per is None else round(1.0 / np_per, 2),
                    speedup_vs_numpy=None if np_per is None else round(np_per / per_step, 1),
                    numpy_allocator=allocator))
    return rows


def format_rows(rows: list[dict], columns: list[str]) -> str:
    """A plain-text table of ``rows`` (dicts) with the given columns, right-aligned."""
    widths = {c: max(len(c), *(len(str(r.get(c, ""))) for r in rows)) for c in columns}
    lines = ["  ".join(c.rjust(widths[c]) for c in columns), "  ".join("-" * widths[c] for c in columns)]
    for r in rows:
        lines.append("  ".join(str(r.get(c, "")).rjust(widths[c]) for c in columns))
    return "\n".join(lines)
