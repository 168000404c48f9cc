"""Strategies registered from outside the package, as a lab would: a control law that moves only
the air, and a placement that puts its IPAM on the free face of lowest index. Imported by
tests/test_strategies.py, and by the command line through ``WARP_SHAPE_PLUGINS=strategy_plugin``."""

from __future__ import annotations

import numpy as np

import warp_shape as ws
from warp_shape.controller import Controls, LawStep, PaperLaw
from warp_shape.designer.placement import Decision, free_faces, other_end, rest_directions, scaled_errors


class AirOnlyLaw(PaperLaw):
    """The paper's air law, eq. (11); the IPAMs stay vented (0 Pa) and no cell ever jams."""

    name = "air_only"
    summary = "the paper's air law alone (IPAMs vented, no jamming)"

    def step(self, obs, controls, active) -> LawStep:
        out = super().step(obs, controls, active)
        return LawStep(Controls(out.controls.air, np.zeros_like(out.controls.pressures)), [])


class LowestFacePlacement(ws.Placement):
    """One end on the free face of lowest index, the other by the paper's 120-degree rule."""

    name = "lowest_face"
    summary = "one end on the free face of lowest index (a test strategy)"

    def place(self, run, results, i, round_settings):
        errors, _ = scaled_errors(results, run.ctx)
        free = free_faces(run.current)
        a = int(np.flatnonzero(free)[0])
        b = other_end(errors[0], free, rest_directions(run.ctx), a, run.settings.min_angle_deg, i + 1)
        return Decision(ends=(a, b), record=dict(round=i, target=0, face_a=a, face_b=b, error=float(errors[0, a])))


ws.register_law(AirOnlyLaw, replace=True)
ws.register_placement(LowestFacePlacement, replace=True)
