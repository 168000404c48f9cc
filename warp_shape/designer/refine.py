"""Simulated placement, after the last round: per-target neutral holds tried in batches of worlds.

The design (every actuator set) is Algorithm 1's; what changes is which actuators each target's
control sequence uses (section V-C: an actuator can be held neutral, masked out of that target's
world). Each refinement round:

1. **Candidates.** Per target, up to ``candidates`` (K) holds, alternating between an IPAM with its
   cells and the cells of an IPAM alone (the IPAM still acts; only cells the target's run jammed),
   IPAMs placed for another target first, then those with the smallest final force; and what the
   construction rounds held for it (``construction_holds``). Each is added to what the target
   already leaves out.
2. **Screened in one batch per jam plan.** Every target's candidates run together (K x targets
   worlds of the one design, per-world masks), each controlled by the design's controller limited to
   the jam plan it chose for that target (which reproduces the target's current fit exactly and
   costs about a third of the full controller): one ``control_many`` call per plan in use, usually
   one or two.
3. **Verified.** Per target the hold that lowers its screened objective most (by more than
   ``min_gain``) is controlled by the design's own controller (every plan); it is kept when the fit
   it reaches is better than the target's current fit. Targets do not trade: each keeps its own
   holds, so no refinement round makes any target worse, and the final fit of every target is at
   least Algorithm 1's.
4. The next round tries again only the targets that kept a hold (the others were tried as they
   stand). The rounds stop when no hold is proposed or none is kept (and say so), or after
   ``refine_rounds``.
"""

from __future__ import annotations

from dataclasses import dataclass

from ..controller import control_many
from ..design import Design
from .selection import Selection

__all__ = ["Hold", "ipam_cells", "refine_holds"]


def ipam_cells(design: Design, i: int) -> list[int]:
    """The cells around IPAM ``i``'s ends (those holding either end face)."""
    ip = design.ipams[i]
    return [c for c, cell in enumerate(design.cells) if ip.face_a in cell.faces or ip.face_b in cell.faces]


@dataclass(frozen=True)
class Hold:
    """What a target leaves out of its sequence on top of what it already leaves out."""

    ipams: frozenset = frozenset()
    cells: frozenset = frozenset()

    def as_record(self) -> dict:
        """``{"hold": [IPAMs], "cells": [cells]}``, as the refinement records name a hold."""
        return dict(hold=sorted(self.ipams), cells=sorted(self.cells))

    def label(self) -> str:
        return "+".join([f"ipam{i}" for i in sorted(self.ipams)] + [f"cell{c}" for c in sorted(self.cells)]) or "none"


def _holds_for(design: Design, t: int, result, selection: Selection, construction: tuple, placed_for: list,
               K: int) -> list[Hold]:
    """Target ``t``'s K candidate holds, alternating between an IPAM with its cells and the cells of an
    IPAM alone (the IPAM still acting; only cells the target's run jammed). IPAMs placed for another
    target come first (section V-C: what one target needs another may not), then by smallest final
    force. Then what the rounds held for it (``construction``: IPAMs, cells)."""
    order = sorted((i for i in range(design.n_ipams) if i not in selection.ipams[t]),
                   key=lambda i: (placed_for[i] == t, abs(float(result.ipam_forces[i])), i))
    jammed = {c for c in range(len(result.jammed)) if result.jammed[c]} - selection.cells[t]
    out = []
    for i in order:
        for h in (Hold(frozenset({i}), frozenset(ipam_cells(design, i)) - selection.cells[t]),
                  Hold(cells=frozenset(ipam_cells(design, i)) & jammed)):
            if (h.ipams or h.cells) and h not in out:
                out.append(h)
    out = out[:K]
    extra = Hold(frozenset(construction[0]) - selection.ipams[t], frozenset(construction[1]) - selection.cells[t])
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


def _passive(selection: Selection, t: int, hold: Hold = Hold()) -> tuple[list, list]:
    return sorted(selection.ipams[t] | hold.ipams), sorted(selection.cells[t] | hold.cells)


