"""Units and plausibility on the command line: scans and references in millimetres or metres, the
design's actuated shape as a reference, length flags checked against the device before any work."""

from __future__ import annotations

import json
import re
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import warp_shape as ws
from warp_shape.cli import main
from warp_shape.cli.progress import without_progress

ROOT = Path(__file__).resolve().parents[1]
R = 0.04


def error_of(capsys, argv) -> str:
    """The one line of error a command ends with (exit status 2)."""
    assert main(argv) == 2, argv
    err = without_progress(capsys.readouterr().err)  # a log's progress lines, then the error
    assert re.match(r"warp-shape( compare)?: error: ", err) and "Traceback" not in err and err.count("\n") == 1, err
    return err


def _stl(path, mesh: ws.TriMesh, scale: float = 1.0, noise: float = 0.0) -> Path:
    m = mesh.to_trimesh()
    if noise:
        m.vertices = m.vertices + np.random.default_rng(3).normal(0.0, noise, m.vertices.shape)
    m.apply_scale(scale)
    m.export(str(path))
    return path


# ------------------------------------------------------------------------------------------ compare units
@pytest.fixture(scope="module")
def mm_files(tmp_path_factory):
    """The oval target as a noisy scan and as a clean reference, both in millimetres."""
    d = tmp_path_factory.mktemp("mm")
    oval = ws.target("oval")
    return _stl(d / "scan_mm.stl", oval, 1e3, noise=4e-4), _stl(d / "oval_mm.stl", oval, 1e3)


def _compare(capsys, *argv) -> dict:
    assert main(["compare", *map(str, argv), "--json"]) == 0
    return json.loads(capsys.readouterr().out)


def test_compare_reads_millimetre_files_as_millimetres(mm_files, capsys):
    scan, ref = mm_files
    truth = _compare(capsys, scan, "--to", "oval", "--units", "mm")
    assert truth["scan_units"] == "mm" and truth["reference_units"] == "m"
    assert 1e-4 < truth["mare_m"] < 1e-3  # the 0.4 mm noise, in metres
    for reference in ("oval", ref):  # detected: against a shipped target and against a millimetre STL
        res = _compare(capsys, scan, "--to", reference)
        assert res["scan_units"] == "mm" and res["mare_m"] == pytest.approx(truth["mare_m"], rel=0.05)
    assert res["reference_units"] == "mm"
    assert main(["compare", str(scan), "--to", str(ref)]) == 0
    table = capsys.readouterr().out
    assert "(read in millimetres)" in table and f"MARE         {truth['mare_m'] * 1e3:.3f} mm" in table


def test_compare_refuses_a_unit_that_makes_no_display(mm_files, capsys):
    scan, ref = mm_files
    err = error_of(capsys, ["compare", str(scan), "--to", "oval", "--units", "m"])
    assert re.search(r"the scan is 10\d\.\d m across read in m", err) and "--units mm" in err
    err = error_of(capsys, ["compare", str(scan), "--to", str(ref), "--reference-units", "m"])
    assert "the reference is 101.3 m across read in m" in err


# --------------------------------------------------------------------------------- compare with a design
@pytest.fixture(scope="module")
def design_folder(tmp_path_factory):
    """A design folder as `design` writes it: design.usda and the actuated run of its target, here a
    sphere growing to 1.2x its rest radius at 1 s of the schedule and 1.5x at 2 s."""
    from warp_shape.io.scene_schema import Scene
    from warp_shape.io.scene_write import save_scene
    from warp_shape.io.usd_animation import export_animation

    d = tmp_path_factory.mktemp("design")
    rest = ws.icosphere(2, R)
    design = ws.Design(rest)
    blob = ws.icosphere(2, 1.2 * R)
    save_scene(Scene(design=design, targets=[blob], target_names=["blob"]), d / "design.usda")
    frames = [rest.vertices * s for s in (1.0, 1.2, 1.5)]
    export_animation(d / "actuation_blob.usdc", design, frames, [0.0, 1.0, 2.0], targets=[blob], target_names=["blob"])
    return d, _stl(d / "scan_mm.stl", blob, 1e3)


