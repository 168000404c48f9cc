"""Output folders of runs: every input checked before the first write, outputs staged and swapped in
whole with a manifest, finished rounds recorded, and a folder that always holds one whole set, even
when a run into it is killed at any point."""

from __future__ import annotations

import csv
import dataclasses
import json
import os
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import pytest

import warp_shape as ws
from warp_shape.cli import main
from warp_shape.cli.progress import without_progress
from warp_shape.io.atomic import MANIFEST, OutputError, StagedFolder, file_digest, manifest_problems, read_manifest
from warp_shape.io.outputs import is_run_output

ROOT = Path(__file__).resolve().parents[1]
SMALL = ["--subdivisions", "2", "--actuators", "1", "--placement", "paper", "--codesign", "off"]


def snapshot(folder: Path) -> dict:
    """{name: SHA-256} of every entry in a folder (folders as 'dir')."""
    return {p.name: (file_digest(p) if p.is_file() else "dir") for p in sorted(folder.iterdir())}


def ipam_columns(csv_path: Path) -> int:
    with open(csv_path, newline="") as f:
        header = next(csv.reader(f))
    return len({c.split("_")[0] for c in header if c.startswith("ipam")})


def assert_whole_set(folder: Path, foreign=()) -> dict:
    """``folder`` holds exactly one run's set: the files its manifest lists, unchanged, and nothing
    else of a run; rounds, report, control sequences and design agree. Returns the report."""
    assert manifest_problems(folder) == []
    manifest = read_manifest(folder)
    names = {p.name for p in folder.iterdir()} - set(foreign)
    assert names == set(manifest["files"]) | {MANIFEST}, names ^ (set(manifest["files"]) | {MANIFEST})
    report = json.loads((folder / "report.json").read_text())
    rounds = json.loads((folder / "rounds.json").read_text())
    assert report["complete"] == manifest["complete"]
    assert rounds["targets"] == report["targets"]
    last = rounds["rounds"][-1]
    assert [r["round"] for r in rounds["rounds"]] == list(range(len(rounds["rounds"])))
    if not report["complete"]:
        assert report["rounds_done"] == len(rounds["rounds"])
    controls = {p.name for p in folder.glob("control_*.csv")}
    assert controls == {f"control_{t}.csv" for t in report["targets"]}
    for t in report["targets"]:
        assert ipam_columns(folder / f"control_{t}.csv") == len(last["ipams"]), t
    if report["complete"]:
        from warp_shape.io.scene_read import load_scene

        design = load_scene(folder / "design.usda").design
        assert [(ip.face_a, ip.face_b) for ip in design.ipams] == [(i["face_a"], i["face_b"]) for i in last["ipams"]]
        assert [sorted(c.faces.tolist()) for c in design.cells] == [sorted(c) for c in last["cells"]]
        assert report["actuators"] == len(last["ipams"])
    return report


def bad_scene(tmp_path: Path, line: str) -> Path:
    """The shipped oval_heart problem with one more designer setting line."""
    folder = tmp_path / "scene"
    folder.mkdir()
    for p in (ROOT / "scenes").glob("target_*.usda"):
        shutil.copy(p, folder / p.name)
    text = (ROOT / "scenes" / "oval_heart.usda").read_text()
    anchor = "custom double warpShape:designer:cell_radius"
    assert anchor in text
    (folder / "bad.usda").write_text(text.replace(anchor, f"{line}\n        {anchor}", 1))
    return folder / "bad.usda"


def fake_previous_set(out: Path) -> dict:
    staged = StagedFolder(out, owned=is_run_output)
    (staged.path / "report.json").write_text(json.dumps({"complete": True, "targets": ["heart"]}))
    (staged.path / "control_heart.csv").write_text("step,time\n0,0\n")
    staged.commit(True)
    return snapshot(out)


@pytest.mark.parametrize("line, message", [
    ("custom double warpShape:designer:ipam_stiffness = -1", "ipam_stiffness must be a finite number > 0"),
    ("custom double warpShape:designer:ipam_area = 0", "ipam_area must be a finite number > 0"),
    ("custom double warpShape:designer:cell_radiuss = 0.01", "unknown designer setting(s) ['cell_radiuss']"),
    ("custom double warpShape:designer:volume_scale = 2", "volume_scale must be in (0, 1]"),
])
def test_bad_setting_fails_before_anything_runs_or_is_written(tmp_path, monkeypatch, capsys, line, message):
    import warp_shape.designer.loop as designer_loop

    def no_control(*args, **kwargs):
        raise AssertionError("a control round ran before the settings were checked")

    monkeypatch.setattr(designer_loop, "control_many", no_control)
    out = tmp_path / "out"
    before = fake_previous_set(out)
    rc = main(["design", str(bad_scene(tmp_path, line)), "--out", str(out)])
    assert rc == 2 and message in capsys.readouterr().err
    assert snapshot(out) == before
    assert not (tmp_path / "out.partial").exists()


