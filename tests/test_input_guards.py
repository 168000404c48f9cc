"""Inputs refused before any work, each with one clear line: files that are not regular files (a FIFO, a
link to /dev/zero, a folder) wherever a file is read or composed, work beyond a bound, a target in the
wrong unit, strings for booleans and fractions for counts, non-manifold, self-crossing or tangled
membranes, degenerate scans, and the API misuse that used to end in a traceback."""

from __future__ import annotations

import os
import re
import signal

import numpy as np
import pytest

import warp_shape as ws
from warp_shape.cli import main
from warp_shape.errors import MAX_INPUT_BYTES


@pytest.fixture(autouse=True)
def no_hang():
    """A regression that blocks on a special file fails the test instead of hanging the suite."""
    def fail(signum, frame):
        raise AssertionError("blocked for 60 s (reading a special file?)")

    old = signal.signal(signal.SIGALRM, fail)
    signal.alarm(60)
    yield
    signal.alarm(0)
    signal.signal(signal.SIGALRM, old)


def error_of(capsys, argv) -> str:
    """The one error line of a refused command (exit 2, no traceback)."""
    assert main([str(a) for a in argv]) == 2, argv
    err = capsys.readouterr().err
    assert re.match(r"warp-shape( \w+)?: error: ", err) and "Traceback" not in err and err.count("\n") == 1, err
    return err


def no_work(monkeypatch):
    """Make any design or control run fail loudly: the checks must come before any work."""
    import warp_shape.controller.loop as control_loop
    import warp_shape.designer.loop as designer_loop

    def forbidden(*args, **kwargs):
        raise AssertionError("work started before the inputs were checked")

    monkeypatch.setattr(designer_loop, "control_many", forbidden)
    monkeypatch.setattr(control_loop, "_simulator", forbidden)


@pytest.fixture
def special(tmp_path):
    """{kind: path maker}: a FIFO, a link to /dev/zero and a folder, each with the name asked for."""
    def make(kind, name):
        p = tmp_path / name
        if kind == "fifo":
            os.mkfifo(p)
        elif kind == "zero":
            p.symlink_to("/dev/zero")
        else:
            p.mkdir()
        return p

    return make


WHAT = {"fifo": "is a FIFO (named pipe), not a regular file", "zero": "is a device, not a regular file",
        "folder": "is a folder"}


# ------------------------------------------------------------------------------------ special files
@pytest.mark.parametrize("kind", ["fifo", "zero", "folder"])
def test_special_files_are_refused_by_every_command_before_they_are_read(kind, special, tmp_path, capsys):
    mesh, scan, scene, rrd = (special(kind, f"{kind}.{ext}") for ext in ("stl", "ply", "usda", "rrd"))
    assert WHAT[kind] in error_of(capsys, ["design", "--targets", mesh, "--out", tmp_path / "o"])
    assert WHAT[kind] in error_of(capsys, ["compare", scan, "--to", "oval"])
    assert WHAT[kind] in error_of(capsys, ["control", scene, "--out", tmp_path / "o"])
    assert WHAT[kind] in error_of(capsys, ["view", rrd])
    for fn, p, error in ((ws.TriMesh.load, mesh, ws.MeshError), (ws.load_scan, scan, ws.ShapeError),
                         (ws.load_scene, scene, ws.SceneError), (ws.read_recording, rrd, ws.WarpShapeError)):
        with pytest.raises(error, match=re.escape(WHAT[kind])):
            fn(p)


@pytest.mark.parametrize("kind", ["fifo", "zero"])
@pytest.mark.parametrize("how", ["subLayers", "references", "binary subLayers"])
def test_a_scene_composing_a_special_file_is_refused_before_usd_opens_it(kind, how, special, tmp_path):
    from pxr import Sdf

    layer = special(kind, f"layer_{kind}.usda")
    base = ws.save_scene(ws.Scene(design=ws.Design(ws.icosphere(1, 0.04)), targets=[ws.icosphere(1, 0.05)]),
                         tmp_path / "base.usda").read_text()
    head, rest = base.split("(\n", 1)
    if how == "subLayers":
        scene = tmp_path / "s.usda"
        scene.write_text(f"{head}(\n    subLayers = [@./{layer.name}@]\n{rest}")
    elif how == "references":
        scene = tmp_path / "s.usda"
        scene.write_text(f'{base}\ndef "Extra" (\n    references = @./{layer.name}@\n)\n{{\n}}\n')
    else:
        crate = Sdf.Layer.CreateAnonymous(".usda")
        crate.ImportFromString(base)
        crate.subLayerPaths.append(f"./{layer.name}")
        scene = tmp_path / "s.usdc"
        crate.Export(str(scene))
    with pytest.raises(ws.SceneError, match="composes .*not a regular file"):
        ws.load_scene(scene)


