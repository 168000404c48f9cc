"""One observation of every simulated world per control step: what the control laws and the record see.

An observation holds, per world: the membrane and the target sampled radially through its vertices,
the enclosed and target volumes and the absolute chamber pressure, each IPAM's length, target length
and axial force (and what every other actuator family observes), each cell's curvature and target curvature and jam state, the mean edge stretch, the
largest vertex speed and the fit: the objective (``objectives.radial.fit_objective``: area-weighted RMS of
(R - r) / V_t^(1/3), weights the sampled target's vertex area shares, V_t the target mesh's own
volume), PCC, MARE and MPRE, each by its one implementation in ``sampling``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..model import HostModel
from ..physics.ipam import IPAM
from ..physics.pressure import volumes_np
from ..objectives.radial import fit_metrics
from ..sampling import RadialSampler, vertex_area_shares

__all__ = ["Observation", "Observer", "ipam_lengths_and_forces",
           "ipam_neutral_pressures", "vertex_area_shares", "fit_of"]


def ipam_lengths_and_forces(centroids: np.ndarray, target_centroids: np.ndarray, host: HostModel,
                            pressures: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The IPAM law on the host: (W, n_ipam) length L (distance between the end-face centroids),
    target length L_t (the same on the sampled target) and axial force k (L - L_n), L_n = L0 + (A/k) P
    (N, + = tension). ``centroids``: (W, F, 3) face centroids; ``pressures``: (W, n_ipam) gauge Pa."""
    return IPAM.lengths_and_forces(host.actuators[IPAM.name], centroids, target_centroids, pressures)


def ipam_neutral_pressures(lengths: np.ndarray, host: HostModel) -> np.ndarray:
    """(W, n_ipam) the gauge pressures (within limits) whose natural length is the current length:
    an IPAM held at such a pressure exerts no force."""
    return IPAM.neutral_pressures(host.actuators[IPAM.name], lengths)


@dataclass
class Observation:
    """Every world's state at one control step (``W`` worlds, SI units)."""

    step: int
    time: float  # s
    positions: np.ndarray  # (W, V, 3) m
    sampled: np.ndarray  # (W, V, 3) target hits through the vertices, m
    volume: np.ndarray  # (W,) m^3
    target_volume: np.ndarray  # (W,) volume of the sampled target, m^3
    pressure_abs: np.ndarray  # (W,) absolute chamber pressure, Pa
    ipam_lengths: np.ndarray  # (W, n_ipam) m
    ipam_target_lengths: np.ndarray  # (W, n_ipam) m
    ipam_forces: np.ndarray  # (W, n_ipam) axial, N (+ = tension)
    kappa: np.ndarray  # (W, n_cell) cell curvature, m
    kappa_target: np.ndarray  # (W, n_cell) m
    jammed: np.ndarray  # (W, n_cell) bool
    mean_stretch: np.ndarray  # (W,) mean edge length / rest length
    max_speed: np.ndarray  # (W,) largest vertex speed, m/s
    objective: np.ndarray  # (W,) fit objective (unitless, 0 = perfect fit)
    pcc: np.ndarray  # (W,) eq. (10) on vertex radii
    mare: np.ndarray  # (W,) m
    mpre: np.ndarray  # (W,) %
    # actuator family name -> what it observed ({quantity: (W, n)}, ActuatorFamily.observe) and the
    # controls it was observed at ("controls", (W, n)); the IPAM's quantities are also the fields above
    actuators: dict = field(default_factory=dict)

    def volume_within(self, deadband: float) -> np.ndarray:
        """(W,) bool: |V - V_t| / V_t below ``deadband``."""
        return np.abs(self.volume - self.target_volume) / self.target_volume < deadband


def _curvatures(radii: np.ndarray, host: HostModel) -> np.ndarray:
    """(W, n_cell) kappa = r_anchor - mean r over the cell's faces (eq. 13), from (W, F) face radii."""
    if not host.n_cells:
        return np.zeros((radii.shape[0], 0))
    return np.stack([radii[:, host.cell_anchors[j]] - radii[:, host.cell_faces[j]].mean(axis=1)
                     for j in range(host.n_cells)], 1)


def fit_of(positions: np.ndarray, sampled: np.ndarray, faces: np.ndarray, target_volumes: np.ndarray) -> dict:
    """Per world the fit of (W, V, 3) membrane ``positions`` to the ``sampled`` target (hits through the
    same vertices): ``objective`` (weights: the sampled target's vertex area shares; V_t:
    ``target_volumes`` (W,), the target meshes' own volumes), ``pcc``, ``mare`` (m), ``mpre`` (%), each
    a (W,) array."""
    r, R = np.linalg.norm(positions, axis=2), np.linalg.norm(sampled, axis=2)
    return fit_metrics(r, R, target_volumes, vertex_area_shares(sampled, faces))


class Observer:
    """Takes one observation of every world of a simulator (one target per world; ``target_volumes``:
    (W,) each world's target mesh volume, m^3, the scale of the objective)."""

    def __init__(self, host: HostModel, sampler: RadialSampler, worlds: int, target_volumes):
        self.host = host
        self.sampler = sampler
        self.world_index = np.arange(worlds)
        self.target_volumes = np.asarray(target_volumes, dtype=np.float64).reshape(worlds)  # m^3, per world

    def observe(self, sim, step: int, air: np.ndarray, pressures: np.ndarray) -> Observation:
        """The state of every world of ``sim`` now; ``air`` (W,) mol and ``pressures`` (W, n_ipam) Pa
        are the controls in force (the other actuator families' are read from ``sim``)."""
        host, W = self.host, len(self.world_index)
        x = np.asarray(sim.positions, dtype=np.float64).reshape(W, -1, 3)
        sampled = self.sampler.sample_worlds(x, self.world_index)
        vol = volumes_np(x, host.faces)
        vol_t = volumes_np(sampled, host.faces)
        cen = x[:, host.faces].mean(axis=2)  # (W, F, 3)
        cen_t = sampled[:, host.faces].mean(axis=2)
        parts = {}
        for fam in host.actuator_families:
            controls = pressures if fam is IPAM else \
                np.asarray(sim.actuator_controls(fam.name)).reshape(W, host.count(fam.name))
            parts[fam.name] = dict(fam.observe(host, x, sampled, cen, cen_t, controls), controls=controls)
        ipam = parts[IPAM.name]
        stretch = np.linalg.norm(x[:, host.hinges[:, 1]] - x[:, host.hinges[:, 0]], axis=2) / host.rest_length
        v = np.asarray(sim.velocities, dtype=np.float64).reshape(W, -1, 3)
        fit = fit_of(x, sampled, host.faces, self.target_volumes)
        return Observation(
            step=step, time=sim.time, positions=x, sampled=sampled, volume=vol, target_volume=vol_t,
            pressure_abs=air * host.gas_rt / vol, ipam_lengths=ipam["lengths"],
            ipam_target_lengths=ipam["target_lengths"], ipam_forces=ipam["forces"], kappa=_curvatures(np.linalg.norm(cen, axis=2), host),
            kappa_target=_curvatures(np.linalg.norm(cen_t, axis=2), host),
            jammed=np.asarray(sim.jammed).reshape(W, host.n_cells),
            mean_stretch=stretch.mean(axis=1), max_speed=np.linalg.norm(v, axis=2).max(axis=1),
            actuators=parts, **fit)