def test_staged_folder_replaces_the_previous_set_whole(tmp_path):
    out = tmp_path / "out"
    fake_previous_set(out)
    (out / "notes.txt").write_text("mine")  # not a run output: kept
    (out / "sub").mkdir()
    (out / "sub" / "scan.ply").write_text("ply")
    staged = StagedFolder(out, owned=is_run_output)
    (staged.path / "report.json").write_text(json.dumps({"complete": True, "targets": ["oval"]}))
    (staged.path / "control_oval.csv").write_text("step,time\n0,0\n")
    assert snapshot(out)["control_heart.csv"]  # nothing changes before the commit
    staged.commit(True)
    assert set(snapshot(out)) == {"report.json", "control_oval.csv", MANIFEST, "notes.txt", "sub"}
    assert (out / "notes.txt").read_text() == "mine" and (out / "sub" / "scan.ply").read_text() == "ply"
    assert manifest_problems(out) == [] and not (tmp_path / "out.partial").exists()
    # a run that fails leaves the set as it was
    before = snapshot(out)
    staged = StagedFolder(out, owned=is_run_output)
    (staged.path / "report.json").write_text("{}")
    staged.discard()
    assert snapshot(out) == before and not (tmp_path / "out.partial").exists()


def test_a_folder_that_is_not_a_run_folder_is_refused(tmp_path, monkeypatch, capsys):
    import warp_shape.io.atomic as atomic

    monkeypatch.chdir(tmp_path)
    err = main(["design", "--out", ".", *SMALL]) == 2 and capsys.readouterr().err
    assert "holds the current folder" in err and "--out out" in err
    err = main(["design", "--out", str(tmp_path.parent), *SMALL]) == 2 and capsys.readouterr().err
    assert "holds the current folder" in err
    monkeypatch.setattr(atomic, "MAX_FOREIGN_ENTRIES", 5)
    project = tmp_path / "project"
    (project / "src").mkdir(parents=True)
    for i in range(6):
        (project / "src" / f"m{i}.py").write_text("")
    before = snapshot(project)
    err = main(["design", "--out", str(project), *SMALL]) == 2 and capsys.readouterr().err
    assert "holds more than 5 files that are not outputs of a run" in err and snapshot(project) == before


def test_interrupt_keeps_the_previous_finished_run(tmp_path, ctrl_c_in_round_1, capsys):
    """Ctrl-C in round 1 into a folder holding a finished run: the folder is untouched, round 0 is
    kept whole in <out>.partial (rounds.json records it)."""
    out = tmp_path / "out"
    before = fake_previous_set(out)
    rc = main(["design", "--out", str(out), *SMALL, "--targets", "oval", "pear"])
    assert rc == 130 and "out.partial" in capsys.readouterr().err
    assert snapshot(out) == before
    partial = tmp_path / "out.partial"
    report = assert_whole_set(partial)
    assert report["complete"] is False and report["rounds_done"] == 1
    assert json.loads((partial / "rounds.json").read_text())["rounds"][0]["ipams"] == []
    assert not (tmp_path / ".out.lock").exists()


def test_a_design_that_stops_early_records_each_round_once(tmp_path, monkeypatch):
    """When no candidate set helps, the design is controlled again as the last round: rounds.json
    holds that round once, matching the saved design."""
    import warp_shape.designer.greedy as greedy

    real = greedy.greedy_placement

    def stop_in_round_1(current, results, ctx, i, *args, **kwargs):
        if i == 1:  # no candidate gains 99.9 %: the design stops
            ctx = dataclasses.replace(ctx, settings=ctx.settings.replace(min_gain=0.999))
        return real(current, results, ctx, i, *args, **kwargs)

    monkeypatch.setattr(greedy, "greedy_placement", stop_in_round_1)
    out = tmp_path / "out"
    assert main(["design", "--out", str(out), "--subdivisions", "2", "--actuators", "3", "--candidates", "1",
                 "--placement", "greedy", "--codesign", "off", "--targets", "oval"]) == 0
    report = assert_whole_set(out)
    rounds = json.loads((out / "rounds.json").read_text())["rounds"]
    assert [r["round"] for r in rounds] == [0, 1] and report["actuators"] == 1
    assert not (tmp_path / ".out.lock").exists()  # a finished run leaves no lock file


def test_a_second_run_into_the_same_folder_is_refused(tmp_path, monkeypatch, capsys):
    import fcntl

    import warp_shape.designer.loop as designer_loop

    monkeypatch.setattr(designer_loop, "control_many", lambda *a, **k: pytest.fail("the second run started"))
    out = tmp_path / "out"
    before = fake_previous_set(out)
    with open(tmp_path / ".out.lock", "w") as held:  # the first run, still running
        fcntl.flock(held, fcntl.LOCK_EX)
        held.write("4242")
        held.flush()
        assert main(["design", "--out", str(out), *SMALL]) == 2
    assert "another run (process 4242) is writing to" in capsys.readouterr().err
    assert snapshot(out) == before and not (tmp_path / "out.partial").exists()


