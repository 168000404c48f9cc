"""The ``warp-shape`` command line."""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

from .io.outputs import write_json

__all__ = ["main", "build_parser"]


def _quiet_warp(verbose: bool = False):
    import warp as wp

    wp.config.quiet = not verbose
    if not verbose:
        wp.config.log_level = wp.LOG_WARNING


def _progress(done: int, total: int, label: str, stream=sys.stderr):
    """A one-line progress bar on a terminal; a line per 10 % in logs."""
    if stream.isatty():
        stream.write(f"\r{label}: {done}/{total} ({100.0 * done / total:5.1f} %)" + ("\n" if done == total else ""))
    elif done == total or done % max(1, total // 10) == 0:
        stream.write(f"{label}: {done}/{total} ({100.0 * done / total:5.1f} %)\n")
    stream.flush()


def _control_progress(step, total, done, worlds, prefix: str = ""):
    """Progress of a control run over several targets; complete once every target is done."""
    _progress(total if done == worlds else step, total, f"{prefix}control ({done}/{worlds} targets done)")


# --------------------------------------------------------------------------- rerun and figures

def _add_common_args(sp, rerun: bool = True):
    sp.add_argument("--device", default="cpu", help="Warp device: cpu or cuda:N")
    sp.add_argument("--out", default="out", help="output directory")
    sp.add_argument("--json", action="store_true", help="print machine-readable results")
    sp.add_argument("--verbose", action="store_true", help="show Warp's compile messages")
    if rerun:
        _add_rerun_args(sp)


def _add_rerun_args(sp):
    sp.add_argument("--rerun", metavar="FILE.rrd", default=None, help="write a rerun recording (open: rerun FILE.rrd)")
    sp.add_argument("--rerun-spawn", action="store_true", help="stream to a live rerun viewer (needs a display)")
    sp.add_argument("--rerun-every", type=int, default=1, help="log every k-th control step (the last is always logged)")


def _recorder(args):
    if not (getattr(args, "rerun", None) or getattr(args, "rerun_spawn", False)):
        return contextlib.nullcontext(None)
    from .recorder import Recorder

    return Recorder(args.rerun, spawn=args.rerun_spawn, every=args.rerun_every)


# --------------------------------------------------------------------------- simulate

def cmd_simulate(args) -> int:
    _quiet_warp(args.verbose)
    from .scenarios import cube_fig6_design
    from .simulator import Simulator

    design = cube_fig6_design(subdivisions=args.subdivisions)
    sim = Simulator(design, device=args.device, integrator=args.integrator, dt=args.dt, precision=args.precision)
    n_inflate = int(round(args.inflate_time / args.dt))
    n_actuate = int(round(args.actuate_time / args.dt))
    air0 = sim.air_moles
    rows = []

    with _recorder(args) as rec:  # closed (and the recording saved) even when the run fails
        if rec is not None:
            rec.begin_simulation(design)

        def frame(force=False):
            if rec is not None:
                rec.log_sim_frame(sim.step_count, sim.time, sim.positions, sim.volume(), sim.pressure(),
                                  sim.ipam_lengths(), sim.ipam_forces(), sim.jammed, force=force)

        def record(phase):
            rows.append(dict(phase=phase, time=sim.time, volume=sim.volume(), pressure=sim.pressure(),
                             ipam_length=sim.ipam_lengths().tolist(), ipam_force=sim.ipam_forces().tolist(),
                             jammed=int(sim.jammed.sum())))
            frame(force=True)

        t0 = time.perf_counter()
        record("rest")
        chunk = max(1, n_inflate // 20)
        for i in range(0, n_inflate, chunk):
            frac = min(1.0, (i + chunk) / n_inflate)
            sim.air_moles = air0 * (1.0 + (args.air_scale - 1.0) * frac)
            sim.step(min(chunk, n_inflate - i))
            frame()
            _progress(min(i + chunk, n_inflate), n_inflate + n_actuate, "simulate")
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
            _progress(n_inflate + min(i + chunk, n_actuate), n_inflate + n_actuate, "simulate")
        record("actuated")
    wall = time.perf_counter() - t0
    result = dict(design=dict(vertices=design.rest.n_vertices, ipams=design.n_ipams, cells=design.n_cells),
                  device=sim.device, integrator=sim.integrator, precision=sim.precision, dt=sim.dt,
                  substeps=sim.substeps, stable_dt=sim.stable_dt(), wall_seconds=wall, frames=rows)
    out = write_json(Path(args.out) / "simulate.json", result)
    if args.json:
        print(json.dumps(result, indent=2))
    else:
        print(f"Fig. 6 sphere ({design.rest.n_vertices} vertices, {design.n_ipams} IPAMs, {design.n_cells} cells), "
              f"{sim.integrator} {sim.precision} on {sim.device}, dt {sim.dt:g} s x {sim.substeps} substeps")
        print(f"{'phase':<10}{'t (s)':>8}{'V (cm^3)':>11}{'p (Pa)':>10}   IPAM axial force (N, + = tension)")
        for r in rows:
            forces = " ".join(f"{f:+.3f}" for f in r["ipam_force"])
            print(f"{r['phase']:<10}{r['time']:8.3f}{r['volume'] * 1e6:11.2f}{r['pressure']:10.1f}   {forces}")
        print(f"wall time {wall:.2f} s; written {out}")
    return 0


# --------------------------------------------------------------------------- control

def _resolve_design_and_targets(scene: str | None, target_names):
    """The built-in Fig. 6 problem (no USD needed), or a scene file / shipped scene name; then the
    chosen targets: the scene's own by name, else shipped target names or mesh files."""
    from .scenarios import cube_fig6_design
    from .targets import target

    if scene in (None, "cube_fig6", "fig6"):
        design, targets, settings = cube_fig6_design(), [("cube", target("cube"))], {}
    else:
        from .scene import load_scene

        sc = load_scene(scene)
        design, settings = sc.design, sc.settings or {}
        targets = list(zip(sc.target_names, sc.targets))
    if target_names:
        own = dict(targets)
        targets = [(name, own[name]) if name in own else _load_targets([name])[0] for name in target_names]
    return design, targets, settings


def _selection(args, scene_settings, names) -> dict:
    """The per-target actuator selection a design stored in its scene (unless --all-actuators)."""
    from .designer import selection_from_settings

    if getattr(args, "all_actuators", False):
        return {}
    ipams, cells = selection_from_settings(scene_settings, names)
    return dict(passive_ipams=ipams, passive_cells=cells) if any(ipams) or any(cells) else {}


def cmd_control(args) -> int:
    _quiet_warp(args.verbose)
    from .controller import ControlSettings, control_many
    from .settings import SimulationSettings

    design, targets, scene_settings = _resolve_design_and_targets(args.scene, args.target)
    settings = ControlSettings(max_steps=args.max_steps, jamming=not args.no_jamming,
                               simulation=SimulationSettings(integrator=args.integrator, precision=args.precision))

    with _recorder(args) as rec:
        results = control_many(design, [t for _, t in targets], device=args.device, settings=settings,
                               progress=_control_progress, recorder=rec, target_names=[n for n, _ in targets],
                               **_selection(args, scene_settings, [n for n, _ in targets]))
    from .io.outputs import write_control_outputs, write_figures_or_skip

    out = Path(args.out)
    names = [n for n, _ in targets]
    write_figures_or_skip(results, out, names)
    write_control_outputs(results, names, out)
    report = {name: res.summary() for name, res in zip(names, results)}
    if args.json:
        print(json.dumps(report, indent=2))
        return 0
    print(f"design: {design.rest.n_vertices} vertices, {design.n_ipams} IPAMs, {design.n_cells} cells; "
          f"{settings.simulation.integrator} {settings.simulation.precision} on {args.device}")
    print(f"{'target':<10}{'PCC':>8}{'MARE mm':>9}{'MPRE %':>8}{'vol err %':>10}{'steps':>7}  result")
    for (name, _), res in zip(targets, results):
        print(f"{name:<10}{res.pcc:8.4f}{res.mare * 1e3:9.3f}{res.mpre:8.2f}{100 * res.volume_error:10.3f}"
              f"{res.control_steps:7d}  {res.reason}")
        for a in res.actuator_summary:
            print(f"    IPAM {a['ipam']}: push {a['peak_push_n']:.3f} N, pull {a['peak_pull_n']:.3f} N, "
                  f"strain {a['peak_strain']:.3f}, pressure {a['pressure_min_pa'] / 1e3:.1f}..{a['pressure_max_pa'] / 1e3:.1f} kPa")
    print(f"control sequences written to {out}/control_<target>.csv|json")
    return 0


# --------------------------------------------------------------------------- design (the main job)

def _load_targets(specs):
    """Target names (oval pear heart cube) or mesh files -> [(name, TriMesh)]."""
    from .mesh import TriMesh
    from .targets import TARGET_NAMES, target

    out = []
    for spec in specs:
        if spec in TARGET_NAMES:
            out.append((spec, target(spec)))
        else:
            out.append((Path(spec).stem, TriMesh.load(spec, center=True)))
    return out


def cmd_design(args) -> int:
    _quiet_warp(args.verbose)
    from .designer import DesignSettings, design
    from .errors import DesignError
    from .io.outputs import write_design_outputs, write_round_outputs
    from .io.report import design_markdown
    from .mesh import icosphere
    from .scene import load_scene

    # ---- everything is validated before anything is written
    scene = load_scene(args.scene or "oval_heart")
    base = scene.design.rest if scene.design is not None else icosphere(3, 0.035)
    named = list(zip(scene.target_names, scene.targets))
    if args.targets:
        named = _load_targets(args.targets)
    if not named:
        raise DesignError("no targets: give --targets (e.g. --targets oval heart) or a scene with targets")
    opts = dict((scene.settings or {}).get("designer", {}))
    actuators = int(args.actuators if args.actuators is not None else opts.pop("actuators", 4))
    opts.pop("actuators", None)
    if args.cell_radius is not None:
        opts["cell_radius"] = args.cell_radius
    settings = DesignSettings(**{k: v for k, v in opts.items() if k in DesignSettings.__dataclass_fields__},
                              initialize=not args.keep_rest)
    names = [n for n, _ in named]
    out = Path(args.out)
    written: list[Path] = []

    def progress(i, p, step, total, done, worlds):
        _control_progress(step, total, done, worlds, prefix=f"round {i}/{p}: ")

    def on_round(i, d_i, results):
        # finished rounds are written as they complete, so an interrupted run keeps them
        rounds_seen.append(results)
        written.extend(write_round_outputs(out, i, names, rounds_seen))

    rounds_seen: list = []
    t0 = time.perf_counter()
    try:
        with _recorder(args) as rec:
            res = design(base, [t for _, t in named], actuators=actuators, device=args.device, target_names=names,
                         settings=settings, progress=progress, on_round=on_round, recorder=rec)
    except Exception:
        if not isinstance(sys.exc_info()[1], KeyboardInterrupt):
            for path in written:  # a failed run leaves no partial outputs
                path.unlink(missing_ok=True)
        raise
    wall = time.perf_counter() - t0
    write_design_outputs(res, out, marker_height=args.marker_height, layer_thickness=args.layer_thickness,
                         extra_report=dict(complete=True, wall_seconds=wall, device=args.device))
    report = json.loads((out / "report.json").read_text())
    if args.json:
        print(json.dumps(report, indent=2))
    else:
        print(design_markdown(res))
        print(f"wall time {wall:.1f} s; outputs in {out}/: {', '.join(report['outputs'])}")
    return 0


# --------------------------------------------------------------------------- export

def cmd_export(args) -> int:
    """Fabrication and content outputs of an existing design: molds, control sequences, USD."""
    _quiet_warp(args.verbose)
    from .controller import ControlSettings, control_many
    from .errors import DesignError
    from .io.outputs import write_control_outputs, write_figures_or_skip, write_molds
    from .scene import load_scene, save_scene

    scene = load_scene(args.scene)
    if scene.design is None:
        raise DesignError(f"{args.scene} holds no design (only targets); export needs a design scene, "
                          f"e.g. out/design.usda from warp-shape design or the shipped cube_fig6")
    named = list(zip(scene.target_names, scene.targets))
    if args.targets:
        named = _load_targets(args.targets)
    out = Path(args.out)
    written = []
    if "molds" in args.what:
        written += write_molds(scene.design, out, marker_height=args.marker_height,
                               layer_thickness=args.layer_thickness)
    if "usd" in args.what:
        written.append(save_scene(scene, out / "design.usda"))
    if "control" in args.what and named:
        names = [n for n, _ in named]

        with _recorder(args) as rec:
            results = control_many(scene.design, [t for _, t in named], device=args.device,
                                   settings=ControlSettings(), progress=_control_progress, recorder=rec, target_names=names,
                                   **_selection(args, scene.settings, names))
        written += write_control_outputs(results, names, out, usd="usd" in args.what)
        written += write_figures_or_skip(results, out, names)
    if args.json:
        print(json.dumps({"outputs": [str(p) for p in written]}, indent=2))
    else:
        print(f"exported {len(written)} files to {out}/: " + ", ".join(Path(p).name for p in written))
    return 0


# --------------------------------------------------------------------------- bench

def cmd_bench(args) -> int:
    import warp as wp

    _quiet_warp()
    from .bench import BENCH_COLUMNS, bench_sim, format_rows

    results = {}
    if args.which in ("sim", "all"):
        rows = bench_sim(device=args.device, subdivisions=args.subdivisions, repeats=args.repeats)
        results["sim"] = rows
        print(format_rows(rows, BENCH_COLUMNS + ["estimate_ms"]))
    if args.which in ("tradeoff", "all"):
        from .bench_tradeoff import bench_tradeoff

        out = bench_tradeoff(device=args.device)
        results["tradeoff"] = out
        cols = ["vertices", "integrator", "step", "substeps", "precision", "bending", "wall_s", "error_mm", "default",
                "note"]
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
    if args.which in ("design", "all"):
        from .bench_tradeoff import bench_design

        rows = bench_design(device=args.device)
        results["design"] = rows
        print(format_rows(rows, ["problem", "targets", "actuators", "wall_s", "final_pcc", "control_steps"]))
    if args.which in ("peer", "all"):
        from .bench_peer import bench_peer

        rows = bench_peer(subdivisions=args.subdivisions, device=args.device)
        results["peer"] = rows
        print("peer: the same spring + bending membrane in Newton's SolverSemiImplicit (warp_shape also "
              "evaluates pressure and viscous damping); force evaluations per second")
        print(format_rows(rows, list(rows[0].keys())))
    if args.which in ("rays", "all"):
        try:
            from .bench_shapes import bench_rays, format_table
        except ImportError:
            print("ray benchmark unavailable in this build")
        else:
            rows = bench_rays(device=args.device)
            results["rays"] = rows
            print(format_table(rows))
    results["meta"] = dict(date=time.strftime("%Y-%m-%d %H:%M:%S"), device=args.device, machine=os.uname().nodename,
                           cpu_count=os.cpu_count(), warp=wp.config.version)
    out = write_json(Path(args.out) / "bench.json", results)
    print(f"written {out}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    """The ``warp-shape`` argument parser with every subcommand."""
    p = argparse.ArgumentParser(prog="warp-shape", description="Simulate and design soft 3-D haptic shape displays.")
    sub = p.add_subparsers(dest="command", required=True)

    s = sub.add_parser("simulate", help="inflate and actuate the Fig. 6 sphere-with-five-IPAMs device")
    s.add_argument("--integrator", default="rk4", choices=["rk4", "semi_implicit"])
    s.add_argument("--precision", default="float32", choices=["float32", "float64"])
    s.add_argument("--dt", type=float, default=1e-3, help="output step, s (internal substeps are automatic)")
    s.add_argument("--subdivisions", type=int, default=3, help="icosphere subdivisions of the membrane")
    s.add_argument("--air-scale", type=float, default=1.6, help="final air amount relative to the rest amount")
    s.add_argument("--inflate-time", type=float, default=0.4, help="s")
    s.add_argument("--actuate-time", type=float, default=0.4, help="s")
    _add_common_args(s)
    s.set_defaults(func=cmd_simulate)

    d = sub.add_parser("design", help="design a display for target shapes (default: oval + heart, 4 IPAMs)")
    d.add_argument("scene", nargs="?", default=None, help="design problem: a shipped scene name or .usda file "
                   "(default oval_heart)")
    d.add_argument("--targets", nargs="+", help="target names (oval pear heart cube) or mesh files")
    d.add_argument("--actuators", type=int, default=None, help="number of IPAMs to place")
    d.add_argument("--cell-radius", type=float, default=None, help="jamming-cell radius, m")
    d.add_argument("--keep-rest", action="store_true", help="single-target mode: keep the scene's rest shape")
    d.add_argument("--layer-thickness", type=float, default=5e-3, help="jamming layer (outer mold offset), m")
    d.add_argument("--marker-height", type=float, default=2e-3, help="IPAM marker height on the inner mold, m")
    _add_common_args(d)
    d.set_defaults(func=cmd_design)

    c = sub.add_parser("control", help="drive a design to target shapes; writes the control sequences")
    c.add_argument("scene", nargs="?", default=None, help="problem: cube_fig6 (default) or a scene file/name")
    c.add_argument("--target", nargs="+", help="target names (oval pear heart cube) or mesh files")
    c.add_argument("--integrator", default="rk4", choices=["rk4", "semi_implicit"])
    c.add_argument("--precision", default="float32", choices=["float32", "float64"])
    c.add_argument("--max-steps", type=int, default=300, help="control-step limit")
    c.add_argument("--no-jamming", action="store_true", help="never jam (path-dependence studies)")
    c.add_argument("--all-actuators", action="store_true",
                   help="use every actuator for every target, ignoring the design's per-target selection")
    _add_common_args(c)
    c.set_defaults(func=cmd_control)

    e = sub.add_parser("export", help="molds (STL), control sequences (CSV/JSON) and USD of a design scene")
    e.add_argument("scene", help="a design scene: a .usda/.usdc file (e.g. out/design.usda) or a shipped name")
    e.add_argument("--what", nargs="+", default=["molds", "control", "usd"], choices=["molds", "control", "usd"])
    e.add_argument("--targets", nargs="+", help="control targets (default: the scene's targets)")
    e.add_argument("--all-actuators", action="store_true",
                   help="use every actuator for every target, ignoring the design's per-target selection")
    e.add_argument("--layer-thickness", type=float, default=5e-3, help="jamming layer (outer mold offset), m")
    e.add_argument("--marker-height", type=float, default=2e-3, help="IPAM marker height on the inner mold, m")
    _add_common_args(e)
    e.set_defaults(func=cmd_export)

    b = sub.add_parser("bench", help="speed benchmarks (tables + JSON)")
    b.add_argument("which", nargs="?", default="sim", choices=["sim", "tradeoff", "design", "peer", "rays", "all"])
    b.add_argument("--device", default="cpu")
    b.add_argument("--subdivisions", type=int, nargs="+", default=[3, 4, 5, 6],
                   help="icosphere subdivisions for the sim bench (3..6: 642..40962 vertices)")
    b.add_argument("--repeats", type=int, default=3)
    b.add_argument("--out", default="out")
    b.set_defaults(func=cmd_bench)

    try:
        from .shapes_cli import register
    except ImportError:
        pass
    else:
        register(sub)
    return p


def main(argv=None) -> int:
    """Entry point of ``warp-shape``: returns 0 on success, 2 on a clear input error, 130 on Ctrl-C."""
    args = build_parser().parse_args(argv)
    from .errors import WarpShapeError

    try:
        return int(args.func(args) or 0)
    except WarpShapeError as exc:
        print(f"warp-shape: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("\nwarp-shape: interrupted; finished outputs were kept", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
