"""Calibration from scans on synthetic devices (docs/calibration.md).

The "device" is the 162-vertex Fig. 6 design with its parameters perturbed near the issue's extremes
in the direction that moves the shape most (E t +30 %, bending -50 %, each IPAM's k -10..-20 % and A
+10..+20 %: each IPAM strokes 1.3-1.5 x the model's per unit pressure; rest scale +2 %), driven to
four control states that use every IPAM, held to rest and scanned: 60 % of the surface, 0.3 mm noise,
a random rigid pose, one scan in millimetres, 20000 points each; the chamber pressure is read with
each scan (20 Pa noise), which pins the common scale of E t, k and A that shape alone fixes least
(docs/calibration.md). A scan at a state where an IPAM's pressure is zero cannot fit its area, and
E with t is one product: the fit must say so. Parts of the membrane stiffer than the rest (the plug,
the cells' edges) are fitted as regions.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

import warp_shape as ws
from warp_shape.calibration import ControlState, apply_values, replay_held, scan_residuals
from warp_shape.calibration.files import apply_calibration, read_calibration, write_calibration
from warp_shape.calibration.regions import region_faces
from warp_shape.io.recording_read import read_recording
from warp_shape.cli import main
from warp_shape.model import host_model
from warp_shape.objectives.radial import fit_objective_and_gradient
from warp_shape.scan import surface_samples
from warp_shape.scenarios import cube_fig6_design

NOISE = 3e-4  # m, per coordinate
POINTS = 20000  # per scan (about 0.8 mm apart on the 60 % scanned)
COVERAGE = 0.6
PRESSURE_NOISE = 20.0  # Pa, the chamber pressure sensor (0.2 % of a 10 kPa range)
#: the inverse controller's tolerance in the sim-to-real loop (a tenth of the default, so that the gain
#: of the calibrated model on the heart, 0.3 %, is not within the controller's own noise)
LOOP_TOLERANCE = 5e-4
#: the control states scanned: (chamber air / rest air, IPAM gauge pressures kPa); the last is held out
STATES = [(1.3, (200, -30, 100, 0, 150)), (2.0, (0, 220, -40, 150, 280)), (2.6, (250, 120, 180, -40, 60)),
          (1.8, (120, 60, 140, 40, 200))]


def rotation(rng) -> np.ndarray:
    q = rng.normal(size=4)
    a, b, c, d = q / np.linalg.norm(q)
    return np.array([[a*a + b*b - c*c - d*d, 2*(b*c - a*d), 2*(b*d + a*c)],
                     [2*(b*c + a*d), a*a - b*b + c*c - d*d, 2*(c*d - a*b)],
                     [2*(b*d - a*c), 2*(c*d + a*b), a*a - b*b - c*c + d*d]])


def scan_of(mesh: ws.TriMesh, rng) -> np.ndarray:
    """A one-sided scan of ``COVERAGE`` of the surface, noisy, in a random pose (m)."""
    pts = surface_samples(mesh, int(POINTS / COVERAGE), seed=int(rng.integers(1 << 30)))
    u = rng.normal(size=3)
    u /= np.linalg.norm(u)
    dirs = pts - mesh.centroid()
    pts = pts[(dirs / np.linalg.norm(dirs, axis=1, keepdims=True)) @ u > 1 - 2 * COVERAGE]
    pts = pts + rng.normal(0.0, NOISE, pts.shape)
    return pts @ rotation(rng).T + rng.normal(0.0, 0.05, 3)


class Device:
    """The default design, the perturbed "device", its states and their scans."""

    def __init__(self, seed: int = 1, readings: bool = False):
        rng = np.random.default_rng(seed)
        self.design = d = cube_fig6_design(subdivisions=2)
        k0 = np.array([ip.stiffness for ip in d.ipams])
        a0 = np.array([ip.area for ip in d.ipams])
        self.truth = dict(youngs_modulus=d.material.youngs_modulus * 1.3,
                          bending_stiffness=d.material.bending_stiffness * 0.5,
                          ipam_stiffness=k0 * rng.uniform(0.8, 0.9, 5), ipam_area=a0 * rng.uniform(1.1, 1.2, 5),
                          rest_scale=1.02)
        self.device = apply_values(d, self.truth)
        n = host_model(d).rest_air
        self.states = [ControlState(n * air, tuple(1e3 * p for p in kpa)) for air, kpa in STATES]
        probe = [ws.ScanObservation(np.random.default_rng(0).random((60, 3)) * 0.05, s) for s in self.states]
        shapes, pressures = replay_held(self.device, [o.sequence(self.device) for o in probe], pressures=True)
        self.scans = [scan_of(self.device.rest.copy_with(x), rng) for x in shapes]
        self.pressures = pressures + rng.normal(0.0, PRESSURE_NOISE, len(pressures))  # a chamber sensor's readings
        read = [dict(pressure=r, pressure_stderr=PRESSURE_NOISE) if readings else {} for r in self.pressures]
        self.obs = [ws.ScanObservation(p * (1e3 if i == 0 else 1.0), s, name=f"s{i}", **r)  # s0 in mm
                    for i, (p, s, r) in enumerate(zip(self.scans, self.states, read))]
        self.cal = ws.calibrate(d, self.obs[:3])


@pytest.fixture(scope="module")
def dev():
    return Device(readings=True)


def test_units_of_the_scans_are_detected(dev):
    assert dev.obs[0].units == "mm" and dev.obs[1].units == "m"
    assert np.allclose(dev.obs[0].points, dev.scans[0])


def test_identifiable_parameters_are_recovered_and_their_errors_cover_the_truth(dev):
    cal = dev.cal
    assert cal.unidentifiable == [] and np.all(np.isfinite(cal.stderr["ipam_area"]))
    for name, truth in dev.truth.items():
        value, se = np.atleast_1d(cal.values[name]), np.atleast_1d(cal.stderr[name])
        truth = np.broadcast_to(truth, value.shape)
        seen = np.isfinite(se)
        err = np.abs(value / truth - 1.0)
        assert np.all(np.abs(value - truth)[seen] <= 3.0 * se[seen]), (name, value, truth, se)  # 3 sigma coverage
        if name != "bending_stiffness":  # determined to 1.5 % and recovered within 3 % (2 standard errors)
            assert np.all(se / value < 0.015) and np.all(err < 0.03), (name, err, se / value)
    assert [n.split(":")[0] for n in cal.poorly_determined] == ["bending_stiffness"], cal.poorly_determined
    assert all(r < 1.1 * NOISE * 1e3 for r in cal.residual_mm)
    assert all(b > a for a, b in zip(cal.residual_mm, cal.initial_residual_mm))


def test_a_held_out_scan_is_predicted_within_the_scanner_noise(dev):
    before = scan_residuals(dev.design, dev.obs[3]).rms_mm
    after = scan_residuals(dev.cal.design, dev.obs[3]).rms_mm
    assert after <= 1.2 * NOISE * 1e3 < before


def test_what_the_scans_cannot_separate_is_named(dev):
    """One scan at a state where IPAM 4 is unpressurised, E and t both fitted (one Gauss-Newton step):
    IPAM 4's area and the pair E ~ t are named not identifiable, their standard errors infinite."""
    state = ControlState(dev.states[0].air_moles, (200e3, -30e3, 100e3, 0.0, 0.0))
    shape = replay_held(dev.device, [ws.ScanObservation(dev.scans[0], state).sequence(dev.device)])[0]
    obs = ws.ScanObservation(scan_of(dev.device.rest.copy_with(shape), np.random.default_rng(5)), state)
    cal = ws.calibrate(dev.design, [obs], wrt=("youngs_modulus", "thickness", "ipam_area"), max_iterations=1)
    assert "ipam_area[4]" in cal.unidentifiable and "youngs_modulus ~ thickness" in cal.unidentifiable
    assert any("pressure never changed" in n for n in cal.notes)
    assert not np.isfinite(cal.stderr["ipam_area"][4]) and not np.isfinite(cal.stderr["youngs_modulus"])


