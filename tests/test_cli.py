"""The command line and the README example."""

from __future__ import annotations

import io
import json
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from warp_shape.cli import build_parser, main
from warp_shape.cli.progress import without_progress

ROOT = Path(__file__).resolve().parents[1]


def test_simulate_writes_results_and_reproduces_fig6_signs(tmp_path, capsys):
    rc = main(["simulate", "--inflate-time", "0.15", "--actuate-time", "0.15", "--subdivisions", "2",
               "--out", str(tmp_path)])
    assert rc == 0
    data = json.loads((tmp_path / "simulate.json").read_text())
    inflated, actuated = data["frames"][1], data["frames"][2]
    assert inflated["volume"] > 1.3 * data["frames"][0]["volume"]
    forces = np.array(actuated["ipam_force"])
    # paper, section IV-C: corner IPAMs push (compression), the face IPAM pulls (tension)
    assert np.all(forces[:4] < 0) and forces[4] > 0
    assert not list(tmp_path.glob(".*"))  # no temporary files left behind
    assert "IPAM axial force" in capsys.readouterr().out


def test_cli_reports_bad_input_cleanly(capsys):
    rc = main(["simulate", "--device", "cuda:9", "--inflate-time", "0.01", "--actuate-time", "0.01"])
    assert rc == 2
    assert "not available" in capsys.readouterr().err


def test_readme_example_runs():
    text = (ROOT / "README.md").read_text()
    block = re.search(r"```python\n(.*?)```", text, re.S).group(1)
    namespace: dict = {}
    exec(compile(block, "README.md", "exec"), namespace)
    sim = namespace["sim"]
    assert sim.jammed.all() and sim.pressure() > 0 and np.isfinite(sim.positions).all()


def test_control_command_writes_sequences(tmp_path, capsys):
    rc = main(["control", "--targets", "cube", "--out", str(tmp_path), "--max-steps", "60", "--method", "paper"])
    assert rc == 0
    data = json.loads((tmp_path / "control_cube.json").read_text())
    rows = (tmp_path / "control_cube.csv").read_text().strip().splitlines()
    assert len(rows) == len(data["rows"]) + 1 and rows[0].startswith("step,time,phase,air_mol")
    forces = np.array(data["ipam_forces_n"])
    assert np.all(forces[:4] < 0) and forces[4] > 0
    out = capsys.readouterr().out
    assert "cube" in out and "IPAM 4" in out


def test_control_command_records_rerun(tmp_path, capsys):
    from warp_shape.io.recording_read import read_recording

    rrd = tmp_path / "run.rrd"
    rc = main(["control", "--target", "cube", "--out", str(tmp_path), "--max-steps", "15", "--method", "paper",  # former spelling
               "--rerun", str(rrd)])
    assert rc == 0 and rrd.stat().st_size > 1000
    assert f"recording: {rrd}" in capsys.readouterr().out  # where it went, and how to open it
    rec = read_recording(rrd)
    data = json.loads((tmp_path / "control_cube.json").read_text())
    membrane = rec["entities"]["/control/cube/membrane"]
    assert len(membrane["times"]["control_step"]) == len(data["rows"])
    assert (tmp_path / "control_cube.png").exists()


# ------------------------------------------------------------------------------- answers to bad input
def no_work(monkeypatch):
    """Make any control run fail loudly: the checks must come before any work."""
    import warp_shape.designer.loop as designer_loop

    def forbidden(*args, **kwargs):
        raise AssertionError("work started before the inputs were checked")

    monkeypatch.setattr(designer_loop, "control_many", forbidden)


def error_of(capsys, argv) -> str:
    assert main(argv) == 2, argv
    err = without_progress(capsys.readouterr().err)  # a log's progress lines, then the error
    assert err.startswith("warp-shape: error: ") and "Traceback" not in err
    return err


def test_unknown_target_and_scene_suggest_the_closest_name(tmp_path, monkeypatch, capsys):
    no_work(monkeypatch)
    err = error_of(capsys, ["design", "--targets", "ovl", "--out", str(tmp_path)])
    assert "unknown target 'ovl' (did you mean 'oval'?)" in err and "oval, pear, heart, cube" in err
    err = error_of(capsys, ["design", "oval_hart", "--out", str(tmp_path)])
    assert "unknown scene 'oval_hart' (did you mean 'oval_heart'?)" in err and "four_targets_5" in err
    err = error_of(capsys, ["control", "--targets", "hart", "--out", str(tmp_path)])
    assert "did you mean 'heart'?" in err


