"""Report figures (matplotlib, drawn off screen; PNGs written atomically).

- ``control_figure(result, path)``: the paper's Fig. 6 panels from a ``ControlResult.history``:
  (a) volume vs target volume, (b) IPAM lengths (solid) vs targets (dashed), (c) cell curvatures
  (solid) vs targets (dashed) with jam times marked, (d) PCC over the control sequence. The
  initial-inflation phase is shaded.
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

from .atomic import atomic_write

__all__ = ["control_figure", "pcc_by_round_figure", "write_figures"]

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


def _shade_inflation(ax, step, phase):
    if phase is not None and np.any(phase == 1):
        end = step[phase == 1].max()
        ax.axvspan(step[0], end, color="0.92", zorder=0, lw=0)


def _plot_with_target(ax, step, values_m, targets_m, color, label, width):
    """A quantity (solid) and its target (dashed, same colour), in mm; returns the values in mm."""
    values = np.asarray(values_m) * 1e3
    ax.plot(step, values, color=color, lw=width, label=label)
    ax.plot(step, np.asarray(targets_m) * 1e3, color=color, ls="--", lw=0.6 * width)
    return values


def control_figure(result, path, title: str | None = None) -> Path:
    """Fig. 6-style panels of one control run (``ws.ControlResult``) as a PNG at ``path``."""
    h = result.history
    step = np.asarray(h["step"])
    phase = np.asarray(h["phase"]) if "phase" in h else None
    fig = _figure((10.0, 7.0))
    axes = fig.subplots(2, 2, sharex=True)
    (a, b), (c, d) = axes
    colors = [f"C{i % 10}" for i in range(10)]

    a.plot(step, np.asarray(h["volume_m3"]) * 1e6, color="C0", lw=2, label="volume")
    a.plot(step, np.asarray(h["target_volume_m3"]) * 1e6, color="C0", ls="--", lw=1.2, label="target volume")
    a.set_ylabel("volume (cm$^3$)")
    a.set_title("(a) volume")
    a.legend(loc="best", fontsize=8)

    lengths = _columns(h, "ipam", "_length_m")
    for i, col in enumerate(lengths):
        _plot_with_target(b, step, h[col], h[f"ipam{i}_target_length_m"], colors[i % 10], f"IPAM {i}", 1.8)
    b.set_ylabel("length (mm)")
    b.set_title("(b) IPAM lengths (solid) and targets (dashed)")
    if lengths:
        b.legend(loc="best", fontsize=7, ncol=2)
    else:
        b.text(0.5, 0.5, "no IPAMs", ha="center", va="center", transform=b.transAxes, color="0.5")

    kappas = _columns(h, "cell", "_kappa_m")
    jam_steps = np.asarray(getattr(result, "jam_steps", np.full(len(kappas), -1)))
    for j, col in enumerate(kappas):
        k_col = colors[j % 10]
        k = _plot_with_target(c, step, h[col], h[f"cell{j}_kappa_target_m"], k_col, f"cell {j}", 1.5)
        js = int(jam_steps[j]) if j < len(jam_steps) else -1
        if js < 0 and f"cell{j}_jammed" in h:  # fall back to the recorded jam state
            on = np.flatnonzero(np.asarray(h[f"cell{j}_jammed"]) > 0)
            js = int(step[on[0]]) if on.size else -1
        if js >= 0:
            idx = int(np.searchsorted(step, js))
            idx = min(idx, len(step) - 1)
            c.plot([step[idx]], [k[idx]], marker="v", ms=7, color=k_col, mec="k", mew=0.6, ls="none")
            c.axvline(step[idx], color=k_col, lw=0.6, ls=":")
    c.set_ylabel("curvature $\\kappa$ (mm)")
    c.set_title("(c) cell curvatures and targets; $\\blacktriangledown$ jammed")
    c.set_xlabel("control step")
    if kappas:
        c.legend(loc="best", fontsize=6, ncol=2)
    else:
        c.text(0.5, 0.5, "no jamming cells", ha="center", va="center", transform=c.transAxes, color="0.5")

    d.plot(step, np.asarray(h["pcc"]), color="C3", lw=2)
    d.set_ylabel("PCC")
    d.set_xlabel("control step")
    d.set_title(f"(d) fit: final PCC {result.pcc:.4f}")
    d.set_ylim(min(0.0, float(np.min(h["pcc"]))) if len(step) else 0.0, 1.0)
    for ax in (a, b, c, d):
        _shade_inflation(ax, step, phase)
        ax.grid(True, lw=0.4, alpha=0.5)
    fig.suptitle(title or "Control sequence (shaded: initial inflation)")
    return _save(fig, path)


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
