"""Report figures (matplotlib, drawn off screen; each a PNG with an SVG beside it, written atomically).

- ``control_figure(result, path)``: the paper's Fig. 6 panels from a ``ControlResult.history``
  against the lab's time of the valve CSV and the USD animation (``io.valve.row_times``; the
  simulated time on a top axis): (a) volume vs target volume, (b) IPAM lengths (solid) vs targets
  (dashed), (c) cell curvatures (solid) vs targets (dashed) with jam times marked, (d) PCC, (e) IPAM
  gauge pressure commands (kPa), (f) chamber gauge pressure (kPa: at rest under each row's
  controls, as the valve CSV, the simulated transient grey) and air (mL at atmospheric pressure);
  lines drawn over others thinner, so identical ones both show. Passive IPAMs (not used for this target, held neutral) are grey dashed and
  labelled so; the initial inflation is a grey band, named in panel (a).
- ``pcc_by_round_figure(design_result_or_array, target_names, path)``: the objective, MARE and PCC
  per target against the number of IPAMs placed (Figs. 9 and 13b).
- ``build_fit_figure(result)``: the achieved membrane coloured by its signed radial error R - r (mm,
  the report's sign) with the target drawn as a wire surface, a run's fit figures on one colour
  scale (``fit_colour_limit``); ``build_rest_figure(design)``: the rest shape with its jamming cells and
  IPAMs (both seen from two sides).
- ``write_figures(result, out_dir)``: ``pcc_by_round``, ``rest_shape`` and ``fit_<target>``
  (design results only) and ``control_<target>`` for each target; inside a run whose worker
  processes are running (``controller.shard.worker_pool``) each figure is drawn by one of them.

matplotlib is imported lazily, so the rest of the package works without it.
"""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np

from ..controller.shard import run_jobs
from ..material import GAS_CONSTANT
from .atomic import atomic_write
from .valve import ValveTiming, quasi_static_pressure, row_times

__all__ = ["build_control_figure", "control_figure", "pcc_by_round_figure", "write_figures", "line_colors", "svg_path",
           "signed_radial_error", "fit_colour_limit", "build_by_round_figure", "label_spots", "stacked_widths", "build_fit_figure", "build_rest_figure", "write_shape_figures"]

DPI = 120


def _figure(figsize):
    # a bare Figure draws with the Agg canvas: no pyplot state, no display needed
    try:
        from matplotlib.figure import Figure
    except ImportError as exc:
        raise ImportError("report figures need matplotlib: pip install 'warp-shape[figures]'") from exc

    return Figure(figsize=figsize, dpi=DPI, layout="constrained")


def _save(fig, path) -> Path:
    """The figure as a PNG at ``path`` and, beside it, the same as an SVG (vector, for a report to
    scale); both written atomically. Returns the PNG's path (``svg_path`` names the other)."""
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=DPI)
    png = atomic_write(path, buf.getvalue())
    fig.set_layout_engine("none")  # the layout the PNG's draw placed is the SVG's: not computed twice
    buf = io.BytesIO()
    fig.savefig(buf, format="svg")
    atomic_write(svg_path(path), buf.getvalue())
    return png


def svg_path(path) -> Path:
    """The SVG written beside a figure's PNG: the same name, ``.svg``."""
    return Path(path).with_suffix(".svg")


def _columns(history: dict, prefix: str, suffix: str) -> list[str]:
    out, i = [], 0
    while f"{prefix}{i}{suffix}" in history:
        out.append(f"{prefix}{i}{suffix}")
        i += 1
    return out


PASSIVE_COLOR = "0.55"  # passive IPAMs: grey, dashed
INFLATION_LABEL = "inflation: chamber filled to the target volume, IPAMs neutral"


def _seconds(h: dict) -> np.ndarray:
    """Simulated time from 0, s."""
    t = np.asarray(h["time"], dtype=np.float64) if "time" in h else np.asarray(h["step"], dtype=np.float64)
    return t - t[0]