TETRA_OBJ = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n"


@pytest.mark.parametrize("kind", ["fifo", "zero"])
def test_a_mesh_file_naming_a_special_file_reads_without_it(kind, special, tmp_path):
    special(kind, "pipe.mtl")
    obj = tmp_path / "tetra.obj"
    obj.write_text("mtllib pipe.mtl\n" + TETRA_OBJ)  # the material library is not read: no block, no flood
    assert ws.TriMesh.load(obj).n_faces == 4 and len(ws.load_scan(obj)[0]) == 4


def test_special_manifest_and_sweep_results_are_no_files_of_ours(special, tmp_path):
    from warp_shape.io.atomic import read_manifest
    from warp_shape.sweeps.params import SweepError
    from warp_shape.sweeps.results import ResultsTable

    out = tmp_path / "out"
    out.mkdir()
    os.mkfifo(out / "manifest.json")
    assert read_manifest(out) is None  # not read, not blocking: a folder without a manifest
    sweep = tmp_path / "sweep"
    sweep.mkdir()
    (sweep / "results.json").symlink_to("/dev/zero")
    with pytest.raises(SweepError, match="is a device, not a regular file"):
        ResultsTable(sweep, [], {}).load()


def test_an_input_file_over_the_size_cap_is_refused_unread(tmp_path):
    big = tmp_path / "big.stl"
    with open(big, "wb") as f:  # sparse: 2 GiB on paper, nothing on disk
        f.truncate(2 * MAX_INPUT_BYTES)
    with pytest.raises(ws.MeshError, match=r"big.stl is 2048 MiB, over the 1024 MiB that are read"):
        ws.TriMesh.load(big)
    with pytest.raises(ws.SceneError, match="over the 1024 MiB"):
        ws.load_scene(big.rename(tmp_path / "big.usda"))


def test_view_of_a_mesh_file_says_it_is_not_a_recording(tmp_path, capsys):
    tetra = tmp_path / "tetra.obj"
    tetra.write_text(TETRA_OBJ)
    err = error_of(capsys, ["view", tetra])
    assert "tetra.obj is not a rerun recording" in err and "--rerun FILE.rrd" in err


# ------------------------------------------------------------------------------------ bounds on work
def test_work_beyond_a_bound_is_refused_in_one_line_naming_the_bound_and_the_fix(tmp_path, capsys, monkeypatch):
    no_work(monkeypatch)
    with pytest.raises(ws.ShapeError, match=r"1000000000 directions asked for, more than the 1e\+07"):
        ws.fibonacci_directions(10**9)
    err = error_of(capsys, ["simulate", "--dt", "1e-9", "--out", tmp_path / "s"])
    assert "8e+08 output steps, more than 200000" in err and "larger --dt" in err
    err = error_of(capsys, ["simulate", "--inflate-time", "1e9", "--out", tmp_path / "s"])
    assert "1e+12 output steps" in err and "shorter times" in err
    grid = [a for k in ("max_steps", "control_period", "max_settle_steps")
            for a in ("--param", f"{k}={','.join(str(v) for v in range(2, 102))}")]
    err = error_of(capsys, ["sweep", "grid", *grid, "--backend", "serial", "--out", tmp_path / "sw"])
    assert "this sweep is 1000000 runs" in err and "more than the 10000" in err and "sweep fewer values" in err
    assert not (tmp_path / "sw" / "results.json").exists()


