"""Valve-ready sequences: lab units (kPa gauge, mL of air at atmospheric pressure), time from 0 in
seconds, passive IPAMs named, and re-timing for real valves (slew limit, uniform rate)."""

from __future__ import annotations

import csv
import json
from types import SimpleNamespace

import numpy as np
import pytest

from warp_shape.errors import DesignError
from warp_shape.io.valve import row_times, valve_schedule, write_valve_outputs
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


def test_units_and_columns_one_row_per_step():
    s = valve_schedule(_result(), rate_hz=None, max_slew_kpa_s=None)
    assert list(s) == ["time_s", "phase", "ipam0_pressure_kpa", "ipam1_pressure_kpa", "chamber_pressure_kpa",
                       "chamber_air_ml", "chamber_air_added_ml", "cell0_jammed", "cell1_jammed"]
    assert s["time_s"] == pytest.approx(DT * np.arange(6))  # from 0, simulated pace
    assert s["ipam0_pressure_kpa"] == pytest.approx([0, 0, 40, 80, 120, 120])  # kPa, not Pa
    assert s["chamber_pressure_kpa"][-1] == pytest.approx(1.5)
    # 0.010 mol at 293.15 K and 101.325 kPa: 240.55 mL (n R T / p_atm)
    assert s["chamber_air_ml"][0] == pytest.approx(0.010 * GAS_CONSTANT * 293.15 / 101325.0 * 1e6, rel=1e-9)
    assert s["chamber_air_ml"][0] == pytest.approx(240.55, abs=0.01)
    assert s["chamber_air_added_ml"][-1] == pytest.approx(48.11, abs=0.01)  # 2 mmol dosed
    assert s["cell0_jammed"].tolist() == [0, 0, 0, 1, 1, 1]
    zero = valve_schedule(_result(), rate_hz=None, max_slew_kpa_s=None, passive="zero")
    assert np.all(zero["ipam1_pressure_kpa"] == 0.0) and zero["ipam0_pressure_kpa"][-1] == pytest.approx(120)


def test_slew_limit_stretches_fast_steps_only():
    t = row_times(_result(), max_slew_kpa_s=100.0)
    # the 40 kPa steps take 0.4 s at 100 kPa/s; the slow steps keep their 10 ms
    assert np.diff(t) == pytest.approx([0.01, 0.4, 0.4, 0.4, 0.01])
    s = valve_schedule(_result(), rate_hz=None, max_slew_kpa_s=100.0)
    for col in ("ipam0_pressure_kpa", "ipam1_pressure_kpa", "chamber_pressure_kpa"):
        assert np.max(np.abs(np.diff(s[col])) / np.diff(s["time_s"])) <= 100.0 + 1e-9
    # a pump flow limit stretches the inflation: 24.055 mL per step at 10 mL/s takes 2.4055 s
    tf = row_times(_result(), max_slew_kpa_s=None, max_flow_ml_s=10.0)
    assert np.diff(tf)[:2] == pytest.approx([2.4055, 2.4055], abs=1e-3)


def test_rate_resamples_on_a_uniform_clock_and_keeps_the_slew_limit():
    s = valve_schedule(_result(), rate_hz=20.0, max_slew_kpa_s=100.0)
    t = s["time_s"]
    assert t[0] == 0.0 and t[-1] == pytest.approx(1.22)  # stretched end: 0.01 + 3 x 0.4 + 0.01
    assert np.diff(t)[:-1] == pytest.approx(np.full(len(t) - 2, 0.05))  # 20 Hz, last sample at the end
    assert np.max(np.abs(np.diff(s["ipam0_pressure_kpa"])) / np.diff(t)) <= 100.0 + 1e-9
    assert s["ipam0_pressure_kpa"][-1] == pytest.approx(120.0)
    # cell 0 jams at row 3, stretched to 0.81 s: held 0 before, 1 from then on
    assert np.all(s["cell0_jammed"][t < 0.81 - 1e-9] == 0) and np.all(s["cell0_jammed"][t >= 0.81] == 1)
    assert set(s["phase"].tolist()) == {1, 2, 3}


def test_bad_options_are_clear():
    for kw, msg in ((dict(rate_hz=0.0), "rate"), (dict(max_slew_kpa_s=-1.0), "slew"),
                    (dict(passive="off"), "passive"), (dict(max_flow_ml_s=0.0), "flow")):
        with pytest.raises(DesignError, match=msg):
            valve_schedule(_result(), **kw)


def test_written_csv_and_sidecar(tmp_path):
    paths = write_valve_outputs([_result()], ["heart"], tmp_path, rate_hz=50.0, max_slew_kpa_s=100.0)
    assert [p.name for p in paths] == ["valve_heart.csv", "valve_heart.json"]
    with open(tmp_path / "valve_heart.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert float(rows[0]["time_s"]) == 0.0 and float(rows[-1]["ipam0_pressure_kpa"]) == pytest.approx(120.0)
    assert {r["cell0_jammed"] for r in rows} == {"0", "1"}
    side = json.loads((tmp_path / "valve_heart.json").read_text())
    assert side["passive_ipams"] == [1] and "neutral" in side["passive_note"]
    assert side["columns"]["ipam0_pressure_kpa"] == "kPa gauge"
    assert side["duration_s"] == pytest.approx(float(rows[-1]["time_s"]))
    assert side["simulated_duration_s"] == pytest.approx(0.05)


@pytest.mark.slow
def test_export_writes_valve_files_at_the_requested_pace(tmp_path, capsys):
    from warp_shape.cli import main

    rc = main(["export", "cube_fig6", "--what", "control", "--targets", "cube", "--out", str(tmp_path),
               "--rate", "10", "--max-slew", "40"])
    assert rc == 0
    with open(tmp_path / "valve_cube.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    t = np.array([float(r["time_s"]) for r in rows])
    assert t[0] == 0.0 and np.allclose(np.diff(t)[:-1], 0.1)  # 10 Hz
    for col in [c for c in rows[0] if c.endswith("_pressure_kpa")]:
        p = np.array([float(r[col]) for r in rows])
        assert np.max(np.abs(np.diff(p)) / np.diff(t)) <= 40.05, col  # 6 significant digits in the CSV
    side = json.loads((tmp_path / "valve_cube.json").read_text())
    assert side["rate_hz"] == 10.0 and side["max_slew_kpa_s"] == 40.0
    assert side["duration_s"] > 5 * side["simulated_duration_s"]
