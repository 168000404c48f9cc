"""Simulated placement, after the last round: per-target neutral holds tried in batches of worlds.

The design (every actuator set) is Algorithm 1's; what changes is which actuators each target's
control sequence uses (section V-C: an actuator can be held neutral, masked out of that target's
world). Each refinement round:

1. **Candidates.** Per target, up to ``candidates`` (K) holds, alternating between an IPAM with its
   cells and the cells of an IPAM alone (the IPAM still acts; only cells the target's run jammed),
   the IPAMs with the smallest final force first; and what the construction rounds held for it
   (``construction_holds``). Each is added to what the target already leaves out.
2. **One batch.** The K candidate holds of every target and every target as it stands, K x targets
   + targets worlds of the one design, controlled in one ``control_many`` call by the screening
   controller (model-based control with the paper's jam times and two refinement steps, ``quick``).
3. **Verified.** Per target the hold that lowers its screened objective most (by more than
   ``min_gain``) is controlled by the design's own controller; it is kept when the fit it reaches
   is better than the target's current fit. Targets do not trade: each keeps its own holds, so no
   refinement round makes any target worse, and the final design is at least as good as Algorithm
   1's on every target.
4. The next round tries again only the targets that kept a hold (the others were tried as they
   stand). The rounds stop when no hold is proposed or none is kept (and say so), or after
   ``refine_rounds``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..controller import control_many
from ..design import Design
from .selection import Selection
from .settings import round_control_settings

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

    def label(self) -> str:
        return "+".join([f"ipam{i}" for i in sorted(self.ipams)] + [f"cell{c}" for c in sorted(self.cells)]) or "none"


def _holds_for(design: Design, t: int, result, selection: Selection, construction: tuple, K: int) -> list[Hold]:
    """Target ``t``'s K candidate holds, alternating between an IPAM with its cells and the cells of an
    IPAM alone (the IPAM still acting; only cells the target's run jammed), the IPAMs with the
    smallest final force first; then what the rounds held for it (``construction``: IPAMs, cells)."""
    by_force = sorted((i for i in range(design.n_ipams) if i not in selection.ipams[t]),
                      key=lambda i: (abs(float(result.ipam_forces[i])), i))
    jammed = {c for c in range(len(result.jammed)) if result.jammed[c]} - selection.cells[t]
    whole = [Hold(frozenset({i}), frozenset(ipam_cells(design, i)) - selection.cells[t]) for i in by_force]
    cells = [Hold(cells=frozenset(ipam_cells(design, i)) & jammed) for i in by_force]
    out = []
    for pair in zip(whole, cells + [None] * (len(whole) - len(cells))):
        out += [h for h in pair if h is not None and (h.ipams or h.cells) and h not in out]
    out = out[:K]
    extra = Hold(frozenset(construction[0]) - selection.ipams[t], frozenset(construction[1]) - selection.cells[t])
    if (extra.ipams or extra.cells) and extra not in out:
        out.append(extra)
    return out


def _passive(selection: Selection, t: int, hold: Hold = Hold()) -> tuple[list, list]:
    return sorted(selection.ipams[t] | hold.ipams), sorted(selection.cells[t] | hold.cells)


def refine_holds(design: Design, results: list, selection: Selection, construction_holds: list, *, targets, names,
                 settings, control_settings, device, progress=None, recorder=None) -> tuple[list, list[dict], str]:
    """Refinement rounds (module docstring) from the final ``results`` (one per target, controlled by
    ``control_settings`` with ``selection``'s holds). Updates ``selection``; returns the refined
    results, one record per round, and why the rounds stopped."""
    T, K = len(targets), settings.candidates
    screen = round_control_settings(control_settings, "quick")
    current = list(results)
    records, stop = [], f"the round limit ({settings.refine_rounds}) was reached"
    active = list(range(T))  # targets whose holds changed (all at first): the others were tried as they stand
    for r in range(settings.refine_rounds):
        holds = {t: _holds_for(design, t, current[t], selection, construction_holds[t], K) for t in active}
        worlds = [(t, Hold()) for t in active] + [(t, h) for t in active for h in holds[t]]
        if len(worlds) == len(active):
            stop = "every target already leaves out every IPAM it could"
            break
        passive = [_passive(selection, t, h) for t, h in worlds]
        runs = control_many(design, [targets[t] for t, _ in worlds], device=device, settings=screen,
                            progress=progress, recorder=recorder, recorder_prefix=f"design/refine_{r}",
                            passive_ipams=[p for p, _ in passive], passive_cells=[c for _, c in passive],
                            target_names=[f"{names[t]}_hold_{h.label()}" for t, h in worlds])
        n = len(active)
        base = {t: runs[k].objective for k, t in enumerate(active)}
        record = dict(round=r, worlds=len(worlds), candidates=[], proposed={}, kept={})
        best: dict[int, tuple[float, Hold]] = {}
        for (t, h), run in zip(worlds[n:], runs[n:]):
            gain = float((base[t] - run.objective) / base[t]) if base[t] > 0 else 0.0
            record["candidates"].append(dict(target=t, hold=sorted(h.ipams), cells=sorted(h.cells),
                                             objective=run.objective,
                                             screened_before=float(base[t]), gain=gain, score=run.objective))
            if gain > settings.min_gain and (t not in best or gain > best[t][0]):
                best[t] = (gain, h)
        if not best:
            records.append(record)
            stop = (f"no hold lowers a target's screened objective by more than {100 * settings.min_gain:g} %")
            break
        order = sorted(best)
        passive = [_passive(selection, t, best[t][1]) for t in order]
        checked = control_many(design, [targets[t] for t in order], device=device, settings=control_settings,
                               progress=progress, passive_ipams=[p for p, _ in passive],
                               passive_cells=[c for _, c in passive], target_names=[names[t] for t in order])
        for t, run, (pi, pc) in zip(order, checked, passive):
            record["proposed"][names[t]] = dict(hold=sorted(best[t][1].ipams), cells=sorted(best[t][1].cells),
                                                objective=run.objective,
                                                before=current[t].objective)
            if run.objective < current[t].objective:
                selection.ipams[t], selection.cells[t] = set(pi), set(pc)
                current[t] = run
                record["kept"][names[t]] = dict(hold=sorted(best[t][1].ipams), cells=sorted(best[t][1].cells))
        records.append(record)
        active = [t for t in order if names[t] in record["kept"]]
        if not active:
            stop = "no proposed hold reached a better fit under the design's controller"
            break
    return current, records, stop
