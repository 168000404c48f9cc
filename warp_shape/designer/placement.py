"""Actuator placement: where a design round puts its new IPAM and the jamming cells around its ends.

A placement is a function ``place(design, results, ctx, round_index) -> (record, new_cells)``: it
adds one IPAM and its cells to ``design`` (in place) given the round's control results (one per
target), and returns what it placed (a JSON-ready dict) and the indices of the new cells.
``paper_placement`` is the paper's rule (Algorithm 1); ``PLACEMENTS``: the placements by name.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..design import Design
from ..errors import DesignError
from ..sampling import RadialSampler
from .settings import DesignSettings

__all__ = ["PlacementContext", "scaled_errors", "free_faces", "paper_ends", "add_actuator_set", "paper_placement",
           "PLACEMENTS"]


@dataclass(frozen=True)
class PlacementContext:
    """What a placement needs besides the design and the round's results."""

    sampler: RadialSampler  # the (centred) targets, one per index
    target_scale: np.ndarray  # (n_targets,) V_t^(1/3), m
    rest_centroids: np.ndarray  # (F, 3) face centroids of the rest shape (cell radii are measured there)
    settings: DesignSettings
    actuators: int  # IPAMs the run places in all


def scaled_errors(results, ctx: PlacementContext) -> tuple[np.ndarray, list]:
    """(n_targets, F) scaled radial error (R - r) / V_t^(1/3) at each achieved face centroid, and the
    (F, 3) achieved face centroids per target."""
    errors, cents = [], []
    for j, r in enumerate(results):
        c = r.achieved.face_centroids()
        R = np.linalg.norm(ctx.sampler.sample(c, j), axis=1)
        errors.append((R - np.linalg.norm(c, axis=1)) / ctx.target_scale[j])
        cents.append(c)
    return np.array(errors), cents


def free_faces(design: Design) -> np.ndarray:
    """(F,) bool: faces in no cell and at no IPAM end."""
    free = design.face_cell() < 0
    ends = {f for ip in design.ipams for f in (ip.face_a, ip.face_b)}
    free[list(ends)] = False
    return free


def paper_ends(errors: np.ndarray, cents: list, free: np.ndarray, min_angle_deg: float, actuator: int,
               actuators: int) -> tuple[int, int, int]:
    """(target, face_a, face_b): face_a the free face with the largest |error| over all targets; face_b
    in that target the free face at least ``min_angle_deg`` away (seen from the origin) with the
    largest error of the same sign (the smallest opposite one where none is left). ``actuator`` (1-based)
    of ``actuators`` names the actuator in errors."""
    if not free.any():
        raise DesignError(f"no free face left for actuator {actuator} of {actuators}: every face is in a cell or "
                          f"an IPAM end; use fewer actuators or a smaller cell_radius")
    masked = np.where(free[None, :], np.abs(errors), -np.inf)
    j_max, f_max = np.unravel_index(int(np.argmax(masked)), masked.shape)
    e_max = errors[j_max, f_max]
    u = cents[j_max] / np.linalg.norm(cents[j_max], axis=1, keepdims=True)
    far = u @ u[f_max] <= math.cos(math.radians(min_angle_deg))
    same = np.sign(errors[j_max]) == np.sign(e_max)
    cand = free & far & same
    if not cand.any():
        cand = free & far  # no same-sign face left: the smallest opposite-sign error hurts least
        if not cand.any():
            raise DesignError(f"no free face at least {min_angle_deg} degrees from face {f_max} for "
                              f"actuator {actuator}; use fewer actuators or a smaller cell_radius")
    score = np.where(cand, errors[j_max] * np.sign(e_max), -np.inf)
    return int(j_max), int(f_max), int(np.argmax(score))


def add_actuator_set(design: Design, face_a: int, face_b: int, ctx: PlacementContext) -> list[int]:
    """Add an IPAM between ``face_a`` and ``face_b`` and a cell around each end (rest-shape faces within
    ``cell_radius`` not yet in a cell); returns the new cells' indices."""
    s = ctx.settings
    design.add_ipam(face_a, face_b, stiffness=s.ipam_stiffness, area=s.ipam_area,
                    pressure_limits=s.ipam_pressure_limits, damping=s.ipam_damping)
    c = ctx.rest_centroids
    new_cells = []
    for end in (face_a, face_b):
        near = np.flatnonzero((np.linalg.norm(c - c[end], axis=1) < s.cell_radius) & (design.face_cell() < 0))
        if near.size:
            new_cells.append(design.add_cell(near))
    return new_cells


def paper_placement(design: Design, results, ctx: PlacementContext, round_index: int) -> tuple[dict, list[int]]:
    """The paper's placement (Algorithm 1): ends by ``paper_ends`` on the scaled radial errors of the
    round's results, then ``add_actuator_set``."""
    errors, cents = scaled_errors(results, ctx)
    j, a, b = paper_ends(errors, cents, free_faces(design), ctx.settings.min_angle_deg, round_index + 1,
                         ctx.actuators)
    new_cells = add_actuator_set(design, a, b, ctx)
    record = dict(round=round_index, target=j, face_a=a, face_b=b, error=float(errors[j, a]),
                  error_b=float(errors[j, b]))
    return record, new_cells


PLACEMENTS = {"paper": paper_placement}