def test_compare_with_the_designs_actuated_shape(design_folder, capsys):
    d, scan = design_folder
    at_1s = _compare(capsys, scan, "--to", d / "design.usda", "--time", "1")
    assert at_1s["mare_m"] < 1e-5 and at_1s["scan_units"] == "mm"
    assert "target blob, simulated shape at 1.000 of 2.000 s" in at_1s["reference"]
    achieved = _compare(capsys, scan, "--to", d / "actuation_blob.usdc")  # default: the end of the schedule
    assert 0.25 * R < achieved["mare_m"] < 0.3 * R  # 0.3 R apart, less what ICP's shift takes up
    halfway = _compare(capsys, scan, "--to", d / "design.usda", "--target", "blob", "--time", "0.5")
    assert halfway["mare_m"] == pytest.approx(0.1 * R, rel=0.05)  # interpolated between the samples: 1.1 R
    err = error_of(capsys, ["compare", str(scan), "--to", str(d / "design.usda"), "--time", "3"])
    assert "--time 3 s lies outside the run of target blob (0 to 2 s" in err
    err = error_of(capsys, ["compare", str(scan), "--to", str(d / "design.usda"), "--target", "oval"])
    assert "has no target 'oval'; its targets: blob" in err
    err = error_of(capsys, ["compare", str(scan), "--to", "oval", "--time", "1"])
    assert "--to oval is not a design" in err


def test_compare_names_the_missing_run_of_a_design(design_folder, tmp_path, capsys):
    d, scan = design_folder
    (tmp_path / "design.usda").write_bytes((d / "design.usda").read_bytes())
    err = error_of(capsys, ["compare", str(scan), "--to", str(tmp_path / "design.usda")])
    assert "no actuation_blob.usdc beside" in err and "warp-shape export" in err


# ------------------------------------------------------------------------------- length flags, before work
def no_work(monkeypatch):
    """Any design, control run or mold making fails loudly: the checks must come first (patched where
    the commands look them up)."""
    import warp_shape.cli.design as design_cli
    import warp_shape.cli.export as export
    import warp_shape.designer.loop as designer_loop

    def forbidden(*args, **kwargs):
        raise AssertionError("work started before the inputs were checked")

    monkeypatch.setattr(designer_loop, "control_many", forbidden)
    for module, name in ((export, "control_many"), (export, "write_molds"), (design_cli, "write_design_outputs")):
        monkeypatch.setattr(module, name, forbidden)


@pytest.mark.parametrize("flag, value, expect", [
    ("--layer-thickness", "5", "--layer-thickness 5 m is no jamming layer for a device 37 mm in radius: give "
                               "metres, 0 < --layer-thickness <= 0.0186; if 5 is millimetres: --layer-thickness 0.005"),
    ("--layer-thickness", "-1", "0 < --layer-thickness <= 0.0186"),
    ("--layer-thickness", "nan", "--layer-thickness nan is no jamming layer"),
    ("--layer-thickness", "0", "--layer-thickness 0 m is no jamming layer"),
    ("--layer-thickness", "inf", "--layer-thickness inf is no jamming layer"),
    ("--marker-height", "nan", "--marker-height nan is no IPAM marker for a device 37 mm in radius: give metres, "
                               "0 <= --marker-height <= 0.00928"),
    ("--marker-height", "-1", "--marker-height -1 m is no IPAM marker"),
    ("--marker-height", "2", "if 2 is millimetres: --marker-height 0.002"),
])
def test_design_length_flags_are_checked_against_the_device_first(tmp_path, monkeypatch, capsys, flag, value, expect):
    no_work(monkeypatch)
    err = error_of(capsys, ["design", flag, value, "--out", str(tmp_path / "out")])
    assert expect in err
    assert not (tmp_path / "out").exists() and not list(tmp_path.iterdir())  # nothing left, not even a lock


@pytest.mark.parametrize("flag, value", [("--layer-thickness", "3"), ("--layer-thickness", "inf"),
                                         ("--marker-height", "nan"), ("--marker-height", "-1")])
def test_export_length_flags_are_checked_against_the_device_first(tmp_path, monkeypatch, capsys, flag, value):
    no_work(monkeypatch)
    err = error_of(capsys, ["export", "cube_fig6", flag, value, "--out", str(tmp_path / "out")])
    assert f"{flag} {value}" in err and "for a device 35 mm in radius" in err
    assert not (tmp_path / "out").exists()
    with pytest.raises(AssertionError, match="work started"):  # the guard holds: valid flags reach the work
        main(["export", "cube_fig6", "--what", "molds", "--out", str(tmp_path / "out")])