def _timeline(result, timing) -> tuple[np.ndarray, np.ndarray, str]:
    """(lab time, simulated time, x label) of each control step: the lab's clock of the valve CSV and
    the USD animation (``io.valve.row_times`` under ``timing``); a record without the chamber's air
    (not a controller's) keeps the simulated time."""
    sim = _seconds(result.history)
    timing = timing or ValveTiming()
    if not {"time", "air_mol", "pressure_pa", "phase"} <= set(result.history):
        return sim, sim, "time (s, simulated)"
    return row_times(result, timing), sim, f"lab time (s; {timing.describe()}, as the valve CSV)"


def _simulated_axis(ax, lab: np.ndarray, sim: np.ndarray) -> None:
    """A top axis giving the simulated time at the lab time's ticks (the map is linear between control
    steps but far from uniform: the pump's inflation stretches most)."""
    if len(lab) < 2 or np.array_equal(lab, sim):
        return
    ticks = [float(t) for t in ax.get_xticks() if lab[0] - 1e-9 <= t <= lab[-1] + 1e-9]
    top = ax.secondary_xaxis("top")
    top.set_xticks(ticks, [f"{np.interp(t, lab, sim):.3f}" for t in ticks])
    top.set_xlabel("simulated time (s) at these lab times (not to scale: the pump stretches the inflation)",
                   fontsize=8)
    top.tick_params(labelsize=7)


def _shade_inflation(ax, t, phase, *, name: bool = False):
    """The grey band over the inflation rows (phase 1); ``name`` writes what it is at the band's top
    (where no legend goes: legends sit at the bottom right)."""
    if phase is None or not np.any(phase == 1):
        return
    last = int(np.flatnonzero(phase == 1).max())
    end = float(t[min(last + 1, len(t) - 1)])  # the air dosed after the last inflation row is inflation's
    ax.axvspan(t[0], end, color="0.92", zorder=0, lw=0, label=INFLATION_LABEL if name else None)
    if name:
        narrow = end - t[0] < 0.15 * (t[-1] - t[0])
        ax.text(0.5 * (t[0] + end), 0.97, "inflation", transform=ax.get_xaxis_transform(), ha="center",
                va="top", fontsize=7, color="0.35", rotation=90 if narrow else 0)


def line_colors(n: int) -> list:
    """``n`` distinct colours, none grey (grey marks passive IPAMs): tab10 up to 9, tab20 up to 18,
    else evenly along turbo."""
    from matplotlib import colormaps

    if n <= 9:
        return [f"C{i}" for i in range(10) if i != 7][:n]
    if n <= 18:
        cmap = colormaps["tab20"]
        return [cmap(i) for i in range(20) if i not in (14, 15)][:n]
    cmap = colormaps["turbo"]
    return [cmap(0.05 + 0.9 * i / (n - 1)) for i in range(n)]


