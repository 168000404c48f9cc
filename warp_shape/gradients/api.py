"""``ws.gradient``: d(fit objective)/d(design parameters and controls) of a replayed control sequence."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..controller.result import ControlResult
from ..display import Design
from ..errors import DesignError
from ..mesh import TriMesh
from ..model import PRECISIONS, model_families
from ..objectives.radial import fit_objective_and_gradient
from ..sampling import RadialSampler
from .families import check_adjoints, family_parameters
from .differentiable_replay import DifferentiableReplay

__all__ = ["gradient", "replay_gradient", "Gradient", "GRADIENT_PARAMETERS", "gradient_parameters"]

#: the parameters ``gradient`` differentiates by, with their units (d objective / d parameter is in 1 / unit)
GRADIENT_PARAMETERS = {
    "rest_positions": "m, (V, 3): the rest shape's vertices",
    "youngs_modulus": "Pa: the silicone's Young's modulus in the edge springs (thickness held; 0 with a "
                      "hyperelastic membrane, whose constants are membrane_shear_modulus, ...)",
    "bending_stiffness": "N m/rad: the paper's hinge bending stiffness k_t (0 with a hyperelastic membrane, whose "
                         "hinges follow membrane_shear_modulus and membrane_thickness)",
    "ipam_stiffness": "N/m, (n_ipam,): each IPAM's stiffness k",
    "ipam_area": "m^2, (n_ipam,): each IPAM's area A",
    "air": "mol, (rows,): the chamber air of each history row (in force up to that row)",
    "ipam_pressures": "Pa, (rows, n_ipam): each row's IPAM gauge pressures",
}


@dataclass
class Gradient:
    """The fit objective of a replayed sequence and its derivatives (SI, see ``GRADIENT_PARAMETERS``).

    ``objective``: the fit objective of the replay's final shape against the target; ``values``:
    {name: d objective / d parameter} for the names asked for; ``positions``: (V, 3) the final shape (m);
    ``internal_steps``: the replay's internal steps; ``precision``; ``segment``."""

    objective: float
    values: dict
    positions: np.ndarray = field(repr=False)
    internal_steps: int = 0
    precision: str = "float64"
    segment: int = 0  # output steps between the adjoint's checkpoints


def gradient_parameters(design: Design) -> dict:
    """{name: unit} of every parameter ``gradient`` can differentiate ``design``'s replay by:
    ``GRADIENT_PARAMETERS``, then each of its other force families' parameters and controls
    (``<family>_<array>``, ``<family>_controls``); a family without an adjoint is refused by name."""
    fams = model_families(design)
    count = {f.name: f.count(design) for f in fams}.get
    check_adjoints(fams, count)
    out = dict(GRADIENT_PARAMETERS)
    for name, unit in family_parameters(fams, count).items():
        out.setdefault(name, unit)
    return out


def check_wrt(wrt, parameters: dict = GRADIENT_PARAMETERS) -> tuple:
    """The parameter names asked for, checked against ``parameters`` (a clear error naming the
    choices for an unknown one)."""
    names = (wrt,) if isinstance(wrt, str) else tuple(wrt)
    bad = [n for n in names if n not in parameters]
    choices = ", ".join(parameters)
    if not names:
        raise DesignError(f"gradient wrt: no parameter given; choose from {choices}")
    if bad:
        raise DesignError(f"gradient wrt: unknown parameter {bad[0]!r}; choose from {choices}")
    return names


def gradient(design: Design, result: ControlResult, target: TriMesh | None = None, wrt=tuple(GRADIENT_PARAMETERS), *,
             precision: str = "float64", device: str = "cpu", segment: int | None = None,
             threads: int | None = None) -> Gradient:
    """Replay ``result``'s control sequence open loop on ``design`` (as ``ws.replay``) and return the fit
    objective of its final shape against ``target`` (centred on its volume centroid; None: the result's
    own target) with its gradient with respect to ``wrt`` (names of ``GRADIENT_PARAMETERS``).

    The adjoint runs back through every internal step, the jam events included (a jammed cell's rest
    lengths and angles are those of the state it jammed at, so they depend on everything before),
    with checkpoints every ``segment`` output steps (None: the square root of their number), so memory
    grows with the square root of the sequence's length. ``precision`` "float64" (the default, for
    checks) or "float32". ``threads``: 2 recomputes the next segment on a second thread while the
    adjoint steps back through this one (the same gradient, bit for bit), 1 does both on this thread;
    None: 2 on a CPU with two cores or more. docs/gradients.md gives the algorithm, its checks and its
    cost."""
    if not isinstance(design, Design):
        raise DesignError(f"gradient needs a ws.Design, got {type(design).__name__}")
    if not isinstance(result, ControlResult):
        raise DesignError(f"gradient needs a control result (ws.control returns one), got {type(result).__name__}")
    names = check_wrt(wrt, gradient_parameters(design))
    if threads is not None and (isinstance(threads, bool) or not isinstance(threads, int) or threads not in (1, 2)):
        raise DesignError(f"gradient threads must be 1, 2 or None (2 where the CPU has two cores), got {threads!r}")
    if precision not in PRECISIONS:
        raise DesignError(f"precision must be one of {sorted(PRECISIONS)}, got {precision!r}")
    target = result.target if target is None else target
    if not isinstance(target, TriMesh):
        raise DesignError(f"gradient needs the target as a ws.TriMesh, got {type(target).__name__}")
    if len(result.ipam_pressures) != design.n_ipams or len(result.jammed) != design.n_cells:
        raise DesignError("the result was recorded on a design with other IPAMs or cells than the one given")
    return replay_gradient(design, result, target, names, precision=precision, device=device, segment=segment,
                           threads=threads)


def replay_gradient(design: Design, result: ControlResult, target: TriMesh, names: tuple, *,
                    precision: str = "float64", device: str = "cpu", segment: int | None = None,
                    threads: int | None = None, plan=None) -> Gradient:
    """``gradient``'s work on checked arguments (``names`` of ``GRADIENT_PARAMETERS``); ``plan``: the
    forward replay's plan where it was made already (``replay.plan_replay`` of this design and result
    in this precision, e.g. by the replay that accepted a co-design step), so only the adjoint runs."""
    target = target.centered()
    replay = DifferentiableReplay(design, result, precision=precision, device=device, segment=segment)
    plan = replay.forward(plan)
    sampler = RadialSampler(target, device=device)
    objective, dj_dx = fit_objective_and_gradient(plan.final, sampler, 0, design.rest.faces, target.volume())
    values = replay.backward(dj_dx, objective, threads=threads).values
    return Gradient(objective=objective, values={n: values[n] for n in names}, positions=plan.final,
                    internal_steps=plan.internal_steps, precision=precision, segment=plan.segment)
