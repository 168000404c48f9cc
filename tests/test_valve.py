"""Valve-ready sequences: lab units (kPa gauge, mL of air at atmospheric pressure), lab and simulated
time from 0 in seconds, passive IPAMs named, and retiming for a real pump and valves (flow and slew
limits, every control step on a uniform grid)."""

from __future__ import annotations

import csv
import json
from types import SimpleNamespace

import numpy as np
import pytest

import warp_shape as ws
from warp_shape.errors import DesignError
from warp_shape.io.valve import PLAN_MARGIN, ValveTiming, peak_rates, row_times, valve_schedule, write_valve_outputs
from warp_shape.material import GAS_CONSTANT, Material

DT = 0.01  # s, simulated control step


def _result(passive=(1,)):
    """A control record of 6 steps: inflation (air up), then IPAM 0 steps by 40 kPa per step, cell 0
    jams at step 3. Times start at 0.5 s, as a record that followed a settling run would."""
    n = 6
    h = {"step": np.arange(n), "time": 0.5 + DT * np.arange(n), "phase": np.array([1, 1, 2, 2, 2, 3]),
         "air_mol": np.array([0.010, 0.011, 0.012, 0.012, 0.012, 0.012]),
         "pressure_pa": np.array([0.0, 500.0, 1000.0, 1500.0, 1500.0, 1500.0]),
         "ipam0_pressure_pa": np.array([0.0, 0.0, 40e3, 80e3, 120e3, 120e3]),
         "ipam1_pressure_pa": np.array([0.0, 0.0, 2e3, 3e3, 3e3, 3e3]),  # passive: neutral pressure
         "cell0_jammed": np.array([0, 0, 0, 1, 1, 1]), "cell1_jammed": np.zeros(n, dtype=int)}
    return SimpleNamespace(history=h, passive_ipams=np.array(passive), passive_cells=np.array([1]),
                           design=SimpleNamespace(material=Material()))


SIMULATED = ValveTiming(rate_hz=None, max_slew_kpa_s=None, max_flow_ml_s=None)
KEEP = 1.0 - PLAN_MARGIN


def test_units_and_columns_one_row_per_step():
    s = valve_schedule(_result(), SIMULATED)
    assert list(s) == ["time_s", "sim_time_s", "phase", "control_step", "ipam0_pressure_kpa", "ipam1_pressure_kpa",
                       "chamber_pressure_kpa", "chamber_air_ml", "chamber_air_added_ml", "cell0_jammed",
                       "cell1_jammed"]
    assert s["time_s"] == pytest.approx(DT * np.arange(6))  # from 0, simulated pace
    assert s["sim_time_s"] == pytest.approx(DT * np.arange(6))
    assert s["ipam0_pressure_kpa"] == pytest.approx([0, 0, 40, 80, 120, 120])  # kPa, not Pa
    assert s["chamber_pressure_kpa"][-1] == pytest.approx(1.5)
    # 0.010 mol at 293.15 K and 101.325 kPa: 240.55 mL (n R T / p_atm)
    assert s["chamber_air_ml"][0] == pytest.approx(0.010 * GAS_CONSTANT * 293.15 / 101325.0 * 1e6, rel=1e-9)
    assert s["chamber_air_ml"][0] == pytest.approx(240.55, abs=0.01)
    assert s["chamber_air_added_ml"][-1] == pytest.approx(48.11, abs=0.01)  # 2 mmol dosed
    assert s["cell0_jammed"].tolist() == [0, 0, 0, 1, 1, 1]
    zero = valve_schedule(_result(), SIMULATED, passive="zero")
    assert np.all(zero["ipam1_pressure_kpa"] == 0.0) and zero["ipam0_pressure_kpa"][-1] == pytest.approx(120)


def test_slew_and_flow_limits_stretch_fast_steps_only():
    t = row_times(_result(), ValveTiming(rate_hz=None, max_slew_kpa_s=100.0, max_flow_ml_s=None))
    # the 40 kPa steps take 0.4 s at 100 kPa/s (planned 0.1 % below the limit); the slow steps keep their 10 ms
    assert np.diff(t) == pytest.approx([0.01, 0.4 / KEEP, 0.4 / KEEP, 0.4 / KEEP, 0.01])
    # a pump flow limit stretches the inflation: 24.055 mL per step at 10 mL/s takes 2.4055 s
    tf = row_times(_result(), ValveTiming(rate_hz=None, max_slew_kpa_s=None, max_flow_ml_s=10.0))
    assert np.diff(tf)[:2] == pytest.approx([2.4055 / KEEP] * 2, abs=1e-3)


