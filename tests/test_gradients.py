"""Gradients of a replayed control sequence against central finite differences (float64).

The sequence is the paper's law driving the Fig. 6 device (162 vertices) to the cube with every
IPAM's pressure limit lowered to 100 kPa: all four corner IPAMs saturate at P_max and two cells jam,
so every gradient below runs back through a jam event (the frozen rest lengths and angles depend on
the state they froze at) and through the saturated IPAMs' phases.
"""

from __future__ import annotations

import numpy as np
import pytest

import warp_shape as ws
from warp_shape.calibration import apply_values
from warp_shape.gradients import DifferentiableReplay
from warp_shape.gradients.api import replay_gradient
from warp_shape.gradients.differentiable_replay import plan_replay
from warp_shape.objectives.radial import fit_objective_and_gradient
from warp_shape.scenarios import cube_fig6_design
from warp_shape.simulation_settings import SimulationSettings
from conftest import with_pressure_max

RTOL = 1e-4


class Case:
    """A recorded sequence, its differentiable replay, the objective and the adjoint gradient."""

    def __init__(self, integrator: str = "rk4"):
        self.design = with_pressure_max(cube_fig6_design(subdivisions=2), 100e3)
        self.target = ws.target("cube").centered()
        settings = ws.ControlSettings(method="paper", simulation=SimulationSettings(integrator=integrator))
        self.result = ws.control(self.design, self.target, settings=settings)
        self.replay = DifferentiableReplay(self.design, self.result, precision="float64")
        self.plan = self.replay.forward()
        self.sampler = ws.RadialSampler(self.target)
        j, dj = self.objective(self.plan.final)
        self.values = self.replay.backward(dj, j).values

    def objective(self, x):
        return fit_objective_and_gradient(x, self.sampler, 0, self.design.rest.faces, self.target.volume())

    def central(self, eps: float, **change) -> float:
        """Central difference of the objective along the change: change(+-eps) -> positions(**kwargs)."""
        (key, fn), = change.items()
        up = self.objective(self.replay.positions(**{key: fn(eps)}))[0]
        down = self.objective(self.replay.positions(**{key: fn(-eps)}))[0]
        return (up - down) / (2.0 * eps)


@pytest.fixture(scope="module")
def case():
    return Case()


def _close(adjoint: float, fd: float, scale: float) -> bool:
    """Relative error at most RTOL (relative to the component, or to 1e-3 of its family's largest)."""
    return abs(adjoint - fd) <= RTOL * max(abs(fd), 1e-3 * scale)


def test_the_sequence_saturates_and_jams(case):
    assert len(case.result.saturated) == 4 and all("P_max 100 kPa" in s for s in case.result.saturated)
    assert case.plan.jam_steps and all(len(e) for e in case.plan.jam_edges)
    p = case.plan.pressures
    assert np.any(np.isclose(p, 100e3)), "no row at the saturated limit"
    # the jam happens before the last row: the replay runs on after it
    assert case.plan.jam_steps[0] < case.plan.n_steps - 10


def test_kernel_replay_is_the_simulators_replay(case):
    """The replay's backward-enabled kernels round as the simulator's step (its RK4 sums the slopes in the
    step's order; its model arrays are the simulator's at the design's values): the same positions, bit for
    bit in float64, through the saturated rows and the jam events (the plan is the simulator's replay)."""
    x = case.replay.positions()
    np.testing.assert_array_equal(x, case.plan.final)
    np.testing.assert_allclose(x, ws.replay(case.design, case.result), rtol=0, atol=1e-6)  # float32 replay


def test_rest_position_gradient(case):
    g = case.values["rest_positions"]
    x0 = case.design.rest.vertices
    cell = case.design.cells[int(np.flatnonzero(case.result.jammed)[0])].faces
    end = case.design.rest.faces[case.design.ipams[0].face_a]
    vertices = sorted({int(case.design.rest.faces[cell[0], 0]), int(end[0]), int(np.argmax(np.abs(g).sum(1)))})
    for v in vertices:
        for c in range(3):
            def moved(e, v=v, c=c):
                x = x0.copy()
                x[v, c] += e
                return x
            fd = case.central(1e-7, rest=moved)
            assert _close(g[v, c], fd, np.abs(g).max()), (v, c, g[v, c], fd)
    # every vertex at once: the derivative along a random direction of the whole rest shape
    d = np.random.default_rng(7).normal(size=x0.shape)
    fd = case.central(1e-7, rest=lambda e: x0 + e * d)
    assert abs(np.sum(g * d) - fd) <= RTOL * abs(fd), (np.sum(g * d), fd)


