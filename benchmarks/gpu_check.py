"""The device check: the CUDA tests, the batched-worlds step bench and the design bench on one device,
gathered into one JSON file and one Markdown table (run by ``scripts/gpu_check.sh``; docs/gpu.md).

    python -P -m warp_shape.benchmarks.gpu_check --device cuda:0 --out DIR [--quick | --tiny]

Plans: ``full`` (642..40962 vertices x 1, 64, 1024, 4096 worlds, both design problems; under
8 minutes on an H200 with the install), ``quick`` (642 and 10242 vertices x 1 and 4096 worlds, the
default design problem; under 3 minutes) and ``tiny`` (42 vertices x 1 and 3 worlds, a one-actuator
design; runs the whole check on a CPU in seconds). The step bench times RK4 in float32 with the
captured step graph and no periodic stable-step re-estimate (host work, timed apart), so its figures
are the step kernels' throughput: vertex-RK4-steps/s = vertices x worlds x steps/s. Results are
written after every phase, so a run stopped early still leaves what it measured; a time budget
skips the remaining bench cases (marked in the JSON) rather than overrunning.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time
import xml.etree.ElementTree as ET
from pathlib import Path

import warp as wp

import warp_shape as ws
from warp_shape.benchmarks.design import bench_design
from warp_shape.benchmarks.sim import bench_sim
from warp_shape.cli.options import quiet_warp
from warp_shape.designer import design
from warp_shape.io.atomic import atomic_write, write_json

__all__ = ["PLANS", "TARGET_VERTEX_STEPS", "run_tests", "bench_steps", "bench_designs", "markdown", "main"]

#: the step-throughput goal at 642 vertices x 4096 worlds (vertex-RK4-steps/s): about a quarter of an
#: H200's memory bandwidth for the bytes one vertex-RK4-step moves
TARGET_VERTEX_STEPS = 1e9
TARGET_CASE = (642, 4096)

#: the tests that run on a CUDA device: batch, graph, blow-up, sampling and controller against the CPU;
#: every force term per family against the NumPy oracle (CPU and CUDA); the integrators CUDA = CPU
CUDA_TESTS = ["tests/test_cuda.py", "tests/test_forces.py", "tests/test_integrators.py::test_cuda_matches_cpu"]

PLANS = {
    "full": dict(subdivisions=(3, 4, 5, 6), worlds=(1, 64, 1024, 4096), repeats=3, seconds=0.3,
                 design="shipped", four_targets=True, tests=CUDA_TESTS, budget_s=330.0),
    "quick": dict(subdivisions=(3, 5), worlds=(1, 4096), repeats=2, seconds=0.2,
                  design="shipped", four_targets=False, tests=CUDA_TESTS + ["-k", "cuda"], budget_s=80.0),
    "tiny": dict(subdivisions=(1,), worlds=(1, 3), repeats=1, seconds=0.02,
                 design="tiny", four_targets=False, tests=CUDA_TESTS[:1], budget_s=120.0),
}


def run_tests(paths: list[str], device: str, out: Path, root: Path) -> dict:
    """Run pytest on ``paths`` (from ``root``) in a child process; counts from its JUnit report.

    On a CPU device the CUDA tests run against the CPU (``WARP_SHAPE_CUDA_TEST_DEVICE``), a dry run."""
    report = out / "pytest.xml"
    env = dict(os.environ)
    if not device.startswith("cuda"):
        env["WARP_SHAPE_CUDA_TEST_DEVICE"] = device
    cmd = [sys.executable, "-P", "-m", "pytest", "-q", "-p", "no:cacheprovider", f"--junitxml={report}", *paths]
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, cwd=root, env=env, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    counts = dict(tests=0, failures=0, errors=0, skipped=0)
    if report.exists():
        suites = ET.parse(report).getroot()
        for suite in suites.iter("testsuite"):
            for k in counts:
                counts[k] += int(suite.get(k, 0))
    passed = counts["tests"] - counts["failures"] - counts["errors"] - counts["skipped"]
    tail = (proc.stdout + proc.stderr).strip().splitlines()[-40:]
    return dict(command=" ".join(cmd[1:]), returncode=proc.returncode, passed=passed, wall_s=round(wall, 1),
                ok=proc.returncode == 0 and counts["tests"] > 0, tail=tail, **counts)


def bench_steps(device: str, subdivisions, worlds, repeats: int, seconds: float, deadline: float) -> list[dict]:
    """One row per (vertices, worlds): RK4 float32 graph-replay throughput of the jammed Fig. 6
    device (``bench_sim`` without NumPy and without periodic re-estimates). Cases past ``deadline``
    (perf_counter seconds) are skipped; a case that fails records its error."""
    rows = []
    for sub in subdivisions:
        vertices = 10 * 4 ** sub + 2
        for w in worlds:
            base = dict(vertices=vertices, worlds=int(w), integrator="rk4", precision="float32", device=device)
            if time.perf_counter() > deadline:
                rows.append(dict(base, skipped="time budget spent"))
                continue
            t0 = time.perf_counter()
            try:
                row = bench_sim(device=device, subdivisions=(sub,), integrators=("rk4",), precisions=("float32",),
                                repeats=repeats, seconds=seconds, numpy=False, worlds=(int(w),),
                                reestimate_every=0)[0]
            except Exception as exc:  # one failing case must not lose the others
                rows.append(dict(base, error=f"{type(exc).__name__}: {exc}"))
                continue
            row["case_wall_s"] = round(time.perf_counter() - t0, 1)
            rows.append(row)
            print(f"  {vertices} vertices x {w} worlds: {row['vertex_steps_per_s']:.3g} vertex-RK4-steps/s "
                  f"({row['steps_per_s']} steps/s, case {row['case_wall_s']} s)", flush=True)
    return rows


def _tiny_design(device: str) -> list[dict]:
    """A one-actuator design of a 162-vertex sphere for oval and heart, placed only (the CPU dry run)."""
    names = ["oval", "heart"]
    t0 = time.perf_counter()
    res = design(ws.icosphere(2, 0.035), [ws.target(n) for n in names], actuators=1, cell_radius=0.016,
                 target_names=names, device=device, codesign="off")
    return [dict(problem="tiny", targets=" ".join(names), actuators=1, wall_s=round(time.perf_counter() - t0, 2),
                 final_pcc=" ".join(f"{v:.3f}" for v in res.pcc_by_round[-1]),
                 control_steps=sum(r.control_steps for rs in res.rounds for r in rs))]


def bench_designs(device: str, which: str, four_targets: bool) -> list[dict]:
    """The design bench on ``device``: the shipped problems (``bench_design``) or the tiny one."""
    try:
        if which == "tiny":
            return _tiny_design(device)
        return bench_design(device=device, four_targets=four_targets)
    except Exception as exc:
        return [dict(problem=which, error=f"{type(exc).__name__}: {exc}")]


def _fmt(x) -> str:
    return f"{x:.3g}" if isinstance(x, float) and (abs(x) >= 1e5 or 0 < abs(x) < 1e-2) else str(x)


def _table(rows: list[dict], columns: list[tuple[str, str]]) -> list[str]:
    columns = [(key, title) for key, title in columns if any(key in r for r in rows)]  # no empty columns
    lines = ["| " + " | ".join(title for _, title in columns) + " |", "|" + "---|" * len(columns)]
    for r in rows:
        lines.append("| " + " | ".join(_fmt(r.get(key, "")) for key, _ in columns) + " |")
    return lines


def markdown(result: dict) -> str:
    """The check's results as Markdown: environment, tests, step throughput, design bench."""
    env, tests = result["environment"], result.get("tests") or {}
    gpu = f"; sm_{env['arch']}, {env['memory_gib']} GiB, driver {env['driver']}" if "arch" in env else ""
    lines = [f"# Device check ({result['plan']} plan): {env.get('device_name', env['device'])}", "",
             f"{result['date']}; Warp {env.get('warp')}; device {env.get('device')}{gpu}; "
             f"{env['cpu_count']} CPU cores", ""]
    if tests:
        lines += [f"Tests: {tests['passed']} passed, {tests['failures']} failed, {tests['errors']} errors, "
                  f"{tests['skipped']} skipped in {tests['wall_s']} s (`{tests['command']}`)", ""]
    steps = result.get("steps") or []
    if steps:
        lines += ["Step throughput: the Fig. 6 device (5 IPAMs, 10 jammed cells, every force family), RK4 "
                  "float32, captured step graph, no periodic re-estimate; vertex-RK4-steps/s = vertices x "
                  "worlds x steps/s.", ""]
        lines += _table(steps, [("vertices", "vertices"), ("worlds", "worlds"), ("steps_per_s", "steps/s"),
                                ("us_per_step", "us/step"), ("vertex_steps_per_s", "vertex-RK4-steps/s"),
                                ("ns_per_vertex_step", "ns/vertex-step"), ("error", "error"),
                                ("skipped", "skipped")])
        goal = result.get("goal")
        if goal:
            lines += ["", f"{goal['vertices']} vertices x {goal['worlds']} worlds: "
                      f"{_fmt(goal['vertex_steps_per_s'])} vertex-RK4-steps/s against the goal "
                      f"{_fmt(goal['target'])}: {'met' if goal['met'] else 'not met'}"]
    designs = result.get("design") or []
    if designs:
        lines += ["", "Design bench (targets as worlds):", ""]
        lines += _table(designs, [("problem", "problem"), ("targets", "targets"), ("actuators", "actuators"),
                                  ("wall_s", "wall s"), ("final_pcc", "final PCC"),
                                  ("control_steps", "control steps"), ("error", "error")])
    phases = result.get("phases_s") or {}
    lines += ["", "Phases (s): " + ", ".join(f"{k} {v}" for k, v in phases.items())]
    return "\n".join(lines) + "\n"


