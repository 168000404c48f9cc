"""The command line when things go wrong around it: Ctrl-C at any moment, a full disk, odd paths and
absurd sizes. Each ends in one line (exit 130, 1 or 2), and a previous run's outputs are never lost."""

from __future__ import annotations

import errno
import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from warp_shape.cli import main
from warp_shape.cli.progress import without_progress
from warp_shape.io.atomic import manifest_problems
from test_run_folders import SMALL, assert_whole_set, fake_previous_set, no_control, snapshot

ROOT = Path(__file__).resolve().parents[1]


def one_line(capsys, rc: int, argv) -> str:
    assert main(argv) == rc, argv
    err = without_progress(capsys.readouterr().err).strip()  # a log's progress lines, then the error
    assert "Traceback" not in err and err.count("\n") == 0, err
    return err


# ------------------------------------------------------------------------------------------ Ctrl-C
def test_ctrl_c_while_the_final_outputs_are_written_keeps_the_finished_rounds(tmp_path, monkeypatch, capsys):
    """Into a folder holding a finished run: that run stays; the new one's rounds (and the final files
    written so far) are kept whole in <out>.partial. Into a new folder: kept there, complete false."""
    import warp_shape.io.outputs as outputs

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(outputs, "write_molds", interrupted)  # after design.usda and the sequences
    out = tmp_path / "out"
    before = fake_previous_set(out)
    assert main(["design", "--out", str(out), *SMALL, "--targets", "oval"]) == 130
    assert "2 finished round(s) kept in" in capsys.readouterr().err  # rounds 0 and 1
    assert snapshot(out) == before
    partial = tmp_path / "out.partial"
    report = assert_whole_set(partial)
    assert report["complete"] is False and report["rounds_done"] == 2 and (partial / "design.usda").is_file()
    fresh = tmp_path / "fresh"
    assert main(["design", "--out", str(fresh), *SMALL, "--targets", "oval"]) == 130
    assert "report.json says complete: false" in capsys.readouterr().err
    assert assert_whole_set(fresh)["complete"] is False and not (tmp_path / "fresh.partial").exists()


def test_a_ctrl_c_that_usd_swallows_at_start_up_still_stops_the_run(tmp_path, monkeypatch, capsys):
    """USD's module loading catches a KeyboardInterrupt raised inside it ("Error occurred postprocessing
    module") and goes on; the run stops all the same before any work, the previous outputs untouched."""
    import warp_shape.cli.design as design_cli
    import warp_shape.io.scene_read as scene_read

    real = scene_read.load_scene

    def swallowing(*args, **kwargs):
        try:
            os.kill(os.getpid(), signal.SIGINT)
        except KeyboardInterrupt:
            pass  # what USD does with it
        return real(*args, **kwargs)

    no_control(monkeypatch)
    monkeypatch.setattr(design_cli, "load_scene", swallowing)
    out = tmp_path / "out"
    before = fake_previous_set(out)
    assert one_line(capsys, 130, ["design", "--out", str(out), *SMALL]) == "warp-shape: interrupted"
    assert snapshot(out) == before and not (tmp_path / "out.partial").exists()


def test_ctrl_c_during_the_folder_swap_lets_it_finish_and_ends_as_done(tmp_path, monkeypatch, capsys):
    """A real SIGINT as the finished set is sealed for the swap: the swap completes (the new set whole
    in <out>, no staging folder left), then the command ends with 0, saying the outputs were in place
    (it ended with 130 "interrupted" over the new set: the exit code no longer said which set was there)."""
    from warp_shape.io.atomic import StagedFolder

    real = StagedFolder.seal

    def seal_with_ctrl_c(self, complete, **info):
        if complete:  # the commit's seal, not a round's
            os.kill(os.getpid(), signal.SIGINT)
        return real(self, complete, **info)

    out = tmp_path / "out"
    fake_previous_set(out)
    monkeypatch.setattr(StagedFolder, "seal", seal_with_ctrl_c)
    assert main(["design", "--out", str(out), *SMALL, "--targets", "oval"]) == 0
    assert "warp-shape: interrupted after the outputs were in place" in capsys.readouterr().err
    report = assert_whole_set(out)
    assert report["complete"] is True and report["targets"] == ["oval"] and not (tmp_path / "out.partial").exists()


