"""Output files of controlled runs and designs: control sequences, molds, reports and round records.

Every file is written atomically (a temporary file, then a rename), so an interrupted run never
leaves half a file. Units: control sequences in SI (s, Pa, m, N) as in the controller's history
columns; molds as binary STL in millimetres (the unit is in the file name).
"""

from __future__ import annotations

import csv
import io
import json
import sys
from dataclasses import asdict
from pathlib import Path

import numpy as np

from ..designer.run_settings import RunSettings
from ..molds import mold_set
from .atomic import atomic_write, write_json
from .feel_outputs import add_feel_primvars, feel_summary, write_feel_maps
from .figures import write_figures
from .report import design_markdown
from .scene_schema import Scene
from .scene_write import save_scene
from .usd_animation import export_animation, playback_times
from .valve import ValveTiming, write_valve_outputs

__all__ = ["control_csv_text", "control_json_data", "write_control_usd", "write_control_outputs",
           "write_molds", "round_record", "record_round", "write_round_outputs", "write_figures_or_skip",
           "write_design_outputs", "is_run_output", "RUN_OUTPUT_PREFIXES", "RUN_OUTPUT_NAMES"]

#: How the files a design or control run writes are named (a file in an output folder named so is
#: part of a run's set, even in a folder written before manifests existed). Add new outputs here.
RUN_OUTPUT_NAMES = ("design.usda", "report.json", "report.md", "rounds.json", "pcc_by_round.png", "pcc_by_round.svg",
                    "rest_shape.png", "rest_shape.svg", "manifest.json")
RUN_OUTPUT_PREFIXES = ("control_", "actuation_", "mold_", "molds_", "valve_", "fit_", "feel_")


def is_run_output(name: str) -> bool:
    """Whether a file name is one a design or control run writes (``RUN_OUTPUT_NAMES`` and
    ``RUN_OUTPUT_PREFIXES``); an output folder's other files are kept when a new run replaces it."""
    return name in RUN_OUTPUT_NAMES or name.startswith(RUN_OUTPUT_PREFIXES)


def control_csv_text(result) -> str:
    """A control result's history as CSV text, one row per control step (columns as in the history)."""
    buf = io.StringIO()
    w = csv.writer(buf)
    cols = list(result.history)
    w.writerow(cols)
    for row in zip(*(result.history[c] for c in cols)):
        w.writerow([f"{v:.9g}" if isinstance(v, (float, np.floating)) else int(v) for v in row])
    return buf.getvalue()


def control_json_data(result) -> dict:
    """A control result's summary plus its full history (``columns`` and ``rows``) as a JSON-ready dict."""
    data = result.summary()
    data["columns"] = list(result.history)
    data["rows"] = [list(map(float, r)) for r in zip(*(result.history[c] for c in result.history))]
    return data


def write_control_usd(result, path, target_name: str = "target", playback: str = "valve", timing=None) -> Path:
    """The controlled run as an animated USD stage (``.usda`` or ``.usdc``): membrane points, IPAM
    curves, pressures, forces and jam state time-sampled once per control step, the target as a ghost,
    and the controller and simulation settings. ``playback``: ``"valve"`` plays each control step at
    its time in the valve CSV (``io.valve.row_times`` under ``timing``, default ``ValveTiming()``),
    ``"simulated"`` at the simulator's clock (``usd_animation``)."""
    h = result.history
    n_ipam, n_cell = len(result.ipam_forces), len(result.jammed)
    per = lambda key, n: np.stack([h[key.format(i)] for i in range(n)], axis=1) if n else None  # noqa: E731
    controller = {k: v for k, v in asdict(result.settings).items() if v is not None and k != "simulation"}
    how = {"timing": playback, "simulated_duration_s": float(h["time"][-1] - h["time"][0])}
    if playback == "valve":
        how.update((timing or ValveTiming()).to_dict())
    return export_animation(
        path, result.design, result.frames, playback_times(result, playback, timing),
        ipam_pressures=per("ipam{}_pressure_pa", n_ipam), ipam_forces=per("ipam{}_force_n", n_ipam),
        jammed=per("cell{}_jammed", n_cell).astype(bool) if n_cell else None,
        targets=[result.target] if result.target is not None else None,
        target_names=[target_name] if result.target is not None else None,
        settings={"controller": controller, "simulation": result.settings.simulation.to_dict()}, playback=how)


def write_control_outputs(results, names, out_dir, *, usd: bool = False, timing=None) -> list[Path]:
    """Per target: ``control_<name>.csv`` and ``control_<name>.json`` (indented by 1), and
    ``actuation_<name>.usdc`` when ``usd`` (on the lab's clock under ``timing``, see ``write_control_usd``)."""
    out = Path(out_dir)
    written = []
    for name, res in zip(names, results):
        written.append(atomic_write(out / f"control_{name}.csv", control_csv_text(res)))
        written.append(atomic_write(out / f"control_{name}.json", json.dumps(control_json_data(res), indent=1) + "\n"))
        if usd:
            written.append(write_control_usd(res, out / f"actuation_{name}.usdc", target_name=name, timing=timing))
    return written


def write_molds(design, out_dir, *, marker_height: float, layer_thickness: float, units: str = "mm") -> list[Path]:
    """The printable molds in ``units`` (unit in each file name): ``mold_core_<u>.stl`` (rest shape
    with IPAM bosses), ``mold_shell_bottom_<u>.stl`` and ``mold_shell_top_<u>.stl`` (the two-part
    shell whose cavity is the rest shape offset by the jamming layer), and ``molds_<u>.json``
    (units, sizes, split plane, keys, pour and vent, IPAM markers, per part extents and volume)."""
    out = Path(out_dir)
    molds = mold_set(design, units=units, marker_height=marker_height, layer_thickness=layer_thickness)
    written = [atomic_write(out / f"{name}_{units}.stl", mesh.export(file_type="stl"))
               for name, mesh in molds.parts().items()]
    return written + [write_json(out / f"molds_{units}.json", molds.info)]