def _screen(design: Design, worlds: list, current: list, selection: Selection, targets, names, control_settings, *,
            device, progress, recorder, r: int) -> list:
    """The candidate worlds (target, hold), grouped by their screening settings (one batch per jam
    plan, usually one or two); their results in ``worlds`` order."""
    groups: dict = {}
    for k, (t, h) in enumerate(worlds):
        s = _screen_settings(control_settings, current[t])
        groups.setdefault((s.method, s.inverse_plans), (s, []))[1].append(k)
    runs = [None] * len(worlds)
    for g, (s, ks) in enumerate(groups.values()):
        passive = [_passive(selection, worlds[k][0], worlds[k][1]) for k in ks]
        out = control_many(design, [targets[worlds[k][0]] for k in ks], device=device, settings=s, progress=progress,
                           recorder=recorder, recorder_prefix=f"design/refine_{r}" + (f"_{g}" if g else ""),
                           passive_ipams=[p for p, _ in passive], passive_cells=[c for _, c in passive],
                           target_names=[f"{names[worlds[k][0]]}_hold_{worlds[k][1].label()}" for k in ks])
        for k, run in zip(ks, out):
            runs[k] = run
    return runs


def refine_holds(design: Design, results: list, selection: Selection, construction_holds: list, placed_for: list, *,
                 targets, names, settings, control_settings, device, progress=None,
                 recorder=None) -> tuple[list, list[dict], str]:
    """Refinement rounds (module docstring) from the final ``results`` (one per target, controlled by
    ``control_settings`` with ``selection``'s holds; ``placed_for[i]``: the target IPAM ``i`` was
    placed for). Updates ``selection``; returns the refined results, one record per round, and why
    the rounds stopped."""
    T, K = len(targets), settings.candidates
    current = list(results)
    records, stop = [], f"the round limit ({settings.refine_rounds}) was reached"
    active = list(range(T))  # targets whose holds changed (all at first): the others were tried as they stand

    def finish(record):
        records.append(record)
        if recorder is not None:
            recorder.log_design_refinement(record["round"], record, names)

    for r in range(settings.refine_rounds):
        worlds = [(t, h) for t in active
                  for h in _holds_for(design, t, current[t], selection, construction_holds[t], placed_for, K)]
        if not worlds:
            stop = "every target already leaves out every actuator it could"
            break
        runs = _screen(design, worlds, current, selection, targets, names, control_settings, device=device,
                       progress=progress, recorder=recorder, r=r)
        record = dict(round=r, worlds=len(worlds), candidates=[], proposed={}, kept={})
        best: dict[int, tuple[float, Hold]] = {}
        for (t, h), run in zip(worlds, runs):
            before = current[t].objective
            gain = float((before - run.objective) / before) if before > 0 else 0.0
            record["candidates"].append(dict(target=t, **h.as_record(), objective=run.objective,
                                             screened_before=float(before), gain=gain, score=run.objective))
            if gain > settings.min_gain and (t not in best or gain > best[t][0]):
                best[t] = (gain, h)
        if not best:
            finish(record)
            stop = (f"no hold lowers a target's screened objective by more than {100 * settings.min_gain:g} %")
            break
        order = sorted(best)
        passive = [_passive(selection, t, best[t][1]) for t in order]
        checked = control_many(design, [targets[t] for t in order], device=device, settings=control_settings,
                               progress=progress, passive_ipams=[p for p, _ in passive],
                               passive_cells=[c for _, c in passive], target_names=[names[t] for t in order])
        for t, run, (pi, pc) in zip(order, checked, passive):
            record["proposed"][names[t]] = dict(**best[t][1].as_record(), objective=run.objective,
                                                before=current[t].objective)
            if run.objective < current[t].objective:
                selection.ipams[t], selection.cells[t] = set(pi), set(pc)
                current[t] = run
                record["kept"][names[t]] = best[t][1].as_record()
        finish(record)
        active = [t for t in order if names[t] in record["kept"]]
        if not active:
            stop = "no proposed hold reached a better fit under the design's controller"
            break
    return current, records, stop
