"""Sweeps: the plan of runs, checked parameters, the streamed results table, resuming, Ray against serial,
a worker killed mid-sweep."""

from __future__ import annotations

import csv
import ipaddress
import json
import logging
import os
import signal
import socket
import sys
import types

import pytest

import warp_shape as ws
from warp_shape.cli import main
from warp_shape.sweeps import SweepError, execute, parse_param
from warp_shape.sweeps.backends import check_address, start_ray
from warp_shape.sweeps.plan import grid_plan, load_problem, subsets_plan

#: a tiny run: 162-vertex base mesh, one IPAM, the paper's law, short control, the placed design (co-design off)
TINY = {"subdivisions": 2, "method": "paper", "max_steps": 60, "codesign": "off"}
NUMBERS = ("objective", "pcc_oval", "pcc_heart", "mare_oval_m", "mare_heart_m", "mpre_oval_pct", "mpre_heart_pct")


def tiny_sweep(out, **kw):
    return ws.sweep("subsets", targets=["oval", "heart"], actuators=1, fixed=dict(TINY), out=out, **kw)


def read_csv(path):
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def test_subsets_plan_is_every_nonempty_subset_and_grid_the_product():
    problem = load_problem(None, ["oval", "pear", "heart", "cube"], {"actuators": 5})
    runs = subsets_plan(problem)
    subsets = {tuple(t.target_names) for t in runs}
    assert len(runs) == len(subsets) == 15 and {len(s) for s in subsets} == {1, 2, 3, 4}
    assert all(t.actuators == 5 for t in runs) and len({t.run_id for t in runs}) == 15
    grid = grid_plan(load_problem("four_targets_20", ["oval", "cube"]),
                     [parse_param("actuators=5,10,20"), parse_param("cell_radius=0.006,0.012")])
    assert [(t.actuators, t.settings["designer"]["cell_radius"]) for t in grid] == [
        (5, 0.006), (5, 0.012), (10, 0.006), (10, 0.012), (20, 0.006), (20, 0.012)]
    assert all(t.target_names == ["oval", "cube"] for t in grid)


def test_any_setting_can_be_swept_and_bad_names_or_values_are_refused_before_any_run(tmp_path, capsys):
    p = parse_param("youngs_modulus=5e4,9e4")
    assert (p.group, p.values) == ("material", (5e4, 9e4))
    assert parse_param("controller.max_steps=10,20").values == (10, 20)
    with pytest.raises(SweepError, match="did you mean cell_radius"):
        parse_param("cel_radius=0.01")
    with pytest.raises(SweepError, match="youngs_modulus must be > 0"):
        parse_param("youngs_modulus=-1")
    with pytest.raises(SweepError, match="method.*choose one of"):
        parse_param("method=fast")
    rc = main(["sweep", "grid", "--param", "actuator=5,10", "--backend", "serial", "--out", str(tmp_path / "s")])
    assert rc == 2 and "did you mean actuators" in capsys.readouterr().err
    assert not (tmp_path / "s").exists()  # refused before anything was written


def test_an_address_where_no_cluster_listens_is_a_quick_clear_error():
    with socket.socket() as s:  # a port nothing listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    with pytest.raises(SweepError, match=f"no Ray cluster answers at 127.0.0.1:{port}.*ray start --head"):
        check_address(f"127.0.0.1:{port}")
    with pytest.raises(SweepError, match="HOST:PORT"):
        check_address("headnode")


def test_sweep_without_ray_says_how_to_install_it(tmp_path, monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "ray", None)  # import ray -> ImportError
    rc = main(["sweep", "subsets", "--targets", "oval", "--out", str(tmp_path / "s")])
    err = capsys.readouterr().err
    assert rc == 2 and "pip install 'warp-shape[cluster]'" in err and "--backend serial" in err