INTERRUPT_AT_START = r"""
import os, signal, sys
import warp_shape.cli as cli
cli.quiet_warp = lambda *a, **k: os.kill(os.getpid(), signal.SIGINT)  # Ctrl-C while Warp starts
from warp_shape.cli import main
sys.exit(main(sys.argv[1:]))
"""


def test_ctrl_c_as_warp_starts_is_one_line_and_exit_130(tmp_path):
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    proc = subprocess.run([sys.executable, "-c", INTERRUPT_AT_START, "simulate", "--out", str(tmp_path / "o")],
                          env=env, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 130 and proc.stderr.strip() == "warp-shape: interrupted", proc.stderr
    assert not (tmp_path / "o").exists()


PRESSED_WHILE_STARTING = r"""
import os, signal, sys
import warp_shape  # the package holds Ctrl-C from its first line when this process is the warp-shape command
os.kill(os.getpid(), signal.SIGINT)  # pressed while the package and Warp load
from warp_shape.cli import main
sys.exit(main(sys.argv[1:]))
"""


@pytest.fixture
def ctrl_c_reaches_python():
    """Ctrl-C as a terminal delivers it, also where the suite runs with SIGINT ignored (a job started in
    the background by a non-interactive shell inherits SIG_IGN, which Python then leaves alone)."""
    saved = signal.signal(signal.SIGINT, signal.default_int_handler)
    yield lambda: signal.signal(signal.SIGINT, signal.SIG_DFL)  # for child processes: Python's own handler
    signal.signal(signal.SIGINT, saved)


def test_ctrl_c_while_the_command_imports_is_one_line_and_nothing_else_is_held(tmp_path, ctrl_c_reaches_python):
    script = tmp_path / "warp-shape"  # the console script's name: what the start-up hold looks for
    script.write_text(PRESSED_WHILE_STARTING)
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    proc = subprocess.run([sys.executable, str(script), "simulate", "--out", str(tmp_path / "o")], env=env,
                          capture_output=True, text=True, timeout=120, preexec_fn=ctrl_c_reaches_python)
    assert proc.returncode == 130 and proc.stderr.strip() == "warp-shape: interrupted", proc.stderr
    assert not (tmp_path / "o").exists()
    other = subprocess.run([sys.executable, "-c", "import signal, warp_shape; "
                            "assert signal.getsignal(signal.SIGINT) is signal.default_int_handler"], env=env,
                           capture_output=True, text=True, timeout=120, preexec_fn=ctrl_c_reaches_python)
    assert other.returncode == 0, other.stderr  # any other program importing warp_shape: Ctrl-C as usual


def test_held_interrupts_deliver_the_press_when_the_block_ends(ctrl_c_reaches_python):
    from warp_shape.interrupts import held_interrupts

    done = []
    with pytest.raises(KeyboardInterrupt):
        with held_interrupts():
            os.kill(os.getpid(), signal.SIGINT)
            done.append("the block ran to its end")
    assert done and signal.getsignal(signal.SIGINT) is signal.default_int_handler


def test_held_interrupts_off_the_main_thread_are_a_plain_block_and_an_error_inside_is_not_held(
        ctrl_c_reaches_python):
    import threading

    from warp_shape.interrupts import held_interrupts

    seen = []

    def worker():
        with held_interrupts():
            seen.append(signal.getsignal(signal.SIGINT))

    t = threading.Thread(target=worker)
    t.start()
    t.join()
    assert seen == [signal.default_int_handler]
    with pytest.raises(ZeroDivisionError):  # the error, not a KeyboardInterrupt for a press inside the block
        with held_interrupts():
            os.kill(os.getpid(), signal.SIGINT)
            1 / 0
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler


#: what Python's start-up (``site``) and the console script (``import re``) have loaded before the package
BEFORE_THE_PACKAGE = "import os, sys, re"


def test_the_start_up_hold_comes_before_any_import_of_the_package_but_signal():
    """The hold is the package's first statement and its module imports nothing that Python's start-up and
    the console script have not loaded (``signal`` aside): Ctrl-C before it is Python's own start-up only."""
    proc = subprocess.run([sys.executable, "-S", "-X", "importtime", "-c", f"{BEFORE_THE_PACKAGE}; import warp_shape"],
                          env=dict(os.environ, PYTHONPATH=str(ROOT)), capture_output=True, text=True, timeout=120)
    names = [line.rpartition("|")[2].strip() for line in proc.stderr.splitlines() if line.startswith("import time:")]
    assert "re" in names and "warp_shape.interrupts" in names, proc.stderr[-2000:]
    before_hold = names[names.index("re") + 1:names.index("warp_shape.interrupts")]
    assert set(before_hold) <= {"__future__", "signal"}, before_hold


# ------------------------------------------------------------------------------------------ full disk
def full_disk(*args, **kwargs):
    raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(args[0]) if args else None)