@pytest.fixture(scope="module")
def stiff_parts(dev):
    """A device whose silicone is stiffer where the tubes leave it (the plug, E t x1.8) and along the
    cells' edges (x1.3), E t elsewhere as modelled, scanned at the three fitted states."""
    regions = region_faces(dev.design, ("plug", "cell_boundaries"))
    device = apply_values(dev.design, {"region_stretch": np.array([1.8, 1.3])}, regions=regions)
    rng = np.random.default_rng(7)
    seqs = [o.sequence(device) for o in dev.obs[:3]]
    shapes = replay_held(device, seqs)
    obs = [ws.ScanObservation(scan_of(device.rest.copy_with(x), rng), s, name=f"r{i}")
           for i, (x, s) in enumerate(zip(shapes, dev.states))]
    return dict(regions=regions, obs=obs, cal=ws.calibrate(dev.design, obs, wrt=("youngs_modulus",),
                                                           regions=("plug", "cell_boundaries")),
                uniform=ws.calibrate(dev.design, obs, wrt=("youngs_modulus",), max_iterations=3))


def test_e_t_is_fitted_per_region(stiff_parts):
    """The plug and the cells' edges fitted on their own recover their stiffness (within 3 standard
    errors) and explain the scans to the noise; one uniform E t cannot (measured: 0.35-0.65 mm after
    29 iterations; the test stops it at 3)."""
    cal, uniform = stiff_parts["cal"], stiff_parts["uniform"]
    assert cal.labels == ["youngs_modulus", "region_stretch[plug]", "region_stretch[cell_boundaries]"]
    value, se = cal.values["region_stretch"], cal.stderr["region_stretch"]
    truth = np.array([1.8, 1.3])
    assert np.all(np.abs(value - truth) <= 3.0 * se) and np.all(np.abs(value / truth - 1) < 0.1), (value, se)
    assert abs(cal.values["youngs_modulus"] / cal.start["youngs_modulus"] - 1) <= 3 * cal.stderr["youngs_modulus"] \
        / cal.start["youngs_modulus"]
    assert max(cal.residual_mm) < 1.05 * NOISE * 1e3 < min(uniform.residual_mm)
    expect = np.ones(cal.design.rest.n_faces)
    for faces, v in zip(stiff_parts["regions"].values(), value):
        expect[faces] *= v  # the two regions overlap: their multipliers multiply
    np.testing.assert_allclose(cal.design.stretch_scale, expect, rtol=1e-12)