@pytest.fixture(scope="module")
def serial_sweep(tmp_path_factory):
    """The tiny sweep from the command line, serially; its rows as ``ws.sweep`` returns them."""
    out = tmp_path_factory.mktemp("serial")
    fixed = [a for k, v in TINY.items() for a in ("--set", f"{k}={v}")]
    assert main(["sweep", "subsets", "--targets", "oval", "heart", "--actuators", "1", *fixed, "--backend", "serial",
                 "--out", str(out)]) == 0
    rows = json.loads((out / "results.json").read_text())["rows"]
    return out, types.SimpleNamespace(rows=rows)


def test_serial_sweep_writes_one_row_per_run_with_the_design_outputs(serial_sweep):
    out, _ = serial_sweep
    rows = read_csv(out / "results.csv")
    assert [r["targets"] for r in rows] == ["oval", "heart", "oval heart"]
    assert list(rows[0])[:4] == ["run_id", "targets", "actuators", "objective"]
    assert list(rows[0])[-4:] == ["wall_s", "status", "error", "out_dir"]
    assert all(r["status"] == "ok" and r["error"] == "" for r in rows)
    assert rows[0]["pcc_heart"] == "" and rows[1]["pcc_oval"] == ""  # a run without that target
    for r in rows:
        report = json.loads((out / r["out_dir"] / "report.json").read_text())
        assert report["complete"] and report["targets"] == r["targets"].split()
        for name in report["targets"]:  # the row is the run's own report, to the last digit
            assert float(r[f"pcc_{name}"]) == report["final"][name]["pcc"]
            assert float(r[f"mare_{name}_m"]) == report["final"][name]["mare_m"]
        assert {"design.usda", "report.md"} <= set(report["outputs"]) and any(n.startswith("mold_")
                                                                               for n in report["outputs"])
        assert all((out / r["out_dir"] / n).is_file() for n in report["outputs"])  # as `design` wrote them
        assert 0.5 < float(r["pcc_oval" if "oval" in r["targets"] else "pcc_heart"]) <= 1.0
    assert (out / "summary.md").read_text().count("| ok |") == 3 and (out / "summary.png").stat().st_size > 1000


def test_a_run_is_the_design_command_with_the_same_settings(tmp_path):
    """A sweep run and ``warp-shape design`` with the same problem and settings reach the same fit and
    write the same files."""
    assert main(["design", "--targets", "oval", "--actuators", "1", "--subdivisions", "2", "--placement", "paper",
                 "--codesign", "off", "--out", str(tmp_path / "design")]) == 0
    res = ws.sweep("grid", targets=["oval"], params={"actuators": [1]},
                   fixed={"subdivisions": 2, "placement": "paper", "codesign": "off"}, out=tmp_path / "sweep",
                   backend="serial")
    row = res.rows[0]
    by_design = json.loads((tmp_path / "design" / "report.json").read_text())
    by_sweep = json.loads((tmp_path / "sweep" / row["out_dir"] / "report.json").read_text())
    assert row["pcc_oval"] == by_design["final"]["oval"]["pcc"] and row["mare_oval_m"] == by_design["final"]["oval"]["mare_m"]
    timeless = lambda final: {k: v for k, v in final["oval"].items() if k != "refinement"}  # noqa: E731
    assert timeless(by_sweep["final"]) == timeless(by_design["final"])
    assert by_sweep["pcc_by_round"] == by_design["pcc_by_round"] and by_sweep["added"] == by_design["added"]
    assert set(by_sweep["outputs"]) == set(by_design["outputs"])
    for name in ("rounds.json", "control_oval.csv"):
        assert (tmp_path / "sweep" / row["out_dir"] / name).read_bytes() == (tmp_path / "design" / name).read_bytes()


def test_rerun_skips_finished_runs_and_a_different_sweep_is_refused(serial_sweep):
    out, first = serial_sweep
    again = tiny_sweep(out, backend="serial")  # the same sweep from Python: nothing left to run
    assert (again.ran, again.skipped) == (0, 3) and again.rows == first.rows
    with pytest.raises(SweepError, match="different sweep"):
        ws.sweep("subsets", targets=["oval", "pear"], actuators=1, fixed=dict(TINY), out=out, backend="serial")