ZYGOTE = r"""
import json, os, signal, sys, traceback
import warp_shape.io.atomic as atomic
import warp_shape.io.figures as figures
import warp_shape.cli.calibrate as cal_cli
from warp_shape.cli import main
def figure_files(kind, what, path, title, timing, *, progress=None):
    # a figure's file events (its PNG and SVG, each written atomically), without drawing it
    atomic.atomic_write(path, b"\x89PNG\r\n\x1a\n" + kind.encode())
    atomic.atomic_write(figures.svg_path(path), b"<svg/>")
    return path
figures.draw_figure = figure_files
# a calibration's fit (about 20 s here) replaced by the one a first run saved: the killed runs write the same
# files as the real one, without fitting again
import pickle
real_fit = cal_cli.calibrate
def cached_fit(*a, **kw):
    cache = os.environ["FIT_CACHE"]
    if not os.path.exists(cache):
        with open(cache, "wb") as f:
            pickle.dump(real_fit(*a, **kw), f)
    with open(cache, "rb") as f:
        result = pickle.load(f)
    result.values["youngs_modulus"] *= float(os.environ.get("FIT_SCALE", "1"))  # another set, the same files
    return result
cal_cli.calibrate = cached_fit
def count_events(k, log, watched, sig):
    count = [0]
    def counted(name, fn):
        def wrapper(*a, **kw):
            path = os.fspath(a[0]) if a else ""
            if name != "exchange" and os.path.isabs(path) and not path.startswith(watched):
                return fn(*a, **kw)  # not the run's folders (Warp's kernel cache, matplotlib's, ...)
            count[0] += 1
            with open(log, "a") as f:
                f.write(f"{count[0]} {name}\n")
            if count[0] == k:
                os.kill(os.getpid(), sig)
            return fn(*a, **kw)
        return wrapper
    for name in ("replace", "rename", "unlink", "rmdir", "link", "mkdir"):
        setattr(os, name, counted(name, getattr(os, name)))
    atomic._exchange = counted("exchange", atomic._exchange)
def run(req):
    old = dict(os.environ)
    os.environ.update(req["env"])
    try:
        return main(req["argv"])
    finally:
        os.environ.clear()
        os.environ.update(old)
answers = os.fdopen(os.dup(1), "w")  # the runs' own output goes to stderr, the answers to stdout
os.dup2(2, 1)
def answer(rc):
    answers.write(json.dumps(rc) + "\n")
    answers.flush()
for line in sys.stdin:
    req = json.loads(line)
    if not req["fork"]:  # in this process: the modules and kernels the command loads stay for the next runs
        answer(run(req))
        continue
    pid = os.fork()
    if pid == 0:
        rc = 99
        try:
            fd = os.open(req["stderr"], os.O_WRONLY | os.O_CREAT | os.O_TRUNC)
            os.dup2(fd, 1)
            os.dup2(fd, 2)
            if req["k"]:
                open(req["log"], "w").close()
            count_events(req["k"], req["log"], req["watched"], getattr(signal, "SIG" + req["signal"]))
            rc = run(req)
        except SystemExit as exc:
            rc = exc.code if isinstance(exc.code, int) else 1
        except BaseException:
            traceback.print_exc()
        finally:
            sys.stdout.flush()
            sys.stderr.flush()
            os._exit(rc)
    _, status = os.waitpid(pid, 0)
    answer(-os.WTERMSIG(status) if os.WIFSIGNALED(status) else os.WEXITSTATUS(status))
"""


class Zygote:
    """One process that has imported the package and run each command once, forking a child per run:
    the runs killed at a file event start in milliseconds instead of seconds (imports, Warp, kernels)."""

    def __init__(self):
        env = dict(os.environ, PYTHONPATH=str(ROOT))
        self.proc = subprocess.Popen([sys.executable, "-c", ZYGOTE], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                     env=env, text=True)

    def run(self, argv, log: Path, k: int = 0, env=None, fork: bool = True, sig: str = "KILL") -> int:
        """``warp-shape argv``, in a child that gets ``sig`` at its k-th file event in ``log``'s folder
        (0: none; the events are counted in ``log``); ``fork=False``: in the process itself, uncounted."""
        req = dict(argv=[str(a) for a in argv], log=str(log), watched=str(log.parent), k=k, env=env or {},
                   fork=fork, signal=sig, stderr=str(log.with_suffix(".err")))
        log.unlink(missing_ok=True)
        self.proc.stdin.write(json.dumps(req) + "\n")
        self.proc.stdin.flush()
        line = self.proc.stdout.readline()
        assert line, "the forking process ended"
        return json.loads(line)

    def stderr(self, log: Path) -> str:
        return log.with_suffix(".err").read_text()

    def close(self):
        self.proc.stdin.close()
        self.proc.wait(timeout=60)