def test_a_scene_with_too_many_ipams_is_refused_at_reading(tmp_path):
    d = ws.Design(ws.icosphere(2, 0.04))
    c = d.rest.face_centroids()
    d.add_ipam(int(np.argmax(c[:, 2])), int(np.argmin(c[:, 2])))
    text = ws.save_scene(ws.Scene(design=d), tmp_path / "one.usda").read_text()
    start = text.index('def BasisCurves "Ipams"')
    block = re.sub(r"(warpShape:\w+ = )\[(.*)\]", lambda m: f"{m.group(1)}[{', '.join([m.group(2)] * 2000)}]",
                   text[start:])
    (tmp_path / "many.usda").write_text(text[:start] + block)
    with pytest.raises(ws.SceneError, match="2000 IPAMs, more than the 1000 a design holds"):
        ws.load_scene(tmp_path / "many.usda")
    opposite = np.argmin(c @ c.T, axis=1)
    for k in range(999):
        d.add_ipam(k % 320, int(opposite[k % 320]))
    with pytest.raises(ws.DesignError, match="at most 1000 IPAMs"):
        d.add_ipam(5, int(opposite[5]))


def test_a_scene_of_100000_ipams_is_refused_before_usd_reads_it(tmp_path, capsys, monkeypatch):
    """A scene of 100,000 IPAMs was refused only after USD had parsed it (33 s): now the count is read
    from the text first, one line naming the bound and the fix, USD never opening the file."""
    import types

    import warp_shape.io.scene_read as scene_read

    no_work(monkeypatch)
    d = ws.Design(ws.icosphere(1, 0.04))
    c = d.rest.face_centroids()
    d.add_ipam(int(np.argmax(c[:, 2])), int(np.argmin(c[:, 2])))
    text = ws.save_scene(ws.Scene(design=d, targets=[ws.target("oval")], target_names=["oval"]),
                         tmp_path / "one.usda").read_text()
    start = text.index('def BasisCurves "Ipams"')
    end = text.index("def Scope", start)
    block = re.sub(r"(warpShape:\w+ = )\[(.*)\]", lambda m: f"{m.group(1)}[{', '.join([m.group(2)] * 100000)}]",
                   text[start:end])
    (tmp_path / "many.usda").write_text(text[:start] + block + text[end:])
    real = scene_read.load_pxr()

    def never(*a, **k):
        raise AssertionError("USD opened the scene before its IPAMs were counted")

    monkeypatch.setattr(scene_read, "load_pxr", lambda: types.SimpleNamespace(
        Sdf=real.Sdf, Tf=real.Tf, UsdGeom=real.UsdGeom, Usd=types.SimpleNamespace(Stage=types.SimpleNamespace(Open=never))))
    err = error_of(capsys, ["control", tmp_path / "many.usda", "--out", tmp_path / "c"])
    assert "warpShape:faces: 100000 IPAMs, more than the 1000 a design holds" in err and "use fewer" in err
    assert not (tmp_path / "c").exists()


# ------------------------------------------------------------------------------------ units and names
def test_a_target_100x_too_big_names_centimetres_and_the_units_flag(tmp_path, capsys, monkeypatch):
    no_work(monkeypatch)
    big = tmp_path / "big.stl"  # a 4 cm display saved in centimetres, read as metres: 100x too big
    ws.target("oval", resolution=2).scaled(100.0).to_trimesh().export(str(big))
    for units in ("auto", "m"):
        err = error_of(capsys, ["design", "--targets", big, "--units", units, "--out", tmp_path / "o"])
        assert "it looks like centimetres (10.25 cm across)" in err and "give --units m or --units mm" in err
    design = ws.Design(ws.icosphere(2, 0.035))
    with pytest.raises(ws.ShapeError, match=r"\d+x the size .* looks like centimetres: scale it by 1e-2 .*--units m "
                                            r"or --units mm"):
        ws.control(design, ws.target("oval").scaled(100.0))
    with pytest.raises(ws.ShapeError, match=r"looks like millimetres: scale it by 1e-3"):
        ws.control(design, ws.target("oval").scaled(1000.0))
    with pytest.raises(ws.ShapeError, match="far too large for a display of that size in any unit"):
        ws.control(design, ws.target("oval").scaled(1e5))
    with pytest.raises(ws.ShapeError, match="looks like centimetres"):  # the designer checks against its base mesh
        ws.design(ws.icosphere(2, 0.04), [ws.target("oval").scaled(100.0)], actuators=1)