def test_a_rerun_runs_again_a_finished_run_whose_outputs_were_deleted(serial_sweep):
    out, first = serial_sweep
    lost = out / first.rows[0]["out_dir"] / "design.usda"
    lost.unlink()  # its row says ok, its folder is there, but its manifest's file is gone
    again = tiny_sweep(out, backend="serial")
    assert (again.ran, again.skipped) == (1, 2) and lost.is_file()


def test_a_second_sweep_into_a_busy_folder_is_refused(tmp_path):
    from warp_shape.sweeps.results import ResultsTable

    busy = ResultsTable(tmp_path, [], {})
    busy.lock()  # as a sweep running in another process holds it
    try:
        with pytest.raises(SweepError, match=f"another sweep \\(process {os.getpid()}\\) is writing"):
            tiny_sweep(tmp_path, backend="serial")
    finally:
        busy.unlock()
    assert not (tmp_path / "results.csv").exists()


def test_a_failing_run_records_its_error_and_the_sweep_goes_on(tmp_path):
    res = ws.sweep("grid", targets=["oval"], params={"cell_radius": [0.2, 0.012], "actuators": [1]}, fixed=TINY,
                   out=tmp_path, backend="serial")
    bad, good = res.rows
    assert (bad["cell_radius"], good["cell_radius"], good["actuators"]) == (0.2, 0.012, 1)
    assert bad["status"] == "error" and "DesignError" in bad["error"] and "cell" in bad["error"]
    assert bad["out_dir"] == "" and "objective" not in bad
    assert good["status"] == "ok" and good["pcc_oval"] > 0.5
    rows = read_csv(tmp_path / "results.csv")
    assert [r["status"] for r in rows] == ["error", "ok"] and list(rows[0])[:4] == ["run_id", "targets", "actuators",
                                                                                    "cell_radius"]


# --- Ray -------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def ray_local():
    """The sweep's own local Ray instance (``start_ray``, as ``--backend ray`` without ``--address``)."""
    ray = pytest.importorskip("ray")
    assert start_ray(None, 2)[0]
    ray.cloudpickle.register_pickle_by_value(sys.modules[__name__])  # run_fn below, on the workers
    yield ray
    ray.shutdown()


def process_tree(root: int) -> dict[int, str]:
    """{pid: command name} of ``root`` and every process descended from it, from /proc."""
    parent, name = {}, {}
    for entry in os.listdir("/proc"):
        try:
            stat = open(f"/proc/{entry}/stat").read() if entry.isdigit() else ""
        except OSError:  # exited meanwhile
            continue
        if stat:
            head, _, rest = stat.rpartition(")")
            parent[int(entry)], name[int(entry)] = int(rest.split()[1]), head.partition("(")[2]
    tree, grew = {root}, True
    while grew:
        more = {pid for pid, ppid in parent.items() if ppid in tree} - tree
        tree |= more
        grew = bool(more)
    return {pid: name.get(pid, "?") for pid in tree}


def listening_tcp() -> dict[int, tuple[ipaddress._BaseAddress, int]]:
    """{socket inode: (address, port)} of every TCP socket in LISTEN state (/proc/net/tcp and tcp6)."""
    out = {}
    for table in ("/proc/net/tcp", "/proc/net/tcp6"):
        with open(table) as f:
            for line in f.readlines()[1:]:
                fields = line.split()
                if fields[3] != "0A":  # LISTEN
                    continue
                host, port = fields[1].split(":")
                raw = bytes.fromhex(host)  # 32-bit words in host (little-endian) order
                addr = ipaddress.ip_address(b"".join(raw[i:i + 4][::-1] for i in range(0, len(raw), 4)))
                out[int(fields[9])] = (addr, int(port, 16))
    return out