def test_regions_that_cover_the_membrane_with_e_name_their_product(dev, stiff_parts, tmp_path):
    """Patches covering the whole membrane, fitted with E itself: only E times each patch's multiplier
    acts, so the fit names that combination; a calibration file keeps its regions and gives a design
    the same per-face E t, and refuses another membrane."""
    obs = stiff_parts["obs"][:1]
    cal = ws.calibrate(dev.design, obs, wrt=("youngs_modulus",), regions="patches:3", max_iterations=1)
    assert cal.labels[1:] == [f"region_stretch[patch{k}]" for k in range(3)]
    assert any(n.startswith("youngs_modulus ~ region_stretch[patch") for n in cal.unidentifiable), cal.unidentifiable
    assert not np.isfinite(cal.stderr["youngs_modulus"])
    good = stiff_parts["cal"]
    path = write_calibration(good, dev.design, tmp_path / "calibration.json")
    assert json.loads(path.read_text())["regions"]["plug"] == [int(f) for f in stiff_parts["regions"]["plug"]]
    np.testing.assert_allclose(apply_calibration(dev.design, path).stretch_scale, good.design.stretch_scale,
                               rtol=1e-12)
    with pytest.raises(ws.DesignError, match="faces"):
        apply_calibration(ws.Design(ws.icosphere(1, 0.04)), path)
    with pytest.raises(ws.DesignError, match="not known"):
        ws.calibrate(dev.design, obs, regions=("plugs",))


