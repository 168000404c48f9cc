"""The Markdown design report: the fit achieved first, then PCC by round, actuators added, placement
(method, K, candidate scores per round, a bad start), final fit (objective, PCC, MARE, MPRE, at
rest) and actuator needs (with the IPAMs that ended at a pressure limit); for the builder, IPAM
ends and jamming cells in mm on the rest shape, and a glossary of the fit measures
(``lab_sections``)."""

from __future__ import annotations

from ..designer import PLACEMENTS

__all__ = ["design_markdown", "design_summary", "verdict", "largest_error_mm", "idle_actuators", "flat_rounds", "REACHED_MPRE", "REACHED_PCC",
           "PARTLY_MPRE", "HELPS_PCC", "figures_section", "ipam_geometry_section", "cell_extent_section", "glossary_section", "lab_sections"]


def _pcc_table(result) -> list[str]:
    names = result.target_names
    lines = ["## PCC by round (round i: design with i IPAMs)", "",
             "| round | " + " | ".join(names) + " |", "|---" * (len(names) + 1) + "|"]
    for i, row in enumerate(result.pcc_by_round):
        lines.append(f"| {i} | " + " | ".join(f"{v:.4f}" for v in row) + " |")
    return lines


def _added_table(result) -> list[str]:
    names = result.target_names
    pcc = result.pcc_by_round
    lines = ["## Actuators added", "",
             "| # | placed for | face a | face b | max scaled error | best PCC gain in its round |", "|---|---|---|---|---|---|"]
    for k, a in enumerate(result.added):
        gain = float((pcc[k + 1] - pcc[k]).max()) if k + 1 < len(pcc) else float("nan")
        lines.append(f"| {k} | {names[a['target']]} | {a['face_a']} | {a['face_b']} | {a['error']:+.4f} | {gain:+.4f} |")
    idle = idle_actuators(result)
    if idle:
        lines += ["", f"**Helps no target**: IPAM {', '.join(map(str, idle))} (held neutral for every target of the "
                  f"final design); a build may leave {'them' if len(idle) > 1 else 'it'} out."]
    flat = [k for k in flat_rounds(result) if k not in idle]
    if flat:
        lines += ["", f"IPAM {', '.join(map(str, flat))}: {'their rounds' if len(flat) > 1 else 'its round'} raised no "
                  f"target's PCC by {HELPS_PCC:g}; the final design's controller uses {'them' if len(flat) > 1 else 'it'}, "
                  f"whether {'they are' if len(flat) > 1 else 'it is'} needed is not measured."]
    reached0 = [names[j] for j in range(len(names)) if result.rounds and verdict(result.rounds[0][j]) == "reached"]
    if reached0:
        lines += ["", f"Reached before any actuator (round 0: the rest shape under inflation alone): "
                  f"{', '.join(reached0)}; the actuators are not needed for {'them' if len(reached0) > 1 else 'it'}."]
    if result.added and len(names) > 1:
        first = result.added[0]["target"]
        others = [j for j in range(len(names)) if j != first]
        gains = {names[j]: float(result.pcc_by_round[1, j] - result.pcc_by_round[0, j]) for j in others}
        held = result.added[0].get("passive_for") or []
        lines += ["", f"The first IPAM was placed for {names[first]}; its effect on the other target(s): "
                  + ", ".join(f"{n} PCC {g:+.4f}" + (" (held neutral: it raised the objective)" if n in held else "")
                              for n, g in gains.items()) + "."]
    return lines


#: a target is *reached* where its mean percent radial error is at most REACHED_MPRE % and its PCC at
#: least REACHED_PCC; *partly* where the error is at most PARTLY_MPRE %; else *not reached*
#: (README, *How the report judges a fit*)
REACHED_MPRE = 2.5
REACHED_PCC = 0.95
PARTLY_MPRE = 5.0
#: an actuator whose round raised no target's PCC by this much helps no target
HELPS_PCC = 1e-3


def verdict(r) -> str:
    """"reached", "partly" or "not reached": a control result's fit against the thresholds above."""
    if r.mpre <= REACHED_MPRE and r.pcc >= REACHED_PCC:
        return "reached"
    return "partly" if r.mpre <= PARTLY_MPRE else "not reached"


def largest_error_mm(r) -> float:
    """The largest |R - r| over the membrane, mm: the distance from each achieved vertex to the target
    point on its ray (``sampled_target``)."""
    d = r.sampled_target.vertices - r.achieved.vertices
    return float(((d ** 2).sum(axis=1) ** 0.5).max() * 1e3)


