"""``placement="greedy"``: each round, K candidate actuator sets controlled to every target in one
batch of worlds of one union model (per-world masks); the set that lowers the summed fit objective
most is kept and passive for the targets it does not help; the design stops early when none
gains more than ``min_gain``. It trades targets off. docs/placement.md describes and measures it."""

from __future__ import annotations

import numpy as np

from ..controller import CONTROL_METHODS, control_many
from ..controller.problem import take
from ..display import Design
from .initialize import copy_design
from .placement import (Decision, Placement, PlacementContext, add_actuator_set, candidate_ends, end_angle_deg,
                        free_faces, planned_cells, register_placement, scaled_errors)
from .passive import PassiveSets

__all__ = ["candidate_worlds", "greedy_placement", "GreedyPlacement", "ESCALATED"]


def candidate_worlds(base: Design, ends: list, ctx: PlacementContext) -> tuple[Design, list[int], list[list[int]]]:
    """The union design (``base`` plus every candidate's IPAM and cells, cells around each end among
    the faces in no cell of ``base``), the candidates' IPAM indices and their cell indices."""
    union = copy_design(base)
    taken = base.face_cell() >= 0
    ipams, cells = [], []
    for _, a, b in ends:
        cells.append(add_actuator_set(union, a, b, ctx, taken=taken))
        ipams.append(union.n_ipams - 1)
    return union, ipams, cells


def _passive(passive_sets: PassiveSets, k: int, j: int, ipams: list, cells: list) -> tuple[list, list]:
    """World (k, j): what target j leaves out plus every candidate but k."""
    pi = set(passive_sets.ipams[j]) | {ipams[m] for m in range(len(ipams)) if m != k}
    pc = set(passive_sets.cells[j]) | {c for m in range(len(cells)) if m != k for c in cells[m]}
    return sorted(pi), sorted(pc)


def greedy_placement(current: Design, results, ctx: PlacementContext, round_index: int, passive_sets: PassiveSets, *,
                     targets, names, control_settings, device, progress=None, recorder=None) -> tuple[dict, list]:
    """Round ``round_index`` of the greedy placement (module docstring); ``current`` and ``passive_sets``
    are left as they are. Returns the round's record: every candidate's ends, per-target objectives and
    score, the one kept (``chosen``, None when the round stopped the design), the cells it adds
    (``new_cells``) and the targets that leave it out (``passive_for``, names; ``left_out``, indices)."""
    T = len(results)
    errors, _ = scaled_errors(results, ctx)
    ends = candidate_ends(errors, free_faces(current), ctx, ctx.settings.candidates, round_index + 1)
    union, ipams, cells = candidate_worlds(current, ends, ctx)
    K = len(ends)
    passive = [_passive(passive_sets, k, j, ipams, cells) for k in range(K) for j in range(T)]
    runs = control_many(union, take(targets, [j for _ in range(K) for j in range(T)]), device=device,
                        settings=control_settings, progress=progress, recorder=recorder,
                        passive_ipams=[p for p, _ in passive], passive_cells=[c for _, c in passive],
                        recorder_prefix=f"design/round_{round_index}_candidates",
                        target_names=[f"{names[j]}_candidate{k}" for k in range(K) for j in range(T)])
    obj = np.array([r.objective for r in runs]).reshape(K, T)
    prev = np.array([r.objective for r in results])
    score = np.minimum(obj, prev[None, :]).sum(axis=1)
    gain = (prev.sum() - score) / prev.sum()
    best = int(np.argmin(score))
    record = dict(round=round_index, method="greedy", candidates=[
        dict(target=j, face_a=a, face_b=b, error=float(errors[j, a]), error_b=float(errors[j, b]),
             rest_angle_deg=end_angle_deg(ctx, a, b), objective=obj[k].tolist(),
             mare_m=[runs[k * T + t].mare for t in range(T)], pcc=[runs[k * T + t].pcc for t in range(T)],
             score=float(score[k]), gain=float(gain[k])) for k, (j, a, b) in enumerate(ends)],
        previous_objective=prev.tolist(), previous_score=float(prev.sum()), worlds=K * T)
    if gain[best] <= ctx.settings.min_gain:
        record.update(chosen=None, stopped=(
            f"no candidate lowers the summed objective by more than {100 * ctx.settings.min_gain:g} % "
            f"(best {100 * gain[best]:.3g} %): the design stops with {current.n_ipams} IPAMs"))
        return record, []
    j, a, b = ends[best]
    left_out = [t for t in range(T) if obj[best, t] >= prev[t]]
    record.update(chosen=best, target=j, face_a=a, face_b=b, error=float(errors[j, a]),
                  error_b=float(errors[j, b]), rest_angle_deg=end_angle_deg(ctx, a, b),
                  new_cells=planned_cells(current, a, b, ctx), passive_for=[names[t] for t in left_out])
    return record, left_out


ESCALATED = ("no candidate helped under the paper's law, which can hide what an actuator does (a cube corner "
             "IPAM alone); this round and those after it are controlled by model-based control (round_control 'quick')")


class GreedyPlacement(Placement):
    """The best of ``candidates`` sets per round by summed objective (module docstring); a round whose
    candidates all fail under the paper's law is run again by model-based control, once; a round that
    still finds none is the last."""

    name = "greedy"
    summary = "the best of K candidate sets per round by summed objective (trades targets off)"
    uses_candidates = True

    def place(self, run, results, i, round_settings):
        record, left_out = greedy_placement(run.current, results, run.ctx, i, run.passive_sets, targets=run.targets,
                                            names=run.names, control_settings=round_settings, device=run.device,
                                            progress=run.round_progress(i), recorder=run.recorder)
        if run.recorder is not None:
            run.recorder.log_design_candidates(i, record)
        if record["chosen"] is not None:
            decision = Decision(ends=(record["face_a"], record["face_b"]), record=record, passive_for=tuple(left_out),
                                report=(record,))
        elif run.round_control == "law" and CONTROL_METHODS[run.control_settings.method].refines:
            # nothing helps: this round again, by model-based control
            record["escalated"] = ESCALATED
            decision = Decision(again=True, round_control="quick", info=dict(escalated_at=i), report=(record,))
        else:  # nothing helps: this round again, as the last
            decision = Decision(again=True, final=True, info=dict(stopped=record["stopped"]), report=(record,))
        return decision

    @classmethod
    def describe(cls, info):
        return (f", K = {info.get('candidates')} candidate sets per round (each controlled to every target in one "
                "batch of worlds)")


register_placement(GreedyPlacement)
