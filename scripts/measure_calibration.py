"""The figures of docs/calibration.md: the synthetic device of tests/test_calibration.py calibrated,
its held-out scan predicted, and each target of the default problem controlled on the default, the
calibrated and the true model and replayed on the device.

    .venv/bin/python scripts/measure_calibration.py [--seed 1] [--noise-mm 0.3] [--method paper|inverse]
        [--no-readings] [--inverse-tolerance T]
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
from warp_shape.calibration import scan_residuals  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--noise-mm", type=float, default=0.3)
    ap.add_argument("--method", default="inverse")
    ap.add_argument("--no-readings", action="store_true", help="scans without chamber pressure readings")
    ap.add_argument("--inverse-tolerance", type=float, default=None, help="the inverse controller's tolerance")
    args = ap.parse_args()
    tc.NOISE = args.noise_mm * 1e-3
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
