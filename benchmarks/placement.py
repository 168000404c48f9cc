"""Placement benchmark: the paper's Algorithm 1 against the simulated placement on the shipped cases.

``python -m warp_shape.benchmarks.placement CASE --placement paper|simulated|greedy [--candidates K] --out DIR``
designs CASE and writes ``DIR/placement_<CASE>_<placement>.json``: wall time, the objective, PCC, MARE
and MPRE of every target after every round, the actuators placed (ends, the target each was placed
for, rest-shape angle, how many ends sit at a cube corner), and the placement record (every
candidate's scores per round, the start against the rest shape, an early stop).

Cases: ``oval``, ``pear``, ``heart``, ``cube`` (single-target mode as in the paper's Figs. 7-8: a
spherical 642-vertex rest shape kept as it is, 5 IPAMs) and the shipped scenes ``oval_heart``,
``four_targets_5``, ``four_targets_20`` (their own rest mesh, actuators and cell radius).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
import warp as wp

import warp_shape as ws
from warp_shape.designer import DesignSettings, design
from warp_shape.io.atomic import atomic_write
from warp_shape.io.scene_read import load_scene

SINGLE = ("oval", "pear", "heart", "cube")
SCENES = ("oval_heart", "four_targets_5", "four_targets_20")
CASES = SINGLE + SCENES

__all__ = ["CASES", "run_case", "corner_ends", "main"]


def corner_ends(design, cell_radius: float) -> list[int]:
    """Per IPAM, how many of its two ends lie within ``cell_radius`` (arc on the rest shape) of a cube
    corner direction (+-1, +-1, +-1)/sqrt(3) (Fig. 8: the cube's first four IPAMs join opposite corners)."""
    corners = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float) / np.sqrt(3.0)
    c = design.rest.face_centroids()
    radius = np.linalg.norm(c, axis=1)
    u = c / radius[:, None]
    out = []
    for ip in design.ipams:
        n = 0
        for f in (ip.face_a, ip.face_b):
            arc = radius[f] * np.arccos(np.clip((corners @ u[f]).max(), -1.0, 1.0))
            n += int(arc < cell_radius)
        out.append(n)
    return out


def _problem(case: str):
    if case in SINGLE:
        return ws.icosphere(3, 0.035), [case], [ws.target(case)], dict(actuators=5, initialize=False)
    sc = load_scene(case)
    opts = sc.settings["designer"]
    return sc.design.rest, list(sc.target_names), sc.targets, dict(actuators=int(opts["actuators"]),
                                                                   cell_radius=float(opts["cell_radius"]))


def run_case(case: str, placement: str, candidates: int | None = None, device: str = "cpu", on_round=None) -> dict:
    """Design ``case`` with ``placement``; the JSON-ready record described in the module docstring."""
    if case not in CASES:
        raise SystemExit(f"unknown case {case!r}; choose one of {', '.join(CASES)}")
    base, names, targets, opts = _problem(case)
    actuators = opts.pop("actuators")
    K = DesignSettings().candidates if candidates is None else int(candidates)
    t0 = time.perf_counter()
    res = design(base, targets, actuators=actuators, target_names=names, device=device, placement=placement,
                 candidates=K, on_round=on_round, **opts)
    wall = time.perf_counter() - t0
    cell_radius = res.settings.cell_radius
    by_round = {key: [[float(getattr(r, attr)) for r in rs] for rs in res.rounds]
                for key, attr in (("objective", "objective"), ("pcc", "pcc"), ("mare_m", "mare"), ("mpre_pct", "mpre"))}
    corners = corner_ends(res.design, cell_radius)
    added = [dict(round=a["round"], placed_for=names[a["target"]], face_a=a["face_a"], face_b=a["face_b"],
                  passive_for=a.get("passive_for", []),
                  rest_angle_deg=a.get("rest_angle_deg"), corner_ends=corners[k],
                  passive_for=a.get("passive_for", [])) for k, a in enumerate(res.added)]
    return dict(case=case, placement=placement, candidates=K if placement != "paper" else None, device=device,
                targets=names, actuators_requested=actuators, actuators=res.design.n_ipams, wall_s=wall,
                vertices=res.design.rest.n_vertices, cell_radius=cell_radius, by_round=by_round,
                final={key: v[-1] for key, v in by_round.items()}, added=added,
                cube_corner_ends_first4=sum(corners[:4]) if "cube" in names else None,
                placement_record=res.placement)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m warp_shape.benchmarks.placement", description=__doc__.splitlines()[0])
    p.add_argument("case", choices=CASES)
    p.add_argument("--placement", choices=["paper", "simulated", "greedy"], default="simulated")
    p.add_argument("--candidates", type=int, default=None, help="K (simulated: holds per target per refinement "
                   "round; greedy: candidate sets per round)")
    p.add_argument("--device", default="cpu")
    p.add_argument("--out", default="out")
    args = p.parse_args(argv)
    wp.config.quiet = True
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    path = out / f"placement_{args.case}_{args.placement}.json"
    t0 = time.perf_counter()

    partial = dict(case=args.case, placement=args.placement, complete=False, by_round=[])

    def on_round(i, d_i, results):  # progress and a partial record, so a long case keeps the rounds it finished
        partial["by_round"].append(dict(round=i, ipams=d_i.n_ipams, wall_s=time.perf_counter() - t0,
                                        **{k: [float(getattr(r, a)) for r in results] for k, a in
                                           (("objective", "objective"), ("pcc", "pcc"), ("mare_m", "mare"),
                                            ("mpre_pct", "mpre"))}))
        atomic_write(out / f"placement_{args.case}_{args.placement}.partial.json", json.dumps(partial, indent=1))
        print(f"{args.case} {args.placement}: round {i} done at {time.perf_counter() - t0:.0f} s, objective "
              + " ".join(f"{r.objective:.4f}" for r in results), flush=True)

    rec = run_case(args.case, args.placement, args.candidates, args.device, on_round=on_round)
    atomic_write(path, json.dumps(rec, indent=1))
    f = rec["final"]
    print(f"{args.case} {args.placement}: {rec['actuators']} IPAMs, {rec['wall_s']:.1f} s, objective "
          + " ".join(f"{v:.4f}" for v in f["objective"]) + f"; written {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
