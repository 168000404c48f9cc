"""Force evaluation composed from the force families: per-term read-outs and the fused step pass."""

from __future__ import annotations

from warp_shape.kernels import hinge as kh

from .model import Control, Model, State
from .physics import FORCE_TERMS, Launch
from .physics.bending import eval_bending
from .physics.damping import eval_init_step, eval_init_viscous
from .physics.pressure import eval_pressure, eval_pressure_gradient, eval_volume
from .physics.springs import eval_springs

__all__ = ["eval_forces", "eval_hinges", "eval_forces_fused", "eval_actuators", "force_terms"]


def eval_forces(model: Model, state: State, control: Control, x, v, f, volume, launch: Launch,
                paper_bending: bool = False, terms=None):
    """Force terms at (x, v) into f (overwritten), one kernel per family (``terms``: names of
    ``force_terms(model)``, all when None); volume (W,) receives the enclosed volume per world.
    Used for per-term read-outs; steps use the fused pass below."""
    terms = force_terms(model) if terms is None else terms
    eval_init_viscous(model, v, f, volume, launch, enabled="viscous" in terms)
    if "pressure" in terms:
        eval_volume(model, x, volume, launch)
        eval_pressure(model, x, volume, control, f, launch)
    if "spring" in terms:
        eval_springs(model, state, x, v, f, launch)
    if "bending" in terms:
        eval_bending(model, state, x, f, launch, paper_bending)
    for fam in model.families:
        if fam.name in terms:
            fam.eval_forces(model, state, control, x, v, f, launch)


def eval_actuators(model: Model, state: State, control: Control, x, v, f, launch: Launch):
    """Every actuator family's forces at (x, v) into f (accumulated), in the model's family order."""
    for fam in model.families:
        fam.eval_forces(model, state, control, x, v, f, launch)


def force_terms(model: Model) -> tuple:
    """The force terms a read-out of ``model`` can ask for: ``FORCE_TERMS`` and the model's actuator
    families (the IPAM's term is 'ipam')."""
    return FORCE_TERMS + tuple(f.name for f in model.families if f.name not in FORCE_TERMS)


def eval_hinges(model: Model, state: State, xv, fg, volume2d, slot: int, launch: Launch, paper: bool = False):
    """One fused pass over the hinges at the point xv (2, W, V): springs + dampers, bending (only
    when k_t > 0), the enclosed volume (into column ``slot`` of volume2d) and dV/dx (into fg[1]).
    Accumulates."""
    _, W, _ = xv.shape
    E = model.n_edges
    kernel = kh.eval_hinge_bending_kernel if model.has_bending else kh.eval_hinge_kernel
    launch(kernel, (W * E,),
           [model.hinges, model.hinge_owns, model.scalar(model.spring_damping), int(paper), W, E, state.edge, xv, slot,
            fg, volume2d])


def eval_forces_fused(model: Model, state: State, control: Control, fg, volume2d, launch: Launch,
                      paper_bending: bool = False):
    """Total force at the current state into fg[0] (overwritten; fg is (2, W, V), fg[1] receives
    dV/dx) through the same fused kernels as a step."""
    eval_init_step(model, state.xv, fg, volume2d, launch)
    eval_hinges(model, state, state.xv, fg, volume2d, 0, launch, paper_bending)
    eval_actuators(model, state, control, state.x, state.v, fg[0], launch)
    eval_pressure_gradient(model, control, fg, volume2d, 0, launch)