def test_a_pressure_reading_sharpens_the_stiffness_scale_and_one_state_leaves_k_with_a(dev):
    """One scan at one state, E t, every IPAM's k and A fitted (one Gauss-Newton step): a chamber
    pressure reading with the scan narrows E t's standard error; one state cannot part an IPAM's k from
    its A (both act at one pressure), which the fit reports as poorly determined with the remedy."""
    wrt = ("youngs_modulus", "ipam_stiffness", "ipam_area")
    scan = dev.obs[0].points
    bare = ws.calibrate(dev.design, [ws.ScanObservation(scan, dev.states[0])], wrt=wrt, max_iterations=1)
    read = ws.calibrate(dev.design, [ws.ScanObservation(scan, dev.states[0], pressure=float(dev.pressures[0]),
                                                        pressure_stderr=PRESSURE_NOISE)], wrt=wrt, max_iterations=1)
    rel = [c.stderr["youngs_modulus"] / c.values["youngs_modulus"] for c in (bare, read)]
    assert rel[1] < 0.8 * rel[0], rel
    assert any("stiffness and area act together at one pressure" in n for n in bare.poorly_determined), \
        bare.poorly_determined
    assert any("without chamber pressure readings" in n for n in bare.poorly_determined)
    assert not any("without chamber pressure readings" in n for n in read.poorly_determined)


def _objective_on(device, result, target) -> float:
    x = ws.replay(device, result)
    t = target.centered()
    return fit_objective_and_gradient(x, ws.RadialSampler(t), 0, device.rest.faces, t.volume())[0]


@pytest.fixture(scope="module")
def loop(dev):
    """{(target, model): (objective on the device, on the model)}: each target of the default problem
    controlled (method inverse) on the default and on the calibrated model, replayed on the device."""
    out = {}
    for name in ("oval", "heart"):
        target = ws.target(name)
        for label, model in (("default", dev.design), ("calibrated", dev.cal.design)):
            res = ws.control(model, target, settings=ws.ControlSettings(method="inverse",
                                                                        inverse_tolerance=LOOP_TOLERANCE))
            out[name, label] = (_objective_on(dev.device, res, target), _objective_on(model, res, target))
    return out


def test_sequences_controlled_on_the_calibrated_model_fit_the_device_better(loop):
    """The sim-to-real loop: on every target of the default problem the sequence controlled on the
    calibrated model fits the device better than the one controlled on the default model (the default
    model's IPAMs stroke 1.3-1.5 x less than the device's; docs/calibration.md has the figures), by
    more than the controller's own tolerance (so not by the controller's noise)."""
    for name in ("oval", "heart"):
        assert loop[name, "calibrated"][0] < (1.0 - LOOP_TOLERANCE) * loop[name, "default"][0], (name, loop)


def test_the_calibrated_model_predicts_what_its_sequences_do_on_the_device(loop):
    """The calibrated model's own fit objective of its sequence is the closer prediction of the device's."""
    for name in ("oval", "heart"):
        errors = [abs(loop[name, m][0] - loop[name, m][1]) for m in ("default", "calibrated")]
        assert errors[1] < errors[0], (name, loop)


def test_the_calibration_file_round_trips_and_is_checked(dev, tmp_path):
    path = write_calibration(dev.cal, dev.design, tmp_path / "calibration.json")
    data = json.loads(path.read_text())
    assert data["version"] == 1 and data["units"]["youngs_modulus"] == "Pa"
    assert data["stderr"]["ipam_area"][4] is not None and data["unidentifiable"] == []
    d = apply_calibration(dev.design, path)
    assert d.material.youngs_modulus == pytest.approx(dev.cal.values["youngs_modulus"])
    assert [ip.area for ip in d.ipams] == pytest.approx(list(dev.cal.values["ipam_area"]))
    assert read_calibration(path)["rest_scale"] == pytest.approx(dev.cal.values["rest_scale"])
    with pytest.raises(ws.DesignError, match="5 IPAMs"):
        apply_calibration(ws.Design(dev.design.rest), path)
    (tmp_path / "bad.json").write_text('{"format": "warp-shape calibration", "version": 1, '
                                       '"values": {"youngs_modulus": -3}}')
    with pytest.raises(ws.DesignError, match="positive"):
        read_calibration(tmp_path / "bad.json")


