"""``warp-shape design``: the main job, design a display for target shapes and write every output.

Every input is checked before any work (the scene, the targets, every designer setting, the device,
``--out`` and the recording path). The outputs are staged in ``<out>.partial`` (each finished
round's design in ``rounds.json``, its report and control sequences) and swapped into ``<out>``
whole when the run finishes, with a ``manifest.json`` of every file: ``<out>`` never mixes two
runs, and a failed or killed run leaves the previous set there untouched.
"""

from __future__ import annotations

import json
import math
import sys
import time
from dataclasses import replace

from ..calibration.files import ipam_values, material_values, read_calibration
from ..controller.shard import worker_pool
from ..designer import PLACEMENTS, design
from ..designer.design_settings import CODESIGN_MODES
from ..designer.run_settings import RunSettings
from ..errors import DesignError
from ..feel import feel_map, pressable_directions
from ..interrupts import held_interrupts
from ..io.atomic import StagedFolder
from ..io.figures import prepare_drawing
from ..io.outputs import is_run_output, record_round, write_design_outputs, write_round_outputs
from ..io.report import design_summary
from ..io.scene_read import load_scene
from ..molds import equivalent_radius
from ..material import Material
from ..limits import MAX_ACTUATORS, MAX_CANDIDATES, MAX_REFINE_ROUNDS
from .calibrate import add_calibration_arg
from .lab_timing import add_timing_args, timing_from_args
from .options import (MAX_LENGTH, MIN_LENGTH, add_bounded, add_common_args, add_membrane_arg, add_units_arg,
                      add_workers_arg, check_device, check_mold_flags, check_out, check_rerun, commit, load_targets,
                      material_with_membrane, open_recorder, print_outputs, run_progress, stop_if_interrupted)

__all__ = ["register", "run"]


def register(subparsers) -> None:
    """Add the ``design`` subcommand."""
    d = subparsers.add_parser("design", help="design a display for target shapes (default: oval + heart, 4 IPAMs)",
                              description="Design a shape display for target shapes (Algorithm 1) and write the "
                                          "design, control sequences, molds, figures and reports.")
    d.add_argument("scene", nargs="?", default=None, help="design problem: a shipped scene name or .usda file "
                   "(default: oval_heart)")
    d.add_argument("--targets", nargs="+", help="target names (oval pear heart cube) or mesh files "
                   "(default: the scene's targets)")
    add_bounded(d, "--actuators", 1, MAX_ACTUATORS, type=int, default=None,
                help="number of IPAMs to place (default: the scene's, else 4)")
    d.add_argument("--subdivisions", type=int, default=None,
                   help="base membrane: an icosphere with N subdivisions (10 * 4**N + 2 vertices; 2: 162, 3: 642, "
                        "4: 2562) instead of the scene's base mesh (default: the scene's, 642 vertices)")
    add_bounded(d, "--cell-radius", 5 * MIN_LENGTH, MAX_LENGTH, type=float, default=None, metavar="M",
                help="jamming-cell radius, m (default: the scene's, else 0.012)")
    d.add_argument("--placement", choices=list(PLACEMENTS), default=None,
                   help=f"actuator placement (default: simulated): {PLACEMENTS.help()}")
    add_bounded(d, "--candidates", 1, MAX_CANDIDATES, type=int, default=None,
                   help="K: simulated: holds tried per target per refinement round; greedy: candidate sets per round")
    add_bounded(d, "--refine-rounds", 0, MAX_REFINE_ROUNDS, type=int, default=None,
                   help="simulated placement: refinement rounds at most after the last round (default 5; 0: none)")
    d.add_argument("--codesign", choices=list(CODESIGN_MODES), default=None,
                   help="after placement, optimise by exact gradients: the rest shape ('rest') and the IPAM sizes "
                        "('rest+ipams'), never worse on any target; 'off' keeps the placed design (default: the scene's, else "
                        "rest+ipams; docs/gradients.md)")
    d.add_argument("--keep-rest", action="store_true", help="single-target mode: keep the scene's rest shape")
    d.add_argument("--layer-thickness", type=float, default=5e-3, metavar="M",
                   help="jamming layer (outer mold offset), m (at most half the device's radius)")
    d.add_argument("--marker-height", type=float, default=2e-3, metavar="M",
                   help="IPAM marker height on the inner mold, m (0: none; at most a quarter of the device's radius)")
    add_bounded(d, "--feel", 4, 4096, type=int, nargs="?", const=64, default=None, metavar="POINTS",
                help="also map what a fingertip feels on each controlled shape: POINTS presses (default 64) of "
                     "--feel-depth by a --feel-radius sphere, one per world (feel_<target>.png|csv, a report section, "
                     "a primvar on design.usda; costly: on CPU a 64-point map of a 642-vertex shape takes minutes, "
                     "docs/feel.md)")
    add_bounded(d, "--feel-depth", 1e-5, 0.02, type=float, default=0.002, metavar="M", help="--feel's press depth, m")
    add_bounded(d, "--feel-radius", 1e-3, 0.05, type=float, default=0.008, metavar="M",
                help="--feel's fingertip radius, m")
    add_units_arg(d)
    add_workers_arg(d)
    add_timing_args(d)
    add_calibration_arg(d, "the new design's material (E, t, bending) and its IPAMs' stiffness and area (the "
                           "fitted mean) are the calibrated ones")
    add_membrane_arg(d, "the new design")
    add_common_args(d)
    d.set_defaults(func=run)


