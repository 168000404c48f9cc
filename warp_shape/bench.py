"""Speed benchmarks. Timings on shared machines are noisy: compare rows measured in one run and
report the minimum of repeats."""

from __future__ import annotations

import time

import numpy as np

__all__ = ["bench_sim", "format_rows"]


def _time_steps(sim, seconds: float, repeats: int) -> float:
    """Minimum wall time per internal step over ``repeats`` runs of about ``seconds`` each."""
    sim.step(2)  # build the plan, compile, warm caches
    t0 = time.perf_counter()
    sim.step(5)
    per = max((time.perf_counter() - t0) / 5, 1e-6)
    n = max(5, int(seconds / per))
    best = float("inf")
    for _ in range(repeats):
        t0 = time.perf_counter()
        sim.step(n)
        best = min(best, (time.perf_counter() - t0) / n)
    return best / sim.substeps


def bench_sim(device: str = "cpu", subdivisions=(3, 4, 5), integrators=("rk4", "semi_implicit"),
              precisions=("float32", "float64"), repeats: int = 3, seconds: float = 0.3,
              launch_modes=("graph",)) -> list[dict]:
    """Internal steps per second of the Fig. 6 device (all force families, cells jammed)."""
    from .scenarios import cube_fig6_design
    from .simulator import Simulator

    rows = []
    for sub in subdivisions:
        design = cube_fig6_design(subdivisions=sub)
        for integrator in integrators:
            for precision in precisions:
                for mode in launch_modes:
                    probe = Simulator(design, device=device, integrator=integrator, precision=precision)
                    probe.air_moles = probe.air_moles * 1.3
                    for c in range(design.n_cells):
                        probe.jam(c)
                    h = 0.9 * probe.stable_dt()
                    sim = Simulator(design, device=device, integrator=integrator, precision=precision, dt=h,
                                    substeps=1, launch_mode=mode)
                    sim.air_moles = probe.air_moles
                    for c in range(design.n_cells):
                        sim.jam(c)
                    sim.ipam_pressures = np.full(design.n_ipams, 20e3)
                    per_step = _time_steps(sim, seconds, repeats)
                    V = design.rest.n_vertices
                    rows.append(dict(vertices=V, integrator=sim.integrator, precision=precision, launch_mode=mode,
                                     device=sim.device, steps_per_s=round(1.0 / per_step, 1),
                                     us_per_step=round(per_step * 1e6, 2),
                                     ns_per_vertex_step=round(per_step * 1e9 / V, 2),
                                     launches_per_step=len(sim.step_kernels), internal_dt=h))
    return rows


def format_rows(rows: list[dict], columns: list[str]) -> str:
    widths = {c: max(len(c), *(len(str(r.get(c, ""))) for r in rows)) for c in columns}
    lines = ["  ".join(c.rjust(widths[c]) for c in columns), "  ".join("-" * widths[c] for c in columns)]
    for r in rows:
        lines.append("  ".join(str(r.get(c, "")).rjust(widths[c]) for c in columns))
    return "\n".join(lines)
