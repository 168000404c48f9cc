"""Report figures (matplotlib, drawn off screen; PNGs written atomically).

- ``control_figure(result, path)``: the paper's Fig. 6 panels from a ``ControlResult.history``
  against simulated time in seconds: (a) volume vs target volume, (b) IPAM lengths (solid) vs
  targets (dashed), (c) cell curvatures (solid) vs targets (dashed) with jam times marked, (d) PCC,
  (e) IPAM gauge pressures (kPa), (f) chamber gauge pressure (kPa) and air (mL at atmospheric
  pressure). Passive IPAMs (not used for this target, held neutral) are grey dashed and labelled
  so; the initial inflation is a grey band, named in panel (a).
- ``pcc_by_round_figure(design_result_or_array, target_names, path)``: PCC per target against the
  number of IPAMs placed (Figs. 9 and 13b).
- ``write_figures(result, out_dir)``: ``pcc_by_round.png`` (design results only) and
  ``control_<target>.png`` for each target.

matplotlib is imported lazily, so the rest of the package works without it.
"""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np

from ..material import GAS_CONSTANT
from .atomic import atomic_write

__all__ = ["build_control_figure", "control_figure", "pcc_by_round_figure", "write_figures"]

DPI = 120


def _figure(figsize):
    # a bare Figure draws with the Agg canvas: no pyplot state, no display needed
    try:
        from matplotlib.figure import Figure
    except ImportError as exc:
        raise ImportError("report figures need matplotlib: pip install 'warp-shape[figures]'") from exc

    return Figure(figsize=figsize, dpi=DPI, layout="constrained")


def _save(fig, path) -> Path:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=DPI)
    return atomic_write(path, buf.getvalue())


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


def _shade_inflation(ax, t, phase, *, name: bool = False):
    """The grey band over the inflation rows (phase 1); ``name`` writes what it is inside it."""
    if phase is None or not np.any(phase == 1):
        return
    end = float(t[phase == 1].max())
    ax.axvspan(t[0], end, color="0.92", zorder=0, lw=0, label=INFLATION_LABEL if name else None)
    if name:
        ax.text(0.5 * (t[0] + end), 0.03, "inflation", transform=ax.get_xaxis_transform(), ha="center",
                va="bottom", fontsize=7, color="0.35", rotation=90 if end - t[0] < 0.15 * (t[-1] - t[0]) else 0)


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
    for i, col in enumerate(lengths):
        if i in passive:
            ax.plot(t, np.asarray(h[col]) * 1e3, color=PASSIVE_COLOR, ls="--", lw=1.2,
                    label=f"IPAM {i} (passive, held neutral)")
        else:
            _plot_with_target(ax, t, h[col], h[f"ipam{i}_target_length_m"], f"C{i % 10}", f"IPAM {i}", 1.8)
    ax.set_ylabel("length (mm)")
    ax.set_title("(b) IPAM lengths (solid) and targets (dashed)")
    if lengths:
        ax.legend(loc="best", fontsize=7, ncol=2)
    else:
        ax.text(0.5, 0.5, "no IPAMs", ha="center", va="center", transform=ax.transAxes, color="0.5")


def _panel_curvatures(ax, t, h, result) -> None:
    """Cell curvatures and targets, jam times marked."""
    kappas = _columns(h, "cell", "_kappa_m")
    jam_steps = np.asarray(getattr(result, "jam_steps", np.full(len(kappas), -1)))
    step = np.asarray(h["step"])
    for j, col in enumerate(kappas):
        k_col = f"C{j % 10}"
        k = _plot_with_target(ax, t, h[col], h[f"cell{j}_kappa_target_m"], k_col, f"cell {j}", 1.5)
        idx = -1
        if f"cell{j}_jammed" in h:  # the first recorded jammed row
            on = np.flatnonzero(np.asarray(h[f"cell{j}_jammed"]) > 0)
            idx = int(on[0]) if on.size else -1
        if idx < 0 and j < len(jam_steps) and jam_steps[j] >= 0:
            idx = min(int(np.searchsorted(step, int(jam_steps[j]))), len(step) - 1)
        if idx >= 0:
            ax.plot([t[idx]], [k[idx]], marker="v", ms=7, color=k_col, mec="k", mew=0.6, ls="none")
            ax.axvline(t[idx], color=k_col, lw=0.6, ls=":")
    ax.set_ylabel("curvature $\\kappa$ (mm)")
    ax.set_title("(c) cell curvatures and targets; $\\blacktriangledown$ jammed")
    if kappas:
        ax.legend(loc="best", fontsize=6, ncol=2)
    else:
        ax.text(0.5, 0.5, "no jamming cells", ha="center", va="center", transform=ax.transAxes, color="0.5")


def _panel_pressures(ax, t, h, passive: set) -> None:
    """IPAM gauge pressures in kPa; passive IPAMs grey dashed (their neutral pressure)."""
    cols = _columns(h, "ipam", "_pressure_pa")
    for i, col in enumerate(cols):
        p = np.asarray(h[col]) / 1e3
        if i in passive:
            ax.plot(t, p, color=PASSIVE_COLOR, ls="--", lw=1.2, label=f"IPAM {i} (passive, held neutral)")
        else:
            ax.plot(t, p, color=f"C{i % 10}", lw=1.8, label=f"IPAM {i}")
    ax.axhline(0.0, color="0.6", lw=0.5)
    ax.set_ylabel("IPAM pressure (kPa gauge)")
    ax.set_title("(e) IPAM pressures")
    if cols:
        ax.legend(loc="best", fontsize=7, ncol=2)


