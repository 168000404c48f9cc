"""Actuator placement: placements as strategies, and the paper's rule.

A placement (a class in ``PLACEMENTS``, built once per design run) decides where each round's
actuator set goes; it reads the run and returns a ``Decision`` (what to add, where, why), which
the design loop (``designer.loop.apply_decision``) applies: a placement never changes the run. The loop
calls, for every round ``i``:
- ``before_round(run, i, round_settings)`` before a round that is not the last: None, or a function of the
  round's results returning a ``Decision`` whose ``results`` the round records instead (e.g. the better
  of two runs per target; ``amend``: entries for the record of the set placed last);
- ``place(run, results, i, round_settings)`` after a round that is not the last: a ``Decision`` whose
  ``ends`` are the faces of the IPAM to add (cells around both ends) and whose ``record`` says why (a
  JSON-ready dict with at least ``RECORD_KEYS``: the round, the target it was placed for, its end
  faces and the scaled error at ``face_a``), or one with ``again`` to run the round again (with
  ``final`` or ``round_control`` to change how); a plain record dict is read as a set the placement
  added to ``run.current`` itself;
- ``finish(run, i)`` once after the last round: None or a ``Decision`` (``results``: the last round's
  refined results, ``passive_sets``: the per-target holds they were controlled with);
and the report calls ``describe(info)`` for its sentence on the method. ``summary`` is the one-line
help of ``--placement``; ``uses_candidates`` says whether ``DesignSettings.candidates`` means
anything to it. ``run`` is a ``designer.rounds.DesignRun``. Built in: ``PaperPlacement`` (here),
``PerTargetPlacement`` (``designer.per_target``), ``GreedyPlacement`` (``designer.greedy``);
``register_placement`` adds one.

``paper_placement`` is the paper's rule (Algorithm 1: the largest scaled error, the other end by the
120-degree rule measured on the rest shape, cells around both ends); ``candidate_ends`` proposes the
candidate sets the greedy placement tries.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..display import Design
from ..errors import DesignError
from ..objectives.radial import SCALED_RADIAL
from ..sampling import RadialSampler
from .design_settings import PLACEMENTS, DesignSettings

__all__ = ["Decision", "planned_cells", "PlacementContext", "scaled_errors", "free_faces", "rest_directions", "other_end", "paper_ends",
           "cell_faces", "add_actuator_set", "paper_placement", "end_angle_deg", "candidate_ends", "PLACEMENTS",
           "Placement", "PaperPlacement", "register_placement", "RECORD_KEYS", "check_record"]

#: what every placement's record of an added set holds (the report and rounds.json read them)
RECORD_KEYS = ("round", "target", "face_a", "face_b", "error")


@dataclass(frozen=True)
class Decision:
    """What a placement decided (module docstring); ``designer.loop.apply_decision`` applies it."""

    ends: tuple | None = None  # (face_a, face_b): add an IPAM between them with a cell around each end
    record: dict | None = None  # why: the record of the set added (``RECORD_KEYS``), appended to run.added
    passive_for: tuple = ()  # the targets (indices) whose sequences leave the new set out
    again: bool = False  # nothing placed: run this round again
    final: bool = False  # the next round is the last
    round_control: str | None = None  # how the rounds before the last are controlled from now
    info: dict = field(default_factory=dict)  # entries of the placement report (``run.info``) to set
    report: tuple = ()  # records appended to ``run.info["rounds"]``
    results: list | None = None  # what the round records instead of its results
    amend: dict = field(default_factory=dict)  # entries for the record of the set placed last
    passive_sets: object = None  # the per-target holds from now (a ``PassiveSets``)


@dataclass(frozen=True)
class PlacementContext:
    """What a placement needs besides the design and the round's results."""

    sampler: RadialSampler  # the (centred) targets, one per index
    target_volumes: np.ndarray  # (n_targets,) V_t, m^3
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
        errors.append(SCALED_RADIAL.errors(np.linalg.norm(c, axis=1), R, ctx.target_volumes[j]))
        cents.append(c)
    return np.array(errors), cents


def free_faces(design: Design) -> np.ndarray:
    """(F,) bool: faces in no cell and at no IPAM end."""
    free = design.face_cell() < 0
    ends = {f for ip in design.ipams for f in (ip.face_a, ip.face_b)}
    free[list(ends)] = False
    return free