def run_settings(scene, args) -> RunSettings:
    """The run's settings: the scene's groups (simulation, controller, designer) and its design's
    material, then the flags; unknown setting names and bad values are errors."""
    designer = dict(actuators=args.actuators, cell_radius=args.cell_radius, placement=args.placement,
                    candidates=args.candidates, refine_rounds=args.refine_rounds, codesign=args.codesign,
                    initialize=False if args.keep_rest else None, workers=args.workers)
    material = scene.design.material if scene.design is not None else None
    if getattr(args, "calibration", None):  # the fitted material, and the fitted IPAMs' mean size for new ones
        calibration = read_calibration(args.calibration)
        material = replace(material or Material(), **material_values(calibration))
        designer.update(ipam_values(calibration))
        if calibration.get("_regions"):
            print(f"note: the calibration's E t per region ({', '.join(calibration['_regions'])}) describes the "
                  f"membrane it was fitted on; a new design takes only its material and mean IPAM size",
                  file=sys.stderr)
    if args.membrane is not None:
        material = material_with_membrane(material or Material(), args.membrane)
    return RunSettings.from_groups(scene.settings, designer=designer, material=material)


def _problem(args):
    """(base mesh, [(name, target)], RunSettings) from the scene and the flags; every input is checked
    here, before anything runs or is written."""
    if args.scene is not None and not args.scene.strip():
        raise DesignError("the scene is an empty name; give a shipped scene name (e.g. oval_heart) or a .usda file, "
                          "or leave it out for the default problem")
    scene = load_scene("oval_heart" if args.scene is None else args.scene)
    if args.subdivisions is not None and not 1 <= args.subdivisions <= 6:
        raise DesignError(f"--subdivisions takes 1..6 (42..40962 vertices), got {args.subdivisions}")
    base = scene.base_mesh(args.subdivisions)
    named = list(zip(scene.target_names, scene.targets))
    if args.targets:
        named = load_targets(args.targets, args.units)
    if not named:
        raise DesignError("no targets: give --targets (e.g. --targets oval heart) or a scene with targets")
    run = run_settings(scene, args)
    check_mold_flags(args, _device_radius(base, named, run.designer))
    return base, named, run


def _device_radius(base, named, settings) -> float:
    """The designed device's radius (m) before it is designed: the rest shape the designer will
    initialise (``volume_scale`` of the smallest target's volume), or the base kept as it is."""
    if not settings.initialize:
        return equivalent_radius(base)
    return settings.volume_scale ** (1.0 / 3.0) * min(equivalent_radius(t) for _, t in named)


def _run_designer(args, base, named, run: RunSettings, staged, bar, rec):
    """Run the designer; each finished round is written to the staging folder as it completes.
    Ctrl-C keeps the finished rounds (in ``<out>`` where it holds no finished run, else in
    ``<out>.partial``); any other failure removes the staging folder."""
    names = [n for n, _ in named]
    records, rounds = [], []

    def on_round(i, d_i, results):
        if record_round(records, i, d_i, results, names):
            rounds.pop()
        rounds.append(results)
        write_round_outputs(staged.path, names, records, rounds)
        staged.seal(False, command="design")

    staged.lock()
    try:
        return design(base, [t for _, t in named], actuators=run.actuators, device=args.device,
                      target_names=names, settings=run.designer, control_settings=run.control,
                      material=run.material, progress=bar.update, on_round=bar.wrap_round(on_round),
                      recorder=rec)
    except KeyboardInterrupt:
        _keep_interrupted(staged, len(records))
        raise
    except DesignError as exc:
        staged.discard()
        hint = _cell_room_hint(exc, args)
        if hint:
            raise DesignError(f"{exc}{hint}") from None
        raise
    except BaseException:
        staged.discard()
        raise


def _cell_room_hint(exc, args) -> str:
    """For the designer's "no room for the cells" error: the cell radius that fits, and what
    ``--subdivisions`` can do (cells cover a fixed share of the surface whatever the mesh; a finer
    mesh helps only where a cell is smaller than a face)."""
    if getattr(exc, "cell_room", None) is None:
        return ""
    need, radius_mm, have = exc.cell_room
    fit_mm = math.floor(10 * radius_mm * math.sqrt(have / max(need, 1))) / 10
    sub = (args.subdivisions or 3) + 1
    return (f". With these actuators, --cell-radius {fit_mm / 1e3:g} (m) fits; a finer base mesh "
            f"(--subdivisions {sub}) helps only where a cell is smaller than a face")


