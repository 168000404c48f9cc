"""A sweep's plan: the design problem (scene, base mesh, targets) and one ``RunTask`` per run.

``subsets_plan``: every non-empty subset of the targets (the paper's Fig. 11); ``grid_plan``: the
product of the values of the swept parameters (Fig. 12: ``actuators=5,10,20``). Each run is the job
``warp-shape design SCENE --targets ... --actuators N`` does, with the swept settings applied.
"""

from __future__ import annotations

import dataclasses
import itertools
import math
from dataclasses import dataclass, field

from ..designer.design_settings import DEFAULT_ACTUATORS
from ..io.scene_read import load_scene
from ..mesh import TriMesh, icosphere_like
from ..targets import load_target
from .params import Param, SweepError, check_values, split_params

__all__ = ["Problem", "RunTask", "load_problem", "subsets_plan", "grid_plan", "run_id", "check_run_count", "MAX_RUNS"]

DEFAULT_SCENE = "oval_heart"  # as `warp-shape design`


@dataclass
class Problem:
    """The fixed part of a sweep: the scene's base mesh, the named targets, the scene's settings groups
    (simulation, controller, designer with ``actuators``) and material, and the settings fixed for
    every run (``fixed``)."""

    scene: str
    base: TriMesh
    targets: list  # [(name, TriMesh)]
    actuators: int
    settings: dict  # the scene's settings groups {group: {key: value}}
    fixed: dict = field(default_factory=dict)  # {name: value} applied to every run
    material: dict = field(default_factory=dict)  # the scene design's material fields (none: the default)


@dataclass
class RunTask:
    """Everything one run needs, as plain picklable data (sent to a Ray worker as is)."""

    index: int
    run_id: str
    target_names: list
    targets: list  # TriMesh per name
    base: TriMesh
    actuators: int
    settings: dict  # {group: {field: value}}: designer, controller, simulation, material, design, run
    swept: dict  # {parameter name as given: value}, the row's parameter columns
    device: str = "cpu"
    marker_height: float = 2e-3
    layer_thickness: float = 5e-3


def _load_targets(specs) -> list:
    """Target names (oval pear heart cube) or mesh files -> [(name, TriMesh)], as ``warp-shape design``
    reads them (an unknown name gets the closest one, an unreadable file a parse error)."""
    out = [load_target(spec) for spec in specs]
    names = [n for n, _ in out]
    if len(set(names)) != len(names):
        raise SweepError(f"targets repeat a name: {names}")
    return out


def load_problem(scene: str | None = None, targets=None, fixed: dict | None = None) -> Problem:
    """The design problem of a scene (default ``oval_heart``, as ``warp-shape design``), its targets
    replaced by ``targets`` (names or mesh files) when given; ``fixed`` settings are checked."""
    checked = {key: check_values(key, [value]).values[0] for key, value in (fixed or {}).items()}  # before any work
    name = scene or DEFAULT_SCENE
    sc = load_scene(name)
    base = sc.base_mesh()
    named = _load_targets(targets) if targets else list(zip(sc.target_names, sc.targets))
    if not named:
        raise SweepError("no targets: give --targets (e.g. --targets oval heart) or a scene with targets")
    groups = {g: dict(v) for g, v in (sc.settings or {}).items() if g in ("simulation", "controller", "designer")}
    actuators = int(groups.get("designer", {}).pop("actuators", DEFAULT_ACTUATORS))
    material = dataclasses.asdict(sc.design.material) if sc.design is not None else {}
    return Problem(scene=str(name), base=base, targets=named, actuators=actuators, settings=groups, fixed=checked,
                   material=material)


def run_id(names, swept: dict) -> str:
    """A run's folder name: its targets, then each swept parameter and value (stable across reruns)."""
    parts = ["+".join(names)] + [f"{k.rpartition('.')[2]}-{v}" for k, v in swept.items()]
    return "__".join(parts).replace("/", "_").replace(" ", "")


def _base_mesh(base: TriMesh, subdivisions) -> TriMesh:
    """The scene's base mesh, or (as ``warp-shape design --subdivisions``) an icosphere of
    ``subdivisions`` enclosing the base's volume."""
    return base if subdivisions is None else icosphere_like(base, subdivisions)


def _task(problem: Problem, index: int, names, values: dict, swept: dict, device: str) -> RunTask:
    """One run: the scene's settings and material, then the fixed settings, then the swept values."""
    groups = split_params({**problem.fixed, **values})
    for group, scene_values in [*problem.settings.items(), ("material", problem.material)]:
        groups[group] = {**scene_values, **groups.get(group, {})}
    run = groups.pop("run")
    actuators = int(run.get("actuators", problem.actuators))
    own = dict(problem.targets)
    return RunTask(index=index, run_id=run_id(names, swept), target_names=list(names),
                   targets=[own[n] for n in names], base=_base_mesh(problem.base, run.get("subdivisions")),
                   actuators=actuators, settings=groups, swept=dict(swept), device=device)


def subsets_plan(problem: Problem, device: str = "cpu", params: list[Param] | None = None) -> list[RunTask]:
    """Every non-empty subset of the problem's targets (in the order given, smallest first), times the
    grid of ``params`` if any."""
    names = [n for n, _ in problem.targets]
    check_run_count((2 ** len(names) - 1) * math.prod(len(p.values) for p in params or []),
                    f"{2 ** len(names) - 1} target subsets")
    subsets = [list(c) for k in range(1, len(names) + 1) for c in itertools.combinations(names, k)]
    combos = _combos(params or [])
    return [_task(problem, i, subset, values, swept, device)
            for i, (subset, (values, swept)) in enumerate(itertools.product(subsets, combos))]


def grid_plan(problem: Problem, params: list[Param], device: str = "cpu") -> list[RunTask]:
    """The product of the swept values, every run with all of the problem's targets."""
    if not params:
        raise SweepError("a grid sweep needs at least one --param NAME=V1,V2 (e.g. actuators=5,10,20)")
    names = [n for n, _ in problem.targets]
    return [_task(problem, i, names, values, swept, device) for i, (values, swept) in enumerate(_combos(params))]


#: the most runs one sweep plans (each is a whole design, minutes on a CPU)
MAX_RUNS = 10_000


def check_run_count(runs: int, what: str = "the grid") -> None:
    """A clear ``SweepError`` for a sweep of more than ``MAX_RUNS`` runs, before any is planned."""
    if runs > MAX_RUNS:
        raise SweepError(f"this sweep is {runs} runs ({what} x the --param values), more than the {MAX_RUNS} one sweep "
                         f"runs (each is a whole design, minutes); sweep fewer values, or split it into several "
                         f"sweeps with their own --out")


def _combos(params: list[Param]) -> list[tuple[dict, dict]]:
    """(values by qualified name, values by column name) for each point of the grid."""
    check_run_count(math.prod(len(p.values) for p in params))
    seen = set()
    for p in params:
        if (p.group, p.name) in seen:
            raise SweepError(f"sweep parameter {p.name} is given twice; give all its values in one --param")
        seen.add((p.group, p.name))
    out = []
    for point in itertools.product(*[p.values for p in params]):
        values = {f"{p.group}.{p.name}" if p.group != "run" else p.name: v for p, v in zip(params, point)}
        swept = {p.name: v for p, v in zip(params, point)}
        out.append((values, swept))
    return out
