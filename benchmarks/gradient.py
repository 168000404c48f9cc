"""Cost of a gradient: the adjoint of a replayed control sequence beside the forward replay.

``bench_gradient``: the paper's law drives the Fig. 6 device to the cube once per mesh; its sequence
is then replayed open loop (``ws.replay``, the simulator's fused step, float32 as the product runs
and float64 as the gradient does) and differentiated (``ws.gradient``, float64, every parameter;
with the next segment recomputed on a second thread where the process may use two cores, as
``ws.gradient`` does by default, and on one thread, ``threads=1``), side by side in alternating
repeats (the best of each is kept). Memory: the peak resident set
while the gradient runs above the process's resident set before it (Linux: the peak is reset through
/proc/self/clear_refs; elsewhere the process's lifetime peak is reported).
"""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path

from warp_shape.controller import control, open_loop
from warp_shape.gradients import gradient
from warp_shape.scenarios import cube_fig6_design
from warp_shape.targets import target

__all__ = ["bench_gradient", "GRADIENT_COLUMNS"]

GRADIENT_COLUMNS = ["vertices", "output_steps", "internal_steps", "replay_s", "replay64_s", "gradient_s",
                    "ratio", "ratio_f32", "serial_s", "serial_ratio_f32", "segment", "rss_mb", "peak_extra_mb"]


def _rss_mb(field: str) -> float:
    """VmRSS or VmHWM of this process in MB (0 where /proc is absent)."""
    status = Path("/proc/self/status")
    if not status.exists():
        return 0.0
    for line in status.read_text().splitlines():
        if line.startswith(field + ":"):
            return float(line.split()[1]) / 1024.0
    return 0.0


def _reset_peak() -> None:
    try:
        Path("/proc/self/clear_refs").write_text("5")
    except OSError:
        pass


def _best(call, repeats: int) -> float:
    best = float("inf")
    for _ in range(repeats):
        t0 = time.perf_counter()
        call()
        best = min(best, time.perf_counter() - t0)
    return best


def bench_gradient(device: str = "cpu", subdivisions=(2, 3, 4), repeats: int = 3) -> list[dict]:
    """One row per mesh: vertices, output and internal steps of the sequence, the best wall time of the
    forward replay (float32 and float64) and of the gradient (float64), their ratios (gradient over the
    float64 replay; over the float32 replay, the product's), the gradient on one thread and its ratio
    to the float32 replay, the checkpoint segment (output steps) and
    the gradient's peak memory above the process's resident set (MB)."""
    rows = []
    cube = target("cube")
    for sub in subdivisions:
        design = cube_fig6_design(subdivisions=sub)
        result = control(design, cube, method="paper", device=device)
        gradient(design, result, cube, device=device)  # compile and warm
        t_replay = t_replay64 = t_grad = t_serial = float("inf")
        sim64 = result.settings.simulation.replace(precision="float64")
        result64 = dataclasses.replace(result, settings=dataclasses.replace(result.settings, simulation=sim64))
        g = None
        rss = peak = 0.0
        for _ in range(repeats):
            t_replay = min(t_replay, _best(lambda: replay(design, result, device=device), 1))
            t_replay64 = min(t_replay64, _best(lambda: replay(design, result64, device=device), 1))
            rss = _rss_mb("VmRSS")
            _reset_peak()
            t0 = time.perf_counter()
            g = gradient(design, result, cube, device=device)
            t_grad = min(t_grad, time.perf_counter() - t0)
            peak = max(peak, _rss_mb("VmHWM") - rss)
            t_serial = min(t_serial, _best(lambda: gradient(design, result, cube, device=device, threads=1), 1))
        rows.append(dict(vertices=design.rest.n_vertices, output_steps=int(round(result.history["time"][-1] /
                                                                                 result.settings.simulation.dt)),
                         internal_steps=g.internal_steps, replay_s=round(t_replay, 4), replay64_s=round(t_replay64, 4),
                         gradient_s=round(t_grad, 4), ratio=round(t_grad / t_replay64, 2),
                         ratio_f32=round(t_grad / t_replay, 2), serial_s=round(t_serial, 4),
                         serial_ratio_f32=round(t_serial / t_replay, 2),
                         segment=g.segment, rss_mb=round(rss, 1), peak_extra_mb=round(peak, 1)))
    return rows
