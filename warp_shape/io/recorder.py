"""Rerun recordings of simulations, control runs and design runs, for visual debugging.

``Recorder`` implements the hooks that ``ws.control`` / ``ws.control_many`` / ``ws.design`` call
when given ``recorder=`` (``begin_run``, ``log_control_step``, ``end_run``, ``log_design_round``),
plus ``begin_simulation`` / ``log_sim_frame`` for plain simulations. Everything it does is host-side
numpy and rerun logging: no Warp launches. Without a recorder the controller does nothing extra.

Entity paths (``{run}`` is the run prefix: ``control``, ``design/round_<i>`` or ``simulate``;
``{name}`` the target name, or ``world<w>`` in a plain simulation):

  {run}/{name}                   Transform3D: targets of one run side by side along x (static)
  {run}/{name}/membrane          Mesh3D: triangle indices once (static), positions and per-vertex
                                 colours per frame (radial error |r| - |R| to the sampled target,
                                 blue inside - white - red outside, saturating at +-ERROR_RANGE_M;
                                 in a plain simulation the radial displacement from rest)
  {run}/{name}/target            Mesh3D: the centred target, translucent grey ghost (static)
  {run}/{name}/ipams             LineStrips3D: one segment per IPAM between its end-face centroids,
                                 blue when pushing (F < 0), red when pulling (F > 0), saturating at
                                 +-FORCE_RANGE_N
  {run}/{name}/cells             Mesh3D: the faces of every jamming cell, lifted 0.4 % outward,
                                 grey while free, green once jammed
  {run}/{name}/volume            Scalars [V, V_t] (m^3)
  {run}/{name}/pressure          Scalars [p] gauge (Pa)
  {run}/{name}/ipam/length       Scalars [L_0..L_n-1, L_t0..L_tn-1] (m)
  {run}/{name}/ipam/force        Scalars [F_0..] (N, + = tension)
  {run}/{name}/ipam/pressure     Scalars [P_0..] (Pa)
  {run}/{name}/cell/kappa        Scalars [kappa_0.., kappa_t0..] (m)
  {run}/{name}/cell/jammed       Scalars [0/1 per cell]
  {run}/{name}/fit/pcc           Scalars [PCC]
  {run}/{name}/fit/mare          Scalars [MARE] (m)
  {run}/{name}/fit/mpre          Scalars [MPRE] (%)
  {run}/{name}/summary           TextDocument: the run's outcome (static, at the end)
  design/pcc/{name}              Scalars [PCC] on the ``round`` timeline (one row per design round)

Timelines: ``control_step`` (sequence) and ``sim_time`` (duration, s) for control runs;
``sim_step`` (sequence) and ``sim_time`` for plain simulations; ``round`` (sequence) for the PCC by
design round. The series styling (names, colours) is static per entity.
"""

from __future__ import annotations

import os
import shutil
import socket
import subprocess
import sys
import tempfile
import uuid
from pathlib import Path

import numpy as np

from ..errors import DesignError
from .atomic import atomic_write, finalize_permissions

__all__ = ["Recorder", "diverging_colors", "viewer_problem", "spawn_viewer", "ERROR_RANGE_M", "FORCE_RANGE_N",
           "VIEWER_PORT"]

#: seconds a recording's flush may take: rerun's default (no bound) waits forever when its file writer has
#: stopped on a full disk, a bounded flush raises at once
FLUSH_TIMEOUT = 600.0
VIEWER_PORT = 9876  # the rerun viewer's usual port, on the loopback interface only

ERROR_RANGE_M = 5e-3  # radial error (m) at which the membrane colour saturates
FORCE_RANGE_N = 2.0  # IPAM axial force (N) at which the segment colour saturates
CELL_LIFT = 1.004  # cell overlay drawn this factor outward (radially) so it does not z-fight
_BLUE = np.array([59, 76, 192], dtype=np.float64)  # inside / push
_WHITE = np.array([242, 242, 242], dtype=np.float64)
_RED = np.array([180, 4, 38], dtype=np.float64)  # outside / pull
_FREE = np.array([150, 150, 150, 150], dtype=np.uint8)  # cell, not jammed
_JAMMED = np.array([30, 170, 80, 230], dtype=np.uint8)  # cell, jammed
_GHOST = (200, 200, 200, 50)  # target ghost albedo (RGBA)
_PALETTE = np.array([[31, 119, 180], [255, 127, 14], [44, 160, 44], [214, 39, 40], [148, 103, 189],
                     [140, 86, 75], [227, 119, 194], [127, 127, 127], [188, 189, 34], [23, 190, 207]], dtype=np.uint8)