def test_a_full_disk_is_one_line_and_the_previous_outputs_stay(tmp_path, monkeypatch, capsys):
    """ENOSPC from the figures (matplotlib's PNG through atomic_write) and from USD (a Tf.ErrorException
    of many lines): one line naming the file and the fix, exit 1, the previous set whole."""
    from pxr import Tf

    import warp_shape.io.figures as figures
    import warp_shape.io.scene_write as scene_write

    out = tmp_path / "out"
    before = fake_previous_set(out)
    with monkeypatch.context() as m:
        m.setattr(figures, "atomic_write", full_disk)
        err = one_line(capsys, 1, ["design", "--out", str(out), *SMALL, "--targets", "oval"])
    assert err.startswith(f"warp-shape: error: no space left on the device writing {tmp_path / 'out.partial'}")
    assert "free some space" in err and "--out a folder on another disk" in err
    assert snapshot(out) == before and not (tmp_path / "out.partial").exists()

    usd_text = ("\n\tError in 'pxr::ArFilesystemWritableAsset::Write' at line 78 in file filesystemWritableAsset.cpp"
                " : 'Error occurred writing file: No space left on device'\n\tError in 'pxr::SdfUsdaFileFormat::"
                "WriteToFile' at line 516 in file usdaFileFormat.cpp : 'Could not close x.usda'")

    def usd_full(layer, path):
        raise Tf.ErrorException(usd_text)

    monkeypatch.setattr(scene_write, "export_layer", usd_full)
    err = one_line(capsys, 1, ["design", "--out", str(out), *SMALL, "--targets", "oval"])
    assert err.startswith(f"warp-shape: error: no space left on the device writing {tmp_path / 'out.partial'}")
    assert snapshot(out) == before and not (tmp_path / "out.partial").exists()
    other = scene_write.usd_write_error(Tf.ErrorException(usd_text.replace("No space left on device", "Bad")), "x.usda")
    assert str(other) == "USD could not write x.usda: Error occurred writing file: Bad"


# ------------------------------------------------------------------------------------------ odd paths
def test_a_recording_path_nothing_can_be_written_to_is_refused_before_any_work(tmp_path, monkeypatch, capsys):
    pytest.importorskip("rerun")
    no_control(monkeypatch)
    err = one_line(capsys, 2, ["design", "--out", str(tmp_path / "out"), *SMALL, "--rerun", "/proc/x.rrd"])
    assert err.startswith("warp-shape: error: --rerun /proc/x.rrd: /proc is not writable (")
    assert "e.g. --rerun out/run.rrd" in err and not (tmp_path / "out").exists()


def test_a_corrupt_sweep_table_is_one_line_naming_the_fix(tmp_path, capsys):
    folder = tmp_path / "s"
    folder.mkdir()
    (folder / "results.json").write_text('{"sweep": {"kind": "subsets"}, "rows": [')
    err = one_line(capsys, 2, ["sweep", "subsets", "--targets", "oval", "--backend", "serial", "--out", str(folder)])
    assert err.startswith(f"warp-shape: error: {folder / 'results.json'} cannot be read (not a sweep's results table")
    assert "give --restart" in err


