"""The model-based controller measured against the paper's law (run from the repository root):

    .venv/bin/python benchmarks/inverse_report.py [--out out] [--device cpu] [--skip-ten]

1. Fig. 6 (642 vertices) to the cube, ``method="paper"`` and ``method="inverse"``: objective, PCC,
   MARE, MPRE, final pressures, saturation, wall time, and every jam plan's fit before and after
   refining;
2. what the 300 kPa pressure limit costs: the same with 450 and 600 kPa limits;
3. ten targets (the four shipped, the six generated in tests/generated_shapes.py) with the Fig. 6
   design, paper vs inverse objective and MARE.
Prints the tables and writes ``<out>/inverse_report.json``.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

import warp_shape as ws
from warp_shape.benchmarks.sim import format_rows
from warp_shape.controller import control_many
from warp_shape.io.atomic import write_json
from warp_shape.scenarios import cube_fig6_design

__all__ = ["main"]

FIT_COLUMNS = ["method", "limit_kpa", "objective", "pcc", "mare_mm", "mpre_pct", "pressures_kpa", "saturated",
               "plan", "wall_s"]


def _with_limit(design: ws.Design, high: float) -> ws.Design:
    d = ws.Design(design.rest, design.material)
    for ip in design.ipams:
        d.add_ipam(ip.face_a, ip.face_b, pressure_limits=(ip.pressure_limits[0], high))
    for cell in design.cells:
        d.add_cell(cell.faces)
    return d


def _row(method: str, limit: float, res, wall: float) -> dict:
    info = res.refinement or {}
    plan = ("paper (kept)" if info.get("fell_back") else info.get("plan", "")) if info else ""
    return dict(method=method, limit_kpa=f"{limit / 1e3:.0f}", objective=f"{res.objective:.5f}",
                pcc=f"{res.pcc:.4f}", mare_mm=f"{res.mare * 1e3:.3f}", mpre_pct=f"{res.mpre:.2f}",
                pressures_kpa=" ".join(f"{p / 1e3:.0f}" for p in res.ipam_pressures),
                saturated="; ".join(info.get("saturated", [])) or "-", plan=plan, wall_s=f"{wall:.1f}")


def _timed(design, targets, method, **overrides):
    t0 = time.perf_counter()
    res = control_many(design, targets, method=method, **overrides)
    return res, time.perf_counter() - t0


def fig6_rows(device_limits=(300e3, 450e3, 600e3)) -> tuple[list[dict], list[dict]]:
    """Fit rows (paper and inverse per pressure limit) and the jam-plan rows of the 300 kPa run."""
    base = cube_fig6_design(subdivisions=3)
    cube = ws.target("cube")
    rows, plans = [], []
    for limit in device_limits:
        d = base if limit == 300e3 else _with_limit(base, limit)
        (paper,), tp = _timed(d, [cube], "paper")
        (inv,), ti = _timed(d, [cube], "inverse")
        rows += [_row("paper", limit, paper, tp), _row("inverse", limit, inv, ti)]
        if limit == 300e3:  # the air and the pressures alone, the paper's jam times kept
            (alone,), ta = _timed(d, [cube], "inverse", inverse_plans="paper")
            rows.append(_row("inverse, paper jams", limit, alone, ta))
        info = inv.refinement
        for name in info["plans"]:
            plans.append(dict(limit_kpa=f"{limit / 1e3:.0f}", plan=name,
                              objective_before=f"{info['plans_before'][name]:.5f}",
                              objective_after=f"{info['plans'][name]:.5f}",
                              mare_after_mm=f"{info['plans_mare'][name] * 1e3:.3f}",
                              mare_vs_paper=f"{info['plans_mare'][name] / paper.mare:.2f}"))
    return rows, plans


def ten_rows() -> list[dict]:
    """Paper vs inverse on the four shipped and six generated targets (Fig. 6 design, 642 vertices)."""
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
    from generated_shapes import NAMES, shape

    names = list(ws.TARGET_NAMES) + list(NAMES)
    targets = [ws.target(n) for n in ws.TARGET_NAMES] + [shape(n) for n in NAMES]
    d = cube_fig6_design(subdivisions=3)
    paper, tp = _timed(d, targets, "paper")
    inv, ti = _timed(d, targets, "inverse")
    rows = []
    for n, p, q in zip(names, paper, inv):
        op, oq = p.objective, q.objective
        rows.append(dict(target=n, paper_objective=f"{op:.5f}", inverse_objective=f"{oq:.5f}",
                         objective_ratio=f"{oq / op:.3f}", paper_mare_mm=f"{p.mare * 1e3:.3f}",
                         inverse_mare_mm=f"{q.mare * 1e3:.3f}", mare_ratio=f"{q.mare / p.mare:.3f}",
                         plan="paper (kept)" if q.refinement["fell_back"] else q.refinement["plan"]))
    ratio = np.array([float(r["objective_ratio"]) for r in rows])
    rows.append(dict(target="mean", objective_ratio=f"{ratio.mean():.3f}",
                     mare_ratio=f"{np.mean([float(r['mare_ratio']) for r in rows]):.3f}",
                     paper_objective=f"{np.mean([p.objective for p in paper]):.5f}",
                     inverse_objective=f"{np.mean([q.objective for q in inv]):.5f}",
                     plan=f"paper {tp:.0f} s, inverse {ti:.0f} s (10 targets in one batch)"))
    return rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="out")
    ap.add_argument("--skip-ten", action="store_true", help="leave out the ten-target table (the longest part)")
    args = ap.parse_args(argv)
    rows, plans = fig6_rows()
    print("Fig. 6 (642 vertices) to the cube: the paper's law vs model-based control, by IPAM pressure limit")
    print(format_rows(rows, FIT_COLUMNS))
    print("\njam plans of the model-based controller (objective before and after refining the controls)")
    print(format_rows(plans, list(plans[0])))
    out = dict(fig6=rows, plans=plans)
    if not args.skip_ten:
        ten = ten_rows()
        print("\nten targets, Fig. 6 design (642 vertices): paper vs inverse")
        print(format_rows(ten, list(ten[0])))
        out["ten_targets"] = ten
    print(f"written {write_json(Path(args.out) / 'inverse_report.json', out)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
