"""Options and helpers shared by the subcommands: common flags, checks made before any work, Warp
quieting, progress, targets and scenes by name, the closing list of outputs."""

from __future__ import annotations

import contextlib
import dataclasses
import errno
import math
import os
import signal
import sys
import tempfile
import threading
from pathlib import Path

import numpy as np
import warp as wp

from ..controller.shard import MAX_WORKERS
from ..designer import passive_from_settings
from ..errors import DesignError
from ..interrupts import held_interrupts, release_the_command
from ..io.atomic import MANIFEST, creation_refused, special_kind
from ..io.recorder import Recorder, viewer_problem
from ..io.recording_read import RRD_MAGIC
from ..material import MEMBRANE_LAWS
from ..io.scene_read import load_scene
from ..model import check_device as check_warp_device
from ..molds import check_mold_lengths
from ..sampling import check_star_shaped
from ..scan import LENGTH_UNITS, length_unit_of
from ..scenarios import cube_fig6_design
from ..targets import TARGET_NAMES, load_target, target
from .progress import Bar, ControlProgress, DesignProgress

__all__ = ["MIN_LENGTH", "MAX_LENGTH", "add_common_args", "add_rerun_args", "add_units_arg", "open_recorder", "quiet_warp", "grouped_outputs", "control_progress",
           "add_workers_arg", "load_targets", "resolve_design_and_targets", "actuator_selection", "check_device",
           "check_out", "check_rerun", "commit", "check_mold_flags", "recording_entry", "print_outputs", "run_progress", "Bar",
           "ControlProgress",
           "interrupts_noted", "stop_if_interrupted", "outputs_in_place", "check_warp_cache", "write_failure", "add_bounded", "check_bounds"]

CUDA_DRIVER_NOTE = b"Could not find or load the NVIDIA CUDA driver"
#: the range of a length flag (m): 0.1 mm (a printer's resolution) to 0.5 m (a display is a few cm)
MIN_LENGTH, MAX_LENGTH = 1e-4, 0.5


def add_membrane_arg(sp, what: str) -> None:
    """``--membrane LAW``: the membrane law (``Material.membrane``) of ``what``."""
    sp.add_argument("--membrane", choices=list(MEMBRANE_LAWS), default=None,
                    help=f"membrane law of {what}: 'springs' (the paper's edge-spring lattice), 'neo_hookean' or "
                         f"'yeoh' (a thin incompressible hyperelastic sheet; docs/membrane.md) (default: the scene's)")


def material_with_membrane(material, law: str | None):
    """``material`` with its membrane law set to ``law`` (None: as it is); a Yeoh law keeps the
    material's C2, C3 and a law that is not Yeoh drops them."""
    if law is None or material.membrane == law:
        return material
    keep = law == "yeoh"
    return dataclasses.replace(material, membrane=law, yeoh_c2=material.yeoh_c2 if keep else 0.0,
                               yeoh_c3=material.yeoh_c3 if keep else 0.0)


def with_membrane(design, law: str | None):
    """``design`` with its material's membrane law set to ``law`` (None: as it is; ``material_with_membrane``)."""
    material = material_with_membrane(design.material, law)
    return design if material is design.material else design.replace(material=material)


def add_common_args(sp, rerun: bool = True, out: str = "out") -> None:
    """``--device``, ``--out`` (default ``out``), ``--json``, ``--verbose`` and (with ``rerun``) the
    rerun flags."""
    sp.add_argument("--device", default="cpu", help="Warp device: cpu or cuda:N")
    sp.add_argument("--out", default=out, help="output folder")
    sp.add_argument("--json", action="store_true", help="print machine-readable results")
    sp.add_argument("--verbose", action="store_true", help="show Warp's start-up and compile messages")
    if rerun:
        add_rerun_args(sp)


def add_workers_arg(sp) -> None:
    """``--workers N``: processes a batch of control jobs is sharded over (0: every core, 1: one process)."""
    add_bounded(sp, "--workers", 1, MAX_WORKERS, zero=True, type=int, default=None,
                help="worker processes the batches of targets run on, each its own Warp CPU instance (default: "
                     "every core; 1: one process, as before; WARP_SHAPE_WORKERS sets the default)")


