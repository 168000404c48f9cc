"""``placement="simulated"``: Algorithm 1's actuator sets, each passive (neutral) for the
targets it does not help, then refinement rounds: per target, candidate passive sets screened in one
batch of worlds per jam plan (the first ``screen_first`` of each target, those it has not screened in
vain in an earlier round first, then the rest only for the targets whose first ones gained more than
``min_gain``) and verified by the design's controller (``refine_passive``). Targets do
not trade, so no target ends worse than under Algorithm 1. docs/placement.md describes and measures
it."""

from __future__ import annotations

from dataclasses import dataclass

from ..controller import control_many, screen_many
from ..controller.problem import take
from ..display import Design
from .placement import Decision, PaperPlacement, register_placement
from .passive import PassiveSets

__all__ = ["PerTargetPlacement", "PassiveCandidate", "ipam_cells", "refine_passive"]


def ipam_cells(design: Design, i: int) -> list[int]:
    """The cells around IPAM ``i``'s ends (those holding either end face)."""
    ip = design.ipams[i]
    return [c for c, cell in enumerate(design.cells) if ip.face_a in cell.faces or ip.face_b in cell.faces]


@dataclass(frozen=True)
class PassiveCandidate:
    """What a target leaves out of its sequence on top of what it already leaves out."""

    ipams: frozenset = frozenset()
    cells: frozenset = frozenset()

    def as_record(self) -> dict:
        """``{"ipams": [IPAMs], "cells": [cells]}``, as the refinement records name a candidate."""
        return dict(ipams=sorted(self.ipams), cells=sorted(self.cells))

    def label(self) -> str:
        return "+".join([f"ipam{i}" for i in sorted(self.ipams)] + [f"cell{c}" for c in sorted(self.cells)]) or "none"


def _candidates_for(design: Design, t: int, result, passive_sets: PassiveSets, construction: tuple, placed_for: list,
               K: int) -> list[PassiveCandidate]:
    """Target ``t``'s K candidate holds, alternating between an IPAM with its cells and the cells of an
    IPAM alone (the IPAM still acting; only cells the target's run jammed). IPAMs placed for another
    target come first (section V-C: what one target needs another may not), then by smallest final
    force. Then what the rounds made passive for it (``construction``: IPAMs, cells)."""
    order = sorted((i for i in range(design.n_ipams) if i not in passive_sets.ipams[t]),
                   key=lambda i: (placed_for[i] == t, abs(float(result.ipam_forces[i])), i))
    jammed = {c for c in range(len(result.jammed)) if result.jammed[c]} - passive_sets.cells[t]
    out = []
    for i in order:
        for h in (PassiveCandidate(frozenset({i}), frozenset(ipam_cells(design, i)) - passive_sets.cells[t]),
                  PassiveCandidate(cells=frozenset(ipam_cells(design, i)) & jammed)):
            if (h.ipams or h.cells) and h not in out:
                out.append(h)
    out = out[:K]
    extra = PassiveCandidate(frozenset(construction[0]) - passive_sets.ipams[t], frozenset(construction[1]) - passive_sets.cells[t])
    if (extra.ipams or extra.cells) and extra not in out:
        out.append(extra)
    return out


def _screen_settings(control_settings, result):
    """The design's controller limited to the jam plan it chose for this target: it reproduces the
    target's current fit exactly and costs about a third of trying every plan (measured: 2.4 s
    against 6.8 s per world on the default problem)."""
    plan = (result.refinement or {}).get("plan")
    if control_settings.method != "inverse" or not plan:
        return control_settings
    return control_settings.replace(inverse_plans=plan)


def _passive(passive_sets: PassiveSets, t: int, hold: PassiveCandidate = PassiveCandidate()) -> tuple[list, list]:
    return sorted(passive_sets.ipams[t] | hold.ipams), sorted(passive_sets.cells[t] | hold.cells)


def _screen(design: Design, worlds: list, current: list, passive_sets: PassiveSets, targets, names, control_settings, *,
            device, progress) -> list:
    """The candidate worlds (target, hold), grouped by their screening settings (one batch per jam
    plan, usually one or two), each screened by ``screen_many`` (the fit its controller predicts, no
    control sequence run); their estimates in ``worlds`` order."""
    groups: dict = {}
    for k, (t, h) in enumerate(worlds):
        s = _screen_settings(control_settings, current[t])
        groups.setdefault((s.method, s.inverse_plans), (s, []))[1].append(k)
    runs = [None] * len(worlds)
    for s, ks in groups.values():
        passive = [_passive(passive_sets, worlds[k][0], worlds[k][1]) for k in ks]
        out = screen_many(design, take(targets, [worlds[k][0] for k in ks]), device=device, settings=s, progress=progress,
                          passive_ipams=[p for p, _ in passive], passive_cells=[c for _, c in passive],
                          target_names=[f"{names[worlds[k][0]]}_hold_{worlds[k][1].label()}" for k in ks])
        for k, run in zip(ks, out):
            runs[k] = run
    return runs


