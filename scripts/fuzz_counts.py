"""Fuzz the public API and the scene / mesh loaders with seeded bad input; count the outcomes.

Every case must end in a warp_shape error (clear) or a valid result (a simulator that steps to
finite positions, a scene, a mesh); anything else (another exception type, NaN, a case running
past its time limit) is counted as "other" and listed. tests/test_fuzz.py runs the same cases
(smaller N) and asserts there are none of those.

The command line's cases (``fuzz_cli``) count three more classes: ``folders`` (user files, a run's
folder with extras, links and staging folders as ``--out``: refused in one line with every file as
it was, or swapped in keeping every file the manifest does not list), ``faults`` (Ctrl-C, raised or
swallowed, and a full disk at every phase of a design run: one line, exit 130 or 1, the previous
set whole) and ``sizes`` (every bounded flag past its bounds: one line naming them, nothing written).

The fixed ``special`` cases (``fuzz_special``) must each be refused: a FIFO, a link to /dev/zero or
/dev/null and a folder given to every file reader and composed by scenes (text and binary), absurd
sizes (directions, IPAMs, sweep runs, simulated steps, a target 100x or 10^5x too big), strings and
numbers for booleans and fractions for counts; one that is accepted counts as "other" ("accepted").

    python scripts/fuzz_counts.py [--n 400] [--cli 130] [--seed 0] [--timeout 20]
"""

from __future__ import annotations

import argparse
import json
import math
import os
import signal
import sys
import tempfile
import time
import warnings
from collections import Counter
from pathlib import Path

import numpy as np

#: odd values tried for every argument
WEIRD = [None, True, False, 0, -1, 1, 2.5, -0.0, 1e-300, 1e-45, 1e-12, 1e12, 1e30, 1e41, 1e300, float("nan"),
         float("inf"), -float("inf"), "x", "1", "", [1, 2], [[1, 2], [3]], (0, float("inf")), {}, object(),
         np.float32(1e-3), np.int64(2**40), 2**70, complex(1, 1), np.array([np.nan]), np.bool_(True)]
SIM_KEYS = ["integrator", "dt", "precision", "bending", "substeps", "launch_mode", "reestimate_every", "worlds"]
MATERIAL_KEYS = ["youngs_modulus", "thickness", "areal_density", "bending_stiffness", "spring_damping",
                 "viscous_damping", "jam_stretch_factor", "jam_bend_factor", "temperature", "atmospheric_pressure"]
IPAM_KEYS = ["stiffness", "area", "free_length", "pressure_limits", "damping"]


class Hang(BaseException):
    """A case ran past its time limit."""


def _alarm(signum, frame):
    raise Hang()


def outcome(fn, timeout: float) -> tuple[str, str]:
    """("clear" | "valid" | "other", detail) of running the case ``fn``."""
    import warp_shape as ws

    old = signal.signal(signal.SIGALRM, _alarm)
    signal.setitimer(signal.ITIMER_REAL, timeout)
    start = time.monotonic()
    try:
        with warnings.catch_warnings(), np.errstate(all="ignore"):
            warnings.simplefilter("ignore")
            result = fn()
        bad = not_finite(result)
        if time.monotonic() - start > timeout:  # blocked in C past the limit, released from outside
            return "other", f"hang (over {timeout:g} s)"
        return ("other", f"non-finite result: {bad}") if bad else ("valid", "")
    except ws.WarpShapeError as exc:
        if time.monotonic() - start > timeout:
            return "other", f"hang (over {timeout:g} s)"
        return "clear", type(exc).__name__
    except Hang:
        return "other", f"hang (over {timeout:g} s)"
    except Exception as exc:  # noqa: BLE001 - counting exactly these
        return "other", f"{type(exc).__name__}: {str(exc)[:120]}"
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)


def not_finite(result) -> str:
    """What is not finite in a case's result ('' when everything is)."""
    import warp_shape as ws

    if isinstance(result, ws.Simulator):
        checks = {"positions": result.positions, "velocities": result.velocities, "volume": result.volume(),
                  "pressure": result.pressure()}
    elif isinstance(result, ws.TriMesh):
        checks = {"vertices": result.vertices, "volume": result.volume()}
    else:
        return ""
    return ", ".join(k for k, v in checks.items() if not np.all(np.isfinite(v)))


def _pick(rng, seq):
    return seq[int(rng.integers(len(seq)))]


# ---------------------------------------------------------------------------------------------- API cases
def _design(ws, ipam=True, cell=True, material=None):
    d = ws.Design(ws.icosphere(1, 0.04), material)
    c = d.rest.face_centroids()
    if ipam:
        d.add_ipam(int(np.argmax(c[:, 2])), int(np.argmin(c[:, 2])))
    if cell:
        d.add_cell([1, 2, 3])
    return d


def _stepped(sim, n=1):
    sim.step(n)
    return sim


def api_case(rng):
    """One API call with an odd argument, then a step where the call made a simulator."""
    state = rng.bit_generator.state["state"]["state"]
    fn = _api_case(rng)
    values = [c.cell_contents for c in fn.__closure__ or [] if not hasattr(c.cell_contents, "__path__")]
    fn.desc = f"api case (rng state {state}) {fn.__code__.co_names[:4]} {values!r}"[:300]  # what "other" names
    return fn


def _api_case(rng):
    import warp_shape as ws

    w = _pick(rng, WEIRD)
    kind = int(rng.integers(17))
    if kind >= 12:
        return _more_api_case(ws, rng, kind, w)
    if kind == 0:
        key = _pick(rng, SIM_KEYS)
        return lambda: _stepped(ws.Simulator(_design(ws), **{key: w}))
    if kind == 1:
        key = _pick(rng, MATERIAL_KEYS)
        return lambda: _stepped(ws.Simulator(_design(ws, ipam=False, material=ws.Material(**{key: w}))))
    if kind == 2:
        key = _pick(rng, IPAM_KEYS)
        return lambda: _stepped(ws.Simulator(_ipam_design(ws, **{key: w})))
    if kind == 3:
        return lambda: _design(ws, cell=False).add_cell(w)
    if kind == 4:
        return lambda: _set(ws, "positions", _array_like(rng, w, scale=True))
    if kind == 5:
        return lambda: _set(ws, "velocities", _array_like(rng, w))
    if kind == 6:
        return lambda: _set(ws, "air_moles", w if rng.random() < 0.5 else _scalar_times(w, 0.01))
    if kind == 7:
        return lambda: _set(ws, "ipam_pressures", w if rng.random() < 0.5 else [_scalar_times(w, 1e3)])
    if kind == 8:
        world = _pick(rng, WEIRD) if rng.random() < 0.5 else None
        return lambda: _jam(ws, w, world)
    if kind == 9:  # a huge step count is a long run asked for, not a hang: those are left out
        n = w if not (isinstance(w, (int, np.integer)) and w > 100) else 3
        return lambda: ws.Simulator(_design(ws)).step(n)
    if kind == 10:
        return lambda: _mesh_from_arrays(ws, rng, w)
    face = _pick(rng, WEIRD)
    return lambda: _design(ws, ipam=False).add_ipam(w, face)