def _environment(device: str) -> dict:
    d = wp.get_device(device)
    env = dict(device=str(d), device_name=d.name, warp=wp.config.version, python=sys.version.split()[0],
               package=str(Path(ws.__file__).parent), machine=os.uname().nodename,
               cpu_count=os.cpu_count())
    if d.is_cuda:
        env.update(arch=d.arch, memory_gib=round(d.total_memory / 2**30, 1),
                   driver=".".join(map(str, wp.get_cuda_driver_version() or ())))
    return env


def _goal(steps: list[dict]) -> dict | None:
    for r in steps:
        if (r.get("vertices"), r.get("worlds")) == TARGET_CASE and "vertex_steps_per_s" in r:
            v = float(r["vertex_steps_per_s"])
            return dict(vertices=TARGET_CASE[0], worlds=TARGET_CASE[1], vertex_steps_per_s=v,
                        target=TARGET_VERTEX_STEPS, met=v >= TARGET_VERTEX_STEPS)
    return None


def _save(result: dict, out: Path) -> None:
    write_json(out / "gpu_check.json", result)
    atomic_write(out / "gpu_check.md", markdown(result))


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="gpu_check", description=__doc__.split("\n\n")[0])
    p.add_argument("--device", default="cuda:0")
    p.add_argument("--out", required=True, help="folder for gpu_check.json, gpu_check.md and pytest.xml")
    plan = p.add_mutually_exclusive_group()
    plan.add_argument("--quick", action="store_const", dest="plan", const="quick")
    plan.add_argument("--tiny", action="store_const", dest="plan", const="tiny")
    p.add_argument("--skip-tests", action="store_true")
    p.add_argument("--root", default=".", help="the repository (its tests/ are run)")
    return p