def test_a_target_file_name_that_is_no_identifier_is_made_one_before_any_work(tmp_path, monkeypatch):
    from warp_shape.cli.options import load_targets

    no_work(monkeypatch)
    path = tmp_path / "my-oval.stl"
    ws.target("oval", resolution=2).to_trimesh().export(str(path))
    assert load_targets([str(path)])[0][0] == "my_oval"
    with pytest.raises(ws.DesignError, match="target name 'my-oval' is not an identifier .* use e.g. 'my_oval'"):
        ws.design(ws.icosphere(2, 0.04), [ws.target("oval")], actuators=1, target_names=["my-oval"])


# ------------------------------------------------------------------------------------ types of settings
@pytest.mark.parametrize("value", ["no", "false", "", 0, 1, None])
def test_strings_and_numbers_for_booleans_are_refused(value):
    with pytest.raises(ws.DesignError, match=r"ControlSettings.jamming must be True or False"):
        ws.ControlSettings(jamming=value)
    with pytest.raises(ws.DesignError, match=r"DesignSettings.initialize must be True or False"):
        ws.DesignSettings(initialize=value)


def test_fractions_for_counts_are_refused_not_truncated():
    with pytest.raises(ws.MeshError, match="subdivisions must be a whole number, got 3.7"):
        ws.icosphere(3.7)
    with pytest.raises(ws.ShapeError, match="resolution must be a whole number, got 2.5"):
        ws.target("oval", resolution=2.5)
    with pytest.raises(ws.DesignError, match="ControlSettings.inverse_iterations must be a whole number, got 1.5"):
        ws.ControlSettings(inverse_iterations=1.5)
    with pytest.raises(ws.DesignError, match="DesignSettings.refine_rounds must be a whole number"):
        ws.DesignSettings(refine_rounds=2.5)
    with pytest.raises(ws.DesignError, match="max_substeps must be"):
        ws.SimulationSettings(max_substeps=2.5)
    # a whole float is the whole number; a float setting takes an int
    assert ws.icosphere(2.0).n_vertices == 162 and ws.ControlSettings(max_steps=20.0).max_steps == 20
    assert isinstance(ws.ControlSettings(air_gain=1).air_gain, float)


# ------------------------------------------------------------------------------------ meshes
def _pinched() -> tuple[np.ndarray, np.ndarray]:
    """Two icospheres sharing one vertex (every edge has two faces; the vertex has two fans)."""
    a, b = ws.icosphere(1, 0.04), ws.icosphere(1, 0.04)
    ia, ib = int(np.argmax(a.vertices[:, 0])), int(np.argmin(b.vertices[:, 0]))
    vb = b.vertices - b.vertices[ib] + a.vertices[ia]
    keep = np.array([i for i in range(len(vb)) if i != ib])
    remap = np.full(len(vb), -1)
    remap[keep] = np.arange(len(keep)) + len(a.vertices)
    remap[ib] = ia
    return np.concatenate([a.vertices, vb[keep]]), np.concatenate([a.faces, remap[b.faces]])


def test_a_pinched_vertex_and_a_self_crossing_rest_mesh_are_refused():
    v, f = _pinched()
    with pytest.raises(ws.MeshError, match=r"not 2-manifold at vertex 40 .* 2 separate fans"):
        ws.TriMesh(v, f)
    m = ws.icosphere(3, 0.04)
    v = m.vertices.copy()
    v[int(np.argmax(v[:, 2]))] = [0.003, 0.002, -0.05]  # the top vertex pulled out through the bottom
    poked = ws.TriMesh(v, m.faces)  # closed, manifold, outward: a valid mesh, but it passes through itself
    design = ws.Design(poked)  # a description; simulating it is refused
    with pytest.raises(ws.MeshError, match=r"the rest mesh passes through itself: edge \(\d+, \d+\) crosses face"):
        ws.Simulator(design)
    ws.Simulator(ws.Design(m))  # the sphere itself is fine