def _more_api_case(ws, rng, kind, w):
    """Settings, scenes, read-outs and sequences of calls."""
    from warp_shape.io.scene_read import load_scene
    from warp_shape.io.scene_schema import Scene

    if kind == 12:
        group = _pick(rng, ["simulation", "designer", "bad group", 3, None])
        return lambda: Scene(design=_design(ws), settings={group: {_pick(rng, SIM_KEYS): w}}).simulation_settings
    if kind == 13:
        return lambda: ws.Material.from_dict({_pick(rng, MATERIAL_KEYS): w} if rng.random() < 0.7 else w)
    if kind == 14:
        return lambda: load_scene(w)
    if kind == 15:
        return lambda: ws.Simulator(_design(ws)).forces(w)
    ops = [("air_moles", 3.0), ("jam", 0), ("ipam_pressures", [5e4]), ("step", 2), ("positions", 1.05)]
    seq = [ops[int(rng.integers(len(ops)))] for _ in range(4)]
    return lambda: _sequence(ws, seq, w)


def _sequence(ws, seq, w):
    """Calls in a row on one simulator (each possibly refused), then a step; an odd value in the middle."""
    sim = ws.Simulator(_design(ws))
    for i, (name, value) in enumerate(seq):
        try:
            if name == "step":
                sim.step(value)
            elif name == "jam":
                sim.jam(value)
            elif name == "positions":
                sim.positions = sim.positions * value
            elif name == "air_moles":
                sim.air_moles = sim.air_moles * value if i != 2 else w
            else:
                sim.ipam_pressures = value if i != 2 else w
        except ws.WarpShapeError:
            pass
    return _stepped(sim)


def _ipam_design(ws, **kwargs):
    d = _design(ws, ipam=False)
    c = d.rest.face_centroids()
    d.add_ipam(int(np.argmax(c[:, 2])), int(np.argmin(c[:, 2])), **kwargs)
    return d


def _scalar_times(w, scale):
    try:
        return float(w) * scale
    except (TypeError, ValueError, OverflowError):
        return w


def _array_like(rng, w, scale=False):
    """Rest-shaped arrays with odd entries, odd scales, or the odd value itself."""
    import warp_shape as ws

    x = ws.icosphere(1, 0.04).vertices.copy() if scale else np.zeros((42, 3))
    r = rng.random()
    if r < 0.3:
        return w
    if r < 0.6:
        factor = _scalar_times(w, 1.0)
        return x * factor if isinstance(factor, float) else w
    i, j = int(rng.integers(42)), int(rng.integers(3))
    try:
        x[i, j] = w
    except (TypeError, ValueError, OverflowError):
        return x.tolist()[:i] + [w]
    return x


def _set(ws, name, value):
    sim = ws.Simulator(_design(ws))
    setattr(sim, name, value)
    return _stepped(sim)


def _jam(ws, cell, world):
    sim = ws.Simulator(_design(ws), worlds=2)
    sim.jam(cell, world=world)
    return _stepped(sim)


def _mesh_from_arrays(ws, rng, w):
    m = ws.icosphere(1, 0.04)
    v, f = m.vertices.copy(), m.faces.astype(np.int64)
    r = rng.random()
    if r < 0.25:
        f[int(rng.integers(len(f))), int(rng.integers(3))] += int(rng.choice([2**32, -1, 42, 2**31]))
        return ws.TriMesh(v, f)
    if r < 0.5:
        return ws.TriMesh(v, f.astype(str) if rng.random() < 0.5 else w)
    if r < 0.75:
        return ws.TriMesh(w, f)
    v[int(rng.integers(len(v)))] *= _scalar_times(w, 1.0) if isinstance(_scalar_times(w, 1.0), float) else 1.0
    return ws.TriMesh(v, f)


# ---------------------------------------------------------------------------------------------- file cases
def base_files(folder: Path) -> dict:
    """A small scene (.usda and .usdc) and mesh files (.ply, .obj, .stl) to mutate."""
    import warp_shape as ws
    from warp_shape.io.scene_schema import Scene
    from warp_shape.io.scene_write import save_scene

    d = _design(ws)
    sc = Scene(design=d, targets=[ws.icosphere(1, 0.03)], settings={"simulation": {"dt": 1e-3},
                                                                    "designer": {"actuators": 2}})
    out = {}
    for ext in ("usda", "usdc"):
        out[ext] = save_scene(sc, folder / f"base.{ext}").read_bytes()
    mesh = ws.icosphere(1, 0.04).to_trimesh()
    for ext, kwargs in (("ply", {"encoding": "ascii"}), ("obj", {}), ("stl", {"file_type": "stl_ascii"})):
        p = folder / f"base.{ext}"
        mesh.export(str(p), **{"file_type": ext, **kwargs})
        out[ext] = p.read_bytes()
    return out


TEXT_SUBS = [b"nan", b"inf", b"-1", b"0", b"1e40", b"-1e-300", b"abc", b"", b"2147483648", b"4294967296",
             b'"four"', b"(", b"]"]


def mutate(rng, data: bytes, binary: bool) -> bytes:
    """One random mutation: a number replaced, a line dropped or doubled, a type renamed, a byte flip,
    a truncation, or a sublayer / setting line added."""
    kind = int(rng.integers(7 if not binary else 3))
    if kind == 0 or binary and kind == 2:
        b = bytearray(data)
        for _ in range(int(rng.integers(1, 8))):
            k = int(rng.integers(len(b)))
            b[k] ^= int(rng.integers(1, 256))
        return bytes(b)
    if kind == 1:
        return data[: int(rng.integers(len(data)))]
    lines = data.split(b"\n")
    i = int(rng.integers(len(lines)))
    if kind == 2:
        del lines[i]
    elif kind == 3:
        lines.insert(i, lines[i])
    elif kind == 4:
        nums = [k for k, ln in enumerate(lines) if any(c in ln for c in b"0123456789")]
        if nums:
            i = _pick(rng, nums)
            toks = lines[i].replace(b",", b" , ").replace(b"(", b" ( ").replace(b")", b" ) ").split(b" ")
            idx = [k for k, t in enumerate(toks) if t[:1].isdigit() or t[:1] == b"-"]
            if idx:
                toks[_pick(rng, idx)] = _pick(rng, TEXT_SUBS)
            lines[i] = b" ".join(toks)
    elif kind == 5:
        for a, b_ in ((b"double", b"string"), (b"int[]", b"float[]"), (b"point3d", b"double2"),
                      (b"int64", b"bool"), (b"Mesh", b"Xform")):
            if a in lines[i]:
                lines[i] = lines[i].replace(a, b_, 1)
                break
    else:
        extra = [b"    custom double warpShape:simulation:dtt = 0.001",
                 b"    custom int64 warpShape:simulation:integrator = 4",
                 b'    custom string warpShape:designer:actuators = "four"',
                 b"    custom double warpShape:simulation:dt",
                 b"    subLayers = [@/etc/hostname@]",
                 b"    custom double warpShape:simulation:dt = 1e-30"]
        lines.insert(i, _pick(rng, extra))
    return b"\n".join(lines)


