"""Strategies plug in from outside the package, and every command runs with the settings it is given.

A control law and a placement registered by a test module (``tests/strategy_plugin.py``) run through
``ws.control``, ``ws.design`` and the command line (``WARP_SHAPE_PLUGINS``) with no edit inside the
package; ``warp-shape design SCENE`` honours the scene's material and settings groups and saves them,
so ``warp-shape control`` on the saved design reproduces its sequences.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import strategy_plugin  # noqa: F401  (registers the test strategies)
import warp_shape as ws
from warp_shape.controller import ControlSettings
from warp_shape.designer.placement import free_faces
from warp_shape.designer.run_settings import RunSettings
from warp_shape.scenarios import cube_fig6_design

TESTS = Path(__file__).resolve().parent


def cli(*argv, cwd=None):
    """The real command, with the test strategies registered through WARP_SHAPE_PLUGINS."""
    env = dict(os.environ, WARP_SHAPE_PLUGINS="strategy_plugin",
               PYTHONPATH=os.pathsep.join([str(TESTS), os.environ.get("PYTHONPATH", "")]))
    return subprocess.run([sys.executable, "-m", "warp_shape.cli", *map(str, argv)], capture_output=True, text=True,
                          env=env, cwd=cwd, timeout=600)


def test_registries_list_the_strategies_and_name_the_closest_on_a_typo():
    assert {"inverse", "paper", "air_only"} <= set(ws.CONTROL_METHODS)
    assert {"simulated", "paper", "greedy", "lowest_face"} <= set(ws.PLACEMENTS)
    with pytest.raises(ws.DesignError, match="did you mean 'air_only'"):
        ControlSettings(method="air_onyl")
    with pytest.raises(ws.DesignError, match="did you mean 'greedy'"):
        ws.DesignSettings(placement="gredy")
    with pytest.raises(ws.DesignError, match="registered already"):
        ws.register_placement(type("Other", (ws.Placement,), {"name": "paper", "summary": "x"}))


def test_a_registered_law_controls_through_the_api():
    fig6, cube = cube_fig6_design(), ws.target("cube")
    own = ws.control(fig6, cube, method="air_only", max_steps=60)
    paper = ws.control(fig6, cube, method="paper", max_steps=60)
    assert own.settings.method == "air_only"
    assert np.all(own.ipam_pressures == 0.0) and not own.jammed.any()  # the law's own behaviour
    assert np.any(paper.ipam_pressures != 0.0) and paper.jammed.any()
    assert abs(own.volume_error) < 3 * own.settings.volume_deadband  # eq. (11) still brings the volume in


def test_a_registered_law_and_placement_design_through_the_api():
    base, oval = ws.icosphere(2, 0.035), ws.target("oval")
    res = ws.design(base, [oval], actuators=1, placement="lowest_face", codesign="off",
                    control_settings=ControlSettings(method="air_only", max_steps=60))
    a = res.design.ipams[0].face_a
    first_round_free = free_faces(res.designs[0])
    assert a == int(np.flatnonzero(first_round_free)[0])  # the placement's own rule
    assert np.all(res.results[0].ipam_pressures == 0.0)  # the final round ran the registered law
    assert res.report()["placement"]["method"] == "lowest_face" if "placement" in res.report() else True


def _scene(tmp_path, settings) -> Path:
    mat = ws.Material(youngs_modulus=2 * ws.Material().youngs_modulus)
    scene = ws.Scene(design=ws.Design(rest=ws.icosphere(2, 0.035), material=mat), targets=[ws.target("oval")],
                     target_names=["oval"], settings=settings)
    return ws.save_scene(scene, tmp_path / "problem.usda")


def test_design_honours_the_scenes_material_and_settings_and_control_reproduces_it(tmp_path):
    settings = {"simulation": {"reestimate_every": 500},
                "controller": {"method": "paper", "max_steps": 80},
                "designer": {"actuators": 1, "cell_radius": 0.012}}
    problem = _scene(tmp_path, settings)
    out = tmp_path / "out"
    r = cli("design", problem, "--placement", "lowest_face", "--codesign", "off", "--out", out)
    assert r.returncode == 0, r.stderr
    saved = ws.load_scene(out / "design.usda")
    assert saved.design.material.youngs_modulus == 2 * ws.Material().youngs_modulus
    run = RunSettings.from_groups(saved.settings)
    assert run.simulation.reestimate_every == 500 and run.control.method == "paper"
    assert run.control.max_steps == 80 and run.designer.placement == "lowest_face" and run.actuators == 1
    designed = json.loads((out / "control_oval.json").read_text())
    assert designed["settings"]["simulation"]["reestimate_every"] == 500
    # the saved design re-controlled with the settings it was designed with: the same sequence (a
    # co-designed one may hold a sequence its re-control does not give: test_designer.py)
    again = tmp_path / "again"
    r = cli("control", out / "design.usda", "--out", again)
    assert r.returncode == 0, r.stderr
    recontrolled = json.loads((again / "control_oval.json").read_text())
    assert recontrolled["objective"] == designed["objective"]
    assert recontrolled["rows"] == designed["rows"]


def test_control_honours_the_scenes_controller_group(tmp_path):
    bad = _scene(tmp_path, {"controller": {"control_period": 0}})
    r = cli("control", bad, "--out", tmp_path / "x")
    assert r.returncode == 2 and "control_period" in r.stderr and not (tmp_path / "x").exists()
    r = cli("design", bad, "--out", tmp_path / "y")
    assert r.returncode == 2 and "control_period" in r.stderr and not (tmp_path / "y").exists()
    own = _scene(tmp_path, {"controller": {"method": "air_only", "max_steps": 40}})
    r = cli("control", own, "--out", tmp_path / "z")
    assert r.returncode == 0, r.stderr
    data = json.loads((tmp_path / "z" / "control_oval.json").read_text())
    assert data["settings"]["method"] == "air_only" and data["settings"]["max_steps"] == 40
    assert data["control_steps"] <= 40 + data["settings"]["max_settle_steps"]


def test_cli_takes_registered_strategies_as_choices(tmp_path):
    r = cli("control", "--help")
    assert "air_only" in r.stdout and "the paper's air law alone" in r.stdout
    r = cli("design", "--help")
    assert "lowest_face" in r.stdout
    env = dict(os.environ, WARP_SHAPE_PLUGINS="no_such_module_here")
    r = subprocess.run([sys.executable, "-m", "warp_shape.cli", "control", "--help"], capture_output=True,
                       text=True, env=env)
    assert r.returncode == 2 and "no_such_module_here" in r.stderr and "WARP_SHAPE_PLUGINS" in r.stderr


def test_a_placement_record_without_its_keys_is_an_error_naming_it():
    class Careless(ws.Placement):
        name, summary = "careless", "forgets its record (a test strategy)"

        def place(self, run, results, i, round_settings):
            return {"round": i}

    ws.register_placement(Careless, replace=True)
    try:
        with pytest.raises(ws.DesignError, match=r"placement 'careless' returned a record without \['target'"):
            ws.design(ws.icosphere(1, 0.035), [ws.target("oval")], actuators=1, placement="careless",
                      control_settings=ControlSettings(method="paper", max_steps=20))
    finally:
        ws.PLACEMENTS.unregister("careless")


def test_one_name_per_idea():
    import types

    from warp_shape.controller.plans import parse_plans

    assert parse_plans("paper never") == [("warm", 0.0), ("never", 0.0)]  # the former name still reads
    assert ControlSettings().inverse_plans.split()[0] == "warm"
    assert ws.DesignSettings(round_control="paper").round_control == "law"
    assert isinstance(ws.sweep, types.FunctionType)
    import warp_shape.sweeps as sweeps
    assert ws.sweep is sweeps.sweep and isinstance(sweeps, types.ModuleType)
    from warp_shape.controller import loop
    assert loop.SETTLE_PHASE == 3 and not hasattr(loop, "HOLD_PHASE")