def rest_directions(ctx: PlacementContext) -> np.ndarray:
    """(F, 3) unit directions of the rest shape's face centroids (the 120-degree rule is measured here)."""
    c = ctx.rest_centroids
    return c / np.linalg.norm(c, axis=1, keepdims=True)


def other_end(errors_j: np.ndarray, free: np.ndarray, u_rest: np.ndarray, a: int, min_angle_deg: float,
              actuator: int) -> int:
    """The free face at least ``min_angle_deg`` from face ``a`` in the rest shape (seen from the
    origin) with the largest error of the sign of ``errors_j[a]`` (the smallest opposite one where
    none is left)."""
    far = u_rest @ u_rest[a] <= math.cos(math.radians(min_angle_deg))
    cand = free & far & (np.sign(errors_j) == np.sign(errors_j[a]))
    if not cand.any():
        cand = free & far  # no same-sign face left: the smallest opposite-sign error hurts least
        if not cand.any():
            raise DesignError(f"no free face at least {min_angle_deg} degrees from face {a} for "
                              f"actuator {actuator}; use fewer actuators or a smaller cell_radius")
    return int(np.argmax(np.where(cand, errors_j * np.sign(errors_j[a]), -np.inf)))


def _check_free(free: np.ndarray, actuator: int, actuators: int) -> None:
    if not free.any():
        raise DesignError(f"no free face left for actuator {actuator} of {actuators}: every face is in a cell or "
                          f"an IPAM end; use fewer actuators or a smaller cell_radius")


def paper_ends(errors: np.ndarray, free: np.ndarray, u_rest: np.ndarray, min_angle_deg: float, actuator: int,
               actuators: int) -> tuple[int, int, int]:
    """(target, face_a, face_b): face_a the free face with the largest |error| over all targets; face_b
    in that target by ``other_end`` (the 120-degree rule on the rest shape, ``u_rest``). ``actuator``
    (1-based) of ``actuators`` names the actuator in errors."""
    _check_free(free, actuator, actuators)
    masked = np.where(free[None, :], np.abs(errors), -np.inf)
    j_max, f_max = np.unravel_index(int(np.argmax(masked)), masked.shape)
    return int(j_max), int(f_max), other_end(errors[j_max], free, u_rest, int(f_max), min_angle_deg, actuator)


def cell_faces(taken: np.ndarray, end: int, ctx: PlacementContext) -> np.ndarray:
    """Faces whose rest centroids lie within ``cell_radius`` of face ``end``'s and are not ``taken``."""
    c = ctx.rest_centroids
    return np.flatnonzero((np.linalg.norm(c - c[end], axis=1) < ctx.settings.cell_radius) & ~taken)


def planned_cells(design: Design, face_a: int, face_b: int, ctx: PlacementContext) -> list[int]:
    """The indices of the cells ``add_actuator_set(design, face_a, face_b, ctx)`` would add, ``design``
    left as it is."""
    taken = design.face_cell() >= 0
    out = []
    for end in (face_a, face_b):
        near = cell_faces(taken, end, ctx)
        if near.size:
            out.append(design.n_cells + len(out))
            taken[near] = True
    return out


def add_actuator_set(design: Design, face_a: int, face_b: int, ctx: PlacementContext,
                     taken: np.ndarray | None = None) -> list[int]:
    """Add an IPAM between ``face_a`` and ``face_b`` and a cell around each end (rest-shape faces within
    ``cell_radius`` not yet in a cell); returns the new cells' indices. ``taken``: (F,) bool faces no
    new cell may use (default: those in a cell of ``design``); given, the cells may share faces with
    cells of ``design`` (a model of alternative candidate sets)."""
    s = ctx.settings
    design.add_ipam(face_a, face_b, stiffness=s.ipam_stiffness, area=s.ipam_area,
                    pressure_limits=s.ipam_pressure_limits, damping=s.ipam_damping)
    shared = taken is not None
    new_cells = []
    for end in (face_a, face_b):
        near = cell_faces(design.face_cell() >= 0 if taken is None else taken, end, ctx)
        if near.size:
            new_cells.append(design.add_cell(near, shared=shared))
    return new_cells