def test_absent_device_is_a_clear_error(tmp_path, monkeypatch, capsys):
    no_work(monkeypatch)
    err = error_of(capsys, ["design", "--device", "cuda:9", "--out", str(tmp_path / "out")])
    assert "device 'cuda:9' is not available" in err and "devices here: cpu" in err
    assert not (tmp_path / "out").exists()


def test_out_is_checked_before_any_work(tmp_path, monkeypatch, capsys):
    no_work(monkeypatch)
    a_file = tmp_path / "a_file"
    a_file.write_text("x")
    for command in (["design"], ["control"], ["simulate"], ["bench", "sim"]):
        err = error_of(capsys, [*command, "--out", str(a_file)])
        assert f"--out {a_file} is a file, not a folder" in err, command
    err = error_of(capsys, ["design", "--out", str(a_file / "sub")])
    assert "is a file, not a folder" in err
    monkeypatch.delenv("WARP_CACHE_PATH", raising=False)  # its own check writes a probe file first
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o555)
    if os.geteuid() == 0:  # root writes into read-only folders: the file system's refusal, as a user meets it
        import warp_shape.io.atomic as atomic

        def refuse(*args, dir=None, **kwargs):
            raise PermissionError(13, "Permission denied")

        monkeypatch.setattr(atomic.tempfile, "mkstemp", refuse)
    try:
        err = error_of(capsys, ["design", "--out", str(ro / "out")])
        assert f"the folder holding --out {ro} is not writable (Permission denied)" in err
    finally:
        ro.chmod(0o755)


@pytest.mark.parametrize("suffix, data, message", [
    (".stl", b"solid? no\x00\xff\xfe garbage" * 9, "could not parse STL file"),
    (".stl", b"", "the file is empty"),
    (".obj", b"\x89PNG\r\n\x1a\n\x00\x00\xff\xfe", "could not parse OBJ file"),
    (".obj", b"# only a comment\n", "no OBJ vertex lines"),
    # what trimesh says of it depends on whether charset_normalizer is installed; either way a parse error
    (".off", b"garbage\x00\xff\xfe\x01\x02", "could not parse mesh file"),
])
def test_unreadable_mesh_is_a_parse_error(tmp_path, monkeypatch, capsys, suffix, data, message):
    no_work(monkeypatch)
    path = tmp_path / f"scan{suffix}"
    path.write_bytes(data)
    err = error_of(capsys, ["design", "--targets", str(path), "--out", str(tmp_path / "out")])
    assert message in err and str(path) in err and "charset_normalizer" not in err


def test_simulate_refuses_a_step_that_takes_no_steps(tmp_path, capsys):
    err = error_of(capsys, ["simulate", "--dt", "1", "--out", str(tmp_path)])
    assert "--dt 1 s takes no step of --inflate-time 0.4 s" in err and "give --dt at most 0.4 s" in err
    assert not list(tmp_path.iterdir())


def test_too_many_actuators_names_the_options_that_fit_them(tmp_path, monkeypatch, capsys):
    no_work(monkeypatch)
    err = error_of(capsys, ["design", "--actuators", "30", "--subdivisions", "2", "--out", str(tmp_path / "o")])
    assert "30 actuators need about" in err and "--cell-radius 0.0097 (m) fits" in err
    assert "--subdivisions 3" in err
    m = re.search(r"--cell-radius ([\d.]+)", err)
    with pytest.raises(AssertionError, match="work started"):  # the suggested radius fits: round 0 starts
        main(["design", "--actuators", "30", "--subdivisions", "2", "--cell-radius", m.group(1), "--out",
              str(tmp_path / "o")])


def test_version_and_defaults_in_help(capsys):
    from warp_shape import __version__

    with pytest.raises(SystemExit) as exc:
        main(["--version"])
    assert exc.value.code == 0 and capsys.readouterr().out.strip() == f"warp-shape {__version__}"
    parser = build_parser()
    sub = next(a for a in parser._actions if a.dest == "command").choices
    design_help = sub["design"].format_help()
    assert "(default: 0.005)" in design_help and "(default: out)" in design_help
    assert "--subdivisions" in design_help
    control_help = sub["control"].format_help()
    assert "--targets" in control_help and "--target " not in control_help  # one spelling shown
    assert "else 300)" in control_help and "(default: out/control)" in control_help
    assert parser.parse_args(["control", "--target", "cube"]).targets == ["cube"]  # the former spelling
    assert parser.parse_args(["simulate"]).out == "out/simulate"  # not the design's folder
    assert parser.parse_args(["design"]).out == "out"