def test_default_timing_is_a_pump_and_valves_a_lab_has():
    """By default (5 mL/s, 100 kPa/s, 50 Hz) every control step lands on the 50 Hz grid, the last
    row included, and no row pair asks for more flow or slew than the limits."""
    res = _result()
    assert ValveTiming() == ValveTiming(rate_hz=50.0, max_slew_kpa_s=100.0, max_flow_ml_s=5.0)
    s = valve_schedule(res)
    t = s["time_s"]
    ticks = t * 50.0
    assert np.allclose(ticks, np.round(ticks), atol=1e-9) and np.allclose(np.diff(t), 0.02)
    rows = row_times(res)
    assert np.allclose(rows * 50.0, np.round(rows * 50.0), atol=1e-9) and rows[-1] == pytest.approx(t[-1])
    # inflation: 24.055 mL per step at 5 mL/s, 4.82 s each (whole 20 ms periods); 40 kPa steps: 0.42 s
    assert np.diff(rows) == pytest.approx([4.82, 4.82, 0.42, 0.42, 0.02])
    peak = peak_rates(s)
    assert peak["flow_ml_s"] <= 5.0 and peak["slew_kpa_s"] <= 100.0
    assert peak["flow_ml_s"] > 4.9  # the pump is the bottleneck of the inflation, used nearly at its limit
    # every control step's state is a row: simulated time, pressures and jams exactly as recorded
    at = np.searchsorted(t, rows - 1e-9)
    assert s["sim_time_s"][at] == pytest.approx(DT * np.arange(6))
    assert s["ipam0_pressure_kpa"][at] == pytest.approx([0, 0, 40, 80, 120, 120])
    assert s["cell0_jammed"][at].tolist() == [0, 0, 0, 1, 1, 1]
    assert np.flatnonzero(s["control_step"]).tolist() == at.tolist()  # the control steps are marked, only they
    # the run jammed cell 0 at control step 2, then applied step 3's controls: the valve opens on the row after
    # step 2, as the ramp to step 3 begins
    assert s["cell0_jammed"][at[2]] == 0 and np.all(s["cell0_jammed"][at[2] + 1:] == 1)


def test_rate_resamples_on_a_uniform_clock_and_keeps_the_limits():
    s = valve_schedule(_result(), ValveTiming(rate_hz=20.0, max_slew_kpa_s=100.0, max_flow_ml_s=None))
    t = s["time_s"]
    # each interval in whole 50 ms periods: 0.05 + 3 x 0.45 + 0.05
    assert t[0] == 0.0 and t[-1] == pytest.approx(1.45)
    assert np.diff(t) == pytest.approx(np.full(len(t) - 1, 0.05))  # 20 Hz, the end on the grid
    assert np.max(np.abs(np.diff(s["ipam0_pressure_kpa"])) / np.diff(t)) <= 100.0
    assert s["ipam0_pressure_kpa"][-1] == pytest.approx(120.0)
    # cell 0 shows jammed at control step 3 (0.05 + 2 x 0.45 = 0.95 s): the run jammed it at step 2 (0.5 s),
    # so its valve opens on the row after 0.5 s, as the ramp to step 3 begins
    assert np.all(s["cell0_jammed"][t < 0.5 + 1e-9] == 0) and np.all(s["cell0_jammed"][t > 0.5 + 1e-9] == 1)
    assert set(s["phase"].tolist()) == {1, 2, 3}


def test_bad_options_are_clear():
    for kw, msg in ((dict(rate_hz=0.0), "rate"), (dict(max_slew_kpa_s=-1.0), "slew"),
                    (dict(max_flow_ml_s=0.0), "flow"), (dict(max_flow_ml_s=float("nan")), "flow")):
        with pytest.raises(DesignError, match=msg):
            ValveTiming(**kw)
    with pytest.raises(DesignError, match="passive"):
        valve_schedule(_result(), passive="off")