def test_a_membrane_tangled_for_two_checks_is_an_error_naming_the_step():
    from warp_shape.simulator import TANGLE_EVERY

    d = ws.Design(ws.icosphere(3, 0.04))
    sim = ws.Simulator(d)
    sim.positions = d.rest.vertices * 0.1  # 1000x the pressure: it bursts and folds through itself
    with pytest.raises(ws.SimulationError, match=f"tangled at output step {2 * TANGLE_EVERY} .* passes through "
                                                 f"itself since output step {TANGLE_EVERY}") as info:
        sim.step(3 * TANGLE_EVERY)
    assert info.value.quantity == "tangle" and info.value.step == 2 * TANGLE_EVERY



def test_the_tangle_screen_counts_the_faces_that_face_the_centre():
    """inward_fraction: none of a sphere's faces, all of a sphere turned inside out, each world on its
    own, and the same float operations as the cross product and sum it replaces."""
    from warp_shape.crossing import inward_fraction

    m = ws.icosphere(2, 0.04)
    corners = tuple(np.ascontiguousarray(m.faces[:, k]) for k in range(3))
    rng = np.random.default_rng(4)
    x = np.stack([m.vertices, -m.vertices, m.vertices + rng.normal(0, 0.01, m.vertices.shape)]).astype(np.float32)
    frac = inward_fraction(x, corners)
    assert frac[0] == 0 and frac[1] == 1 and 0 < frac[2] < 1
    a, b, c = (x[:, k] for k in corners)
    out = a + b + c - 3.0 * x.mean(axis=1, keepdims=True)
    assert np.array_equal(frac, np.mean((np.cross(b - a, c - a) * out).sum(axis=2) < 0, axis=1))

# ------------------------------------------------------------------------------------ scans and scenes
def test_a_degenerate_scan_is_refused():
    with pytest.raises(ws.ShapeError, match="the scan is 0 m across"):
        ws.compare_scan(np.full((100, 3), 0.01), "oval")
    line = np.c_[np.linspace(0, 0.05, 100), np.zeros(100), np.zeros(100)]
    with pytest.raises(ws.ShapeError, match="lie on one line"):
        ws.compare_scan(line, "oval")


def test_a_target_prim_that_is_no_mesh_and_an_odd_format_version_are_named(tmp_path):
    sc = ws.Scene(design=ws.Design(ws.icosphere(1, 0.04)), targets=[ws.icosphere(1, 0.05)], target_names=["ball"])
    text = ws.save_scene(sc, tmp_path / "s.usda").read_text()
    (tmp_path / "x.usda").write_text(text.replace('def Mesh "ball"', 'def Xform "ball"'))
    with pytest.raises(ws.SceneError, match=r"<.*/Targets/ball>: is a Xform, not a Mesh"):
        ws.load_scene(tmp_path / "x.usda")
    (tmp_path / "v.usda").write_text(text.replace("formatVersion = 1", "formatVersion = 1.0000001")
                                     .replace("int warpShape:formatVersion", "double warpShape:formatVersion"))
    with pytest.raises(ws.SceneError, match=r"format version 1.0000001 is not supported \(this build reads version "
                                            r"1: set"):
        ws.load_scene(tmp_path / "v.usda")


# ------------------------------------------------------------------------------------ API misuse
@pytest.mark.parametrize("call,error,match", [
    (lambda: ws.icosphere(None), ws.MeshError, "subdivisions must be a whole number, got None"),
    (lambda: ws.icosphere(2, "a"), ws.MeshError, "radius must be a positive finite length"),
    (lambda: ws.icosphere(2, 0.04, center=(0, 0)), ws.MeshError, r"center must be a finite point \(x, y, z\)"),
    (lambda: ws.radial_metrics(ws.icosphere(1), ws.icosphere(1)), ws.ShapeError, "not meshes; .* shape_metrics"),
    (lambda: ws.design(ws.icosphere(2, 0.04), None), ws.DesignError, "design needs target shapes"),
    (lambda: ws.design(ws.icosphere(2, 0.04), [ws.target("oval")], settings={"candidates": 2}), ws.DesignError,
     "settings must be a DesignSettings or None, got dict"),
    (lambda: ws.replay(ws.Design(ws.icosphere(1, 0.04)), None), ws.DesignError, "replay needs control results"),
    (lambda: ws.pcc("abc", "abd"), ws.ShapeError, "must be an array of numbers"),
    (lambda: ws.Material(atmospheric_pressure=1e300), ws.DesignError, "atmospheric_pressure = 1e\\+300 Pa is no "
                                                                        "atmosphere"),
])
def test_api_misuse_is_one_clear_error(call, error, match):
    with pytest.raises(error, match=match):
        call()


