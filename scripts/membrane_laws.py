"""The membrane law in use (docs/membrane.md, "Designs and calibration with each law"): problems designed
with the springs and with the neo-Hookean membrane, and a device simulated with the neo-Hookean law
calibrated by each law.

    nice -n 10 .venv/bin/python scripts/membrane_laws.py designs [--problems default egg+peanut ...]
    nice -n 10 .venv/bin/python scripts/membrane_laws.py calibration [--seed 1]
    nice -n 10 .venv/bin/python scripts/membrane_laws.py compression

``designs``: each problem designed by ``ws.design`` with ``codesign="off"`` (as measured while co-design
refused a hyperelastic membrane) once per law, the runs alternating, after every kernel of both laws is compiled
(``warm_up``: a worker process otherwise compiles the triangle kernel inside the first timed run); for each, the wall time, how far the IPAMs'
ends moved (each IPAM's end faces against the nearest IPAM of the other law's design, on the rest
shape), the cells kept, and per target the fit (MARE, each against its own law's model) and the IPAM
pressures. The default problem is the shipped oval_heart scene as ``warp-shape design`` runs it
(642 vertices); the generated problems (benchmarks/generated_shapes.py) start from a 162-vertex sphere
with 3 IPAMs.

``calibration``: the 162-vertex Fig. 6 device of tests/test_calibration.py built with the neo-Hookean
membrane (mu 1.3 x E / 3, each IPAM's k -10..-20 % and A +10..+20 %, rest scale +2 %), scanned at the
test's four states (0.3 mm noise, 60 % coverage, random pose, chamber pressure read), the first three
fitted and the fourth held out, calibrated by the springs model (``DEFAULT_WRT``) and by the neo-Hookean
model (``HYPERELASTIC_WRT``).

``compression``: the 642-vertex Fig. 6 device with the neo-Hookean membrane at 1.2, 1.0 and 0.9 x its
rest air and every IPAM at 250 kPa, settled statically in float64 with the solid sheet and with the tension field
(``Material.compression``): the triangles in compression, wrinkled and slack, and how far the two
shapes lie apart. Prints the tables and writes out/membrane_laws/<part>.json.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT / "tests"), str(ROOT / "benchmarks")]

import warp_shape as ws  # noqa: E402
from warp_shape.calibration import (DEFAULT_WRT, HYPERELASTIC_WRT, ControlState, apply_values,  # noqa: E402
                                    replay_held)
from warp_shape.designer import design  # noqa: E402
from warp_shape.designer.run_settings import RunSettings  # noqa: E402
from warp_shape.io.atomic import atomic_write  # noqa: E402
from warp_shape.io.scene_read import load_scene  # noqa: E402
from warp_shape.model import host_model  # noqa: E402
from warp_shape.scenarios import cube_fig6_design  # noqa: E402

LAWS = ("springs", "neo_hookean")
OUT = ROOT / "out" / "membrane_laws"


def _material(material, law: str):
    return replace(material or ws.Material(), membrane=law, yeoh_c2=0.0, yeoh_c3=0.0)


def _problem(name: str):
    """(base, targets, names, settings kwargs) of a problem: "default" or generated names joined by +."""
    if name == "default":
        scene = load_scene("oval_heart")
        run = RunSettings.from_groups(scene.settings)
        material = scene.design.material if scene.design is not None else None
        return (scene.base_mesh(), list(scene.targets), list(scene.target_names), material,
                dict(actuators=run.actuators, settings=run.designer.replace(codesign="off"),
                     control_settings=run.control))
    from generated_shapes import shape

    names = name.split("+")
    return (ws.icosphere(2, 0.035), [shape(n, subdivisions=3) for n in names], names, None,
            dict(actuators=3, codesign="off"))


def _ends(d) -> np.ndarray:
    """(n_ipam, 2, 3) the rest-shape centroids of each IPAM's end faces."""
    c = d.rest.face_centroids()
    return np.array([[c[ip.face_a], c[ip.face_b]] for ip in d.ipams]).reshape(-1, 2, 3)


def _ipam_distance(a, b) -> float:
    """Mean over the IPAMs of ``a`` of the distance (mm, both ends) to the nearest IPAM of ``b``."""
    ea, eb = _ends(a), _ends(b)
    if not len(ea) or not len(eb):
        return float("nan")
    out = []
    for e in ea:
        same = np.linalg.norm(eb - e, axis=2).mean(axis=1)
        flip = np.linalg.norm(eb[:, ::-1] - e, axis=2).mean(axis=1)
        out.append(min(same.min(), flip.min()))
    return 1e3 * float(np.mean(out))


def warm_up() -> None:
    """Every kernel of both laws compiled (and cached on disk for the worker processes) before any timing."""
    for law in LAWS:
        d = cube_fig6_design(subdivisions=1)
        for precision in ("float32", "float64"):
            sim = ws.Simulator(d.replace(material=_material(d.material, law)), precision=precision)
            sim.air_moles = 1.3 * sim.air_moles
            sim.step(2)
            sim.settle_static()


