"""The control sequences a design run saved beside its scene (``control_<target>.json``), replayed on
the scene's design: ``export`` writes the design's own sequences again (valve files, USD, figures)
instead of controlling anew, which can land elsewhere (another objective, other final pressures).

The replay is open loop (``controller.open_loop.replay_result``): the same controls and jam events on
the same design and simulation settings give the same membrane (bit for bit on the CPU for a
single-target run; a batch's worlds can take other internal steps, within float rounding). The fit
of the replay is compared with the saved one; a replay off by more than ``SAME_OBJECTIVE`` (relative)
is not the design's sequence and is not used.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from ..controller.open_loop import replay_result
from ..controller.result import ControlResult

__all__ = ["SAME_OBJECTIVE", "saved_result", "replayed_saved_results"]

#: a replayed sequence's objective within this relative difference of the saved one is the same sequence
SAME_OBJECTIVE = 1e-4


def saved_result(folder, name: str, design, target, settings) -> ControlResult | None:
    """The ``ControlResult`` skeleton of ``folder/control_<name>.json`` (history, final controls, jam
    steps, passive actuators; the membrane still the rest shape until replayed), or None where there is
    no such file or it is not a control record of ``design``."""
    path = Path(folder) / f"control_{name}.json"
    try:
        data = json.loads(path.read_text())
        cols, rows = data["columns"], np.asarray(data["rows"], dtype=np.float64)
        history = {c: rows[:, k] for k, c in enumerate(cols)}
        pressures = np.asarray(data["ipam_pressures_pa"], dtype=np.float64)
        jammed = np.asarray(data["jammed"], dtype=bool)
    except (OSError, ValueError, KeyError, TypeError, IndexError):
        return None
    if len(pressures) != design.n_ipams or len(jammed) != design.n_cells or rows.ndim != 2 or not len(rows):
        return None
    rest = design.rest
    return ControlResult(
        achieved=rest, sampled_target=rest, objective=float(data["objective"]), pcc=float(data["pcc"]),
        mare=float(data["mare_m"]), mpre=float(data["mpre_pct"]), volume_error=float(data["volume_error"]),
        ipam_forces=np.asarray(data["ipam_forces_n"], dtype=np.float64), ipam_pressures=pressures,
        air_moles=float(data["air_moles"]), jammed=jammed, jam_steps=np.asarray(data["jam_steps"], dtype=np.int64),
        converged=bool(data["converged"]), reason=str(data["reason"]), saturated=list(data["saturated"]),
        settled=bool(data["settled"]), max_speed=float(data["max_speed_m_s"]), control_steps=int(data["control_steps"]),
        history=history, settings=settings, design=design, target=target,
        passive_ipams=np.asarray(data.get("passive_ipams", []), dtype=np.int64),
        passive_cells=np.asarray(data.get("passive_cells", []), dtype=np.int64), refinement=data.get("refinement"))


def replayed_saved_results(folder, named, design, settings, *, device: str = "cpu") -> tuple[list | None, str]:
    """(results, note): every target of ``named`` ([(name, target)]) replayed from its saved
    ``control_<name>.json`` in ``folder`` on ``design``; or (None, why not) where a target has no saved sequence or its replay is not it."""
    out = []
    for name, target in named:
        saved = saved_result(folder, name, design, target, settings)
        if saved is None:
            return None, f"no control_{name}.json of this design beside the scene"
        res = replay_result(design, saved, device=device)
        off = abs(res.objective - saved.objective) / max(abs(saved.objective), 1e-12)
        if not off <= SAME_OBJECTIVE:
            return None, (f"control_{name}.json replayed on the scene's design reaches objective {res.objective:.6g}, "
                          f"not its saved {saved.objective:.6g}: the scene is not the design it was controlled on")
        out.append(res)
    return out, "the design's saved sequences (control_<target>.json beside the scene), replayed"
