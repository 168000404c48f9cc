"""The figures of docs/calibration.md: the synthetic device of tests/test_calibration.py calibrated,
its held-out scan predicted, and each target of the default problem controlled on the default, the
calibrated and the true model and replayed on the device.

    .venv/bin/python scripts/measure_calibration.py [--seed 1] [--noise-mm 0.3] [--method paper|inverse]
        [--no-readings] [--inverse-tolerance T]
    .venv/bin/python scripts/measure_calibration.py --devices 10 11 12   # devices perturbed in random directions
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

import test_calibration as tc  # noqa: E402

import warp_shape as ws  # noqa: E402
from warp_shape.calibration import ControlState, apply_values, replay_held, scan_residuals  # noqa: E402
from warp_shape.model import host_model  # noqa: E402


def random_device(seed: int, readings: bool) -> None:
    """One device with E t x0.7 or x1.3, bending x0.5 or x1.5, each IPAM's k and A x U(0.8, 1.2), rest scale
    x0.98 or x1.02 (the signs drawn), scanned at the test's states; the largest error per parameter, the
    largest |z|, the held-out scan's RMS."""
    rng = np.random.default_rng(seed)
    d = tc.cube_fig6_design(subdivisions=2)
    k0, a0 = (np.array([getattr(ip, n) for ip in d.ipams]) for n in ("stiffness", "area"))
    sign = lambda: rng.choice([-1.0, 1.0])  # noqa: E731
    truth = dict(youngs_modulus=d.material.youngs_modulus * (1 + 0.3 * sign()),
                 bending_stiffness=d.material.bending_stiffness * (1 + 0.5 * sign()),
                 ipam_stiffness=k0 * (1 + rng.uniform(-0.2, 0.2, 5)), ipam_area=a0 * (1 + rng.uniform(-0.2, 0.2, 5)),
                 rest_scale=1 + 0.02 * sign())
    device = apply_values(d, truth)
    n = host_model(d).rest_air
    states = [ControlState(n * air, tuple(1e3 * p for p in kpa)) for air, kpa in tc.STATES]
    probe = [ws.ScanObservation(np.random.default_rng(0).random((60, 3)) * 0.05, s) for s in states]
    shapes, pressures = replay_held(device, [o.sequence(device) for o in probe], pressures=True)
    scans = [tc.scan_of(device.rest.copy_with(x), rng) for x in shapes]
    read = pressures + rng.normal(0.0, tc.PRESSURE_NOISE, len(pressures))
    obs = [ws.ScanObservation(p, s, name=f"s{i}", **(dict(pressure=r, pressure_stderr=tc.PRESSURE_NOISE)
                                                       if readings else {}))
           for i, (p, s, r) in enumerate(zip(scans, states, read))]
    t = time.perf_counter()
    cal = ws.calibrate(d, obs[:3])
    errs, zs = {}, {}
    for name, tr in truth.items():
        v, se = np.atleast_1d(cal.values[name]), np.atleast_1d(cal.stderr[name])
        tr = np.broadcast_to(tr, v.shape)
        errs[name] = round(100 * float(np.max(np.abs(v / tr - 1))), 2)
        zs[name] = round(float(np.max(np.abs((v - tr) / se))), 2)
    held = scan_residuals(cal.design, obs[3]).rms_mm
    print(f"device {seed} ({time.perf_counter() - t:.0f} s): truth / start "
          f"{ {k: round(float(np.mean(np.atleast_1d(truth[k]) / np.atleast_1d(cal.start[k]))), 3) for k in truth} }")
    print(f"   largest |error| %: {errs}; largest |z|: {zs}; held-out {held:.3f} mm; realigned {cal.realigned}")


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--noise-mm", type=float, default=0.3)
    ap.add_argument("--method", default="inverse")
    ap.add_argument("--no-readings", action="store_true", help="scans without chamber pressure readings")
    ap.add_argument("--inverse-tolerance", type=float, default=None, help="the inverse controller's tolerance")
    ap.add_argument("--devices", type=int, nargs="+", default=None, metavar="SEED",
                    help="calibrate devices perturbed in random directions (the issue's ranges) instead")
    args = ap.parse_args()
    tc.NOISE = args.noise_mm * 1e-3
    if args.devices:
        for seed in args.devices:
            random_device(seed, readings=not args.no_readings)
        return
    t = time.perf_counter()
    dev = tc.Device(seed=args.seed, readings=not args.no_readings)
    print(f"device built and calibrated in {time.perf_counter() - t:.1f} s; {dev.cal.iterations} iterations, "
          f"{dev.cal.jacobians} Jacobians, converged {dev.cal.converged}")
    print(f"{'parameter':<22}{'true/start':>11}{'fitted err %':>13}{'stderr %':>10}{'z':>7}")
    for name, truth in dev.truth.items():
        v, se, s0 = (np.atleast_1d(np.asarray(x, float)) for x in (dev.cal.values[name], dev.cal.stderr[name],
                                                                    dev.cal.start[name]))
        truth = np.broadcast_to(truth, v.shape)
        for i in range(len(v)):
            label = name if len(v) == 1 else f"{name}[{i}]"
            print(f"{label:<22}{truth[i] / s0[i]:11.3f}{100 * (v[i] / truth[i] - 1):13.2f}"
                  f"{100 * se[i] / v[i]:10.2f}{(v[i] - truth[i]) / se[i]:7.2f}")
    print("unidentifiable:", dev.cal.unidentifiable, "poorly determined:", dev.cal.poorly_determined)
    print("residual mm before:", np.round(dev.cal.initial_residual_mm, 3), "after:", np.round(dev.cal.residual_mm, 3))
    before = scan_residuals(dev.design, dev.obs[3]).rms_mm
    after = scan_residuals(dev.cal.design, dev.obs[3]).rms_mm
    print(f"held-out scan: {before:.3f} mm default, {after:.3f} mm calibrated ({after / args.noise_mm:.2f} x noise)")
    extra = {} if args.inverse_tolerance is None else {"inverse_tolerance": args.inverse_tolerance}
    settings = ws.ControlSettings(method=args.method, **extra)
    models = (("default", dev.design), ("calibrated", dev.cal.design), ("true", dev.device))
    for name in ("oval", "heart"):
        target = ws.target(name)
        row = []
        for label, model in models:
            res = ws.control(model, target, settings=settings)
            plan = (res.refinement or {}).get("plan", "-")
            row.append(f"{label} {tc._objective_on(dev.device, res, target):.5f} (plan {plan})")
        print(f"{name}: objective on the device of the {args.method} sequence controlled on the " + ", ".join(row))

if __name__ == "__main__":
    main()
