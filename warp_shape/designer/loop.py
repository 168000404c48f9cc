"""The design loop (Algorithm 1): control every target, record, place the next actuator set (the
paper's rule, with per-target holds and refinement rounds, or greedy candidate sets,
``DesignSettings.placement``)."""

from __future__ import annotations

import numpy as np

from ..controller import ControlSettings, control_many
from ..controller.checks import check_target_units, check_targets_against_rest, target_labels
from ..design import Design
from ..material import Material
from ..mesh import TriMesh
from ..sampling import RadialSampler, pcc
from ..settings import settings_or_default
from .initialize import check_cell_room, check_request, check_targets, copy_design, initial_rest_shape
from .placement import PLACEMENTS, PlacementContext
from .refine import ipam_cells, refine_holds
from .result import DesignResult
from .selection import Selection
from .greedy import greedy_placement
from .settings import DesignSettings, round_control_settings

__all__ = ["design"]


def _start_pcc(rest: TriMesh, sampler: RadialSampler, n_targets: int) -> np.ndarray:
    """(n_targets,) PCC of the rest shape's radii against each target's, sampled through its vertices:
    below 0, a target is anti-correlated with the (averaged) rest shape, a bad start."""
    r = np.linalg.norm(rest.vertices, axis=1)
    return np.array([pcc(r, np.linalg.norm(sampler.sample(rest.vertices, j), axis=1)) for j in range(n_targets)])


def _placement_info(settings: DesignSettings, names, start_pcc: np.ndarray) -> dict:
    bad = [n for n, v in zip(names, start_pcc) if v < 0]
    return dict(method=settings.placement, candidates=settings.candidates if settings.placement != "paper" else 1,
                start_pcc=start_pcc.tolist(), bad_start=bad, rounds=[], stopped=None)


def _round_progress(progress, i: int, rounds_total: int):
    def ctl_progress(step, total, done, worlds):
        if progress is not None:
            progress(i, rounds_total, step, total, done, worlds)
    return ctl_progress


def _control_round(i: int, current: Design, targets, names, selection: Selection, round_settings, designs: list,
                   rounds: list, *, device, progress, recorder, on_round, rounds_total: int, hold=None) -> list:
    """Round ``i``: the current design controlled to every target (one batch of worlds), the actuators
    each target leaves out held neutral; recorded, appended to ``designs`` and ``rounds``. ``hold``:
    what the round records instead of the results (``_hold_last_set``); the results are returned."""
    designs.append(copy_design(current))
    results = control_many(current, targets, device=device, settings=round_settings,
                           progress=_round_progress(progress, i, rounds_total),
                           passive_ipams=selection.passive_ipams(), passive_cells=selection.passive_cells(),
                           recorder=recorder, recorder_prefix=f"design/round_{i}", target_names=names)
    rounds.append(results if hold is None else hold(results))
    if recorder is not None:
        recorder.log_design_round(i, np.array([r.pcc for r in rounds[-1]]), names, designs[-1])
    if on_round is not None:
        on_round(i, designs[-1], rounds[-1])
    return results


def _hold_last_set(current: Design, targets, names, held: Selection, round_settings, *, device, progress):
    """Simulated placement, a round before the last: each target also controlled with the newest
    actuator set held neutral on top of what it held before (its previous round's fit), and the better
    of the two recorded, so that no round makes a target worse while the sets themselves stay
    Algorithm 1's (placed on the errors with every actuator in use). Returns ``hold(results)`` for
    ``_control_round``; it records in ``held`` what each target holds (the newest IPAM among them
    where the held run was kept)."""
    new = current.n_ipams - 1
    cells = set(ipam_cells(current, new))

    def hold(results):
        pi = [sorted(held.ipams[t] | {new}) for t in range(len(targets))]
        pc = [sorted(held.cells[t] | cells) for t in range(len(targets))]
        runs = control_many(current, targets, device=device, settings=round_settings, progress=progress,
                            passive_ipams=pi, passive_cells=pc, target_names=names)
        out = []
        for t, (r_all, r_held) in enumerate(zip(results, runs)):
            keep = r_held.objective < r_all.objective
            held.ipams[t], held.cells[t] = (set(pi[t]), set(pc[t])) if keep else (set(), set())
            out.append(r_held if keep else r_all)
        return out
    return hold


def _refine_last_round(i: int, current: Design, designs: list, rounds: list, selection: Selection, held: Selection,
                       added: list, info: dict, *, targets, names, settings, control_settings, device, progress,
                       recorder, on_round) -> None:
    """Simulated placement: the refinement rounds (``designer.refine``) after the last round; a
    target's refined result replaces its last-round result (``on_round`` is told again)."""
    info["paper_objective"] = [r.objective for r in rounds[-1]]  # every actuator in use: Algorithm 1's fit
    refined, info["refinement"], info["refinement_stopped"] = refine_holds(
        current, rounds[-1], selection, list(zip(held.passive_ipams(), held.passive_cells())),
        [a["target"] for a in added], targets=targets, names=names, settings=settings,
        control_settings=control_settings, device=device, progress=progress, recorder=recorder)
    if any(a is not b for a, b in zip(refined, rounds[-1])):
        rounds[-1] = refined
        if on_round is not None:
            on_round(i, designs[-1], refined)


