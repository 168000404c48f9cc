"""Scenes as USD: round trips, shipped scenes, validation, corrupt inputs, atomic saves, animated export."""

from __future__ import annotations

import importlib.util
import os
import re
from pathlib import Path

import numpy as np
import pytest

pxr = pytest.importorskip("pxr")
from pxr import Sdf, Usd, UsdGeom, Vt  # noqa: E402

import warp_shape as ws  # noqa: E402
from warp_shape.errors import SceneError  # noqa: E402
from warp_shape.io import scene_write  # noqa: E402
from warp_shape.io.scene_read import load_scene, validate_usd  # noqa: E402
from warp_shape.io.scene_registry import list_scenes, resolve_targets, scene_dirs  # noqa: E402
from warp_shape.io.scene_schema import IPAM_ATTRIBUTES, MATERIAL_ATTRIBUTES, Scene  # noqa: E402
from warp_shape.io.scene_write import save_scene  # noqa: E402
from warp_shape.io.usd_animation import export_animation  # noqa: E402
from warp_shape.scenarios import cube_fig6_design  # noqa: E402
from warp_shape.simulation_settings import SimulationSettings  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
SHIPPED = ["cube_fig6", "oval_heart", "four_targets_5", "four_targets_20",
           "target_oval", "target_pear", "target_heart", "target_cube"]