def designs(problems) -> dict:
    warm_up()
    rows = []
    for name in problems:
        base, targets, names, material, kw = _problem(name)
        runs = {}
        for law in LAWS:
            t0 = time.perf_counter()
            res = design(base, targets, target_names=names, material=_material(material, law), **kw)
            runs[law] = (time.perf_counter() - t0, res)
            print(f"{name} {law}: {runs[law][0]:.0f} s", flush=True)
        (ts, s), (tn, n) = runs["springs"], runs["neo_hookean"]
        same = len({(ip.face_a, ip.face_b) for ip in s.design.ipams} & {(ip.face_a, ip.face_b) for ip in n.design.ipams})
        row = dict(problem=name, vertices=base.n_vertices, seconds=[ts, tn], ipams=[s.design.n_ipams, n.design.n_ipams],
                   cells=[s.design.n_cells, n.design.n_cells], same_ipams=same,
                   ipam_end_distance_mm=max(_ipam_distance(s.design, n.design), _ipam_distance(n.design, s.design)),
                   targets=[])
        for t, rs, rn in zip(names, s.results, n.results):
            row["targets"].append(dict(target=t, mare_mm=[1e3 * rs.mare, 1e3 * rn.mare],
                                       pressures_kpa=[(rs.ipam_pressures / 1e3).round(1).tolist(),
                                                      (rn.ipam_pressures / 1e3).round(1).tolist()]))
        rows.append(row)
        _print_designs(rows)  # each problem as it finishes (a run takes minutes)
        _write("designs", dict(designs=rows))
    return dict(designs=rows)


def _write(part: str, data: dict) -> None:
    OUT.mkdir(parents=True, exist_ok=True)
    atomic_write(OUT / f"{part}.json", json.dumps(data, indent=2))


def _print_designs(rows) -> None:
    print("\n| problem | vertices | time springs / neo-Hookean (s) | IPAMs | cells | same IPAMs | IPAM ends apart (mm) |")
    print("|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['problem']} | {r['vertices']} | {r['seconds'][0]:.0f} / {r['seconds'][1]:.0f} "
              f"({r['seconds'][1] / r['seconds'][0]:.2f}x) | {r['ipams'][0]} / {r['ipams'][1]} | "
              f"{r['cells'][0]} / {r['cells'][1]} | {r['same_ipams']} | {r['ipam_end_distance_mm']:.1f} |")
    print("\n| problem | target | MARE springs (mm) | MARE neo-Hookean (mm) | IPAM kPa springs | IPAM kPa neo-Hookean |")
    print("|---|---|---|---|---|---|")
    for r in rows:
        for t in r["targets"]:
            print(f"| {r['problem']} | {t['target']} | {t['mare_mm'][0]:.3f} | {t['mare_mm'][1]:.3f} | "
                  f"{' '.join(f'{p:.0f}' for p in t['pressures_kpa'][0])} | "
                  f"{' '.join(f'{p:.0f}' for p in t['pressures_kpa'][1])} |")


def _device(seed: int):
    """(model design with the neo-Hookean law, the device, truth, observations: 3 fitted + 1 held out)."""
    import test_calibration as tc

    rng = np.random.default_rng(seed)
    d = cube_fig6_design(subdivisions=2)
    neo = d.replace(material=_material(d.material, "neo_hookean"))
    k0, a0 = (np.array([getattr(ip, n) for ip in d.ipams]) for n in ("stiffness", "area"))
    truth = dict(shear_modulus=1.3 * neo.material.mu, ipam_stiffness=k0 * rng.uniform(0.8, 0.9, 5),
                 ipam_area=a0 * rng.uniform(1.1, 1.2, 5), rest_scale=1.02)
    device = apply_values(neo, truth)
    n = host_model(d).rest_air
    states = [ControlState(n * air, tuple(1e3 * p for p in kpa)) for air, kpa in tc.STATES]
    probe = [ws.ScanObservation(np.random.default_rng(0).random((60, 3)) * 0.05, s) for s in states]
    shapes, pressures = replay_held(device, [o.sequence(device) for o in probe], pressures=True)
    obs = []
    for i, (x, s, p) in enumerate(zip(shapes, states, pressures)):
        obs.append(ws.ScanObservation(tc.scan_of(device.rest.copy_with(x), rng), s, name=f"s{i}",
                                      pressure=float(p + rng.normal(0.0, tc.PRESSURE_NOISE)),
                                      pressure_stderr=tc.PRESSURE_NOISE, held_out=i == len(states) - 1))
    return d, neo, truth, obs