def round_record(round_index: int, design, results, names) -> dict:
    """One finished design round as JSON-ready data: the design it controlled (the faces every IPAM
    joins with its properties, the faces of every jamming cell) and each target's fit."""
    ipams = [dict(face_a=int(ip.face_a), face_b=int(ip.face_b), stiffness_n_per_m=float(ip.stiffness),
                  area_m2=float(ip.area), free_length_m=float(ip.free_length),
                  pressure_limits_pa=[float(p) for p in ip.pressure_limits], damping_n_s_per_m=float(ip.damping))
             for ip in design.ipams]
    return dict(round=int(round_index), ipams=ipams, cells=[[int(f) for f in c.faces] for c in design.cells],
                pcc={n: float(r.pcc) for n, r in zip(names, results)},
                objective={n: float(r.objective) for n, r in zip(names, results)},
                passive_ipams={n: [int(i) for i in r.passive_ipams] for n, r in zip(names, results)})


def record_round(records: list, round_index: int, design, results, names) -> bool:
    """Append round ``round_index``'s ``round_record`` to ``records``; a round controlled again as the
    last (a design that stops early) replaces its earlier record. Returns whether it replaced one."""
    replaced = bool(records) and records[-1]["round"] == round_index
    if replaced:
        records.pop()
    records.append(round_record(round_index, design, results, names))
    return replaced


def write_round_outputs(out_dir, names, records, rounds) -> list[Path]:
    """What finished design rounds leave behind, so an interrupted run keeps them: ``rounds.json``
    (every finished round's design and fit, see ``round_record``), a partial ``report.json``
    (``complete`` false, PCC and fit objective by round so far) and the last round's control sequences.
    ``records``: ``round_record`` of every finished round; ``rounds``: their control results, in order."""
    out = Path(out_dir)
    report = dict(complete=False, rounds_done=len(records), targets=list(names),
                  pcc_by_round=[[r.pcc for r in rs] for rs in rounds],
                  objective_by_round=[[r.objective for r in rs] for rs in rounds])
    return [write_json(out / "rounds.json", dict(targets=list(names), rounds=list(records))),
            write_json(out / "report.json", report)] + write_control_outputs(rounds[-1], names, out)


def write_figures_or_skip(result, out_dir, target_names=None, timing=None) -> list[Path]:
    """The report figures (``figures.write_figures``; time axes on the lab's clock under ``timing``);
    skipped, with a note on stderr, where matplotlib is missing."""
    try:
        return write_figures(result, out_dir, target_names=target_names, timing=timing)
    except ImportError as exc:
        print(f"figures skipped: {exc}", file=sys.stderr)
        return []


def write_design_outputs(result, out_dir, *, marker_height: float, layer_thickness: float,
                         extra_report: dict | None = None, kept=(), timing=None,
                         feel: dict | None = None) -> list[Path]:
    """Every output of a finished design: ``design.usda`` (the design, its targets, its run settings
    (``RunSettings.groups``) and each target's actuator selection), per target the control sequence (CSV, JSON), the valve-ready
    sequence (``valve_<name>.csv|json``) and ``actuation_<name>.usdc``, the molds, the figures,
    ``report.md`` and ``report.json`` (the result's report, ``extra_report`` entries and the list of
    outputs, with the names in ``kept``: files of the run already in ``out_dir`` such as
    ``rounds.json``), written last. ``timing``: the lab's clock of the valve CSV, the USD animations
    and the figures (``io.valve.ValveTiming``, default 5 mL/s, 100 kPa/s, 50 Hz). ``feel``: {target: FeelMap}
    of the controlled shapes (``warp-shape design --feel``): per target ``feel_<name>.csv|png``, a primvar
    ``feel_stiffness_n_per_mm_<name>`` on ``design.usda``'s membrane, a section of ``report.md`` and
    ``report.json["feel"]`` (keys with units)."""
    out = Path(out_dir)
    names = result.target_names
    settings = RunSettings(control=result.control_settings, designer=result.settings,
                           actuators=max(result.design.n_ipams, 1)).groups()
    settings["controller"].update(result.passive_settings())
    written = [save_scene(Scene(design=result.design, targets=result.targets, target_names=names,
                                settings=settings), out / "design.usda")]
    written += write_control_outputs(result.results, names, out, usd=True, timing=timing)
    written += write_valve_outputs(result.results, names, out, timing)
    written += write_molds(result.design, out, marker_height=marker_height, layer_thickness=layer_thickness)
    figures = write_figures_or_skip(result, out, timing=timing)
    written += figures
    feel_md = ""
    if feel:
        add_feel_primvars(out / "design.usda", result.design.rest.faces, feel)
        feel_files, feel_md = write_feel_maps(out, feel, result.design.rest.faces, result.design.face_cell())
        written += feel_files
    report = result.report()
    report.update(extra_report or {})
    if feel:
        report["feel"] = {name: feel_summary(fm) for name, fm in feel.items()}
    report["outputs"] = sorted({p.name for p in written} | {"report.json", "report.md"} | set(kept))
    markdown = design_markdown(result, [p.name for p in figures])
    written.append(atomic_write(out / "report.md", markdown + ("\n" + feel_md if feel_md else "")))
    written.append(write_json(out / "report.json", report))
    return written
