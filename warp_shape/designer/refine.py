"""Simulated placement, after the last round: per-target neutral holds tried in batches of worlds.

The design (every actuator set) is Algorithm 1's; what changes is which actuators each target's
control sequence uses (section V-C: an actuator can be held neutral, masked out of that target's
world). Each refinement round:

1. **Candidates.** Per target, up to ``candidates`` (K) holds: each of the K IPAMs it uses with the
   smallest final force (with their cells), and the IPAMs the construction rounds held neutral for
   it (``construction_holds``), each added to what the target already leaves out.
2. **One batch.** The K candidate holds of every target and every target as it stands, K x targets
   + targets worlds of the one design, controlled in one ``control_many`` call by the screening
   controller (model-based control with the paper's jam times and two refinement steps, ``quick``).
3. **Verified.** Per target the hold that lowers its screened objective most (by more than
   ``min_gain``) is controlled by the design's own controller; it is kept when the fit it reaches
   is better than the target's current fit. Targets do not trade: each keeps its own holds, so no
   refinement round makes any target worse, and the final design is at least as good as Algorithm
   1's on every target.
4. The rounds stop when no hold is proposed or none is kept (and say so), or after ``refine_rounds``.
"""

from __future__ import annotations

import numpy as np

from ..controller import control_many
from ..design import Design
from .selection import Selection
from .settings import round_control_settings

__all__ = ["ipam_cells", "refine_holds"]


def ipam_cells(design: Design, i: int) -> list[int]:
    """The cells around IPAM ``i``'s ends (those holding either end face)."""
    ip = design.ipams[i]
    return [c for c, cell in enumerate(design.cells) if ip.face_a in cell.faces or ip.face_b in cell.faces]


def _holds_for(t: int, result, selection: Selection, construction_holds: list, K: int) -> list[frozenset]:
    """Target ``t``'s candidate holds: sets of IPAMs to leave out in addition to what it leaves out."""
    used = [i for i in range(len(result.ipam_forces)) if i not in selection.ipams[t]]
    by_force = sorted(used, key=lambda i: (abs(float(result.ipam_forces[i])), i))[:K]
    out = [frozenset({i}) for i in by_force]
    extra = frozenset(construction_holds[t]) - frozenset(selection.ipams[t])
    if extra and extra not in out:
        out.append(extra)
    return out


def _passive(design: Design, selection: Selection, t: int, hold=frozenset()) -> tuple[list, list]:
    ipams = sorted(set(selection.ipams[t]) | set(hold))
    cells = sorted(set(selection.cells[t]) | {c for i in hold for c in ipam_cells(design, i)})
    return ipams, cells


def refine_holds(design: Design, results: list, selection: Selection, construction_holds: list, *, targets, names,
                 settings, control_settings, device, progress=None, recorder=None) -> tuple[list, list[dict], str]:
    """Refinement rounds (module docstring) from the final ``results`` (one per target, controlled by
    ``control_settings`` with ``selection``'s holds). Updates ``selection``; returns the refined
    results, one record per round, and why the rounds stopped."""
    T, K = len(targets), settings.candidates
    screen = round_control_settings(control_settings, "quick")
    current = list(results)
    records, stop = [], f"the round limit ({settings.refine_rounds}) was reached"
    for r in range(settings.refine_rounds):
        holds = [_holds_for(t, current[t], selection, construction_holds, K) for t in range(T)]
        worlds = [(t, frozenset()) for t in range(T)] + [(t, h) for t in range(T) for h in holds[t]]
        if len(worlds) == T:
            stop = "every target already leaves out every IPAM it could"
            break
        passive = [_passive(design, selection, t, h) for t, h in worlds]
        runs = control_many(design, [targets[t] for t, _ in worlds], device=device, settings=screen,
                            progress=progress, recorder=recorder, recorder_prefix=f"design/refine_{r}",
                            passive_ipams=[p for p, _ in passive], passive_cells=[c for _, c in passive],
                            target_names=[f"{names[t]}_hold{'_'.join(map(str, sorted(h))) or '_none'}"
                                          for t, h in worlds])
        base = np.array([runs[t].objective for t in range(T)])
        record = dict(round=r, worlds=len(worlds), candidates=[], proposed={}, kept={})
        best: dict[int, tuple[float, frozenset]] = {}
        for (t, h), run in zip(worlds[T:], runs[T:]):
            gain = float((base[t] - run.objective) / base[t]) if base[t] > 0 else 0.0
            record["candidates"].append(dict(target=t, hold=sorted(h), objective=run.objective,
                                             screened_before=float(base[t]), gain=gain, score=run.objective))
            if gain > settings.min_gain and (t not in best or gain > best[t][0]):
                best[t] = (gain, h)
        if not best:
            records.append(record)
            stop = (f"no hold lowers a target's screened objective by more than {100 * settings.min_gain:g} %")
            break
        order = sorted(best)
        passive = [_passive(design, selection, t, best[t][1]) for t in order]
        checked = control_many(design, [targets[t] for t in order], device=device, settings=control_settings,
                               progress=progress, passive_ipams=[p for p, _ in passive],
                               passive_cells=[c for _, c in passive], target_names=[names[t] for t in order])
        for t, run, (pi, pc) in zip(order, checked, passive):
            record["proposed"][names[t]] = dict(hold=sorted(best[t][1]), objective=run.objective,
                                                before=current[t].objective)
            if run.objective < current[t].objective:
                selection.ipams[t], selection.cells[t] = set(pi), set(pc)
                current[t] = run
                record["kept"][names[t]] = sorted(best[t][1])
        records.append(record)
        if not record["kept"]:
            stop = "no proposed hold reached a better fit under the design's controller"
            break
    return current, records, stop
