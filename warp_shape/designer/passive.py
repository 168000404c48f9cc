"""Which actuators each target's control sequence leaves out (passive: held neutral, section V-C).

The simulated placement holds a set neutral for a target when that fits it better (in the rounds and
in its refinement rounds, ``designer.per_target``); the greedy placement (``designer.greedy``) leaves a
kept candidate set out of the sequence of every target it does not help; the paper's placement
leaves nothing out. The passive_sets is stored in
scene settings as flat strings.
"""

from __future__ import annotations

import numpy as np

__all__ = ["PassiveSets", "passive_to_settings", "passive_from_settings", "PASSIVE_PREFIXES"]

#: the scene ``controller`` keys that store a passive_sets: ``passive_ipams_<target>``, ``passive_cells_<target>``
PASSIVE_PREFIXES = ("passive_ipams_", "passive_cells_")


class PassiveSets:
    """Per target: the IPAMs and cells left out of its control sequence."""

    def __init__(self, n_targets: int):
        self.ipams: list[set] = [set() for _ in range(n_targets)]
        self.cells: list[set] = [set() for _ in range(n_targets)]

    def copy(self) -> "PassiveSets":
        out = PassiveSets(0)
        out.ipams, out.cells = [set(s) for s in self.ipams], [set(s) for s in self.cells]
        return out

    def passive_ipams(self, targets=None) -> list[list[int]]:
        """Sorted IPAM indices left out, per target (of ``targets``, default all)."""
        return [sorted(self.ipams[j]) for j in (range(len(self.ipams)) if targets is None else targets)]

    def passive_cells(self, targets=None) -> list[list[int]]:
        """Sorted cell indices left out, per target (of ``targets``, default all)."""
        return [sorted(self.cells[j]) for j in (range(len(self.cells)) if targets is None else targets)]


def _setting_key(name: str) -> str:
    return "".join(ch if ch.isalnum() else "_" for ch in name)


def passive_to_settings(names, passive_ipams, passive_cells) -> dict:
    """Scene controller settings recording each target's passive IPAMs and cells (flat strings)."""
    out = {}
    for name, pi, pc in zip(names, passive_ipams, passive_cells):
        if pi:
            out[f"passive_ipams_{_setting_key(name)}"] = " ".join(str(int(i)) for i in pi)
        if pc:
            out[f"passive_cells_{_setting_key(name)}"] = " ".join(str(int(c)) for c in pc)
    return out


def passive_from_settings(settings: dict | None, names) -> tuple[list, list]:
    """Per-target passive IPAM and cell lists stored by ``passive_to_settings`` (empty if none)."""
    ctl = (settings or {}).get("controller", {})
    ipams = [[int(v) for v in str(ctl.get(f"passive_ipams_{_setting_key(n)}", "")).split()] for n in names]
    cells = [[int(v) for v in str(ctl.get(f"passive_cells_{_setting_key(n)}", "")).split()] for n in names]
    return ipams, cells
