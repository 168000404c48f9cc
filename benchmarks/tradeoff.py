"""Speed/accuracy trade-off benchmark: the error of the Fig. 6 shape against wall time, per numerical setting.

``bench_tradeoff``: record the Fig. 6 control sequence once (air, IPAM pressures and jam steps per
control step), replay it open loop under every integrator x internal step x precision x bending
variant x mesh resolution, and measure the achieved shape's error against a reference (float64,
RK4, an eighth of the automatic step, same mesh; for the resolution axis, the finest mesh sampled
radially) beside the wall time. The Pareto front (least error for the time) is taken per mesh;
the default is marked.

``bench_settle``: the other axis, how a hold until rest is found: the Fig. 6 device after its cells
jam and its IPAMs step to 150 / -20 kPa, settled by RK4 until the largest vertex speed is below
the controller's ``settle_speed`` against the quasi-static settle (``Simulator.settle_static``),
each in both precisions: force evaluations, wall time (minimum of repeats) and the shape's distance
to a float64 static settle at a tight tolerance (rigid motion taken out; raw beside it).
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass

import numpy as np

from warp_shape.controller import control
from warp_shape.static_settle import FORCE_TOLERANCE
from warp_shape.sampling import radial_sample
from warp_shape.scenarios import cube_fig6_design
from warp_shape.simulator import Simulator
from warp_shape.targets import target

from .common import jammed_fig6
from .membrane import LAW_MATERIALS

__all__ = ["ControlSequence", "record_sequence", "replay", "bench_tradeoff", "bench_settle", "pareto_front",
           "SETTLE_COLUMNS", "MEMBRANE_COLUMNS", "bench_membrane_axis"]

MEMBRANE_COLUMNS = ["vertices", "law", "integrator", "precision", "substeps", "wall_s", "error_mm"]

SETTLE_COLUMNS = ["vertices", "settle", "precision", "criterion", "evaluations", "wall_s", "residual_n", "error_um",
                  "error_raw_um"]


@dataclass
class ControlSequence:
    """An open-loop control sequence: per control step the air (relative to the rest amount),
    the IPAM pressures (Pa) and the cells to jam at that step."""

    dt: float
    period: int
    air_relative: np.ndarray  # (n,) n / n_rest applied from step k on
    pressures: np.ndarray  # (n, n_ipam) Pa applied from step k on
    jam_step: np.ndarray  # (n_cell,) control step at which each cell jams, -1 never

    @property
    def steps(self) -> int:
        return len(self.air_relative)


def record_sequence(design, target, **control_overrides) -> ControlSequence:
    """Run the controller (the paper's law unless ``method`` is given) once and keep what it commanded."""
    res = control(design, target, **{"method": "paper", **control_overrides})
    h = res.history
    n0 = h["air_mol"][0]
    P = np.stack([h[f"ipam{i}_pressure_pa"] for i in range(design.n_ipams)], axis=1) if design.n_ipams \
        else np.zeros((len(h["step"]), 0))
    # the row of step k holds the state before step k's update: the update is the next row's controls
    return ControlSequence(dt=res.settings.simulation.dt, period=res.settings.control_period,
                           air_relative=np.append(h["air_mol"][1:], h["air_mol"][-1]) / n0,
                           pressures=np.vstack([P[1:], P[-1:]]), jam_step=res.jam_steps.copy())


def replay(design, seq: ControlSequence, *, integrator="rk4", precision="float32", substeps=None, bending="exact",
           device="cpu", internal_dt=None):
    """Apply a sequence open loop; returns (final positions (V, 3), wall seconds, substeps used)."""
    if internal_dt is not None:
        substeps = max(1, int(round(seq.dt / internal_dt)))
    sim = Simulator(design, device=device, integrator=integrator, dt=seq.dt, precision=precision, substeps=substeps,
                    bending=bending)
    n_rest = sim.air_moles
    sim.step(0)
    t0 = time.perf_counter()
    for k in range(seq.steps - 1):
        for c in np.flatnonzero(seq.jam_step == k):
            sim.jam(int(c))
        sim.air_moles = n_rest * seq.air_relative[k]
        if design.n_ipams:
            sim.ipam_pressures = seq.pressures[k]
        sim.step(seq.period)
    return sim.positions, time.perf_counter() - t0, sim.substeps


def _stepped_fig6(design, precision: str, device: str):
    """The Fig. 6 device inflated to 1.3 x its rest air and at rest, every cell jammed there, then its
    IPAMs stepped to 150 kPa (the four corner ones) and -20 kPa (the face one)."""
    sim = Simulator(design, device=device, precision=precision)
    sim.air_moles = sim.air_moles * 1.3
    for _ in range(100):
        sim.step(10)
        if np.linalg.norm(sim.velocities, axis=1).max() < 1e-3:
            break
    for c in range(design.n_cells):
        sim.jam(c)
    sim.ipam_pressures = np.where(np.arange(design.n_ipams) < 4, 150e3, -20e3)
    return sim


def _rigid_distance(a: np.ndarray, b: np.ndarray) -> float:
    """Largest vertex distance (m) between a and b once b is moved onto a by the best rigid motion."""
    ca, cb = a.mean(axis=0), b.mean(axis=0)
    u, _, vt = np.linalg.svd((b - cb).T @ (a - ca))
    r = (u @ np.diag([1.0, 1.0, np.sign(np.linalg.det(u @ vt))]) @ vt).T
    return float(np.linalg.norm(a - ((b - cb) @ r.T + ca), axis=1).max())


def bench_settle(device: str = "cpu", subdivisions: int = 3, repeats: int = 3, settle_speed: float = 1e-3) -> list[dict]:
    """RK4 settle against static settle after the Fig. 6 jam + IPAM step (module docstring)."""
    design = cube_fig6_design(subdivisions=subdivisions)
    starts = {p: _stepped_fig6(design, p, device) for p in ("float32", "float64")}
    refs = {p: sim.snapshot() for p, sim in starts.items()}
    ref_sim = starts["float64"]
    ref_sim.settle_static(tolerance=1e-10, max_iterations=20000)
    x_ref = np.asarray(ref_sim.positions)
    rows = []
    for settle in ("dynamic", "static"):
        for precision in ("float32", "float64"):
            sim = Simulator(design, device=device, precision=precision)
            best, evals, x = np.inf, 0, None
            for _ in range(repeats):
                sim.load_worlds(refs[precision])
                sim.velocities = np.zeros((design.rest.n_vertices, 3))
                if settle == "dynamic":
                    assert sim.substeps  # the stable-step estimate of the loaded state, outside the timing
                    t0, steps = time.perf_counter(), 0
                    while True:
                        sim.step(1)
                        steps += 1
                        if np.linalg.norm(sim.velocities, axis=1).max() < settle_speed:
                            break
                    wall = time.perf_counter() - t0
                    evals = steps * sim.substeps * 4
                else:
                    t0 = time.perf_counter()
                    out = sim.settle_static()
                    wall = time.perf_counter() - t0
                    evals = int(out.evaluations[0])
                best = min(best, wall)
                x = np.asarray(sim.positions)
            rows.append(dict(vertices=design.rest.n_vertices, settle=settle, precision=precision,
                             criterion=(f"speed < {settle_speed * 1e3:g} mm/s" if settle == "dynamic" else
                                        f"force < {FORCE_TOLERANCE[precision]:.0e} N"),
                             evaluations=evals, wall_s=round(best, 4),
                             residual_n=float(np.linalg.norm(sim.forces(), axis=1).max()),
                             error_um=_rigid_distance(x_ref, x) * 1e6,
                             error_raw_um=float(np.linalg.norm(x - x_ref, axis=1).max()) * 1e6))
    return rows


def pareto_front(rows: list[dict], x: str = "wall_s", y: str = "error_mm") -> list[dict]:
    """Rows not beaten on both time and error by another row."""
    front = []
    for r in sorted(rows, key=lambda r: (r[x], r[y])):
        if not front or r[y] < front[-1][y]:
            front.append(r)
    return front


def _law_design(design, law: str):
    """``design`` with the membrane law ``law`` (``membrane.LAW_MATERIALS``), its other material values kept."""
    return design.replace(material=dataclasses.replace(design.material, **LAW_MATERIALS[law]))


def bench_membrane_axis(seq: ControlSequence, device: str = "cpu", subdivisions=(2, 3), reference_subdivisions: int = 4,
                        laws=tuple(LAW_MATERIALS), integrators=("rk4", "semi_implicit"),
                        precisions=("float32", "float64")) -> list[dict]:
    """The membrane axis: the Fig. 6 sequence ``seq`` replayed open loop with each law x mesh x
    integrator (automatic step) x precision; error = mean radial distance (mm) of the achieved shape
    from the finest float64 hyperelastic run (neo-Hookean, RK4 at a quarter of its automatic step, on
    ``reference_subdivisions``), sampled along each vertex's ray; wall time beside it."""
    ref_design = _law_design(cube_fig6_design(subdivisions=reference_subdivisions), "neo_hookean")
    probe = jammed_fig6(ref_design, device, "rk4", "float64", dt=seq.dt, air_scale=seq.air_relative.max())
    x_ref, _, _ = replay(ref_design, seq, integrator="rk4", precision="float64", device=device,
                         internal_dt=seq.dt / probe.substeps / 4)
    fine = ref_design.rest.copy_with(x_ref)
    rows = []
    for s in subdivisions:
        for law in laws:
            d = _law_design(cube_fig6_design(subdivisions=s), law)
            for integrator in integrators:
                for precision in precisions:
                    x, wall, sub = replay(d, seq, integrator=integrator, precision=precision, device=device)
                    x = np.asarray(x, dtype=np.float64)
                    err = float(np.mean(np.abs(np.linalg.norm(x, axis=1)
                                               - np.linalg.norm(radial_sample(fine, x), axis=1))))
                    rows.append(dict(vertices=d.rest.n_vertices, law=law, integrator=integrator, precision=precision,
                                     substeps=sub, wall_s=round(wall, 3), error_mm=err * 1e3))
    return rows


def bench_tradeoff(device: str = "cpu", subdivisions=(2, 3, 4), reference_subdivisions: int = 4,
                   step_fractions=(1.0, 0.5, 0.25), settle: bool = True, membrane: bool = True) -> dict:
    """Error of the achieved Fig. 6 shape versus wall time over the numerical settings; with ``settle``
    also ``bench_settle``'s rows (``settle``) and their front (``settle_pareto``)."""
    cube = target("cube")
    base_design = cube_fig6_design(subdivisions=3)
    seq = record_sequence(base_design, cube)
    designs = {s: cube_fig6_design(subdivisions=s) for s in subdivisions}

    def worst_case_step(d, integrator):
        # the smallest stable step of the run: every cell jammed at the highest air amount
        probe = jammed_fig6(d, device, integrator, "float64", dt=seq.dt, air_scale=seq.air_relative.max())
        return seq.dt / probe.substeps

    references = {}
    for s, d in designs.items():
        h_ref = worst_case_step(d, "rk4") / 8
        x_ref, _, _ = replay(d, seq, integrator="rk4", precision="float64", internal_dt=h_ref, device=device)
        references[s] = x_ref
    rows = []
    for s, d in designs.items():
        x_ref = references[s]
        for integrator in ("rk4", "semi_implicit"):
            h_auto = worst_case_step(d, integrator)
            for frac in step_fractions:
                for precision in ("float32", "float64"):
                    for bending in (("exact", "paper") if (s == 3 and frac == 1.0) else ("exact",)):
                        # frac 1.0 = automatic substeps (the default); smaller = finer fixed steps
                        kw = dict(substeps=None) if frac == 1.0 else dict(internal_dt=h_auto * frac)
                        try:
                            x, wall, sub = replay(d, seq, integrator=integrator, precision=precision, bending=bending,
                                                  device=device, **kw)
                            err = float(np.sqrt(np.mean(np.sum((x - x_ref) ** 2, axis=1))))
                        except Exception as exc:  # an unstable setting is a result too
                            x, wall, sub, err = None, float("nan"), 0, float("inf")
                            note = type(exc).__name__
                        else:
                            note = ""
                        rows.append(dict(vertices=d.rest.n_vertices, integrator=integrator,
                                         step="auto" if frac == 1.0 else f"{frac:g} x auto", substeps=sub,
                                         precision=precision, bending=bending, wall_s=round(wall, 3),
                                         error_mm=err * 1e3, note=note,
                                         default=(s == 3 and integrator == "rk4" and frac == 1.0
                                                  and precision == "float32" and bending == "exact")))
    # resolution axis: each mesh's reference against the finest, radially sampled
    fine = designs[max(designs)].rest.copy_with(references[max(designs)])
    resolution = []
    for s, d in designs.items():
        x_ref = references[s]
        R = np.linalg.norm(radial_sample(fine, x_ref), axis=1)
        r = np.linalg.norm(x_ref, axis=1)
        resolution.append(dict(vertices=d.rest.n_vertices, error_vs_finest_mm=float(np.mean(np.abs(r - R)) * 1e3)))
    finite = [r for r in rows if np.isfinite(r["error_mm"])]
    pareto = []  # per mesh: the resolution axis is reported separately
    for v in sorted({r["vertices"] for r in finite}):
        pareto += pareto_front([r for r in finite if r["vertices"] == v])
    out = dict(rows=rows, pareto=pareto, resolution=resolution, control_steps=seq.steps)
    if membrane:
        out["membrane"] = bench_membrane_axis(seq, device=device, subdivisions=tuple(s for s in subdivisions if s < 4),
                                              reference_subdivisions=reference_subdivisions)
    if settle:
        out["settle"] = bench_settle(device=device)
        out["settle_pareto"] = pareto_front(out["settle"], y="error_um")
    return out