# ------------------------------------------------------------------------------------------ absurd sizes
@pytest.mark.parametrize("argv, message", [
    (["export", "out/design.usda", "--what", "control", "--rate", "1e9"], "--rate takes 0 or 0.001..10000, got 1e+09"),
    (["export", "out/design.usda", "--max-slew", "1e-6"], "--max-slew takes 0 or 0.1..1e+09, got 1e-06"),
    (["export", "out/design.usda", "--max-flow", "1e-9"], "--max-flow takes 0 or 0.01..1e+09, got 1e-09"),
    (["design", "--actuators", "100000"], "--actuators takes 1..500, got 100000"),
    (["design", "--candidates", "100000"], "--candidates takes 1..256, got 100000"),
    (["design", "--refine-rounds", "100000"], "--refine-rounds takes 0..50, got 100000"),
    (["control", "--max-steps", "1000000000"], "--max-steps takes 1..100000, got 1000000000"),
    (["simulate", "--subdivisions", "12"], "--subdivisions takes 1..6, got 12"),
    (["simulate", "--dt", "1e-9"], "are 8e+08 output steps, more than 200000; give a larger --dt or shorter times"),
    (["simulate", "--inflate-time", "1e300"], "more than 200000"),
    (["bench", "sim", "--worlds", "1", "100000"], "--worlds takes 1..4096, got 100000"),
    (["bench", "sim", "--subdivisions", "9"], "--subdivisions takes 1..7, got 9"),
    (["bench", "control", "--repeats", "1000000"], "--repeats takes 1..100, got 1000000"),
    (["compare", "scan.ply", "--to", "oval", "--max-iterations", "1000000000"], "--max-iterations takes 1..10000"),
    (["sweep", "subsets", "--workers", "100000"], "--workers takes 1..1024, got 100000"),
    (["sweep", "grid", "--param", "actuators=5", "--actuators", "0"], "--actuators takes 1..500, got 0"),
    # a sweep's settings (--param values, --set values) are held to the bounds of the flags that give them
    (["sweep", "grid", "--param", "max_steps=5,1000000000"],
     "sweep setting controller.max_steps takes 1..100000, as --max-steps does, got 1000000000"),
    (["sweep", "subsets", "--set", "controller.max_steps=1000000000"], "controller.max_steps takes 1..100000"),
    (["sweep", "grid", "--param", "actuators=5,100000"], "sweep setting actuators takes 1..500, as --actuators does"),
    (["sweep", "subsets", "--set", "candidates=100000"], "designer.candidates takes 1..256, as --candidates does"),
    (["sweep", "grid", "--param", "refine_rounds=0,100000"], "designer.refine_rounds takes 0..50, as --refine-rounds"),
    (["sweep", "subsets", "--set", "subdivisions=12"], "sweep setting subdivisions takes 1..6, as --subdivisions"),
    (["sweep", "grid", "--param", "control_period=10,1000000"], "controller.control_period takes 1..1000, got 1000000"),
    (["sweep", "grid", "--param", "max_settle_steps=1000000000000"], "max_settle_steps takes 0..100000, got 1000000000000"),
    (["sweep", "subsets", "--set", "simulation.max_substeps=1000000000"], "simulation.max_substeps takes 1..1000000"),
])
def test_every_size_a_flag_requests_is_bounded_before_any_work(tmp_path, monkeypatch, capsys, argv, message):
    """Rates, counts, resolutions and steps: a one-line error naming the bounds, before any file is
    read or written (the scene and scan named here do not even exist)."""
    monkeypatch.chdir(tmp_path)
    err = one_line(capsys, 2, argv)
    assert message in err and err.startswith("warp-shape: error: ")
    assert list(tmp_path.iterdir()) == []


