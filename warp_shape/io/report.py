"""The Markdown design report: PCC by round, actuators added, placement (method, K, candidate scores
per round, a bad start), final fit (objective, PCC, MARE, MPRE,
saturation, convergence) and actuator needs; for the builder, IPAM ends and jamming cells in mm on
the rest shape, and a glossary of the fit measures (``lab_sections``)."""

from __future__ import annotations

from ..designer import PLACEMENTS

__all__ = ["design_markdown", "ipam_geometry_section", "cell_extent_section", "glossary_section", "lab_sections"]


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
        held = result.added[0].get("held_for") or []
        lines += ["", f"The first IPAM was placed for {names[first]}; its effect on the other target(s): "
                  + ", ".join(f"{n} PCC {g:+.4f}" + (" (held neutral: it raised the objective)" if n in held else "")
                              for n, g in gains.items()) + "."]
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
    what = PLACEMENTS[method].describe(info) if method in PLACEMENTS else ""
    lines = ["## Placement", "", f"Method: {method}{what}."]
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
        if rnd.get("escalated"):
            lines.append(f"\nNo gain: {rnd['escalated']}.")
        if rnd.get("left_out_for"):
            lines.append(f"\nThe kept set is held neutral for {', '.join(rnd['left_out_for'])} "
                         "(it does not help there).")
    if info.get("stopped"):
        lines += ["", f"Stopped early: {info['stopped']}."]
    return lines + _holds_lines(result, info)


def _held(hold: dict) -> str:
    """"IPAM 2 with cells 4 5" / "cells 4 5" (the IPAM acting): a refinement candidate's hold."""
    ipams = " ".join(map(str, hold.get("hold", [])))
    cells = " ".join(map(str, hold.get("cells", [])))
    if ipams:
        return f"IPAM {ipams}" + (f" with cells {cells}" if cells else "")
    return f"cells {cells}"


def _holds_lines(result, info: dict) -> list[str]:
    """Simulated placement: the sets held neutral in the construction rounds and the refinement rounds."""
    names = result.target_names
    lines = []
    for k, a in enumerate(result.added):
        if a.get("held_for"):
            lines += ["", f"Round {k + 1}: IPAM {k} was held neutral for {', '.join(a['held_for'])} in that round "
                      "(with it their objective was higher; the last round uses every actuator again)."]
    for rnd in info.get("refinement", []):
        lines += ["", f"Refinement round {rnd['round']}: {rnd['worlds']} worlds.", "",
                  "| target | held | screened objective | screened before | gain |", "|---|---|---|---|---|"]
        for c in rnd["candidates"]:
            lines.append(f"| {names[c['target']]} | {_held(c)} | {c['objective']:.4f} | "
                         f"{c['screened_before']:.4f} | {100 * c['gain']:+.2f} % |")
        for n, p in rnd.get("proposed", {}).items():
            kept = "kept" if n in rnd.get("kept", {}) else "not kept"
            lines.append(f"\n{n}: holding {_held(p)} reaches {p['objective']:.4f} (before {p['before']:.4f}) "
                         f"under the design's controller: {kept}.")
    if info.get("refinement_stopped"):
        lines += ["", f"Refinement stopped: {info['refinement_stopped']}."]
    if info.get("paper_objective"):
        final = [r.objective for r in result.results]
        lines += ["", "Against Algorithm 1 as published (the same actuator sets, every actuator in use), final "
                  "objective: " + ", ".join(f"{n} {p:.4f} -> {f:.4f} ({f / p:.3f}x)" if p > 0 else f"{n} {p:.4f}"
                                            for n, p, f in zip(names, info["paper_objective"], final)) + "."]
    return lines


def _xyz(p) -> str:
    return "(" + ", ".join(f"{v * 1e3:+.1f}" for v in p) + ")"


def ipam_geometry_section(result) -> list[str]:
    """Where each IPAM is attached: its end-face centroids in mm on the rest shape (the frame of
    ``design.usda`` and of ``mold_core_mm.stl``), its rest length, and the targets that use it."""
    d = result.design
    cent = d.rest.face_centroids()
    names = list(result.target_names)
    lines = ["## IPAM ends (rest shape, mm)", "",
             "End = centroid of the attachment face on the rest shape, in the coordinates of `design.usda` "
             "and `mold_core_mm.stl` (whose bosses mark these faces); x, y, z in mm.", "",
             "| IPAM | face a | end a (x, y, z) | face b | end b (x, y, z) | rest length (mm) | used by |",
             "|---|---|---|---|---|---|---|"]
    for i, ip in enumerate(d.ipams):
        users = [n for n, r in zip(names, result.results)
                 if i not in {int(k) for k in getattr(r, "passive_ipams", [])}]
        lines.append(f"| {i} | {ip.face_a} | {_xyz(cent[ip.face_a])} | {ip.face_b} | {_xyz(cent[ip.face_b])} | "
                     f"{ip.rest_length * 1e3:.1f} | {', '.join(users) or '- (held neutral for every target)'} |")
    return lines


