"""Options and helpers shared by the subcommands: common flags, progress display, Warp quieting, targets."""

from __future__ import annotations

import contextlib
import sys
from pathlib import Path

__all__ = ["add_common_args", "add_rerun_args", "open_recorder", "quiet_warp", "progress", "control_progress",
           "load_targets", "resolve_design_and_targets", "actuator_selection"]


def add_common_args(sp, rerun: bool = True) -> None:
    """``--device``, ``--out``, ``--json``, ``--verbose`` and (with ``rerun``) the rerun flags."""
    sp.add_argument("--device", default="cpu", help="Warp device: cpu or cuda:N")
    sp.add_argument("--out", default="out", help="output directory")
    sp.add_argument("--json", action="store_true", help="print machine-readable results")
    sp.add_argument("--verbose", action="store_true", help="show Warp's compile messages")
    if rerun:
        add_rerun_args(sp)


def add_rerun_args(sp) -> None:
    """``--rerun FILE.rrd``, ``--rerun-spawn`` and ``--rerun-every``."""
    sp.add_argument("--rerun", metavar="FILE.rrd", default=None, help="write a rerun recording (open: rerun FILE.rrd)")
    sp.add_argument("--rerun-spawn", action="store_true", help="stream to a live rerun viewer (needs a display)")
    sp.add_argument("--rerun-every", type=int, default=1, help="log every k-th control step (the last is always logged)")


def open_recorder(args):
    """A context manager giving the rerun ``Recorder`` the flags ask for, or None."""
    if not (getattr(args, "rerun", None) or getattr(args, "rerun_spawn", False)):
        return contextlib.nullcontext(None)
    from ..io.recorder import Recorder

    return Recorder(args.rerun, spawn=args.rerun_spawn, every=args.rerun_every)


def quiet_warp(verbose: bool = False) -> None:
    """Silence Warp's banner and compile messages unless ``verbose``."""
    import warp as wp

    wp.config.quiet = not verbose
    if not verbose:
        wp.config.log_level = wp.LOG_WARNING


def progress(done: int, total: int, label: str, stream=sys.stderr) -> None:
    """A one-line progress bar on a terminal; a line per 10 % in logs."""
    if stream.isatty():
        stream.write(f"\r{label}: {done}/{total} ({100.0 * done / total:5.1f} %)" + ("\n" if done == total else ""))
    elif done == total or done % max(1, total // 10) == 0:
        stream.write(f"{label}: {done}/{total} ({100.0 * done / total:5.1f} %)\n")
    stream.flush()


def control_progress(step, total, done, worlds, prefix: str = "") -> None:
    """Progress of a control run over several targets; complete once every target is done."""
    progress(total if done == worlds else step, total, f"{prefix}control ({done}/{worlds} targets done)")


def load_targets(specs) -> list:
    """Target names (oval pear heart cube) or mesh files -> [(name, TriMesh)]."""
    from ..mesh import TriMesh
    from ..targets import TARGET_NAMES, target

    out = []
    for spec in specs:
        if spec in TARGET_NAMES:
            out.append((spec, target(spec)))
        else:
            out.append((Path(spec).stem, TriMesh.load(spec, center=True)))
    return out


def resolve_design_and_targets(scene: str | None, target_names):
    """The built-in Fig. 6 problem (no USD needed), or a scene file / shipped scene name; then the
    chosen targets: the scene's own by name, else shipped target names or mesh files."""
    from ..scenarios import cube_fig6_design
    from ..targets import target

    if scene in (None, "cube_fig6", "fig6"):
        design, targets, settings = cube_fig6_design(), [("cube", target("cube"))], {}
    else:
        from ..io.scene_read import load_scene

        sc = load_scene(scene)
        design, settings = sc.design, sc.settings or {}
        targets = list(zip(sc.target_names, sc.targets))
    if target_names:
        own = dict(targets)
        targets = [(name, own[name]) if name in own else load_targets([name])[0] for name in target_names]
    return design, targets, settings


def actuator_selection(args, scene_settings, names) -> dict:
    """The per-target actuator selection a design stored in its scene (unless --all-actuators), as
    ``control_many`` keyword arguments."""
    from ..designer import selection_from_settings

    if getattr(args, "all_actuators", False):
        return {}
    ipams, cells = selection_from_settings(scene_settings, names)
    return dict(passive_ipams=ipams, passive_cells=cells) if any(ipams) or any(cells) else {}