def calibration(seed: int) -> dict:
    springs, neo, truth, obs = _device(seed)
    rows = []
    for law, model, wrt in (("springs", springs, DEFAULT_WRT), ("neo_hookean", neo, HYPERELASTIC_WRT)):
        t0 = time.perf_counter()
        cal = ws.calibrate(model, obs, wrt=wrt)
        held = cal.held_out[0]
        rows.append(dict(law=law, wrt=list(wrt), seconds=time.perf_counter() - t0,
                         initial_mm=list(cal.initial_residual_mm), fitted_mm=list(cal.residual_mm),
                         held_out_before_mm=held[1], held_out_after_mm=held[2], flags=list(cal.flags),
                         values={k: np.asarray(v).tolist() for k, v in cal.values.items()}))
        print(f"{law}: {rows[-1]['seconds']:.0f} s", flush=True)
    print(f"\ndevice: neo-Hookean, mu = {truth['shear_modulus']:.0f} Pa (model start {neo.material.mu:.0f}); "
          f"scanner noise 0.30 mm")
    print("| calibrated by | fitted scans RMS (mm), start -> fitted | held-out scan RMS (mm), start -> calibrated |")
    print("|---|---|---|")
    for r in rows:
        print(f"| {r['law']} | {' '.join(f'{a:.3f}' for a in r['initial_mm'])} -> "
              f"{' '.join(f'{a:.3f}' for a in r['fitted_mm'])} | "
              f"{r['held_out_before_mm']:.3f} -> {r['held_out_after_mm']:.3f} |")
    mu = rows[1]["values"].get("shear_modulus")
    if mu is not None:
        print(f"neo-Hookean fit: mu = {mu:.0f} Pa ({100 * (mu / truth['shear_modulus'] - 1):+.1f} % of the truth)")
    return dict(truth={k: np.asarray(v).tolist() for k, v in truth.items()}, calibration=rows)


def _settle(d, mode: str, air: float, kpa: float):
    """(positions (V, 3), row) of the neo-Hookean device ``d`` settled with ``mode`` at ``air`` x its rest air,
    every IPAM at ``kpa``."""
    from warp_shape.physics.membrane import principal_stretches_np

    dm = d.replace(material=replace(_material(d.material, "neo_hookean"), compression=mode))
    sim = ws.Simulator(dm, precision="float64")
    sim.air_moles = air * host_model(dm).rest_air
    sim.ipam_pressures = np.full(dm.n_ipams, 1e3 * kpa)
    eq = sim.settle_static()
    x = np.asarray(sim.positions, dtype=np.float64).reshape(-1, 3)
    h = host_model(dm).actuators["membrane"]
    s = principal_stretches_np(x[None], h["faces"], h["rest"])[0]
    slack = s[:, 1] <= 1.0
    margin = s[:, 0] * np.sqrt(s[:, 1])  # below 1: the minor stress is compressive (the tension field wrinkles it)
    return x, dict(air=air, kpa=kpa, compression=mode, converged=bool(np.all(eq.converged)),
                   compressed_pct=100 * float(np.mean(s[:, 0] < 1.0)), least_stretch=float(s[:, 0].min()),
                   least_margin=float(margin.min()), wrinkled_pct=100 * float(np.mean(~slack & (margin < 1.0))),
                   slack_pct=100 * float(slack.mean()), pressure_pa=float(sim.pressure()))


def compression(states=((1.2, 250.0), (1.0, 250.0), (0.9, 250.0))) -> dict:
    d = cube_fig6_design(subdivisions=3)
    rows = []
    for air, kpa in states:
        xs, rs = _settle(d, "solid", air, kpa)
        xt, rt = _settle(d, "tension_field", air, kpa)
        dist = np.linalg.norm(xs - xt, axis=1)
        rows += [rs, dict(rt, rms_mm=1e3 * float(np.sqrt(np.mean(dist ** 2))), max_mm=1e3 * float(dist.max()))]
    print("\n| air x rest | compression | converged | l2 < 1 | least l2 | least l2 l1^1/2 | wrinkled | slack | "
          "pressure (Pa) | apart RMS / max (mm) |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        apart = f"{r['rms_mm']:.3f} / {r['max_mm']:.3f}" if "rms_mm" in r else ""
        print(f"| {r['air']} | {r['compression']} | {r['converged']} | {r['compressed_pct']:.0f} % | "
              f"{r['least_stretch']:.2f} | {r['least_margin']:.3f} | {r['wrinkled_pct']:.1f} % | {r['slack_pct']:.1f} % | "
              f"{r['pressure_pa']:.0f} | {apart} |")
    return dict(rows=rows)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("part", choices=["designs", "calibration", "compression"])
    ap.add_argument("--problems", nargs="+", default=["default", "egg+peanut", "tilted_ellipsoid+puck"])
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args()
    out = (designs(args.problems) if args.part == "designs" else calibration(args.seed) if args.part == "calibration"
           else compression())
    _write(args.part, out)


if __name__ == "__main__":
    main()