def paper_placement(design: Design, results, ctx: PlacementContext, round_index: int) -> Decision:
    """The paper's placement (Algorithm 1): ends by ``paper_ends`` on the scaled radial errors of the
    round's results, the set to add there (``add_actuator_set``) and its record; ``design`` unchanged."""
    errors, _ = scaled_errors(results, ctx)
    j, a, b = paper_ends(errors, free_faces(design), rest_directions(ctx), ctx.settings.min_angle_deg,
                         round_index + 1, ctx.actuators)
    record = dict(round=round_index, target=j, face_a=a, face_b=b, error=float(errors[j, a]),
                  error_b=float(errors[j, b]), rest_angle_deg=end_angle_deg(ctx, a, b))
    return Decision(ends=(a, b), record=record)


def end_angle_deg(ctx: PlacementContext, a: int, b: int) -> float:
    """Angle between faces ``a`` and ``b`` of the rest shape seen from the origin, degrees."""
    u = rest_directions(ctx)
    return float(np.degrees(np.arccos(np.clip(u[a] @ u[b], -1.0, 1.0))))


def candidate_ends(errors: np.ndarray, free: np.ndarray, ctx: PlacementContext, count: int,
                   actuator: int) -> list[tuple[int, int, int]]:
    """Up to ``count`` distinct candidate (target, face_a, face_b): first ends taken in turn from every
    target's free faces by decreasing |error| (targets in order of their largest |error|; a face
    within two cell radii (rest shape) of a first end already taken is skipped, so candidates differ),
    the other end by ``other_end``. The first candidate is the paper's choice."""
    _check_free(free, actuator, ctx.actuators)
    u, c = rest_directions(ctx), ctx.rest_centroids
    masked = np.where(free[None, :], np.abs(errors), -np.inf)
    order_t = np.argsort(-masked.max(axis=1), kind="stable")
    queues = {int(j): [int(f) for f in np.argsort(-masked[j], kind="stable") if free[f]] for j in order_t}
    firsts: list[tuple[int, int]] = []
    out, seen = [], set()
    while len(out) < count and any(queues.values()):
        for j in order_t:
            q = queues[int(j)]
            while q and any(np.linalg.norm(c[q[0]] - c[f]) < 2 * ctx.settings.cell_radius for _, f in firsts):
                q.pop(0)
            if not q or len(out) >= count:
                continue
            a = q.pop(0)
            firsts.append((int(j), a))
            b = other_end(errors[j], free, u, a, ctx.settings.min_angle_deg, actuator)
            if frozenset((a, b)) not in seen:  # the same pair reached from its other end
                seen.add(frozenset((a, b)))
                out.append((int(j), a, b))
    return out


class Placement:
    """The base of the placement strategies (module docstring): no holds, nothing after the last round."""

    name = ""
    summary = ""
    uses_candidates = False

    def before_round(self, run: DesignRun, i: int, round_settings: ControlSettings):
        return None

    def place(self, run: DesignRun, results: list, i: int, round_settings: ControlSettings) -> Decision:
        raise NotImplementedError

    def finish(self, run: DesignRun, i: int) -> Decision | None:
        return None

    @classmethod
    def describe(cls, info: dict) -> str:
        return ""


class PaperPlacement(Placement):
    """Algorithm 1 as published: ``paper_placement`` every round; every target uses every actuator."""

    name = "paper"
    summary = "Algorithm 1 as published (every target uses every actuator)"

    def place(self, run, results, i, round_settings):
        return paper_placement(run.current, results, run.ctx, i)

    @classmethod
    def describe(cls, info):
        return " (Algorithm 1 as published: every target uses every actuator)"


def check_record(placement: Placement, record) -> dict:
    """``record`` if it is a dict with every ``RECORD_KEYS`` entry, else an error naming the placement."""
    missing = [k for k in RECORD_KEYS if k not in record] if isinstance(record, dict) else list(RECORD_KEYS)
    if missing:
        raise DesignError(f"placement {placement.name!r} returned a record without {missing}; a placement's place() "
                          f"returns a dict with {list(RECORD_KEYS)} (or None to run the round again)")
    return record


def register_placement(placement, *, replace: bool = False):
    """Make ``placement`` (a ``Placement`` subclass, see the module docstring) selectable as
    ``DesignSettings.placement``, in ``ws.design`` and ``warp-shape design --placement``; returns it."""
    if not (isinstance(placement, type) and issubclass(placement, Placement)):
        raise DesignError(f"a placement is a subclass of warp_shape.designer.Placement, got {placement!r}")
    return PLACEMENTS.register(placement, replace=replace)


register_placement(PaperPlacement)
