"""A sweep's summary: ``summary.md`` (a Markdown table) and ``summary.png`` (the fit by subset or by setting).

The figure follows the paper: for a subsets sweep (Fig. 11) a table of subsets (rows) by targets
(columns) coloured by the PCC each target reaches with that subset's design; for a grid sweep
(Fig. 12) each target's PCC against the first numeric swept parameter (e.g. the actuator count), one
line per target and per combination of the other swept values. matplotlib is imported lazily; without
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


def _subsets_axes(fig, rows, target_names):
    import numpy as np

    ax = fig.add_subplot(1, 1, 1)
    grid = np.full((len(rows), len(target_names)), np.nan)
    for i, r in enumerate(rows):
        for j, t in enumerate(target_names):
            if _num(r.get(f"pcc_{t}")) is not None:
                grid[i, j] = r[f"pcc_{t}"]
    finite = grid[np.isfinite(grid)]
    lo = float(finite.min()) if finite.size else 0.0
    im = ax.imshow(np.ma.masked_invalid(grid), cmap="viridis", vmin=min(lo, 0.9), vmax=1.0, aspect="auto")
    for (i, j), v in np.ndenumerate(grid):
        if math.isfinite(v):
            ax.text(j, i, f"{v:.3f}", ha="center", va="center", fontsize=8, color="w" if v < 0.5 * (lo + 1) else "k")
    ax.set_xticks(range(len(target_names)), target_names)
    ax.set_yticks(range(len(rows)), [r["targets"] + ("" if r.get("status") == "ok" else " (failed)") for r in rows])
    ax.set_xlabel("target")
    ax.set_title("fit (PCC) of each target by designed subset")
    fig.colorbar(im, ax=ax, label="PCC")


def _grid_axes(fig, rows, target_names, swept_names):
    numeric = [n for n in swept_names if all(_num(r.get(n)) is not None for r in rows)]
    if not numeric:
        return _subsets_axes(fig, rows, target_names)
    x_name = numeric[0]
    others = [n for n in swept_names if n != x_name]
    ax = fig.add_subplot(1, 1, 1)
    groups: dict = {}
    for r in rows:
        if r.get("status") == "ok":
            groups.setdefault(tuple(r.get(n) for n in others), []).append(r)
    styles = ["-", "--", ":", "-."]
    for k, (key, rs) in enumerate(sorted(groups.items(), key=lambda kv: str(kv[0]))):
        rs = sorted(rs, key=lambda r: r[x_name])
        tag = ", ".join(f"{n}={v}" for n, v in zip(others, key))
        for j, t in enumerate(target_names):
            pts = [(r[x_name], r[f"pcc_{t}"]) for r in rs if _num(r.get(f"pcc_{t}")) is not None]
            if pts:
                xs, ys = zip(*pts)
                ax.plot(xs, ys, styles[k % len(styles)], marker="o", color=f"C{j}",
                        label=t + (f" ({tag})" if tag else ""))
    xs_all = sorted({float(r[x_name]) for rs in groups.values() for r in rs})
    if xs_all and all(x.is_integer() for x in xs_all):  # counts (actuators): ticks at the swept values only
        ax.set_xticks(xs_all, [f"{x:g}" for x in xs_all])
    ax.set_xlabel(x_name)
    ax.set_ylabel("PCC of the final design")
    ax.set_title(f"fit by {x_name}")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)


def build_summary_figure(rows, target_names, swept_names, kind: str):
    """The sweep's matplotlib ``Figure``: Fig. 11 style (subsets sweep) or Fig. 12 style (grid sweep)."""
    from matplotlib.figure import Figure

    height = 1.2 + 0.35 * len(rows) if kind == "subsets" else 4.0
    fig = Figure(figsize=(6.5, max(3.0, height)), dpi=120, layout="constrained")
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