def socket_inodes(pid: int) -> set[int]:
    """The inodes of the sockets process ``pid`` holds open."""
    inodes = set()
    try:
        fds = os.listdir(f"/proc/{pid}/fd")
    except OSError:  # exited meanwhile
        return inodes
    for fd in fds:
        try:
            link = os.readlink(f"/proc/{pid}/fd/{fd}")
        except OSError:  # closed meanwhile (the listing's own descriptor among them)
            continue
        if link.startswith("socket:["):
            inodes.add(int(link[8:-1]))
    return inodes


def is_loopback(addr) -> bool:
    return addr.is_loopback or bool(getattr(addr, "ipv4_mapped", None) and addr.ipv4_mapped.is_loopback)


def worker_pid() -> int:
    return os.getpid()


def test_the_local_ray_instance_listens_on_the_loopback_interface_only(ray_local):
    worker = ray_local.get(ray_local.remote(worker_pid).remote())
    tree = process_tree(os.getpid())
    assert {"gcs_server", "raylet"} <= set(tree.values()) and worker in tree
    listening, found = listening_tcp(), []
    for pid, name in tree.items():
        for inode in socket_inodes(pid) & listening.keys():
            found.append((name, pid, *listening[inode]))
    owners = {pid for _, pid, _, _ in found}
    assert {os.getpid(), worker} <= owners and {"gcs_server", "raylet"} <= {name for name, *_ in found}
    assert [f for f in found if not is_loopback(f[2])] == []


def test_ray_runs_give_the_numbers_of_the_serial_runs(ray_local, serial_sweep, tmp_path):
    _, serial = serial_sweep
    res = tiny_sweep(tmp_path, backend="ray", workers=2)
    assert res.ran == 3 and not res.failed
    for s, r in zip(serial.rows, res.rows):
        assert s["run_id"] == r["run_id"]
        assert {k: s.get(k) for k in NUMBERS} == {k: r.get(k) for k in NUMBERS}


def kill_once(marker_dir):
    """A run function whose run ``heart`` kills its own worker process the first time it is tried."""
    def run(task):
        marker = os.path.join(marker_dir, f"{task.run_id}.tried")
        if task.run_id == "heart" and not os.path.exists(marker):
            open(marker, "w").close()
            os.kill(os.getpid(), signal.SIGKILL)
        return execute(task)
    return run


def test_worker_killed_mid_sweep_keeps_finished_rows_and_a_rerun_completes_only_the_missing_run(
        ray_local, serial_sweep, tmp_path):
    _, serial = serial_sweep
    out, markers = tmp_path / "sweep", tmp_path / "markers"
    markers.mkdir()
    first = tiny_sweep(out, backend="ray", workers=2, retries=0, run_fn=kill_once(str(markers)))
    status = {r["run_id"]: r["status"] for r in read_csv(out / "results.csv")}
    assert status == {"oval": "ok", "heart": "error", "oval+heart": "ok"}
    assert "WorkerCrashedError" in first.failed[0]["error"] and not (out / "runs" / "heart").exists()
    again = tiny_sweep(out, backend="ray", workers=2, retries=0, run_fn=kill_once(str(markers)))
    assert (again.ran, again.skipped) == (1, 2) and not again.failed
    assert [r["status"] for r in read_csv(out / "results.csv")] == ["ok"] * 3
    assert {k: again.rows[1].get(k) for k in NUMBERS} == {k: serial.rows[1].get(k) for k in NUMBERS}


def test_a_killed_worker_is_retried_within_the_sweep(ray_local, tmp_path):
    markers = tmp_path / "markers"
    markers.mkdir()
    res = ws.sweep("subsets", targets=["heart"], actuators=1, fixed=dict(TINY), out=tmp_path / "s", backend="ray",
                   retries=1, run_fn=kill_once(str(markers)))
    assert (markers / "heart.tried").exists() and res.ran == 1 and not res.failed


