"""The design loop (Algorithm 1): control every target, record, place the next actuator set by the
placement strategy ``DesignSettings.placement`` (``designer.placement``)."""

from __future__ import annotations

import numpy as np

from ..controller import ControlSettings, control_many
from ..controller.shard import worker_pool
from ..controller.checks import check_target_units
from ..display import Design
from ..errors import DesignError
from ..material import Material
from ..mesh import TriMesh
from ..sampling import RadialSampler, pcc
from ..simulation_settings import settings_or_default
from .codesign import CodesignRecord, CodesignSettings, codesign
from .initialize import check_cell_room, check_request, check_targets, copy_design, initial_rest_shape
from .placement import Decision, PlacementContext, add_actuator_set, check_record
from .result import DesignResult
from .rounds import DesignRun
from .passive import PassiveSets
from .design_settings import DEFAULT_ACTUATORS, PLACEMENTS, DesignSettings, round_control_settings

__all__ = ["design", "apply_decision"]


def _start_pcc(rest: TriMesh, sampler: RadialSampler, n_targets: int) -> np.ndarray:
    """(n_targets,) PCC of the rest shape's radii against each target's, sampled through its vertices:
    below 0, a target is anti-correlated with the (averaged) rest shape, a bad start."""
    r = np.linalg.norm(rest.vertices, axis=1)
    return np.array([pcc(r, np.linalg.norm(sampler.sample(rest.vertices, j), axis=1)) for j in range(n_targets)])


def _placement_info(settings: DesignSettings, names, start_pcc: np.ndarray) -> dict:
    bad = [n for n, v in zip(names, start_pcc) if v < 0]
    uses = PLACEMENTS[settings.placement].uses_candidates
    return dict(method=settings.placement, candidates=settings.candidates if uses else 1,
                start_pcc=start_pcc.tolist(), bad_start=bad, rounds=[], stopped=None)


def control_round(run: DesignRun, i: int, round_settings: ControlSettings, choose=None) -> list:
    """Round ``i``: the current design controlled to every target (one batch of worlds), the actuators
    each target leaves out passive; recorded, appended to ``run.designs`` and ``run.rounds``.
    ``choose``: what the round records instead of the results (``Placement.before_round``); the results are
    returned."""
    run.designs.append(copy_design(run.current))
    results = control_many(run.current, run.targets, device=run.device, settings=round_settings,
                           progress=run.round_progress(i), passive_ipams=run.passive_sets.passive_ipams(),
                           passive_cells=run.passive_sets.passive_cells(), recorder=run.recorder,
                           recorder_prefix=f"design/round_{i}", target_names=run.names)
    chosen = results if choose is None else choose(results)
    if isinstance(chosen, Decision):  # the round records the placement's choice of results
        if chosen.amend:
            run.added[-1].update(chosen.amend)
        chosen = chosen.results
    run.rounds.append(chosen)
    if run.recorder is not None:
        run.recorder.log_design_round(i, np.array([r.pcc for r in run.rounds[-1]]), run.names, run.designs[-1])
    if run.on_round is not None:
        run.on_round(i, run.designs[-1], run.rounds[-1])
    return results


def _codesign(run: DesignRun) -> dict:
    """Co-design the placed design (``DesignSettings.codesign``); a kept result replaces the last
    round's design and results. Returns the record (``CodesignRecord.as_dict``)."""
    s = run.settings
    if s.codesign == "off":
        return CodesignRecord(mode="off", reason="co-design off").as_dict()
    bound = s.volume_scale * min(t.volume() for t in run.targets) if s.initialize else run.current.rest.volume()
    new, results, record = codesign(run.current, run.targets, run.rounds[-1], mode=s.codesign, volume_bound=bound,
                                    control_settings=run.control_settings,
                                    passive_ipams=run.passive_sets.passive_ipams(),
                                    passive_cells=run.passive_sets.passive_cells(), device=run.device,
                                    settings=CodesignSettings(steps=s.codesign_steps, rounds=s.codesign_rounds,
                                                              move_rest=s.initialize),
                                    target_names=run.names)
    if run.recorder is not None:
        run.recorder.log_codesign(record.as_dict(), run.names)
    if record.kept:
        run.current = new
        run.designs[-1] = copy_design(new)
        run.rounds[-1] = results
    return record.as_dict()


def apply_decision(run: DesignRun, decision: Decision) -> dict | None:
    """Apply a placement's ``decision`` after a round (``designer.placement``): the report entries, how
    the rounds go on, and the set it adds (an IPAM between ``ends``, a cell around each end, left out
    of the ``passive_for`` targets' sequences). Returns the set's record, or None: the round again
    (its design and results are dropped)."""
    run.info.update(decision.info)
    run.info["rounds"].extend(decision.report)
    if decision.round_control is not None:
        run.round_control = decision.round_control
    run.final = run.final or decision.final
    if decision.again:
        run.designs.pop(), run.rounds.pop()
        return None
    new_cells = add_actuator_set(run.current, *decision.ends, run.ctx)
    for t in decision.passive_for:
        run.passive_sets.ipams[t].add(run.current.n_ipams - 1)
        run.passive_sets.cells[t].update(new_cells)
    return decision.record


