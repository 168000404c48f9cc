"""The controls' gradient at a static equilibrium (gradients.equilibrium) and the refinement that uses it.

Checked against central finite differences of settled equilibria in float64 on the 162-vertex Fig. 6
device, after a jam event (three cells frozen where they stand), with one IPAM at its pressure limit
and one disabled (it exerts no force: its gradient is zero and the others see a membrane without it).
"""

import numpy as np
import pytest
import warp as wp

import warp_shape as ws
from warp_shape.controller.control_settings import ControlSettings
from warp_shape.errors import DesignError
from warp_shape.gradients.equilibrium import EquilibriumGradient
from warp_shape.model import host_model
from warp_shape.objectives.radial import fit_objective_and_gradient
from warp_shape.scenarios import cube_fig6_design
from warp_shape.simulation_settings import SimulationSettings
from warp_shape.simulator import Simulator

SETTLE = 1e-10  # N, the static settle's residual: far below the finite differences' signal


@pytest.fixture(scope="module")
def equilibrium():
    wp.config.quiet = True
    design = cube_fig6_design(subdivisions=2)
    target = ws.target("cube").centered()
    sampler = ws.RadialSampler(target)
    host = host_model(design)
    sim = Simulator(design, settings=SimulationSettings(precision="float64"))
    n = design.n_ipams
    enabled = np.ones(n, bool)
    enabled[n - 1] = False  # disabled: no force
    sim.ipam_mask = enabled.reshape(1, n)
    air = host.rest_air * 1.3
    p = np.array([90e3, 60e3, 120e3, 40e3, 0.0])[:n]
    p[0] = host.ipam_limits[0, 1]  # at its upper limit (saturated)
    sim.air_moles = air
    sim.ipam_pressures = p * 0.8
    sim.settle_static(tolerance=SETTLE)
    for j in range(3):  # the jam event: these cells' rest lengths and angles frozen here
        sim.jam(j)
    sim.air_moles = air
    sim.ipam_pressures = p
    sim.settle_static(tolerance=SETTLE)
    start = sim.snapshot()  # every settle starts at the equilibrium, as the refinement's worlds do

    def settled(a, q):
        sim.load_worlds(start)
        sim.ipam_mask = enabled.reshape(1, n)
        sim.air_moles = a
        sim.ipam_pressures = q
        sim.settle_static(tolerance=SETTLE)
        x = np.asarray(sim.positions, np.float64).reshape(-1, 3)
        return x, fit_objective_and_gradient(x, sampler, 0, design.rest.faces, target.volume())

    x, (j, dj_dx) = settled(air, p)
    eg = EquilibriumGradient(host, design.material)
    eg.load(x, start[0].state.edge.numpy()[:, 0], air, p, enabled)
    weights = np.random.default_rng(7).normal(size=x.shape)  # a smooth functional: sum weights . x
    return dict(eg=eg, grad=eg.control_gradient(dj_dx), settled=settled, air=air, p=p, n=n, objective=j,
                weights=weights, linear=eg.control_gradient(weights, tolerance=1e-9))


def test_the_equilibrium_is_one(equilibrium):
    """The loaded point is an equilibrium: the net force is at the settle's residual."""
    assert np.abs(equilibrium["eg"].force()).max() < 1e-8


def _central(e, functional, h_air=1e-4, h_p=100.0):
    """Second-order differences of ``functional(x, fit)`` of the settled equilibrium in the air and
    every enabled IPAM's pressure: central, and one-sided (from below) for the IPAM at its limit."""
    f = lambda a, q: functional(*e["settled"](a, q))  # noqa: E731
    h = h_air * e["air"]
    out = [(f(e["air"] + h, e["p"]) - f(e["air"] - h, e["p"])) / (2 * h)]
    for k in range(e["n"] - 1):
        dp = np.zeros(e["n"])
        dp[k] = h_p
        if k == 0:  # saturated: the simulator refuses a pressure past the limit
            out.append((3 * f(e["air"], e["p"]) - 4 * f(e["air"], e["p"] - dp) + f(e["air"], e["p"] - 2 * dp))
                       / (2 * h_p))
        else:
            out.append((f(e["air"], e["p"] + dp) - f(e["air"], e["p"] - dp)) / (2 * h_p))
    return np.array(out)


