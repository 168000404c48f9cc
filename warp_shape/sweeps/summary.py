"""A sweep's summary: ``summary.md`` (a Markdown table) and ``summary.png`` (the fit by subset or by setting).

The figure follows the paper: for a subsets sweep (Fig. 11) tables of subsets (rows) by targets
(columns) coloured by the PCC and the MARE each target reaches with that subset's design, the mean
objective beside them, a cell worse than the same target designed alone boxed in red; for a grid sweep
(Fig. 12) each target's PCC, MARE and the objective against the first numeric swept parameter (e.g. the
actuator count), one line per target and per combination of the other swept values, a point worse
than the one before it on its line crossed in red (a PCC that rose does not hide a MARE that got worse). matplotlib is imported lazily; without
it the figure is skipped and the table still written.
"""

from __future__ import annotations

import io
import math
import sys
from pathlib import Path

from ..io.atomic import atomic_write

__all__ = ["markdown_table", "write_summary", "summary_figure", "build_summary_figure"]


def _num(value):
    return value if isinstance(value, (int, float)) and not isinstance(value, bool) else None


def _fmt(value, digits=3) -> str:
    v = _num(value)
    if v is None:
        return "" if value in (None, "") else str(value)
    return f"{v:.{digits}f}" if isinstance(v, float) else str(v)