def test_each_bench_writes_its_own_file(tmp_path, monkeypatch, capsys):
    import warp_shape.benchmarks.design as design_bench

    row = {c: 1 for c in design_bench.DESIGN_COLUMNS}
    monkeypatch.setattr(design_bench, "bench_design", lambda **kw: [row])
    assert main(["bench", "sim", "--subdivisions", "1", "--repeats", "1", "--out", str(tmp_path)]) == 0
    printed = capsys.readouterr()
    assert printed.err.startswith("bench sim: internal steps per second")  # says what it does, then does it
    assert str(tmp_path / "bench_sim.json") in printed.out
    assert main(["bench", "design", "--out", str(tmp_path)]) == 0
    sim = json.loads((tmp_path / "bench_sim.json").read_text())
    design = json.loads((tmp_path / "bench_design.json").read_text())
    assert sim["sim"] and sim["sim"][0]["vertices"] == 42 and design["design"] == [row]
    assert not (tmp_path / "bench.json").exists()


def test_view_opens_a_recording_or_says_why_not(tmp_path, monkeypatch, capsys):
    import warp_shape.cli.view as view

    err = error_of(capsys, ["view", str(tmp_path / "none.rrd")])
    assert "no recording at" in err and "--rerun" in err
    rrd = tmp_path / "run.rrd"
    rrd.write_bytes(b"RRF2")
    calls = []
    monkeypatch.setattr(view.subprocess, "call", lambda cmd: calls.append(cmd) or 0)
    monkeypatch.setenv("DISPLAY", ":0")
    assert main(["view", str(rrd)]) == 0
    # the viewer's server listens on this machine only
    assert calls == [[sys.executable, "-m", "rerun", str(rrd), "--bind", "127.0.0.1"]]
    assert "opening" in capsys.readouterr().err
    monkeypatch.delenv("DISPLAY")
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    err = error_of(capsys, ["view", str(rrd)])  # headless: said in a line, before any viewer starts
    assert "no display here" in err and f"copy {rrd} to a machine with one" in err and "rerun run.rrd" in err
    assert len(calls) == 1
    monkeypatch.setitem(sys.modules, "rerun", None)  # rerun-sdk not installed
    err = error_of(capsys, ["view", str(rrd)])
    assert "pip install 'warp-shape[rerun]'" in err