def test_implicit_gradient_matches_central_differences(equilibrium):
    """d/d(air, every IPAM pressure, the saturated one included) of a smooth functional of the
    equilibrium (sum w . x, rigid motions included: the settles start at the equilibrium, so their
    response has no rigid part) within 1e-4 relative of differences of settled equilibria, every
    component; the disabled IPAM's is zero."""
    e, g = equilibrium, equilibrium["linear"]
    assert g.converged and g.residual <= 1e-9
    fd = _central(e, lambda x, fit: float(np.sum(e["weights"] * x)))
    got = np.concatenate([[g.air], g.pressures[:-1]])
    np.testing.assert_allclose(got, fd, rtol=1e-4)
    assert g.pressures[-1] == 0.0


def test_fit_objective_gradient_matches_central_differences(equilibrium):
    """The same for the fit objective (its radial sampling differentiated, objectives.radial), every
    component within 1e-4 relative."""
    e, g = equilibrium, equilibrium["grad"]
    assert g.converged and g.residual <= 1e-6
    fd = _central(e, lambda x, fit: fit[0])
    got = np.concatenate([[g.air], g.pressures[:-1]])
    np.testing.assert_allclose(got, fd, rtol=1e-4)
    assert np.all(np.abs(fd) > 0)


def test_stiffness_is_symmetric_and_positive_off_the_rigid_modes(equilibrium):
    """K = -dF/dx (matrix-free) is symmetric, and positive on directions without rigid motion."""
    eg = equilibrium["eg"]
    rng = np.random.default_rng(3)
    a, b = (eg.project(rng.normal(size=(eg.V, 3))) for _ in range(2))
    Ka, Kb = eg.stiffness_product(a), eg.stiffness_product(b)
    assert float(np.sum(Ka * b)) == pytest.approx(float(np.sum(Kb * a)), rel=1e-9)
    assert float(np.sum(Ka * a)) > 0 and float(np.sum(Kb * b)) > 0


@pytest.fixture(scope="module")
def refinements():
    wp.config.quiet = True
    design = cube_fig6_design(subdivisions=2)
    out = {}
    for way in ("finite-difference", "adjoint", "auto"):
        out[way] = ws.control(design, ws.target("cube"), target_name="cube",
                              settings=ControlSettings(inverse_gradient=way, workers=1))
    return out


def test_adjoint_refinement_is_never_worse_than_its_start_and_close_to_the_jacobians(refinements):
    """The refinement by the adjoint (quasi-Newton on its gradient) lowers the objective from every
    refined plan's start and ends within 3 % of the finite-difference Gauss-Newton refinement; "auto"
    on 6 controls is the finite-difference refinement, bit for bit."""
    fd, adj, auto = refinements["finite-difference"], refinements["adjoint"], refinements["auto"]
    assert adj.refinement["gradient"] == "adjoint" and adj.refinement["adjoint_iterations"] > 0
    assert fd.refinement["gradient"] == "finite-difference" and fd.refinement["adjoint_iterations"] == 0
    for name, before in adj.refinement["plans_before"].items():
        assert adj.refinement["plans"][name] <= before * (1 + 1e-9), name
    assert adj.objective < adj.refinement["warm_objective"]
    assert adj.objective <= 1.03 * fd.objective, (adj.objective, fd.objective)
    assert auto.refinement["gradient"] == "finite-difference" and auto.objective == fd.objective


def test_an_unknown_gradient_is_refused_before_any_work():
    with pytest.raises(DesignError, match="inverse_gradient must be one of auto, finite-difference, adjoint"):
        ControlSettings(inverse_gradient="exact")