def file_case(rng, folder: Path, bases: dict, n: int):
    """Load one mutated scene or mesh file; a loaded scene with a design is simulated one step."""
    import warp_shape as ws
    from warp_shape.io.scene_read import load_scene

    ext = _pick(rng, list(bases))
    data = mutate(rng, bases[ext], binary=ext == "usdc")
    path = folder / f"case{n}.{ext}"
    path.write_bytes(data)

    def run():
        if ext in ("usda", "usdc"):
            sc = load_scene(path)
            if sc.design is None:
                return sc
            sim = ws.Simulator(sc.design, **sc.simulation_settings.to_dict())
            return _stepped(sim)
        return ws.TriMesh.load(path)

    return run


# ------------------------------------------------------------------ command-line cases: folders, faults, sizes
# Three classes, each case ending in a one-line refusal (clear) or a run that kept everything (valid):
# "folders": an --out of user files, a run's folder with extras, links, a staging folder that is not
# a run's, checked and swapped by StagedFolder, and refused by `warp-shape design` in one line;
# "faults": Ctrl-C (raised, or swallowed as USD does) or a full disk (ENOSPC, USD's Tf error) at every
# phase of a design run; "sizes": every bounded flag of every command given a value past its bounds.
SMALL_DESIGN = ["--subdivisions", "2", "--actuators", "1", "--placement", "paper", "--codesign", "off", "--targets", "oval"]
USER_NAMES = ["control_plan.txt", "valve_wiring.pdf", "mold_photo.jpg", "molds_notes.txt", "actuation_video.mp4",
              "report.md", "design.usda", "rounds.json", "manifest.json", "README.txt", "notes.txt", ".DS_Store"]
SET_NAMES = ["design.usda", "report.json", "report.md", "rounds.json", "control_oval.csv", "valve_oval.csv",
             "mold_core_mm.stl"]
FOLDER_KINDS = ["absent", "empty", "subfolders", "user", "ours", "ours+extras", "ours+named", "ours+edited",
                "ours+folder", "link:ours+extras", "link:user", "link:empty", "dangling", "partial:user",
                "partial:link", "partial:leftover", "root"]
#: (module, attribute) of each phase of a design run, in order; the k-th call of it is where the fault lands
#: (each named where its caller looks it up)
PHASES = [("warp_shape.cli.design", "load_scene"), ("replay", "round"),
          ("warp_shape.cli.design", "write_round_outputs"), ("warp_shape.io.atomic.StagedFolder", "seal"),
          ("warp_shape.io.scene_write", "export_layer"), ("warp_shape.io.outputs", "write_control_outputs"),
          ("warp_shape.io.outputs", "write_valve_outputs"), ("warp_shape.io.outputs", "write_molds"),
          ("warp_shape.io.outputs", "write_figures_or_skip"), ("warp_shape.io.outputs", "design_markdown"),
          ("warp_shape.io.atomic.StagedFolder", "commit"), ("warp_shape.io.atomic", "_exchange"), ("os", "replace")]
FAULTS = ["interrupt", "swallowed", "disk", "usd"]
ABSURD_INTS = [10**12, -10**12, 2**63, -1]
ABSURD_FLOATS = [1e300, -1e300, float("nan"), float("inf"), 1e-300, -1.0]


def tree(folder: Path) -> dict:
    """{relative path: SHA-256, 'dir' or '-> link target'} of everything under ``folder`` (links not followed)."""
    from warp_shape.io.atomic import file_digest

    out = {}
    if not folder.is_dir():
        return out
    for p in sorted(folder.rglob("*")):
        rel = str(p.relative_to(folder))
        out[rel] = f"-> {os.readlink(p)}" if p.is_symlink() else "dir" if p.is_dir() else file_digest(p)
    return out


def _fake_set(out: Path, names) -> None:
    from warp_shape.io.atomic import StagedFolder
    from warp_shape.io.outputs import is_run_output

    staged = StagedFolder(out, owned=is_run_output)
    for name in names:
        (staged.path / name).write_text(json.dumps({"complete": True, "targets": ["oval"], "name": name}))
    staged.commit(True)


def _user_files(folder: Path, rng, names=USER_NAMES) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    for name in rng.choice(names, size=int(rng.integers(1, min(5, len(names) + 1))), replace=False):
        (folder / name).write_text(f"mine: {name} {rng.random()}")


def folder_case(rng, root: Path) -> tuple[Path, bool]:
    """An --out of one of ``FOLDER_KINDS`` under ``root``: (the path to give, whether a run may use it)."""
    kind = _pick(rng, FOLDER_KINDS)
    out = root / "out"
    base = kind.split(":")[-1]
    target = root / "target" if kind.startswith("link:") else out
    if base in ("empty", "subfolders") or base.startswith("ours"):
        target.mkdir(parents=True)
    if base == "subfolders":
        _user_files(target / "control", rng)
    elif base == "user":
        _user_files(target, rng)
    elif base.startswith("ours"):
        _fake_set(target, rng.choice(SET_NAMES, size=int(rng.integers(1, 4)), replace=False))
        if base in ("ours+extras", "ours+folder"):
            _user_files(target, rng, ["README.txt", "notes.txt", ".DS_Store"])
            _user_files(target / "sub", rng)
        if base == "ours+named":
            (target / "mold_photo.jpg").write_text("mine")
        if base == "ours+edited":
            listed = json.loads((target / "manifest.json").read_text())["files"]
            (target / _pick(rng, sorted(listed))).write_text("edited by hand")
        if base == "ours+folder":
            (target / "sub" / "report.md").write_text("mine")  # output names below the top level are the user's
    if kind.startswith("link:"):
        out.symlink_to(target)
    elif kind == "dangling":
        out.symlink_to(root / "nowhere")
    elif kind.startswith("partial:"):
        partial = root / "out.partial"
        if base == "user":
            _user_files(partial, rng, ["thesis.tex", "notes.txt"])
        elif base == "link":
            (root / "elsewhere").mkdir()
            partial.symlink_to(root / "elsewhere")
        else:
            _user_files(partial, rng, SET_NAMES)  # an earlier run's unfinished outputs: removed
    if kind == "root":
        return Path("/"), False
    usable = kind in ("absent", "empty", "subfolders", "ours", "ours+extras", "ours+folder", "link:ours+extras",
                      "link:empty", "partial:leftover")
    return out, usable


def _kept(before: dict, after: dict, listed) -> str:
    """What of ``before`` (a tree) is missing or changed in ``after``, ignoring the run's own ``listed`` files."""
    lost = [k for k, v in before.items() if k.split("/")[0] not in listed and k.split("/")[0] != "manifest.json"
            and after.get(k) != v]
    return ", ".join(lost[:5])