def cell_extent_section(result) -> list[str]:
    """Each jamming cell on the rest shape: its faces, area, centre and size in mm, and the IPAM
    end it surrounds (where its silicone boundary goes)."""
    d = result.design
    rest = d.rest
    cent, area = rest.face_centroids(), rest.face_areas()
    ends = {f: f"IPAM {i} {e}" for i, ip in enumerate(d.ipams) for e, f in (("a", ip.face_a), ("b", ip.face_b))}
    lines = ["## Jamming cells (rest shape, mm)", "",
             "Centre = area-weighted centroid of the cell's faces; radius = farthest cell vertex from it; "
             "size = bounding box (dx, dy, dz).", "",
             "| cell | faces | area (cm^2) | centre (x, y, z) | radius (mm) | size (dx, dy, dz) | around |",
             "|---|---|---|---|---|---|---|"]
    for j, cell in enumerate(d.cells):
        f = cell.faces
        c = (cent[f] * area[f, None]).sum(axis=0) / area[f].sum()
        v = rest.vertices[rest.faces[f].reshape(-1)]
        radius = float(max(((v - c) ** 2).sum(axis=1)) ** 0.5)
        around = ", ".join(ends[k] for k in f.tolist() if k in ends) or "-"
        lines.append(f"| {j} | {len(f)} | {area[f].sum() * 1e4:.2f} | {_xyz(c)} | {radius * 1e3:.1f} | "
                     f"{_xyz(v.max(axis=0) - v.min(axis=0)).replace('+', '')} | {around} |")
    return lines


def glossary_section() -> list[str]:
    """What the report's fit measures mean."""
    return ["## Glossary", "",
            "Radial sampling: from the target's centroid, the ray through each membrane point meets the "
            "target at radius R; the membrane point lies at radius r. V_t is the target's volume, so "
            "V_t^(1/3) is its size.", "",
            "- **objective**: the area-weighted RMS of the scaled radial error (R - r) / V_t^(1/3) over the "
            "membrane; unitless, 0 is a perfect fit, 0.01 is a radial error of about 1 % of the target's size. "
            "The controller and the designer minimise it.",
            "- **PCC**: Pearson correlation coefficient of r and R over the sampled points (eq. 10): 1 is the "
            "same shape; it ignores a uniform scale or offset of the radii, so read it with MARE.",
            "- **MARE**: mean absolute radial error, mean |R - r|, in mm.",
            "- **MPRE**: mean percent radial error, 100 x mean(|R - r| / R), in %.",
            "- **max scaled error** (actuators added): the scaled radial error e = (R - r) / V_t^(1/3) at the "
            "face where the new IPAM's first end was placed, the largest |e| over the free faces of every "
            "target in that round. e > 0: the membrane lies inside the target there (it must move out); "
            "e < 0: outside. +0.05 means 5 % of the target's size.",
            "- **volume error**: (V - V_t) / V_t of the achieved membrane.",
            "- **saturated**: an IPAM at a pressure limit while the fit asks for more; **converged**: at rest, "
            "within the deadbands, nothing saturated."]


def lab_sections(result) -> list[str]:
    """The sections a builder reads: IPAM ends, jamming cells, glossary."""
    return ipam_geometry_section(result) + [""] + cell_extent_section(result) + [""] + glossary_section()


def design_markdown(result) -> str:
    """A short Markdown report of a ``DesignResult``: PCC table by round, actuators added, final fit,
    actuator needs."""
    d = result.design
    lines = [f"# Design report: {', '.join(result.target_names)}", "",
             f"{d.n_ipams} IPAMs, {d.n_cells} jamming cells, "
             f"{d.rest.n_vertices}-vertex membrane (rest volume {d.rest.volume() * 1e6:.1f} cm^3).", ""]
    lines += _pcc_table(result) + [""] + _added_table(result) + [""] + _placement_section(result) + [""] \
        + _fit_table(result) + [""] + _actuator_needs(result)
    lines += [""] + lab_sections(result)
    return "\n".join(lines) + "\n"