def add_bounded(sp, flag: str, lo: float, hi: float, *, zero: bool = False, **kwargs):
    """``sp.add_argument(flag, **kwargs)`` for a number (or numbers, with ``nargs``) that ``check_bounds``
    holds to ``lo..hi`` (and 0, with ``zero``: the flag's "off") before any work; the help names the bounds."""
    span = f"{'0 or ' if zero else ''}{lo:g}..{hi:g}"
    kwargs["help"] = f"{kwargs.get('help', '')} [{span}]".strip()
    action = sp.add_argument(flag, **kwargs)
    sp.set_defaults(flag_bounds={**(sp.get_default("flag_bounds") or {}), action.dest: (flag, lo, hi, zero)})
    return action


def check_bounds(args) -> None:
    """Every number a flag of ``add_bounded`` was given, within its bounds: a one-line error naming them
    otherwise (rates, counts, resolutions and steps all request memory, disk or time in proportion)."""
    for dest, (flag, lo, hi, zero) in (getattr(args, "flag_bounds", None) or {}).items():
        value = getattr(args, dest, None)
        for v in value if isinstance(value, (list, tuple)) else [value]:
            if v is None or (zero and v == 0) or (math.isfinite(v) and lo <= v <= hi):
                continue
            got = v if isinstance(v, int) else f"{v:g}"
            raise DesignError(f"{flag} takes {'0 or ' if zero else ''}{lo:g}..{hi:g}, got {got}; give a value "
                              f"within these bounds")


def add_rerun_args(sp) -> None:
    """``--rerun FILE.rrd``, ``--rerun-spawn`` and ``--rerun-every``."""
    sp.add_argument("--rerun", metavar="FILE.rrd", default=None,
                    help="write a rerun recording (open it with: warp-shape view FILE.rrd)")
    sp.add_argument("--rerun-spawn", action="store_true", help="stream to a live rerun viewer (needs a display)")
    add_bounded(sp, "--rerun-every", 1, 10**9, type=int, default=1,
                help="log every k-th control step (the last is always logged)")


def add_units_arg(sp) -> None:
    """``--units auto|m|mm``: the length unit of target mesh files."""
    sp.add_argument("--units", choices=("auto", "m", "mm"), default="auto",
                    help="length unit of target mesh files: auto (default) reads a file as millimetres when its "
                         "size is a display's in mm, else as metres; shipped targets and scenes are in metres")


def open_recorder(args):
    """A context manager giving the rerun ``Recorder`` the flags ask for, or None."""
    if not (getattr(args, "rerun", None) or getattr(args, "rerun_spawn", False)):
        return contextlib.nullcontext(None)
    return Recorder(args.rerun, spawn=args.rerun_spawn, every=args.rerun_every)


@contextlib.contextmanager
def _held_stderr(drop):
    """Run Warp with the C-level stderr held (Warp 1.19 prints its CUDA notes and errors from native
    code, with no setting to turn them off); afterwards the lines ``drop(line)`` rejects are passed on."""
    sys.stderr.flush()
    saved = os.dup(2)
    with tempfile.TemporaryFile() as held:
        os.dup2(held.fileno(), 2)
        try:
            yield
        finally:
            os.dup2(saved, 2)
            os.close(saved)
            held.seek(0)
            rest = [ln for ln in held.read().splitlines(keepends=True) if not drop(ln)]
            if rest:
                sys.stderr.write(b"".join(rest).decode(errors="replace"))
                sys.stderr.flush()


def check_warp_cache() -> None:
    """``WARP_CACHE_PATH`` (Warp's kernel cache), where it is set, a folder this process can write to:
    a one-line error before Warp starts (Warp itself ends in a traceback)."""
    path = os.environ.get("WARP_CACHE_PATH")
    if not path:
        return
    try:
        os.makedirs(path, exist_ok=True)
        reason = creation_refused(path)
    except OSError as exc:
        reason = exc.strerror or type(exc).__name__
    if reason is not None:
        raise DesignError(f"WARP_CACHE_PATH {path} cannot hold Warp's kernel cache ({reason}); give it a folder you "
                          f"can write to, or unset it")


