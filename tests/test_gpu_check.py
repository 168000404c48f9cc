"""The device check (scripts/gpu_check.sh) end to end on the CPU with its tiny plan, and the batched
worlds of ``warp-shape bench sim --worlds``: files written, figures sane and consistent."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from warp_shape.benchmarks.gpu_check import PLANS
from warp_shape.cli import main

ROOT = Path(__file__).resolve().parents[1]


def _consistent(row: dict) -> None:
    """The rates of one bench row agree with each other (to their rounding)."""
    V, W = row["vertices"], row["worlds"]
    assert row["steps_per_s"] > 0 and row["vertex_steps_per_s"] > 0 and row["us_per_step"] > 0
    assert row["vertex_steps_per_s"] == pytest.approx(row["steps_per_s"] * V * W, rel=2e-3)
    assert row["ns_per_vertex_step"] == pytest.approx(1e9 / row["vertex_steps_per_s"], rel=2e-3)
    assert row["us_per_step"] == pytest.approx(1e6 / row["steps_per_s"], rel=2e-3)


@pytest.fixture(scope="module")
def check(tmp_path_factory):
    """One run of the whole check on the CPU: install skipped (Warp is importable), the project
    staged into a fresh folder, the CUDA tests as a dry run on the CPU, both benches."""
    tmp = tmp_path_factory.mktemp("gpu_check")
    out = tmp / "results"
    env = dict(os.environ, PYTHON=sys.executable, GPU_CHECK_SITE=str(tmp / "site"))
    proc = subprocess.run(["bash", str(ROOT / "scripts" / "gpu_check.sh"), "--device", "cpu", "--tiny",
                           "--out", str(out)], cwd=ROOT, env=env, capture_output=True, text=True, timeout=600)
    return proc, out, tmp / "site"


def test_check_runs_end_to_end_and_names_its_files(check):
    proc, out, _ = check
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    assert "warp importable: install skipped" in proc.stdout
    assert f"results: {out.resolve()}/gpu_check.json {out.resolve()}/gpu_check.md" in proc.stdout
    assert (out / "gpu_check.json").is_file() and (out / "gpu_check.md").is_file()


def test_check_json_holds_sane_figures(check):
    _, out, site = check
    result = json.loads((out / "gpu_check.json").read_text())
    plan = PLANS["tiny"]
    assert result["plan"] == "tiny" and result["environment"]["device"] == "cpu"
    # the staged copy of the project was measured, not the source tree
    assert Path(result["environment"]["package"]) == (site / "warp_shape").resolve()
    tests = result["tests"]
    assert tests["ok"] and tests["passed"] >= 8 and tests["failures"] == tests["errors"] == 0
    steps = result["steps"]
    asked = [(10 * 4**s + 2, w) for s in plan["subdivisions"] for w in plan["worlds"]]
    assert [(r["vertices"], r["worlds"]) for r in steps] == asked  # one row per size x worlds asked
    for r in steps:
        assert r["integrator"] == "rk4" and r["precision"] == "float32" and r["launch_mode"] == "graph"
        _consistent(r)
    (design,) = result["design"]
    assert design["wall_s"] > 0 and design["control_steps"] > 0
    assert all(0 < float(p) <= 1 for p in design["final_pcc"].split())
    assert set(result["phases_s"]) == {"tests", "steps", "design", "total"}


def test_check_markdown_has_a_row_per_case(check):
    _, out, _ = check
    md = (out / "gpu_check.md").read_text()
    assert md.startswith("# Device check (tiny plan)")
    for w in PLANS["tiny"]["worlds"]:
        assert f"\n| 42 | {w} | " in md
    assert "vertex-RK4-steps/s" in md and "| tiny | oval heart | 1 |" in md


def test_bench_sim_worlds_option(tmp_path, capsys):
    assert main(["bench", "sim", "--subdivisions", "1", "--worlds", "1", "2", "--repeats", "1",
                 "--out", str(tmp_path)]) == 0
    printed = capsys.readouterr().out
    assert "worlds" in printed.splitlines()[0] and "vertex_steps_per_s" in printed.splitlines()[0]
    rows = json.loads((tmp_path / "bench_sim.json").read_text())["sim"]
    assert sorted({(r["worlds"], r["integrator"], r["precision"]) for r in rows}) == sorted(
        (w, i, p) for w in (1, 2) for i in ("rk4", "semi_implicit") for p in ("float32", "float64"))
    for r in rows:
        _consistent(r)
        # the NumPy baseline steps one world: the ratio compares vertex-steps per second
        assert r["speedup_vs_numpy"] == pytest.approx(r["worlds"] * r["steps_per_s"] / r["numpy_steps_per_s"], rel=0.05)


def test_bench_sim_refuses_zero_worlds(tmp_path, capsys):
    assert main(["bench", "sim", "--subdivisions", "1", "--worlds", "0", "--out", str(tmp_path)]) != 0
    assert "--worlds takes 1..4096, got 0" in capsys.readouterr().err