def _screen_round(design: Design, r: int, holds: dict, failed: list, current: list, passive_sets: PassiveSets,
                  targets, names, settings, control_settings, *, device, progress):
    """Round ``r``'s screening of ``holds`` ({target: [PassiveCandidate]}) in two stages (module
    docstring); ``failed[t]`` (the holds target t screened in vain) is updated. Returns the round's
    record, {target: (gain, hold)} of the holds that gained more than ``min_gain`` (the best per
    target) and how many holds a target screens first."""
    K = settings.candidates
    record = dict(round=r, worlds=0, candidates=[], proposed={}, kept={}, screened_out={})
    best: dict[int, tuple[float, PassiveCandidate]] = {}
    first = settings.screen_first or K + 1
    # the first holds of a target, those it did not screen in vain in an earlier round first
    lead = {t: [h for h in hs if h not in failed[t]][:first] if settings.screen_first else hs
            for t, hs in holds.items()}
    stages = [lead, {t: [h for h in hs if h not in lead[t]] for t, hs in holds.items()}]
    for stage, batch in enumerate(stages):
        if stage:  # the rest of a target's holds only where its first ones gained more than min_gain
            for t in list(batch):
                if batch[t] and t not in best:
                    record["screened_out"][names[t]] = (
                        f"{len(batch[t])} more hold(s) not screened: " + (
                            f"none of its first {len(lead[t])} lowered its screened objective by more than "
                            f"{100 * settings.min_gain:g} %" if lead[t] else
                            "each was screened in an earlier round without a gain"))
                    del batch[t]
        worlds = [(t, h) for t, hs in batch.items() for h in hs]
        if not worlds:
            continue
        runs = _screen(design, worlds, current, passive_sets, targets, names, control_settings, device=device,
                       progress=progress)
        record["worlds"] += len(worlds)
        for (t, h), run in zip(worlds, runs):
            before = current[t].objective
            gain = float((before - run.objective) / before) if before > 0 else 0.0
            record["candidates"].append(dict(target=t, **h.as_record(), objective=run.objective,
                                             screened_before=float(before), gain=gain, score=run.objective))
            if gain > settings.min_gain and (t not in best or gain > best[t][0]):
                best[t] = (gain, h)
            if gain <= settings.min_gain:
                failed[t].add(h)
    if not record["screened_out"]:
        del record["screened_out"]
    return record, best, first


def refine_passive(design: Design, results: list, passive_sets: PassiveSets, construction_holds: list, placed_for: list, *,
                 targets, names, settings, control_settings, device, progress=None,
                 recorder=None) -> tuple[list, list[dict], str]:
    """Refinement rounds (module docstring) from the final ``results`` (one per target, controlled by
    ``control_settings`` with ``passive_sets``'s holds; ``placed_for[i]``: the target IPAM ``i`` was
    placed for). Updates ``passive_sets``; returns the refined results, one record per round, and why
    the rounds stopped."""
    T, K = len(targets), settings.candidates
    current = list(results)
    records, stop = [], f"the round limit ({settings.refine_rounds}) was reached"
    active = list(range(T))  # targets whose holds changed (all at first): the others were tried as they stand
    failed = [set() for _ in range(T)]  # per target the holds screened without a gain above min_gain

    def finish(record):
        records.append(record)
        if recorder is not None:
            recorder.log_design_refinement(record["round"], record, names)

    for r in range(settings.refine_rounds):
        holds = {t: _candidates_for(design, t, current[t], passive_sets, construction_holds[t], placed_for, K)
                 for t in active}
        if not any(holds.values()):
            stop = "every target already leaves out every actuator it could"
            break
        record, best, first = _screen_round(design, r, holds, failed, current, passive_sets, targets, names, settings,
                                            control_settings, device=device, progress=progress)
        if not best:
            finish(record)
            stop = (f"no hold lowers a target's screened objective by more than {100 * settings.min_gain:g} %")
            if record.get("screened_out"):
                stop += (f" (each target's first {first} holds screened; its others not, as those first ones "
                         "gained nothing)")
            break
        order = sorted(best)
        passive = [_passive(passive_sets, t, best[t][1]) for t in order]
        checked = control_many(design, take(targets, order), device=device, settings=control_settings,
                               progress=progress, passive_ipams=[p for p, _ in passive],
                               passive_cells=[c for _, c in passive], target_names=[names[t] for t in order])
        for t, run, (pi, pc) in zip(order, checked, passive):
            record["proposed"][names[t]] = dict(**best[t][1].as_record(), objective=run.objective,
                                                before=current[t].objective)
            if run.objective < current[t].objective:
                passive_sets.ipams[t], passive_sets.cells[t] = set(pi), set(pc)
                current[t] = run
                record["kept"][names[t]] = best[t][1].as_record()
        finish(record)
        active = [t for t in order if names[t] in record["kept"]]
        if not active:
            stop = "no proposed hold reached a better fit under the design's controller"
            break
    return current, records, stop


