"""Actuator selection: which actuators each target's control sequence leaves out (held neutral).

Not in the paper's algorithm: when a new actuator set lowers a target's PCC by more than
``max_drop``, the target is re-run with the set held neutral and the better run is kept (section V-C
notes an actuator can be neutralised). The selection is stored in scene settings as flat strings.
"""

from __future__ import annotations

import numpy as np

__all__ = ["Selection", "pcc_selection", "selection_to_settings", "selection_from_settings"]


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


def pcc_selection(results: list, previous_pcc: np.ndarray, selection: Selection, new_ipams: set, new_cells: set,
                  max_drop: float, rerun) -> list[int]:
    """Today's PCC-based selection. Targets whose PCC fell below ``previous_pcc - max_drop`` are re-run
    by ``rerun(targets, passive_ipams, passive_cells) -> results`` with the new set held neutral as
    well; where that run fits better it replaces the result in ``results`` and ``selection`` leaves the
    set out for that target. Returns the targets that leave the new set out."""
    worse = [j for j, r in enumerate(results) if r.pcc < previous_pcc[j] - max_drop]
    if not worse:
        return []
    retry = rerun(worse, [sorted(selection.ipams[j] | new_ipams) for j in worse],
                  [sorted(selection.cells[j] | new_cells) for j in worse])
    left_out = []
    for j, r in zip(worse, retry):
        if r.pcc > results[j].pcc:
            results[j] = r
            selection.ipams[j] |= new_ipams
            selection.cells[j] |= new_cells
            left_out.append(j)
    return left_out


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
