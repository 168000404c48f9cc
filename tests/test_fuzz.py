"""Seeded, bounded fuzz of the API and the scene / mesh loaders (scripts/fuzz_counts.py, smaller N):
every case ends in a warp_shape error or a valid result (a simulator stepping to finite values, a
scene, a mesh); never another exception type, NaN, or a case running past its time limit."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "fuzz_counts.py"


def _fuzz_module():
    spec = importlib.util.spec_from_file_location("fuzz_counts", SCRIPT)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


@pytest.mark.slow
def test_fuzz_api_and_files_gives_clear_errors_or_valid_results(tmp_path):
    res = _fuzz_module().fuzz(400, seed=1, timeout=20.0, folder=tmp_path)
    counts = res["counts"]
    assert res["others"] == []
    for family in ("api", "files"):
        c = counts[family]
        assert sum(c.values()) == 400
        # the cases exercise both sides: clear refusals and runs that are valid
        assert c["clear"] > 30 and c["valid"] > 5, dict(c)


def test_fuzz_detects_a_foreign_exception_nan_and_a_hang():
    """The harness itself: a ValueError, a NaN result and an endless case count as "other"."""
    import numpy as np

    import warp_shape as ws

    fz = _fuzz_module()
    assert fz.outcome(lambda: int("x"), 5)[0] == "other"
    assert fz.outcome(lambda: ws.Material(youngs_modulus=-1), 5) == ("clear", "DesignError")
    nan_mesh = ws.TriMesh(ws.icosphere(0, 0.04).vertices * np.nan, ws.icosphere(0, 0.04).faces, validate=False)
    assert fz.outcome(lambda: nan_mesh, 5)[0] == "other"

    def endless():
        while True:
            pass

    assert fz.outcome(endless, 0.2) == ("other", "hang (over 0.2 s)")