def _generator():
    spec = importlib.util.spec_from_file_location("make_scenes", ROOT / "scripts" / "make_scenes.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


@pytest.fixture(scope="module")
def definitions():
    return _generator().scene_definitions()


# ------------------------------------------------------------------------------------------ comparison
def assert_designs_equal(a: ws.Design, b: ws.Design):
    assert (a is None) == (b is None)
    if a is None:
        return
    np.testing.assert_array_equal(a.rest.vertices, b.rest.vertices)
    np.testing.assert_array_equal(a.rest.faces, b.rest.faces)
    assert a.rest.vertices.dtype == b.rest.vertices.dtype == np.float64
    assert a.material == b.material
    assert a.material.to_dict() == b.material.to_dict()
    assert a.n_ipams == b.n_ipams and a.n_cells == b.n_cells
    for p, q in zip(a.ipams, b.ipams):
        assert (p.face_a, p.face_b) == (q.face_a, q.face_b)
        assert p.stiffness == q.stiffness and p.area == q.area and p.free_length == q.free_length
        assert p.pressure_limits == q.pressure_limits and p.damping == q.damping
        assert p.rest_length == q.rest_length
        np.testing.assert_array_equal(p.pairs, q.pairs)
        np.testing.assert_array_equal(p.offsets, q.offsets)
    for c, e in zip(a.cells, b.cells):
        np.testing.assert_array_equal(c.faces, e.faces)
    np.testing.assert_array_equal(a.face_cell(), b.face_cell())


#: generated target shapes go through NumPy's trigonometry, whose last bit differs between NumPy builds and
#: CPUs; shipped files are compared with the generator to this relative tolerance, round trips exactly
GENERATOR_RTOL = 1e-12


def assert_scenes_equal(a: Scene, b: Scene, rtol: float = 0.0):
    assert_designs_equal(a.design, b.design)
    assert a.target_names == b.target_names
    assert len(a.targets) == len(b.targets)
    for s, t in zip(a.targets, b.targets):
        np.testing.assert_allclose(s.vertices, t.vertices, rtol=rtol, atol=rtol * np.abs(s.vertices).max())
        np.testing.assert_array_equal(s.faces, t.faces)
    assert a.settings == b.settings
    for group in a.settings:
        for key, value in a.settings[group].items():
            assert type(b.settings[group][key]) is type(value), (group, key)


def _full_scene() -> Scene:
    d = cube_fig6_design()
    # a non-default material and IPAM parameters, so every field is exercised
    mat = ws.Material(youngs_modulus=71234.5, thickness=1.9e-3, areal_density=3.25, bending_stiffness=1.3e-4,
                      spring_damping=4e-3, viscous_damping=0.025, jam_stretch_factor=9.5, jam_bend_factor=27.0,
                      temperature=295.0, atmospheric_pressure=100e3, membrane="yeoh", shear_modulus=21e3,
                      yeoh_c2=900.0, yeoh_c3=40.0, compression="tension_field")
    d2 = ws.Design(d.rest, mat)
    for i, ip in enumerate(d.ipams):
        d2.add_ipam(ip.face_a, ip.face_b, stiffness=40.0 + i, area=1.2e-5 + 1e-7 * i,
                    free_length=None if i % 2 else 0.061 + 1e-3 * i, pressure_limits=(-40e3 - i, 250e3 + i),
                    damping=0.003 + 1e-4 * i)
    for c in d.cells:
        d2.add_cell(c.faces)
    settings = {"simulation": {"integrator": "rk4", "dt": 1e-3, "precision": "float64", "bending": "paper"},
                "controller": {"period_steps": 20, "volume_deadband": 0.01, "enabled": True, "note": "a b c"},
                "designer": {"actuators": 5, "cell_radius": 0.012, "seed": -(2**40)}}
    return Scene(design=d2, targets=[ws.target("cube"), ws.target("oval", volume=2e-4)],
                 target_names=["cube", "small_oval"], settings=settings)


# ------------------------------------------------------------------------------------------ round trips
@pytest.mark.parametrize("ext", [".usda", ".usdc", ".usd"])
def test_round_trip_every_field(tmp_path, ext):
    sc = _full_scene()
    path = save_scene(sc, tmp_path / f"full{ext}")
    assert path.exists() and sorted(os.listdir(tmp_path)) == [path.name]
    back = load_scene(path)
    assert_scenes_equal(sc, back)
    assert validate_usd(path) == []
    if ext == ".usda":
        text = path.read_text()
        assert 'subdivisionScheme = "none"' in text and 'upAxis = "Z"' in text and "metersPerUnit = 1" in text
        assert 'defaultPrim = "Scene"' in text and 'familyName = "jammingCell"' in text


def test_attribute_table_names_and_types_what_is_written(tmp_path):
    stage = Usd.Stage.Open(str(save_scene(_full_scene(), tmp_path / "table.usda")))
    for prim_path, table in (("/Scene/Membrane", MATERIAL_ATTRIBUTES), ("/Scene/Ipams", IPAM_ATTRIBUTES)):
        prim = stage.GetPrimAtPath(prim_path)
        for attr in table:
            a = prim.GetAttribute(attr.name)
            assert a and str(a.GetTypeName()) == attr.usd_type, attr.name
    n = len(_full_scene().design.ipams)
    assert len(stage.GetPrimAtPath("/Scene/Ipams").GetAttribute("warpShape:pairs").Get()) == 3 * n


def test_shipped_scenes_present_valid_and_equal_to_generator(definitions):
    assert sorted(list_scenes()) == sorted(SHIPPED)
    assert list(definitions) and sorted(definitions) == sorted(SHIPPED)
    for name in SHIPPED:
        path = scene_dirs()[0] / f"{name}.usda"
        assert path.stat().st_size < 1.5e6, name
        assert validate_usd(path) == [], name
        loaded = load_scene(name)
        assert_scenes_equal(definitions[name][0], loaded, rtol=GENERATOR_RTOL)


@pytest.mark.parametrize("name", SHIPPED)
def test_shipped_scene_round_trip(tmp_path, name):
    sc = load_scene(name)
    for ext in (".usda", ".usdc"):
        path = save_scene(sc, tmp_path / f"{name}{ext}")
        assert validate_usd(path) == []
        assert_scenes_equal(sc, load_scene(path))


def test_shipped_problem_contents():
    fig6 = load_scene("cube_fig6")
    assert fig6.design.n_ipams == 5 and fig6.design.n_cells == 10 and fig6.target_names == ["cube"]
    oh = load_scene("oval_heart")
    assert oh.target_names == ["oval", "heart"] and oh.design.rest.n_vertices == 642
    assert oh.settings["designer"]["actuators"] == 4
    f5, f20 = load_scene("four_targets_5"), load_scene("four_targets_20")
    assert f5.target_names == f20.target_names == ["oval", "pear", "heart", "cube"]
    assert f5.settings["designer"]["actuators"] == 5 and f20.settings["designer"]["actuators"] == 20
    assert f20.settings["designer"]["cell_radius"] == pytest.approx(f5.settings["designer"]["cell_radius"] / 2)
    assert oh.settings["designer"]["cell_radius"] > f5.settings["designer"]["cell_radius"]
    for name in ("oval", "pear", "heart", "cube"):
        t = load_scene(f"target_{name}")
        assert t.design is None
        np.testing.assert_allclose(t.targets[0].vertices, ws.target(name).vertices, rtol=0, atol=GENERATOR_RTOL)


_NUMBER = re.compile(r"-?\d+\.\d*(?:[eE][-+]?\d+)?|-?\d+[eE][-+]?\d+")


def _text_and_numbers(text: str):
    """A file's text with its decimal numbers taken out, and those numbers."""
    return _NUMBER.sub("#", text), np.array([float(x) for x in _NUMBER.findall(text)])


def test_generator_reproduces_shipped_files(tmp_path):
    """The shipped scenes are what scripts/make_scenes.py writes today: the same text, numbers equal to the
    generator's last-bit tolerance (byte identity would tie the files to one NumPy build)."""
    paths = _generator().write_scenes(tmp_path)
    assert sorted(p.stem for p in paths) == sorted(SHIPPED)
    for p in paths:
        new, old = (_text_and_numbers(f.read_text()) for f in (p, scene_dirs()[0] / p.name))
        stale = f"{p.name} is stale: run scripts/make_scenes.py"
        assert new[0] == old[0] and new[1].shape == old[1].shape, stale
        np.testing.assert_allclose(new[1], old[1], rtol=GENERATOR_RTOL, atol=1e-15, err_msg=stale)
    assert not [n for n in os.listdir(tmp_path) if n.startswith(".")]  # no temporary files left


def test_loaded_scene_simulates_identically():
    d = cube_fig6_design()
    loaded = load_scene("cube_fig6").design
    out = []
    for design in (d, loaded):
        sim = ws.Simulator(design, precision="float64")
        sim.air_moles *= 1.2
        sim.ipam_pressures = np.linspace(-20e3, 80e3, design.n_ipams)
        sim.step(10)
        sim.jam(0)
        sim.step(10)
        out.append(sim.positions)
    assert np.array_equal(out[0], out[1])


def test_scene_simulation_settings():
    sc = load_scene("cube_fig6")
    settings = sc.simulation_settings
    assert isinstance(settings, SimulationSettings) and settings == SimulationSettings()
    assert Scene(settings={"simulation": {"dt": 2e-3, "precision": "float64"}}).simulation_settings == \
        SimulationSettings(dt=2e-3, precision="float64")
    sim = ws.Simulator(sc.design, **settings.replace(dt=2e-3).to_dict())
    assert sim.dt == 2e-3 and sim.precision == settings.precision


def test_targets_by_name_resolve_outside_the_scene():
    meshes, names = resolve_targets(["oval", ws.target("cube")])
    assert names == ["oval", "target1"]
    np.testing.assert_array_equal(meshes[0].vertices, ws.target("oval").vertices)
    sc = Scene(targets=meshes, target_names=names)
    assert sc.target("oval") is meshes[0]
    with pytest.raises(SceneError, match="resolve_targets"):
        Scene(targets=["oval"])


# ------------------------------------------------------------------------------------------ errors
def test_unknown_name_lists_available():
    with pytest.raises(SceneError, match="cube_fig6") as info:
        load_scene("no_such_scene")
    assert "four_targets_20" in str(info.value)


def test_bad_inputs_to_scene_and_save(tmp_path):
    with pytest.raises(SceneError, match="identifier"):
        Scene(targets=[ws.target("oval")], target_names=["my oval"])
    with pytest.raises(SceneError, match="bool, int, float or str"):
        Scene(settings={"designer": {"radii": [1, 2]}})
    with pytest.raises(SceneError, match=r"\.usda"):
        save_scene(Scene(), tmp_path / "scene.obj")
    with pytest.raises(SceneError, match="not found"):
        load_scene(tmp_path / "missing.usda")


@pytest.fixture()
def saved(tmp_path):
    d = cube_fig6_design()
    path = save_scene(Scene(design=d, targets=[ws.target("cube")], target_names=["cube"]), tmp_path / "s.usda")
    return path


def _edit(path: Path, fn):
    stage = Usd.Stage.Open(str(path))
    fn(stage)
    stage.GetRootLayer().Save()
    del stage


@pytest.mark.parametrize("ext", [".usda", ".usdc"])
def test_truncated_file(tmp_path, ext):
    path = save_scene(Scene(design=cube_fig6_design()), tmp_path / f"s{ext}")
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    with pytest.raises(SceneError, match="not a readable USD file"):
        load_scene(path)


def test_removed_required_attribute(saved):
    _edit(saved, lambda st: st.GetPrimAtPath("/Scene/Membrane").RemoveProperty("warpShape:youngsModulus"))
    with pytest.raises(SceneError, match=r"</Scene/Membrane>\.warpShape:youngsModulus: required attribute is missing") as e:
        load_scene(saved)
    assert e.value.prim == "/Scene/Membrane" and e.value.attribute == "warpShape:youngsModulus"


def test_removed_ipam_attribute(saved):
    _edit(saved, lambda st: st.GetPrimAtPath("/Scene/Ipams").RemoveProperty("warpShape:stiffness"))
    with pytest.raises(SceneError, match=r"</Scene/Ipams>\.warpShape:stiffness: required"):
        load_scene(saved)


def test_wrong_type(saved):
    def edit(st):
        prim = st.GetPrimAtPath("/Scene/Membrane")
        prim.RemoveProperty("warpShape:thickness")
        prim.CreateAttribute("warpShape:thickness", Sdf.ValueTypeNames.String, custom=True).Set("2 mm")

    _edit(saved, edit)
    with pytest.raises(SceneError, match=r"</Scene/Membrane>\.warpShape:thickness: has type string"):
        load_scene(saved)


def test_invalid_material_value(saved):
    _edit(saved, lambda st: st.GetPrimAtPath("/Scene/Membrane").GetAttribute("warpShape:temperature").Set(-3.0))
    with pytest.raises(SceneError, match=r"</Scene/Membrane>\.warpShape:temperature: Material.temperature must be > 0"):
        load_scene(saved)


def test_ipam_face_out_of_range(saved):
    def edit(st):
        a = st.GetPrimAtPath("/Scene/Ipams").GetAttribute("warpShape:faces")
        v = np.array(a.Get())
        v[2, 1] = 99999
        a.Set(Vt.Vec2iArray.FromNumpy(v.astype(np.int32)))

    _edit(saved, edit)
    with pytest.raises(SceneError, match=r"</Scene/Ipams>\.warpShape:faces: IPAM 2 joins faces .*99999.*out of range"):
        load_scene(saved)


def test_cell_face_out_of_range(saved):
    _edit(saved, lambda st: st.GetPrimAtPath("/Scene/Membrane/Cell_003").GetAttribute("indices").Set(
        Vt.IntArray([1, 2, 5000])))
    with pytest.raises(SceneError, match=r"</Scene/Membrane/Cell_003>\.indices: face 5000 is out of range"):
        load_scene(saved)


def test_overlapping_cells(saved):
    def edit(st):
        c0 = st.GetPrimAtPath("/Scene/Membrane/Cell_000").GetAttribute("indices").Get()
        st.GetPrimAtPath("/Scene/Membrane/Cell_004").GetAttribute("indices").Set(c0)

    _edit(saved, edit)
    with pytest.raises(SceneError, match=r"</Scene/Membrane/Cell_004>\.indices: face \d+ is already in cell "
                                         r"</Scene/Membrane/Cell_000>"):
        load_scene(saved)
    assert validate_usd(saved) != []  # the nonOverlapping family is flagged by the USD validators too


def test_non_manifold_membrane(saved):
    def edit(st):
        mesh = UsdGeom.Mesh.Get(st, "/Scene/Membrane")
        idx = np.array(mesh.GetFaceVertexIndicesAttr().Get())
        counts = np.array(mesh.GetFaceVertexCountsAttr().Get())
        mesh.GetFaceVertexIndicesAttr().Set(Vt.IntArray.FromNumpy(np.concatenate([idx, idx[:3]]).astype(np.int32)))
        mesh.GetFaceVertexCountsAttr().Set(Vt.IntArray.FromNumpy(np.append(counts, 3).astype(np.int32)))

    _edit(saved, edit)
    with pytest.raises(SceneError, match=r"</Scene/Membrane>\.faceVertexIndices/warpShape:restPoints: not a valid "
                                         r"closed membrane mesh: mesh is not 2-manifold"):
        load_scene(saved)


def test_membrane_index_out_of_range_and_quads(saved, tmp_path):
    _edit(saved, lambda st: UsdGeom.Mesh.Get(st, "/Scene/Membrane").GetFaceVertexIndicesAttr().Set(
        Vt.IntArray([0, 1, 700000] + list(UsdGeom.Mesh.Get(st, "/Scene/Membrane").GetFaceVertexIndicesAttr().Get())[3:])))
    with pytest.raises(SceneError, match=r"</Scene/Membrane>\.faceVertexIndices: index 700000 \(face 0\) is out of range"):
        load_scene(saved)


def test_edited_points_disagree_with_rest_points(saved):
    def edit(st):
        a = UsdGeom.Mesh.Get(st, "/Scene/Membrane").GetPointsAttr()
        a.Set(Vt.Vec3fArray.FromNumpy(np.array(a.Get()) * np.float32(1.5)))

    _edit(saved, edit)
    with pytest.raises(SceneError, match=r"</Scene/Membrane>\.points: disagrees with warpShape:restPoints"):
        load_scene(saved)


def test_not_a_scene(tmp_path):
    stage = Usd.Stage.CreateNew(str(tmp_path / "other.usda"))
    UsdGeom.Xform.Define(stage, "/World")
    stage.SetDefaultPrim(stage.GetPrimAtPath("/World"))
    stage.GetRootLayer().Save()
    with pytest.raises(SceneError, match=r"</World>\.warpShape:formatVersion: required attribute is missing"):
        load_scene(tmp_path / "other.usda")


@pytest.mark.parametrize("ext", [".usda", ".usdc"])
def test_failed_save_leaves_no_partial_or_temporary_file(tmp_path, monkeypatch, ext):
    good = save_scene(Scene(design=cube_fig6_design()), tmp_path / f"keep{ext}")
    before = good.read_bytes()

    def failing_export(layer, tmp):
        with open(tmp, "wb") as fh:
            fh.write(b"#usda 1.0\n(\n  partial")
        raise RuntimeError("disk full (injected)")

    monkeypatch.setattr(scene_write, "export_layer", failing_export)
    with pytest.raises(RuntimeError, match="injected"):
        save_scene(_full_scene(), good)  # overwrite: the old file must survive intact
    with pytest.raises(RuntimeError, match="injected"):
        save_scene(_full_scene(), tmp_path / f"new{ext}")
    with pytest.raises(RuntimeError, match="injected"):
        d = cube_fig6_design()
        export_animation(tmp_path / f"anim{ext}", d, d.rest.vertices[None], [0.0])
    assert sorted(os.listdir(tmp_path)) == [good.name]
    assert good.read_bytes() == before
    monkeypatch.undo()
    load_scene(good)


# ------------------------------------------------------------------------------------------ animation
@pytest.fixture(scope="module")
def recorded():
    d = cube_fig6_design()
    sim = ws.Simulator(d, dt=1e-3)
    frames, times, pressures, forces, jams = [], [], [], [], []

    def record():
        frames.append(sim.positions)
        times.append(sim.time)
        pressures.append(np.array(sim.ipam_pressures, dtype=np.float64))
        forces.append(sim.ipam_forces())
        jams.append(sim.jammed.copy())

    sim.air_moles *= 1.3
    sim.ipam_pressures = np.full(d.n_ipams, 60e3)
    record()
    for k in range(1, 9):
        sim.step(5)
        if k == 4:
            sim.jam(0)
            sim.jam(3)
        record()
    return d, np.array(frames), np.array(times), np.array(pressures), np.array(forces), np.array(jams)


@pytest.mark.parametrize("ext", [".usda", ".usdc"])
def test_animation_export(tmp_path, recorded, ext):
    d, frames, times, pressures, forces, jams = recorded
    assert jams[0].sum() == 0 and jams[-1][[0, 3]].all()
    path = export_animation(tmp_path / f"run{ext}", d, frames, times, ipam_pressures=pressures, ipam_forces=forces,
                            jammed=jams, targets=[ws.target("cube")], target_names=["cube"],
                            settings={"simulation": {"dt": 1e-3}})
    assert sorted(os.listdir(tmp_path)) == [path.name]
    assert validate_usd(path) == []
    stage = Usd.Stage.Open(str(path))
    nfr = frames.shape[0]
    # content tools play at 24 frames per second: time codes and frames per second both 24
    assert stage.GetTimeCodesPerSecond() == stage.GetFramesPerSecond() == 24.0
    mesh = UsdGeom.Mesh.Get(stage, "/Scene/Membrane")
    pts = mesh.GetPointsAttr()
    samples = pts.GetTimeSamples()
    assert len(samples) == nfr
    assert stage.GetStartTimeCode() == samples[0] == 0.0 and stage.GetEndTimeCode() == samples[-1]
    np.testing.assert_allclose(np.array(samples) / 24.0, times - times[0], rtol=0, atol=1e-9)
    assert stage.GetEndTimeCode() == pytest.approx(24.0 * (times[-1] - times[0]))
    np.testing.assert_array_equal(np.array(pts.Get(samples[-1])), frames[-1].astype(np.float32))
    np.testing.assert_array_equal(np.array(pts.Get(samples[3])), frames[3].astype(np.float32))
    # the rest shape stays readable: default value and exact rest points
    np.testing.assert_array_equal(np.array(pts.Get(Usd.TimeCode.Default())), d.rest.vertices.astype(np.float32))
    np.testing.assert_array_equal(np.array(mesh.GetPrim().GetAttribute("warpShape:restPoints").Get()), d.rest.vertices)
    ext_last = np.array(mesh.GetExtentAttr().Get(samples[-1]))
    np.testing.assert_array_equal(ext_last, np.stack([frames[-1].astype(np.float32).min(0),
                                                      frames[-1].astype(np.float32).max(0)]))
    # IPAMs: end-face centroids per frame, pressures and forces per frame
    curves = UsdGeom.BasisCurves.Get(stage, "/Scene/Ipams")
    cs = curves.GetPointsAttr().GetTimeSamples()
    assert len(cs) == nfr
    last_ends = np.array(curves.GetPointsAttr().Get(cs[-1]))
    tri = d.rest.faces[[f for ip in d.ipams for f in (ip.face_a, ip.face_b)]]
    np.testing.assert_allclose(last_ends, frames[-1][tri].mean(axis=1), rtol=0, atol=1e-7)
    pa = curves.GetPrim().GetAttribute("warpShape:pressure")
    assert pa.GetNumTimeSamples() == nfr
    np.testing.assert_array_equal(np.array(pa.Get(samples[-1])), pressures[-1])
    np.testing.assert_array_equal(np.array(curves.GetPrim().GetAttribute("warpShape:force").Get(samples[-1])), forces[-1])
    # jam state: a per-face uniform primvar, held between changes
    pv = UsdGeom.PrimvarsAPI(mesh).GetPrimvar("warpShape:jammed")
    assert pv.GetInterpolation() == UsdGeom.Tokens.uniform
    face_cell = d.face_cell()
    expect_last = np.isin(face_cell, [0, 3]).astype(np.int32)
    np.testing.assert_array_equal(np.array(pv.Get(samples[-1])), expect_last)
    np.testing.assert_array_equal(np.array(pv.Get(samples[0])), np.zeros(d.rest.n_faces, np.int32))
    np.testing.assert_array_equal(np.array(pv.Get(samples[3])), np.zeros(d.rest.n_faces, np.int32))
    np.testing.assert_array_equal(np.array(mesh.GetPrim().GetAttribute("warpShape:cellJammed").Get(samples[-1])),
                                  jams[-1])
    # the file is also a scene: it loads back as the same design
    back = load_scene(path)
    assert_designs_equal(d, back.design)
    assert back.target_names == ["cube"] and back.settings == {"simulation": {"dt": 1e-3}}


def test_animation_plays_over_a_given_duration(tmp_path, recorded):
    d, frames, times, *_ = recorded
    path = export_animation(tmp_path / "slow.usda", d, frames, times, duration=3.0, playback={"timing": "test"})
    stage = Usd.Stage.Open(str(path))
    assert stage.GetTimeCodesPerSecond() == stage.GetFramesPerSecond() == 24.0
    assert stage.GetEndTimeCode() == pytest.approx(72.0)  # 3 s at 24 per second
    samples = np.array(UsdGeom.Mesh.Get(stage, "/Scene/Membrane").GetPointsAttr().GetTimeSamples())
    np.testing.assert_allclose(samples, 72.0 * (times - times[0]) / (times[-1] - times[0]), atol=1e-9)
    meta = stage.GetRootLayer().customLayerData["warpShape:playback"]
    assert meta["timing"] == "test" and meta["duration_s"] == pytest.approx(3.0)
    with pytest.raises(SceneError, match="duration"):
        export_animation(tmp_path / "bad.usda", d, frames, times, duration=0.0)


def test_control_animation_plays_at_the_valve_schedule(tmp_path):
    """A controlled run's animation lasts as long as its valve schedule (the lab's clock: pump and
    valve limits, every frame a row of the valve CSV), not the simulator's fraction of a second;
    ``playback="simulated"`` keeps the simulated clock."""
    from warp_shape.io.outputs import write_control_usd
    from warp_shape.io.usd_animation import playback_times
    from warp_shape.io.valve import valve_schedule

    res = ws.control(cube_fig6_design(subdivisions=2), ws.target("cube"), max_steps=15)
    schedule = valve_schedule(res)
    valve_s = float(schedule["time_s"][-1])
    sim_s = float(res.history["time"][-1] - res.history["time"][0])
    assert valve_s > 2 * sim_s  # real valves are slower than the simulated steps
    for playback, seconds in (("valve", valve_s), ("simulated", sim_s)):
        stage = Usd.Stage.Open(str(write_control_usd(res, tmp_path / f"{playback}.usdc", "cube", playback=playback)))
        assert stage.GetTimeCodesPerSecond() == stage.GetFramesPerSecond() == 24.0
        assert stage.GetStartTimeCode() == 0.0
        assert stage.GetEndTimeCode() == pytest.approx(24.0 * seconds, rel=1e-9)
        assert stage.GetRootLayer().customLayerData["warpShape:playback"]["timing"] == playback
    frames = playback_times(res, "valve")
    assert frames[-1] == pytest.approx(valve_s)
    # every frame is a row of the valve CSV: its time on the 50 Hz grid, its simulated time the step's
    rows = np.searchsorted(schedule["time_s"], frames - 1e-9)
    np.testing.assert_allclose(schedule["time_s"][rows], frames, atol=1e-12)
    np.testing.assert_allclose(schedule["sim_time_s"][rows], playback_times(res, "simulated"), atol=1e-12)
    stage = Usd.Stage.Open(str(tmp_path / "valve.usdc"))
    meta = stage.GetRootLayer().customLayerData["warpShape:playback"]
    assert (meta["max_flow_ml_s"], meta["max_slew_kpa_s"], meta["rate_hz"]) == (5.0, 100.0, 50.0)
    with pytest.raises(SceneError, match="playback"):
        playback_times(res, "fast")


def test_animation_input_checks(tmp_path):
    d = cube_fig6_design()
    x = np.repeat(d.rest.vertices[None], 3, axis=0)
    with pytest.raises(SceneError, match="frames must have shape"):
        export_animation(tmp_path / "a.usda", d, x[:, :10], [0, 1, 2])
    with pytest.raises(SceneError, match="strictly increasing"):
        export_animation(tmp_path / "a.usda", d, x, [0, 1, 1])
    with pytest.raises(SceneError, match="ipam_pressures must have shape"):
        export_animation(tmp_path / "a.usda", d, x, [0, 1, 2], ipam_pressures=np.zeros((3, 2)))
    assert os.listdir(tmp_path) == []


def test_missing_referenced_target_file(tmp_path):
    copy = tmp_path / "cube_fig6.usda"
    copy.write_bytes((scene_dirs()[0] / "cube_fig6.usda").read_bytes())
    with pytest.raises(SceneError, match=r"composition error.*target_cube\.usda"):
        load_scene(copy)
    (tmp_path / "target_cube.usda").write_bytes((scene_dirs()[0] / "target_cube.usda").read_bytes())
    assert load_scene(copy).target_names == ["cube"]
