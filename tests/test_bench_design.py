"""``bench design --baseline``'s probe: a baseline checkout's package imported in place of the
installed one (every mapped package folder; the hook runs at the start of every Python process, the
run's spawned workers too), and phases timed once however their calls nest."""

from __future__ import annotations

import subprocess
import sys
import threading
import time

import pytest

from warp_shape.benchmarks import design as design_bench
from warp_shape.benchmarks import design_phases
from warp_shape.errors import DesignError


def _fake_checkout(root):
    (root / "warp_shape").mkdir(parents=True)
    (root / "warp_shape" / "__init__.py").write_text("WHERE = 'baseline'\n")
    (root / "kernels").mkdir()
    (root / "kernels" / "__init__.py").write_text("")
    (root / "kernels" / "adjoint.py").write_text("WHERE = 'baseline kernels'\n")
    (root / "pyproject.toml").write_text('[project]\nname = "x"\n\n[tool.setuptools.package-dir]\n'
                                         '"warp_shape" = "warp_shape"\n"warp_shape.kernels" = "kernels"\n\n'
                                         '[tool.other]\nkey = "v"\n')


def test_a_process_started_with_the_probes_hook_imports_the_baselines_package_and_mapped_folders(tmp_path):
    _fake_checkout(tmp_path / "base")
    site = design_phases.write_site_hook(tmp_path / "site")
    code = ("import warp_shape, warp_shape.kernels.adjoint as a\n"
            "print(warp_shape.WHERE, '|', a.WHERE)\n")
    env = {design_phases.SOURCE_VARIABLE: str(tmp_path / "base"), "PYTHONPATH": str(site)}
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "baseline | baseline kernels"
    # without the variable the installed package: the hook does nothing
    out = subprocess.run([sys.executable, "-c", "import warp_shape; print(hasattr(warp_shape, 'WHERE'))"],
                         env={"PYTHONPATH": str(site)}, capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


def test_a_phase_nested_in_itself_or_on_two_threads_at_once_counts_its_wall_time_once():
    clock = design_phases.PhaseClock()
    clock.enter("p")
    clock.enter("p")  # nested
    threads = [threading.Thread(target=lambda: (clock.enter("p"), time.sleep(0.05), clock.leave("p"))) for _ in range(2)]
    t0 = time.perf_counter()
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    clock.leave("p")
    clock.leave("p")
    wall = time.perf_counter() - t0
    assert clock.calls["p"] == 4
    assert clock.seconds["p"] == pytest.approx(wall, abs=0.02)  # once, not 2 x 0.05 s on top


def test_an_unknown_baseline_commit_is_named_before_anything_runs():
    with pytest.raises(DesignError, match="git rev-parse"):
        design_bench.bench_design_phases("no-such-commit-abc", repeats=1)
