"""``warp-shape bench``: speed and accuracy benchmarks, printed as tables and written one JSON file per
benchmark (``bench_<name>.json``), so running one benchmark never overwrites another's results."""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path

import warp as wp

from ..benchmarks.feel import FEEL_COLUMNS, PRESSURE_COLUMNS, bench_feel, stiffness_by_pressure  # light: the API's own
from ..errors import DesignError
from ..io.atomic import StagedFolder, write_json
from ..limits import MAX_CANDIDATES, MAX_WORLDS
from ..interrupts import held_interrupts
from .options import add_bounded, check_device, check_out, print_outputs, stop_if_interrupted

# the benchmarks are imported by the functions that run them: ~20 ms kept out of every command's start-up

__all__ = ["register", "run"]

TRADEOFF_COLUMNS = ["vertices", "integrator", "step", "substeps", "precision", "bending", "wall_s", "error_mm",
                    "default", "note"]


def register(subparsers) -> None:
    """Add the ``bench`` subcommand."""
    b = subparsers.add_parser("bench", help="speed benchmarks (tables + JSON)",
                              description="Speed benchmarks: a table on stdout and bench_<name>.json in --out per bench.")
    b.add_argument("which", nargs="?", default="sim", choices=["sim", "tradeoff", "design", "control", "peer",
                                                                    "rays", "gradient", "control_gradient", "codesign",
                                                                    "membrane", "feel", "all"],
                   help="; ".join(f"{k}: {v}" for k, v in ABOUT.items()) + "; all: every one but codesign")
    b.add_argument("--device", default="cpu", help="Warp device: cpu or cuda:N")
    add_bounded(b, "--subdivisions", 1, 7, type=int, nargs="+", default=[3, 4, 5, 6],
                   help="icosphere subdivisions for the sim bench (3..6: 642..40962 vertices)")
    add_bounded(b, "--worlds", 1, MAX_WORLDS, type=int, nargs="+", default=[1],
                   help="sim bench: worlds stepped as one batch, e.g. 1 64 1024 4096 (default 1); control bench: "
                        "the breakdown's batch sizes (default 64)")
    add_bounded(b, "--candidates", 1, MAX_CANDIDATES, type=int, nargs="+", default=None,
                   help="design bench: also the default problem by the paper's placement and at each K, e.g. 1 2 4 8")
    add_bounded(b, "--repeats", 1, 100, type=int, default=3, help="timing repeats (the best is kept)")
    b.add_argument("--cases", nargs="+", default=None, metavar="CASE",
                   help="codesign bench: the cases (default: all; shipped problems, targets, generated shapes, "
                        "pairs as a+b, e.g. oval_heart egg puck+peanut)")
    b.add_argument("--baseline", default=None, metavar="COMMIT",
                   help="design bench: the default `warp-shape design` phase by phase (placement, refinement, "
                        "co-design, outputs, compile), this checkout against COMMIT (a temporary git worktree) in "
                        "alternating whole processes, --repeats each")
    b.add_argument("--scene", default="", help="design bench with --baseline: the shipped problem (default oval_heart)")
    b.add_argument("--out", default="out/bench", help="folder of the bench_<name>.json files")
    b.set_defaults(func=run)


