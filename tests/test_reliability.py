"""Nothing NaN, nothing lost, nothing hangs: every failure a bad-input sweep found, each with its message.

A simulator that raises keeps its last good state (or refuses further steps with the same error);
an interrupt inside a step leaves a state whose positions, step count and time agree; inputs are
checked in the precision they are stored in; an output step that would need more internal steps
than ``max_substeps`` is refused naming the value behind it; API and scene-loader checks raise
warp_shape errors, never library tracebacks.
"""

from __future__ import annotations

import numpy as np
import pytest

import warp_shape as ws


def _sphere(subdivisions=1):
    return ws.icosphere(subdivisions, 0.04)


def _runaway(sim):
    v = np.zeros((sim.model.n_vertices, 3))
    v[0] = [1e5, 0, 0]  # crosses the device in one internal step
    return v


# --------------------------------------------------------------------------- last good state


def test_blowup_restores_the_last_good_state():
    """After a SimulationError the state is that after the last whole output step: finite, with the
    step count and time that belong to it; the simulator keeps working once the bad input is gone."""
    d = ws.Design(_sphere())
    clean = ws.Simulator(d)
    clean.step(2)
    sim = ws.Simulator(d)
    sim.step(2)
    x2, v2 = sim.positions, sim.velocities
    sim.velocities = _runaway(sim)
    with pytest.raises(ws.SimulationError, match=r"blew up at output step 3 .*ran away"):
        sim.step(3)
    assert sim.step_count == 2 and sim.time == pytest.approx(2 * sim.dt)
    np.testing.assert_array_equal(sim.positions, x2)  # the failed step left no trace in the positions
    assert sim.volume() == pytest.approx(d.rest.volume(), rel=0.05) and np.isfinite(sim.pressure())
    sim.velocities = v2  # the bad input taken back: the run continues as if it never happened
    sim.air_moles = sim.air_moles  # the old failure mode: "cannot convert float NaN to integer"
    sim.step(1)
    clean.step(1)
    np.testing.assert_allclose(sim.positions, clean.positions, atol=1e-9)
    assert sim.step_count == 3 and np.all(np.isfinite(sim.positions))


def test_state_corrupted_behind_the_api_refuses_every_further_step():
    """Where even the last good state is not finite, every further step repeats the clear error
    until positions and velocities are set through the API. (On the GPU path the last good state is
    the one at the start of a call, here already corrupted.)"""
    from warp_shape.integrators import BlowupWatch

    sim = ws.Simulator(ws.Design(_sphere()))
    sim.blowup_watch = BlowupWatch(sim.solver.status, deferred=True)
    sim.step(1)
    x = sim.state.x.numpy()
    x[0, 3, 1] = np.nan
    sim.state.x.assign(x)
    with pytest.raises(ws.SimulationError, match="positions became non-finite"):
        sim.step(1)
    for _ in range(2):
        with pytest.raises(ws.SimulationError, match="non-finite.*set positions and velocities to continue"):
            sim.step(1)
    assert sim.step_count == 1
    sim.positions = sim.design.rest.vertices
    sim.step(2)
    assert sim.step_count == 3 and np.all(np.isfinite(sim.positions))


def test_state_corrupted_between_calls_is_undone_on_cpu():
    """On CPU the last good state is the one after the last whole output step: a corruption behind
    the API's back after it is undone with the failed step, which is then taken again (automatic
    substeps retry a blown-up step from the last good state) and continues the clean trajectory."""
    d = ws.Design(_sphere())
    clean = ws.Simulator(d)
    clean.step(2)
    sim = ws.Simulator(d)
    sim.step(1)
    x = sim.state.x.numpy()
    x[0, 3, 1] = np.nan
    sim.state.x.assign(x)
    sim.step(1)
    assert sim.step_count == 2 and np.all(np.isfinite(sim.positions))
    np.testing.assert_allclose(sim.positions, clean.positions, atol=1e-5)  # (taken with shorter steps)


