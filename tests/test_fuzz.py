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


# ------------------------------------------------------------------ the command line: folders, faults, sizes
@pytest.mark.slow
def test_fuzz_cli_folders_faults_and_sizes_lose_nothing_and_answer_in_one_line(tmp_path):
    """Every --out kind, a fault at every phase of a design run (each phase once), every bounded flag
    past its bounds: one-line refusals or runs that kept every file, never anything else."""
    fz = _fuzz_module()
    res = fz.fuzz_cli(30, seed=1, folder=tmp_path, faults=len(fz.PHASES))
    assert res["others"] == []
    c = res["counts"]
    assert c["folders"]["clear"] > 5 and c["folders"]["valid"] > 5, dict(c["folders"])
    assert c["sizes"]["clear"] == 30
    assert c["faults"]["clear"] >= len(fz.PHASES) - 2, dict(c["faults"])  # nearly every phase met its fault


def test_fuzz_cli_detects_a_swap_that_loses_the_users_files(tmp_path, monkeypatch):
    """The harness itself: a folder check that lets everything through is caught (user files lost or
    a folder accepted that holds what a run may not replace)."""
    import warp_shape.io.atomic as atomic

    fz = _fuzz_module()
    monkeypatch.setattr(atomic.StagedFolder, "check", lambda self, replaced=True: None)
    res = fz.fuzz_cli(12, seed=1, folder=tmp_path, faults=0)
    assert res["counts"]["folders"]["other"] > 0
    assert any("accepted" in o or "lost" in o for o in res["others"])


# ------------------------------------------------------------------ special files, sizes and types
def test_fuzz_special_files_sizes_and_types_are_all_refused(tmp_path):
    """The fixed special cases (FIFOs, /dev/zero links and folders for every file reader and composed by
    scenes; absurd sizes; strings for booleans; fractions for counts): each refused with a clear error
    (manifests that are no regular file read as none, an OBJ naming a FIFO reads without it), none
    accepted, none blocking."""
    fz = _fuzz_module()
    counts, others = fz.fuzz_special(tmp_path, fz.base_files(tmp_path), timeout=20.0)
    assert others == []
    assert counts["clear"] > 150 and counts["valid"] == 5, dict(counts)  # valid: 4 special manifests, 1 OBJ


# ------------------------------------------------------------------ inputs: locks, recordings, schemas, units
def test_fuzz_inputs_lose_nothing_and_accept_nothing_wrong(tmp_path):
    """Locks that are links, folders, user files or stale; --rerun onto inputs, files and outputs;
    misspelt manifest keys and odd manifest values; sizes in mm or mm^2 given as SI: each refused in
    one line with every file as it was, or (a stale lock, a valid value) accepted, never anything else."""
    res = _fuzz_module().fuzz_inputs(60, seed=1, folder=tmp_path)
    assert res["others"] == []
    assert res["counts"]["clear"] >= 40 and res["counts"]["valid"] >= 3, dict(res["counts"])


def test_fuzz_inputs_detect_a_misspelt_key_accepted_and_a_lock_through_a_link(tmp_path, monkeypatch):
    """The harness itself: a manifest read that ignores unknown keys, and a lock that follows links and
    truncates, are counted as silent and as data loss."""
    import os

    import warp_shape.calibration.files as files
    import warp_shape.io.atomic as atomic

    monkeypatch.setattr(files, "_known_keys", lambda *a: None)

    def following(path, busy):  # the lock before: opened through a link, truncated
        fd = os.open(path, os.O_CREAT | os.O_RDWR, 0o644)
        os.ftruncate(fd, 0)
        os.write(fd, str(os.getpid()).encode())
        return fd

    monkeypatch.setattr(atomic, "hold_lock", following)
    res = _fuzz_module().fuzz_inputs(20, seed=1, folder=tmp_path)
    assert any("silent: " in o for o in res["others"]) and any("data loss" in o for o in res["others"])
