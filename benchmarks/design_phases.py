"""Where the default ``warp-shape design`` spends its time, phase by phase, in a process of its own.

Run as a script (``python design_phases.py OUT_JSON -- DESIGN_ARGS...``) by ``bench design
--baseline``, with this checkout's ``warp_shape`` or, where ``SOURCE_VARIABLE`` names another checkout
(a baseline commit's worktree), with that one's (its package folders, pyproject's package-dir, imported
in place of the installed ones), so it uses the standard library only at import time and finds the
functions it times by name: where a commit lacks one, its phase is left out (None). Each phase's time is the wall time of
its calls (a call inside another timed call of the same phase is not counted twice):

- ``placement``: the control rounds of Algorithm 1 and their placements (``designer.loop``'s rounds),
  less the refinement;
- ``refinement``: the default placement's refinement rounds after the last round (its ``finish``);
- ``codesign``: co-design after placement, and inside it ``gradients`` (its gradient batches),
  ``replays`` (its other batches of jobs: the replays that judge steps and end rounds) and
  ``recontrol`` (its re-controls);
- ``outputs``: every output file (figures, USD, molds, reports);
- ``compile``: Warp module loads in this process (with a warm kernel cache: reading the built modules;
  the worker processes load theirs while the designer sets up);
- ``process``: the whole process, start-up (imports) included, as measured here from the first line.
"""

from __future__ import annotations

import importlib
import importlib.abc
import importlib.util
import json
import os
import sys
import threading
import re
import time
from pathlib import Path

T_START = time.perf_counter()

#: phase -> [(module, attribute path)]: the functions whose calls make the phase
PHASES = {
    "rounds": [("warp_shape.designer.loop", "_rounds")],
    "refinement": [("warp_shape.designer.per_target", "PerTargetPlacement.finish")],
    "codesign": [("warp_shape.designer.loop", "_codesign")],
    "gradients": [("warp_shape.designer.codesign", "CodesignProblem.gradients")],
    "batches": [("warp_shape.designer.codesign", "run_jobs")],
    "recontrol": [("warp_shape.designer.codesign", "control_many")],
    "outputs": [("warp_shape.cli.design", "_write_outputs")],
    "compile": [("warp._src.context", "Module.load"), ("warp.context", "Module.load")],
}


#: environment variable: the checkout whose ``warp_shape`` the probe imports (unset: the installed one)
SOURCE_VARIABLE = "WARP_SHAPE_SOURCE"


class CheckoutFinder(importlib.abc.MetaPathFinder):
    """Imports ``warp_shape`` and its mapped packages (``warp_shape.kernels`` is the checkout's
    ``kernels/``, ...) from the checkout ``root``, ahead of the installed (editable) package."""

    def __init__(self, root: Path):
        text = (root / "pyproject.toml").read_text()
        section = re.search(r"^\[tool\.setuptools\.package-dir\]\s*$(.*?)(?=^\[|\Z)", text, re.M | re.S)
        dirs = dict(re.findall(r'^"([\w.]+)"\s*=\s*"([^"]+)"', section.group(1), re.M)) if section else {}
        self.dirs = {name: root / folder for name, folder in (dirs or {"warp_shape": "warp_shape"}).items()}

    def find_spec(self, fullname, path=None, target=None):
        prefix = max((p for p in self.dirs if fullname == p or fullname.startswith(p + ".")), key=len, default=None)
        if prefix is None:
            return None
        base = self.dirs[prefix].joinpath(*fullname[len(prefix) + 1:].split(".")) if fullname != prefix \
            else self.dirs[prefix]
        if (base / "__init__.py").exists():
            return importlib.util.spec_from_file_location(fullname, base / "__init__.py",
                                                          submodule_search_locations=[str(base)])
        if base.with_suffix(".py").exists():
            return importlib.util.spec_from_file_location(fullname, base.with_suffix(".py"))
        return None


#: ``sitecustomize.py`` of the baseline's processes (the design process and its spawned workers): the
#: finder installed at start-up, so every process of the run imports the baseline's code
SITE_HOOK = """import importlib.util, os, sys
from pathlib import Path
if os.environ.get({var!r}):
    spec = importlib.util.spec_from_file_location("ws_design_phases", {path!r})
    probe = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(probe)
    sys.meta_path.insert(0, probe.CheckoutFinder(Path(os.environ[{var!r}])))
"""


def write_site_hook(folder: Path) -> Path:
    """``folder``/sitecustomize.py installing ``CheckoutFinder`` where ``SOURCE_VARIABLE`` is set;
    ``folder`` goes on PYTHONPATH."""
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "sitecustomize.py").write_text(SITE_HOOK.format(var=SOURCE_VARIABLE, path=str(Path(__file__).resolve())))
    return folder


class PhaseClock:
    """Wall seconds per phase and call counts; nested calls of one phase (on any thread) count once."""

    def __init__(self):
        self.seconds, self.calls, self._depth, self._since = {}, {}, {}, {}
        self._lock = threading.Lock()

    def enter(self, phase: str) -> None:
        with self._lock:
            self.calls[phase] = self.calls.get(phase, 0) + 1
            if self._depth.get(phase, 0) == 0:
                self._since[phase] = time.perf_counter()
            self._depth[phase] = self._depth.get(phase, 0) + 1

    def leave(self, phase: str) -> None:
        with self._lock:
            self._depth[phase] -= 1
            if self._depth[phase] == 0:
                self.seconds[phase] = self.seconds.get(phase, 0.0) + time.perf_counter() - self._since[phase]


def _timed(fn, phase: str, clock: PhaseClock):
    def wrapper(*args, **kwargs):
        clock.enter(phase)
        try:
            return fn(*args, **kwargs)
        finally:
            clock.leave(phase)

    wrapper.__wrapped__ = fn
    return wrapper


def install(clock: PhaseClock) -> dict:
    """Wrap every phase's functions that this ``warp_shape`` has; returns {phase: found}."""
    found = {}
    for phase, places in PHASES.items():
        found[phase] = False
        for module_name, path in places:
            try:
                owner = importlib.import_module(module_name)
            except ImportError:
                continue
            *parents, name = path.split(".")
            for part in parents:
                owner = getattr(owner, part, None)
            if owner is None or not hasattr(owner, name):
                continue
            setattr(owner, name, _timed(getattr(owner, name), phase, clock))
            found[phase] = True
    return found


def main(argv) -> int:
    out, design_args = argv[0], argv[argv.index("--") + 1:]
    if os.environ.get(SOURCE_VARIABLE) and not any(isinstance(f, CheckoutFinder) or type(f).__name__ == "CheckoutFinder"
                                                   for f in sys.meta_path):
        sys.meta_path.insert(0, CheckoutFinder(Path(os.environ[SOURCE_VARIABLE])))
    clock = PhaseClock()
    found = install(clock)
    # the command of the checkout timed, imported by name as the phases' functions are
    rc = importlib.import_module("warp_shape.cli").main(["design", *design_args])
    process = time.perf_counter() - T_START
    phases = {p: (round(clock.seconds.get(p, 0.0), 3) if found[p] else None) for p in PHASES}
    if phases["rounds"] is not None:
        phases["placement"] = round(phases["rounds"] - (phases["refinement"] or 0.0), 3)
    if phases["batches"] is not None:
        phases["replays"] = round(phases["batches"] - (phases["gradients"] or 0.0), 3)
    phases["process"] = round(process, 3)
    calls = {p: clock.calls.get(p, 0) for p in PHASES if found[p]}
    with open(out, "w") as f:
        json.dump(dict(rc=rc, phases=phases, calls=calls), f)
    return rc


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