def _keep_interrupted(staged, rounds_done: int) -> None:
    """After Ctrl-C: the finished rounds (and any final outputs written) kept, sealed as they are, in
    ``<out>`` where it holds no finished run, else in ``<out>.partial``; nothing where no round finished."""
    if not rounds_done:
        staged.discard()
        print(f"\nno design round had finished; {staged.out} is unchanged", file=sys.stderr)
        return
    try:
        complete = json.loads((staged.path / "report.json").read_text()).get("complete") is True
    except (OSError, ValueError):
        complete = False
    if staged.holds_complete_set():
        staged.seal(complete, command="design")
        staged.unlock()
        print(f"\n{rounds_done} finished round(s) kept in {staged.partial} ({staged.out} still holds the previous "
              f"finished run)", file=sys.stderr)
    else:
        with held_interrupts():
            staged.commit(complete, command="design")
        print(f"\n{rounds_done} finished round(s) kept in {staged.out} (report.json says complete: "
              f"{str(complete).lower()})", file=sys.stderr)


def feel_maps(res, args) -> dict:
    """{target: FeelMap} of every controlled shape of the design (``--feel``), or {} without the flag."""
    if args.feel is None:
        return {}
    return {name: feel_map(r, pressable_directions(r, args.feel, radius=args.feel_radius), args.feel_depth,
                           args.feel_radius) for name, r in zip(res.target_names, res.results)}


def _write_outputs(res, args, staged, wall: float, timing, rec=None) -> list:
    """Every output of the finished design into the staging folder (with ``--feel`` the stiffness maps, timed
    as ``feel_seconds``, also into the recording ``rec``): the paths written. Ctrl-C keeps what is finished
    (``_keep_interrupted``)."""
    try:
        t0 = time.perf_counter()
        maps = feel_maps(res, args)
        extra = dict(complete=True, wall_seconds=wall, device=args.device)
        if maps:
            extra["feel_seconds"] = time.perf_counter() - t0
        written = write_design_outputs(res, staged.path, marker_height=args.marker_height,
                                       layer_thickness=args.layer_thickness, kept=["rounds.json", "manifest.json"],
                                       extra_report=extra, timing=timing, feel=maps)
        if rec is not None:
            for name, fm in maps.items():
                rec.log_feel_map(name, res.design.rest.faces, fm)
        stop_if_interrupted()
        return written
    except KeyboardInterrupt:
        _keep_interrupted(staged, len(res.rounds))
        raise
    except BaseException:
        staged.discard()
        raise


def _commit(staged, args):
    """The staged outputs swapped into ``<out>`` (the recording, closed by now, in the manifest)."""
    try:
        return commit(staged, args, command="design")  # a Ctrl-C now lets the swap finish
    except BaseException:
        staged.discard()
        raise


def run(args) -> int:
    """Design, then write the scene, control sequences, USD animations, molds, figures and reports."""
    staged = StagedFolder(args.out, owned=is_run_output)
    check_out(staged)
    check_device(args.device)
    check_rerun(args, staged, inputs=[args.scene, args.calibration, *(args.targets or [])])
    base, named, run_opts = _problem(args)
    stop_if_interrupted()  # a Ctrl-C that USD's start-up swallowed
    timing = timing_from_args(args)
    t0 = time.perf_counter()
    with run_progress(run_opts.actuators + 1, [n for n, _ in named], run_opts.designer, run_opts.control) as bar, \
            worker_pool(run_opts.designer.workers) as pool:  # the run's workers, who draw the figures too
        if pool is not None and str(args.device).startswith("cpu"):
            pool.when_idle(prepare_drawing)
            pool.start(len(named))  # they start while the designer sets up
        with open_recorder(args) as rec:
            res = _run_designer(args, base, named, run_opts, staged, bar, rec)
            wall = time.perf_counter() - t0
            bar.writing_outputs()
            written = _write_outputs(res, args, staged, wall, timing, rec)
            if rec is not None:  # the report's figures, the same images, in the recording
                rec.log_figures([p for p in written if p.suffix == ".png"])
        out = _commit(staged, args)
    report = json.loads((out / "report.json").read_text())
    if args.json:
        print(json.dumps(report, indent=2))
    else:
        print(f"design of {', '.join(n for n, _ in named)} finished in {wall:.1f} s: "
              + "\n".join(design_summary(res)))
        print(f"\nthe full report: {out / 'report.md'}")
        print_outputs(out, report["outputs"], args, short=True, next_step=f"print the molds (mold_*_mm.stl); re-control the saved design: warp-shape "
                      f"control {out / 'design.usda'} --out {out / 'control'}")
    return 0