def test_interrupt_inside_a_step_leaves_a_consistent_state(monkeypatch):
    """Ctrl-C in the middle of an output step's internal steps: that output step did not happen
    (positions, velocities, step_count and time those before it), so a rerun of it continues the
    same trajectory as a clean run. The old behaviour kept the internal steps run (13.4 mm off)."""
    d = ws.Design(_sphere())
    clean = ws.Simulator(d)
    clean.air_moles = clean.air_moles * 1.3
    clean.step(2)
    sim = ws.Simulator(d)
    sim.air_moles = sim.air_moles * 1.3
    sim.step(1)
    x1 = sim.positions
    run = sim.plan.run

    def interrupted(count):
        run(max(1, count // 2))  # half the internal steps of the output step, then Ctrl-C
        raise KeyboardInterrupt

    monkeypatch.setattr(sim.plan, "run", interrupted)
    with pytest.raises(KeyboardInterrupt):
        sim.step(1)
    monkeypatch.setattr(sim.plan, "run", run)
    assert sim.step_count == 1 and sim.time == pytest.approx(sim.dt)
    np.testing.assert_array_equal(sim.positions, x1)
    sim.step(1)
    np.testing.assert_allclose(sim.positions, clean.positions, atol=1e-9)


def _interrupt_third_output_step(monkeypatch, sim):
    """``sim.step(5)`` interrupted (Ctrl-C) in its third output step; returns the real step runner."""
    run, calls = sim.plan.run, []

    def interrupted(count):
        calls.append(count)
        if len(calls) == 3:
            raise KeyboardInterrupt
        run(count)

    monkeypatch.setattr(sim.plan, "run", interrupted)
    with pytest.raises(KeyboardInterrupt):
        sim.step(5)
    return run


def test_interrupt_keeps_the_whole_output_steps_already_taken(monkeypatch):
    """An interrupt in the third output step of ``step(5)`` keeps the two whole ones before it."""
    d = ws.Design(_sphere())
    sim = ws.Simulator(d)
    sim.air_moles = sim.air_moles * 1.3
    run = _interrupt_third_output_step(monkeypatch, sim)
    monkeypatch.setattr(sim.plan, "run", run)
    ref = ws.Simulator(d)
    ref.air_moles = ref.air_moles * 1.3
    ref.step(2)
    assert sim.step_count == 2
    np.testing.assert_array_equal(sim.positions, ref.positions)


def test_deferred_blowup_check_undoes_the_whole_call(monkeypatch):
    """The GPU path reads blow-up codes at the end of a call: a failed or interrupted call is undone
    whole (the state, step count and time before it), never left part-way."""
    from warp_shape.integrators import BlowupWatch

    d = ws.Design(_sphere())
    sim = ws.Simulator(d)
    sim.blowup_watch = BlowupWatch(sim.solver.status, deferred=True)
    sim.step(2)
    x2, v2 = sim.positions, sim.velocities
    sim.velocities = _runaway(sim)
    with pytest.raises(ws.SimulationError, match="blew up at output step 3 .*ran away"):
        sim.step(4)
    assert sim.step_count == 2 and not sim.blowup_watch.pending
    np.testing.assert_array_equal(sim.positions, x2)
    sim.velocities = v2
    run = _interrupt_third_output_step(monkeypatch, sim)
    assert sim.step_count == 2 and sim.time == pytest.approx(2 * sim.dt)
    np.testing.assert_array_equal(sim.positions, x2)


# --------------------------------------------------------------------------- inputs in their storage precision


def test_positions_are_checked_in_the_precision_they_are_stored_in():
    """x 1e41 is finite in float64 but inf in float32: refused before it reaches the state."""
    d = ws.Design(_sphere())
    sim = ws.Simulator(d)
    with pytest.raises(ws.DesignError, match=r"positions up to .* do not fit in float32.*precision='float64'"):
        sim.positions = sim.positions * 1e41
    with pytest.raises(ws.DesignError, match="velocities up to .* do not fit in float32"):
        sim.velocities = np.full((d.rest.n_vertices, 3), 1e39)
    assert np.isfinite(sim.volume()) and sim.volume() == pytest.approx(d.rest.volume(), rel=1e-6)
    sim.step(1)
    assert np.all(np.isfinite(sim.positions))


def test_material_values_that_do_not_fit_the_precision_are_refused():
    d = ws.Design(_sphere(), ws.Material(youngs_modulus=1e42))
    with pytest.raises(ws.DesignError, match=r"youngs_modulus x thickness .* does not fit in float32"):
        ws.Simulator(d)


# --------------------------------------------------------------------------- bounded substeps


@pytest.mark.parametrize("make,cause", [
    (lambda: ws.Simulator(ws.Design(_sphere(3), ws.Material(spring_damping=1e12))), "spring_damping = 1e\\+12"),
    (lambda: ws.Simulator(ws.Design(_sphere(3), ws.Material(viscous_damping=1e12))), "viscous_damping = 1e\\+12"),
    (lambda: ws.Simulator(ws.Design(_sphere(3), ws.Material(areal_density=1e-12))), "areal_density = 1e-12"),
])
def test_extreme_material_is_refused_instead_of_running_forever(make, cause):
    """Substeps per 1 ms step reached 1e12-1e13 (hours to years of work); now refused, naming the value."""
    with pytest.raises(ws.StabilityError, match=rf"needs .* internal steps .* more than max_substeps = 10000.*{cause}"):
        make()


def test_extreme_air_and_tiny_positions_are_refused_naming_them():
    sim = ws.Simulator(ws.Design(_sphere(3)))
    x0 = sim.positions
    sim.air_moles = 1e30
    with pytest.raises(ws.StabilityError, match=r"max_substeps = 10000.*air_moles = 1e\+30 mol"):
        sim.step(1)
    assert sim.step_count == 0 and np.all(np.isfinite(sim.positions))
    sim.air_moles = ws.Simulator(ws.Design(_sphere(3))).air_moles
    sim.positions = x0 * 1e-6
    with pytest.raises(ws.StabilityError, match=r"positions at 1e-06 x the rest size"):
        sim.step(1)


def test_max_substeps_is_a_setting_and_a_keyword():
    d = ws.Design(_sphere(3))
    n = ws.Simulator(d).substeps
    assert n >= 2
    with pytest.raises(ws.StabilityError, match=f"more than max_substeps = {n - 1}"):
        ws.Simulator(d, max_substeps=n - 1)
    with pytest.raises(ws.StabilityError, match=f"more than max_substeps = {n - 1}"):
        ws.Simulator(d, settings=ws.SimulationSettings(max_substeps=n - 1))
    assert ws.Simulator(d, max_substeps=n).substeps == n  # the limit itself is allowed
    for bad in (0, -1, 2.5, True, "10"):
        with pytest.raises(ws.DesignError, match="max_substeps must be an integer >= 1"):
            ws.SimulationSettings(max_substeps=bad)


# --------------------------------------------------------------------------- API arguments


def test_deep_api_errors_are_warp_shape_errors():
    d = ws.Design(_sphere())
    with pytest.raises(ws.DesignError, match="unknown integrator None"):
        ws.Simulator(d, integrator=None)
    with pytest.raises(ws.DesignError, match="reestimate_every must be an integer >= 0"):
        ws.Simulator(d, reestimate_every="x")
    sim = ws.Simulator(d)
    with pytest.raises(ws.DesignError, match="positions must be an array of numbers"):
        sim.positions = "abc"
    with pytest.raises(ws.DesignError, match="positions must be an array of numbers"):
        sim.positions = np.full((d.rest.n_vertices, 3), "1")
    with pytest.raises(ws.DesignError, match=r"volume of -.* mirrored, inside out"):
        sim.positions = -d.rest.vertices  # mirrored: was ZeroDivisionError in the solver
    with pytest.raises(ws.DesignError, match="volume of 0 m\\^3"):
        sim.positions = np.zeros((d.rest.n_vertices, 3))  # was LinAlgError in the estimate
    with pytest.raises(ws.DesignError, match="step count must be an integer"):
        sim.step(True)
    far = d.rest.faces.shape[0] - 1
    d2 = ws.Design(_sphere())
    far = int(np.argmin(d2.rest.face_centroids() @ d2.rest.face_centroids()[0]))
    with pytest.raises(ws.DesignError, match="IPAM free_length must be a finite number, got '0.05'"):
        d2.add_ipam(0, far, free_length="0.05")
    with pytest.raises(ws.DesignError, match="pressure_limits must be a pair of finite numbers"):
        d2.add_ipam(0, far, pressure_limits=("0", "1e5"))
    with pytest.raises(ws.DesignError, match="cell faces must be a flat list"):
        d2.add_cell([[1, 2], [3]])
    d2.add_ipam(0, far)
    sim2 = ws.Simulator(d2)
    with pytest.raises(ws.DesignError, match="ipam_pressures must be an array of numbers"):
        sim2.ipam_pressures = ["1"]
    with pytest.raises(ws.MeshError, match="faces must be an array of numbers"):
        ws.TriMesh(d.rest.vertices, d.rest.faces.astype(str))


def test_int64_face_indices_are_not_wrapped():
    """f[7, 1] += 2**32 used to wrap to a valid int32 index silently."""
    m = _sphere()
    f = m.faces.astype(np.int64)
    f[7, 1] += 2**32
    with pytest.raises(ws.MeshError, match=r"face 7 .*4294967\d+.* indexes a vertex outside 0..41"):
        ws.TriMesh(m.vertices, f)


def test_minor_argument_cases():
    d = ws.Design(_sphere())
    with pytest.raises(ws.DesignError, match="dt must be a positive number"):
        ws.Simulator(d, dt=True)
    with pytest.raises(ws.DesignError, match="reestimate_every must be an integer >= 0"):
        ws.Simulator(d, reestimate_every=-1)
    assert ws.Simulator(d, dt=np.float32(1e-3)).dt == 1e-3  # the decimal the float32 prints as
    d.add_cell([1, 2])
    sim = ws.Simulator(d, worlds=2)
    with pytest.raises(ws.DesignError, match="world must be None .* or an integer index, got 1.5"):
        sim.jam(0, world=1.5)
    assert not sim.jammed.any()
    far = int(np.argmin(d.rest.face_centroids() @ d.rest.face_centroids()[0]))
    with pytest.raises(ws.DesignError, match=r"pressure_limits must be a pair of finite numbers .*\(0, inf\)"):
        d.add_ipam(0, far, pressure_limits=(0, float("inf")))


def test_rigid_translation_far_away_is_no_blowup():
    """A rigid 1 km move used to be flagged as a blow-up (the region around the rest place); in float64
    it now runs like the unmoved membrane, and float32 (resolution 6e-5 m there) refuses it clearly."""
    d = ws.Design(_sphere())
    sim = ws.Simulator(d, precision="float64")
    ref = ws.Simulator(d, precision="float64")
    for s in (sim, ref):
        s.air_moles = s.air_moles * 1.2
    sim.positions = d.rest.vertices + 1000.0
    sim.step(3)
    ref.step(3)
    np.testing.assert_allclose(sim.positions - 1000.0, ref.positions, atol=1e-9)
    with pytest.raises(ws.DesignError, match="float32 resolves them only to 6.1e-05 m"):
        ws.Simulator(d).positions = d.rest.vertices + 1000.0


def test_nan_vertex_in_a_mesh_file_is_named(tmp_path):
    m = _sphere()
    lines = ["ply", "format ascii 1.0", f"element vertex {m.n_vertices}", "property float x", "property float y",
             "property float z", f"element face {m.n_faces}", "property list uchar int vertex_indices", "end_header"]
    v = m.vertices.copy()
    v[5, 2] = np.nan
    lines += [" ".join(f"{c:.9g}" for c in row) for row in v]
    lines += ["3 " + " ".join(str(i) for i in f) for f in m.faces]
    path = tmp_path / "bad.ply"
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(ws.MeshError, match="vertex 5 is not finite"):
        ws.TriMesh.load(path)


# --------------------------------------------------------------------------- scene loader


def _scene_file(tmp_path, settings=None, name="s.usda"):
    from warp_shape.io.scene_schema import Scene
    from warp_shape.io.scene_write import save_scene

    d = ws.Design(ws.icosphere(0, 0.04))
    d.add_cell([1, 2])
    sc = Scene(design=d, targets=[ws.icosphere(0, 0.03)], settings=settings or {"simulation": {"dt": 1e-3}})
    return save_scene(sc, tmp_path / name)


def _edited(path, old, new):
    text = path.read_text()
    assert old in text, old
    path.write_text(text.replace(old, new, 1))
    return path


def test_loader_names_a_nan_in_a_vector_array(tmp_path):
    from warp_shape.io.scene_read import load_scene

    p = _scene_file(tmp_path)
    text = p.read_text()
    i = text.index("warpShape:restPoints = [(") + len("warpShape:restPoints = [(")
    p.write_text(text[:i] + "nan" + text[text.index(",", i):])
    with pytest.raises(ws.SceneError, match=r"restPoints: element 0 is not finite"):
        load_scene(p)


def test_loader_non_utf8_and_corrupt_crate(tmp_path):
    from warp_shape.io.scene_read import load_scene

    p = _scene_file(tmp_path)
    p.write_bytes(p.read_bytes().replace(b'doc = "warp_shape', b'doc = "\xff\xfe\xfa'))
    with pytest.raises(ws.SceneError):
        load_scene(p)
    c = _scene_file(tmp_path, name="s.usdc")
    data = bytearray(c.read_bytes())
    for k in range(len(data) // 3, len(data) // 3 + 64):
        data[k] ^= 0x5A
    c.write_bytes(bytes(data))
    with pytest.raises(ws.SceneError):
        load_scene(c)


def test_crate_counts_that_cannot_fit_the_file_are_refused_before_usd_reads_them(tmp_path):
    """USD believes a crate's element counts: 1.5e9 tokens claimed in a 7 kB file took it 40 s and 12 GB
    before it reported the error. The counts are checked against the file size first."""
    import struct

    from warp_shape.io.scene_read import load_scene

    c = _scene_file(tmp_path, name="s.usdc")
    data = bytearray(c.read_bytes())
    toc = struct.unpack_from("<q", data, 16)[0]
    for i in range(struct.unpack_from("<Q", data, toc)[0]):
        name, start, _ = struct.unpack_from("<16sqq", data, toc + 8 + 32 * i)
        if name.rstrip(b"\0") == b"TOKENS":
            struct.pack_into("<Q", data, start, 1543503964)
    c.write_bytes(bytes(data))
    with pytest.raises(ws.SceneError, match="corrupt crate data: section TOKENS claims 1543503964 elements"):
        load_scene(c)


def test_loader_checks_the_settings(tmp_path):
    from warp_shape.io.scene_read import load_scene

    p = _edited(_scene_file(tmp_path), "custom double warpShape:simulation:dt = 0.001",
                "custom double warpShape:simulation:dt")
    with pytest.raises(ws.SceneError, match="simulation:dt: is declared without a value"):
        load_scene(p)
    cases = [("custom double warpShape:simulation:dtt = 0.001", r"unknown simulation setting\(s\) \['dtt'\]"),
             ("custom int64 warpShape:simulation:integrator = 4", "unknown integrator 4"),
             ('custom string warpShape:designer:actuators = "four"', "actuators: must be an integer >= 1"),
             ("custom double warpShape:simulation:dt = -1", "dt must be a positive number")]
    for line, match in cases:
        p = _edited(_scene_file(tmp_path), "custom double warpShape:simulation:dt = 0.001", line)
        with pytest.raises(ws.SceneError, match=match):
            load_scene(p)


def test_scene_composition_is_limited_to_its_folder(tmp_path):
    from warp_shape.io.scene_read import load_scene

    outside = tmp_path / "elsewhere"
    outside.mkdir()
    (outside / "extra.usda").write_text('#usda 1.0\n\nover "Scene"\n{\n}\n')
    inside = tmp_path / "scene"
    inside.mkdir()
    p = _scene_file(inside)
    text = p.read_text()
    p.write_text(text.replace("(\n", "(\n    subLayers = [@../elsewhere/extra.usda@]\n", 1))
    with pytest.raises(ws.SceneError, match="outside the scene's folder .* allow_outside=True"):
        load_scene(p)
    assert load_scene(p, allow_outside=True).design is not None
    (inside / "extra.usda").write_text('#usda 1.0\n\nover "Scene"\n{\n}\n')
    p.write_text(text.replace("(\n", "(\n    subLayers = [@./extra.usda@]\n", 1))
    assert load_scene(p).design is not None  # a layer next to the scene is fine


# --------------------------------------------------------------------------- warp-shape control SCENE


class _Stop(Exception):
    pass


def _control_settings(monkeypatch, tmp_path, simulation, extra=()):
    import warp_shape.cli.control as control_cli
    from warp_shape.cli import main
    from warp_shape.io.scene_schema import Scene
    from warp_shape.io.scene_write import save_scene
    from warp_shape.scenarios import cube_fig6_design

    seen = {}

    def fake(design, targets, settings=None, **kwargs):
        seen["settings"] = settings
        raise _Stop

    monkeypatch.setattr(control_cli, "control_many", fake)
    path = save_scene(Scene(design=cube_fig6_design(), targets=[ws.target("cube")], target_names=["cube"],
                            settings={"simulation": simulation}), tmp_path / "problem.usda")
    try:
        rc = main(["control", str(path), "--out", str(tmp_path / "out"), *extra])
    except _Stop:
        return seen["settings"].simulation
    return rc


def test_control_applies_the_scene_simulation_settings(monkeypatch, tmp_path, capsys):
    sim = _control_settings(monkeypatch, tmp_path, {"integrator": "semi_implicit", "precision": "float64",
                                                     "dt": 5e-4})
    assert (sim.integrator, sim.precision, sim.dt) == ("semi_implicit", "float64", 5e-4)
    sim = _control_settings(monkeypatch, tmp_path, {"integrator": "semi_implicit", "dt": 5e-4},
                            extra=["--integrator", "rk4"])
    assert (sim.integrator, sim.dt) == ("rk4", 5e-4)  # a flag overrides the scene
    assert _control_settings(monkeypatch, tmp_path, {"integrator": "foo"}) == 2
    assert "unknown integrator 'foo'" in capsys.readouterr().err
    assert _control_settings(monkeypatch, tmp_path, {"dt": -1.0}) == 2
    assert "dt must be a positive number" in capsys.readouterr().err


def test_a_huge_output_step_is_named_as_the_cause():
    with pytest.raises(ws.StabilityError, match=r"output step of 1e\+30 s .* the output step dt = 1e\+30 s itself"):
        ws.Simulator(ws.Design(_sphere()), dt=1e30)
    with pytest.raises(ws.DesignError, match="substeps = 20000 is more than max_substeps = 10000"):
        ws.Simulator(ws.Design(_sphere()), substeps=20000)


def test_ipam_values_that_do_not_fit_the_precision_are_refused():
    d = ws.Design(_sphere())
    far = int(np.argmin(d.rest.face_centroids() @ d.rest.face_centroids()[0]))
    d.add_ipam(0, far, stiffness=1e39)
    with pytest.raises(ws.DesignError, match=r"Design.add_ipam stiffness = 1e\+39 .* does not fit in float32"):
        ws.Simulator(d)
    with pytest.raises(ws.StabilityError, match=r"most likely from an IPAM stiffness of 1e\+39 N/m"):
        ws.Simulator(d, precision="float64")  # fits float64, and is refused by the step limit


def test_interrupted_jam_is_undone_whole(monkeypatch):
    import warp_shape.simulator as simulator

    d = ws.Design(_sphere())
    d.add_cell(np.arange(10))
    sim = ws.Simulator(d)
    edge = sim.state.edge.numpy().copy()

    def jam_then_interrupt(model, state, cell, mask, launch):
        real(model, state, cell, mask, launch)
        raise KeyboardInterrupt

    real = simulator.eval_jam
    monkeypatch.setattr(simulator, "eval_jam", jam_then_interrupt)
    with pytest.raises(KeyboardInterrupt):
        sim.jam(0)
    np.testing.assert_array_equal(sim.state.edge.numpy(), edge)
    assert not sim.jammed.any() and not sim.state.jammed.numpy().any()
    monkeypatch.setattr(simulator, "eval_jam", real)
    sim.jam(0)
    assert sim.jammed.all() and not np.array_equal(sim.state.edge.numpy(), edge)


def test_a_crash_of_usd_reading_a_binary_scene_is_a_scene_error(tmp_path, monkeypatch):
    """USD can crash the process (segmentation fault) on corrupt crate data; a binary scene is read in
    a child process first, and a crash there is a SceneError here."""
    import warp_shape.io.scene_read as scene_read

    c = _scene_file(tmp_path, name="s.usdc")
    assert scene_read.load_scene(c).design is not None  # a sound binary scene passes the probe
    monkeypatch.setattr(scene_read, "PROBE_SCRIPT", "import os, signal\nos.kill(os.getpid(), signal.SIGSEGV)\n")
    with pytest.raises(ws.SceneError, match=r"USD crashed reading it \(signal 11; corrupt binary crate data\)"):
        scene_read.load_scene(c)


def test_binary_scene_probe_is_memory_bounded(tmp_path, monkeypatch):
    """A corrupt crate count can make USD allocate tens of GB; the child that reads a binary scene
    first has a bounded address space, and its failure is a SceneError (the parent never reads it)."""
    import warp_shape.io.scene_read as scene_read

    c = _scene_file(tmp_path, name="s.usdc")
    limited = scene_read.PROBE_SCRIPT.split("from pxr")[0]  # the probe's own memory limit, then a huge allocation
    assert "RLIMIT_AS" in limited
    monkeypatch.setattr(scene_read, "PROBE_SCRIPT", limited + "bytearray(limit + 2**30)\n")
    with pytest.raises(ws.SceneError, match="not a readable USD file .*MemoryError"):
        scene_read.load_scene(c)
