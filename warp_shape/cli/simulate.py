"""``warp-shape simulate``: inflate and actuate the Fig. 6 sphere-with-five-IPAMs device."""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

from ..errors import StabilityError
from ..io.atomic import StagedFolder, write_json
from ..limits import MAX_SIM_STEPS, MAX_SUBDIVISIONS
from ..scenarios import cube_fig6_design
from ..simulator import Simulator
from .options import (Bar, add_bounded, add_common_args, add_membrane_arg, check_device, check_out, check_rerun, commit, open_recorder, with_membrane,
                      print_outputs)

__all__ = ["register", "run"]


def register(subparsers) -> None:
    """Add the ``simulate`` subcommand."""
    s = subparsers.add_parser("simulate", help="inflate and actuate the Fig. 6 sphere-with-five-IPAMs device",
                              description="Inflate the paper's Fig. 6 device (a silicone sphere with five IPAMs and a "
                                          "jamming cell at every IPAM end), jam its cells, then drive the corner IPAMs "
                                          "to push and the pole IPAM to pull; writes simulate.json (section IV-C).")
    s.add_argument("--integrator", default="rk4", choices=["rk4", "semi_implicit"],
                   help="time integrator: rk4 (the paper's reference) or semi_implicit (Euler, about 3x faster)")
    s.add_argument("--precision", default="float32", choices=["float32", "float64"], help="floating-point precision")
    s.add_argument("--dt", type=float, default=1e-3, help="output step, s (internal substeps are automatic)")
    add_bounded(s, "--subdivisions", 1, MAX_SUBDIVISIONS, type=int, default=3,
                help="icosphere subdivisions of the membrane")
    add_bounded(s, "--air-scale", 0.01, 100.0, type=float, default=1.6,
                help="final air amount relative to the rest amount")
    s.add_argument("--inflate-time", type=float, default=0.4, help="s")
    s.add_argument("--actuate-time", type=float, default=0.4, help="s")
    add_membrane_arg(s, "the Fig. 6 device")
    add_common_args(s, out="out/simulate")
    s.set_defaults(func=run)


def _step_counts(args) -> tuple[int, int]:
    """Output steps of the inflation and the actuation; a clear error for a step that takes none."""
    for name, value in (("--dt", args.dt), ("--inflate-time", args.inflate_time), ("--actuate-time", args.actuate_time)):
        if not (value > 0 and np.isfinite(value)):
            raise StabilityError(f"{name} must be a positive number of seconds, got {value}")
    n_inflate, n_actuate = (round(min(t / args.dt, 1e18)) for t in (args.inflate_time, args.actuate_time))
    if n_inflate < 1 or n_actuate < 1:
        raise StabilityError(f"--dt {args.dt:g} s takes no step of --inflate-time {args.inflate_time:g} s or "
                             f"--actuate-time {args.actuate_time:g} s; give --dt at most "
                             f"{min(args.inflate_time, args.actuate_time):g} s (default 0.001)")
    if n_inflate + n_actuate > MAX_SIM_STEPS:
        raise StabilityError(f"--inflate-time {args.inflate_time:g} s and --actuate-time {args.actuate_time:g} s at "
                             f"--dt {args.dt:g} s are {n_inflate + n_actuate:.3g} output steps, more than "
                             f"{MAX_SIM_STEPS}; give a larger --dt or shorter times")
    return n_inflate, n_actuate


