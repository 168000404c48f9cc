"""``warp-shape design``: the main job, design a display for target shapes and write every output."""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

from .options import add_common_args, control_progress, load_targets, open_recorder, quiet_warp

__all__ = ["register", "run"]


def register(subparsers) -> None:
    """Add the ``design`` subcommand."""
    d = subparsers.add_parser("design", help="design a display for target shapes (default: oval + heart, 4 IPAMs)")
    d.add_argument("scene", nargs="?", default=None, help="design problem: a shipped scene name or .usda file "
                   "(default oval_heart)")
    d.add_argument("--targets", nargs="+", help="target names (oval pear heart cube) or mesh files")
    d.add_argument("--actuators", type=int, default=None, help="number of IPAMs to place")
    d.add_argument("--cell-radius", type=float, default=None, help="jamming-cell radius, m")
    d.add_argument("--placement", choices=["paper", "simulated"], default=None,
                   help="actuator placement: simulated candidate sets (default) or the paper's Algorithm 1")
    d.add_argument("--candidates", type=int, default=None, help="simulated placement: candidate sets per round (K)")
    d.add_argument("--keep-rest", action="store_true", help="single-target mode: keep the scene's rest shape")
    d.add_argument("--layer-thickness", type=float, default=5e-3, help="jamming layer (outer mold offset), m")
    d.add_argument("--marker-height", type=float, default=2e-3, help="IPAM marker height on the inner mold, m")
    add_common_args(d)
    d.set_defaults(func=run)


def _problem(args):
    """(base mesh, [(name, target)], actuators, DesignSettings) from the scene and the flags; every
    input is checked here, before anything is written."""
    from ..designer import DesignSettings
    from ..errors import DesignError
    from ..mesh import icosphere
    from ..io.scene_read import load_scene

    scene = load_scene(args.scene or "oval_heart")
    base = scene.design.rest if scene.design is not None else icosphere(3, 0.035)
    named = list(zip(scene.target_names, scene.targets))
    if args.targets:
        named = load_targets(args.targets)
    if not named:
        raise DesignError("no targets: give --targets (e.g. --targets oval heart) or a scene with targets")
    opts = dict((scene.settings or {}).get("designer", {}))
    actuators = int(args.actuators if args.actuators is not None else opts.pop("actuators", 4))
    opts.pop("actuators", None)
    if args.cell_radius is not None:
        opts["cell_radius"] = args.cell_radius
    for key in ("placement", "candidates"):
        if getattr(args, key, None) is not None:
            opts[key] = getattr(args, key)
    settings = DesignSettings(**{k: v for k, v in opts.items() if k in DesignSettings.__dataclass_fields__},
                              initialize=not args.keep_rest)
    return base, named, actuators, settings


def _design_keeping_rounds(args, base, named, actuators, settings, out: Path):
    """Run the designer, writing each finished round as it completes (an interrupted run keeps them);
    a run that fails otherwise removes what it wrote."""
    from ..designer import design
    from ..io.outputs import write_round_outputs

    names = [n for n, _ in named]
    written: list[Path] = []
    rounds_seen: list = []

    def progress(i, p, step, total, done, worlds):
        control_progress(step, total, done, worlds, prefix=f"round {i}/{p}: ")

    def on_round(i, d_i, results):
        rounds_seen.append(results)
        written.extend(write_round_outputs(out, i, names, rounds_seen))

    try:
        with open_recorder(args) as rec:
            return design(base, [t for _, t in named], actuators=actuators, device=args.device, target_names=names,
                          settings=settings, progress=progress, on_round=on_round, recorder=rec)
    except Exception:
        if not isinstance(sys.exc_info()[1], KeyboardInterrupt):
            for path in written:  # a failed run leaves no partial outputs
                path.unlink(missing_ok=True)
        raise


def run(args) -> int:
    """Design, then write the scene, control sequences, USD animations, molds, figures and reports."""
    quiet_warp(args.verbose)
    from ..io.outputs import write_design_outputs
    from ..io.report import design_markdown

    base, named, actuators, settings = _problem(args)
    out = Path(args.out)
    t0 = time.perf_counter()
    res = _design_keeping_rounds(args, base, named, actuators, settings, out)
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
