"""The command line and the README example."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np

from warp_shape.cli import main

ROOT = Path(__file__).resolve().parents[1]


def test_simulate_writes_results_and_reproduces_fig6_signs(tmp_path, capsys):
    rc = main(["simulate", "--inflate-time", "0.15", "--actuate-time", "0.15", "--subdivisions", "2",
               "--out", str(tmp_path)])
    assert rc == 0
    data = json.loads((tmp_path / "simulate.json").read_text())
    inflated, actuated = data["frames"][1], data["frames"][2]
    assert inflated["volume"] > 1.3 * data["frames"][0]["volume"]
    forces = np.array(actuated["ipam_force"])
    # paper, section IV-C: corner IPAMs push (compression), the face IPAM pulls (tension)
    assert np.all(forces[:4] < 0) and forces[4] > 0
    assert not list(tmp_path.glob(".*"))  # no temporary files left behind
    assert "IPAM axial force" in capsys.readouterr().out


def test_cli_reports_bad_input_cleanly(capsys):
    rc = main(["simulate", "--device", "cuda:9", "--inflate-time", "0.01", "--actuate-time", "0.01"])
    assert rc == 2
    assert "not available" in capsys.readouterr().err


def test_readme_example_runs():
    text = (ROOT / "README.md").read_text()
    block = re.search(r"```python\n(.*?)```", text, re.S).group(1)
    namespace: dict = {}
    exec(compile(block, "README.md", "exec"), namespace)
    sim = namespace["sim"]
    assert sim.jammed.all() and sim.pressure() > 0 and np.isfinite(sim.positions).all()


def test_control_command_writes_sequences(tmp_path, capsys):
    rc = main(["control", "--target", "cube", "--out", str(tmp_path), "--max-steps", "60", "--method", "paper"])
    assert rc == 0
    data = json.loads((tmp_path / "control_cube.json").read_text())
    rows = (tmp_path / "control_cube.csv").read_text().strip().splitlines()
    assert len(rows) == len(data["rows"]) + 1 and rows[0].startswith("step,time,phase,air_mol")
    forces = np.array(data["ipam_forces_n"])
    assert np.all(forces[:4] < 0) and forces[4] > 0
    out = capsys.readouterr().out
    assert "cube" in out and "IPAM 4" in out


def test_control_command_records_rerun(tmp_path):
    from warp_shape.io.recording_read import read_recording

    rrd = tmp_path / "run.rrd"
    rc = main(["control", "--target", "cube", "--out", str(tmp_path), "--max-steps", "15", "--method", "paper",
               "--rerun", str(rrd)])
    assert rc == 0 and rrd.stat().st_size > 1000
    rec = read_recording(rrd)
    data = json.loads((tmp_path / "control_cube.json").read_text())
    membrane = rec["entities"]["/control/cube/membrane"]
    assert len(membrane["times"]["control_step"]) == len(data["rows"])
    assert (tmp_path / "control_cube.png").exists()