def markdown_table(rows, target_names, swept_names) -> str:
    """One line per run: targets, swept values, objective, PCC and MARE (mm) per target, wall time, status."""
    swept = [n for n in swept_names if n != "actuators"]
    head = ["run", "targets", "actuators", *swept, "objective", *[f"PCC {t}" for t in target_names],
            *[f"MARE {t} (mm)" for t in target_names], "wall (s)", "status"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for i, r in enumerate(rows):
        mare = [_fmt(r[f"mare_{t}_m"] * 1e3, 2) if _num(r.get(f"mare_{t}_m")) is not None else ""
                for t in target_names]
        status = r.get("status", "")
        if status != "ok":
            status = f"{status}: {r.get('error', '')[:80]}"
        cells = [str(i), r.get("targets", ""), _fmt(r.get("actuators")), *[_fmt(r.get(n), 4) for n in swept],
                 _fmt(r.get("objective"), 4), *[_fmt(r.get(f"pcc_{t}")) for t in target_names], *mare,
                 _fmt(r.get("wall_s"), 1), status]
        lines.append("| " + " | ".join(c.replace("|", "/") for c in cells) + " |")
    return "\n".join(lines) + "\n"


# the three measures the figure shows: (row key, axis label, scale, higher is better)
def _measures(target_names):
    pcc = [(t, f"pcc_{t}", 1.0) for t in target_names]
    mare = [(t, f"mare_{t}_m", 1e3) for t in target_names]
    return [("PCC", pcc, True), ("MARE (mm)", mare, False), ("objective", [("all", "objective", 1.0)], False)]


def _value(row, key, scale):
    v = _num(row.get(key)) if row.get("status", "ok") == "ok" else None
    return None if v is None or not math.isfinite(v) else v * scale


def _worse(value, reference, higher_better: bool) -> bool:
    """``value`` worse than ``reference`` by more than a rounding (1e-9 relative)."""
    if value is None or reference is None:
        return False
    tol = 1e-9 * max(abs(value), abs(reference), 1e-12)
    return value < reference - tol if higher_better else value > reference + tol


WORSE_STYLE = dict(marker="x", color="red", markersize=11, markeredgewidth=2.0, linestyle="none", zorder=5)


def _alone_rows(rows, target_names):
    """Each target's run designed for it alone (the reference a subset's value is marked against)."""
    alone = {}
    for r in rows:
        names = str(r.get("targets", "")).split()  # a run's targets, space-separated (sweeps/run.py)
        if len(names) == 1 and names[0] in target_names and r.get("status") == "ok":
            alone[names[0]] = r
    return alone


def _subsets_table(ax, rows, target_names, label, cols, higher_better, alone):
    import numpy as np
    from matplotlib.patches import Rectangle

    grid = np.full((len(rows), len(cols)), np.nan)
    for i, r in enumerate(rows):
        for j, (_, key, scale) in enumerate(cols):
            v = _value(r, key, scale)
            grid[i, j] = np.nan if v is None else v
    finite = grid[np.isfinite(grid)]
    lo, hi = (float(finite.min()), float(finite.max())) if finite.size else (0.0, 1.0)
    if label == "PCC":
        lo, hi = min(lo, 0.9), 1.0
    cmap = "viridis" if higher_better else "viridis_r"
    ax.imshow(np.ma.masked_invalid(grid), cmap=cmap, vmin=lo, vmax=hi if hi > lo else lo + 1e-9, aspect="auto")
    worse = []
    for (i, j), v in np.ndenumerate(grid):
        if not math.isfinite(v):
            continue
        name, key, scale = cols[j]
        ref = alone.get(name)
        bad = ref is not None and ref is not rows[i] and _worse(float(v), _value(ref, key, scale), higher_better)
        dark = (v < 0.5 * (lo + hi)) == higher_better
        ax.text(j, i, f"{v:.3f}" if label != "MARE (mm)" else f"{v:.2f}", ha="center", va="center", fontsize=8,
                color="w" if dark else "k", fontweight="bold" if bad else "normal")
        if bad:
            ax.add_patch(Rectangle((j - 0.5, i - 0.5), 1, 1, fill=False, edgecolor="red", linewidth=2.0, zorder=5))
            worse.append((j, i))
    ax.set_xticks(range(len(cols)), [c[0] for c in cols])
    ax.set_yticks(range(len(rows)), [r["targets"] + ("" if r.get("status") == "ok" else " (failed)") for r in rows])
    ax.set_title(label)
    return worse


def _subsets_axes(fig, rows, target_names):
    """PCC and MARE by subset (rows) and target (columns), the mean objective beside them; a cell worse than
    the same target designed alone has a red box."""
    axes = fig.subplots(1, 3, gridspec_kw=dict(width_ratios=[len(target_names), len(target_names), 1]))
    alone = _alone_rows(rows, target_names)
    marked = {}
    for ax, (label, cols, higher_better) in zip(axes, _measures(target_names)):
        marked[label] = _subsets_table(ax, rows, target_names, label, cols, higher_better,
                                       alone if label != "objective" else {})
    axes[1].set_yticks([])
    axes[2].set_yticks([])
    note = "; red box: worse than the target designed alone" if any(marked.values()) else ""
    fig.suptitle(f"fit of each target by designed subset (PCC higher is better, MARE and objective lower{note})",
                 fontsize=9)
    fig.worse_marks = marked
    return axes


def _grid_panel(ax, groups, x_name, others, label, cols, higher_better):
    """One measure against ``x_name``, a line per target and per other swept values; each point worse than
    the one before it on its line (fewer of ``x_name``) gets a red cross. Returns the crosses (x, y)."""
    styles = ["-", "--", ":", "-."]
    worse = []
    for k, (key, rs) in enumerate(sorted(groups.items(), key=lambda kv: str(kv[0]))):
        rs = sorted(rs, key=lambda r: r[x_name])
        tag = ", ".join(f"{n}={v}" for n, v in zip(others, key))
        for j, (name, col, scale) in enumerate(cols):
            pts = [(r[x_name], _value(r, col, scale)) for r in rs if _value(r, col, scale) is not None]
            if not pts:
                continue
            xs, ys = zip(*pts)
            ax.plot(xs, ys, styles[k % len(styles)], marker="o", color=f"C{j}" if name != "all" else "k",
                    label=name + (f" ({tag})" if tag else ""))
            worse += [(x, y) for (_, y0), (x, y) in zip(pts, pts[1:]) if _worse(y, y0, higher_better)]
    if worse:
        wx, wy = zip(*worse)
        ax.plot(wx, wy, label=f"worse than at the smaller {x_name}", **WORSE_STYLE)
    ax.set_xlabel(x_name)
    ax.set_ylabel(label + " of the final design")
    ax.set_title(f"{label} by {x_name} ({'higher' if higher_better else 'lower'} is better)", fontsize=9)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
    return worse


def _grid_axes(fig, rows, target_names, swept_names):
    numeric = [n for n in swept_names if all(_num(r.get(n)) is not None for r in rows)]
    if not numeric:
        return _subsets_axes(fig, rows, target_names)
    x_name = numeric[0]
    others = [n for n in swept_names if n != x_name]
    axes = fig.subplots(1, 3)
    groups: dict = {}
    for r in rows:
        if r.get("status") == "ok":
            groups.setdefault(tuple(r.get(n) for n in others), []).append(r)
    fig.worse_marks = {label: _grid_panel(ax, groups, x_name, others, label, cols, hb)
                       for ax, (label, cols, hb) in zip(axes, _measures(target_names))}
    xs_all = sorted({float(r[x_name]) for rs in groups.values() for r in rs})
    if xs_all and all(x.is_integer() for x in xs_all):  # counts (actuators): ticks at the swept values only
        for ax in axes:
            ax.set_xticks(xs_all, [f"{x:g}" for x in xs_all])
    fig.suptitle(f"fit by {x_name}: PCC, MARE and the objective (red cross: worse than at the smaller {x_name})",
                 fontsize=9)
    return axes


def build_summary_figure(rows, target_names, swept_names, kind: str):
    """The sweep's matplotlib ``Figure``: Fig. 11 style (subsets sweep) or Fig. 12 style (grid sweep), each
    with PCC, MARE (mm) and the objective side by side, and the values that got worse marked in red
    (``fig.worse_marks``: per measure, the marked points)."""
    from matplotlib.figure import Figure

    height = 1.4 + 0.35 * len(rows) if kind == "subsets" else 4.2
    fig = Figure(figsize=(13.0, max(3.2, height)), dpi=120, layout="constrained")
    if kind == "subsets":
        _subsets_axes(fig, rows, target_names)
    else:
        _grid_axes(fig, rows, target_names, swept_names)
    return fig


def summary_figure(rows, target_names, swept_names, kind: str, path) -> Path:
    """``summary.png`` (and ``summary.svg`` beside it): ``build_summary_figure``."""
    fig = build_summary_figure(rows, target_names, swept_names, kind)
    buf = io.BytesIO()
    fig.savefig(buf, format="svg")
    atomic_write(Path(path).with_suffix(".svg"), buf.getvalue())
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=120)
    return atomic_write(path, buf.getvalue())


def write_summary(folder, rows, target_names, swept_names, kind: str) -> list[Path]:
    """``summary.md`` and (with matplotlib) ``summary.png`` in the sweep folder."""
    folder = Path(folder)
    title = "Subsets sweep" if kind == "subsets" else "Grid sweep"
    written = [atomic_write(folder / "summary.md", f"# {title}\n\n" + markdown_table(rows, target_names, swept_names))]
    try:
        png = summary_figure(rows, target_names, swept_names, kind, folder / "summary.png")
        written += [png, png.with_suffix(".svg")]
    except ImportError:
        print("summary figure skipped: matplotlib is not installed (pip install 'warp-shape[figures]')",
              file=sys.stderr)
    return written
