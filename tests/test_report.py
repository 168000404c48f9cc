"""The design report judges: each target reached / partly / not reached against the thresholds the
README states, what limits a target short of reached, the actuators that help no target, and an
"at rest" that never contradicts the table."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from warp_shape.io.report import PARTLY_MPRE, REACHED_MPRE, design_markdown, idle_actuators, verdict
from warp_shape.scenarios import cube_fig6_design


def _result(rest, *, mpre, pcc, scale=1.0, saturated=(), settled=True, passive=()):
    achieved = rest.copy_with(rest.vertices * scale)
    return SimpleNamespace(achieved=achieved, sampled_target=rest, objective=mpre / 250, pcc=pcc, mare=mpre * 4e-4,
                           mpre=mpre, volume_error=0.01, saturated=list(saturated), settled=settled,
                           max_speed=1.6e-3 if not settled else 1e-4, passive_ipams=np.array(passive, dtype=int),
                           actuator_summary=[])


def _design_result(rounds, pcc_by_round):
    d = cube_fig6_design(subdivisions=2)
    added = [dict(target=0, face_a=ip.face_a, face_b=ip.face_b, error=0.1) for ip in d.ipams]
    return SimpleNamespace(design=d, target_names=["egg", "pear"], rounds=rounds, results=rounds[-1],
                           pcc_by_round=np.array(pcc_by_round), added=added, placement={}, codesign={})


def test_the_report_judges_each_target_and_names_what_limits_it():
    rest = cube_fig6_design(subdivisions=2).rest
    egg = _result(rest, mpre=1.2, pcc=0.999)
    pear = _result(rest, mpre=9.3, pcc=0.93, scale=1.2, saturated=["ipam 1 at P_max 300 kPa"], settled=False)
    assert verdict(egg) == "reached" and verdict(pear) == "not reached"
    assert verdict(_result(rest, mpre=(REACHED_MPRE + PARTLY_MPRE) / 2, pcc=0.99)) == "partly"
    assert verdict(_result(rest, mpre=1.0, pcc=0.9)) == "partly"  # a small error of the wrong shape
    # the egg is reached before any actuator; IPAMs 1-4 raise no target's PCC in their rounds; IPAM 4 is held
    # neutral for both targets
    egg.passive_ipams, pear.passive_ipams = np.array([4]), np.array([2, 4])
    pcc = [[0.999, 0.80], [0.999, 0.85]] + [[0.999, 0.85]] * 4
    md = design_markdown(_design_result([[egg, pear]] * 6, pcc))
    achieved = md.split("## Achieved fit")[1].split("\n## ")[0]
    assert "pear not at rest" in achieved.splitlines()[0]  # the heading does not claim "at rest"
    pear_line = next(x for x in achieved.splitlines() if x.startswith("- **pear**"))
    assert "**not reached**" in pear_line and "limited by IPAM 1 at P_max 300 kPa" in pear_line
    assert "still moving at 1.60 mm/s" in pear_line
    assert f"largest {np.linalg.norm(0.2 * rest.vertices, axis=1).max() * 1e3:.1f} mm" in pear_line
    assert "**reached**" in next(x for x in achieved.splitlines() if x.startswith("- **egg**"))
    assert f"at most {REACHED_MPRE:g} %" in achieved  # the thresholds are in the report
    table = md.split("## Final fit")[1].split("\n## ")[0]
    pear_row = next(x for x in table.splitlines() if x.startswith("| pear"))
    assert "| no | not reached |" in pear_row
    assert idle_actuators(_design_result([[egg, pear]] * 6, pcc)) == [4]
    assert "**Helps no target**: IPAM 4 (held neutral for every target" in md
    assert "IPAM 1, 2, 3: their rounds raised no target's PCC" in md and "not measured" in md
    assert "Reached before any actuator (round 0: the rest shape under inflation alone): egg" in md


def test_the_largest_error_is_the_distance_to_the_target_on_each_ray():
    from warp_shape.io.report import largest_error_mm

    rest = cube_fig6_design(subdivisions=2).rest
    c = rest.vertices.mean(axis=0)
    grown = rest.copy_with(c + (rest.vertices - c) * 1.1)
    r = SimpleNamespace(achieved=rest, sampled_target=grown)
    expect = float(np.linalg.norm(rest.vertices - c, axis=1).max() * 0.1 * 1e3)
    assert abs(largest_error_mm(r) - expect) < 1e-6


def test_a_replayed_sequence_says_it_is_not_at_rest_where_it_is_not():
    """A design's final results are its sequences replayed on the final design: where the replay ends
    moving, its reason says so beside the original run's (which was at rest), and it is not converged
    (report.json once read "converged; at rest" beside converged False)."""
    import dataclasses

    import warp_shape as ws
    from warp_shape.controller.open_loop import replay_result

    design = cube_fig6_design(subdivisions=2)
    res = ws.control(design, ws.target("oval"), method="paper", max_steps=40)
    assert res.settled and "at rest" in res.reason
    cut = dataclasses.replace(res, history={k: np.asarray(v)[:4] for k, v in res.history.items()},
                              frames=res.frames[:4])  # stopped during the inflation: still moving
    moving = replay_result(design, cut)
    assert not moving.settled and not moving.converged
    assert moving.reason.endswith("so not converged") and "not at rest (" in moving.reason
    held = replay_result(design, res)
    assert held.settled and held.reason.endswith("open loop on this design: at rest")


def test_the_final_fit_table_stays_narrow():
    """The final-fit table's lines stay under 100 characters (a report read in a terminal)."""
    rest = cube_fig6_design(subdivisions=2).rest
    r = _result(rest, mpre=12.5, pcc=0.9, scale=1.3)
    md = design_markdown(_design_result([[r, r]] * 6, [[0.9, 0.9]] * 6))
    table = [x for x in md.split("## Final fit")[1].split("\n## ")[0].splitlines() if x.startswith("|")]
    assert len(table) == 4 and max(len(x) for x in table) < 100, max(table, key=len)