# ------------------------------------------------------------------------------------ the command line
@pytest.fixture(scope="module")
def lab(tmp_path_factory):
    """A lab folder: the design (162 vertices), a scan of the default device at one state, a manifest."""
    import trimesh

    root = tmp_path_factory.mktemp("lab")
    design = cube_fig6_design(subdivisions=2)
    ws.save_scene(ws.Scene(design=design, targets=[ws.target("oval")], target_names=["oval"]), root / "design.usda")
    n = host_model(design).rest_air
    state = {"air_mol": n * 1.8, "ipam_pressures_kpa": [150, 0, 100, 50, 0], "jammed": []}
    rng = np.random.default_rng(3)
    shape = replay_held(design, [ws.ScanObservation(rng.random((60, 3)) * 0.05, ControlState(
        state["air_mol"], tuple(p * 1e3 for p in state["ipam_pressures_kpa"]))).sequence(design)])[0]
    trimesh.PointCloud(scan_of(design.rest.copy_with(shape), rng) * 1e3).export(root / "scan.ply")
    trimesh.PointCloud(surface_samples(ws.TriMesh(*_cylinder()), 3000) * 1e3).export(root / "pipe.ply")
    g = np.stack(np.meshgrid(np.linspace(0, 0.03, 40), np.linspace(0, 0.03, 40)), -1).reshape(-1, 2)
    trimesh.PointCloud(np.c_[g, np.zeros(len(g))] * 1e3).export(root / "patch.ply")
    return root, state


def _cylinder():
    import trimesh

    c = trimesh.creation.cylinder(radius=0.01, height=0.15, sections=32)
    return np.asarray(c.vertices, np.float64), np.asarray(c.faces, np.int32)


def _manifest(root, name, observations) -> str:
    (root / name).write_text(json.dumps({"observations": observations}))
    return str(root / name)


def _calibrate(root, manifest, out, *extra):
    return main(["calibrate", manifest, "--design", str(root / "design.usda"), "--out", str(out), *extra])


@pytest.mark.parametrize("scan,state,message", [
    ("pipe.ply", None, "does not match the display"),
    ("patch.ply", None, "no overlap"),
    ("scan.ply", {"air_mol": 0.01, "ipam_pressures_kpa": [0, 0, 0], "jammed": []}, "has 5 IPAMs"),
    ("../outside.ply", None, "outside the manifest's folder"),
])
def test_bad_input_is_one_line_and_writes_nothing(lab, tmp_path, capsys, scan, state, message):
    root, good = lab
    manifest = _manifest(root, f"bad_{scan.strip('./')}.json", [{"scan": scan, "state": state or good}])
    out = tmp_path / "cal"
    assert _calibrate(root, manifest, out) == 2
    err = capsys.readouterr().err.strip()
    assert message in err and len(err.splitlines()) == 1, err
    assert not out.exists()


def test_a_region_the_design_lacks_is_one_line_and_writes_nothing(lab, tmp_path, capsys):
    root, state = lab
    (root / "regions.json").write_text(json.dumps({"observations": [{"scan": "scan.ply", "state": state}],
                                                   "regions": ["plug", "patches:1"]}))
    out = tmp_path / "cal"
    assert _calibrate(root, str(root / "regions.json"), out) == 2
    err = capsys.readouterr().err.strip()
    assert "patches:N with N from 2 to 32" in err and len(err.splitlines()) == 1, err
    plain = _manifest(root, "plain.json", [{"scan": "scan.ply", "state": state}])
    assert _calibrate(root, plain, out, "--regions", "ribs") == 2
    assert "'ribs' is not known" in capsys.readouterr().err
    assert not out.exists()