def _limits(r, n_ipams: int) -> str:
    """What holds a target back: IPAMs at a limit, no air, a membrane still moving, or (none of those)
    the actuators and the rest shape themselves."""
    why = [x.replace("ipam ", "IPAM ") for x in r.saturated]
    if not getattr(r, "settled", True):
        why.append(f"still moving at {r.max_speed * 1e3:.2f} mm/s when measured")
    if why:
        return "limited by " + "; ".join(why)
    used = n_ipams - len(getattr(r, "passive_ipams", []))
    return f"no actuator at a limit: {used} IPAM{'s' if used != 1 else ''} in use cannot bend it closer (more " \
           f"actuators, or a rest shape nearer the target)"


def _achieved(result) -> list[str]:
    """What the design achieves, first: each target's fit in a line, judged (``verdict``)."""
    moving = [n for n, r in zip(result.target_names, result.results) if not getattr(r, "settled", True)]
    head = "at rest" if not moving else f"{', '.join(moving)} not at rest"
    lines = [f"## Achieved fit (final design; {head})", "",
             f"Reached: mean percent radial error at most {REACHED_MPRE:g} % and PCC at least {REACHED_PCC:g}; "
             f"partly: error at most {PARTLY_MPRE:g} %; else not reached.", ""]
    for n, r in zip(result.target_names, result.results):
        v = verdict(r)
        lines.append(f"- **{n}**: **{v}**; mean radial error {r.mare * 1e3:.2f} mm ({r.mpre:.1f} %, largest "
                     f"{largest_error_mm(r):.1f} mm; objective {r.objective:.4f}, PCC {r.pcc:.4f}, volume within "
                     f"{100 * abs(r.volume_error):.1f} %)" + ("" if v == "reached" else f"; {_limits(r, result.design.n_ipams)}"))
    return lines


def idle_actuators(result) -> list[int]:
    """IPAMs that help no target: held neutral for every target of the final design."""
    return [k for k in range(result.design.n_ipams)
            if all(k in {int(i) for i in getattr(r, "passive_ipams", [])} for r in result.results)]


def flat_rounds(result) -> list[int]:
    """IPAMs whose round raised no target's PCC by ``HELPS_PCC`` (the final design's controller may still
    use them: whether they are needed is not measured)."""
    pcc = result.pcc_by_round
    return [k for k in range(min(result.design.n_ipams, len(pcc) - 1)) if float((pcc[k + 1] - pcc[k]).max()) < HELPS_PCC]


def _fit_table(result) -> list[str]:
    lines = ["## Final fit (measured at the end of each sequence; \"at rest\": every vertex slower than 1 mm/s)", "",
             "Objective: area-weighted RMS of the radial error scaled by the target's size, (R - r) / V_t^(1/3); "
             "0 is a perfect fit.", "",
             "| target | objective | PCC | MARE (mm) | MPRE (%) | max (mm) | vol. error (%) | at rest | verdict |", "|---|---|---|---|---|---|---|---|---|"]
    for n, r in zip(result.target_names, result.results):
        lines.append(f"| {n} | {r.objective:.4f} | {r.pcc:.4f} | {r.mare * 1e3:.3f} | {r.mpre:.2f} | "
                     f"{largest_error_mm(r):.2f} | {100 * r.volume_error:.3f} | "
                     f"{'yes' if getattr(r, 'settled', True) else 'no'} | {verdict(r)} |")
    return lines


def _limit_note(entry: str) -> str:
    """ "ipam 1 at P_max 300 kPa" -> "at its 300 kPa limit" (short words for the builder)."""
    value = entry.split(" at ", 1)[1].split(" ", 1)[1] if " at P_" in entry else entry
    return f"**at its {value} limit**"


def _actuator_needs(result) -> list[str]:
    lines = ["## Actuator requirements (final design, per target)", "",
             "An IPAM **at its limit** ended there while the fit asked for more: one rated beyond that pressure "
             "would fit that target better; the fit above is what these limits allow. Report.json gives each "
             "run's full stop reason.", ""]
    for n, r in zip(result.target_names, result.results):
        pinned = {int(x.split()[1]): x for x in r.saturated if x.startswith("ipam ")}
        for a in r.actuator_summary:
            note = f"; {_limit_note(pinned[a['ipam']])}" if a["ipam"] in pinned else ""
            lines.append(f"- {n}, IPAM {a['ipam']}: push {a['peak_push_n']:.3f} N, pull {a['peak_pull_n']:.3f} N, "
                         f"strain {a['peak_strain']:.3f}, pressure {a['pressure_min_pa'] / 1e3:.1f} to "
                         f"{a['pressure_max_pa'] / 1e3:.1f} kPa{note}")
        if "air at 0 mol" in r.saturated:
            lines.append(f"- {n}, chamber: **no air left** to let out while the membrane is larger than the target")
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
        if rnd.get("passive_for"):
            lines.append(f"\nThe kept set is held neutral for {', '.join(rnd['passive_for'])} "
                         "(it does not help there).")
    if info.get("stopped"):
        lines += ["", f"Stopped early: {info['stopped']}."]
    return lines + _holds_lines(result, info)


