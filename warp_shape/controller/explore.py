"""Scratch batches of worlds: copy states in, set controls, settle a fixed number of steps, measure.

The model-based controller asks "what shape does the membrane settle to under these controls, from
this state?" for many control vectors at once: every question is one world of one Simulator, so a
finite-difference Jacobian or a line search is one batch (one launch per kernel for all of them).
Passive IPAMs are held neutral while a batch settles, as in the control loop: every control period
their pressure is set so that their natural length is their current length.

With ``SimulationSettings.settle == "static"`` a batch is not stepped: every world goes to the
equilibrium of its controls (``Simulator.settle_static``; passive IPAMs are masked out, so they exert
no force either way), which is where the dynamics comes to rest. Nothing jams while a batch settles,
so the equilibrium is on the branch the dynamics would take (docs/equilibria.md); a batch whose
static settle fails is stepped instead.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import SimulationError
from ..model import HostModel, WorldRef
from ..sampling import RadialSampler
from ..simulator import Simulator
from .observe import fit_of, ipam_neutral_pressures, vertex_area_shares
from .worlds import mask_passive, max_speeds

__all__ = ["Settled", "Explorer"]


@dataclass
class Settled:
    """A batch after settling: per world the radii, the target's radii and weights, and the end state."""

    r: np.ndarray  # (B, V) design radii, m
    R: np.ndarray  # (B, V) sampled target radii through the same vertices, m
    weights: np.ndarray  # (B, V) vertex area shares of the sampled target, m^2
    objective: np.ndarray  # (B,) the fit objective
    mare: np.ndarray  # (B,) mean |r - R|, m
    speed: np.ndarray  # (B,) largest vertex speed at the end, m/s
    states: list  # (B,) model.WorldRef: each world at the end (a snapshot on the device)


class Explorer:
    """Settles batches of worlds of one design. ``target_volume``: (T,) volume of every target;
    ``passive``: (T, n_ipam) bool, the IPAMs each target holds neutral."""

    def __init__(self, design, sim_settings, device: str, sampler: RadialSampler, host: HostModel,
                 target_volume: np.ndarray, passive: np.ndarray, settle_steps: int, control_period: int):
        self.design, self.sim_settings, self.device = design, sim_settings, device
        self.sampler, self.host = sampler, host
        self.target_volume, self.passive = np.asarray(target_volume, float), passive
        self.settle_steps, self.period = int(settle_steps), int(control_period)
        self._sims: dict[int, object] = {}
        self.world_steps = 0  # world-steps simulated so far (cost)
        self.evaluations = 0  # force evaluations of the static settles so far (cost; settle "static")
        self.equilibrium_gradient = None  # gradients.equilibrium.EquilibriumGradient, made on first use
        self.adjoint_iterations = 0  # conjugate-gradient iterations of the adjoint solves so far (cost)

    def _sim(self, worlds: int):
        if worlds not in self._sims:
            self._sims[worlds] = Simulator(self.design, device=self.device, settings=self.sim_settings, worlds=worlds)
        return self._sims[worlds]

    def settle(self, states: list[WorldRef], air: np.ndarray, pressures: np.ndarray, targets: np.ndarray) -> Settled:
        """Worlds started from ``states`` (copied on the device) under controls ``air`` (B,) mol and ``pressures`` (B, n_ipam)
        Pa (passive IPAMs: neutral instead), settled ``settle_steps`` steps, measured on ``targets`` (B,)."""
        B = len(states)
        sim = self._sim(B)
        sim.load_worlds(states)
        sim.air_moles = np.asarray(air, dtype=np.float64)
        passive = self.passive[np.asarray(targets)] if self.host.n_ipams else np.zeros((B, 0), bool)
        mask_passive(sim, passive)
        p = np.array(pressures, dtype=np.float64).reshape(B, self.host.n_ipams)
        if self.sim_settings.settle == "static" and self._settle_static(sim, passive, p):
            return self.measure(sim, np.asarray(targets))
        done = 0
        while done < self.settle_steps:
            if passive.any():
                lengths = np.asarray(sim.ipam_lengths()).reshape(B, -1)
                p = np.where(passive, ipam_neutral_pressures(lengths, self.host), p)
            if self.host.n_ipams:
                sim.ipam_pressures = p
            n = min(self.period, self.settle_steps - done)
            sim.step(n)
            done += n
        self.world_steps += B * self.settle_steps
        return self.measure(sim, np.asarray(targets))

    def _settle_static(self, sim, passive: np.ndarray, p: np.ndarray) -> bool:
        """Every world of ``sim`` to the equilibrium of its controls; False (the state as it was) where
        the static settle fails, so that the caller steps instead."""
        if passive.any():
            lengths = np.asarray(sim.ipam_lengths()).reshape(len(p), -1)
            p = np.where(passive, ipam_neutral_pressures(lengths, self.host), p)
        if self.host.n_ipams:
            sim.ipam_pressures = p
        try:
            out = sim.settle_static()
        except SimulationError:
            return False
        self.evaluations += int(out.iterations)
        return True

    def jammed(self, states: list[WorldRef], cells: np.ndarray) -> list[WorldRef]:
        """``states`` with the cells ``cells`` (B, n_cell) bool of each jammed where they are now."""
        sim = self._sim(len(states))
        sim.load_worlds(states)
        done = np.asarray(sim.jammed).reshape(len(states), -1)
        for b, j in zip(*np.nonzero(np.asarray(cells, dtype=bool) & ~done)):
            sim.jam(int(j), world=int(b))
        return sim.snapshot()

    def measure(self, sim, targets: np.ndarray) -> Settled:
        """The fit of every world of ``sim`` (world b measured on target ``targets[b]``)."""
        x = np.asarray(sim.positions, dtype=np.float64).reshape(sim.worlds, -1, 3)
        sampled = self.sampler.sample_worlds(x, targets)
        r, R = np.linalg.norm(x, axis=2), np.linalg.norm(sampled, axis=2)
        fit = fit_of(x, sampled, self.host.faces, self.target_volume[targets])
        return Settled(r=r, R=R, weights=vertex_area_shares(sampled, self.host.faces), objective=fit["objective"],
                       mare=fit["mare"], speed=max_speeds(sim), states=sim.snapshot())