def test_mold_lengths_of_the_api_are_checked_too():
    from warp_shape.errors import DesignError
    from warp_shape.molds import mold_set

    design = ws.Design(ws.icosphere(1, R))
    for kw in (dict(marker_height=float("nan")), dict(layer_thickness=float("inf")), dict(layer_thickness=5.0)):
        with pytest.raises(DesignError, match="is no (jamming layer|IPAM marker) for a device 3[0-9] mm in radius"):
            mold_set(design, **kw)


def test_a_run_that_fails_after_taking_the_lock_leaves_no_lock_file(tmp_path, monkeypatch, capsys):
    no_work(monkeypatch)
    err = error_of(capsys, ["design", "--actuators", "30", "--subdivisions", "2", "--out", str(tmp_path / "o")])
    assert "30 actuators need about" in err  # found by the designer, once the run holds its lock
    assert not list(tmp_path.iterdir())


# ------------------------------------------------------------------------------------- target files
def test_target_files_are_read_in_their_unit_and_named_in_errors(mm_files, tmp_path, monkeypatch, capsys):
    import trimesh

    no_work(monkeypatch)
    _, oval_mm = mm_files
    err = error_of(capsys, ["design", "--targets", str(oval_mm), "--units", "m", "--out", str(tmp_path / "o")])
    assert f"target file {oval_mm} is 101.3 m across read in m" in err and "is it in mm? (--units mm or auto)" in err
    assert "centimetres" not in err  # 101 mm is a display, 101 cm hardly: millimetres are named
    err = error_of(capsys, ["control", "--targets", str(oval_mm), "--units", "m", "--out", str(tmp_path / "o")])
    assert f"target file {oval_mm} is 101.3 m across" in err
    with pytest.raises(AssertionError, match="work started"):  # read in millimetres, the design starts
        main(["design", "--targets", str(oval_mm), "--out", str(tmp_path / "o")])
    assert f"target file {oval_mm}: read in millimetres (101 mm across)" in capsys.readouterr().err
    cm = _stl(tmp_path / "oval_cm.stl", ws.target("oval"), 100.0)
    err = error_of(capsys, ["design", "--targets", str(cm), "--out", str(tmp_path / "o")])
    assert "is 10.13 units across: neither metres nor millimetres give a display" in err
    torus = tmp_path / "torus.stl"
    trimesh.creation.torus(0.04, 0.015).export(str(torus))
    err = error_of(capsys, ["design", "--targets", str(torus), "--out", str(tmp_path / "o")])
    assert err.startswith(f"warp-shape: error: target file {torus} is not star-shaped") and len(err) - len(str(torus)) < 400
    assert "origin is not enclosed" in err and "target 0" not in err


# ------------------------------------------------------------------------- late checks and tracebacks
def test_export_and_sweep_check_their_inputs_before_any_work(tmp_path, monkeypatch, capsys):
    no_work(monkeypatch)
    a_file = tmp_path / "a_file"
    a_file.write_text("x")
    err = error_of(capsys, ["export", "cube_fig6", "--out", str(a_file)])
    assert f"--out {a_file} is a file, not a folder" in err
    err = error_of(capsys, ["sweep", "grid", "--param", "actuators=1,2", "--backend", "serial", "--out", str(a_file)])
    assert f"--out {a_file} is a file, not a folder" in err
    err = error_of(capsys, ["sweep", "grid", "--param", "actuators=1,2", "--backend", "serial", "--out",
                            str(a_file / "sub")])
    assert f"{a_file} is a file, not a folder" in err
    err = error_of(capsys, ["export", "cube_fig6", "--rate", "-5", "--out", str(tmp_path / "out")])
    assert "--rate takes 0 or" in err and "got -5" in err
    mesh = _stl(tmp_path / "oval.stl", ws.target("oval"))
    err = error_of(capsys, ["export", str(mesh), "--out", str(tmp_path / "out")])
    assert f"{mesh} is not a USD scene (.usda, .usdc, .usd)" in err and "pxr" not in err
    assert not (tmp_path / "out").exists()


def _cli(*argv, code: str | None = None):
    cmd = [sys.executable, "-c", code] if code else [sys.executable, "-m", "warp_shape.cli", *argv]
    return subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT, timeout=300)


