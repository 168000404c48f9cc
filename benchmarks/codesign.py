"""Co-design benchmark: the fit of every target after co-design beside Algorithm 1 and the default placement.

``bench_codesign``: each case (a shipped design problem, a shipped target alone, or generated targets
the project does not ship, alone and in pairs) is designed three ways on the same base mesh and
actuator count: ``placement="paper"`` (Algorithm 1 as published), the default placement with
co-design off ("default": the design as placed), and the default placement with its default
co-design, ``codesign="rest+ipams"``. One row per target and way:
objective, PCC, MARE (mm), MPRE (%), and the ratio of the objective to Algorithm 1's.
"""

from __future__ import annotations

import time

from warp_shape.designer import design
from warp_shape.errors import DesignError
from warp_shape.io.scene_read import load_scene
from warp_shape.mesh import icosphere
from warp_shape.targets import TARGET_NAMES, target

from .generated_shapes import NAMES, shape

__all__ = ["bench_codesign", "check_cases", "CODESIGN_COLUMNS", "CODESIGN_CASES"]

CODESIGN_COLUMNS = ["case", "target", "way", "objective", "vs_paper", "pcc", "mare_mm", "mpre_pct", "wall_s"]

#: the cases: shipped problems (scene names), shipped targets alone, generated targets alone and in pairs
CODESIGN_CASES = ("oval_heart", "four_targets_5", "four_targets_20", "pear", "heart", "cube", "egg", "puck",
                  "peanut", "tilted_ellipsoid", "bean", "teardrop", "egg+tilted_ellipsoid", "puck+peanut",
                  "bean+teardrop")

#: the three ways a case is designed: Algorithm 1 as published, the default placement as placed, and the
#: default (placement and co-design)
WAYS = (("paper", dict(placement="paper", codesign="off")), ("default", dict(codesign="off")),
        ("codesign", dict(codesign="rest+ipams")))


def check_cases(cases) -> list:
    """The cases asked for (None: all), each a name of ``CODESIGN_CASES`` or shapes joined by '+'."""
    cases = list(cases or CODESIGN_CASES)
    shapes = set(NAMES) | set(TARGET_NAMES)
    bad = [c for c in cases if c not in CODESIGN_CASES and any(part not in shapes for part in c.split("+"))]
    if bad:
        raise DesignError(f"--cases: unknown case {bad[0]!r}; choose from {', '.join(CODESIGN_CASES)} (or a+b pairs "
                          f"of {', '.join(sorted(shapes))})")
    return cases


def _problem(case: str, generated):
    """(base mesh, targets, names, actuators, cell radius) of a case."""
    if case in ("oval_heart", "four_targets_5", "four_targets_20"):
        sc = load_scene(case)
        opts = sc.settings["designer"]
        return sc.design.rest, sc.targets, sc.target_names, opts["actuators"], opts["cell_radius"]
    names = case.split("+")
    targets = [target(n) if n in TARGET_NAMES else generated(n) for n in names]
    return icosphere(3, 0.04), targets, names, 4 if len(names) > 1 else 3, 0.012


def bench_codesign(cases=CODESIGN_CASES, device: str = "cpu", generated=shape, progress=print) -> list[dict]:
    """Rows of ``CODESIGN_COLUMNS`` for every case; ``generated(name)`` makes a target the project does
    not ship (the tests' shapes); ``progress(text)`` is told each finished design."""
    rows = []
    for case in cases:
        base, targets, names, actuators, cell_radius = _problem(case, generated)
        paper = None
        for way, opts in WAYS:
            t0 = time.perf_counter()
            res = design(base, targets, actuators=actuators, target_names=names, cell_radius=cell_radius,
                         device=device, **opts)
            wall = time.perf_counter() - t0
            paper = paper or [r.objective for r in res.results]
            for name, r, p in zip(names, res.results, paper):
                rows.append(dict(case=case, target=name, way=way, objective=round(r.objective, 5),
                                 vs_paper=round(r.objective / p, 3), pcc=round(r.pcc, 4), mare_mm=round(r.mare * 1e3, 3),
                                 mpre_pct=round(r.mpre, 2), wall_s=round(wall, 1)))
            if progress is not None:
                progress(f"{case} {way}: {wall:.0f} s, objectives "
                         + " ".join(f"{r.objective:.4f}" for r in res.results))
    return rows