def run_folder_case(rng, root: Path) -> tuple[str, str]:
    """Check and (where accepted) swap a new set into one ``folder_case``: a refusal must leave every
    file as it was and read as one line through the command line; a swap must keep every file its
    manifest does not list."""
    from warp_shape.io.atomic import OutputError, StagedFolder, manifest_problems, read_manifest
    from warp_shape.io.outputs import is_run_output

    given, usable = folder_case(rng, root)
    before = tree(root)
    try:
        staged = StagedFolder(given, owned=is_run_output)
        staged.check()
    except OutputError as exc:
        if tree(root) != before:
            return "other", f"a refusal changed files: {exc}"
        if usable:
            return "other", f"refused a folder a run may use: {exc}"
        return _refused_in_one_line(given, root, before)
    if not usable:
        return "other", f"accepted {given}, which holds what a run may not replace"
    old = set((read_manifest(staged.out) or {}).get("files", {}))
    names = rng.choice(SET_NAMES, size=int(rng.integers(1, 4)), replace=False)
    for name in names:
        (staged.path / name).write_text(f"new {name}")
    staged.commit(True)
    inside = staged.out.relative_to(root) if staged.out.is_relative_to(root) else None
    lost = _kept({k[len(str(inside)) + 1:]: v for k, v in before.items() if inside and k.startswith(f"{inside}/")},
                 tree(staged.out), old | set(names))
    if lost or manifest_problems(staged.out) or (given.is_symlink() != (before.get("out", "").startswith("->"))):
        return "other", f"lost or changed {lost or 'the set or the link'} swapping into {given}"
    return "valid", ""


def _refused_in_one_line(given: Path, root: Path, before: dict) -> tuple[str, str]:
    import contextlib
    import io

    import warp_shape.designer.loop as designer_loop
    from warp_shape.cli import main

    def no_work(*a, **k):
        raise AssertionError("work started")

    real, designer_loop.control_many = designer_loop.control_many, no_work
    err = io.StringIO()
    try:
        with contextlib.redirect_stderr(err):
            rc = main(["design", "--out", str(given), *SMALL_DESIGN])
    except AssertionError:
        return "other", f"design --out {given}: work started"
    finally:
        designer_loop.control_many = real
    text = err.getvalue().strip()
    if rc != 2 or "\n" in text or not text.startswith("warp-shape: error: ") or tree(root) != before:
        return "other", f"design --out {given}: rc {rc}, {text[:200]!r}"
    return "clear", "OutputError"


class Replay:
    """One small design run for real (``warp_shape.designer.design``), then replayed: its rounds handed
    to ``on_round`` and its result returned at once, so each fault case costs only the writing."""

    def __init__(self):
        import warp_shape as ws
        from warp_shape.designer import DesignSettings, design

        self.rounds = []
        self.result = design(ws.icosphere(2, 0.04), [ws.target("oval", resolution=2)], actuators=1,
                             target_names=["oval"], settings=DesignSettings(placement="paper"),
                             on_round=lambda *a: self.rounds.append(a))
        self.fault = None  # set per case: called with ("replay", "round") before each round

    def __call__(self, *args, on_round=None, **kwargs):
        for r in self.rounds:
            if self.fault is not None:
                self.fault()
            if on_round is not None:
                on_round(*r)
        return self.result


def _raiser(fault: str, path: str):
    from pxr import Tf

    if fault == "interrupt":
        raise KeyboardInterrupt
    if fault == "swallowed":  # Ctrl-C inside USD's module loading: caught there, the run goes on
        try:
            os.kill(os.getpid(), signal.SIGINT)
        except KeyboardInterrupt:
            return
    if fault == "usd":
        raise Tf.ErrorException(f"\n\tError in 'Write' at line 78 in file x.cpp : 'Error occurred writing file: "
                                f"No space left on device'\n\tError in 'WriteToFile' : 'Could not close {path}'")
    raise OSError(28, "No space left on device", path)


def _patched(phase, k: int, fault: str, replay: Replay, hit: list):
    """(object, attribute, replacement) list: the k-th call of ``phase`` meets ``fault``."""
    import importlib

    module, attr = phase
    calls = [0]

    def at_kth(first_arg=None):
        calls[0] += 1
        if calls[0] == k:
            hit.append(phase)
            _raiser(fault, str(first_arg))

    if module == "replay":
        replay.fault = at_kth
        return []
    if module.endswith(".StagedFolder"):
        owner = getattr(importlib.import_module(module.rsplit(".", 1)[0]), "StagedFolder")
    else:
        owner = importlib.import_module(module)
    real = getattr(owner, attr)

    def wrapper(*a, **kw):
        paths = [x for x in a if isinstance(x, (str, Path))]
        at_kth(paths[-1] if paths else "output")
        return real(*a, **kw)

    return [(owner, attr, wrapper)]


def run_fault_case(rng, root: Path, replay: Replay, phase=None, fault=None) -> tuple[str, str]:
    """`warp-shape design` into a folder holding a finished run (with a user's file) or into a new one,
    a fault at one phase: one line and exit 130 (Ctrl-C) or 1 (full disk), the previous set and the
    user's file as they were, <out> and <out>.partial each one whole set or absent."""
    import contextlib
    import io

    import warp_shape.cli.design as design_cli
    from warp_shape.cli import main
    from warp_shape.io.atomic import manifest_problems, read_manifest

    phase = phase or PHASES[int(rng.integers(len(PHASES)))]
    fault = fault or _pick(rng, {"load_scene": ["interrupt", "swallowed"], "export_layer": ["interrupt", "disk", "usd"]}
                           .get(phase[1], ["interrupt", "disk"]))
    k = int(rng.integers(1, 4)) if phase[1] in ("seal", "replace", "round") else 1
    out = root / "out"
    if rng.random() < 0.6:
        _fake_set(out, ["report.json", "control_heart.csv"])
        (out / "notes.txt").write_text("mine")
    before = tree(out)
    hit: list = []
    patches = [(design_cli, "design", replay)] + _patched(phase, k, fault, replay, hit)
    saved = [(o, a, getattr(o, a)) for o, a, _ in patches]
    err = io.StringIO()
    try:
        for o, a, v in patches:
            setattr(o, a, v)
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
            rc = main(["design", "--out", str(out), *SMALL_DESIGN])
    except BaseException as exc:  # noqa: BLE001 - a fault that escaped main is what this counts
        return "other", f"{phase[1]} #{k} {fault}: {type(exc).__name__} escaped main"
    finally:
        for o, a, v in saved:
            setattr(o, a, v)
        replay.fault = None
    text = err.getvalue().strip()
    last = text.splitlines()[-1] if text else ""
    what = f"{phase[1]} #{k} {fault}"
    want = {"interrupt": 130, "swallowed": 130, "disk": 1, "usd": 1}[fault] if hit else 0
    if rc != want or "Traceback" in text or (hit and not (last == "warp-shape: interrupted" if want == 130 else
                                                          last.startswith("warp-shape: error: no space left"))):
        return "other", f"{what}: rc {rc} (wanted {want}), {last[:160]!r}"
    for folder in (out, root / "out.partial"):
        if folder.exists() and manifest_problems(folder):
            return "other", f"{what}: {folder.name} is not one whole set: {manifest_problems(folder)[:2]}"
    now = tree(out)
    if before and (now != before if rc != 0 else now.get("notes.txt") != before["notes.txt"]):
        return "other", f"{what}: the previous set or the user's file changed"
    if rc == 0 and not (read_manifest(out) or {}).get("complete"):
        return "other", f"{what}: exit 0 without a complete set"
    return ("clear", fault) if hit else ("valid", "")