def test_air_scale_that_is_no_amount_of_air_names_the_flag(tmp_path, capsys):
    err = error_of(capsys, ["simulate", "--air-scale", "-1", "--out", tmp_path / "s"])
    assert "--air-scale takes 0.01..100, got -1" in err
    assert not (tmp_path / "s" / "simulate.json").exists()


# --------------------------------------------------------------------------- calibration inputs, strictly read
def _lab(tmp_path):
    """A 42-vertex Fig. 6 design, a scan file (its content is not read before the manifest's check)
    and a control CSV of three rows."""
    from warp_shape.scenarios import cube_fig6_design

    design = cube_fig6_design(subdivisions=1)
    (tmp_path / "scan.ply").write_text("ply")
    cols = ["step", "time", "air_mol", *[f"ipam{i}_pressure_pa" for i in range(design.n_ipams)]]
    rows = [[0, 0.0, 0.01, *[0] * design.n_ipams], [1, 0.5, 0.012, *[1e3] * design.n_ipams],
            [2, 1.0, 0.013, *[2e3] * design.n_ipams]]
    (tmp_path / "control_oval.csv").write_text("\n".join(",".join(map(str, r)) for r in [cols, *rows]) + "\n")
    return design


@pytest.mark.parametrize("entry, top, message", [
    ({"time": 0.5}, {}, "unknown key 'time'; did you mean 'time_s'?"),
    ({"time_s": 0.5, "chamber_pressure": 3}, {}, "unknown key 'chamber_pressure'; did you mean 'chamber_pressure_kpa'?"),
    ({"time_s": 0.5, "unit": "mm"}, {}, "unknown key 'unit'; did you mean 'units'?"),
    ({"time_s": 0.5}, {"wrtt": ["youngs_modulus"]}, "unknown key 'wrtt'; did you mean 'wrt'?"),
    ({"time_s": 0.5}, {"region": ["plug"]}, "unknown key 'region'; did you mean 'regions'?"),
    ({"time_s": float("nan")}, {}, "time_s (s) must be a finite number, got nan"),
    ({"time_s": "10s"}, {}, "time_s (s) must be a finite number, got '10s'"),
    ({"row": 2.5}, {}, "row must be a whole row number >= 0, got 2.5"),
    ({"row": True}, {}, "row must be a whole row number >= 0, got True"),
    ({"row": 1, "time_s": 0.5}, {}, "give \"row\" or \"time_s\", not both"),
    ({"row": 1, "chamber_pressure_kpa": [3]}, {}, "chamber_pressure_kpa must be a finite number"),
])
def test_a_calibration_manifest_is_read_strictly(tmp_path, entry, top, message):
    """A misspelt key was ignored (the fit then used the schedule's end), NaN meant the end, 2.5 read as
    row 2 and true as row 1, "10s" was a ValueError: each is now one line naming the key and the fix."""
    import json

    from warp_shape.calibration.files import read_manifest

    design = _lab(tmp_path)
    (tmp_path / "m.json").write_text(json.dumps({"observations": [{"scan": "scan.ply", "control": "control_oval.csv",
                                                                   **entry}], **top}))
    with pytest.raises(ws.DesignError) as info:
        read_manifest(tmp_path / "m.json", design)
    assert message in str(info.value) and "\n" not in str(info.value)