def test_a_valve_sequence_past_its_row_bound_is_refused_before_it_is_made():
    from types import SimpleNamespace

    import numpy as np

    from warp_shape.errors import DesignError
    from warp_shape.io.valve import MAX_VALVE_ROWS, ValveTiming, valve_schedule

    n = 3
    history = {"time": np.linspace(0, 1, n), "phase": np.ones(n, int), "pressure_pa": np.zeros(n),
               "air_mol": np.ones(n), "ipam0_pressure_pa": np.array([0.0, 2e5, 0.0])}
    result = SimpleNamespace(history=history, design=None, passive_ipams=[])
    slow = dict(max_slew_kpa_s=0.1, max_flow_ml_s=None)  # 200 kPa at 0.1 kPa/s (planned 0.1 % below): 2002 s
    rows = len(valve_schedule(result, ValveTiming(rate_hz=100.0, **slow))["time_s"])  # 4004 s
    assert rows == 2 * 200_201 + 1 <= MAX_VALVE_ROWS
    with pytest.raises(DesignError, match=r"would have 4e\+06 rows \(4004 s at 1000 Hz\), more than 1000000"):
        valve_schedule(result, ValveTiming(rate_hz=1000.0, **slow))



# ------------------------------------------------------------- what used to be a traceback or a late error
SIM = ["simulate", "--subdivisions", "1", "--inflate-time", "0.01", "--actuate-time", "0.01"]


def test_rerun_spawn_binds_loopback_or_is_refused_before_the_job(tmp_path, monkeypatch, capsys):
    """--rerun-spawn printed "Rerun is disabled", ran the whole job, then ended in a gRPC traceback; the
    viewer rerun starts by default listens on 0.0.0.0. Without a display it is refused before any work;
    the viewer it starts listens on 127.0.0.1 only."""
    pytest.importorskip("rerun")
    import warp_shape.io.recorder as recorder

    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    err = one_line(capsys, 2, [*SIM, "--rerun-spawn", "--out", str(tmp_path / "s")])
    assert "--rerun-spawn cannot open a viewer: there is no display here" in err and not (tmp_path / "s").exists()
    started = []
    monkeypatch.setattr(recorder.subprocess, "Popen", lambda argv, **kw: started.append(argv))
    url = recorder.spawn_viewer(port=1)  # nothing listens on port 1
    assert url == "rerun+http://127.0.0.1:1/proxy"
    argv = started[0]
    assert argv[argv.index("--bind") + 1] == "127.0.0.1" and argv[argv.index("--port") + 1] == "1"


def test_a_recording_the_disk_refuses_is_one_line_and_leaves_no_temporary_file(tmp_path, monkeypatch):
    """rerun's file writer stopping (a full disk) was "RuntimeError: File-writer thread shut down
    prematurely" with a .x.rrd.*.tmp left behind."""
    pytest.importorskip("rerun")
    from warp_shape.errors import DesignError
    from warp_shape.io.recorder import Recorder

    rec = Recorder(tmp_path / "x.rrd")

    def full(*a, **k):
        raise RuntimeError("File-writer thread shut down prematurely")

    monkeypatch.setattr(rec.stream, "flush", full)
    with pytest.raises(DesignError, match="the recording .*x.rrd could not be written .*free some space"):
        rec.close()
    assert os.listdir(tmp_path) == []


FULL_DISK = r"""
import resource, signal, sys
from warp_shape.cli import main
out, rrd = sys.argv[1], sys.argv[2]
sim = ["simulate", "--subdivisions", "1", "--inflate-time", "0.01", "--actuate-time", "0.01", "--out", out]
assert main(sim) == 0  # the previous set, and every kernel loaded before the limit
signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # a write past the limit fails (EFBIG) as on a full disk
resource.setrlimit(resource.RLIMIT_FSIZE, (65536, resource.getrlimit(resource.RLIMIT_FSIZE)[1]))
sys.exit(main([*sim, "--rerun", rrd]))
"""