@pytest.mark.parametrize("name,key", [("youngs_modulus", "stretch_modulus"), ("bending_stiffness", "bending_stiffness")])
def test_material_gradient(case, name, key):
    mat = case.design.material
    value = mat.stretch_modulus if key == "stretch_modulus" else mat.bending_stiffness
    fd = case.central(1e-6, **{key: lambda e: [value * (1.0 + e)]}) / value
    if name == "youngs_modulus":
        fd = fd * value / mat.youngs_modulus  # d/dE = t d/d(E t), E t = value
    assert _close(case.values[name], fd, 0.0), (case.values[name], fd)


@pytest.mark.parametrize("name", ["ipam_stiffness", "ipam_area"])
def test_ipam_size_gradient(case, name):
    base = np.array([ip.stiffness if name == "ipam_stiffness" else ip.area for ip in case.design.ipams])
    g = case.values[name]
    for i in range(len(base)):
        def scaled(e, i=i):
            b = base.copy()
            b[i] *= 1.0 + e
            return b
        fd = case.central(1e-6, **{name: scaled}) / base[i]
        assert _close(g[i], fd, np.abs(g).max()), (i, g[i], fd)


def test_control_gradients(case):
    p = case.plan
    jam_row = int(p.row[p.jam_steps[0]])
    g_air, g_p = case.values["air"], case.values["ipam_pressures"]
    assert g_air[0] == 0.0 and not g_p[0].any()  # row 0's controls hold for no step
    for row in sorted({1, jam_row - 1, jam_row, jam_row + 1, len(p.air) - 1}):
        def air(e, row=row):
            a = p.air.copy()
            a[row] *= 1.0 + e
            return a
        fd = case.central(1e-6, air=air) / p.air[row]
        assert _close(g_air[row], fd, np.abs(g_air).max()), (row, g_air[row], fd)
    saturated = int(np.flatnonzero(np.isclose(p.pressures[:, 0], 100e3))[0])
    for row, i in sorted({(saturated, 0), (saturated, 3), (jam_row, 1), (len(p.air) - 1, 4)}):
        def pressure(e, row=row, i=i):
            q = p.pressures.copy()
            q[row, i] += e
            return q
        fd = case.central(1.0, ipam_pressures=pressure)
        assert _close(g_p[row, i], fd, np.abs(g_p).max()), (row, i, g_p[row, i], fd)


def test_semi_implicit_replay_gradient():
    case = Case("semi_implicit")
    assert case.plan.jam_steps
    np.testing.assert_array_equal(case.replay.positions(), case.plan.final)  # the simulator's, bit for bit
    A = np.array([ip.area for ip in case.design.ipams])

    def area(e):
        a = A.copy()
        a[2] *= 1.0 + e
        return a
    fd = case.central(1e-6, ipam_area=area) / A[2]
    assert _close(case.values["ipam_area"][2], fd, 0.0)
    x0 = case.design.rest.vertices

    def moved(e):
        x = x0.copy()
        x[5, 2] += e
        return x
    assert _close(case.values["rest_positions"][5, 2], case.central(1e-7, rest=moved), 0.0)


def test_ws_gradient_contract(case):
    g = ws.gradient(case.design, case.result, case.target, wrt=("rest_positions", "ipam_area", "air"))
    assert set(g.values) == {"rest_positions", "ipam_area", "air"}
    assert g.values["rest_positions"].shape == (case.design.rest.n_vertices, 3)
    assert g.values["ipam_area"].shape == (case.design.n_ipams,)
    assert g.values["air"].shape == (len(case.result.history["time"]),)
    np.testing.assert_allclose(g.values["ipam_area"], case.values["ipam_area"], rtol=1e-9)
    assert g.objective == pytest.approx(case.result.objective, rel=1e-5)  # float64 replay of a float32 run
    with pytest.raises(ws.DesignError, match="unknown parameter 'rest'; choose from rest_positions"):
        ws.gradient(case.design, case.result, case.target, wrt=("rest",))
    with pytest.raises(ws.DesignError, match="control result"):
        ws.gradient(case.design, None, case.target)
    with pytest.raises(ws.DesignError, match="threads must be 1, 2 or None"):
        ws.gradient(case.design, case.result, case.target, threads=3)


def test_the_pipelined_backward_is_the_serial_one_bit_for_bit(case):
    """Recomputing the next segment on a second thread while the adjoint steps back through this one
    changes when the arithmetic runs, not what it computes: every parameter's gradient is the same bit
    for bit, through many segments and the jam events."""
    _, dj = case.objective(case.plan.final)
    assert len(case.plan.checkpoints) > 4
    serial = case.replay.backward(dj, threads=1).values
    pipelined = case.replay.backward(dj, threads=2).values
    for name, value in serial.items():
        assert np.array_equal(np.asarray(value), np.asarray(pipelined[name])), name
    assert np.any(serial["rest_positions"]) and np.any(serial["air"])