def test_a_finished_design_prints_a_short_verdict_table_and_where_its_outputs_are():
    """The run's own printout (the demo's): a line per target with its verdict, fit and what limits it, the
    thresholds, the idle IPAMs; the outputs grouped in a few lines (the full report stays in report.md)."""
    from warp_shape.cli.options import grouped_outputs
    from warp_shape.io.report import design_summary

    rest = cube_fig6_design(subdivisions=2).rest
    egg = _result(rest, mpre=1.2, pcc=0.999, passive=[4])
    pear = _result(rest, mpre=9.3, pcc=0.93, scale=1.2, saturated=["ipam 1 at P_max 300 kPa"], settled=False,
                   passive=[2, 4])
    lines = design_summary(_design_result([[egg, pear]] * 6, [[0.999, 0.8]] * 6))
    assert len(lines) <= 8 and max(len(x) for x in lines) <= 100
    rows = {x.split()[0]: x for x in lines if x.split() and x.split()[0] in ("egg", "pear")}
    assert rows["egg"].split()[1:3] == ["reached", "0.9990"] and rows["egg"].rstrip().endswith("-")
    assert rows["pear"].split()[1:3] == ["not", "reached"] and "IPAM 1 at P_max 300 kPa" in rows["pear"]
    assert "moving at 1.60 mm/s" in rows["pear"] and f"MPRE <= {REACHED_MPRE:g} %" in "\n".join(lines)
    assert any(x.startswith("IPAM 4 helps no target") for x in lines)
    names = [f"{k}_{t}.{e}" for k in ("control", "fit", "valve") for t in ("egg", "pear") for e in ("png", "csv")]
    listed = grouped_outputs(names + ["design.usda", "report.md", "mold_core_mm.stl", "mold_shell_top_mm.stl"])
    assert len(listed) <= 3 and "valve_*.csv (2)" in listed[-1] and "report.md" in "".join(listed)


def test_the_report_names_the_membrane_law_and_its_constants():
    """The report's first lines say which membrane law the design was made with and its constants,
    report.json's ``membrane`` the same with units in its keys."""
    import dataclasses

    rest = cube_fig6_design(subdivisions=2).rest
    fits = [[_result(rest, mpre=1.2, pcc=0.999), _result(rest, mpre=1.2, pcc=0.999)]] * 6
    springs = _design_result(fits, [[0.99, 0.99]] * 6)
    head = design_markdown(springs).split("## ")[0]
    assert "edge-spring lattice (E 69.0 kPa, t 2.00 mm" in head
    rubber = _design_result(fits, [[0.99, 0.99]] * 6)
    rubber.design = rubber.design.replace(material=dataclasses.replace(
        rubber.design.material, membrane="yeoh", shear_modulus=23e3, yeoh_c2=2e3))
    head = design_markdown(rubber).split("## ")[0]
    assert "incompressible Yeoh sheet (mu 23.00 kPa, C2 2 kPa, C3 0 kPa, t 2.00 mm" in head
    summary = rubber.design.material.membrane_summary()
    assert summary["law"] == "yeoh" and summary["shear_modulus_pa"] == 23e3 and summary["yeoh_c2_pa"] == 2e3
    assert all(k in ("law", "compression") or k.rsplit("_", 1)[-1] in ("m", "pa", "rad")
               for k in summary), summary