def main(argv=None) -> int:
    """Run the check; returns 0 when every phase ran and the tests passed."""
    args = _parser().parse_args(argv)
    plan_name = args.plan or "full"
    plan = PLANS[plan_name]
    out, root = Path(args.out), Path(args.root).resolve()
    out.mkdir(parents=True, exist_ok=True)
    quiet_warp()
    wp.init()
    t_start = time.perf_counter()
    result = dict(plan=plan_name, date=time.strftime("%Y-%m-%d %H:%M:%S"), environment=_environment(args.device),
                  plan_settings={k: v for k, v in plan.items() if k != "tests"}, phases_s={})
    _save(result, out)
    phases = result["phases_s"]
    if not args.skip_tests:
        print(f"tests: {' '.join(plan['tests'])}", flush=True)
        result["tests"] = run_tests(plan["tests"], args.device, out, root)
        phases["tests"] = result["tests"]["wall_s"]
        print(f"  {result['tests']['passed']} passed, {result['tests']['failures']} failed", flush=True)
        _save(result, out)
    print("step bench:", flush=True)
    t0 = time.perf_counter()
    result["steps"] = bench_steps(args.device, plan["subdivisions"], plan["worlds"], plan["repeats"], plan["seconds"],
                                  deadline=t_start + plan["budget_s"])
    result["goal"] = _goal(result["steps"])
    phases["steps"] = round(time.perf_counter() - t0, 1)
    _save(result, out)
    print("design bench:", flush=True)
    t0 = time.perf_counter()
    result["design"] = bench_designs(args.device, plan["design"], plan["four_targets"])
    phases["design"] = round(time.perf_counter() - t0, 1)
    phases["total"] = round(time.perf_counter() - t_start, 1)
    _save(result, out)
    print(markdown(result), flush=True)
    failed = (result.get("tests") and not result["tests"]["ok"]) or any(
        "error" in r for r in result["steps"] + result["design"])
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