def _drive(sim, design, args, rec, bar) -> list[dict]:
    """Inflate in 20 chunks, jam every cell, then ramp the IPAMs; returns the rest, inflated and
    actuated rows."""
    n_inflate, n_actuate = _step_counts(args)
    air0 = sim.air_moles
    rows = []

    def frame(force=False):
        if rec is not None:
            rec.log_sim_frame(sim.step_count, sim.time, sim.positions, sim.volume(), sim.pressure(),
                              sim.ipam_lengths(), sim.ipam_forces(), sim.jammed, force=force)

    def record(phase):
        rows.append(dict(phase=phase, time=sim.time, volume=sim.volume(), pressure=sim.pressure(),
                         ipam_length=sim.ipam_lengths().tolist(), ipam_force=sim.ipam_forces().tolist(),
                         jammed=int(sim.jammed.sum())))
        frame(force=True)

    record("rest")
    chunk = max(1, n_inflate // 20)
    for i in range(0, n_inflate, chunk):
        frac = min(1.0, (i + chunk) / n_inflate)
        sim.air_moles = air0 * (1.0 + (args.air_scale - 1.0) * frac)
        sim.step(min(chunk, n_inflate - i))
        frame()
        bar.to(min(i + chunk, n_inflate))
    record("inflated")
    for c in range(design.n_cells):
        sim.jam(c)
    # corner IPAMs push (pressurise), the face IPAM pulls (vents to its lower limit)
    lo = np.array([ip.pressure_limits[0] for ip in design.ipams])
    hi = np.array([ip.pressure_limits[1] for ip in design.ipams])
    target = np.where(np.arange(design.n_ipams) < 4, 0.5 * hi, np.maximum(lo, -20e3))
    chunk = max(1, n_actuate // 20)
    for i in range(0, n_actuate, chunk):
        frac = min(1.0, (i + chunk) / n_actuate)
        sim.ipam_pressures = target * frac
        sim.step(min(chunk, n_actuate - i))
        frame()
        bar.to(n_inflate + min(i + chunk, n_actuate))
    record("actuated")
    return rows


def run(args) -> int:
    """Run the Fig. 6 sequence; write ``simulate.json``; print a table (or the JSON)."""
    staged = StagedFolder(args.out, owned=lambda name: name == "simulate.json", command="simulate")
    check_out(staged)
    check_device(args.device)
    check_rerun(args, staged)
    steps = sum(_step_counts(args))
    design = with_membrane(cube_fig6_design(subdivisions=args.subdivisions), args.membrane)
    sim = Simulator(design, device=args.device, integrator=args.integrator, dt=args.dt, precision=args.precision)
    with staged.writing():  # the run's lock; simulate.json staged, then swapped into --out whole
        # the recorder is closed (and the recording saved) even when the run fails
        with open_recorder(args) as rec, Bar(total=steps, desc="simulate", unit="step") as bar:
            if rec is not None:
                rec.begin_simulation(design)
            t0 = time.perf_counter()
            rows = _drive(sim, design, args, rec, bar)
        wall = time.perf_counter() - t0
        result = dict(design=dict(vertices=design.rest.n_vertices, ipams=design.n_ipams, cells=design.n_cells,
                                    membrane=design.material.membrane),
                      device=sim.device, integrator=sim.integrator, precision=sim.precision, dt=sim.dt,
                      substeps=sim.substeps, stable_dt=sim.stable_dt(), wall_seconds=wall, frames=rows)
        write_json(staged.path / "simulate.json", result)
        out = commit(staged, args) / "simulate.json"
    if args.json:
        print(json.dumps(result, indent=2))
    else:
        print(f"Fig. 6 sphere ({design.rest.n_vertices} vertices, {design.n_ipams} IPAMs, {design.n_cells} cells), "
              f"{sim.integrator} {sim.precision} on {sim.device}, dt {sim.dt:g} s x {sim.substeps} substeps")
        print(f"{'phase':<10}{'t (s)':>8}{'V (cm^3)':>11}{'p (Pa)':>10}   IPAM axial force (N, + = tension)")
        for r in rows:
            forces = " ".join(f"{f:+.3f}" for f in r["ipam_force"])
            print(f"{r['phase']:<10}{r['time']:8.3f}{r['volume'] * 1e6:11.2f}{r['pressure']:10.1f}   {forces}")
        print(f"wall time {wall:.2f} s")
        print_outputs(out.parent, [out.name], args, next_step="warp-shape design   (the main job: design a display "
                      "for target shapes)")
    return 0