@pytest.fixture(scope="module")
def zygote():
    z = Zygote()
    yield z
    z.close()


#: a design run of one actuator on a 42-vertex membrane (the killed runs' own problem)
TINY = ["--subdivisions", "1", "--actuators", "1", "--placement", "paper", "--codesign", "off", "--workers", "1"]


def design_problem(tmp_path: Path) -> Path:
    """A 42-vertex pear problem with the paper's law (its runs write the same files as the model-based
    controller's, sooner)."""
    return ws.save_scene(ws.Scene(design=ws.Design(rest=ws.icosphere(1, 0.04)), targets=[ws.target("pear")],
                                  target_names=["pear"], settings={"controller": {"method": "paper"}}),
                         tmp_path / "problem.usda")


def design_events(zygote, tmp_path: Path, problem: Path):
    """``out`` holding a finished oval-and-heart run (its snapshot returned), and the file events of the
    pear run that the kills interrupt (counted in a copy of it): (old snapshot, events, swap's index)."""
    out, ref, log = tmp_path / "out", tmp_path / "ref", tmp_path / "events.log"
    assert zygote.run(["design", problem, "--out", out, *TINY, "--targets", "oval", "heart"], log, fork=False) == 0
    shutil.copytree(out, tmp_path / "old")
    shutil.copytree(out, ref)
    assert zygote.run(["design", problem, *TINY, "--out", ref], log) == 0, zygote.stderr(log)
    events = log.read_text().split("\n")[:-1]
    swap = next(i for i, e in enumerate(events, 1) if e.endswith("exchange"))
    return snapshot(out), events, swap


@pytest.mark.slow
def test_sigkill_at_ten_points_leaves_one_whole_set(zygote, tmp_path):
    """A design run into a folder holding a different finished run, SIGKILLed at 10 points (file
    writes, renames, the folder swap, the removal of the old set): the folder holds one whole set
    every time, the old one until the swap, the new one after. The killed runs write their figures'
    files as the real ones are written (two atomic writes each) without drawing them."""
    out, log, problem = tmp_path / "out", tmp_path / "events.log", design_problem(tmp_path)
    old, events, swap = design_events(zygote, tmp_path, problem)
    points = sorted({*(round(1 + j * (swap - 2) / 6) for j in range(7)), swap, swap + 1, swap + 3})
    assert len(points) == 10 and points[-1] < len(events)
    for k in points:
        shutil.rmtree(tmp_path / "out.partial", ignore_errors=True)  # the same events in every run: no staging
        (tmp_path / ".out.lock").unlink(missing_ok=True)  # folder or lock of the last killed run to clear first
        rc = zygote.run(["design", problem, *TINY, "--out", out], log, k)
        assert rc == -signal.SIGKILL, (k, rc, zygote.stderr(log))
        report = assert_whole_set(out)
        if k <= swap:
            assert snapshot(out) == old, k
        else:
            assert report["targets"] == ["pear"] and report["complete"], k
    assert zygote.run(["design", problem, *TINY, "--out", out], log) == 0  # past a killed run's leftovers
    assert assert_whole_set(out)["targets"] == ["pear"]
    assert not list(out.glob("*heart*")) and not (tmp_path / "out.partial").exists()