def _legend(ax, n_lines: int) -> None:
    """A small legend at the lower right (the inflation band's name is at the top), in columns."""
    ax.legend(loc="lower right", fontsize=6 if n_lines > 8 else 7, ncol=1 + (n_lines - 1) // 4, framealpha=0.8)


def _plot_with_target(ax, t, values_m, targets_m, color, label, width):
    """A quantity (solid) and its target (dashed, same colour), in mm; returns the values in mm."""
    values = np.asarray(values_m) * 1e3
    ax.plot(t, values, color=color, lw=width, label=label)
    ax.plot(t, np.asarray(targets_m) * 1e3, color=color, ls="--", lw=0.6 * width)
    return values


def _passive(result) -> set:
    return {int(i) for i in np.atleast_1d(getattr(result, "passive_ipams", []))}


def _panel_lengths(ax, t, h, passive: set) -> None:
    """IPAM lengths (solid) and targets (dashed); passive IPAMs grey dashed, without a target."""
    lengths = _columns(h, "ipam", "_length_m")
    colors, widths = line_colors(len(lengths)), stacked_widths(len(lengths), 1.5)
    for i, col in enumerate(lengths):
        if i in passive:
            ax.plot(t, np.asarray(h[col]) * 1e3, color=PASSIVE_COLOR, ls="--", lw=1.2,
                    label=f"IPAM {i} (passive, held neutral)")
        else:
            _plot_with_target(ax, t, h[col], h[f"ipam{i}_target_length_m"], colors[i], f"IPAM {i}", widths[i])
    ax.set_ylabel("length (mm)")
    ax.set_title("(b) IPAM lengths (solid) and targets (dashed)")
    if lengths:
        _legend(ax, len(lengths))
    else:
        ax.text(0.5, 0.5, "no IPAMs", ha="center", va="center", transform=ax.transAxes, color="0.5")


def _jam_row(h, step, jam_steps, j: int) -> int:
    """The first recorded row where cell j is jammed (-1: never)."""
    if f"cell{j}_jammed" in h:
        on = np.flatnonzero(np.asarray(h[f"cell{j}_jammed"]) > 0)
        if on.size:
            return int(on[0])
    if j < len(jam_steps) and jam_steps[j] >= 0:
        return min(int(np.searchsorted(step, int(jam_steps[j]))), len(step) - 1)
    return -1


def _panel_curvatures(ax, t, h, result) -> None:
    """Cell curvatures and targets, jam times marked."""
    kappas = _columns(h, "cell", "_kappa_m")
    jam_steps = np.asarray(getattr(result, "jam_steps", np.full(len(kappas), -1)))
    step = np.asarray(h["step"])
    colors, widths = line_colors(len(kappas)), stacked_widths(len(kappas), 1.3)
    for j, col in enumerate(kappas):
        k = _plot_with_target(ax, t, h[col], h[f"cell{j}_kappa_target_m"], colors[j], f"cell {j}", widths[j])
        idx = _jam_row(h, step, jam_steps, j)
        if idx >= 0:
            ax.plot([t[idx]], [k[idx]], marker="v", ms=7, color=colors[j], mec="k", mew=0.6, ls="none")
            ax.axvline(t[idx], color=colors[j], lw=0.6, ls=":")
    ax.set_ylabel("cell curvature $\\kappa$ (mm):\nIPAM end radius $-$ mean cell radius", fontsize=8)
    ax.set_title("(c) cell curvatures and targets; $\\blacktriangledown$ jammed")
    if kappas:
        _legend(ax, len(kappas))
    else:
        ax.text(0.5, 0.5, "no jamming cells", ha="center", va="center", transform=ax.transAxes, color="0.5")


def _panel_pressures(ax, t, h, passive: set) -> None:
    """IPAM gauge pressures in kPa; passive IPAMs grey dashed (their neutral pressure)."""
    cols = _columns(h, "ipam", "_pressure_pa")
    colors, widths = line_colors(len(cols)), stacked_widths(len(cols), 1.5)
    for i, col in enumerate(cols):
        p = np.asarray(h[col]) / 1e3
        if i in passive:
            ax.plot(t, p, color=PASSIVE_COLOR, ls="--", lw=1.2, label=f"IPAM {i} (passive, held neutral)")
        else:
            ax.plot(t, p, color=colors[i], lw=widths[i], label=f"IPAM {i}")
    ax.axhline(0.0, color="0.6", lw=0.5)
    ax.set_ylabel("IPAM pressure (kPa gauge)")
    ax.set_title("(e) IPAM pressure commands")
    if cols:
        _legend(ax, len(cols))


def _panel_chamber(ax, t, h, result) -> None:
    """Chamber gauge pressure (kPa): at rest under each row's controls, as the valve CSV gives it
    (``io.valve.quasi_static_pressure``), the simulated transient thin grey beside it; its air as mL
    at atmospheric pressure (right axis)."""
    material = getattr(getattr(result, "design", None), "material", None)
    settled, source = quasi_static_pressure(result)
    ax.plot(t, np.asarray(h["pressure_pa"]) / 1e3, color="0.6", lw=0.8, label="simulated transient")
    ax.plot(t, settled / 1e3, color="k", lw=1.8, label="at rest (as the valve CSV)" if source == "quasi-static"
            else "simulated")
    ax.set_ylabel("chamber pressure (kPa gauge)")
    ax.set_title("(f) chamber: pressure and air dosed")
    ax.legend(loc="lower right", fontsize=7)
    if "air_mol" in h:
        temp, p_atm = (material.temperature, material.atmospheric_pressure) if material else (293.15, 101325.0)
        air = ax.twinx()
        air.plot(t, np.asarray(h["air_mol"]) * GAS_CONSTANT * temp / p_atm * 1e6, color="C9", lw=1.2, ls="-.")
        air.set_ylabel(f"air (mL at {p_atm / 1e3:.1f} kPa, {temp:.0f} K)", color="C9")
        air.tick_params(axis="y", colors="C9")


def stacked_widths(n: int, width: float) -> list[float]:
    """Line widths for ``n`` lines drawn in order: each thinner than the one before, so a line drawn
    over an identical one leaves it showing at both edges."""
    return [width * (1.0 + 1.2 * (n - 1 - k) / max(n - 1, 1)) for k in range(n)]


def _panel_fit(ax, t, h, result) -> None:
    """PCC over the run on an axis fitted to its values (a 0-1 axis flattens the change)."""
    pcc_values = np.asarray(h["pcc"], dtype=np.float64)
    ax.plot(t, pcc_values, color="C3", lw=2)
    ax.set_ylabel("PCC")
    ax.set_title(f"(d) fit: final PCC {result.pcc:.4f}")
    if pcc_values.size:
        lo, hi = float(np.min(pcc_values)), float(np.max(pcc_values))
        pad = 0.08 * max(hi - lo, 1e-3)
        ax.set_ylim(lo - pad, min(1.0, hi + pad) if hi < 1.0 else hi + pad)


def build_control_figure(result, title: str | None = None, timing=None):
    """Fig. 6-style panels of one control run (``ws.ControlResult``) as a matplotlib ``Figure``:
    (a) volume, (b) IPAM lengths, (c) cell curvatures, (d) PCC, (e) IPAM pressures, (f) chamber
    pressure and air, against the lab's time of the valve CSV (``timing``, default
    ``io.valve.ValveTiming()``) with the simulated time on a top axis; passive IPAMs grey dashed and
    labelled, the inflation phase a named grey band (the title names the band only where one is drawn: a
    model-based sequence has no inflation phase of its own)."""
    h = result.history
    t, sim, xlabel = _timeline(result, timing)
    phase = np.asarray(h["phase"]) if "phase" in h else None
    passive = _passive(result)
    fig = _figure((10.0, 10.5))
    (a, b), (c, d), (e, f) = fig.subplots(3, 2, sharex=True)
    _shade_inflation(a, t, phase, name=True)
    a.plot(t, np.asarray(h["volume_m3"]) * 1e6, color="C0", lw=2, label="volume")
    a.plot(t, np.asarray(h["target_volume_m3"]) * 1e6, color="C0", ls="--", lw=1.2, label="target volume")
    a.set_ylabel("volume (cm$^3$)")
    a.set_title("(a) volume")
    a.legend(loc="lower right", fontsize=7)
    _panel_lengths(b, t, h, passive)
    _panel_curvatures(c, t, h, result)
    _panel_fit(d, t, h, result)
    _panel_pressures(e, t, h, passive)
    if "pressure_pa" in h:
        _panel_chamber(f, t, h, result)
    for ax in (b, c, d, e, f):
        _shade_inflation(ax, t, phase, name=False)
    for ax in (a, b, c, d, e, f):
        ax.grid(True, lw=0.4, alpha=0.5)
    for ax in (a, b):
        _simulated_axis(ax, t, sim)
    for ax in (e, f):
        ax.set_xlabel(xlabel, fontsize=8)
    notes = (["grey band: inflation"] if phase is not None and np.any(phase == 1) else []) + (
        ["grey dashed: passive IPAMs held neutral"] if passive else [])  # only what is drawn
    fig.suptitle(f"{title or 'Control sequence'}" + (f" ({'; '.join(notes)})" if notes else ""))
    return fig


def control_figure(result, path, title: str | None = None, timing=None) -> Path:
    """``build_control_figure`` of one control run as a PNG at ``path`` (and an SVG beside it)."""
    return _save(build_control_figure(result, title, timing), path)


def _by_round(design_result_or_array) -> dict:
    """Measure name -> (rounds, n_targets) array: PCC, and where a design result gives them the
    objective and MARE (mm)."""
    src = design_result_or_array
    out = {"PCC": np.atleast_2d(np.asarray(getattr(src, "pcc_by_round", src), dtype=np.float64))}
    rounds = getattr(src, "rounds", None)
    if rounds:
        out = {"objective (0 = perfect fit)": np.array([[r.objective for r in rs] for rs in rounds], dtype=np.float64),
               "MARE (mm)": np.array([[r.mare * 1e3 for r in rs] for rs in rounds], dtype=np.float64), **out}
    return out


def pcc_by_round_figure(design_result_or_array, target_names=None, path="pcc_by_round.png",
                        title: str | None = None) -> Path:
    """The fit of every target against the number of IPAMs (round i: design with i IPAMs; Figs. 9 and
    13b): for a design result the objective (what the designer minimises) and MARE beside the PCC,
    each axis fitted to its values; for an array, PCC alone."""
    if target_names is None:
        target_names = getattr(design_result_or_array, "target_names", None)
    return _save(build_by_round_figure(_by_round(design_result_or_array), target_names, title), path)


def build_by_round_figure(measures: dict, target_names, title: str | None):
    """The figure of ``pcc_by_round_figure`` from its measures ({name: (rounds, n_targets)}), unsaved."""
    pcc = measures["PCC"]
    names = list(target_names) if target_names is not None else [f"target{j}" for j in range(pcc.shape[1])]
    rounds = np.arange(pcc.shape[0])
    fig = _figure((4.2 * len(measures) + 0.6, 4.0))
    axes = np.atleast_1d(fig.subplots(1, len(measures)))
    markers = "osD^vP*X"
    colors = line_colors(len(names))
    final = "MARE (mm)" in measures and len(rounds) > 1  # a design's last row: the final design's own controller
    for ax, (what, values) in zip(axes, measures.items()):
        for j, name in enumerate(names):
            ax.plot(rounds, values[:, j], marker=markers[j % len(markers)], color=colors[j], lw=1.8, label=name)
        ax.set_xlabel("number of IPAMs")
        ax.set_ylabel(what)
        ax.set_xticks(rounds, [str(int(r)) for r in rounds[:-1]] + [f"{int(rounds[-1])}" + ("\nfinal" if final else "")])
        ax.margins(y=0.08)
        if what == "PCC":  # the axis reaches 1 (the same shape): the gap left is drawn, not cut off
            ax.set_ylim(top=1.0 + 0.04 * (1.0 - float(np.nanmin(values))))
        if final:
            ax.axvspan(rounds[-1] - 0.5, rounds[-1] + 0.5, color="0.93", zorder=0, lw=0, gid="final")
        ax.grid(True, lw=0.4, alpha=0.5)
        ax.set_title({"PCC": "PCC (1 = same shape)"}.get(what, what.split(" (")[0]) + (" (lower is better)"
                     if what != "PCC" else ""), fontsize=10)
    axes[0].legend(loc="best", fontsize=8)
    fig.suptitle((title or "Fit by actuator round") + ("\n(grey, \"final\": the finished design under its own "
                                                        "controller, with refinement and co-design; not the last "
                                                        "IPAM's gain alone)" if final else ""), fontsize=10)
    return fig


def write_figures(result, out_dir, target_names=None, timing=None) -> list[Path]:
    """Write the report figures into ``out_dir``, each a PNG with an SVG beside it.

    ``result``: a ``DesignResult`` (writes ``pcc_by_round``, ``rest_shape``, and ``fit_<target>``
    and ``control_<target>`` for every target of the final design), or a ``ControlResult`` / list of them (``control_<target>`` only;
    names from ``target_names``, default ``target<j>``). ``timing``: the lab's clock of the time
    axes (``io.valve.ValveTiming``, default 5 mL/s, 100 kPa/s, 50 Hz).
    """
    out = Path(out_dir)
    jobs = []
    if hasattr(result, "pcc_by_round"):
        names = list(target_names or result.target_names)
        jobs.append(("by_round", (_by_round(result), names), out / "pcc_by_round.png", None, None))
        jobs += _shape_jobs(result.design, result.results, names, out)
        results = result.results
        extra = f", {result.design.n_ipams} IPAMs"
    else:
        results = [result] if hasattr(result, "history") else list(result)
        names = list(target_names) if target_names is not None else [f"target{j}" for j in range(len(results))]
        extra = ""
    jobs += [("control", r, out / f"control_{name}.png", f"Control to {name}{extra}", timing)
             for name, r in zip(names, results)]
    return [q for p in _draw_all(jobs) for q in (p, svg_path(p))]


def _shape_jobs(design, results, names, out: Path) -> list[tuple]:
    """The rest shape's figure and a fit figure per target, all fit figures on one colour scale."""
    lim = fit_colour_limit(results) if results else None
    return [("rest", design, out / "rest_shape.png", None, None)] + [
        ("fit", r, out / f"fit_{name}.png", f"Achieved {name}", lim) for name, r in zip(names, results)]


_COST = {"control": 0, "fit": 1, "rest": 2, "by_round": 3}  # the order figures are handed out: slowest first


def _draw_all(jobs: list[tuple]) -> list[Path]:
    """Every figure job drawn and saved; on the run's worker processes where they are running (one
    figure per job, the slowest first), else here. The PNGs' paths, in the order of ``jobs``."""
    order = sorted(range(len(jobs)), key=lambda k: _COST[jobs[k][0]])
    done = run_jobs(draw_figure, [jobs[k] for k in order])
    out = [None] * len(jobs)
    for k, path in zip(order, done):
        out[k] = path
    return out


def prepare_drawing() -> None:
    """Load matplotlib and its fonts by drawing a small figure to PNG and SVG (nothing is written): what
    a worker process does while it waits, so that its first report figure does not pay for it."""
    fig = _figure((2.0, 1.5))
    ax = fig.subplots()
    ax.plot([0, 1], [0, 1], label="a")
    ax.set_xlabel("x (mm)")
    ax.legend()
    fig.suptitle("prepare")
    for fmt in ("png", "svg"):
        fig.savefig(io.BytesIO(), format=fmt, dpi=DPI)


def draw_figure(kind: str, what, path, title: str | None, timing, *, progress=None) -> Path:
    """One report figure ``kind`` ("control", "fit", "rest", "by_round") of ``what`` (a control
    result, a design, or (measures, names)) saved at ``path`` (PNG, and an SVG beside it): a job a
    worker process can run (``progress`` is the pool's, unused). ``timing``: a control figure's
    lab clock; a fit figure's colour limit (mm)."""
    if kind == "control":
        fig = build_control_figure(what, title, timing)
    elif kind == "fit":
        fig = build_fit_figure(what, title=title, limit=timing)
    elif kind == "rest":
        fig = build_rest_figure(what, title)
    elif kind == "by_round":
        fig = build_by_round_figure(*what, title)
    else:
        raise ValueError(f"unknown figure kind {kind!r}")
    return _save(fig, path)


def _mesh_axes(fig, spec, title: str, extent: float, view: tuple):
    """A 3-D axis of equal scale in mm, seen from ``view`` (elevation, azimuth in degrees)."""
    ax = fig.add_subplot(spec, projection="3d")
    ax.set_title(title, fontsize=9)
    for setter in (ax.set_xlim, ax.set_ylim, ax.set_zlim):
        setter(-extent, extent)
    ax.set_box_aspect((1, 1, 1), zoom=0.85)  # room for the z label
    ax.view_init(*view)
    ax.set_xlabel("x (mm)", fontsize=7)
    ax.set_ylabel("y (mm)", fontsize=7)
    ax.set_zlabel("z (mm)", fontsize=7)
    ax.tick_params(labelsize=6)
    return ax


def _draw_mesh(ax, vertices_mm: np.ndarray, faces: np.ndarray, face_colors) -> None:
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    ax.add_collection3d(Poly3DCollection(vertices_mm[faces], facecolors=face_colors, edgecolors=(0, 0, 0, 0.08),
                                         linewidths=0.2))


VIEWS = ((20, -60), (20, 120))  # front-left and back-right


def signed_radial_error(result) -> np.ndarray:
    """(V,) R - r of the achieved membrane against the target, m, per vertex (the report's sign): r
    its radius, R the target's along the same ray from the target's centroid
    (``ControlResult.sampled_target``); > 0 where the membrane lies inside the target (it must move out)."""
    x = np.asarray(result.achieved.vertices, dtype=np.float64)
    return np.linalg.norm(np.asarray(result.sampled_target.vertices), axis=1) - np.linalg.norm(x, axis=1)


def fit_colour_limit(results) -> float:
    """The colour scale's half-width (mm) shared by a run's fit figures: the largest |R - r| of any of
    them (at least 0.1 mm), so one colour means one error in every figure and nothing is clipped."""
    return max([float(np.abs(signed_radial_error(r)).max()) * 1e3 for r in results] + [0.1])


def build_fit_figure(result, title: str | None = None, limit: float | None = None):
    """The achieved membrane of one control run coloured by its signed radial error R - r against
    the target (mm, red inside the target, blue outside; the scale symmetric about 0 and ``limit``
    mm wide each way, default this figure's largest error: give a run's ``fit_colour_limit`` to share
    one scale), with the target drawn as a grey wire surface, from two sides, as a matplotlib
    ``Figure``."""
    from matplotlib import colormaps
    from matplotlib.cm import ScalarMappable
    from matplotlib.colors import Normalize

    err_mm = signed_radial_error(result) * 1e3
    faces = np.asarray(result.achieved.faces)
    x_mm = np.asarray(result.achieved.vertices) * 1e3
    target_mm = np.asarray(result.sampled_target.vertices) * 1e3
    lim = float(limit) if limit is not None else fit_colour_limit([result])
    norm, cmap = Normalize(-lim, lim), colormaps["RdBu_r"]
    colors = cmap(norm(err_mm[faces].mean(axis=1)))
    fig = _figure((10.0, 5.0))
    grid = fig.add_gridspec(1, 3, width_ratios=[1, 1, 0.06])
    extent = 0.55 * float(np.max(np.r_[x_mm, target_mm].max(axis=0) - np.r_[x_mm, target_mm].min(axis=0)))
    for k, view in enumerate(VIEWS):
        ax = _mesh_axes(fig, grid[0, k], ("front" if k == 0 else "back") + " view", extent, view)
        _draw_mesh(ax, x_mm, faces, colors)
        _draw_target(ax, target_mm, faces)
    bar = fig.colorbar(ScalarMappable(norm=norm, cmap=cmap), cax=fig.add_subplot(grid[0, 2]))
    bar.set_label("signed radial error R - r (mm): + inside the target, - outside; grey wire: the target")
    fig.suptitle(f"{title or 'Achieved shape'}: MARE {result.mare * 1e3:.2f} mm, largest |R - r| "
                 f"{float(np.abs(err_mm).max()):.2f} mm, PCC {result.pcc:.4f} (colour scale +-{lim:.2f} mm)")
    return fig


def _draw_target(ax, target_mm: np.ndarray, faces: np.ndarray) -> None:
    """The target where the membrane's rays meet it, as a grey wire surface (``gid`` "target")."""
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    wire = Poly3DCollection(target_mm[faces], facecolors=(0, 0, 0, 0), edgecolors=(0.3, 0.3, 0.3, 0.35),
                            linewidths=0.3)
    wire.set_gid("target")
    ax.add_collection3d(wire)


def build_rest_figure(design, title: str | None = None):
    """The design's rest shape with its jamming cells (one colour each, the rest light grey) and its
    IPAMs (a numbered line between the two end-face centroids), from two sides."""
    rest = design.rest
    faces = np.asarray(rest.faces)
    x_mm = np.asarray(rest.vertices) * 1e3
    cell_of = design.face_cell()
    palette = line_colors(max(design.n_cells, 1))
    from matplotlib.colors import to_rgba

    normals = rest.face_normals()
    light = 0.65 + 0.35 * np.clip(normals @ np.array([-0.4, -0.6, 0.7]) / np.linalg.norm([-0.4, -0.6, 0.7]), 0, 1)
    base = np.array([to_rgba(palette[c]) if c >= 0 else (0.88, 0.88, 0.88, 1.0) for c in cell_of])
    colors = np.concatenate([base[:, :3] * light[:, None], base[:, 3:]], axis=1)  # lit from the front-left
    ends = rest.face_centroids() * 1e3
    fig = _figure((10.0, 5.2))
    grid = fig.add_gridspec(1, 2)
    extent = 0.55 * float(np.max(x_mm.max(axis=0) - x_mm.min(axis=0)))
    spots = label_spots([(ends[ip.face_a], ends[ip.face_b]) for ip in design.ipams])
    for k, view in enumerate(VIEWS):
        ax = _mesh_axes(fig, grid[0, k], ("front" if k == 0 else "back") + " view", extent, view)
        _draw_mesh(ax, x_mm, faces, colors)
        for i, ip in enumerate(design.ipams):
            a, b = ends[ip.face_a], ends[ip.face_b]
            ax.plot(*np.stack([a, b]).T, color="k", lw=2.0, zorder=10)
            ax.text(*spots[i], str(i), fontsize=7, color="k", zorder=11,
                    bbox=dict(boxstyle="round,pad=0.15", fc="w", ec="k", lw=0.4, alpha=0.85))
    _rest_legend(fig, design, palette)
    fig.suptitle(f"{title or 'Rest shape'}: {design.n_ipams} IPAMs (black lines between their end faces), "
                 f"{design.n_cells} jamming cells (coloured), {rest.n_vertices} vertices", fontsize=10)
    return fig


def label_spots(segments: list) -> list[np.ndarray]:
    """A label point on each IPAM's line (``segments``: (end a, end b) in mm): of the points 15 %, 30 %,
    ..., 85 % along it, the one farthest from the labels placed before it (IPAMs cross near the
    centre, where labels at one fixed fraction overlap)."""
    placed = []
    for a, b in segments:
        a, b = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
        tries = [a + f * (b - a) for f in (0.15, 0.3, 0.45, 0.55, 0.7, 0.85)]
        placed.append(max(tries, key=lambda p: min([float(np.linalg.norm(p - q)) for q in placed] + [np.inf])))
    return placed


def _rest_legend(fig, design, palette) -> None:
    """What the rest-shape figure's colours and lines are: IPAMs (numbered) and each jamming cell."""
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    handles = [Line2D([], [], color="k", lw=2, label="IPAM (number: its index), between its end faces")]
    handles += [Patch(color=palette[j], label=f"cell {j}") for j in range(design.n_cells)]
    handles.append(Patch(color=(0.88, 0.88, 0.88), label="membrane (no cell)"))
    fig.legend(handles=handles, loc="lower center", ncol=min(len(handles), 6), fontsize=7, frameon=False)


def write_shape_figures(result, out_dir, target_names=None) -> list[Path]:
    """Per target ``fit_<target>`` (``build_fit_figure``) and ``rest_shape`` of the design
    (``build_rest_figure``), each a PNG with an SVG beside it, from a ``DesignResult`` (or a list of
    control results of one design, named by ``target_names``)."""
    results = result.results if hasattr(result, "rounds") else list(result)
    names = list(target_names or getattr(result, "target_names", None) or [f"target{j}" for j in range(len(results))])
    design = result.design if hasattr(result, "rounds") else results[0].design
    return [q for p in _draw_all(_shape_jobs(design, results, names, Path(out_dir))) for q in (p, svg_path(p))]