def test_grid_summary_ticks_counts_at_the_swept_values_only(tmp_path):
    pytest.importorskip("matplotlib")
    from warp_shape.sweeps.summary import build_summary_figure, write_summary

    rows = [dict(status="ok", targets="oval", actuators=a, pcc_oval=p) for a, p in ((1, 0.91), (2, 0.95))]
    ax = build_summary_figure(rows, ["oval"], ["actuators"], "grid").axes[0]
    assert [t.get_text() for t in ax.get_xticklabels()] == ["1", "2"]  # no 1.2, 1.4 actuators
    written = write_summary(tmp_path, rows, ["oval"], ["actuators"], "grid")
    assert {p.name for p in written} == {"summary.md", "summary.png", "summary.svg"}


def test_the_summary_shows_a_mare_that_got_worse_while_the_pcc_rose():
    """A sweep where one more actuator raised the PCC (0.91 -> 0.95) but worsened the MARE (1.32 -> 1.55 mm):
    the figure has a MARE panel in mm and an objective panel beside the PCC, and the worse MARE is crossed in
    red; a subsets sweep boxes a joint design's value worse than the target designed alone."""
    pytest.importorskip("matplotlib")
    from warp_shape.sweeps.summary import build_summary_figure

    rows = [dict(status="ok", targets="oval", actuators=a, pcc_oval=p, mare_oval_m=m, objective=o)
            for a, p, m, o in ((1, 0.91, 1.32e-3, 0.020), (2, 0.95, 1.55e-3, 0.018))]
    fig = build_summary_figure(rows, ["oval"], ["actuators"], "grid")
    pcc, mare, objective = fig.axes[:3]
    assert "MARE (mm)" in mare.get_ylabel() and "objective" in objective.get_ylabel()
    drawn = {tuple(round(float(y), 6) for y in line.get_ydata()) for line in mare.get_lines()}
    assert (1.32, 1.55) in drawn  # the MARE in mm, not metres
    crosses = [line for ax in (pcc, mare, objective) for line in ax.get_lines() if line.get_color() == "red"]
    assert len(crosses) == 1 and crosses[0] in mare.get_lines()  # only the MARE got worse
    assert list(crosses[0].get_xydata()[0]) == pytest.approx([2, 1.55])

    rows = [dict(status="ok", targets="oval", pcc_oval=0.95, mare_oval_m=1.3e-3, objective=0.01),
            dict(status="ok", targets="heart", pcc_heart=0.90, mare_heart_m=2.0e-3, objective=0.02),
            dict(status="ok", targets="oval heart", pcc_oval=0.96, mare_oval_m=1.5e-3, pcc_heart=0.88,
                 mare_heart_m=1.8e-3, objective=0.03)]
    fig = build_summary_figure(rows, ["oval", "heart"], [], "subsets")
    boxed = {ax.get_title(): [(p.get_x() + 0.5, p.get_y() + 0.5) for p in ax.patches] for ax in fig.axes[:3]}
    assert boxed == {"PCC": [(1, 2)], "MARE (mm)": [(0, 2)], "objective": []}  # heart's PCC, oval's MARE worse


def test_rays_token_notice_is_left_out_while_a_local_instance_starts():
    """Ray >= 2.59 says "Token authentication is enabled ..." on every local start (docs/sweeps.md says it
    once): left out while the sweep starts its instance; Ray's other warnings still pass, and the notice
    shows again afterwards."""
    pytest.importorskip("ray")
    from ray._private.authentication import authentication_token_setup as setup

    from warp_shape.sweeps.backends import quiet_token_notice

    class Keep(logging.Handler):
        def __init__(self):
            super().__init__(logging.WARNING)
            self.said = []

        def emit(self, record):
            self.said.append(record.getMessage()[:36])

    keep = Keep()
    setup.logger.addHandler(keep)  # Ray's loggers do not propagate to the root
    try:
        with quiet_token_notice():
            setup._warn_token_auth_enabled()
            setup._warn_token_auth_disabled()
        assert keep.said == ["Token authentication is disabled for"]
        setup._warn_token_auth_enabled()
        assert keep.said[-1] == "Token authentication is enabled for "
    finally:
        setup.logger.removeHandler(keep)
