"""``warp-shape feel``: what a fingertip feels on a design's controlled shapes: per target, a stiffness
map (N/mm over the surface) as a figure, a CSV and a section of ``feel_report.md``."""

from __future__ import annotations

import json
from pathlib import Path

from ..controller import CONTROL_METHODS, control_many
from ..designer.run_settings import RunSettings
from ..feel import feel_map, pressable_directions
from ..io.atomic import StagedFolder, atomic_write
from ..limits import MAX_CONTROL_STEPS
from ..io.feel_outputs import feel_figure, feel_report_section, write_feel_csv
from .options import (actuator_selection, add_bounded, add_common_args, check_device, check_out, commit, print_outputs,
                      resolve_design_and_targets, stop_if_interrupted)

__all__ = ["register", "run"]


def register(subparsers) -> None:
    """Add the ``feel`` subcommand."""
    c = subparsers.add_parser("feel", help="stiffness maps: what a fingertip feels on each controlled shape",
                              description="Control a design (a design.usda or scene; default the Fig. 6 device) to "
                                          "each target, then press a fingertip into the final shape at points spread "
                                          "over it (one press per world, the device held at its plug): writes "
                                          "feel_<target>.png|csv and feel_report.md (docs/feel.md).")
    c.add_argument("scene", nargs="?", default=None, help="design.usda, a scene file/name or cube_fig6 (default)")
    c.add_argument("--target", nargs="+", dest="targets", metavar="NAME",
                   help="target names (default: the design's targets)")
    add_bounded(c, "--points", 4, 4096, type=int, default=64,
                help="directions pressed (a Fibonacci lattice, the plug's left out)")
    add_bounded(c, "--depth", 1e-5, 0.02, type=float, default=0.002, help="press depth, m")
    add_bounded(c, "--radius", 1e-3, 0.05, type=float, default=0.008, help="fingertip radius, m")
    c.add_argument("--method", default=None, choices=list(CONTROL_METHODS),
                   help="control method (default: the scene's controller:method, else inverse)")
    add_bounded(c, "--max-steps", 1, MAX_CONTROL_STEPS, type=int, default=None,
                help="control-step limit (default: the scene's controller:max_steps, else 300)")
    add_common_args(c, rerun=False)
    c.set_defaults(func=run)


def write_maps(results, names, design, folder: Path, args) -> tuple[list, dict]:
    """Per target the map's CSV and figure, then the report, into ``folder``; (paths, summary)."""
    written, sections, summary = [], ["# Feel\n"], {}
    for name, res in zip(names, results):
        fm = feel_map(res, pressable_directions(res, args.points, radius=args.radius), args.depth, args.radius)
        written.append(write_feel_csv(folder / f"feel_{name}.csv", fm.directions, fm.points, fm.stiffness))
        written.append(feel_figure(folder / f"feel_{name}.png", fm.positions, design.rest.faces, design.face_cell(),
                                   fm.points, fm.stiffness, title=f"{name}: fingertip stiffness at "
                                                                  f"{args.depth * 1e3:.3g} mm"))
        sections.append(feel_report_section(name, fm.stiffness, fm.depth, fm.radius, fm.points))
        summary[name] = dict(points=len(fm.stiffness), min_n_per_mm=float(fm.stiffness.min()) / 1000,
                             median_n_per_mm=float(sorted(fm.stiffness)[len(fm.stiffness) // 2]) / 1000,
                             max_n_per_mm=float(fm.stiffness.max()) / 1000)
    written.append(atomic_write(folder / "feel_report.md", "\n".join(sections)))
    return written, summary


def run(args) -> int:
    """Control the design to every target, then map the fingertip's stiffness over each final shape."""
    staged = StagedFolder(args.out, owned=lambda name: name.startswith("feel_"), command="feel")
    check_out(staged)
    check_device(args.device)
    design, targets, scene_settings = resolve_design_and_targets(args.scene, args.targets)
    stop_if_interrupted()
    names = [n for n, _ in targets]
    settings = RunSettings.from_groups(scene_settings,
                                       controller=dict(max_steps=args.max_steps, method=args.method)).control
    with staged.writing():
        results = control_many(design, [t for _, t in targets], device=args.device, settings=settings,
                               target_names=names, **actuator_selection(args, scene_settings, names))
        written, summary = write_maps(results, names, design, staged.path, args)
        commit(staged, args)
    out = Path(args.out)
    if args.json:
        print(json.dumps(summary, indent=2))
        return 0
    for name, row in summary.items():
        print(f"{name}: {row['points']} points, fingertip stiffness {row['min_n_per_mm']:.4f} .. "
              f"{row['max_n_per_mm']:.4f} N/mm (median {row['median_n_per_mm']:.4f})")
    print_outputs(out, sorted(Path(p).name for p in written), args)
    return 0