def _viewer_executable() -> str | None:
    """The ``rerun`` program of the installed rerun-sdk (beside this Python first, else on PATH)."""
    near = Path(sys.executable).parent / "rerun"
    return str(near) if near.is_file() and os.access(near, os.X_OK) else shutil.which("rerun")


def viewer_problem() -> str | None:
    """Why no live rerun viewer can be started here (no ``rerun`` program, no display), or None."""
    if _viewer_executable() is None:
        return "the rerun viewer program (rerun, installed with rerun-sdk) is not found"
    if sys.platform.startswith("linux") and not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
        return "there is no display here (DISPLAY and WAYLAND_DISPLAY are unset)"
    return None


def spawn_viewer(port: int = VIEWER_PORT) -> str:
    """Start a rerun viewer listening on 127.0.0.1 only (rerun's own default is every interface),
    unless something listens on ``port`` there already (a viewer started before); returns its URL."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.settimeout(0.2)
        listening = s.connect_ex(("127.0.0.1", port)) == 0
    if not listening:
        subprocess.Popen([_viewer_executable(), "--port", str(port), "--bind", "127.0.0.1", "--memory-limit", "75%"],
                         stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                         start_new_session=True)
    return f"rerun+http://127.0.0.1:{port}/proxy"


def diverging_colors(values, value_range: float) -> np.ndarray:
    """(N, 4) uint8 RGBA: blue for -value_range and below, white at 0, red for +value_range and above."""
    t = np.clip(np.asarray(values, dtype=np.float64) / float(value_range), -1.0, 1.0)[:, None]
    rgb = np.where(t < 0, _WHITE + (_BLUE - _WHITE) * (-t), _WHITE + (_RED - _WHITE) * t)
    out = np.empty((rgb.shape[0], 4), dtype=np.uint8)
    out[:, :3] = np.rint(rgb)
    out[:, 3] = 255
    return out


def _value_and_target_lines(pal, names):
    """Series styling for n values followed by their n targets: bold colours, then paler thin lines."""
    import rerun as rr

    n = len(names)
    return rr.SeriesLines(colors=np.concatenate([pal, (pal.astype(np.int32) + 255) // 2]).astype(np.uint8),
                          widths=[2.0] * n + [1.0] * n, names=list(names) + [f"{nm} target" for nm in names])


def _palette(n: int) -> np.ndarray:
    return _PALETTE[np.arange(n) % len(_PALETTE)]


class _Run:
    """Static description of one logged run (one design driven to one or more targets)."""

    def __init__(self, design, prefix: str, names: list, targets, kind: str):
        self.design = design
        self.prefix = prefix.strip("/")
        self.names = list(names)
        self.targets = targets
        self.kind = kind  # "control" or "simulate"
        rest = design.rest
        self.faces = np.asarray(rest.faces, dtype=np.int64)
        self.rest_radius = np.linalg.norm(rest.vertices, axis=1)
        self.ipam_faces = np.array([[ip.face_a, ip.face_b] for ip in design.ipams], dtype=np.int64).reshape(-1, 2)
        self.n_ipam, self.n_cell = design.n_ipams, design.n_cells
        # cell overlay: every cell's vertices duplicated so each cell has its own colour
        verts, tris, owner = [], [], []
        base = 0
        for j, cell in enumerate(design.cells):
            cf = self.faces[np.asarray(cell.faces, dtype=np.int64)]
            uniq, inv = np.unique(cf, return_inverse=True)
            verts.append(uniq)
            tris.append(inv.reshape(-1, 3) + base)
            owner.append(np.full(len(uniq), j))
            base += len(uniq)
        self.cell_vertices = np.concatenate(verts) if verts else np.zeros(0, dtype=np.int64)
        self.cell_tris = np.concatenate(tris).astype(np.uint32) if tris else np.zeros((0, 3), dtype=np.uint32)
        self.cell_owner = np.concatenate(owner) if owner else np.zeros(0, dtype=np.int64)
        extent = float(self.rest_radius.max())
        if targets:
            extent = max(extent, max(float(np.linalg.norm(t.vertices, axis=1).max()) for t in targets))
        self.spacing = 2.5 * extent
        self.logged_step = [-1] * len(self.names)
        self.logged_frames = [0] * len(self.names)

    def base(self, w: int) -> str:
        return f"{self.prefix}/{self.names[w]}"


class Recorder:
    """Log simulations, control runs and design runs to a rerun recording.

    ``path``: the ``.rrd`` file, written whole on ``close()`` (kept in memory while recording, or with
    ``spawn`` in a temporary file in the same directory, renamed into place at the end, so the path
    never holds a partial recording; rerun's own file writer hung for good on a full disk).
    ``spawn``: also stream live to a rerun viewer started for it. With neither, the recording is
    kept in memory. ``every``: log every k-th control step (the last state of every run is always
    logged). Use as a context manager, or call ``close()``; the default blueprint (the 3-D view
    beside the time series, one tab per run) is written into the recording on close.
    """

    def __init__(self, path=None, spawn: bool = False, every: int = 1, application_id: str = "warp_shape",
                 recording_id: str | None = None):
        if isinstance(every, bool) or not isinstance(every, (int, np.integer)) or every < 1:
            raise DesignError(f"every must be an integer >= 1 (log every k-th control step), got {every!r}")
        problem = viewer_problem() if spawn else None
        if problem is not None:
            raise DesignError(f"--rerun-spawn cannot open a viewer: {problem}; record to a file instead "
                              f"(--rerun run.rrd) and open it with warp-shape view run.rrd")
        try:
            import rerun as rr
        except ImportError as exc:
            raise ImportError("rerun recordings need rerun-sdk: pip install 'warp-shape[rerun]'") from exc

        self._rr = rr
        self.every = int(every)
        self.path = Path(path) if path is not None else None
        self.recording_id = recording_id or str(uuid.uuid4())
        self.stream = rr.RecordingStream(application_id, recording_id=self.recording_id)
        self.runs: list[_Run] = []
        self.design_targets: list[str] | None = None
        self._run: _Run | None = None
        self._sim_calls = 0
        self._closed = False
        self._tmp = None
        self._memory = None
        sinks = []
        if self.path is not None and spawn:  # a file beside a live viewer: rerun's file writer
            self.path.parent.mkdir(parents=True, exist_ok=True)
            fd, tmp = tempfile.mkstemp(prefix=f".{self.path.name}.", suffix=".tmp", dir=self.path.parent)
            os.close(fd)
            self._tmp = tmp
            sinks.append(rr.FileSink(tmp))
        if spawn:
            sinks.append(rr.GrpcSink(spawn_viewer()))
        self.spawn = bool(spawn)
        if sinks:
            self.stream.set_sinks(*sinks)
        else:
            self._memory = self.stream.memory_recording()
        if spawn:
            self.stream.send_blueprint(self.blueprint(), make_active=True, make_default=True)

    # ------------------------------------------------------------------ context manager / close
    def __enter__(self) -> "Recorder":
        return self

    def __exit__(self, *exc) -> None:
        self.close()  # a failed run is still saved: that is when it is most useful

    def close(self) -> Path | None:
        """Write the default blueprint, flush, and move the ``.rrd`` into place. Idempotent."""
        if self._closed:
            return self.path
        self._closed = True
        data = None
        try:
            self.stream.send_blueprint(self.blueprint(), make_active=True, make_default=True)
            self.stream.flush(timeout_sec=FLUSH_TIMEOUT)
            if self._memory is not None and self.path is None:
                return None  # in-memory recording: keep it readable through ``memory_bytes()``
            if self._memory is not None:
                data = self._memory.drain_as_bytes()
            self.stream.disconnect()
            if data is not None:
                atomic_write(self.path, data)
        except (RuntimeError, OSError) as exc:  # a full or failing disk, or the viewer went
            self._drop_tmp()
            where = f"the recording {self.path}" if self.path is not None else "the live recording"
            reason = exc.strerror if isinstance(exc, OSError) and exc.strerror else str(exc)
            raise DesignError(f"{where} could not be written ({reason}); nothing was left half-written: free "
                              f"some space (or check the disk) and run again, or give --rerun a path on another "
                              f"disk") from None
        if self._tmp is not None:
            finalize_permissions(self._tmp)
            os.replace(self._tmp, self.path)
            self._tmp = None
        return self.path

    def memory_bytes(self) -> bytes:
        """The recording as ``.rrd`` bytes (in-memory recorders: no ``path`` and no ``spawn``)."""
        if self._memory is None or self.path is not None:
            raise DesignError("memory_bytes() is for a Recorder without path or spawn; read the .rrd file instead")
        self.stream.flush(timeout_sec=FLUSH_TIMEOUT)
        return self._memory.drain_as_bytes()

    def _drop_tmp(self) -> None:
        tmp, self._tmp = getattr(self, "_tmp", None), None
        if tmp is not None:
            try:
                os.unlink(tmp)
            except OSError:
                pass

    def __del__(self):
        if not getattr(self, "_closed", True):
            self._drop_tmp()

    # ------------------------------------------------------------------ blueprint
    def blueprint(self):
        """The default layout: per run a tab with the 3-D view beside its time series; the PCC by
        design round in its own tab."""
        import rerun.blueprint as rrb

        tabs = []
        for run in self.runs:
            series = [("volume", "volume (m^3)"), ("pressure", "gauge pressure (Pa)")]
            if run.n_ipam:
                series += [("ipam/length", "IPAM length (m)"), ("ipam/force", "IPAM force (N)")]
            if run.n_cell:
                series += [("cell/kappa", "cell curvature (m)")]
            if run.kind == "control":
                series += [("fit/pcc", "PCC")]
            views = [rrb.TimeSeriesView(origin=f"/{run.prefix}", name=title,
                                        contents=[f"+ /{run.prefix}/{n}/{key}" for n in run.names])
                     for key, title in series]
            tabs.append(rrb.Horizontal(rrb.Spatial3DView(origin=f"/{run.prefix}", name=f"{run.prefix} 3-D"),
                                       rrb.Vertical(*views), column_shares=[3, 2], name=run.prefix))
        if self.design_targets:
            tabs.append(rrb.TimeSeriesView(origin="/design/pcc", name="PCC by design round"))
        if not tabs:
            return rrb.Blueprint(rrb.Horizontal(rrb.Spatial3DView(origin="/", name="3-D"),
                                                rrb.TimeSeriesView(origin="/", name="time series")))
        root = tabs[0] if len(tabs) == 1 else rrb.Tabs(*tabs, active_tab=len(tabs) - 1 - bool(self.design_targets))
        return rrb.Blueprint(root, collapse_panels=False)

    # ------------------------------------------------------------------ static parts of a run
    def _begin(self, run: _Run) -> None:
        rr, s = self._rr, self.stream
        self.runs.append(run)
        self._run = run
        for w, name in enumerate(run.names):
            b = run.base(w)
            s.log(b, rr.Transform3D(translation=[w * run.spacing, 0.0, 0.0]), static=True)
            s.log(f"{b}/membrane", rr.Mesh3D.from_fields(triangle_indices=run.faces.astype(np.uint32)), static=True)
            if run.targets:
                t = run.targets[w]
                s.log(f"{b}/target", rr.Mesh3D(vertex_positions=np.asarray(t.vertices, np.float32),
                                                triangle_indices=np.asarray(t.faces, np.uint32),
                                                albedo_factor=_GHOST), static=True)
            if run.n_cell:
                s.log(f"{b}/cells", rr.Mesh3D.from_fields(triangle_indices=run.cell_tris), static=True)
            s.log(f"{b}/volume", rr.SeriesLines(colors=[[31, 119, 180], [150, 190, 220]], names=[
                f"{name} V", f"{name} V target"]), static=True)
            s.log(f"{b}/pressure", rr.SeriesLines(colors=[[31, 119, 180]], names=[f"{name} p"]), static=True)
            if run.n_ipam:
                pal = _palette(run.n_ipam)
                s.log(f"{b}/ipam/length", _value_and_target_lines(pal, [f"{name} ipam{i} L" for i in range(run.n_ipam)]),
                      static=True)
                s.log(f"{b}/ipam/force", rr.SeriesLines(colors=pal, names=[f"{name} ipam{i} F" for i in
                                                                            range(run.n_ipam)]), static=True)
                s.log(f"{b}/ipam/pressure", rr.SeriesLines(colors=pal, names=[f"{name} ipam{i} P" for i in
                                                                               range(run.n_ipam)]), static=True)
            if run.n_cell:
                pal = _palette(run.n_cell)
                s.log(f"{b}/cell/kappa", _value_and_target_lines(pal, [f"{name} cell{j} kappa" for j in range(run.n_cell)]),
                      static=True)
                s.log(f"{b}/cell/jammed", rr.SeriesLines(colors=pal, names=[f"{name} cell{j} jammed" for j in
                                                                             range(run.n_cell)]), static=True)
            if run.kind == "control":
                s.log(f"{b}/fit/pcc", rr.SeriesLines(colors=[[214, 39, 40]], names=[f"{name} PCC"]), static=True)
                s.log(f"{b}/fit/mare", rr.SeriesLines(names=[f"{name} MARE"]), static=True)
                s.log(f"{b}/fit/mpre", rr.SeriesLines(names=[f"{name} MPRE"]), static=True)
        if self.spawn:
            self.stream.send_blueprint(self.blueprint(), make_active=True, make_default=True)

    def _log_geometry(self, run: _Run, w: int, x: np.ndarray, radial: np.ndarray, forces, jammed) -> None:
        """Membrane, IPAM segments and cell overlay of world ``w`` at the current time."""
        rr, s, b = self._rr, self.stream, run.base(w)
        s.log(f"{b}/membrane", rr.Mesh3D.from_fields(vertex_positions=x.astype(np.float32),
                                                     vertex_colors=diverging_colors(radial, ERROR_RANGE_M)))
        if run.n_ipam:
            cen = x[run.faces[run.ipam_faces]].mean(axis=2)  # (n_ipam, 2, 3)
            s.log(f"{b}/ipams", rr.LineStrips3D(cen.astype(np.float32), radii=0.0008,
                                                colors=diverging_colors(forces, FORCE_RANGE_N)))
        if run.n_cell:
            cols = np.where(np.asarray(jammed, bool)[run.cell_owner][:, None], _JAMMED, _FREE)
            s.log(f"{b}/cells", rr.Mesh3D.from_fields(
                vertex_positions=(x[run.cell_vertices] * CELL_LIFT).astype(np.float32), vertex_colors=cols))

    # ------------------------------------------------------------------ controller hooks
    def begin_run(self, *, design, targets, target_names, prefix: str = "control", settings=None) -> None:
        """Start a control run: static topology, target ghosts, series styling."""
        self.stream.reset_time()
        self._begin(_Run(design, prefix, list(target_names), list(targets), "control"))

    def log_control_step(self, *, step: int, time: float, positions, sampled, rows, done) -> None:
        """One control step of every world still running (every ``every``-th step is logged)."""
        run = self._run
        if run is None or step % self.every:
            return
        x_all = np.asarray(positions, dtype=np.float64)
        s_all = np.asarray(sampled, dtype=np.float64)
        self.stream.set_time("control_step", sequence=int(step))
        self.stream.set_time("sim_time", duration=float(time))
        for w in range(len(run.names)):
            if done[w] or not rows[w]:
                continue
            self._log_control_row(run, w, x_all[w], s_all[w], rows[w][-1])

    def _log_control_row(self, run: _Run, w: int, x: np.ndarray, sampled: np.ndarray, row: dict) -> None:
        rr, s, b = self._rr, self.stream, run.base(w)
        n_i, n_c = run.n_ipam, run.n_cell
        radial = np.linalg.norm(x, axis=1) - np.linalg.norm(sampled, axis=1)
        forces = [row[f"ipam{i}_force_n"] for i in range(n_i)]
        jammed = [row[f"cell{j}_jammed"] for j in range(n_c)]
        self._log_geometry(run, w, x, radial, forces, jammed)
        s.log(f"{b}/volume", rr.Scalars([row["volume_m3"], row["target_volume_m3"]]))
        s.log(f"{b}/pressure", rr.Scalars([row["pressure_pa"]]))
        if n_i:
            s.log(f"{b}/ipam/length", rr.Scalars([row[f"ipam{i}_length_m"] for i in range(n_i)]
                                                 + [row[f"ipam{i}_target_length_m"] for i in range(n_i)]))
            s.log(f"{b}/ipam/force", rr.Scalars(forces))
            s.log(f"{b}/ipam/pressure", rr.Scalars([row[f"ipam{i}_pressure_pa"] for i in range(n_i)]))
        if n_c:
            s.log(f"{b}/cell/kappa", rr.Scalars([row[f"cell{j}_kappa_m"] for j in range(n_c)]
                                                + [row[f"cell{j}_kappa_target_m"] for j in range(n_c)]))
            s.log(f"{b}/cell/jammed", rr.Scalars([float(v) for v in jammed]))
        s.log(f"{b}/fit/pcc", rr.Scalars([row["pcc"]]))
        s.log(f"{b}/fit/mare", rr.Scalars([row["mare_m"]]))
        s.log(f"{b}/fit/mpre", rr.Scalars([row["mpre_pct"]]))
        run.logged_step[w] = int(row["step"])
        run.logged_frames[w] += 1

    def end_run(self, results) -> None:
        """Log the final state of any world whose last control step was skipped by ``every``, and a
        summary of each run's outcome."""
        run = self._run
        if run is None:
            return
        for w, res in enumerate(results):
            h = res.history
            last = int(h["step"][-1])
            if run.logged_step[w] != last:
                row = {k: v[-1] for k, v in h.items()}
                self.stream.set_time("control_step", sequence=last)
                self.stream.set_time("sim_time", duration=float(h["time"][-1]))
                self._log_control_row(run, w, np.asarray(res.achieved.vertices, np.float64),
                                      np.asarray(res.sampled_target.vertices, np.float64), row)
            text = (f"**{run.names[w]}** ({run.prefix}): PCC {res.pcc:.4f}, MARE {res.mare * 1e3:.3f} mm, "
                    f"MPRE {res.mpre:.2f} %, volume error {100 * res.volume_error:+.3f} %, "
                    f"{res.control_steps} control steps; {res.reason}. Jammed cells: "
                    f"{np.flatnonzero(res.jammed).tolist()}.")
            self.stream.log(f"{run.base(w)}/summary", self._rr.TextDocument(text, media_type="text/markdown"),
                            static=True)
        self._run = None

    def log_design_round(self, i: int, pcc_row, target_names, design=None) -> None:
        """The PCC of every target after design round ``i`` (``design/pcc/<target>``, ``round`` timeline)."""
        rr, s = self._rr, self.stream
        names = list(target_names)
        if self.design_targets is None:
            self.design_targets = names
            for j, n in enumerate(names):
                s.log(f"design/pcc/{n}", rr.SeriesLines(colors=[_palette(len(names))[j]], names=[f"{n} PCC"]),
                      static=True)
        s.reset_time()
        s.set_time("round", sequence=int(i))
        for n, v in zip(names, np.asarray(pcc_row, dtype=np.float64)):
            s.log(f"design/pcc/{n}", rr.Scalars([float(v)]))
        if design is not None:
            s.log("design/actuators", rr.Scalars([float(design.n_ipams)]))
        s.reset_time()

    def log_figures(self, paths) -> None:
        """The report's figures (PNG files) as static images, ``design/figures/<file stem>``."""
        for p in paths:
            self.stream.log(f"design/figures/{Path(p).stem}", self._rr.EncodedImage(path=str(p)), static=True)

    def log_feel_map(self, name: str, faces: np.ndarray, fm) -> None:
        """A stiffness map (``feel.FeelMap``) of the shape controlled to ``name``: ``design/feel/<name>/membrane``
        (the shape, each vertex coloured by the stiffness of the point pressed nearest its direction from the
        centroid, dark blue the softest to yellow the stiffest), ``.../points`` (the points pressed) and
        ``.../stiffness_n_per_mm`` (their range as text)."""
        rr = self._rr
        x, p = np.asarray(fm.positions, np.float64), np.asarray(fm.points, np.float64)
        k = np.asarray(fm.stiffness, np.float64) / 1000.0
        c = x.mean(axis=0)
        u = (x - c) / np.linalg.norm(x - c, axis=1, keepdims=True)
        q = (p - c) / np.linalg.norm(p - c, axis=1, keepdims=True)
        t = (k - k.min()) / max(float(np.ptp(k)), 1e-12)
        colors = np.stack([68 + 185 * t, 1 + 230 * t, 84 - 47 * t, np.full_like(t, 255)], axis=1).astype(np.uint8)
        base = f"design/feel/{name}"
        self.stream.log(f"{base}/membrane", rr.Mesh3D(vertex_positions=x, triangle_indices=faces,
                                                      vertex_colors=colors[np.argmax(u @ q.T, axis=1)]), static=True)
        self.stream.log(f"{base}/points", rr.Points3D(p, colors=colors, radii=5e-4), static=True)
        self.stream.log(f"{base}/stiffness_n_per_mm", rr.TextDocument(
            f"{name}: fingertip ({fm.radius * 1e3:.3g} mm, {fm.depth * 1e3:.3g} mm deep) stiffness "
            f"{k.min():.4f} .. {k.max():.4f} N/mm, median {np.median(k):.4f} N/mm"), static=True)

    def log_calibration(self, result) -> None:
        """A calibration's residual maps (``CalibrationResult.residuals``): per scan ``calibration/<k>`` the
        replayed membrane coloured by the signed residual (blue inside, red outside, white 0, grey where
        not scanned; the scale is the largest |residual|) and the aligned scan points coloured the same."""
        rr = self._rr
        for k, m in enumerate(result.residuals):
            v = m.vertex_residual
            lim = max(float(np.nanmax(np.abs(v))) if np.any(np.isfinite(v)) else 0.0, 1e-6)
            colors = diverging_colors(np.nan_to_num(v), lim)
            colors[~np.isfinite(v)] = _FREE
            faces = result.design.rest.faces
            self.stream.log(f"calibration/{k}/membrane", rr.Mesh3D(vertex_positions=m.vertices, triangle_indices=faces,
                                                                   vertex_colors=colors), static=True)
            keep = m.weight > 0
            self.stream.log(f"calibration/{k}/scan", rr.Points3D(m.points[keep], colors=diverging_colors(
                m.residual[keep], lim), radii=2e-4), static=True)
            self.stream.log(f"calibration/{k}/rms_mm", rr.TextDocument(f"{m.name}: RMS {m.rms_mm:.3f} mm"), static=True)

    def log_codesign(self, record: dict, target_names) -> None:
        """Co-design's replayed objective of every target after each accepted step
        (``design/codesign/<target>``, ``codesign`` timeline, step 0 = as placed) and the objective under
        the design's controller after it (``design/codesign/<target>/final``)."""
        rr, s = self._rr, self.stream
        rows = [record.get("before", [])] + list(record.get("steps", []))
        s.reset_time()
        for k, row in enumerate(rows):
            s.set_time("codesign", sequence=k)
            for n, v in zip(target_names, row):
                s.log(f"design/codesign/{n}", rr.Scalars([float(v)]))
        for n, v in zip(target_names, record.get("after", [])):
            s.log(f"design/codesign/{n}/final", rr.Scalars([float(v)]))
        s.reset_time()

    def log_design_refinement(self, r: int, record: dict, target_names) -> None:
        """Every hold tried in refinement round ``r`` of the simulated placement: its screened objective
        (``design/refine/<target>/<k>/score``, ``refine`` timeline), and per target whether a hold was
        kept (``design/refine/<target>/kept``: 1 or 0)."""
        rr, s, names = self._rr, self.stream, list(target_names)
        s.reset_time()
        s.set_time("refine", sequence=int(r))
        count: dict = {}
        for c in record.get("candidates", []):
            n = names[c["target"]]
            k = count[n] = count.get(n, -1) + 1
            s.log(f"design/refine/{n}/{k}/score", rr.Scalars([float(c["score"])]))
        for n in {names[c["target"]] for c in record.get("candidates", [])}:
            s.log(f"design/refine/{n}/kept", rr.Scalars([float(n in record.get("kept", {}))]))
        s.reset_time()

    def log_design_candidates(self, i: int, record: dict) -> None:
        """Every candidate set's score (summed fit objective) in greedy placement round ``i``
        (``design/candidates/<k>/score``, ``round`` timeline) and the one kept (``design/candidates/kept``)."""
        rr, s = self._rr, self.stream
        s.reset_time()
        s.set_time("round", sequence=int(i))
        for k, c in enumerate(record.get("candidates", [])):
            s.log(f"design/candidates/{k}/score", rr.Scalars([float(c["score"])]))
        kept = record.get("chosen")
        s.log("design/candidates/kept", rr.Scalars([float(-1 if kept is None else kept)]))
        s.reset_time()

    # ------------------------------------------------------------------ plain simulations
    def begin_simulation(self, design, prefix: str = "simulate", names=None, worlds: int = 1) -> None:
        """Start logging a plain simulation of ``design`` (``worlds`` copies)."""
        names = list(names) if names is not None else [f"world{w}" for w in range(worlds)]
        self.stream.reset_time()
        self._sim_calls = 0
        self._begin(_Run(design, prefix, names, [], "simulate"))

    def log_sim_frame(self, step: int, time: float, positions, volume=None, pressure=None, ipam_lengths=None,
                      ipam_forces=None, jammed=None, *, design=None, force: bool = False) -> None:
        """One frame of a plain simulation: ``positions`` (V, 3) or (W, V, 3); the other quantities a
        scalar / (n,) per world (or with a leading world axis). The membrane colour is the radial
        displacement from rest. Every ``every``-th call is logged (``force=True`` always logs)."""
        x_all = np.asarray(positions, dtype=np.float64)
        if x_all.ndim == 2:
            x_all = x_all[None]
        run = self._run
        if run is None or run.kind != "simulate":
            if design is None:
                raise DesignError("log_sim_frame needs the design: call begin_simulation(design) first "
                                  "or pass design=")
            self.begin_simulation(design, worlds=x_all.shape[0])
            run = self._run
        call = self._sim_calls
        self._sim_calls += 1
        if call % self.every and not force:
            return
        W = x_all.shape[0]

        def per_world(v, w, n):
            if v is None:
                return None
            a = np.asarray(v, dtype=np.float64)
            if n is None:  # scalar per world
                return float(a.reshape(-1)[w] if a.size == W and a.size > 1 else a.reshape(-1)[0])
            return a.reshape(W, n)[w] if a.size == W * n else a.reshape(-1)[:n]

        rr, s = self._rr, self.stream
        s.set_time("sim_step", sequence=int(step))
        s.set_time("sim_time", duration=float(time))
        for w in range(W):
            b = run.base(w)
            x = x_all[w]
            forces = per_world(ipam_forces, w, run.n_ipam) if run.n_ipam else None
            jam = per_world(jammed, w, run.n_cell) if run.n_cell else None
            self._log_geometry(run, w, x, np.linalg.norm(x, axis=1) - run.rest_radius,
                               np.zeros(run.n_ipam) if forces is None else forces,
                               np.zeros(run.n_cell) if jam is None else jam)
            vol = per_world(volume, w, None)
            if vol is not None:
                s.log(f"{b}/volume", rr.Scalars([vol]))
            p = per_world(pressure, w, None)
            if p is not None:
                s.log(f"{b}/pressure", rr.Scalars([p]))
            if run.n_ipam and ipam_lengths is not None:
                s.log(f"{b}/ipam/length", rr.Scalars(per_world(ipam_lengths, w, run.n_ipam)))
            if forces is not None:
                s.log(f"{b}/ipam/force", rr.Scalars(forces))
            if jam is not None:
                s.log(f"{b}/cell/jammed", rr.Scalars(jam))
            run.logged_frames[w] += 1