def _tradeoff(args, format_rows) -> dict:
    from ..benchmarks.tradeoff import bench_tradeoff

    out = bench_tradeoff(device=args.device)
    cols = TRADEOFF_COLUMNS
    fmt = [dict(r, error_mm=f"{r['error_mm']:.2e}", default="*" if r["default"] else "") for r in out["rows"]]
    print(f"trade-off: Fig. 6 control sequence ({out['control_steps']} control steps) replayed open loop; "
          f"error = RMS vertex distance to float64 RK4 at 1/8 of the automatic step, same mesh")
    print(format_rows(fmt, cols))
    print("\nPareto front per mesh (least error for the wall time):")
    print(format_rows([dict(r, error_mm=f"{r['error_mm']:.2e}", default="*" if r["default"] else "")
                       for r in out["pareto"]], cols))
    print("\nresolution (each mesh's reference vs the finest, mean radial distance):")
    print(format_rows([dict(r, error_vs_finest_mm=f"{r['error_vs_finest_mm']:.3f}") for r in out["resolution"]],
                      ["vertices", "error_vs_finest_mm"]))
    if out.get("settle"):
        from ..benchmarks.tradeoff import SETTLE_COLUMNS

        print("\nsettle after the Fig. 6 jam + IPAM step: RK4 to rest against the static equilibrium; error = largest "
              "vertex distance to a float64 static settle at 1e-10 N (rigid motion taken out; raw beside it)")
        print(format_rows([dict(r, residual_n=f"{r['residual_n']:.1e}", error_um=f"{r['error_um']:.2f}",
                                error_raw_um=f"{r['error_raw_um']:.2f}") for r in out["settle"]], SETTLE_COLUMNS))
    if out.get("membrane"):
        print("\nmembrane law (docs/membrane.md): the same sequence with each law, automatic step; error = mean radial "
              "distance to the finest float64 neo-Hookean run (RK4 at a quarter of its automatic step)")
        print(format_rows([dict(r, error_mm=f"{r['error_mm']:.3f}") for r in out["membrane"]],
                          ["vertices", "law", "integrator", "precision", "substeps", "wall_s", "error_mm"]))
    return out


def _control(args, format_rows) -> dict:
    from ..benchmarks.control import BREAKDOWN_COLUMNS, CONTROL_COLUMNS, bench_control, control_breakdown

    worlds = args.worlds if args.worlds != [1] else [64]
    split = [control_breakdown(worlds=w, device=args.device) for w in worlds]
    print("control period: host / device breakdown, the paper's law on the 642-vertex Fig. 6 device, differing "
          "worlds, ms per control period (CPU: CPU time of the process; --worlds sets the batch sizes)")
    print(format_rows(split, BREAKDOWN_COLUMNS))
    rows = bench_control(device=args.device, repeats=args.repeats)
    print("control: the paper's law vs model-based control (method='inverse'), wall time side by side in one run "
          "(paper: minimum of repeats; inverse: one run); objective = RMS of (R - r) / V_t^(1/3)")
    print(format_rows(rows, CONTROL_COLUMNS))
    return dict(cases=rows, breakdown=split)


def _codesign(args, format_rows) -> list:
    from ..benchmarks.codesign import CODESIGN_COLUMNS, bench_codesign, check_cases

    cases = check_cases(args.cases)
    rows = bench_codesign(cases, device=args.device, progress=lambda text: print(text, file=sys.stderr, flush=True))
    print("codesign: per target objective (RMS of (R - r) / V_t^(1/3)), PCC, MARE, MPRE; vs_paper = objective / "
          "Algorithm 1's (placement paper); ways: paper, default (co-design off), codesign (rest+ipams)")
    print(format_rows(rows, CODESIGN_COLUMNS))
    return rows


def _design_phases(args, format_rows, design_bench) -> dict:
    """``bench design --baseline``: the phase table (``design_bench``: ``warp_shape.benchmarks.design``)."""
    if args.device != "cpu":
        raise DesignError("bench design --baseline times the CPU job; leave --device out")
    out = design_bench.bench_design_phases(args.baseline, scene=args.scene, repeats=args.repeats,
                                           progress=lambda text: print(text, file=sys.stderr, flush=True))
    print(f"design phases: `warp-shape design` ({out['scene']}), this checkout against {out['baseline'][:10]}, "
          f"alternating whole processes, best of {out['repeats']} each (s); runs: baseline / this / ... in order")
    print(format_rows(out["rows"], design_bench.PHASE_COLUMNS))
    for r in out["runs"]:
        print(f"  {r['side']} run {r['repeat'] + 1}: load {r['load']}, final objectives "
              + ", ".join(f"{k} {v:.7f}" for k, v in r["objectives"].items()) + "; calls "
              + ", ".join(f"{k} {v}" for k, v in r["calls"].items() if k in ("gradients", "batches", "recontrol")))
    return out


def _peer(args, format_rows) -> list:
    from ..benchmarks.peer import bench_peer

    rows = bench_peer(subdivisions=args.subdivisions, device=args.device)
    print("peer: the same spring + bending membrane in Newton's SolverSemiImplicit (warp_shape also "
          "evaluates pressure and viscous damping); force evaluations per second")
    print(format_rows(rows, list(rows[0].keys())))
    return rows