def test_a_schedule_cell_that_is_no_number_and_odd_manifests_are_one_line(tmp_path):
    """A NaN time in a control CSV leaked a NumPy warning and fitted; a manifest nested 100,000 deep was
    a RecursionError; a FIFO, a folder or /dev/zero given as a manifest was "does not exist"."""
    import json

    from warp_shape.calibration.files import read_calibration, read_manifest

    design = _lab(tmp_path)
    text = (tmp_path / "control_oval.csv").read_text().replace("\n1,0.5,", "\n1,nan,")
    (tmp_path / "control_oval.csv").write_text(text)
    (tmp_path / "m.json").write_text(json.dumps({"observations": [{"scan": "scan.ply", "control": "control_oval.csv",
                                                                   "row": 2}]}))
    with pytest.raises(ws.DesignError, match=r"control_oval.csv row 1: time is 'nan', not a finite number"):
        read_manifest(tmp_path / "m.json", design)
    (tmp_path / "deep.json").write_text("[" * 100_000 + "]" * 100_000)
    with pytest.raises(ws.DesignError, match="nested too deeply"):
        read_manifest(tmp_path / "deep.json", design)
    os.mkfifo(tmp_path / "fifo.json")
    (tmp_path / "folder.json").mkdir()
    (tmp_path / "zero.json").symlink_to("/dev/zero")
    for name, kind in (("fifo.json", "FIFO"), ("folder.json", "folder"), ("zero.json", "device")):
        for read in (lambda p: read_manifest(p, design), read_calibration):
            with pytest.raises(ws.DesignError, match=kind):
                read(tmp_path / name)


@pytest.mark.parametrize("case, message", [
    ("nested", "nested too deeply"),
    ("10s", "time_s (s) must be a finite number, got '10s'"),
    ("list", "youngs_modulus must be a finite positive number"),
])
def test_a_deep_manifest_a_time_in_words_and_a_listed_value_are_one_line_before_any_work(tmp_path, capsys,
                                                                                         monkeypatch, case, message):
    """The command line for three of the probe's tracebacks (a manifest nested 100,000 deep: RecursionError;
    "time_s": "10s": ValueError; a calibration value as a list: TypeError): exit 2, one line, before the
    fit or any control, no --out made."""
    import json

    import warp_shape.cli.calibrate as cal_cli

    no_work(monkeypatch)
    monkeypatch.setattr(cal_cli, "calibrate", lambda *a, **k: pytest.fail("the fit started"))
    _lab(tmp_path)
    out, manifest = tmp_path / "out", tmp_path / "m.json"
    if case == "nested":
        manifest.write_text("[" * 100_000 + "]" * 100_000)
    else:
        manifest.write_text(json.dumps({"observations": [{"scan": "scan.ply", "control": "control_oval.csv",
                                                          "time_s": "10s"}]}))
    argv = ["calibrate", manifest, "--design", "cube_fig6", "--out", out]
    if case == "list":
        (tmp_path / "c.json").write_text(json.dumps({"format": "warp-shape calibration", "version": 1,
                                                     "values": {"youngs_modulus": [1e6]}}))
        argv = ["control", "cube_fig6", "--calibration", tmp_path / "c.json", "--out", out]
    assert message in error_of(capsys, argv) and not out.exists()


@pytest.mark.parametrize("values, message", [
    ({"youngs_modulus": [1e6]}, "youngs_modulus must be a finite positive number"),
    ({"ipam_area": [1e-4, [2e-4]]}, "ipam_area must be a finite positive number or a list of them"),
    ({"youngs_modulus": float("inf")}, "youngs_modulus must be a finite positive number"),
])
def test_a_calibration_value_of_the_wrong_shape_is_one_line(tmp_path, values, message):
    """A calibration value as a list was a TypeError when applied; inf passed as positive."""
    import json

    from warp_shape.calibration.files import read_calibration

    (tmp_path / "c.json").write_text(json.dumps({"format": "warp-shape calibration", "version": 1,
                                                 "values": values}).replace("Infinity", "1e999"))
    with pytest.raises(ws.DesignError, match=message):
        read_calibration(tmp_path / "c.json")


def test_a_value_at_a_bound_of_the_fit_is_reported(tmp_path):
    """E, bending and k at exactly 10x their start were reported with a +-30 % error and no word of the
    bound: the report, the file and the command now name each one."""
    from warp_shape.calibration.files import bounds_reached, calibration_markdown
    from warp_shape.calibration.result import CalibrationResult

    result = CalibrationResult(values={"youngs_modulus": 1.2e7, "bending_stiffness": 3e-4, "ipam_stiffness": [400.0, 55.0]},
                               stderr={"youngs_modulus": 3.6e6, "bending_stiffness": 1e-4, "ipam_stiffness": [120.0, 5.0]},
                               start={"youngs_modulus": 1.2e6, "bending_stiffness": 3e-5, "ipam_stiffness": [40.0, 50.0]},
                               design=None, residual_mm=[1.0], initial_residual_mm=[2.0], unidentifiable=[],
                               labels=["youngs_modulus", "bending_stiffness", "ipam_stiffness[0]", "ipam_stiffness[1]"])
    lines = bounds_reached(result)
    assert [line.split(" =")[0] for line in lines] == ["youngs_modulus", "bending_stiffness", "ipam_stiffness[0]"]
    assert all("upper bound (10x its start" in line for line in lines)
    assert "## At a bound" in calibration_markdown(result)