def _codesign_section(result) -> list[str]:
    """Co-design after placement: each step's replayed objectives and each round's re-control, the
    objectives before and after, the rest shape's largest displacement and the IPAM sizes
    (docs/gradients.md)."""
    rec = getattr(result, "codesign", None) or {}
    if not rec or rec.get("mode", "off") == "off":
        return []
    names = result.target_names
    lines = ["", "## Co-design", "", f"Mode: {rec['mode']} (the rest shape by smooth radial modes"
             + (" and the IPAM sizes" if rec["mode"] == "rest+ipams" else "") + ", by exact gradients of each "
             f"target's replayed sequence). {rec['reason']}."]
    if rec.get("steps"):
        lines += ["", "| step | " + " | ".join(f"{n} replayed objective" for n in names) + " |",
                  "|---" * (len(names) + 1) + "|",
                  "| 0 | " + " | ".join(f"{v:.4f}" for v in rec["before"]) + " |"]
        recontrols = {rc["step"]: rc for rc in rec.get("recontrols", [])}
        for k, row in enumerate(rec["steps"]):
            lines.append(f"| {k + 1} | " + " | ".join(f"{v:.4f}" for v in row) + " |")
            if k + 1 in recontrols:  # the round's end: every target re-controlled on the design reached
                rc = recontrols[k + 1]
                held = set(rc.get("held", []))  # targets whose held sequence, replayed, beat the re-control
                lines.append("| re-controlled" + ("" if rc["kept"] else " (worse: not kept)") + " | "
                             + " | ".join(f"{v:.4f}" + (" (held sequence)" if j in held else "")
                                          for j, v in enumerate(rc["objectives"])) + " |")
    if rec.get("after"):
        lines += ["", "Under the design's controller: " + ", ".join(
            f"{n} {b:.4f} -> {a:.4f}" for n, b, a in zip(names, rec["before"], rec["after"]))
            + (" (kept)." if rec.get("kept") else " (not kept: the placed design stands).")]
    if rec.get("kept"):
        (a0, a1), (k0, k1) = rec["ipam_area_m2"], rec["ipam_stiffness_n_per_m"]
        lines += ["", f"Rest shape moved by at most {rec['max_displacement_m'] * 1e3:.2f} mm.", "",
                  "| IPAM | area before (mm^2) | area after (mm^2) | stiffness before (N/m) | stiffness after (N/m) |",
                  "|---|---|---|---|---|"]
        lines += [f"| {i} | {a0[i] * 1e6:.2f} | {a1[i] * 1e6:.2f} | {k0[i]:.2f} | {k1[i]:.2f} |" for i in range(len(a0))]
    return lines


def _held(hold: dict) -> str:
    """"IPAM 2 with cells 4 5" / "cells 4 5" (the IPAM acting): a refinement candidate's hold."""
    ipams = " ".join(map(str, hold.get("ipams", [])))
    cells = " ".join(map(str, hold.get("cells", [])))
    if ipams:
        return f"IPAM {ipams}" + (f" with cells {cells}" if cells else "")
    return f"cells {cells}"


def _holds_lines(result, info: dict) -> list[str]:
    """Simulated placement: the sets held neutral in the construction rounds and the refinement rounds."""
    names = result.target_names
    lines = []
    for k, a in enumerate(result.added):
        if a.get("passive_for"):
            lines += ["", f"Round {k + 1}: IPAM {k} was held neutral for {', '.join(a['passive_for'])} in that round "
                      "(with it their objective was higher; the last round uses every actuator again)."]
    for rnd in info.get("refinement", []):
        lines += ["", f"Refinement round {rnd['round']}: {rnd['worlds']} worlds.", "",
                  "| target | held | screened objective | screened before | gain |", "|---|---|---|---|---|"]
        for c in rnd["candidates"]:
            lines.append(f"| {names[c['target']]} | {_held(c)} | {c['objective']:.4f} | "
                         f"{c['screened_before']:.4f} | {100 * c['gain']:+.2f} % |")
        for n, why in rnd.get("screened_out", {}).items():
            lines.append(f"\n{n}: {why}.")
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
             "and `mold_core_mm.stl` (whose bosses mark these faces); x, y, z in mm. `molds_mm.json` gives the "
             "same point as `face_centroid` and, as `position`, the boss tip, `--marker-height` (2 mm by "
             "default) further out along the face normal.", "",
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
            "- **at its limit** (actuator requirements): an IPAM at a pressure limit while the fit asks for "
            "more; **at rest**: the membrane settled (every vertex slower than 1 mm/s) before the fit was measured."]


