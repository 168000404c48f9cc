"""Where the model-based refinement's gradient should come from: finite differences or the adjoint.

``bench_control_gradient``: the shipped ``four_targets_20`` problem (642 vertices, 20 IPAMs) placed by
Algorithm 1 with the paper's law (no co-design), then each target controlled by the model-based
method with m active controls (the air and the last m - 1 IPAMs; the others held neutral), once with
the finite-difference Jacobian (``inverse_gradient="finite-difference"``) and once with the
equilibrium's adjoint (``"adjoint"``), side by side. Per run: the refinement's own wall time (the
warm start and the plan settles, the same both ways, are left out), its final objective and its
iterations; ``ratio`` = adjoint / finite-difference time, ``objective_ratio`` the same for the fit.
"""

from __future__ import annotations

import time
from contextlib import contextmanager

from warp_shape.controller import ControlSettings, control
from warp_shape.controller import inverse as inverse_module
from warp_shape.designer import design
from warp_shape.io.scene_read import load_scene

__all__ = ["bench_control_gradient", "CONTROL_GRADIENT_COLUMNS"]

CONTROL_GRADIENT_COLUMNS = ["target", "controls", "fd_refine_s", "adjoint_refine_s", "ratio", "fd_objective",
                            "adjoint_objective", "objective_ratio", "fd_iterations", "adjoint_iterations", "cg_iterations"]

WAYS = ("finite-difference", "adjoint")


@contextmanager
def _refine_clock():
    """Sum the wall time of the refinement (``controller.refine.refine`` as the inverse method calls it)."""
    spent = [0.0]
    original = inverse_module.refine

    def timed(*args, **kwargs):
        t = time.perf_counter()
        try:
            return original(*args, **kwargs)
        finally:
            spent[0] += time.perf_counter() - t

    inverse_module.refine = timed
    try:
        yield spent
    finally:
        inverse_module.refine = original


def bench_control_gradient(device: str = "cpu", controls=(6, 11, 21), targets=None, progress=None) -> list[dict]:
    """One row per (target, number of controls); see the module docstring."""
    scene = load_scene("four_targets_20")
    opts = scene.settings["designer"]
    placed = design(scene.design.rest, scene.targets, actuators=opts["actuators"], target_names=scene.target_names,
                    cell_radius=opts["cell_radius"], placement="paper", codesign="off", device=device,
                    control_settings=ControlSettings(method="paper"))
    d = placed.design
    rows = []
    for t, name in enumerate(scene.target_names):
        if targets is not None and name not in targets:
            continue
        for m in controls:
            m = min(int(m), d.n_ipams + 1)
            passive = tuple(range(d.n_ipams - (m - 1)))
            out = {}
            for way in WAYS:
                with _refine_clock() as spent:
                    r = control(d, scene.targets[t], device=device, passive_ipams=passive, target_name=name,
                                settings=ControlSettings(inverse_gradient=way, workers=1))
                out[way] = (spent[0], r)
            (tf, rf), (ta, ra) = out["finite-difference"], out["adjoint"]
            rows.append(dict(target=name, controls=m, fd_refine_s=round(tf, 3), adjoint_refine_s=round(ta, 3),
                             ratio=round(ta / tf, 3), fd_objective=round(rf.objective, 6),
                             adjoint_objective=round(ra.objective, 6), objective_ratio=round(ra.objective / rf.objective, 4),
                             fd_iterations=rf.refinement["iterations"], adjoint_iterations=ra.refinement["iterations"],
                             cg_iterations=ra.refinement["adjoint_iterations"]))
            if progress is not None:
                progress(f"control_gradient: {name}, {m} controls: {rows[-1]}")
    return rows