class PerTargetPlacement(PaperPlacement):
    """Algorithm 1's sets (placed as ``PaperPlacement`` places them); in each round before the last
    every target is also controlled with the newest set passive and keeps the better fit; after
    the last round, refinement rounds of holds. Never worse than "paper" on any target."""

    name = "simulated"
    summary = ("Algorithm 1's sets, each target holding neutral what does not help it, refined in batches of "
               "worlds; never worse than paper on any target (default)")
    uses_candidates = True

    def __init__(self):
        self.construction = None  # PassiveSets: what each target holds neutral in the construction rounds

    def before_round(self, run, i, round_settings):
        """A round before the last (not the first): each target also controlled with the newest set
        passive on top of what it had passive before, the better of the two recorded; what each target
        holds goes to ``self.construction`` and the newest set's record (``passive_for``)."""
        if self.construction is None:
            self.construction = PassiveSets(len(run.targets))
        if i == 0:
            return None
        current, construction, names = run.current, self.construction, run.names
        new = current.n_ipams - 1
        cells = set(ipam_cells(current, new))

        def choose(results):
            pi = [sorted(construction.ipams[t] | {new}) for t in range(len(run.targets))]
            pc = [sorted(construction.cells[t] | cells) for t in range(len(run.targets))]
            runs = control_many(current, run.targets, device=run.device, settings=round_settings,
                                progress=run.round_progress(i), passive_ipams=pi, passive_cells=pc, target_names=names)
            out = []
            for t, (r_all, r_held) in enumerate(zip(results, runs)):
                keep = r_held.objective < r_all.objective
                construction.ipams[t], construction.cells[t] = (set(pi[t]), set(pc[t])) if keep else (set(), set())
                out.append(r_held if keep else r_all)
            held_by = [names[t] for t in range(len(run.targets)) if new in construction.ipams[t]]
            return Decision(results=out, amend=dict(passive_for=held_by))
        return choose

    def finish(self, run, i):
        """The refinement rounds after the last round: a decision whose refined results replace the
        last round's (``on_round`` is told again) with the holds they were controlled with."""
        if run.settings.refine_rounds <= 0 or run.current.n_ipams == 0:
            return None
        construction = self.construction or PassiveSets(len(run.targets))
        last, holds = run.rounds[-1], run.passive_sets.copy()
        paper_objective = [r.objective for r in last]  # every actuator in use: Algorithm 1's fit
        refined, records, stopped = refine_passive(
            run.current, last, holds, list(zip(construction.passive_ipams(), construction.passive_cells())),
            [a["target"] for a in run.added], targets=run.targets, names=run.names, settings=run.settings,
            control_settings=run.control_settings, device=run.device, progress=run.round_progress(i),
            recorder=run.recorder)
        changed = any(a is not b for a, b in zip(refined, last))
        return Decision(info=dict(paper_objective=paper_objective, refinement=records, refinement_stopped=stopped),
                        results=refined if changed else None, passive_sets=holds)

    @classmethod
    def describe(cls, info):
        K = info.get("candidates")
        refine = (f", then refinement rounds of K = {K} holds per target, each round one batch of worlds"
                  if "refinement" in info else ", no refinement rounds")
        return (f" (Algorithm 1's actuator sets, each passive for the targets it does not help{refine}: "
                "no target ends worse than under Algorithm 1)")


register_placement(PerTargetPlacement)
