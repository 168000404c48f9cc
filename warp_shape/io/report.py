"""The Markdown design report: PCC by round, actuators added, placement (method, K, candidate scores
per round, a bad start), final fit (objective, PCC, MARE, MPRE,
saturation, convergence) and actuator needs."""

from __future__ import annotations

__all__ = ["design_markdown"]


def _pcc_table(result) -> list[str]:
    names = result.target_names
    lines = ["## PCC by round (round i: design with i IPAMs)", "",
             "| round | " + " | ".join(names) + " |", "|---" * (len(names) + 1) + "|"]
    for i, row in enumerate(result.pcc_by_round):
        lines.append(f"| {i} | " + " | ".join(f"{v:.4f}" for v in row) + " |")
    return lines


def _added_table(result) -> list[str]:
    names = result.target_names
    lines = ["## Actuators added", "", "| # | placed for | face a | face b | max scaled error |", "|---|---|---|---|---|"]
    for k, a in enumerate(result.added):
        lines.append(f"| {k} | {names[a['target']]} | {a['face_a']} | {a['face_b']} | {a['error']:+.4f} |")
    if result.added and len(names) > 1:
        first = result.added[0]["target"]
        others = [j for j in range(len(names)) if j != first]
        gains = {names[j]: float(result.pcc_by_round[1, j] - result.pcc_by_round[0, j]) for j in others}
        lines += ["", f"The first IPAM was placed for {names[first]}; its effect on the other target(s): "
                  + ", ".join(f"{n} PCC {g:+.4f}" for n, g in gains.items()) + "."]
    return lines


def _fit_table(result) -> list[str]:
    lines = ["## Final fit (measured at rest)", "",
             "Objective: area-weighted RMS of the radial error scaled by the target's size, (R - r) / V_t^(1/3); "
             "0 is a perfect fit.", "",
             "| target | objective | PCC | MARE (mm) | MPRE (%) | volume error (%) | saturated | converged |",
             "|---|---|---|---|---|---|---|---|"]
    for n, r in zip(result.target_names, result.results):
        lines.append(f"| {n} | {r.objective:.4f} | {r.pcc:.4f} | {r.mare * 1e3:.3f} | {r.mpre:.2f} | "
                     f"{100 * r.volume_error:.3f} | {', '.join(r.saturated) or '-'} | "
                     f"{'yes' if r.converged else 'no: ' + r.reason} |")
    return lines


def _actuator_needs(result) -> list[str]:
    lines = ["## Actuator requirements (final design, per target)", ""]
    for n, r in zip(result.target_names, result.results):
        for a in r.actuator_summary:
            lines.append(f"- {n}, IPAM {a['ipam']}: push {a['peak_push_n']:.3f} N, pull {a['peak_pull_n']:.3f} N, "
                         f"strain {a['peak_strain']:.3f}, pressure {a['pressure_min_pa'] / 1e3:.1f} to "
                         f"{a['pressure_max_pa'] / 1e3:.1f} kPa")
    return lines


def _placement_section(result) -> list[str]:
    """How the actuators were placed: method, K, the start against the rest shape, every round's
    candidate scores (simulated placement) and an early stop."""
    info = getattr(result, "placement", None) or {}
    if not info:
        return []
    names = result.target_names
    method = info.get("method", "paper")
    lines = ["## Placement", "", f"Method: {method}" + (f", K = {info.get('candidates')} candidate sets per round "
                                                       "(each controlled to every target in one batch of worlds)"
                                                       if method == "simulated" else
                                                       " (Algorithm 1 as published: every target uses every "
                                                       "actuator)") + "."]
    start = info.get("start_pcc") or []
    if start:
        lines += ["", "PCC of each target against the rest shape before control: "
                  + ", ".join(f"{n} {v:+.3f}" for n, v in zip(names, start)) + "."]
    for n in info.get("bad_start", []):
        lines.append(f"Bad start: {n} is anti-correlated with the (averaged) rest shape (PCC < 0); its fit "
                     "depends on the actuators placed for it.")
    for rnd in info.get("rounds", []):
        lines += ["", f"Round {rnd['round']}: summed objective before {rnd['previous_score']:.4f}; "
                  f"{rnd['worlds']} worlds.", "",
                  "| candidate | for | faces | rest angle | " + " | ".join(f"{n} objective" for n in names)
                  + " | score | gain |", "|---" * (len(names) + 6) + "|"]
        for k, c in enumerate(rnd["candidates"]):
            mark = " (kept)" if rnd.get("chosen") == k else ""
            lines.append(f"| {k}{mark} | {names[c['target']]} | {c['face_a']}-{c['face_b']} | "
                         f"{c['rest_angle_deg']:.0f} deg | " + " | ".join(f"{v:.4f}" for v in c["objective"])
                         + f" | {c['score']:.4f} | {100 * c['gain']:+.2f} % |")
        if rnd.get("left_out_for"):
            lines.append(f"\nThe kept set is held neutral for {', '.join(rnd['left_out_for'])} (it does not help there).")
    if info.get("stopped"):
        lines += ["", f"Stopped early: {info['stopped']}."]
    return lines


def design_markdown(result) -> str:
    """A short Markdown report of a ``DesignResult``: PCC table by round, actuators added, final fit,
    actuator needs."""
    d = result.design
    lines = [f"# Design report: {', '.join(result.target_names)}", "",
             f"{d.n_ipams} IPAMs, {d.n_cells} jamming cells, "
             f"{d.rest.n_vertices}-vertex membrane (rest volume {d.rest.volume() * 1e6:.1f} cm^3).", ""]
    lines += _pcc_table(result) + [""] + _added_table(result) + [""] + _placement_section(result) + [""] \
        + _fit_table(result) + [""] + _actuator_needs(result)
    return "\n".join(lines) + "\n"