def test_calibrate_command_writes_a_file_that_control_takes(lab, tmp_path, capsys):
    root, state = lab
    manifest = _manifest(root, "good.json", [{"scan": "scan.ply", "state": state}])
    out, rrd = tmp_path / "cal", tmp_path / "cal.rrd"
    assert _calibrate(root, manifest, out, "--wrt", "youngs_modulus", "rest_scale", "--regions", "plug",
                      "--rerun", str(rrd)) == 0
    text = capsys.readouterr().out
    assert "region_stretch[plug]" in text and (out / "calibration.md").is_file()
    data = json.loads((out / "calibration.json").read_text())
    assert set(data["values"]) == {"youngs_modulus", "rest_scale", "region_stretch"}
    assert abs(data["values"]["rest_scale"] - 1.0) < 0.005  # the scan is of the default device
    plug = np.array(data["regions"]["plug"])
    assert 0 < len(plug) < 0.3 * data["design"]["faces"]
    # the residual map: a figure per scan and, in the recording, the replayed membrane and the aligned scan
    assert (out / "residuals_0.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    ents = read_recording(rrd)["entities"]
    mesh = ents["/calibration/0/membrane"]["static"]
    assert len(mesh["Mesh3D:vertex_positions"]) == 162 and len(mesh["Mesh3D:vertex_colors"]) == 162
    assert len(ents["/calibration/0/scan"]["static"]["Points3D:positions"]) > 0.5 * POINTS  # the kept points
    rms = ents["/calibration/0/rms_mm"]["static"]
    assert f"RMS {data['residual_mm'][0]:.3f} mm" in str(next(v for k, v in rms.items() if k.endswith("text")))
    assert main(["control", str(root / "design.usda"), "--calibration", str(out / "calibration.json"),
                 "--method", "paper", "--max-steps", "5", "--out", str(tmp_path / "ctl")]) == 0
    assert main(["control", str(root / "design.usda"), "--calibration", str(root / "scan.ply"),
                 "--out", str(tmp_path / "ctl2")]) == 2
    assert "is not JSON" in capsys.readouterr().err


def test_valve_and_control_files_give_the_sequence_their_result_recorded(tmp_path):
    """A manifest's state from a run's ``control_<target>.csv`` is the result's own sequence (to the
    CSV's 9 digits: replayed and held, within 1 um of it) and so is the one of its ``valve_<target>.csv``
    (its control-step rows; within 10 um). Rows and times select a prefix."""
    from warp_shape.calibration.files import control_sequence, read_manifest, valve_sequence
    from warp_shape.calibration.observations import result_sequence
    from warp_shape.io.outputs import control_csv_text
    from warp_shape.io.valve import write_valve_outputs

    design = cube_fig6_design(subdivisions=2)
    res = ws.control(design, ws.target("oval"), method="paper", max_steps=40)
    (tmp_path / "control_oval.csv").write_text(control_csv_text(res))
    write_valve_outputs([res], ["oval"], tmp_path)
    want = result_sequence(res, None)
    got = control_sequence(tmp_path / "control_oval.csv", design)
    for a, b in [(want.times, got.times), (want.air, got.air), (want.pressures, got.pressures)]:
        np.testing.assert_allclose(b, a, rtol=1e-8, atol=1e-9)
    np.testing.assert_array_equal(got.jammed, want.jammed)
    assert want.jammed[-1].any() and not want.jammed[0].any()  # the run jams cells on its way
    valve = valve_sequence(tmp_path / "valve_oval.csv", design)
    x = replay_held(design, [want, got, valve])
    assert np.abs(x[1] - x[0]).max() < 1e-6
    # the valve schedule is replayed from its control-step rows: the result's own sequence, to the CSV's 9
    # digits (before they were marked, its ramps replayed in simulated time jammed the cells on another
    # path: 0.51 mm at most, 0.11 mm on average here)
    moved = np.linalg.norm(x[2] - x[0], axis=1)
    assert moved.max() < 1e-5, moved.max()
    k = len(want.times) // 2
    part = control_sequence(tmp_path / "control_oval.csv", design, time_s=float(want.times[k]))
    assert len(part.times) == k + 1 and part.times[-1] == pytest.approx(want.times[k])
    assert len(control_sequence(tmp_path / "control_oval.csv", design, row=3).times) == 4
    trimesh = pytest.importorskip("trimesh")
    trimesh.PointCloud(res.achieved.vertices * 1e3).export(tmp_path / "scan.ply")
    manifest = tmp_path / "m.json"
    manifest.write_text(json.dumps({"observations": [{"scan": "scan.ply", "control": "control_oval.csv", "row": 3},
                                                     {"scan": "scan.ply", "valve": "valve_oval.csv"}]}))
    obs, _, _ = read_manifest(manifest, design)
    assert len(obs[0].sequence(design).times) == 4 and len(obs[1].sequence(design).times) == len(valve.times)
    with pytest.raises(ws.DesignError, match="control history of another design"):
        control_sequence(tmp_path / "control_oval.csv", _fewer_ipams(design))
    with pytest.raises(ws.DesignError, match="not a control history"):
        control_sequence(tmp_path / "valve_oval.csv", design)


def _fewer_ipams(design):
    return ws.Design(design.rest, design.material)  # no IPAMs