def run_size_case(rng, root: Path, flag_table=None) -> tuple[str, str]:
    """One bounded flag of one command given a value past its bounds: exit 2 and one line naming the
    flag and its bounds, before anything is read or written (the command's other inputs need not exist)."""
    import contextlib
    import io

    from warp_shape.cli import main

    flag_table = flag_table or bounded_flags()
    command, flag, lo, hi, is_int = flag_table[int(rng.integers(len(flag_table)))]
    pool = ABSURD_INTS if is_int else ABSURD_FLOATS
    value = _pick(rng, [v for v in pool if not lo <= v <= hi or v != v] or [hi * 10 + 1])
    argv = [*command, f"{flag}={value}"]
    cwd = os.getcwd()
    err = io.StringIO()
    try:
        os.chdir(root)
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
            rc = main(argv)
    except BaseException as exc:  # noqa: BLE001
        return "other", f"{' '.join(argv)}: {type(exc).__name__} escaped main"
    finally:
        os.chdir(cwd)
    text = err.getvalue().strip()
    if rc != 2 or "\n" in text or f"{flag} takes" not in text or any(root.iterdir()):
        return "other", f"{' '.join(argv)}: rc {rc}, {text[:160]!r}"
    return "clear", flag


def bounded_flags() -> list:
    """(command argv, flag, lo, hi, integer?) of every flag the parser bounds (``add_bounded``)."""
    import argparse

    from warp_shape.cli import build_parser

    rows = []

    def walk(parser, prefix):
        for action in parser._actions:
            if isinstance(action, argparse._SubParsersAction):
                for name, child in action.choices.items():
                    walk(child, [*prefix, name])
        for dest, (flag, lo, hi, _zero) in (parser.get_default("flag_bounds") or {}).items():
            kind = next(a.type for a in parser._actions if a.dest == dest)
            needs = {"export": ["out/design.usda"], "compare": ["scan.ply", "--to", "oval"],
                     "calibrate": ["manifest.json", "--design", "out/design.usda"],
                     "grid": ["--param", "actuators=5"]}
            rows.append(([*prefix, *needs.get(prefix[-1], [])], flag, lo, hi, kind is int))

    walk(build_parser(), [])
    return rows


# ------------------------------------------------------------------- inputs: locks, recordings, schemas, units
#: the kinds of ``run_input_case``: each must be refused in one warp_shape error with every file as it was
#: (a stale lock: taken and released), or give a valid result only where the input is valid
INPUT_KINDS = ("lock", "rerun", "manifest_key", "manifest_value", "units")


def _input_lab(root: Path):
    """A 42-vertex design, a scan file and a 3-row control CSV of it in ``root``."""
    from warp_shape.scenarios import cube_fig6_design

    import trimesh

    design = cube_fig6_design(subdivisions=1)
    trimesh.PointCloud(np.repeat(design.rest.vertices, 3, axis=0) * 1e3).export(root / "scan.ply")
    cols = ["step", "time", "air_mol", *[f"ipam{i}_pressure_pa" for i in range(design.n_ipams)]]
    rows = [[k, 0.5 * k, 0.01 + 0.001 * k, *[1e3 * k] * design.n_ipams] for k in range(3)]
    (root / "control_oval.csv").write_text("\n".join(",".join(map(str, r)) for r in [cols, *rows]) + "\n")
    return design


def _misspelt(rng, key: str, known) -> str:
    """``key`` with one letter dropped, doubled or swapped with the next (never a known key)."""
    for _ in range(20):
        i = int(rng.integers(len(key)))
        op = int(rng.integers(3))
        bad = key[:i] + key[i + 1:] if op == 0 else key[:i] + key[i] + key[i:] if op == 1 else \
            key[:i] + key[i + 1:i + 2] + key[i] + key[i + 2:]
        if bad not in known and bad:
            return bad
    return key + "x"


def _valid_manifest_value(key: str, value) -> bool:
    """Whether ``value`` is a value the manifest's ``key`` takes (so accepting it is no silent error)."""
    number = not isinstance(value, (bool, np.bool_)) and isinstance(value, (int, float)) and math.isfinite(value)
    if key == "row":
        return number and isinstance(value, int) and 0 <= value <= 2
    if key == "time_s":
        return number and value >= 0
    if key == "air_mol":
        return number and value > 0
    return number  # chamber_pressure_kpa


def _manifest_case(rng, root: Path, kind: str) -> tuple[str, str]:
    from warp_shape.calibration.files import MANIFEST_KEYS, OBSERVATION_KEYS, STATE_KEYS, read_manifest
    from warp_shape.errors import WarpShapeError

    design = _input_lab(root)
    entry, top = {"scan": "scan.ply", "control": "control_oval.csv", "row": 1}, {}
    if kind == "manifest_key":
        where, known = [(entry, OBSERVATION_KEYS), (top, MANIFEST_KEYS)][int(rng.integers(2))]
        key = _misspelt(rng, str(_pick(rng, [k for k in known if k not in ("scan", "observations")])), known)
        where[key] = 1
        bad = True
    else:
        key = str(_pick(rng, ["row", "time_s", "chamber_pressure_kpa", "air_mol"]))
        value = _pick(rng, [v for v in WEIRD if isinstance(v, (int, float, str, list, type(None)))])
        if key == "air_mol":
            entry = {"scan": "scan.ply", "state": {"air_mol": value, "ipam_pressures_kpa": [0] * design.n_ipams}}
        else:
            entry.pop("row") if key == "time_s" else None
            entry[key] = value
        bad = not _valid_manifest_value(key, value)
    (root / "m.json").write_text(json.dumps({"observations": [entry], **top}))
    try:
        read_manifest(root / "m.json", design)
    except WarpShapeError as exc:
        return ("clear", "") if bad and "\n" not in str(exc) else ("other", f"silent: {key} refused: {exc}")
    return ("other", f"silent: {key}={entry.get(key, top.get(key))!r} accepted") if bad else ("valid", "")


def _lock_case(rng, root: Path) -> tuple[str, str]:
    from warp_shape.io.atomic import OutputError, StagedFolder

    mine, lock = root / "t.tex", root / ".out.lock"
    mine.write_text("work")
    how = str(_pick(rng, ["link", "folder", "foreign", "stale"]))
    {"link": lambda: lock.symlink_to(mine), "folder": lock.mkdir, "foreign": lambda: lock.write_text("notes"),
     "stale": lambda: lock.write_text("999999")}[how]()
    before = tree(root)
    staged = StagedFolder(root / "out", command="simulate")
    try:
        staged.lock()
    except OutputError as exc:
        if how == "stale":
            return "other", f"a stale lock refused: {exc}"
        return ("clear", "") if tree(root) == before else ("other", f"data loss: {how} lock changed")
    staged.unlock()
    if how != "stale":
        return "other", f"data loss: a {how} lock was taken (t.tex: {mine.read_text()!r})"
    return ("valid", "") if not os.path.lexists(lock) and mine.read_text() == "work" else ("other", "lock left")