def _panel_chamber(ax, t, h, material) -> None:
    """Chamber gauge pressure (kPa) and its air as mL at atmospheric pressure (right axis)."""
    ax.plot(t, np.asarray(h["pressure_pa"]) / 1e3, color="k", lw=1.8, label="chamber pressure")
    ax.set_ylabel("chamber pressure (kPa gauge)")
    ax.set_title("(f) chamber")
    if "air_mol" in h:
        temp, p_atm = (material.temperature, material.atmospheric_pressure) if material else (293.15, 101325.0)
        air = ax.twinx()
        air.plot(t, np.asarray(h["air_mol"]) * GAS_CONSTANT * temp / p_atm * 1e6, color="C9", lw=1.2, ls="-.")
        air.set_ylabel(f"air (mL at {p_atm / 1e3:.1f} kPa, {temp:.0f} K)", color="C9")
        air.tick_params(axis="y", colors="C9")


def build_control_figure(result, title: str | None = None):
    """Fig. 6-style panels of one control run (``ws.ControlResult``) as a matplotlib ``Figure``:
    (a) volume, (b) IPAM lengths, (c) cell curvatures, (d) PCC, (e) IPAM pressures, (f) chamber
    pressure and air, against simulated time in seconds; passive IPAMs grey dashed and labelled, the
    inflation phase a named grey band."""
    h = result.history
    t = _seconds(h)
    phase = np.asarray(h["phase"]) if "phase" in h else None
    passive = _passive(result)
    fig = _figure((10.0, 10.0))
    (a, b), (c, d), (e, f) = fig.subplots(3, 2, sharex=True)
    _shade_inflation(a, t, phase, name=True)
    a.plot(t, np.asarray(h["volume_m3"]) * 1e6, color="C0", lw=2, label="volume")
    a.plot(t, np.asarray(h["target_volume_m3"]) * 1e6, color="C0", ls="--", lw=1.2, label="target volume")
    a.set_ylabel("volume (cm$^3$)")
    a.set_title("(a) volume")
    a.legend(loc="best", fontsize=7)
    _panel_lengths(b, t, h, passive)
    _panel_curvatures(c, t, h, result)
    d.plot(t, np.asarray(h["pcc"]), color="C3", lw=2)
    d.set_ylabel("PCC")
    d.set_title(f"(d) fit: final PCC {result.pcc:.4f}")
    d.set_ylim(min(0.0, float(np.min(h["pcc"]))) if len(t) else 0.0, 1.0)
    _panel_pressures(e, t, h, passive)
    if "pressure_pa" in h:
        _panel_chamber(f, t, h, getattr(getattr(result, "design", None), "material", None))
    for ax in (b, c, d, e, f):
        _shade_inflation(ax, t, phase, name=False)
    for ax in (a, b, c, d, e, f):
        ax.grid(True, lw=0.4, alpha=0.5)
    for ax in (e, f):
        ax.set_xlabel("time (s, simulated; the valve schedule is slower)")
    note = "grey band: inflation" + ("; grey dashed: passive IPAMs held neutral" if passive else "")
    fig.suptitle(f"{title or 'Control sequence'} ({note})")
    return fig


def control_figure(result, path, title: str | None = None) -> Path:
    """``build_control_figure`` of one control run as a PNG at ``path``."""
    return _save(build_control_figure(result, title), path)


def pcc_by_round_figure(design_result_or_array, target_names=None, path="pcc_by_round.png",
                        title: str | None = None) -> Path:
    """PCC of every target against the number of IPAMs (round i: design with i IPAMs)."""
    pcc = getattr(design_result_or_array, "pcc_by_round", design_result_or_array)
    pcc = np.atleast_2d(np.asarray(pcc, dtype=np.float64))
    if target_names is None:
        target_names = getattr(design_result_or_array, "target_names", None)
    names = list(target_names) if target_names is not None else [f"target{j}" for j in range(pcc.shape[1])]
    rounds = np.arange(pcc.shape[0])
    fig = _figure((6.0, 4.0))
    ax = fig.subplots()
    markers = "osD^vP*X"
    for j, name in enumerate(names):
        ax.plot(rounds, pcc[:, j], marker=markers[j % len(markers)], lw=1.8, label=name)
    ax.set_xlabel("number of IPAMs")
    ax.set_ylabel("PCC")
    ax.set_xticks(rounds)
    lo = float(np.nanmin(pcc)) if pcc.size else 0.0
    ax.set_ylim(max(-1.0, lo - 0.05 * max(1e-3, 1.0 - lo)), 1.0)
    ax.grid(True, lw=0.4, alpha=0.5)
    ax.legend(loc="best")
    ax.set_title(title or "PCC by actuator round")
    return _save(fig, path)


def write_figures(result, out_dir, target_names=None) -> list[Path]:
    """Write the report figures into ``out_dir``.

    ``result``: a ``DesignResult`` (writes ``pcc_by_round.png`` and ``control_<target>.png`` for
    every target of the final design), or a ``ControlResult`` / list of them (``control_<target>.png``
    only; names from ``target_names``, default ``target<j>``).
    """
    out = Path(out_dir)
    written = []
    if hasattr(result, "pcc_by_round"):
        names = list(target_names or result.target_names)
        written.append(pcc_by_round_figure(result, names, out / "pcc_by_round.png"))
        results = result.results
        extra = f", {result.design.n_ipams} IPAMs"
    else:
        results = [result] if hasattr(result, "history") else list(result)
        names = list(target_names) if target_names is not None else [f"target{j}" for j in range(len(results))]
        extra = ""
    for name, r in zip(names, results):
        written.append(control_figure(r, out / f"control_{name}.png", title=f"Control to {name}{extra}"))
    return written
