"""``warp-shape export``: fabrication and content outputs of a design scene (molds, control sequences, USD)."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from ..calibration.files import apply_calibration
from ..controller import control_many
from ..designer.run_settings import RunSettings
from ..errors import DesignError
from ..io.atomic import StagedFolder
from ..io.outputs import is_run_output, write_control_outputs, write_figures_or_skip, write_molds
from ..io.saved_runs import replayed_saved_results
from ..io.scene_read import load_scene
from ..io.scene_write import save_scene
from ..io.valve import write_valve_outputs
from ..molds import equivalent_radius
from .calibrate import add_calibration_arg
from .lab_timing import add_timing_args, timing_from_args
from .options import (actuator_selection, add_common_args, check_device, check_mold_flags, check_out,
                      check_rerun, commit, control_progress, load_targets, open_recorder, stop_if_interrupted)

__all__ = ["register", "run"]


def register(subparsers) -> None:
    """Add the ``export`` subcommand."""
    e = subparsers.add_parser("export", help="molds (STL), control sequences (CSV/JSON) and USD of a design scene",
                              description="Write the fabrication and content outputs of a design scene (e.g. "
                                          "out/design.usda): molds, control and valve sequences, USD.")
    e.add_argument("scene", help="a design scene: a .usda/.usdc file (e.g. out/design.usda) or a shipped name")
    e.add_argument("--what", nargs="+", default=["molds", "control", "usd"], choices=["molds", "control", "usd"],
                   help="molds: mold_*.stl and molds_<units>.json; control: control and valve sequences per target "
                        "(the design's saved sequences replayed where they lie beside the scene, else controlled "
                        "anew); usd: design.usda (with control: actuation_<target>.usdc)")
    e.add_argument("--targets", nargs="+", help="control targets (default: the scene's targets)")
    e.add_argument("--all-actuators", action="store_true",
                   help="use every actuator for every target, ignoring the design's per-target selection")
    e.add_argument("--layer-thickness", type=float, default=5e-3, metavar="M",
                   help="jamming layer (outer mold offset), m (at most half the device's radius)")
    e.add_argument("--marker-height", type=float, default=2e-3, metavar="M",
                   help="IPAM boss height on the mold core, m (0: none; at most a quarter of the device's radius)")
    e.add_argument("--mold-units", dest="units", default="mm", choices=["mm", "cm", "m", "in"],
                   help="length unit of the mold STL files (in their names, e.g. mold_core_mm.stl); default mm")
    e.add_argument("--units", dest="input_units", default=None, help=argparse.SUPPRESS)  # another command's meaning
    add_timing_args(e)
    e.add_argument("--passive", choices=["neutral", "zero"], default="neutral",
                   help="pressure written for IPAMs a target does not use: the simulated neutral pressure "
                        "(force-free, default) or 0 kPa (vented)")
    add_calibration_arg(e, "the control sequences are controlled on the calibrated model (molds and USD stay "
                           "the design's)")
    add_common_args(e, out="out/export")  # beside, not inside, a design's own output folder
    e.set_defaults(func=run)


def _checked_inputs(args, staged):
    """(scene, [(name, target)], ControlSettings, the design to control: calibrated with
    ``--calibration``) once every input is checked, before any work:
    ``--out`` (``staged``), the device, the recording path, the scene (a design, its settings), the
    mold lengths and the targets."""
    if args.input_units is not None:
        raise DesignError("export has no --units: elsewhere --units is the unit of input mesh files; the molds' "
                          f"unit is --mold-units (e.g. --mold-units {args.input_units})")
    check_out(staged)
    check_device(args.device)
    check_rerun(args, staged, inputs=[args.scene, args.calibration, *(args.targets or [])])
    scene = load_scene(args.scene)
    stop_if_interrupted()  # a Ctrl-C that USD's start-up swallowed
    if scene.design is None:
        raise DesignError(f"{args.scene} holds no design (only targets); export needs a design scene, "
                          f"e.g. out/design.usda from warp-shape design or the shipped cube_fig6")
    check_mold_flags(args, equivalent_radius(scene.design.rest))
    settings = RunSettings.from_groups(scene.settings).control  # the design's own, as it was designed
    named = load_targets(args.targets) if args.targets else list(zip(scene.target_names, scene.targets))
    controlled = apply_calibration(scene.design, args.calibration) if args.calibration else scene.design
    return scene, named, settings, controlled


def run(args) -> int:
    """Fabrication and content outputs of an existing design: molds, control sequences, USD."""
    staged = StagedFolder(args.out, owned=is_run_output, command="export")
    scene, named, settings, controlled = _checked_inputs(args, staged)
    timing = timing_from_args(args)
    out = Path(args.out)
    written: list = []
    with staged.writing():  # staged, then swapped into --out whole
        _write(args, scene, named, settings, timing, staged.path, written, controlled)
        commit(staged, args)
    written = [out / Path(p).name for p in written]
    if args.json:
        print(json.dumps({"outputs": [str(p) for p in written]}, indent=2))
    else:
        print(f"exported {len(written)} files to {out}/: " + ", ".join(Path(p).name for p in written))
    return 0


def _write(args, scene, named, settings, timing, out: Path, written: list, controlled=None) -> None:
    """The molds, the scene and the control outputs ``--what`` asks for (control with ``settings``,
    the lab sequences on ``timing``), each appended to ``written`` as it is written."""
    if "molds" in args.what:
        written += write_molds(scene.design, out, marker_height=args.marker_height,
                               layer_thickness=args.layer_thickness, units=args.units)
    if "usd" in args.what:
        written.append(save_scene(scene, out / "design.usda"))
    if "control" in args.what and named:
        names = [n for n, _ in named]
        results, note = _saved(args, scene, named, settings, controlled)
        if results is None:
            with open_recorder(args) as rec:
                results = control_many(controlled or scene.design, [t for _, t in named], device=args.device,
                                       settings=settings, progress=control_progress, recorder=rec, target_names=names,
                                       **actuator_selection(args, scene.settings, names))
        print(f"control sequences: {note}", file=sys.stderr)
        written += write_control_outputs(results, names, out, usd="usd" in args.what, timing=timing)
        written += write_valve_outputs(results, names, out, timing, passive=args.passive)
        written += write_figures_or_skip(results, out, names, timing=timing)


def _saved(args, scene, named, settings, controlled):
    """(the design's saved sequences replayed, or None; a line saying which sequences are written and
    why): they are reused unless --calibration or --all-actuators asks for other ones."""
    if args.calibration or args.all_actuators:
        return None, "controlled anew (" + ("--calibration" if args.calibration else "--all-actuators") + \
            " asks for sequences other than the design's)"
    folder = Path(args.scene).parent if Path(args.scene).is_file() else None
    if folder is None:
        return None, "controlled anew (a shipped scene has no saved sequences)"
    results, note = replayed_saved_results(folder, named, controlled or scene.design, settings, device=args.device)
    return results, note if results is not None else f"controlled anew ({note})"