def _rerun_case(rng, root: Path) -> tuple[str, str]:
    from types import SimpleNamespace

    from warp_shape.cli.options import check_rerun
    from warp_shape.errors import WarpShapeError
    from warp_shape.io.atomic import StagedFolder
    from warp_shape.io.outputs import is_run_output

    scene, thesis, out = root / "design.usda", root / "thesis.tex", root / "out"
    scene.write_text("#usda 1.0\n")
    thesis.write_text("chapter")
    out.mkdir()
    (out / "manifest.json").write_text('{"files": {}}')
    target = _pick(rng, [scene, thesis, out / "manifest.json", out / "report.json", out / "control_x.csv"])
    before = tree(root)
    args = SimpleNamespace(rerun=str(target), rerun_spawn=False)
    try:
        check_rerun(args, StagedFolder(out, owned=is_run_output), inputs=[str(scene)])
    except WarpShapeError:
        return ("clear", "") if tree(root) == before else ("other", "data loss: a refused --rerun changed files")
    return "other", f"data loss: --rerun {target.name} accepted (it would be replaced)"


def _units_case(rng) -> tuple[str, str]:
    import dataclasses

    import warp_shape as ws
    from warp_shape.scenarios import cube_fig6_design

    design = cube_fig6_design(subdivisions=1)
    scale = float(_pick(rng, [1e3, 1e4, 1e6]))
    try:
        if rng.integers(2):
            design.add_ipam(design.ipams[0].face_a, design.ipams[0].face_b, area=1.5e-5 * scale)
        else:
            ws.Design(design.rest, dataclasses.replace(design.material, thickness=2e-3 * scale))
    except ws.DesignError as exc:
        return ("clear", "") if "was meant, give" in str(exc) else ("other", f"silent: no unit named: {exc}")
    return "other", f"silent: a size x{scale:g} in another unit accepted"


def run_input_case(rng, root: Path, kind: str) -> tuple[str, str]:
    """One case of ``kind`` (``INPUT_KINDS``): (outcome, detail)."""
    if kind == "lock":
        return _lock_case(rng, root)
    if kind == "rerun":
        return _rerun_case(rng, root)
    if kind == "units":
        return _units_case(rng)
    return _manifest_case(rng, root, kind)


def fuzz_inputs(n: int, seed: int = 0, folder: Path | None = None) -> dict:
    """``n`` input cases alone (``INPUT_KINDS`` in turn): {"counts": Counter, "others": [details]}."""
    import contextlib

    rng = np.random.default_rng(seed)
    counts, others = Counter(), []
    with contextlib.ExitStack() as stack:
        base = Path(folder) if folder is not None else Path(stack.enter_context(tempfile.TemporaryDirectory()))
        for i in range(n):
            root = base / f"inputs{i}"
            root.mkdir(parents=True)
            kind, detail = _guarded(lambda r, i=i: run_input_case(rng, r, INPUT_KINDS[i % len(INPUT_KINDS)]), root)
            counts[kind] += 1
            if kind == "other":
                others.append(f"inputs case {i} ({INPUT_KINDS[i % len(INPUT_KINDS)]}): {detail}")
    return {"counts": counts, "others": others}


def fuzz_cli(n: int, seed: int = 0, folder: Path | None = None, faults: int | None = None,
             verbose: bool = False) -> dict:
    """``n`` folder cases, ``n`` size cases, ``n`` input cases (``INPUT_KINDS`` in turn) and ``faults``
    (default ``n``) fault cases (every phase in turn, a random fault and call); {"counts": {class:
    Counter}, "others": [details]}."""
    import contextlib
    import logging

    import warp as wp

    wp.config.quiet = True
    logging.getLogger("trimesh").setLevel(logging.CRITICAL)
    rng = np.random.default_rng(seed)
    flags = bounded_flags()
    faults = n if faults is None else faults
    replay = Replay() if faults else None
    jobs = [("folders", i, lambda root: run_folder_case(rng, root)) for i in range(n)]
    jobs += [("sizes", i, lambda root: run_size_case(rng, root, flags)) for i in range(n)]
    jobs += [("faults", i, lambda root, i=i: run_fault_case(rng, root, replay, phase=PHASES[i % len(PHASES)]))
             for i in range(faults)]
    jobs += [("inputs", i, lambda root, i=i: run_input_case(rng, root, INPUT_KINDS[i % len(INPUT_KINDS)]))
             for i in range(n)]
    outcomes = []
    with contextlib.ExitStack() as stack:
        base = Path(folder) if folder is not None else Path(stack.enter_context(tempfile.TemporaryDirectory()))
        for family, i, case in jobs:
            (base / f"{family}{i}").mkdir(parents=True)
            outcomes.append((family, i, *_guarded(case, base / f"{family}{i}")))
    counts = {family: Counter(kind for f, _, kind, _ in outcomes if f == family)
              for family in ("folders", "faults", "sizes", "inputs")}
    others = [f"{family} case {i}: {detail}" for family, i, kind, detail in outcomes if kind == "other"]
    if verbose and others:
        print("\n".join(others), file=sys.stderr)
    return {"counts": counts, "others": others}


def _guarded(case, root: Path) -> tuple[str, str]:
    """A case's (kind, detail); an exception escaping it is an "other" naming it."""
    try:
        return case(root)
    except Exception as exc:  # noqa: BLE001 - what escapes a case is what this counts
        return "other", f"{type(exc).__name__}: {str(exc)[:120]}"
# ---------------------------------------------------------------------------------------------- special cases
# Fixed cases of four classes, each of which must be refused with a clear error (or, where marked, give a
# valid result): special files (FIFO, a symlink to /dev/zero or /dev/null, a folder) given to every file
# reader and composed by scenes; absurd sizes; strings for booleans; non-integers for counts. A case that
# is accepted where it must be refused counts as "other" ("accepted").
BOOL_STRINGS = ["no", "false", "False", "0", "", "yes", 0, 1, None]
FRACTIONS = [1.5, 2.5, 3.7, float("nan"), "2"]


def _special_paths(folder: Path) -> dict:
    """{kind: {ext: path}}: a FIFO, symlinks to /dev/zero and /dev/null, and a folder, for each file kind."""
    import os

    out = {}
    for kind in ("fifo", "zero", "null", "folder"):
        out[kind] = {}
        for ext in ("stl", "ply", "usda", "rrd", "json"):
            p = folder / "special" / f"{kind}_{ext}.{ext}"
            p.parent.mkdir(parents=True, exist_ok=True)
            if not os.path.lexists(p):
                if kind == "fifo":
                    os.mkfifo(p)
                elif kind == "folder":
                    p.mkdir()
                else:
                    p.symlink_to(f"/dev/{kind}")
            out[kind][ext] = p
    return out