def test_written_csv_and_sidecar(tmp_path):
    paths = write_valve_outputs([_result()], ["heart"], tmp_path)
    assert [p.name for p in paths] == ["valve_heart.csv", "valve_heart.json"]
    with open(tmp_path / "valve_heart.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert float(rows[0]["time_s"]) == 0.0 and float(rows[-1]["ipam0_pressure_kpa"]) == pytest.approx(120.0)
    assert float(rows[-1]["sim_time_s"]) == pytest.approx(0.05)
    assert {r["cell0_jammed"] for r in rows} == {"0", "1"}
    side = json.loads((tmp_path / "valve_heart.json").read_text())
    assert side["passive_ipams"] == [1] and "neutral" in side["passive_note"]
    assert side["columns"]["ipam0_pressure_kpa"] == "kPa gauge, command"
    # a record without frames keeps the simulated chamber pressure and says so
    assert side["chamber_pressure_source"].startswith("simulated") and "measured" not in json.dumps(side)
    assert side["chamber_pressure_source"] in side["columns"]["chamber_pressure_kpa"]
    assert side["duration_s"] == pytest.approx(float(rows[-1]["time_s"]))
    assert side["simulated_duration_s"] == pytest.approx(0.05)
    assert (side["rate_hz"], side["max_slew_kpa_s"], side["max_flow_ml_s"]) == (50.0, 100.0, 5.0)
    assert side["peak"]["flow_ml_s"] <= 5.0 and side["peak"]["slew_kpa_s"] <= 100.0


@pytest.mark.slow
def test_export_writes_valve_files_at_the_requested_pace(tmp_path, capsys):
    from warp_shape.cli import main

    # the Fig. 6 design driven by the paper's law: a sequence of inflation and IPAM steps, in seconds
    fig6 = ws.load_scene("cube_fig6")
    fig6.settings["controller"] = {"method": "paper"}
    scene = ws.save_scene(fig6, tmp_path / "fig6_paper_law.usda")
    rc = main(["export", str(scene), "--what", "control", "--targets", "cube", "--out", str(tmp_path),
               "--rate", "10", "--max-slew", "40", "--max-flow", "2"])
    assert rc == 0
    with open(tmp_path / "valve_cube.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    t = np.array([float(r["time_s"]) for r in rows])
    assert t[0] == 0.0 and np.allclose(np.diff(t), 0.1)  # 10 Hz, the end on the grid
    for col in [c for c in rows[0] if c.endswith("_pressure_kpa")]:
        p = np.array([float(r[col]) for r in rows])
        assert np.max(np.abs(np.diff(p)) / np.diff(t)) <= 40.0, col
    air = np.array([float(r["chamber_air_ml"]) for r in rows])
    assert np.max(np.abs(np.diff(air)) / np.diff(t)) <= 2.0
    side = json.loads((tmp_path / "valve_cube.json").read_text())
    assert side["rate_hz"] == 10.0 and side["max_slew_kpa_s"] == 40.0 and side["max_flow_ml_s"] == 2.0
    assert side["duration_s"] > 5 * side["simulated_duration_s"]


def test_timing_flags_are_checked_before_any_work(tmp_path, monkeypatch, capsys):
    from test_cli import error_of, no_work

    no_work(monkeypatch)
    err = error_of(capsys, ["design", "--max-flow", "-5", "--out", str(tmp_path / "o")])
    assert "--max-flow takes 0 or 0.01..1e+09, got -5" in err
    err = error_of(capsys, ["export", "cube_fig6", "--max-slew", "nan", "--out", str(tmp_path / "e")])
    assert "--max-slew takes 0 or 0.1..1e+09, got nan" in err
    assert not (tmp_path / "o").exists() and not (tmp_path / "e").exists()


def test_the_chamber_pressure_column_is_quasi_static_never_below_atmosphere_while_air_is_added(tmp_path, monkeypatch):
    """The simulated inflation lasts tens of ms and its membrane overshoots, so the simulated chamber
    reads below atmospheric while air is added; the lab plays it over seconds, so the valve file
    gives the pressure at rest under each row's controls: never negative while air is added, rising
    with the air, and the simulated one wherever the run was at rest (its end)."""
    from warp_shape.scenarios import cube_fig6_design

    res = ws.control(cube_fig6_design(subdivisions=2), ws.target("oval"), method="paper", max_steps=40)
    inflating = np.asarray(res.history["phase"]) == 1
    assert np.asarray(res.history["pressure_pa"])[inflating].min() < -1e3  # the transient: below -1 kPa
    write_valve_outputs([res], ["oval"], tmp_path)
    with open(tmp_path / "valve_oval.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    p = np.array([float(r["chamber_pressure_kpa"]) for r in rows])
    air = np.array([float(r["chamber_air_ml"]) for r in rows])
    phase = np.array([int(r["phase"]) for r in rows])
    adding = np.flatnonzero(np.diff(air) > 0) + 1
    assert adding.size > 10 and p[adding].min() >= 0.0
    assert np.all(np.diff(p[phase == 1]) >= -1e-6)  # the inflation: more air, more pressure
    assert p[-1] == pytest.approx(res.history["pressure_pa"][-1] / 1e3, rel=0.01)  # at rest both agree
    side = json.loads((tmp_path / "valve_oval.json").read_text())
    assert side["chamber_pressure_source"] == "quasi-static"
    import warp_shape.io.valve as valve

    whole = valve.quasi_static_pressure(res)[0]
    monkeypatch.setattr(valve, "SETTLE_WORLDS", 16)  # settled in chunks of control steps: the same pressures
    np.testing.assert_allclose(valve.quasi_static_pressure(res)[0], whole, rtol=1e-6, atol=1e-3)