def test_a_recording_a_real_disk_refuses_is_one_line_and_the_run_ends(tmp_path):
    """A recording the disk refuses for real (a file size limit, as a full disk: writes fail part-way):
    rerun's file writer hung for good on it (with "File-writer thread shut down prematurely" and a
    .x.rrd.*.tmp left behind on a full tmpfs); now one line, exit 2, no temporary file, the previous
    set whole."""
    pytest.importorskip("rerun")
    out, folder = tmp_path / "s", tmp_path / "rec"
    folder.mkdir()
    run = subprocess.run([sys.executable, "-c", FULL_DISK, str(out), str(folder / "x.rrd")], capture_output=True,
                         text=True, timeout=120, env=dict(os.environ, PYTHONPATH=str(ROOT)))
    err = run.stderr.strip()
    assert run.returncode == 2 and "Traceback" not in err and err.count("\n") == 0, (run.returncode, err)
    assert err.startswith(f"warp-shape: error: the recording {folder / 'x.rrd'} could not be written (File too")
    assert "free some space" in err and os.listdir(folder) == []
    assert manifest_problems(out) == [] and not (tmp_path / "s.partial").exists()


def test_calibrate_checks_its_out_folder_before_the_fit(tmp_path, monkeypatch, capsys):
    """--out /etc/hostname/sub was a NotADirectoryError after the 20 s fit."""
    import warp_shape.cli.calibrate as cal_cli

    monkeypatch.setattr(cal_cli, "calibrate", lambda *a, **k: pytest.fail("the fit started"))
    (tmp_path / "m.json").write_text('{"observations": []}')
    (tmp_path / "file").write_text("x")
    err = one_line(capsys, 2, ["calibrate", str(tmp_path / "m.json"), "--design", "cube_fig6", "--out", str(tmp_path / "file" / "sub")])
    assert "is a file, not a folder" in err


def test_odd_paths_and_environments_are_one_line_before_any_work(tmp_path, monkeypatch, capsys):
    """An --out name over 255 bytes (ENAMETOOLONG), a deleted working folder, an unwritable
    WARP_CACHE_PATH, a plugin that fails as it is imported: each was a traceback."""
    err = one_line(capsys, 2, [*SIM, "--out", str(tmp_path / ("a" * 300))])
    assert "more than a file system allows" in err
    err = one_line(capsys, 2, [*SIM, "--out", str(tmp_path / "s"), "--rerun", str(tmp_path / ("r" * 300))])
    assert "more than a file system allows" in err or "rerun-sdk" in err
    gone = tmp_path / "gone"
    gone.mkdir()
    monkeypatch.chdir(gone)
    gone.rmdir()
    assert "the current folder no longer exists" in one_line(capsys, 2, [*SIM, "--out", "sim"])
    monkeypatch.chdir(tmp_path)
    (tmp_path / "file").write_text("x")
    monkeypatch.setenv("WARP_CACHE_PATH", str(tmp_path / "file" / "cache"))
    assert "WARP_CACHE_PATH" in one_line(capsys, 2, [*SIM, "--out", str(tmp_path / "s")])
    monkeypatch.delenv("WARP_CACHE_PATH")
    (tmp_path / "broken_plugin.py").write_text("raise RuntimeError('boom')\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setenv("WARP_SHAPE_PLUGINS", "broken_plugin")
    err = one_line(capsys, 2, [*SIM, "--out", str(tmp_path / "s")])
    assert "'broken_plugin', which failed as it was imported (RuntimeError: boom)" in err
    assert not (tmp_path / "s").exists()


def test_a_ctrl_c_a_library_caught_still_ends_the_command_as_interrupted(tmp_path, monkeypatch, capsys):
    """A SIGINT near the end of design returned 0 without the "interrupted" line (a library on the way
    caught the KeyboardInterrupt): the press is noted, and the command ends with 130 and that line."""
    import warp_shape.cli.simulate as simulate_cli

    real = simulate_cli.run

    def swallowing(args):
        try:
            signal.raise_signal(signal.SIGINT)
        except KeyboardInterrupt:
            pass  # as a library that catches everything
        return real(args)

    import warp_shape.cli as cli

    parser = cli.build_parser()
    parser._subparsers._group_actions[0].choices["simulate"].set_defaults(func=swallowing)  # registered at build
    monkeypatch.setattr(cli, "build_parser", lambda: parser)
    assert main([*SIM, "--out", str(tmp_path / "s")]) == 130
    assert capsys.readouterr().err.strip().endswith("warp-shape: interrupted")