def test_ctrl_c_at_any_point_of_the_outputs_is_130_with_the_old_set_or_0_with_the_new(zygote, tmp_path):
    """A real SIGINT at file events of a design run (the first, half-way, just before the swap, at the
    swap, after it): before the swap, exit 130 with "interrupted" and the previous set byte for byte in
    <out>; from the swap on (held until it ends), exit 0 with the new set whole (a SIGINT near the end
    of design returned 0 without the line; at the swap it said interrupted over the new set)."""
    out, log, problem = tmp_path / "out", tmp_path / "events.log", design_problem(tmp_path)
    old, events, swap = design_events(zygote, tmp_path, problem)
    for k in sorted({1, swap // 2, swap - 1, swap, swap + 1}):
        shutil.rmtree(tmp_path / "out.partial", ignore_errors=True)  # an interrupted run's finished rounds
        rc = zygote.run(["design", problem, *TINY, "--out", out], log, k, sig="INT")
        err = zygote.stderr(log)
        assert "Traceback" not in err and rc == (130 if k <= swap // 2 else 0 if k >= swap else rc), (k, rc, err)
        if rc != 0:  # just before the swap: as the swap's seal holds the press, either outcome, each whole
            assert rc == 130 and err.strip().splitlines()[-1] == "warp-shape: interrupted", (k, rc, err)
            assert snapshot(out) == old, k
        else:
            assert rc == 0 and "interrupted after the outputs were in place" in err, (k, rc, err)
            report = assert_whole_set(out)
            assert report["targets"] == ["pear"] and report["complete"], k
            assert not (tmp_path / "out.partial").exists() and not (tmp_path / ".out.lock").exists()
            shutil.rmtree(out)
            shutil.copytree(tmp_path / "old", out)  # the oval-and-heart set again


# ------------------------------------------------------------------------------- the user's files in --out
#: the files of a user's folder that look like a run's outputs (and one that does not)
USER_FILES = ["control_plan.txt", "valve_wiring.pdf", "mold_photo.jpg", "molds_notes.txt", "actuation_video.mp4",
              "report.md", "design.usda", "README.txt"]


def no_control(monkeypatch):
    import warp_shape.designer.loop as designer_loop

    monkeypatch.setattr(designer_loop, "control_many", lambda *a, **k: pytest.fail("work started before the check"))


def user_folder(folder: Path) -> dict:
    """A folder no run wrote: files named like outputs, a readme and a sub-folder."""
    (folder / "sub").mkdir(parents=True)
    (folder / "sub" / "scan.ply").write_text("ply")
    for name in USER_FILES:
        (folder / name).write_text(f"mine: {name}")
    return snapshot(folder)


def test_a_folder_of_user_files_is_refused_before_any_work(tmp_path, monkeypatch, capsys):
    """No manifest and files in it: not a run's folder to replace, however its files are named; a
    symbolic link to it is refused the same way, naming both."""
    no_control(monkeypatch)
    x = tmp_path / "X"
    before = user_folder(x)
    link = tmp_path / "L"
    link.symlink_to(x)
    for given, shown in ((x, str(x)), (link, f"{link} (a link to {x})")):
        assert main(["design", "--out", str(given), *SMALL]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and err.startswith(f"warp-shape: error: --out {shown} holds files no run wrote "
                                                       f"(README.txt, actuation_video.mp4, control_plan.txt, ")
        assert "and 3 more) and no manifest.json" in err and "give --out an empty or new folder" in err
        assert snapshot(x) == before and (x / "report.md").read_text() == "mine: report.md"
        assert not (tmp_path / "X.partial").exists() and link.is_symlink()


def test_a_run_folder_keeps_other_files_and_refuses_to_replace_the_users(tmp_path, monkeypatch, capsys):
    """In a folder of a run: a file no run wrote but named as outputs are, and a listed file changed
    since, are refused before any work; every other file and folder is kept by the next run."""
    out = tmp_path / "out"
    fake_previous_set(out)
    (out / "notes.txt").write_text("mine")
    (out / "sub").mkdir()
    (out / "sub" / "scan.ply").write_text("ply")
    (out / "mold_photo.jpg").write_text("jpeg")
    (out / "report.json").write_text('{"mine": 1}')  # listed in the manifest, edited since
    before = snapshot(out)
    with monkeypatch.context() as m:
        no_control(m)
        assert main(["design", "--out", str(out), *SMALL]) == 2
        err = capsys.readouterr().err
        assert f"--out {out} holds files named as a run's outputs that no run wrote (mold_photo.jpg)" in err
        (out / "mold_photo.jpg").rename(out / "sub" / "mold_photo.jpg")
        assert main(["design", "--out", str(out), *SMALL]) == 2
        err = capsys.readouterr().err
        assert f"--out {out}: report.json not as the run wrote (size or SHA-256 differs from manifest.json)" in err
    assert (out / "report.json").read_text() == '{"mine": 1}' and set(snapshot(out)) == set(before) - {"mold_photo.jpg"}
    (out / "report.json").unlink()  # the user takes the edited file away: nothing of theirs is listed now
    assert main(["design", "--out", str(out), *SMALL, "--targets", "oval"]) == 0
    assert assert_whole_set(out, foreign={"notes.txt", "sub"})["targets"] == ["oval"]
    assert (out / "notes.txt").read_text() == "mine" and (out / "sub" / "mold_photo.jpg").read_text() == "jpeg"
    assert not (out / "control_heart.csv").exists()  # the previous run's file, not written again: gone with it


def test_a_link_given_as_out_replaces_the_folder_it_points_to_and_stays(tmp_path):
    out, link = tmp_path / "out", tmp_path / "link"
    fake_previous_set(out)
    (out / "notes.txt").write_text("mine")
    link.symlink_to(out)
    staged = StagedFolder(link, owned=is_run_output)
    staged.check()
    assert staged.partial == tmp_path / "out.partial"
    (staged.path / "report.json").write_text(json.dumps({"complete": True, "targets": ["oval"]}))
    staged.commit(True)
    assert link.is_symlink() and link.resolve() == out
    assert set(snapshot(out)) == {"report.json", MANIFEST, "notes.txt"} and manifest_problems(out) == []
    dangling = tmp_path / "dangling"
    dangling.symlink_to(tmp_path / "nowhere")
    with pytest.raises(OutputError, match="is a symbolic link to .*nowhere, which does not exist"):
        StagedFolder(dangling).check()


def test_the_staging_folder_and_the_root_are_refused_in_one_line(tmp_path, monkeypatch, capsys):
    """``<out>.partial`` is removed when a run starts: never a link nor a folder of other files.
    ``--out /`` has no name to stage beside."""
    no_control(monkeypatch)
    out = tmp_path / "out"
    before = fake_previous_set(out)
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    (elsewhere / "keep.txt").write_text("mine")
    (tmp_path / "out.partial").symlink_to(elsewhere)
    assert main(["design", "--out", str(out), *SMALL]) == 2
    err = capsys.readouterr().err
    assert f"the staging folder {tmp_path / 'out.partial'} is a symbolic link" in err and err.count("\n") == 1
    (tmp_path / "out.partial").unlink()
    (tmp_path / "out.partial").mkdir()
    (tmp_path / "out.partial" / "thesis.tex").write_text("mine")
    assert main(["design", "--out", str(out), *SMALL]) == 2
    assert "holds files no run wrote (thesis.tex)" in capsys.readouterr().err
    assert (tmp_path / "out.partial" / "thesis.tex").exists() and (elsewhere / "keep.txt").exists()
    assert snapshot(out) == before
    assert main(["design", "--out", "/", *SMALL]) == 2
    assert capsys.readouterr().err == ("warp-shape: error: --out / is the root folder; a run replaces its output "
                                       "folder as a whole: give it a folder of its own, e.g. --out out\n")


def test_every_command_replaces_only_its_own_set(tmp_path, monkeypatch, capsys):
    """simulate, control and export stage their set and swap it into --out whole, as design does: a
    file under one of their names that no run wrote is refused, another command's set is never
    changed, and their own set (in the folder's manifest, with the command's name) is theirs to replace."""
    sim = ["simulate", "--subdivisions", "1", "--inflate-time", "0.01", "--actuate-time", "0.01"]
    folder = tmp_path / "sim"
    folder.mkdir()
    (folder / "simulate.json").write_text("mine")
    (folder / "notes.txt").write_text("kept")
    assert main([*sim, "--out", str(folder)]) == 2
    assert "holds files no run wrote (simulate.json)" in capsys.readouterr().err
    assert (folder / "simulate.json").read_text() == "mine"
    (folder / "simulate.json").unlink()
    for _ in range(2):  # the second run replaces the first one's set; the other file is kept
        assert main([*sim, "--out", str(folder)]) == 0
        manifest = read_manifest(folder)
        assert manifest_problems(folder) == [] and set(manifest["files"]) == {"simulate.json"}
        assert manifest["command"] == "simulate" and (folder / "notes.txt").read_text() == "kept"
    capsys.readouterr()
    no_control(monkeypatch)
    out = tmp_path / "out"
    before = fake_previous_set(out)
    assert main(["control", str(ROOT / "scenes" / "cube_fig6.usda"), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert f"--out {out} holds a design run's set" in err and f"--out {out / 'control'}" in err
    assert main([*sim, "--out", str(out)]) == 2
    assert f"--out {out} holds a design run's set" in capsys.readouterr().err
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "design.usda").write_text("my scene")
    assert main(["export", str(out / "design.usda"), "--out", str(mine)]) == 2
    assert "(design.usda)" in capsys.readouterr().err and (mine / "design.usda").read_text() == "my scene"
    assert snapshot(out) == before


# ------------------------------------------------------------- export, control and calibrate killed mid-write
@pytest.fixture(scope="module")
def small_lab(tmp_path_factory):
    """A 42-vertex Fig. 6 design with the paper's law, its scene, a scan of it inflated and a manifest."""
    import numpy as np
    import trimesh

    from warp_shape.model import host_model
    from warp_shape.scan import surface_samples
    from warp_shape.scenarios import cube_fig6_design

    root = tmp_path_factory.mktemp("small_lab")
    design = cube_fig6_design(subdivisions=1)
    ws.save_scene(ws.Scene(design=design, targets=[ws.target("oval")], target_names=["oval"],
                           settings={"controller": {"method": "paper", "max_steps": 4}}), root / "design.usda")
    trimesh.PointCloud(surface_samples(design.rest, 400) * 1.05e3).export(root / "scan.ply")
    state = {"air_mol": host_model(design).rest_air * 1.3, "ipam_pressures_kpa": [0] * design.n_ipams, "jammed": []}
    (root / "manifest.json").write_text(json.dumps({"observations": [{"scan": "scan.ply", "state": state}]}))
    return root


def _kill_cases(lab: Path):
    """(command, first run's flags, the next run's flags): each pair writes two different sets."""
    scene = str(lab / "design.usda")
    cal = ["calibrate", str(lab / "manifest.json"), "--design", scene, "--wrt", "youngs_modulus"]
    return {"export": (["export", scene, "--what", "molds", "usd", "--mold-units", "cm"],
                       ["export", scene, "--what", "molds", "usd", "--mold-units", "mm"]),
            "control": (["control", scene, "--max-steps", "3"], ["control", scene, "--max-steps", "4"]),
            "calibrate": (cal, cal)}


@pytest.mark.parametrize("command", ["export", "control", "calibrate"])
def test_a_command_killed_at_three_points_of_its_writes_keeps_the_previous_set(small_lab, zygote, tmp_path, command):
    """export, control and calibrate SIGKILLed at their first file event, half-way and at the swap:
    ``--out`` holds the previous set byte for byte (its manifest whole) each time, and the next run
    into it succeeds with no hand work (today they wrote file by file: a set mixing two runs, then
    refused as the user's files). A calibration's fit is the one the first run saved."""
    first, second = _kill_cases(small_lab)[command]
    out, log, ref = tmp_path / "out", tmp_path / "events.log", tmp_path / "ref"
    env = {"FIT_CACHE": str(tmp_path / "fit.pickle")}
    assert zygote.run([*first, "--out", out], log, env=dict(env, FIT_SCALE="1.01"), fork=False) == 0
    old = snapshot(out)
    assert manifest_problems(out) == [] and read_manifest(out)["command"] == command
    shutil.copytree(out, ref)
    assert zygote.run([*second, "--out", ref], log, env=env) == 0, zygote.stderr(log)  # counting its events
    assert snapshot(ref) != old
    events = log.read_text().split("\n")[:-1]
    swap = next(i for i, e in enumerate(events, 1) if e.endswith("exchange"))
    for k in sorted({1, swap // 2, swap}):
        rc = zygote.run([*second, "--out", out], log, k, env=env)
        assert rc == -signal.SIGKILL, (k, rc, zygote.stderr(log))
        assert snapshot(out) == old and manifest_problems(out) == [], k
    assert zygote.run([*second, "--out", out], log, env=env) == 0  # past the killed runs' leftovers
    assert manifest_problems(out) == [] and not (tmp_path / "out.partial").exists()
    assert set(snapshot(out)) == set(snapshot(ref))


# --------------------------------------------------------------------- no write through a link, nor over a file
SIM = ["simulate", "--subdivisions", "1", "--inflate-time", "0.01", "--actuate-time", "0.01"]


@pytest.mark.parametrize("make, message", [
    (lambda lock, mine: lock.symlink_to(mine), "is a symbolic link"),
    (lambda lock, mine: lock.mkdir(), "is a folder"),
    (lambda lock, mine: lock.write_text("my notes\n"), "holds something else than a run's process id"),
])
def test_a_lock_that_is_not_a_runs_is_one_line_and_left_as_it_is(tmp_path, capsys, make, message):
    """The folder lock is made anew (O_EXCL, O_NOFOLLOW) and never truncates a file it did not make:
    a link there (today: the linked file's content replaced by a process id), a folder (today:
    IsADirectoryError) or a file of the user's is one line; the file the link points to is unchanged."""
    mine, lock = tmp_path / "t.tex", tmp_path / ".out.lock"
    mine.write_text("work")
    make(lock, mine)
    err = one_line_error(capsys, 2, [*SIM, "--out", str(tmp_path / "out")])
    assert f"the lock file {lock} {message}" in err
    assert mine.read_text() == "work" and not (tmp_path / "out").exists()
    assert lock.is_symlink() or lock.is_dir() or lock.read_text() == "my notes\n"


def test_a_lock_left_by_a_killed_run_is_taken_and_removed(tmp_path, capsys):
    """A lock file holding the process id of a run that ended (no one holds it): replaced, then gone."""
    (tmp_path / ".out.lock").write_text("999999")
    assert main([*SIM, "--out", str(tmp_path / "out")]) == 0
    assert not (tmp_path / ".out.lock").exists() and manifest_problems(tmp_path / "out") == []


def one_line_error(capsys, rc: int, argv) -> str:
    assert main(argv) == rc, argv
    err = without_progress(capsys.readouterr().err).strip()  # a log's progress lines, then the error
    assert "Traceback" not in err and err.count("\n") == 0, err
    return err


def test_export_waits_for_no_run_but_refuses_a_folder_a_run_is_writing(tmp_path, capsys):
    """export honours the folder's lock (today it wrote its files while a design ran into the folder,
    whose swap then replaced them)."""
    import fcntl

    out = tmp_path / "X"
    with open(tmp_path / ".X.lock", "w") as held:
        fcntl.flock(held, fcntl.LOCK_EX)
        held.write("4242")
        held.flush()
        err = one_line_error(capsys, 2, ["export", "cube_fig6", "--what", "molds", "--out", str(out)])
    assert "another run (process 4242) is writing to" in err and not out.exists()
    assert not (tmp_path / "X.partial").exists()


def test_rerun_never_replaces_an_input_a_file_or_an_output(tmp_path, monkeypatch, capsys):
    """--rerun onto the scene the run reads, onto a file that is no recording, onto the output set's
    own names: refused before any work, the file unchanged (today each was replaced)."""
    pytest.importorskip("rerun")
    no_control(monkeypatch)
    scene = ws.save_scene(ws.Scene(design=ws.Design(rest=ws.icosphere(1, 0.04)), targets=[ws.target("oval")],
                                   target_names=["oval"]), tmp_path / "design.usda")
    before = scene.read_bytes()
    err = one_line_error(capsys, 2, ["control", str(scene), "--out", str(tmp_path / "c"), "--rerun", str(scene)])
    assert "is an input of this run" in err and scene.read_bytes() == before
    thesis = tmp_path / "thesis.tex"
    thesis.write_text("\\chapter{One}")
    err = one_line_error(capsys, 2, ["design", *SMALL, "--out", str(tmp_path / "r"), "--rerun", str(thesis)])
    assert "is not a rerun recording" in err and thesis.read_text() == "\\chapter{One}"
    out = tmp_path / "out"
    fake_previous_set(out)
    kept = snapshot(out)
    for name in ("manifest.json", "report.json", "control_oval.csv"):
        err = one_line_error(capsys, 2, ["design", *SMALL, "--out", str(out), "--rerun", str(out / name)])
        assert "is named as one of this run's outputs" in err, name
    assert snapshot(out) == kept
    link = tmp_path / "link.rrd"
    link.symlink_to(thesis)
    assert "is a symbolic link" in one_line_error(capsys, 2, [*SIM, "--out", str(tmp_path / "s"), "--rerun", str(link)])
    assert thesis.read_text() == "\\chapter{One}"


def test_calibrate_and_bench_refuse_the_users_files_before_any_work(tmp_path, monkeypatch, capsys):
    """A calibration.md or calibration.json of the user's in calibrate's --out, a bench_rays.json in
    bench's (today both replaced): one line, before the fit or the bench."""
    import warp_shape.cli.calibrate as cal_cli

    monkeypatch.setattr(cal_cli, "calibrate", lambda *a, **k: pytest.fail("the fit started"))
    manifest = tmp_path / "m.json"
    manifest.write_text('{"observations": []}')
    for name in ("calibration.md", "calibration.json"):
        out = tmp_path / name.replace(".", "_")
        out.mkdir()
        (out / name).write_text("my notes")
        err = one_line_error(capsys, 2, ["calibrate", str(manifest), "--design", "cube_fig6", "--out", str(out)])
        assert f"holds files no run wrote ({name})" in err and (out / name).read_text() == "my notes"
    bench = tmp_path / "bench"
    bench.mkdir()
    (bench / "bench_rays.json").write_text("{}")
    err = one_line_error(capsys, 2, ["bench", "rays", "--out", str(bench)])
    assert "holds files no run wrote (bench_rays.json)" in err and (bench / "bench_rays.json").read_text() == "{}"


@pytest.mark.parametrize("command, module, name", [("export", "warp_shape.cli.export", "write_molds"),
                                                   ("control", "warp_shape.cli.control", "write_control_outputs"),
                                                   ("calibrate", "warp_shape.cli.calibrate", "calibrate")])
def test_ctrl_c_while_a_command_writes_keeps_the_previous_set(small_lab, tmp_path, monkeypatch, capsys,
                                                              command, module, name):
    """Ctrl-C (SIGINT) after export's or control's first staged file, or during calibrate's fit: exit 130
    with one line, the previous set whole, no staging folder, no lock; the next run goes ahead."""
    import importlib

    cli_module = importlib.import_module(module)
    out = tmp_path / "out"
    staged = StagedFolder(out, command=command)
    (staged.path / ("calibration.md" if command == "calibrate" else "control_old.csv")).write_text("previous")
    staged.commit(True)
    before = snapshot(out)
    real = getattr(cli_module, name)

    def interrupted(*args, **kwargs):
        if command != "calibrate":
            real(*args, **kwargs)  # its files staged, then the press
        raise KeyboardInterrupt

    monkeypatch.setattr(cli_module, name, interrupted)
    first = _kill_cases(small_lab)[command][1]
    assert main([*first, "--out", str(out)]) == 130
    assert capsys.readouterr().err.strip().splitlines()[-1] == "warp-shape: interrupted"
    assert snapshot(out) == before and not (tmp_path / "out.partial").exists()
    assert not (tmp_path / ".out.lock").exists()