# ------------------------------------------------------------------------------ units, bounds, empty names
@pytest.mark.parametrize("old, new, message", [
    ("warpShape:area = [0.000015, 0.000015,", "warpShape:area = [15, 0.000015,",
     "IPAM area 15 m^2 is more than the device's cross-section"),
    ("warpShape:thickness = 0.002", "warpShape:thickness = 2", "material thickness 2 m is more than the whole device"),
])
def test_an_area_or_thickness_in_millimetres_is_refused_naming_the_unit(tmp_path, capsys, old, new, message):
    """An IPAM area of 15 (mm^2 meant) controlled to "converged" at 0.01 Pa and export wrote molds from it;
    a thickness of 2 (mm meant) made a 2 m shell on a 70 mm device. The scene, the API: one line each."""
    from warp_shape.scenarios import cube_fig6_design

    design = cube_fig6_design(subdivisions=1)
    path = ws.save_scene(ws.Scene(design=design, targets=[ws.target("oval")], target_names=["oval"]),
                         tmp_path / "design.usda")
    text = path.read_text()
    assert old in text
    path.write_text(text.replace(old, new))
    err = error_of(capsys, ["export", path, "--what", "molds", "--out", tmp_path / "molds"])
    assert message in err and not (tmp_path / "molds").exists()
    with pytest.raises(ws.DesignError, match=r"if 15 mm\^2 was meant, give 1.5e-05"):
        design.add_ipam(design.ipams[0].face_a, design.ipams[0].face_b, area=15)
    with pytest.raises(ws.DesignError, match=r"if 2 mm was meant, give 0.002"):
        ws.Design(design.rest, ws.Material(thickness=2.0))


@pytest.mark.parametrize("argv, message", [
    (["design", "--cell-radius", "1e-9"], "--cell-radius takes 0.0005..0.5, got 1e-09"),
    (["design", "--cell-radius", "1e300"], "--cell-radius takes 0.0005..0.5, got 1e+300"),
    (["design", "--layer-thickness", "1e-12"], "--layer-thickness 1e-12 m is below 0.0001 m"),
    (["export", "cube_fig6", "--marker-height", "1e-9"], "--marker-height 1e-09 m is below 0.0001 m"),
    (["design", ""], "the scene is an empty name"),
    (["sweep", "grid", "--param", "actuators=1,2", "--set", "actuators=3"], "actuators is both swept (--param) and fixed"),
    (["control", "--rerun-every", "0"], "--rerun-every takes 1..1e+09, got 0"),
])
def test_lengths_are_bounded_below_and_empty_or_conflicting_requests_refused(tmp_path, capsys, argv, message):
    """--cell-radius 1e-9 made one-face cells 17 mm across while design.usda recorded 1e-9 (1e300: an
    OverflowError); --layer-thickness 1e-12 wrote a 1e-9 mm layer; design "" designed the default
    problem; a --set of a swept name was dropped: each one line, before any work or file."""
    out = tmp_path / "out"
    assert message in error_of(capsys, [*argv, "--out", out]) and not out.exists()


def test_compare_scan_refuses_a_tolerance_it_can_never_meet():
    """tolerance=nan never converged (the alignment ran to its limit)."""
    pts = np.random.default_rng(0).random((50, 3)) * 0.03
    for kwargs in (dict(tolerance=float("nan")), dict(tolerance=0.0), dict(max_iterations=0),
                   dict(max_iterations=2.5), dict(inlier_sigmas=float("inf"))):
        with pytest.raises(ws.ShapeError, match=next(iter(kwargs))):
            ws.compare_scan(pts, "oval", **kwargs)