def _finish(run: DesignRun, placement, i: int) -> None:
    """The placement's ``finish`` and its decision applied: report entries, the holds, and refined
    results replacing the last round's (``on_round`` told again)."""
    decision = placement.finish(run, i)
    if decision is None:
        return
    run.info.update(decision.info)
    if decision.passive_sets is not None:
        run.passive_sets = decision.passive_sets
    if decision.results is not None:
        run.rounds[-1] = decision.results
        if run.on_round is not None:
            run.on_round(i, run.designs[-1], decision.results)


def _rounds(run: DesignRun, placement, actuators: int) -> None:
    """The rounds of Algorithm 1 by ``placement``, each of its decisions applied, then its ``finish``."""
    i = 0
    while True:
        run.final = run.final or i == actuators
        round_settings = (run.control_settings if run.final
                          else round_control_settings(run.control_settings, run.round_control))
        choose = None if run.final else placement.before_round(run, i, round_settings)
        results = control_round(run, i, round_settings, choose)
        if run.final:
            break
        decision = placement.place(run, results, i, round_settings)
        # a plain record: a set the placement added itself
        record = apply_decision(run, decision) if isinstance(decision, Decision) else decision
        if record is None:  # the placement asks for this round again (run.final or run.round_control changed)
            continue
        run.added.append(check_record(placement, record))
        i += 1
    _finish(run, placement, i)


def design(base: TriMesh, targets, actuators: int = DEFAULT_ACTUATORS, *, device: str = "cpu", target_names=None,
           settings: DesignSettings | None = None, control_settings: ControlSettings | None = None,
           material: Material | None = None, progress=None, on_round=None, recorder=None,
           **overrides) -> DesignResult:
    """Design a shape display for ``targets`` with ``actuators`` IPAMs (Algorithm 1). Where each
    round's actuator set goes: ``placement``, a name in ``PLACEMENTS`` ("simulated", the default,
    "paper" or "greedy"; docs/placement.md).

    ``progress(round, n_rounds, step, max_steps, done, worlds)`` is called during control runs;
    ``on_round(i, design_i, results_i)`` after each round (e.g. to write outputs as they finish).
    ``recorder`` logs every round's control runs under ``design/round_<i>`` and the PCC by round
    (``recorder.log_design_round(round, pcc_row, target_names, design)``).
    Keyword overrides go to ``DesignSettings`` (e.g. ``cell_radius=0.016``, ``initialize=False``).
    ``workers`` (``DesignSettings.workers``; 0, the default: every core) shards each batch of control
    jobs over worker processes started once for the run (``controller.shard``; docs/performance.md).
    """
    check_request(base, actuators)
    settings = settings_or_default(settings, DesignSettings, "settings")
    if overrides:
        settings = settings.replace(**overrides)
    control_settings = settings_or_default(control_settings, ControlSettings, "control_settings")
    problem = check_targets(targets, target_names, device)  # the run's problem, built once and passed down
    targets, names, sampler = problem.targets, problem.names, problem.sampler  # the sampler rejects non-star shapes
    check_target_units(base, targets, names, what="base mesh")
    rest = initial_rest_shape(base, problem, settings.volume_scale, device) if settings.initialize else base.centered()
    problem.check_rest(rest, control_settings.max_stretch)
    check_cell_room(rest, actuators, settings.cell_radius)
    ctx = PlacementContext(sampler=sampler, target_volumes=problem.volumes,
                           rest_centroids=rest.face_centroids(), settings=settings, actuators=int(actuators))
    run = DesignRun(current=Design(rest, material), problem=problem, ctx=ctx, settings=settings,
                    control_settings=control_settings, device=device, progress=progress, recorder=recorder,
                    on_round=on_round, passive_sets=PassiveSets(len(targets)), round_control=settings.round_control,
                    info=_placement_info(settings, names, _start_pcc(rest, sampler, len(targets))))
    with worker_pool(settings.workers) as pool:  # the run's worker processes, started once (controller.shard)
        if pool is not None and str(device).startswith("cpu"):
            pool.start(len(targets))  # more join when a batch has more jobs (refinement screens)
        _rounds(run, PLACEMENTS[settings.placement](), actuators)
        record = _codesign(run)
    pcc_rows = np.array([[r.pcc for r in rs] for rs in run.rounds])
    return DesignResult(design=run.current, designs=run.designs, rounds=run.rounds, pcc_by_round=pcc_rows,
                        target_names=names, targets=targets, added=run.added, settings=settings,
                        control_settings=control_settings, passive_ipams=run.passive_sets.passive_ipams(),
                        passive_cells=run.passive_sets.passive_cells(), placement=run.info, codesign=record)
