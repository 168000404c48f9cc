"""Actuator selection: which actuators each target's control sequence leaves out (held neutral).

Not in the paper's algorithm: when a new actuator set raises a target's fit objective (the
controller's ``objective``, lower is better) by more than the relative tolerance ``max_rise``, the
target is re-run with the set held neutral and the run with the lower objective is kept (section V-C
notes an actuator can be neutralised). The selection is stored in scene settings as flat strings.
"""

from __future__ import annotations

import numpy as np

__all__ = ["Selection", "objective_selection", "selection_to_settings", "selection_from_settings"]


class Selection:
    """Per target: the IPAMs and cells left out of its control sequence."""

    def __init__(self, n_targets: int):
        self.ipams: list[set] = [set() for _ in range(n_targets)]
        self.cells: list[set] = [set() for _ in range(n_targets)]

    def passive_ipams(self, targets=None) -> list[list[int]]:
        """Sorted IPAM indices left out, per target (of ``targets``, default all)."""
        return [sorted(self.ipams[j]) for j in (range(len(self.ipams)) if targets is None else targets)]

    def passive_cells(self, targets=None) -> list[list[int]]:
        """Sorted cell indices left out, per target (of ``targets``, default all)."""
        return [sorted(self.cells[j]) for j in (range(len(self.cells)) if targets is None else targets)]


def objective_selection(results: list, previous_objective: np.ndarray, selection: Selection, new_ipams: set,
                        new_cells: set, max_rise: float, rerun) -> tuple[list[int], list[int]]:
    """Targets whose objective rose above ``previous_objective * (1 + max_rise)`` are re-run by
    ``rerun(targets, passive_ipams, passive_cells) -> results`` (targets may repeat) with the new set
    held neutral as well and, where the target already leaves sets out, with every set in use (sets
    that do not help alone may help together, e.g. the corner IPAMs of a cube); the run with the
    lowest objective replaces the result in ``results`` and ``selection`` follows it. Returns the
    targets that leave the new set out, and those that took every set back."""
    worse = [j for j, r in enumerate(results) if r.objective > previous_objective[j] * (1.0 + max_rise)]
    if not worse:
        return [], []
    runs = [(j, "neutral") for j in worse] + [(j, "all") for j in worse if selection.ipams[j] or selection.cells[j]]
    retry = rerun([j for j, _ in runs],
                  [sorted(selection.ipams[j] | new_ipams) if how == "neutral" else [] for j, how in runs],
                  [sorted(selection.cells[j] | new_cells) if how == "neutral" else [] for j, how in runs])
    best = {}
    for (j, how), r in zip(runs, retry):
        if r.objective < (best[j][1].objective if j in best else results[j].objective):
            best[j] = (how, r)
    left_out, taken_back = [], []
    for j, (how, r) in sorted(best.items()):
        results[j] = r
        if how == "neutral":
            selection.ipams[j] |= new_ipams
            selection.cells[j] |= new_cells
            left_out.append(j)
        else:
            selection.ipams[j], selection.cells[j] = set(), set()
            taken_back.append(j)
    return left_out, taken_back


def _setting_key(name: str) -> str:
    return "".join(ch if ch.isalnum() else "_" for ch in name)


def selection_to_settings(names, passive_ipams, passive_cells) -> dict:
    """Scene controller settings recording each target's passive IPAMs and cells (flat strings)."""
    out = {}
    for name, pi, pc in zip(names, passive_ipams, passive_cells):
        if pi:
            out[f"passive_ipams_{_setting_key(name)}"] = " ".join(str(int(i)) for i in pi)
        if pc:
            out[f"passive_cells_{_setting_key(name)}"] = " ".join(str(int(c)) for c in pc)
    return out


def selection_from_settings(settings: dict | None, names) -> tuple[list, list]:
    """Per-target passive IPAM and cell lists stored by ``selection_to_settings`` (empty if none)."""
    ctl = (settings or {}).get("controller", {})
    ipams = [[int(v) for v in str(ctl.get(f"passive_ipams_{_setting_key(n)}", "")).split()] for n in names]
    cells = [[int(v) for v in str(ctl.get(f"passive_cells_{_setting_key(n)}", "")).split()] for n in names]
    return ipams, cells