def _membrane(args, format_rows, membrane) -> dict:
    out = dict(mesh_independence=membrane.mesh_independence(laws=tuple(membrane.LAW_MATERIALS)),
               thin_sphere=membrane.thin_sphere_table(),
               step_cost=[r for integ in ("rk4", "semi_implicit") for level in args.subdivisions[:2]
                          for r in membrane.step_cost(level=level, integrator=integ, device=args.device,
                                                      repeats=args.repeats)])
    print("mesh independence: a 40/32/32 mm ellipsoid at 1.6 x its rest air on five meshings (float64 static settle); "
          "distance (mm) of each settled shape from the meshings' mean shape, pressure against their mean")
    print(format_rows([{k: (f"{v:.4f}" if isinstance(v, float) else v) for k, v in r.items()}
                       for r in out["mesh_independence"]],
                      ["law", "meshing", "vertices", "rms_mm", "max_mm", "pressure_Pa", "pressure_pct", "evaluations"]))
    print("\nthin sphere (R 20 mm, icosphere 3, float64 static settle) against 2 mu (t/R)(1/l - 1/l^7) (Yeoh: its own law)")
    print(format_rows([{k: (f"{v:.4f}" if isinstance(v, float) else v) for k, v in r.items()}
                       for r in out["thin_sphere"]], ["law", "stretch", "pressure_Pa", "law_Pa", "error_pct",
                                                      "evaluations"]))
    print("\na step's cost (sphere R 40 mm, 2 % more air), measured side by side; *_vs_springs = law / springs")
    print(format_rows([{k: (f"{v:.4g}" if isinstance(v, float) else v) for k, v in r.items()} for r in out["step_cost"]],
                      ["law", "integrator", "precision", "vertices", "internal_dt", "step_us", "step_vs_springs",
                       "seconds_per_simulated_second", "time_vs_springs"]))
    return out


def _rays(args, results: dict) -> None:
    try:
        from ..benchmarks.rays import bench_rays, format_table
    except ImportError:
        print("ray benchmark unavailable in this build")
    else:
        rows = bench_rays(device=args.device, progress=lambda text: print(text, file=sys.stderr, flush=True))
        results["rays"] = rows
        print(format_table(rows))


ABOUT = {
    "sim": "internal steps per second of the Fig. 6 device, Warp beside NumPy, per mesh x integrator x precision",
    "tradeoff": "wall time against error of every integrator, step and precision on the Fig. 6 control sequence",
    "design": "wall time and final fit of the design problems",
    "control": "a control period's host / device breakdown (64 differing worlds); the paper's control law against "
               "model-based control, wall time and objective",
    "peer": "the same membrane in Newton's semi-implicit solver",
    "rays": "radial sampling throughput",
    "gradient": "the adjoint of a replayed Fig. 6 sequence beside the forward replay: wall time and memory",
    "control_gradient": "the model-based refinement by finite differences beside the equilibrium's adjoint, per "
                        "number of controls on the four_targets_20 design: wall time and objective",
    "codesign": "per target fit after co-design beside Algorithm 1 and the default placement (minutes per case)",
    "membrane": "the membrane laws: one ellipsoid on five meshings, the thin sphere against its law, a step's cost "
                "with each law side by side",
    "feel": "a 64-point fingertip stiffness map of the Fig. 6 device's controlled cube beside one control run",
}


def _announce(name: str, args) -> None:
    extra = ""
    if name == "sim":
        extra = (f" ({len(args.subdivisions)} mesh(es) {args.subdivisions}, worlds {args.worlds}, "
                 f"{args.repeats} repeats; about 10 s per mesh on a CPU)")
    print(f"bench {name}: {ABOUT[name]}{extra} ...", file=sys.stderr, flush=True)


