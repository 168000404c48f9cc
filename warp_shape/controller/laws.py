"""Control laws as strategies: from an observation and its own state, the next controls and the cells to jam.

A law has ``phase`` ((W,) int: 1 initial inflation, 2 shape control), ``update_phase(obs, done)``
called once per control step before the step is recorded, and ``step(obs, controls, active)``
returning a ``LawStep`` for the worlds still running (the others keep their controls).
``PaperLaw`` is the paper's law, eqs. (11)-(15), with the gain back-off (see docs/controller.md for
the readings of the paper's ambiguities, e.g. where the jam rule's last curvature starts). ``LAWS``: the laws by name,
each a class with ``name`` and ``summary`` built as ``law(settings, device_constants, passive_ipams, passive_cells)``;
``controller.methods.register_law`` makes a law a control method too.
A law controls the actuator families its ``families`` names (the paper's law: the IPAM);
``hold_neutral`` holds the others at their neutral controls.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..model import HostModel
from .observe import Observation, ipam_neutral_pressures
from .control_settings import LAWS, ControlSettings

__all__ = ["Controls", "LawStep", "PaperLaw", "LAWS", "hold_neutral"]


@dataclass(frozen=True)
class Controls:
    """The actuator commands of every world."""

    air: np.ndarray  # (W,) chamber air amount, mol
    pressures: np.ndarray  # (W, n_ipam) IPAM gauge pressures, Pa


@dataclass(frozen=True)
class LawStep:
    """What a law decided at one control step."""

    controls: Controls
    jam: list = field(default_factory=list)  # (world, cell) pairs to jam now


class PaperLaw:
    """The paper's law (section IV-B): air by eq. (11), IPAM pressures by eq. (12) in phase 2, cells
    jammed by eqs. (13)-(15) the first step their curvature moves away from its target; increments
    rate limited; an error that flips sign without halving backs that gain off (not in the paper).
    Passive IPAMs track their length (no force); passive cells never jam."""

    name = "paper"
    summary = "the paper's law (eqs. 11-15)"
    families = ("ipam",)  # the actuator families it controls; hold_neutral holds the others

    def __init__(self, settings: ControlSettings, host: HostModel, passive_ipams: np.ndarray,
                 passive_cells: np.ndarray):
        W = passive_ipams.shape[0]
        self.settings = settings
        self.host = host
        self.passive_ipams = passive_ipams  # (W, n_ipam) bool
        self.passive_cells = passive_cells  # (W, n_cell) bool
        self.phase = np.ones(W, dtype=np.int64)
        self.gain_air = np.full(W, settings.air_gain)  # backed off per world when the volume oscillates
        self.gain_p = np.full((W, host.n_ipams), settings.pressure_gain)  # per world and IPAM
        self.err_v_prev = np.zeros(W)
        self.err_l_prev = np.zeros((W, host.n_ipams))
        # eqs. (14)-(15)'s last curvature and the IPAM back-off's last length error start at a world's
        # first shape-control step: not carried over from the inflation phase, when neither is controlled
        self.kappa_prev = np.zeros((W, host.n_cells))
        self.shaped = np.zeros(W, dtype=bool)  # (W,) the world has had a shape-control step

    def update_phase(self, obs: Observation, done: np.ndarray) -> np.ndarray:
        """Phase 2 (shape control) starts once the volume is in its deadband; returns ``phase``."""
        vol_ok = obs.volume_within(self.settings.volume_deadband)
        self.phase = np.where((self.phase == 1) & vol_ok & ~done, 2, self.phase)
        return self.phase

    def step(self, obs: Observation, controls: Controls, active: np.ndarray) -> LawStep:
        """The next controls of the ``active`` worlds and the cells to jam now."""
        self._back_off(obs, active)
        shaping = active & (self.phase == 2)
        air = self._air(obs, controls.air, active)
        pressures = self._pressures(obs, controls.pressures, active, shaping)
        jam = self._jams(obs, shaping)
        self.kappa_prev = np.where(shaping[:, None], obs.kappa, self.kappa_prev)
        self.shaped |= shaping
        return LawStep(Controls(air, pressures), jam)

    def _back_off(self, obs: Observation, active: np.ndarray) -> None:
        # eqs. (11)-(12) are deadbeat laws that assume the membrane settles within one control
        # period; when an error flips sign without halving, the loop overshoots, so halve it
        s = self.settings
        err_v = (obs.target_volume - obs.volume) / obs.target_volume
        flip = (err_v * self.err_v_prev < 0) & (np.abs(err_v) > 0.5 * np.abs(self.err_v_prev)) \
            & (np.abs(err_v) > s.volume_deadband)
        self.gain_air = np.where(flip & active, np.maximum(self.gain_air * s.gain_backoff,
                                                           s.min_gain * s.air_gain), self.gain_air)
        self.err_v_prev = err_v
        if self.host.n_ipams:
            err_l = obs.ipam_target_lengths - obs.ipam_lengths
            flip_l = (err_l * self.err_l_prev < 0) & (np.abs(err_l) > 0.5 * np.abs(self.err_l_prev)) \
                & (np.abs(err_l) > s.length_deadband) & self.shaped[:, None]
            self.gain_p = np.where(flip_l & active[:, None], np.maximum(self.gain_p * s.gain_backoff,
                                                                        s.min_gain * s.pressure_gain), self.gain_p)
            self.err_l_prev = err_l

    def _air(self, obs: Observation, air: np.ndarray, active: np.ndarray) -> np.ndarray:
        """Eq. (11), rate limited: dn = (V_t - V) p_abs / (R T)."""
        dn = self.gain_air * (obs.target_volume - obs.volume) * obs.pressure_abs / self.host.gas_rt
        lim = self.settings.air_rate * self.host.rest_air
        return np.where(active, np.maximum(air + np.clip(dn, -lim, lim), 0.0), air)

    def _pressures(self, obs: Observation, pressures: np.ndarray, active: np.ndarray,
                   shaping: np.ndarray) -> np.ndarray:
        """Eq. (12), rate limited and within limits: dP = (k / A) (L_t - L); passive IPAMs neutral."""
        host = self.host
        if not host.n_ipams:
            return pressures
        rate = self.settings.pressure_rate
        dP = self.gain_p * (obs.ipam_target_lengths - obs.ipam_lengths) / host.ipam_area_over_k
        dP = np.clip(dP, -rate, rate)
        newP = np.clip(pressures + dP, host.ipam_limits[:, 0], host.ipam_limits[:, 1])
        pressures = np.where(shaping[:, None], newP, pressures)
        if self.passive_ipams.any():  # natural length follows the length: no force, in every phase
            neutral = ipam_neutral_pressures(obs.ipam_lengths, host)
            pressures = np.where(active[:, None] & self.passive_ipams, neutral, pressures)
        return pressures

    def _jams(self, obs: Observation, shaping: np.ndarray) -> list:
        """Eqs. (13)-(15): a cell jams when its curvature is no longer between its previous value (that of
        the law's last shape-control step) and its target (beyond ``curvature_tolerance``). No cell jams
        at a world's first shape-control step: it has no previous curvature yet."""
        if not (self.host.n_cells and self.settings.jamming):
            return []
        tol = self.settings.curvature_tolerance
        lo = np.minimum(obs.kappa_target, self.kappa_prev) - tol
        hi = np.maximum(obs.kappa_target, self.kappa_prev) + tol
        away = (obs.kappa < lo) | (obs.kappa > hi)
        hit = away & (shaping & self.shaped)[:, None] & ~obs.jammed & ~self.passive_cells
        return [(int(w), int(j)) for w, j in zip(*np.nonzero(hit))]


LAWS.register(PaperLaw)


def hold_neutral(sim, law, host: HostModel, obs: Observation, active: np.ndarray) -> None:
    """Set every actuator family of ``sim`` that ``law`` does not control (its ``families``; the IPAM
    when it names none) to its neutral controls in the ``active`` (W,) worlds (the others keep theirs)."""
    known = getattr(law, "families", ("ipam",))
    for fam in host.actuator_families:
        if fam.name in known or not host.count(fam.name):
            continue
        part = obs.actuators[fam.name]
        neutral = fam.neutral_controls(host.actuators[fam.name], part, part["controls"])
        sim.set_actuator_controls(fam.name, np.where(active[:, None], neutral, part["controls"]))