def lab_sections(result) -> list[str]:
    """The sections a builder reads: IPAM ends, jamming cells, glossary."""
    return ipam_geometry_section(result) + [""] + cell_extent_section(result) + [""] + glossary_section()


#: figure file -> its caption in the report (``{t}``: the target)
FIGURE_CAPTIONS = (("fit_{t}.png", "{t}: the achieved shape coloured by its signed radial error (mm)"),
                   ("control_{t}.png", "{t}: the control sequence on the lab's clock"))


def figures_section(result, figures) -> list[str]:
    """The report's figures (those in ``figures``, file names beside report.md), embedded."""
    have = set(figures)
    shown = [("rest_shape.png", "The rest shape with its IPAMs and jamming cells"),
             ("pcc_by_round.png", "The fit by actuator round: objective, MARE and PCC")]
    shown += [(f.format(t=n), c.format(t=n)) for n in result.target_names for f, c in FIGURE_CAPTIONS]
    lines = [f"![{caption}]({name})" for name, caption in shown if name in have]
    return ["## Figures", "", *[x for line in lines for x in (line, "")]][:-1] if lines else []


def _limits_short(r) -> str:
    """``_limits`` in a table cell: the IPAMs at a limit and a membrane still moving, else the actuators."""
    why = [x.replace("ipam ", "IPAM ") for x in r.saturated]
    if not getattr(r, "settled", True):
        why.append(f"moving at {r.max_speed * 1e3:.2f} mm/s")
    return "; ".join(why) if why else "no IPAM at a limit: more actuators or a nearer rest shape"


def design_summary(result) -> list[str]:
    """The few lines a finished design run prints (the whole report stays in ``report.md``): the design
    in a line, each target's verdict with its fit and what limits it, the thresholds, idle IPAMs."""
    d = result.design
    names = list(result.target_names)
    w = max(6, *(len(n) for n in names))
    lines = [f"{d.n_ipams} IPAMs, {d.n_cells} jamming cells, {d.rest.n_vertices}-vertex membrane", "",
             f"{'target':<{w}}  {'verdict':<11}  {'PCC':>6}  {'MARE mm':>7}  {'MPRE %':>6}  {'max mm':>6}  limited by"]
    for n, r in zip(names, result.results):
        v = verdict(r)
        why = "-" if v == "reached" else _limits_short(r)
        lines.append(f"{n:<{w}}  {v:<11}  {r.pcc:6.4f}  {r.mare * 1e3:7.2f}  {r.mpre:6.1f}  "
                     f"{largest_error_mm(r):6.1f}  {why}")
    lines.append(f"(reached: MPRE <= {REACHED_MPRE:g} % and PCC >= {REACHED_PCC:g}; partly: MPRE <= {PARTLY_MPRE:g} %)")
    idle = idle_actuators(result)
    if idle:
        lines.append(f"IPAM{'s' if len(idle) > 1 else ''} {', '.join(map(str, idle))} help{'' if len(idle) > 1 else 's'} "
                     f"no target (held neutral for every one)")
    return lines


def design_markdown(result, figures=()) -> str:
    """A short Markdown report of a ``DesignResult``: the fit achieved, the figures among ``figures``
    (file names beside the report), PCC table by round, actuators added, final fit, actuator needs."""
    d = result.design
    lines = [f"# Design report: {', '.join(result.target_names)}", "",
             f"{d.n_ipams} IPAMs, {d.n_cells} jamming cells, "
             f"{d.rest.n_vertices}-vertex membrane (rest volume {d.rest.volume() * 1e6:.1f} cm^3). "
             + d.material.membrane_line(), ""]
    shown = figures_section(result, figures)
    lines += _achieved(result) + [""] + (shown + [""] if shown else []) + _pcc_table(result) + [""] + _added_table(result) + [""] \
        + _placement_section(result) + _codesign_section(result) + [""] + _fit_table(result) + [""] \
        + _actuator_needs(result)
    lines += [""] + lab_sections(result)
    return "\n".join(lines) + "\n"