def _run_one(name: str, args, sim_bench, results: dict, membrane_bench=None) -> None:
    format_rows = sim_bench.format_rows
    if name == "sim":
        if min(args.worlds) < 1:
            raise DesignError(f"--worlds takes counts >= 1, got {args.worlds}")
        rows = sim_bench.bench_sim(device=args.device, subdivisions=args.subdivisions, repeats=args.repeats,
                                   worlds=args.worlds)
        results["sim"] = rows
        columns = sim_bench.BENCH_COLUMNS + ["estimate_ms"]
        if max(args.worlds) > 1:
            columns.insert(1, "worlds")
        print(format_rows(rows, columns))
    elif name == "tradeoff":
        results["tradeoff"] = _tradeoff(args, format_rows)
    elif name == "design":
        from ..benchmarks import design as design_bench

        if args.baseline:
            results["design"] = _design_phases(args, format_rows, design_bench)
            return
        rows = design_bench.bench_design(device=args.device, candidates=args.candidates)
        results["design"] = rows
        print(format_rows(rows, design_bench.DESIGN_COLUMNS))
    elif name == "control":
        results["control"] = _control(args, format_rows)
    elif name == "peer":
        results["peer"] = _peer(args, format_rows)
    elif name == "rays":
        _rays(args, results)
    elif name == "codesign":
        results["codesign"] = _codesign(args, format_rows)
    elif name == "membrane":
        results["membrane"] = _membrane(args, format_rows, membrane_bench)
    elif name == "feel":
        rows = bench_feel(device=args.device)
        print("feel: a 64-point fingertip stiffness map (2 mm, one press per world) of the Fig. 6 device's controlled "
              "cube beside the control run (paper's law) that made the state; ratio = map / control")
        print(format_rows(rows, FEEL_COLUMNS))
        by_pressure = stiffness_by_pressure(device=args.device)
        results["feel"] = dict(map=rows, pressure=by_pressure)
        print("\nfeel by chamber pressure: the Fig. 6 device inflated (IPAMs at rest), an 8 mm fingertip 2 mm deep on "
              "the top (free, and with its cell jammed) and on the +x side")
        print(format_rows(by_pressure, PRESSURE_COLUMNS))
    elif name in ("gradient", "control_gradient"):
        from ..benchmarks import control_gradient, gradient

        if name == "control_gradient":
            rows = control_gradient.bench_control_gradient(
                device=args.device, progress=lambda text: print(text, file=sys.stderr, flush=True))
            results["control_gradient"] = rows
            print("control_gradient: the refinement's wall time (warm start and plan settles left out) and final "
                  "objective, finite-difference Jacobian (fd) against the equilibrium's adjoint; ratio = adjoint / fd")
            print(format_rows(rows, control_gradient.CONTROL_GRADIENT_COLUMNS))
            return
        rows = gradient.bench_gradient(device=args.device, subdivisions=[s for s in args.subdivisions if s <= 4] or [2, 3],
                                       repeats=args.repeats)
        results["gradient"] = rows
        print("gradient: ws.gradient (float64, every parameter) beside ws.replay of the same sequence; ratio = "
              "gradient / float64 replay (ratio_f32: / float32 replay, the product's); serial: the gradient on one "
              "thread (by default the next segment is recomputed on a second thread); peak_extra_mb = the gradient's peak resident memory above the process's")
        print(format_rows(rows, gradient.GRADIENT_COLUMNS))

def run(args) -> int:
    """Run the chosen benchmarks; print their tables; write ``bench_<name>.json`` for each."""
    from ..benchmarks import membrane as membrane_bench, sim as sim_bench

    staged = StagedFolder(args.out, owned=lambda name: name.startswith("bench_"), command="bench")
    check_out(staged)
    check_device(args.device)
    names = [n for n in ABOUT if n != "codesign"] if args.which == "all" else [args.which]  # codesign: hours
    meta = dict(date=time.strftime("%Y-%m-%d %H:%M:%S"), device=args.device, machine=os.uname().nodename,
                cpu_count=os.cpu_count(), warp=wp.config.version)
    written = []
    with staged.writing():  # staged, then swapped in with the earlier runs' other bench files
        for name in names:
            results: dict = {}
            _announce(name, args)
            start = time.perf_counter()
            _run_one(name, args, sim_bench, results, membrane_bench)
            print(f"bench {name}: done in {time.perf_counter() - start:.0f} s", file=sys.stderr, flush=True)
            if name in results:
                written.append(write_json(staged.path / f"bench_{name}.json", {name: results[name], "meta": meta}))
        if written:
            stop_if_interrupted()
            with held_interrupts():
                staged.commit(True, keep_previous=True)
    print_outputs(args.out, [p.name for p in written], args)
    return 0