def test_an_absent_cuda_device_is_one_line_of_our_own():
    import warp as wp

    if wp.is_cuda_available():
        pytest.skip("this machine has CUDA: the device is there")
    run = _cli("simulate", "--device", "cuda", "--inflate-time", "0.01", "--actuate-time", "0.01")
    assert run.returncode == 2 and run.stderr.count("\n") == 1, run.stderr
    assert run.stderr.startswith("warp-shape: error: device 'cuda' is not available") and "Warp CUDA" not in run.stderr


def test_compare_and_sweep_check_the_device_first(tmp_path, monkeypatch, capsys):
    import warp as wp

    if wp.is_cuda_available():
        pytest.skip("this machine has CUDA: the device is there")
    no_work(monkeypatch)
    err = error_of(capsys, ["compare", str(ROOT / "scenes" / "targets" / "oval.ply"), "--to", "oval", "--device", "cuda"])
    assert "device 'cuda' is not available" in err
    err = error_of(capsys, ["sweep", "grid", "--param", "actuators=1", "--device", "cuda", "--backend", "serial",
                            "--out", str(tmp_path / "sw")])
    assert "device 'cuda' is not available" in err and not (tmp_path / "sw").exists()


def test_the_readme_api_example_prints_only_its_own_result():
    block = re.search(r"```python\n(.*?)```", (ROOT / "README.md").read_text(), re.S).group(1)
    run = _cli(code=block)
    assert run.returncode == 0, run.stderr
    printed = (run.stdout + run.stderr).splitlines()
    assert not [ln for ln in printed if ln.startswith(("Module ", "Warp 1.", "   "))], printed
    assert len(run.stdout.splitlines()) == 1  # the example's one print


# ------------------------------------------------------------------------------------------------ help
def _parsers(parser, name="warp-shape"):
    import argparse

    yield name, parser
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for sub, child in action.choices.items():
                yield from _parsers(child, f"{name} {sub}")


def test_every_command_has_a_description_and_every_option_help():
    import argparse

    from warp_shape.cli import build_parser

    for name, parser in _parsers(build_parser()):
        has_sub = any(isinstance(a, argparse._SubParsersAction) for a in parser._actions)
        assert parser.description or has_sub, f"{name} has no description"
        for action in parser._actions:
            if action.help != argparse.SUPPRESS and not isinstance(action, argparse._SubParsersAction):
                assert action.help, f"{name} {action.option_strings or action.dest} has no help text"


# -------------------------------------------------------------------------------------- small things
def test_sweeping_a_mold_length_says_what_it_is(tmp_path, monkeypatch, capsys):
    no_work(monkeypatch)
    err = error_of(capsys, ["sweep", "grid", "--param", "layer_thickness=0.003,0.005", "--backend", "serial",
                            "--out", str(tmp_path / "sw")])
    assert "layer_thickness is a mold length (warp-shape design/export --layer-thickness, m)" in err
    assert "material.thickness" not in err and not (tmp_path / "sw").exists()


def test_the_package_metadata_builds_without_license_warnings():
    """setuptools from 77 on warns about the license table and setuptools before 77 refuses the SPDX
    string that replaces it: the build requirement keeps isolated builds below 77, and the metadata
    reads here (setuptools of builds without isolation) without a warning of its own."""
    import tomllib
    import warnings

    from packaging.requirements import Requirement
    from setuptools.config.pyprojecttoml import read_configuration

    data = tomllib.loads((ROOT / "pyproject.toml").read_text())
    setuptools_req = next(Requirement(r) for r in data["build-system"]["requires"] if r.startswith("setuptools"))
    if isinstance(data["project"]["license"], dict):
        assert "76.9" in setuptools_req.specifier and "77.0" not in setuptools_req.specifier
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        config = read_configuration(ROOT / "pyproject.toml")
    assert config["project"]["name"] == "warp-shape"
    assert not [w for w in caught if "license" in str(w.message).lower()]