#: the FIFO feeder: from argv[2] s on, open the FIFO argv[1] for writing and close it, every 0.2 s
FEEDER = ("import os, sys, time\ntime.sleep(float(sys.argv[2]))\nwhile True:\n    try:\n"
          "        os.close(os.open(sys.argv[1], os.O_WRONLY | os.O_NONBLOCK))\n    except OSError:\n        pass\n"
          "    time.sleep(0.2)\n")


class _FifoFeeder:
    """A child process that, from ``after`` s on, opens ``path`` (a FIFO) for writing and closes it every
    0.2 s until stopped: a reader blocked in C (holding the GIL, where neither the time-limit signal nor
    a thread reaches it), however often it opens the FIFO again, then reads end-of-file and the case ends
    as a hang instead of blocking the fuzz."""

    def __init__(self, path: Path, after: float):
        self.path, self.after, self.proc = path, after, None

    def start(self):
        import subprocess

        self.proc = subprocess.Popen([sys.executable, "-c", FEEDER, str(self.path), str(self.after)])

    def cancel(self):
        self.proc.kill()
        self.proc.wait()


def _composing_scenes(folder: Path, bases: dict, paths: dict) -> list:
    """(name, scene path, FIFO it composes or None) of text scenes whose subLayers / references name a
    special file inside their folder, and a binary scene with such a sublayer."""
    text = bases["usda"].decode()
    head, rest = text.split("(\n", 1)
    out = []
    for kind in ("fifo", "zero", "folder"):
        target = paths[kind]["usda"]
        rel = f"./{target.name}"
        for how, body in (("subLayers", f"{head}(\n    subLayers = [@{rel}@]\n{rest}"),
                          ("references", f'{text}\ndef "Extra" (\n    references = @{rel}@\n)\n{{\n}}\n')):
            p = target.parent / f"composes_{kind}_{how}.usda"
            p.write_text(body)
            out.append((f"scene {how} a {kind}", p, target if kind == "fifo" else None))
    from pxr import Sdf

    layer = Sdf.Layer.CreateAnonymous(".usda")
    layer.ImportFromString(text)
    layer.subLayerPaths.append(f"./{paths['fifo']['usda'].name}")
    crate = paths["fifo"]["usda"].parent / "composes_fifo.usdc"
    layer.Export(str(crate))
    out.append(("binary scene subLayers a fifo", crate, paths["fifo"]["usda"]))
    return out


def _many_ipams_scene(folder: Path, bases: dict, n: int) -> Path:
    """The base scene with its one IPAM repeated ``n`` times (every IPAM attribute list repeated)."""
    import re

    text = bases["usda"].decode()
    start = text.index('def BasisCurves "Ipams"')
    end = text.index("\n    }", start)

    def repeat(m):
        return f"{m.group(1)}[{', '.join([m.group(2)] * n)}]"

    block = re.sub(r"(warpShape:\w+ = )\[(.*)\]", repeat, text[start:end])
    p = folder / "special" / f"ipams_{n}.usda"
    p.write_text(text[:start] + block + text[end:])
    return p


def _cli(argv):
    """Run ``warp-shape ARGV`` in this process: a clear refusal (exit 2, one error line) becomes that error."""
    import contextlib
    import io

    import warp_shape as ws
    from warp_shape.cli import main

    err = io.StringIO()
    with contextlib.redirect_stderr(err):
        rc = main([str(a) for a in argv])
    lines = err.getvalue().strip().splitlines()
    if rc == 2 and lines and lines[-1].startswith("warp-shape") and ": error: " in lines[-1]:
        raise ws.WarpShapeError(lines[-1])
    if rc != 0:
        raise RuntimeError(f"exit {rc}: {lines[-1] if lines else ''}")


def _file_readers():
    """(name, file kind, reader) of every reader of a user's file."""
    import warp_shape as ws
    from warp_shape.cli.view import viewer_command
    from warp_shape.sweeps.results import ResultsTable
    from warp_shape.targets import check_mesh_file, load_target

    return [("TriMesh.load", "stl", ws.TriMesh.load), ("TriMesh.load ply", "ply", ws.TriMesh.load),
            ("load_target", "stl", load_target), ("check_mesh_file", "stl", check_mesh_file),
            ("load_scan", "ply", ws.load_scan), ("compare_scan", "stl", lambda p: ws.compare_scan(p, "oval")),
            ("load_scene", "usda", ws.load_scene), ("read_recording", "rrd", ws.read_recording),
            ("view", "rrd", viewer_command),
            ("sweep results.json", "json", lambda p: ResultsTable(p.parent, [], {}).load() if p.name == "results.json"
             else _results_at(p))]


def _results_at(p: Path):
    """A sweep folder whose results.json is ``p`` (a link to it), loaded."""
    from warp_shape.sweeps.results import ResultsTable

    folder = p.parent / f"sweep_{p.stem}"
    folder.mkdir(exist_ok=True)
    link = folder / "results.json"
    if not link.is_symlink():
        link.symlink_to(p.resolve() if not p.is_symlink() else p.readlink())
    return ResultsTable(folder, [], {}).load()


def special_cases(folder: Path, bases: dict) -> list:
    """(name, case, must_refuse, FIFO to feed or None) of the four classes."""
    import warp_shape as ws
    from warp_shape.io.atomic import read_manifest

    paths = _special_paths(folder)
    cases = []
    for kind, by_ext in paths.items():
        for name, ext, reader in _file_readers():
            p = by_ext[ext]
            cases.append((f"{name} of a {kind}", lambda r=reader, p=p: r(p), True, p if kind == "fifo" else None))
        manifest_dir = folder / "special" / f"out_{kind}"
        manifest_dir.mkdir(exist_ok=True)
        if not (manifest_dir / "manifest.json").is_symlink():
            (manifest_dir / "manifest.json").symlink_to(by_ext["json"].resolve() if kind != "zero" else "/dev/zero")
        # a manifest that is no regular file is no manifest: None, quickly
        cases.append((f"read_manifest of a {kind}", lambda d=manifest_dir: _none(read_manifest(d)), False,
                      by_ext["json"] if kind == "fifo" else None))
    for name, p, fifo in _composing_scenes(folder, bases, paths):
        cases.append((name, lambda p=p: ws.load_scene(p), True, fifo))
    obj = folder / "special" / "names_a_fifo.obj"  # its material library is a FIFO: read without it
    obj.write_text(f"mtllib {paths['fifo']['stl'].name}\n" + bases["obj"].decode())
    cases.append(("OBJ whose mtllib is a fifo", lambda: ws.TriMesh.load(obj), False, paths["fifo"]["stl"]))
    cases += _size_cases(folder, bases)
    cases += _type_cases()
    return cases


def _none(value):
    if value is not None:
        raise RuntimeError(f"expected None, got {value!r}")