def quiet_warp(verbose: bool = False) -> None:
    """Silence Warp's banner and compile messages unless ``verbose`` (``wp.config.log_level``) and
    start Warp without its note that no CUDA driver was found (the device check says what matters)."""
    if verbose:
        return
    wp.config.log_level = wp.LOG_WARNING
    with _held_stderr(lambda line: CUDA_DRIVER_NOTE in line):
        wp.init()  # a no-op once Warp has started


_INTERRUPTS: list = []  # Ctrl-C presses since ``interrupts_noted`` began
_IN_PLACE: list = []  # the command's finished set, once swapped into its folder (``commit``)


@contextlib.contextmanager
def interrupts_noted():
    """Ctrl-C raises ``KeyboardInterrupt`` as usual and is also noted, so that one a library swallowed
    (USD's module loading prints "Error occurred postprocessing module" and goes on) still stops the
    run at the next ``stop_if_interrupted``. Main thread only; the previous handler is restored."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def on_sigint(signum, frame):
        _INTERRUPTS.append(signum)
        raise KeyboardInterrupt

    _INTERRUPTS.clear()
    _IN_PLACE.clear()
    previous = signal.signal(signal.SIGINT, on_sigint)
    before_start, pressed = release_the_command()  # Ctrl-C while the command started
    previous = before_start or previous
    if pressed:
        _INTERRUPTS.append(signal.SIGINT)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


def stop_if_interrupted() -> None:
    """``KeyboardInterrupt`` where Ctrl-C was pressed since the command began (even if swallowed), unless
    the command's finished set is in place already (``outputs_in_place``): then the run has done its work."""
    if _INTERRUPTS and not _IN_PLACE:
        raise KeyboardInterrupt


def outputs_in_place():
    """The folder the command's finished set was swapped into (``commit``), or None: a Ctrl-C after that
    swap ends the command as a success, the new set whole; before it, as interrupted, the previous set whole."""
    return _IN_PLACE[-1] if _IN_PLACE else None


#: what a failing disk answers a write with, as the one line a user reads
WRITE_ERRNOS = {errno.ENOSPC: "no space left on the device", errno.EDQUOT: "the disk quota is used up",
                errno.EFBIG: "a file is larger than the file system allows",
                errno.EROFS: "the file system is read-only",
                errno.EIO: "the disk answered with an input/output error"}


def write_failure(exc: OSError) -> str | None:
    """One line for a write a full, read-only or failing disk refused (naming the file and the fix);
    None for any other ``OSError``."""
    what = WRITE_ERRNOS.get(exc.errno)
    if what is None:
        return None
    where = f" writing {exc.filename}" if exc.filename else ""
    return (f"{what}{where}; no file was left half-written: free some space (or fix the disk) and run again, or "
            f"give --out a folder on another disk")


def check_device(device: str) -> str:
    """The Warp name of ``device``; a clear error (listing the devices here) where it is absent, without
    the CUDA errors Warp prints while it looks for one."""
    failed = []
    with _held_stderr(lambda line: bool(failed) and line.startswith(b"Warp CUDA error")):
        try:
            return check_warp_device(device)
        except Exception:
            failed.append(True)
            raise


def check_out(staged) -> None:
    """``--out`` checked before any work: a file in its place, a folder that cannot be written, a
    folder that is not the command's own set to replace (``StagedFolder.check``)."""
    staged.check()


def check_rerun(args, staged=None, inputs=()) -> None:
    """``--rerun FILE.rrd`` and ``--rerun-spawn`` checked before any work: rerun-sdk installed, a viewer
    that can start, the folder writable, and nothing of the user's replaced by the recording
    (``_check_rerun_path``: not an input of the run, not a file other than a recording, not one of
    ``staged``'s output names)."""
    path = getattr(args, "rerun", None)
    if not (path or getattr(args, "rerun_spawn", False)):
        return
    try:
        import rerun  # noqa: F401  (optional, ~1 s to import: only when a recording is asked for)
    except ImportError:
        raise DesignError("--rerun needs rerun-sdk: pip install 'warp-shape[rerun]'") from None
    if getattr(args, "rerun_spawn", False):
        problem = viewer_problem()
        if problem is not None:
            raise DesignError(f"--rerun-spawn cannot open a viewer: {problem}; record to a file instead "
                              f"(--rerun run.rrd) and open it with warp-shape view run.rrd")
    if path:
        _check_rerun_path(path, staged, inputs)


def _check_rerun_path(path, staged, inputs) -> None:
    p = Path(path).expanduser().absolute()
    if len(os.fsencode(p.name)) > 240:
        raise DesignError(f"--rerun {path[:40]}...: the file name is {len(os.fsencode(p.name))} bytes long, more than a "
                          f"file system allows with the recording's temporary suffix; give a shorter name")
    if p.is_dir():
        raise DesignError(f"--rerun {path} is a folder; give a file name such as {p / 'run.rrd'}")
    folder = p.parent
    while not folder.exists():
        folder = folder.parent
    reason = "not a folder" if not folder.is_dir() else creation_refused(folder)
    if reason is not None:
        raise DesignError(f"--rerun {path}: {folder} is not writable ({reason}); give a path in a folder you "
                          f"can write to, e.g. --rerun out/run.rrd")
    real = os.path.realpath(p)
    for given in inputs:
        if given and os.path.lexists(os.path.expanduser(str(given))) \
                and os.path.realpath(os.path.expanduser(str(given))) == real:
            raise DesignError(f"--rerun {path} is an input of this run ({given}); the recording would replace it: "
                              f"give the recording a name of its own, e.g. --rerun run.rrd")
    if staged is not None and (p.parent.resolve() in (staged.out, staged.partial)) \
            and (p.name == MANIFEST or staged.owned(p.name)):
        raise DesignError(f"--rerun {path} is named as one of this run's outputs in {staged.out}; the recording "
                          f"and the output would replace each other: give it another name, e.g. --rerun "
                          f"{staged.out / 'run.rrd'}")
    if p.is_symlink():
        raise DesignError(f"--rerun {path} is a symbolic link; the recording would replace it: give the path "
                          f"of the recording itself")
    if p.exists():
        if not p.is_file():
            raise DesignError(f"--rerun {path} is a {special_kind(p)}; give a file name such as run.rrd")
        with open(p, "rb") as f:
            head = f.read(len(RRD_MAGIC))
        if head and head != RRD_MAGIC:
            raise DesignError(f"--rerun {path} exists and is not a rerun recording; the recording would replace "
                              f"it: give a new file name (or the path of an earlier recording), e.g. --rerun run.rrd")


def commit(staged, args, **info):
    """The staged set swapped into ``<out>`` whole (``StagedFolder.commit``, the run's recording in its
    manifest); a Ctrl-C now lets the swap finish, then stops. Returns ``<out>``."""
    stop_if_interrupted()
    with held_interrupts():  # a Ctrl-C now waits for the swap's end, where the set is in place
        out = staged.commit(True, **recording_entry(args), **info)
        _IN_PLACE.append(out)
    return out


def check_mold_flags(args, radius: float) -> None:
    """``--layer-thickness`` and ``--marker-height`` (m) checked against a device of ``radius`` m
    before any work (``molds.check_mold_lengths``)."""
    check_mold_lengths(radius, spell=lambda name: "--" + name.replace("_", "-"),
                       layer_thickness=args.layer_thickness, marker_height=args.marker_height)
    for flag, value in (("--layer-thickness", args.layer_thickness), ("--marker-height", args.marker_height)):
        if 0 < value < MIN_LENGTH:
            raise DesignError(f"{flag} {value:g} m is below {MIN_LENGTH:g} m (0.1 mm, finer than a mold is printed)"
                              f"{'; give 0 for no marker' if flag == '--marker-height' else ''}; lengths are in "
                              f"metres: give at least {MIN_LENGTH:g}")


def control_progress(step, total, done, worlds, prefix: str = "") -> None:
    """Progress of a control run over several targets (a line per finished target, in logs)."""
    if done == worlds and step == total:
        sys.stderr.write(f"{prefix}control: {done}/{worlds} targets done\n")


def run_progress(rounds: int, names, settings=None, control=None) -> DesignProgress:
    """The design run's progress bar (``rounds`` rounds, the targets ``names``, the phases of the
    designer ``settings`` and the ``control`` settings: the final round's model-based refinement,
    refinement rounds, then the outputs)."""
    refine = settings is not None and settings.placement == "simulated" and settings.refine_rounds > 0
    inverse = control is None or control.method == "inverse"
    return DesignProgress(rounds, n_targets=len(names), refine_last=inverse, refine_rounds=refine, outputs=True)


def load_targets(specs, units: str = "auto") -> list:
    """Target names (oval pear heart cube) or mesh files -> [(name, TriMesh)] in metres; an unknown
    name gets the list of names and the closest one, an unreadable file a parse error. A file's
    numbers are read in ``units`` (auto: detected, with a note on stderr where they are millimetres)
    and the file is checked to be star-shaped, each problem named by the file, before any work."""
    out = []
    for spec in specs:
        name, mesh = load_target(spec)
        if str(spec).strip().lower() not in TARGET_NAMES:  # a mesh file
            unit = length_unit_of(mesh.vertices, units, f"target file {spec}")
            if unit != "m":
                mesh = mesh.scaled(LENGTH_UNITS[unit])
                if units == "auto":
                    span = float(np.max(np.ptp(mesh.vertices, axis=0))) * 1e3
                    sys.stderr.write(f"target file {spec}: read in millimetres ({span:.0f} mm across)\n")
            check_star_shaped(mesh, device="cpu", name=f"target file {spec}")
        out.append((name, mesh))
    return out


def resolve_design_and_targets(scene: str | None, target_names, units: str = "auto"):
    """The built-in Fig. 6 problem (no USD needed), or a scene file / shipped scene name; then the
    chosen targets: the scene's own by name, else shipped target names or mesh files."""
    if scene in (None, "cube_fig6", "fig6"):
        design, targets, settings = cube_fig6_design(), [("cube", target("cube"))], {}
    else:
        sc = load_scene(scene)
        design, settings = sc.design, sc.settings or {}
        targets = list(zip(sc.target_names, sc.targets))
    if target_names:
        own = dict(targets)
        targets = [(name, own[name]) if name in own else load_targets([name], units)[0] for name in target_names]
    return design, targets, settings


def actuator_selection(args, scene_settings, names) -> dict:
    """The per-target actuator selection a design stored in its scene (unless --all-actuators), as
    ``control_many`` keyword arguments."""
    if getattr(args, "all_actuators", False):
        return {}
    ipams, cells = passive_from_settings(scene_settings, names)
    return dict(passive_ipams=ipams, passive_cells=cells) if any(ipams) or any(cells) else {}


def recording_entry(args) -> dict:
    """The manifest's entry for the run's ``--rerun`` recording (its absolute path and size), or none."""
    path = getattr(args, "rerun", None)
    if not path:
        return {}
    p = Path(path).expanduser().absolute()
    return {"recording": {"path": str(p), "bytes": p.stat().st_size if p.is_file() else None}}


def grouped_outputs(names, width: int = 100) -> list[str]:
    """Output file names in a few lines: names sharing a first word and an extension as one
    ``word_*.ext (n)``, the groups joined and wrapped at ``width`` characters."""
    groups: dict = {}
    for name in sorted(names):
        path = Path(name)
        key = (path.stem.split("_", 1)[0], path.suffix) if "_" in path.stem else (name, "")
        groups.setdefault(key, []).append(name)
    items = [ns[0] if len(ns) == 1 else f"{stem}_*{ext} ({len(ns)})" for (stem, ext), ns in groups.items()]
    lines, line = [], ""
    for item in items:
        if line and len(line) + 2 + len(item) > width - 2:
            lines.append(line + ",")
            line = ""
        line = f"{line}, {item}" if line else item
    return ["  " + ln for ln in lines + ([line] if line else [])]


def print_outputs(out, names, args, next_step: str = "", short: bool = False) -> None:
    """The closing lines of a run: where every output and the recording went, and what to do next."""
    out = Path(out)
    if short:  # the names grouped, in a few lines
        print(f"outputs in {out}/ ({len(names)} files, each listed in manifest.json):")
        print("\n".join(grouped_outputs(names)))
    else:
        print(f"outputs in {out}/:")
        for name in names:
            print(f"  {out / name}")
    rrd = getattr(args, "rerun", None)
    if rrd:
        print(f"recording: {Path(rrd).absolute()}   (open it: warp-shape view {rrd})")
    if next_step:
        print(f"next: {next_step}")