def test_the_recording_of_a_design_is_in_its_manifest(tmp_path, capsys):
    """A design's recording is in its manifest; with ``--feel`` the design's outputs carry per target the
    stiffness map: CSV, figure, a report section (N/mm), report.json's entry (keys with units), a per-face
    primvar on design.usda's membrane whose values are the CSV's, and a layer of the recording."""
    import csv

    from warp_shape.io.feel_outputs import feel_primvar_name
    from warp_shape.io.usd_common import load_pxr

    rrd, out = tmp_path / "run.rrd", tmp_path / "out"
    assert main(["design", "--subdivisions", "2", "--actuators", "1", "--placement", "paper", "--targets", "oval",
                 "--codesign", "off", "--rerun", str(rrd), "--out", str(out), "--feel", "6", "--feel-radius",
                 "0.016"]) == 0
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["recording"] == {"path": str(rrd), "bytes": rrd.stat().st_size} and rrd.stat().st_size > 1000
    assert not (tmp_path / ".out.lock").exists()
    with open(out / "feel_oval.csv") as fh:
        k = np.array([float(r["stiffness_n_per_mm"]) for r in csv.DictReader(fh)])
    assert 3 <= len(k) <= 6 and np.all((k > 0.001) & (k < 1.0))  # N/mm of a thumb on an inflated balloon
    assert (out / "feel_oval.png").stat().st_size > 10_000
    report = json.loads((out / "report.json").read_text())
    entry = report["feel"]["oval"]
    assert entry["points"] == len(k) and entry["depth_m"] == 0.002 and entry["radius_m"] == 0.016
    np.testing.assert_allclose(entry["stiffness_n_per_mm"], k, rtol=1e-5)
    assert entry["min_n_per_mm"] == pytest.approx(k.min(), rel=1e-5) and report["feel_seconds"] > 0
    assert {"feel_oval.csv", "feel_oval.png"} <= set(report["outputs"]) & set(manifest["files"])
    assert "## Feel: oval" in (out / "report.md").read_text() and "N/mm" in (out / "report.md").read_text()
    pxr = load_pxr()
    stage = pxr.Usd.Stage.Open(str(out / "design.usda"))
    var = pxr.UsdGeom.PrimvarsAPI(stage.GetPrimAtPath("/Scene/Membrane")).GetPrimvar(feel_primvar_name("oval"))
    faces = np.asarray(var.Get())
    assert var.GetInterpolation() == "uniform" and len(faces) == 320
    assert np.all(np.min(np.abs(faces[:, None] / k[None] - 1.0), axis=1) < 1e-5)  # each face: a pressed point's
    assert np.isclose(faces.min(), k.min(), rtol=1e-5) and np.isclose(faces.max(), k.max(), rtol=1e-5)
    assert ws.load_scene(out / "design.usda").design.rest.n_vertices == 162  # the scene still reads
    assert b"design/feel/oval/membrane" in rrd.read_bytes()  # the map's layer in the recording


def test_a_viewer_that_fails_gets_a_word_of_our_own(tmp_path, monkeypatch, capsys):
    import warp_shape.cli.view as view

    rrd = tmp_path / "run.rrd"
    rrd.write_bytes(b"RRF2")
    monkeypatch.setenv("DISPLAY", ":0")
    monkeypatch.setattr(view.subprocess, "call", lambda cmd: 1)  # e.g. no usable window system after all
    assert main(["view", str(rrd)]) == 1
    assert "the rerun viewer ended with exit status 1" in capsys.readouterr().err


def test_the_icp_warning_does_not_advise_the_method_in_use():
    from warp_shape.scan import IcpConvergenceWarning, compare_scan

    ref = ws.icosphere(3, R)
    pts = ws.icosphere(2, R).vertices[:120] * [1.0, 1.1, 0.9] + 0.01
    for method, advice in (("point_to_plane", False), ("point_to_point", True)):
        with pytest.warns(IcpConvergenceWarning) as caught:
            compare_scan(pts, ref, method=method, max_iterations=1)
        assert ("--method point_to_plane" in str(caught[0].message)) is advice, method


def test_one_meaning_per_flag_and_calibrate_names_its_design(tmp_path, monkeypatch, capsys):
    """``--units`` is the input meshes' unit wherever it exists: ``export --units`` is one line pointing to
    ``--mold-units``, before any work; ``calibrate`` without ``--design`` is refused rather than guessed."""
    monkeypatch.chdir(tmp_path)
    err = error_of(capsys, ["export", "cube_fig6", "--units", "mm", "--out", str(tmp_path / "e")])
    assert "--mold-units" in err and "input mesh files" in err and not (tmp_path / "e").exists()
    with pytest.raises(SystemExit) as stop:
        main(["calibrate", str(tmp_path / "manifest.json"), "--out", str(tmp_path / "c")])
    assert stop.value.code == 2 and "required: --design" in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []
