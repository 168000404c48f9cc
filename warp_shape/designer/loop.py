"""The design loop (Algorithm 1): control every target, select, record, place the next actuator set."""

from __future__ import annotations

import numpy as np

from ..controller import ControlSettings, control_many
from ..controller.checks import check_target_units, check_targets_against_rest
from ..design import Design
from ..material import Material
from ..mesh import TriMesh
from ..sampling import RadialSampler
from .initialize import check_cell_room, check_request, check_targets, copy_design, initial_rest_shape
from .placement import PLACEMENTS, PlacementContext
from .result import DesignResult
from .selection import Selection, objective_selection
from .settings import DesignSettings, round_control_settings

__all__ = ["design"]


def _control_round(i: int, current: Design, targets, names, selection: Selection, new_cells: list,
                   objective: np.ndarray, added: list, settings: DesignSettings, control_settings: ControlSettings, *,
                   device, progress, recorder) -> list:
    """Round ``i``: the current design controlled to every target, then (from round 1) the selection
    of the newest actuator set per target."""
    def ctl_progress(step, total, done, worlds):
        if progress is not None:
            progress(i, len(objective) - 1, step, total, done, worlds)

    results = control_many(current, targets, device=device, settings=control_settings, progress=ctl_progress,
                           passive_ipams=selection.passive_ipams(), passive_cells=selection.passive_cells(),
                           recorder=recorder, recorder_prefix=f"design/round_{i}", target_names=names)
    if i > 0 and settings.select_actuators:
        def rerun(which, passive_ipams, passive_cells):
            # the paper (V-C): an actuator can be held neutral for a target it does not help
            labels = [names[j] if names[j] not in [names[m] for m in which[:k]] else f"{names[j]}_all_sets"
                      for k, j in enumerate(which)]  # a target's second run uses every set
            return control_many(current, [targets[j] for j in which], device=device, settings=control_settings,
                                passive_ipams=passive_ipams, passive_cells=passive_cells, recorder=recorder,
                                recorder_prefix=f"design/round_{i}_selected", target_names=labels)

        left_out, taken_back = objective_selection(results, objective[i - 1], selection, {current.n_ipams - 1},
                                                   set(new_cells), settings.max_rise, rerun)
        for j in left_out:
            added[-1].setdefault("left_out_for", []).append(names[j])
        back = {names[j] for j in taken_back}
        for record in added:  # a target that took every set back uses them all again
            kept = [n for n in record.pop("left_out_for", []) if n not in back]
            if kept:
                record["left_out_for"] = kept
    return results


def design(base: TriMesh, targets, actuators: int = 4, *, device: str = "cpu", target_names=None,
           settings: DesignSettings | None = None, control_settings: ControlSettings | None = None,
           material: Material | None = None, progress=None, on_round=None, recorder=None,
           **overrides) -> DesignResult:
    """Design a shape display for ``targets`` with ``actuators`` IPAMs (Algorithm 1, paper placement).

    ``progress(round, n_rounds, step, max_steps, done, worlds)`` is called during control runs;
    ``on_round(i, design_i, results_i)`` after each round (e.g. to write outputs as they finish).
    ``recorder`` logs every round's control runs under ``design/round_<i>`` and the PCC by round
    (``recorder.log_design_round(round, pcc_row, target_names, design)``).
    Keyword overrides go to ``DesignSettings`` (e.g. ``cell_radius=0.016``, ``initialize=False``).
    """
    check_request(base, actuators)
    settings = settings or DesignSettings()
    if overrides:
        settings = settings.replace(**overrides)
    control_settings = control_settings or ControlSettings()
    targets, names = check_targets(targets, target_names)
    sampler = RadialSampler(targets, device=device)  # rejects non-star-shaped targets with the directions
    check_target_units(base, targets, names, what="base mesh")
    rest = initial_rest_shape(base, targets, settings.volume_scale, device) if settings.initialize else base.centered()
    check_targets_against_rest(rest, targets, sampler, names, max_stretch=control_settings.max_stretch)
    check_cell_room(rest, actuators, settings.cell_radius)
    ctx = PlacementContext(sampler=sampler, target_scale=np.array([t.volume() ** (1.0 / 3.0) for t in targets]),
                           rest_centroids=rest.face_centroids(), settings=settings, actuators=int(actuators))
    current = Design(rest, material)
    designs, rounds, added = [], [], []
    selection = Selection(len(targets))
    new_cells: list[int] = []
    pcc = np.zeros((actuators + 1, len(targets)))
    objective = np.zeros((actuators + 1, len(targets)))
    for i in range(actuators + 1):
        designs.append(copy_design(current))
        round_settings = control_settings if i == actuators else round_control_settings(control_settings,
                                                                                         settings.round_control)
        results = _control_round(i, current, targets, names, selection, new_cells, objective, added, settings,
                                 round_settings, device=device, progress=progress, recorder=recorder)
        rounds.append(results)
        pcc[i] = [r.pcc for r in results]
        objective[i] = [r.objective for r in results]
        if recorder is not None:
            recorder.log_design_round(i, pcc[i].copy(), names, designs[-1])
        if on_round is not None:
            on_round(i, designs[-1], results)
        if i == actuators:
            break
        record, new_cells = PLACEMENTS["paper"](current, results, ctx, i)
        added.append(record)
    return DesignResult(design=current, designs=designs, rounds=rounds, pcc_by_round=pcc, target_names=names,
                        targets=targets, added=added, settings=settings, control_settings=control_settings,
                        passive_ipams=selection.passive_ipams(), passive_cells=selection.passive_cells())