def test_a_plan_made_already_gives_the_gradient_bit_for_bit_and_one_of_another_precision_is_refused(case):
    """Co-design's accepting replay hands its plan to the gradient there (``replay_gradient(plan=)``):
    only the adjoint runs, and it computes what the gradient with its own forward replay computes."""
    wrt = ("rest_positions", "ipam_area", "air")
    own = replay_gradient(case.design, case.result, case.target, wrt, threads=1)
    given = replay_gradient(case.design, case.result, case.target, wrt, threads=1, plan=case.plan)
    assert given.objective == own.objective
    for name in wrt:
        assert np.array_equal(given.values[name], own.values[name]), name
    single = plan_replay(case.design, case.result, precision="float32")
    assert np.abs(single.final - case.plan.final).max() > 0  # another replay, not a copy
    with pytest.raises(ws.DesignError, match="another precision .float32. or mesh than this float64 replay"):
        replay_gradient(case.design, case.result, case.target, wrt, plan=single)


OVERLOADS_SCRIPT = """
import json, sys
import numpy as np
import warp as wp
import warp_shape as ws
import warp_shape.kernels.adjoint as ka
from warp_shape.gradients import DifferentiableReplay
from warp_shape.scenarios import cube_fig6_design
sys.path.insert(0, sys.argv[1])
from conftest import with_pressure_max

def signatures():
    kernels = [k for k in vars(ka).values() if isinstance(k, wp.Kernel) and k.is_generic]
    return sorted(f"{k.key}:{sig}" for k in kernels for sig in k.overloads)

design = with_pressure_max(cube_fig6_design(subdivisions=1), 100e3)
result = ws.control(design, ws.target("cube").centered(), settings=ws.ControlSettings(method="paper"))
replay = DifferentiableReplay(design, result, precision="float64")
made = signatures()
plan = replay.forward()
replay.backward(np.ones((len(plan.final), 3)), threads=2)
replay.positions(rest=design.rest.vertices * 1.001)
print(json.dumps(dict(made=made, after=signatures(), jams=len(plan.jam_steps), segments=len(plan.checkpoints))))
"""


def test_a_replays_overloads_are_made_before_its_first_launch_so_its_module_builds_once():
    """A Warp module compiles every overload it has when first loaded and rebuilds when a launch adds
    one: in a fresh process, a differentiable replay makes every overload its forward, its backward
    (both lanes, a jam event) and its replay with changed parameters launch before it launches any, so
    the module is built once (with a cold cache it was built 14 times over, 20 s)."""
    import json
    import subprocess
    import sys
    from pathlib import Path

    out = subprocess.run([sys.executable, "-c", OVERLOADS_SCRIPT, str(Path(__file__).parent)], capture_output=True,
                         text=True, timeout=600)
    assert out.returncode == 0, out.stderr[-2000:]
    got = json.loads(out.stdout.strip().splitlines()[-1])
    assert got["jams"] >= 1 and got["segments"] > 2  # the backward ran through a jam event and on two lanes
    assert len(got["made"]) >= 10 and got["after"] == got["made"]


def test_a_membrane_stiffer_in_places_replays_as_the_simulator_and_differentiates(case):
    """Per-face E t (a calibration's regions: ``Design.stretch_scale``): the kernel replay builds each
    edge's stiffness from its two faces' multipliers as the simulator's model does, and its E t
    gradient still matches central differences."""
    scale = np.ones(case.design.rest.n_faces)
    scale[: case.design.rest.n_faces // 3] = 2.5  # a third of the membrane much stiffer
    design = apply_values(case.design, {})  # a copy
    design.set_stretch_scale(scale)
    replay = DifferentiableReplay(design, case.result, precision="float64")
    plan = replay.forward()
    x = ws.replay(design, case.result)
    assert np.abs(x - ws.replay(case.design, case.result)).max() > 1e-4  # the stiff part moves the shape
    np.testing.assert_allclose(plan.final, x, rtol=0, atol=1e-6)
    j, dj = case.objective(plan.final)
    g = replay.backward(dj, j).values["youngs_modulus"]
    et = design.material.stretch_modulus
    up, down = (case.objective(replay.positions(stretch_modulus=[et * (1 + e)]))[0] for e in (1e-6, -1e-6))
    fd = (up - down) / 2e-6 / design.material.youngs_modulus
    assert _close(g, fd, 0.0), (g, fd)
