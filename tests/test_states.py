"""States allocated by the model, a step from one state into another, and world copies on the device."""

from __future__ import annotations

import numpy as np

import warp_shape as ws
import warp_shape.model as model_module
import warp_shape.simulator as simulator_module


def test_host_model_is_built_once_per_simulator(monkeypatch):
    calls = []
    real = model_module.host_model

    def counted(design):
        calls.append(design)
        return real(design)

    monkeypatch.setattr(model_module, "host_model", counted)
    monkeypatch.setattr(simulator_module, "host_model", counted)
    d = ws.Design(ws.icosphere(1, 0.04))
    sim = ws.Simulator(d)
    assert len(calls) == 1
    h = sim.model.host
    assert h.rest_air == sim.air_moles and h.n_ipams == 0 and h.n_cells == 0
    assert h.gas_rt == sim.model.gas_rt and h.atmospheric_pressure == sim.model.atmospheric_pressure