def _size_cases(folder: Path, bases: dict) -> list:
    """Work asked for beyond any bound: each must be refused before it starts."""
    import warp_shape as ws

    out = folder / "special" / "out"
    grid = [a for k, name in enumerate(("max_steps", "control_period", "max_settle_steps")) for a in
            ("--param", f"{name}={','.join(str(10 + k * 1000 + v) for v in range(100))}")]

    def many_ipams():  # 1200 IPAMs, each between a face and the face opposite it
        d = ws.Design(ws.icosphere(3, 0.04))
        c = d.rest.face_centroids()
        opposite = np.argmin(c @ c.T, axis=1)
        for k in range(1200):
            d.add_ipam(k, int(opposite[k]))
        return d

    many = _many_ipams_scene(folder, bases, 2000)
    return [(name, fn, True, None) for name, fn in [
        ("fibonacci_directions(1e9)", lambda: ws.fibonacci_directions(10**9)),
        ("target resolution 1e6", lambda: ws.target("oval", resolution=10**6)),
        ("icosphere(1e6)", lambda: ws.icosphere(10**6)),
        ("1200 IPAMs", many_ipams),
        ("scene of 2000 IPAMs", lambda: ws.load_scene(many)),
        ("sweep grid of 1e6 runs", lambda: _cli(["sweep", "grid", *grid, "--backend", "serial", "--out",
                                                  folder / "special" / "sweep"])),
        ("target 100x (cm as m)", lambda: ws.control(_design(ws), ws.target("oval").scaled(100.0))),
        ("target 1e5x", lambda: ws.control(_design(ws), ws.target("oval").scaled(1e5))),
        ("atmospheric_pressure 1e300", lambda: ws.Material(atmospheric_pressure=1e300)),
        ("simulate --dt 1e-9", lambda: _cli(["simulate", "--dt", 1e-9, "--out", out])),
        ("simulate --inflate-time 1e9", lambda: _cli(["simulate", "--inflate-time", 1e9, "--out", out])),
        ("simulate --air-scale -1", lambda: _cli(["simulate", "--air-scale", -1, "--out", out])),
    ]]


def _type_cases() -> list:
    """Strings (and other non-bools) for booleans, non-integers for counts: refused, never truncated."""
    import warp_shape as ws

    cases = []
    for v in BOOL_STRINGS:
        cases.append((f"ControlSettings(jamming={v!r})", lambda v=v: ws.ControlSettings(jamming=v), True, None))
        cases.append((f"DesignSettings(initialize={v!r})", lambda v=v: ws.DesignSettings(initialize=v), True, None))
    counts = [("icosphere", lambda v: ws.icosphere(v, 0.04)), ("target resolution", lambda v: ws.target("oval",
              resolution=v)), ("fibonacci_directions", ws.fibonacci_directions),
              ("Simulator.step", lambda v: ws.Simulator(_design(ws)).step(v)),
              ("design actuators", lambda v: ws.design(ws.icosphere(2, 0.04), [ws.target("oval")], actuators=v))]
    counts += [(f"ControlSettings.{k}", lambda v, k=k: ws.ControlSettings(**{k: v}))
               for k in ("control_period", "max_steps", "max_settle_steps", "inverse_iterations",
                         "inverse_settle_steps")]
    counts += [(f"DesignSettings.{k}", lambda v, k=k: ws.DesignSettings(**{k: v})) for k in ("candidates",
                                                                                              "refine_rounds")]
    counts += [(f"SimulationSettings.{k}", lambda v, k=k: ws.SimulationSettings(**{k: v}))
               for k in ("substeps", "reestimate_every", "max_substeps")]
    for name, fn in counts:
        for v in FRACTIONS:
            cases.append((f"{name}({v!r})", lambda fn=fn, v=v: fn(v), True, None))
    return cases


def fuzz_special(folder: Path, bases: dict, timeout: float, verbose: bool = False) -> tuple[Counter, list[str]]:
    """Run every special case; (Counter of outcomes, "other" details)."""
    counts, others = Counter(), []
    for name, case, refuse, fifo in special_cases(folder, bases):
        feeder = _FifoFeeder(fifo, timeout) if fifo is not None else None
        if feeder:
            feeder.start()
        kind, detail = outcome(case, timeout)
        if feeder:
            feeder.cancel()
        if refuse and kind == "valid":
            kind, detail = "other", "accepted (must be refused)"
        counts[kind] += 1
        if kind == "other":
            others.append(f"special {name}: {detail}")
            if verbose:
                print(f"special {name}: {detail}", file=sys.stderr)
    return counts, others


# ---------------------------------------------------------------------------------------------- driver
def fuzz(n: int, seed: int = 0, timeout: float = 20.0, folder: Path | None = None, verbose: bool = False,
         special: bool = True) -> dict:
    """Run ``n`` API cases and ``n`` file cases (and, with ``special``, the fixed special cases); return
    {family: Counter} and the "other" details."""
    import logging

    import warp as wp

    wp.config.quiet = True
    logging.getLogger("trimesh").setLevel(logging.CRITICAL)
    rng = np.random.default_rng(seed)
    tmp = tempfile.TemporaryDirectory() if folder is None else None
    folder = Path(tmp.name) if tmp else Path(folder)
    counts = {"api": Counter(), "files": Counter()}
    others: list[str] = []
    try:
        bases = base_files(folder)
        if special:
            counts["special"], others = fuzz_special(folder, bases, timeout, verbose)
        for i in range(n):
            for family, make in (("api", lambda: api_case(rng)), ("files", lambda: file_case(rng, folder, bases, i))):
                try:
                    case = make()
                except Exception as exc:  # noqa: BLE001 - a case that cannot even be built is a fuzz bug
                    raise RuntimeError(f"building a {family} case failed: {exc!r}") from exc
                kind, detail = outcome(case, timeout)
                counts[family][kind] += 1
                if kind == "other":
                    others.append(f"{family} case {i}: {detail}")
                    if verbose:
                        print(f"{family} case {i}: {detail} [{getattr(case, 'desc', '')}]", file=sys.stderr)
    finally:
        if tmp:
            tmp.cleanup()
    return {"counts": counts, "others": others}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=400, help="API cases and file cases each")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--timeout", type=float, default=20.0, help="seconds before a case counts as a hang")
    ap.add_argument("--cli", type=int, default=130, help="command-line cases of each class: folders, faults (every "
                    "phase in turn), sizes")
    args = ap.parse_args(argv)
    res = fuzz(args.n, args.seed, args.timeout, verbose=True)
    cli = fuzz_cli(args.cli, args.seed, faults=args.cli, verbose=True)
    res["counts"].update(cli["counts"])
    res["others"] += cli["others"]
    total = Counter()
    for family, c in res["counts"].items():
        total.update(c)
        print(f"{family:<7} tried {sum(c.values()):5d}  clear error {c['clear']:5d}  valid {c['valid']:5d}  "
              f"other {c['other']:5d}")
    print(f"{'all':<7} tried {sum(total.values()):5d}  clear error {total['clear']:5d}  valid {total['valid']:5d}  "
          f"other {total['other']:5d}")
    kinds = Counter(o.split(": ", 1)[1].split(":")[0] for o in res["others"])
    for k, v in kinds.most_common():
        print(f"  other: {v:4d} x {k}")
    return 0 if not res["others"] else 1


if __name__ == "__main__":
    sys.exit(main())