ESCALATED = ("no candidate helped under the paper's law, which can hide what an actuator does (a cube corner "
             "IPAM alone); this round and those after it are controlled by model-based control (round_control 'quick')")


def _escalates(round_control: str, control_settings: ControlSettings) -> bool:
    """Whether a greedy round that found no gain under the paper's law is tried again by model-based
    control: the rounds were controlled by the paper's law and the design is controlled model-based."""
    return round_control == "paper" and control_settings.method == "inverse"


def design(base: TriMesh, targets, actuators: int = 4, *, device: str = "cpu", target_names=None,
           settings: DesignSettings | None = None, control_settings: ControlSettings | None = None,
           material: Material | None = None, progress=None, on_round=None, recorder=None,
           **overrides) -> DesignResult:
    """Design a shape display for ``targets`` with ``actuators`` IPAMs (Algorithm 1). Where each
    round's actuator set goes: ``placement``: "simulated" (the default: Algorithm 1's sets, each
    target holding neutral what does not help it, refinement rounds after the last; never worse than
    "paper" on any target), "paper" (Algorithm 1 as published) or "greedy" (the best of
    ``candidates`` sets per round by summed objective); see ``designer`` and docs/placement.md.

    ``progress(round, n_rounds, step, max_steps, done, worlds)`` is called during control runs;
    ``on_round(i, design_i, results_i)`` after each round (e.g. to write outputs as they finish).
    ``recorder`` logs every round's control runs under ``design/round_<i>`` and the PCC by round
    (``recorder.log_design_round(round, pcc_row, target_names, design)``).
    Keyword overrides go to ``DesignSettings`` (e.g. ``cell_radius=0.016``, ``initialize=False``).
    """
    check_request(base, actuators)
    settings = settings_or_default(settings, DesignSettings, "settings")
    if overrides:
        settings = settings.replace(**overrides)
    control_settings = settings_or_default(control_settings, ControlSettings, "control_settings")
    targets, names = check_targets(targets, target_names)
    sampler = RadialSampler(targets, device=device, names=target_labels(targets, names))  # rejects non-star shapes
    check_target_units(base, targets, names, what="base mesh")
    rest = initial_rest_shape(base, targets, settings.volume_scale, device) if settings.initialize else base.centered()
    check_targets_against_rest(rest, targets, sampler, names, max_stretch=control_settings.max_stretch)
    check_cell_room(rest, actuators, settings.cell_radius)
    ctx = PlacementContext(sampler=sampler, target_scale=np.array([t.volume() ** (1.0 / 3.0) for t in targets]),
                           rest_centroids=rest.face_centroids(), settings=settings, actuators=int(actuators))
    current = Design(rest, material)
    designs, rounds, added = [], [], []
    selection = Selection(len(targets))
    info = _placement_info(settings, names, _start_pcc(rest, sampler, len(targets)))
    held = Selection(len(targets))  # simulated: what each target holds neutral in the construction rounds
    greedy = settings.placement == "greedy"
    i, final, round_control = 0, False, settings.round_control
    while True:
        final = final or i == actuators
        round_settings = control_settings if final else round_control_settings(control_settings, round_control)
        hold = None
        if settings.placement == "simulated" and 0 < i and not final:
            hold = _hold_last_set(current, targets, names, held, round_settings, device=device,
                                  progress=_round_progress(progress, i, actuators))
        results = _control_round(i, current, targets, names, selection, round_settings, designs, rounds, device=device,
                                 progress=progress, recorder=recorder, on_round=on_round, rounds_total=actuators,
                                 hold=hold)
        if hold is not None:
            added[-1]["held_for"] = [names[t] for t in range(len(targets)) if current.n_ipams - 1 in held.ipams[t]]
        if final:
            break
        if not greedy:
            record, _ = PLACEMENTS["paper"](current, results, ctx, i)
        else:
            record = greedy_placement(current, results, ctx, i, selection, targets=targets, names=names,
                                         control_settings=round_settings, device=device,
                                         progress=_round_progress(progress, i, actuators), recorder=recorder)
            info["rounds"].append(record)
            if recorder is not None:
                recorder.log_design_candidates(i, record)
            if record["chosen"] is None:  # nothing helps: this round again, by model-based control or as the last
                designs.pop(), rounds.pop()
                if _escalates(round_control, control_settings):
                    round_control = "quick"
                    record["escalated"] = ESCALATED
                    info["escalated_at"] = i
                else:
                    info["stopped"] = record["stopped"]
                    final = True
                continue
        added.append(record)
        i += 1
    if settings.placement == "simulated" and settings.refine_rounds > 0 and current.n_ipams > 0:
        _refine_last_round(i, current, designs, rounds, selection, held, added, info, targets=targets, names=names,
                           settings=settings, control_settings=control_settings, device=device,
                           progress=_round_progress(progress, i, actuators), recorder=recorder, on_round=on_round)
    pcc_rows = np.array([[r.pcc for r in rs] for rs in rounds])
    return DesignResult(design=current, designs=designs, rounds=rounds, pcc_by_round=pcc_rows, target_names=names,
                        targets=targets, added=added, settings=settings, control_settings=control_settings,
                        passive_ipams=selection.passive_ipams(), passive_cells=selection.passive_cells(),
                        placement=info)
