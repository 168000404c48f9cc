"""``warp-shape control``: drive a design to target shapes and write the control sequences."""

from __future__ import annotations

import json
from pathlib import Path

import argparse

from ..calibration.files import apply_calibration
from ..controller import CONTROL_METHODS, control_many
from ..designer.run_settings import RunSettings
from ..io.atomic import StagedFolder
from ..io.outputs import write_control_outputs, write_figures_or_skip
from ..limits import MAX_CONTROL_STEPS
from .calibrate import add_calibration_arg
from .options import (ControlProgress, actuator_selection, add_bounded, add_common_args, add_membrane_arg,
                      add_units_arg,
                      add_workers_arg, check_device, check_out, check_rerun, commit, open_recorder, print_outputs, with_membrane,
                      resolve_design_and_targets, stop_if_interrupted)

__all__ = ["register", "run"]


def register(subparsers) -> None:
    """Add the ``control`` subcommand."""
    c = subparsers.add_parser("control", help="drive a design to target shapes; writes the control sequences",
                              description="Control a design (a scene, default the Fig. 6 device) to each target "
                                          "shape: the paper's law, then model-based control by default; writes "
                                          "control_<target>.csv|json and a figure per target.")
    c.add_argument("scene", nargs="?", default=None, help="problem: cube_fig6 (default) or a scene file/name")
    c.add_argument("--targets", nargs="+", help="target names (oval pear heart cube) or mesh files "
                   "(default: the scene's targets)")
    c.add_argument("--target", nargs="+", dest="targets", help=argparse.SUPPRESS)  # the former spelling
    c.add_argument("--integrator", default=None, choices=["rk4", "semi_implicit"],
                   help="overrides the scene's simulation:integrator (default rk4)")
    c.add_argument("--precision", default=None, choices=["float32", "float64"],
                   help="overrides the scene's simulation:precision (default float32)")
    add_bounded(c, "--max-steps", 1, MAX_CONTROL_STEPS, type=int, default=None,
                help="control-step limit (default: the scene's controller:max_steps, else 300)")
    c.add_argument("--method", default=None, choices=list(CONTROL_METHODS),
                   help=f"control method (default: the scene's controller:method, else inverse): "
                        f"{CONTROL_METHODS.help()}")
    c.add_argument("--no-jamming", action="store_true", help="never jam (path-dependence studies)")
    c.add_argument("--all-actuators", action="store_true",
                   help="use every actuator for every target, ignoring the design's per-target selection")
    add_units_arg(c)
    add_calibration_arg(c, "each target's sequence is controlled on the calibrated model (its fitted "
                           "material, IPAMs and rest scale)")
    add_workers_arg(c)
    add_membrane_arg(c, "the scene's design")
    add_common_args(c, out="out/control")
    c.set_defaults(func=run)


def _print_table(design, settings, names, results, args, out: Path) -> None:
    print(f"design: {design.rest.n_vertices} vertices, {design.n_ipams} IPAMs, {design.n_cells} cells; "
          f"{settings.simulation.integrator} {settings.simulation.precision} on {args.device}; "
          f"method {settings.method}")
    print(f"{'target':<10}{'objective':>10}{'PCC':>8}{'MARE mm':>9}{'MPRE %':>8}{'vol err %':>10}{'steps':>7}"
          f"  converged")
    for name, res in zip(names, results):
        print(f"{name:<10}{res.objective:10.4f}{res.pcc:8.4f}{res.mare * 1e3:9.3f}{res.mpre:8.2f}"
              f"{100 * res.volume_error:10.3f}{res.control_steps:7d}  {'yes' if res.converged else 'no'}")
        print(f"    {res.reason}")
        if res.saturated:
            print(f"    saturated: {'; '.join(res.saturated)}")
        info = res.refinement
        if info:
            kept = "kept the paper law's result" if info["fell_back"] else f"plan {info['plan']}"
            print(f"    inverse: {kept}; objective {info['warm_objective']:.5f} (paper) -> {info['objective']:.5f}, "
                  f"{info['iterations']} Gauss-Newton step(s), {info['wall_s']:.1f} s")
        for a in res.actuator_summary:
            print(f"    IPAM {a['ipam']}: push {a['peak_push_n']:.3f} N, pull {a['peak_pull_n']:.3f} N, "
                  f"strain {a['peak_strain']:.3f}, pressure {a['pressure_min_pa'] / 1e3:.1f}.."
                  f"{a['pressure_max_pa'] / 1e3:.1f} kPa")


def run(args) -> int:
    """Control the design to every chosen target; write figures and ``control_<target>.csv|json``
    (staged and swapped into ``--out`` whole, see ``StagedFolder``)."""
    staged = StagedFolder(args.out, owned=lambda name: name.startswith("control_"), command="control")
    check_out(staged)
    check_device(args.device)
    check_rerun(args, staged, inputs=[args.scene, args.calibration, *(args.targets or [])])
    design, targets, scene_settings = resolve_design_and_targets(args.scene, args.targets, args.units)
    if args.calibration:
        design = apply_calibration(design, args.calibration)
    design = with_membrane(design, args.membrane)
    stop_if_interrupted()  # a Ctrl-C that USD's start-up swallowed
    names = [n for n, _ in targets]
    # the scene's simulation and controller settings (checked: unknown keys and bad values are errors),
    # then the flags
    settings = RunSettings.from_groups(
        scene_settings, simulation=dict(integrator=args.integrator, precision=args.precision),
        controller=dict(max_steps=args.max_steps, method=args.method,
                        jamming=False if args.no_jamming else None, workers=args.workers)).control
    with staged.writing():
        with open_recorder(args) as rec, ControlProgress(refine=CONTROL_METHODS[settings.method].refines) as bar:
            results = control_many(design, [t for _, t in targets], device=args.device, settings=settings,
                                   progress=bar.update, recorder=rec, target_names=names,
                                   **actuator_selection(args, scene_settings, names))
        written = write_figures_or_skip(results, staged.path, names)
        written += write_control_outputs(results, names, staged.path)
        commit(staged, args)
    out = Path(args.out)
    if args.json:
        print(json.dumps({name: res.summary() for name, res in zip(names, results)}, indent=2))
        return 0
    _print_table(design, settings, names, results, args, out)
    print_outputs(out, sorted(Path(p).name for p in written), args,
                  next_step=f"look at {out / ('control_' + names[0] + '.png')}; the sequences (one row per control "
                            f"step) are the control_<target>.csv files")
    return 0