def test_cuda_driver_note_is_not_printed_on_cpu_runs(tmp_path):
    raw = subprocess.run([sys.executable, "-c", "import warp; warp.init()"], capture_output=True, text=True)
    if "Could not find or load the NVIDIA CUDA driver" not in raw.stderr:
        pytest.skip("this machine has a CUDA driver: Warp prints no note")
    run = subprocess.run([sys.executable, "-m", "warp_shape.cli", "simulate", "--inflate-time", "0.01",
                          "--actuate-time", "0.01", "--subdivisions", "1", "--out", str(tmp_path)],
                         capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    assert "CUDA driver" not in run.stderr and "Fig. 6 sphere" in run.stdout
    run = subprocess.run([sys.executable, "-m", "warp_shape.cli", "compare", str(ROOT / "scenes" / "targets" /
                          "oval.ply"), "--to", "oval"], capture_output=True, text=True)  # every command
    assert run.returncode == 0 and "CUDA driver" not in run.stderr and "PCC" in run.stdout


class Terminal(io.StringIO):
    def isatty(self):
        return True


def test_design_progress_counts_phases_by_the_time_they_take(monkeypatch):
    """Construction rounds of 2.5 s: the bar says "compiling kernels" before the first step, counts
    the final round, the refinement and the outputs by their weights, creeps within a long phase,
    says how long a phase has run, and shows "ETA ?" rather than 0:00 when a phase overruns."""
    from warp_shape.cli import progress

    clock = [100.0]
    monkeypatch.setattr(progress.time, "monotonic", lambda: clock[0])
    term = Terminal()
    bar = progress.DesignProgress(5, n_targets=2, stream=term, refine_rounds=True, outputs=True)
    bar.tqdm.refresh()
    assert "compiling kernels" in term.getvalue() and bar.eta() == "?"
    weights = [1, 1, 1, 1, progress.FINAL_ROUND_WEIGHT, progress.REFINE_WEIGHT, progress.OUTPUTS_WEIGHT]
    assert bar.tqdm.total == sum(weights)
    on_round = bar.wrap_round(lambda i, d, r: None)
    for i in range(5):
        bar.update(i, 4, 3, 300, 0, 2)
        assert bar.tqdm.n == pytest.approx(sum(weights[:i]))
        clock[0] += 2.5 if i < 4 else 0.0
    def clock_text(seconds):
        return f"{int(seconds // 60)}:{int(seconds % 60):02d}"

    # 4 rounds in 10 s: the phases left weigh sum(weights[4:]) rounds of 2.5 s
    assert bar.eta() == clock_text(2.5 * sum(weights[4:]))
    bar.update(4, 4, 24, 300, 2, 2)
    assert "final round: model-based control" in bar.compose(bar._text)
    final = 2.5 * weights[4]  # the final round's estimate, s
    clock[0] += 0.5 * final  # half of it: the bar creeps half way through the phase
    text = bar.compose(bar._text)
    assert bar.tqdm.n == pytest.approx(4 + 0.5 * weights[4]) and f"({0.5 * final:.0f} s)" in text
    after = 2.5 * sum(weights[5:])
    assert bar.eta() == clock_text(0.5 * final + after)
    clock[0] += final  # past its estimate: at least the phases after it
    assert bar.eta() == f"> {clock_text(after)}" and " 5/7 final round" in bar.compose(bar._text)
    on_round(4, None, None)
    assert bar.tqdm.n == pytest.approx(sum(weights[:5]))
    bar.update(4, 4, 7, 300, 0, 9)  # the refinement: 9 worlds for 2 targets
    assert "refinement, 9 worlds: step 7" in bar.compose(bar._text)
    bar.writing_outputs()
    assert bar.tqdm.n == pytest.approx(sum(weights[:6])) and "writing the outputs" in bar.compose(bar._text)
    clock[0] += 2.5 * weights[6] + 1  # past the outputs' estimate, the last phase: "?", never 0:00 or less
    assert bar.eta() == "?"
    bar.__exit__(None, None, None)
    assert bar.tqdm.n == bar.tqdm.total and bar.eta() == "0:00"


def test_progress_off_a_terminal_is_a_line_per_phase_and_per_minute(monkeypatch):
    """A log (not a terminal) gets no bar but a plain line when a design enters a phase and, within a
    long phase, at least once a minute: a run writing to a log is seen working."""
    from warp_shape.cli import progress
    from warp_shape.cli.progress import ControlProgress, DesignProgress

    with DesignProgress(5, stream=Terminal()) as early:  # a design that stops early ends complete
        early.update(2, 4, 3, 300, 0, 1)
    assert early.tqdm.n == early.tqdm.total
    clock = [100.0]
    monkeypatch.setattr(progress.time, "monotonic", lambda: clock[0])
    log = io.StringIO()
    with ControlProgress(stream=log) as steps:
        steps.update(40, 300, 0, 2)
        assert steps.tqdm.total is None  # counted, never against the step limit
        for _ in range(30):  # news every second for 30 s: no line beyond the first
            clock[0] += 1.0
            steps.update(41, 300, 1, 2)
        clock[0] += 31.0
        steps.update(90, 300, 1, 2)  # a minute after the first line
    assert log.getvalue().splitlines() == ["control: 0/2 targets done [0:00]", "control: 1/2 targets done [1:01]"]
    assert "\r" not in log.getvalue() and "|" not in log.getvalue()  # lines, no bar
    log = io.StringIO()
    bar = DesignProgress(3, n_targets=2, stream=log, outputs=True)
    for i in range(3):
        for step in (10, 20):
            bar.update(i, 2, step, 300, 0, 2)
    bar.writing_outputs()
    lines = log.getvalue().splitlines()
    assert len(lines) == 5 and "compiling kernels" in lines[0] and "writing the outputs" in lines[-1]
    assert [ln.split(": ", 1)[0] for ln in lines] == ["design"] * 5 and "round 1/2: step 10" in lines[2]


def test_bench_says_in_a_log_what_each_benchmark_does_how_it_goes_and_how_long_it_took(tmp_path, monkeypatch, capsys):
    """Off a terminal (a log): a line as a benchmark starts, its own progress lines, and "done in N s" as it
    ends, on stderr, before the tables; the rays benchmark reports each measured row as it goes."""
    import warp_shape.benchmarks.rays as rays_bench

    def rays(device, progress):
        progress("  rays: warp, 10000 rays: 1e+06 rays/s; trimesh next")
        clock[0] += 7.0
        return [dict(engine="warp", device="cpu", triangles=1, rays=10000, rays_per_s=1e6, seconds=0.01, note="")]

    clock = [50.0]
    monkeypatch.setattr(rays_bench, "bench_rays", rays)
    monkeypatch.setattr("warp_shape.cli.bench.time.perf_counter", lambda: clock[0])
    assert main(["bench", "rays", "--out", str(tmp_path)]) == 0
    err = capsys.readouterr().err.splitlines()
    assert err == ["bench rays: radial sampling throughput ...", "  rays: warp, 10000 rays: 1e+06 rays/s; trimesh next",
                   "bench rays: done in 7 s"], err
