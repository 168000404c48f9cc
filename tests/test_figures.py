"""Report figures: PNGs from a small design run (Fig. 6 panels per target, PCC by round)."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

import warp_shape as ws

pytest.importorskip("matplotlib")
from matplotlib.image import imread  # noqa: E402

from warp_shape.io.figures import control_figure, pcc_by_round_figure, write_figures  # noqa: E402

PNG = b"\x89PNG\r\n\x1a\n"


@pytest.fixture(scope="module")
def small_design():
    return ws.design(ws.icosphere(2, 0.035), [ws.target("oval"), ws.target("heart")], actuators=1,
                     target_names=["oval", "heart"], codesign="off")  # the figures of a placed design


def _check_png(path, min_w=500, min_h=300):
    data = path.read_bytes()
    assert data[:8] == PNG, path
    img = imread(path)
    h, w = img.shape[:2]
    assert w >= min_w and h >= min_h, (path, img.shape)
    rgb = (img[..., :3] * 255).astype(np.uint8).reshape(-1, 3)
    assert len(np.unique(rgb, axis=0)) > 20, path  # drawn lines, text, several colours
    assert float(img[..., :3].var()) > 1e-3, path


def test_write_figures_for_a_design_run(small_design, tmp_path):
    paths = write_figures(small_design, tmp_path)
    names = sorted(p.name for p in paths)
    assert names == ["control_heart.png", "control_heart.svg", "control_oval.png", "control_oval.svg",
                     "fit_heart.png", "fit_heart.svg", "fit_oval.png", "fit_oval.svg",
                     "pcc_by_round.png", "pcc_by_round.svg", "rest_shape.png", "rest_shape.svg"]
    for p in paths:
        assert p.parent == tmp_path
        if p.suffix == ".png":
            _check_png(p)
        else:
            assert p.read_text().lstrip().startswith("<?xml") and "<svg" in p.read_text()[:2000]
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # atomic: no temporary left


def test_control_figure_and_pcc_from_an_array(small_design, tmp_path):
    res = small_design.results[1]
    p = control_figure(res, tmp_path / "sub" / "heart.png", title="heart")
    _check_png(p)
    q = pcc_by_round_figure(np.array([[0.80, 0.90], [0.85, 0.93], [0.86, 0.95]]), ["a", "b"], tmp_path / "pcc.png")
    _check_png(q, 400, 250)


def test_write_figures_for_control_results(tmp_path):
    from warp_shape.scenarios import cube_fig6_design

    res = ws.control(cube_fig6_design(subdivisions=2), ws.target("cube"), max_steps=15)
    paths = write_figures([res], tmp_path, target_names=["cube"])
    assert [p.name for p in paths] == ["control_cube.png", "control_cube.svg"]
    _check_png(paths[0])


def _synthetic_result():
    """A 20-step record at 10 ms: inflation for the first 5 steps, IPAM 1 passive, cell 0 jams at 12."""
    from types import SimpleNamespace

    n = 20
    t = 0.3 + 0.01 * np.arange(n)  # a record need not start at 0
    ramp = np.minimum(np.arange(n) / 10.0, 1.0)
    h = {"step": np.arange(n), "time": t, "phase": np.where(np.arange(n) < 5, 1, 2),
         "volume_m3": 2e-4 + 5e-5 * ramp, "target_volume_m3": np.full(n, 2.5e-4),
         "pressure_pa": 800.0 * ramp, "air_mol": 0.009 + 0.001 * ramp, "pcc": 0.5 + 0.4 * ramp}
    for i, p in enumerate((60e3, 4e3)):
        h[f"ipam{i}_pressure_pa"] = p * ramp
        h[f"ipam{i}_length_m"] = 0.08 + 0.01 * ramp
        h[f"ipam{i}_target_length_m"] = np.full(n, 0.09)
    h["cell0_kappa_m"], h["cell0_kappa_target_m"] = 0.002 * ramp, np.full(n, 0.002)
    h["cell0_jammed"] = (np.arange(n) >= 12).astype(int)
    return SimpleNamespace(history=h, pcc=0.9, jam_steps=np.array([12]), passive_ipams=np.array([1]), design=None)


def test_control_figure_has_seconds_pressures_passive_and_named_inflation(tmp_path):
    from matplotlib.colors import to_rgba

    from warp_shape.io.figures import INFLATION_LABEL, build_control_figure
    from warp_shape.io.valve import row_times

    res = _synthetic_result()
    fig = build_control_figure(res, "heart")
    axes = {ax.get_title().split(" ")[0]: ax for ax in fig.axes if ax.get_title()}
    assert {"(a)", "(b)", "(c)", "(d)", "(e)", "(f)"} <= set(axes)
    # the lab's clock of the valve CSV from 0 (pump 5 mL/s, valves 100 kPa/s, 50 Hz), not step 19 nor
    # the simulated 0.19 s, which is on the top axis
    lab = row_times(res)
    assert lab[-1] > 0.19
    for key in ("(e)", "(f)"):
        assert axes[key].get_xlabel().startswith("lab time (s; pump 5 mL/s, valves 100 kPa/s, 50 Hz")
    top = [c for c in axes["(a)"].child_axes if c.get_xlabel().startswith("simulated time (s)")]
    assert len(top) == 1
    # its labels: the simulated time at the lab axis's ticks (the record's last tick: 0.19 s at the end)
    ticks = [t for t in axes["(a)"].get_xticks() if 0 <= t <= lab[-1]]
    labels = [float(x.get_text()) for x in top[0].get_xticklabels()]
    assert labels == pytest.approx([np.interp(t, lab, 0.01 * np.arange(20)) for t in ticks], abs=6e-4)
    e = axes["(e)"]
    assert "kPa" in e.get_ylabel()
    lines = {ln.get_label(): ln for ln in e.get_lines() if not ln.get_label().startswith("_")}
    assert max(ln.get_xdata()[-1] for ln in lines.values()) == pytest.approx(lab[-1])
    # IPAM 0 drawn in kPa, IPAM 1 passive: grey, dashed, labelled so, in both the pressure and length panels
    assert lines["IPAM 0"].get_ydata()[-1] == pytest.approx(60.0) and lines["IPAM 0"].get_linestyle() == "-"
    for ax in (e, axes["(b)"]):
        passive = [ln for ln in ax.get_lines() if "passive" in ln.get_label()]
        assert len(passive) == 1 and passive[0].get_label() == "IPAM 1 (passive, held neutral)"
        assert passive[0].get_linestyle() == "--" and to_rgba(passive[0].get_color()) == to_rgba("0.55")
    assert not [ln for ln in axes["(b)"].get_lines() if "IPAM 0" in ln.get_label() and ln.get_linestyle() == "--"]
    # the grey band is named: a labelled patch spanning the 5 inflation steps (to the first row after
    # them: the air dosed in that interval is inflation's) and a text inside it
    a = axes["(a)"]
    band = [p for p in a.patches if p.get_label() == INFLATION_LABEL]
    assert len(band) == 1 and band[0].get_x() == pytest.approx(0.0) and band[0].get_width() == pytest.approx(lab[5])
    assert "inflation" in [tx.get_text() for tx in a.texts]
    assert "grey band: inflation" in fig._suptitle.get_text()
    _check_png(control_figure(res, tmp_path / "c.png"))


def test_the_control_figure_names_a_grey_band_only_where_one_is_drawn():
    """A model-based sequence (every row phase 4) has no inflation rows: no band, and neither the title
    nor a legend speaks of one; passive IPAMs named only where there are some."""
    from warp_shape.io.figures import INFLATION_LABEL, build_control_figure

    res = _synthetic_result()
    res.history["phase"] = np.full(20, 4)
    res.passive_ipams = np.array([], dtype=int)
    fig = build_control_figure(res, "heart")
    assert not [p for ax in fig.axes for p in ax.patches if p.get_label() == INFLATION_LABEL]
    legends = [t.get_text() for ax in fig.axes if ax.get_legend() for t in ax.get_legend().get_texts()]
    assert "grey" not in fig._suptitle.get_text() and INFLATION_LABEL not in legends
    assert fig._suptitle.get_text() == "heart"


def test_report_gives_ipam_ends_and_cells_in_mm_and_a_glossary():
    from types import SimpleNamespace

    from warp_shape.io.report import lab_sections
    from warp_shape.scenarios import cube_fig6_design

    d = cube_fig6_design(subdivisions=2)
    results = [SimpleNamespace(passive_ipams=np.array([], int)), SimpleNamespace(passive_ipams=np.array([2]))]
    text = "\n".join(lab_sections(SimpleNamespace(design=d, target_names=["cube", "egg"], results=results)))
    c = d.rest.face_centroids()
    ip = d.ipams[2]
    row = next(line for line in text.splitlines() if line.startswith("| 2 |"))
    # IPAM 2's ends as rest-shape coordinates in mm (a 35 mm-radius design: tens of mm, not 0.0x)
    for f in (ip.face_a, ip.face_b):
        assert "(" + ", ".join(f"{v * 1e3:+.1f}" for v in c[f]) + ")" in row
    assert np.max(np.abs(c[ip.face_a])) * 1e3 > 10.0
    assert f"| {ip.rest_length * 1e3:.1f} |" in row and row.endswith("| cube |")  # egg holds it neutral
    cells = text.split("## Jamming cells")[1].split("## Glossary")[0]
    assert len([line for line in cells.splitlines() if line.startswith("| ") and line[2].isdigit()]) == d.n_cells
    assert "IPAM 0 a" in cells
    glossary = text.split("## Glossary")[1]
    for term in ("**objective**", "**PCC**", "**MARE**", "**MPRE**", "**max scaled error**"):
        assert term in glossary
    assert "(R - r) / V_t^(1/3)" in glossary


def test_fit_figure_colours_the_membrane_by_its_signed_radial_error(small_design):
    """The achieved heart, coloured by R - r in mm (the report's sign): red where it lies inside the
    target, blue outside, on a scale symmetric about 0 that clips nothing; the target drawn; the
    rest-shape figure draws every IPAM and colours every cell."""
    from warp_shape.io.figures import build_fit_figure, build_rest_figure, signed_radial_error

    res = small_design.results[1]
    err = signed_radial_error(res)
    r = np.linalg.norm(res.achieved.vertices, axis=1)
    R = np.linalg.norm(res.sampled_target.vertices, axis=1)
    np.testing.assert_allclose(err, R - r)
    assert np.mean(np.abs(err)) == pytest.approx(res.mare, rel=0.3)  # the same error as the MARE measures
    fig = build_fit_figure(res, "heart")
    bar = [ax for ax in fig.axes if "signed radial error" in ax.get_ylabel()]
    assert len(bar) == 1 and "(mm)" in bar[0].get_ylabel() and "R - r" in bar[0].get_ylabel()
    lo, hi = bar[0].get_ylim()
    assert lo == pytest.approx(-hi) and hi == pytest.approx(np.abs(err).max() * 1e3)  # nothing clipped
    assert f"+-{hi:.2f} mm" in fig._suptitle.get_text()
    every = [c for ax in fig.axes if ax.name == "3d" for c in ax.collections]
    assert len([c for c in every if c.get_gid() == "target"]) == 2  # the target, in both views
    poly = [c for c in every if c.get_gid() != "target"]
    assert len(poly) == 2  # two views
    colors = poly[0].get_facecolor()  # (faces may be drawn in depth order)
    assert len(colors) == res.achieved.n_faces
    reddest, bluest = colors[np.argmax(colors[:, 0] - colors[:, 2])], colors[np.argmax(colors[:, 2] - colors[:, 0])]
    assert reddest[0] > reddest[2] + 0.3 and bluest[2] > bluest[0] + 0.3  # red inside, blue outside, both there
    face_err_of = err[np.asarray(res.achieved.faces)].mean(axis=1)
    assert face_err_of[np.argmax(colors[:, 0] - colors[:, 2])] > 0  # the reddest face lies inside the target
    face_err = err[np.asarray(res.achieved.faces)].mean(axis=1)
    assert face_err.max() > 0 > face_err.min()
    rest = build_rest_figure(small_design.design)
    ax3 = [ax for ax in rest.axes if ax.name == "3d"][0]
    assert len([t for t in ax3.texts if t.get_text().isdigit()]) == small_design.design.n_ipams
    assert rest.legends and "IPAM" in rest.legends[0].get_texts()[0].get_text()  # what the lines and colours are
    cell_faces = np.flatnonzero(small_design.design.face_cell() >= 0)
    fc = ax3.collections[0].get_facecolor()
    coloured = np.ptp(fc[:, :3], axis=1) > 0.1  # a cell's colour, not a grey
    assert int(coloured.sum()) == len(cell_faces)


def test_line_colours_are_distinct_and_never_grey():
    from matplotlib.colors import to_rgba

    for n in (4, 9, 16, 20, 40):
        rgb = np.array([to_rgba(c)[:3] for c in ws.io.figures.line_colors(n)])
        assert len(np.unique(np.round(rgb, 3), axis=0)) == n, n
        assert np.all(np.ptp(rgb, axis=1) > 0.1), n  # not a grey (grey is for passive IPAMs)


def test_figures_drawn_by_a_runs_workers_are_the_ones_drawn_here(small_design, tmp_path):
    """Inside a run whose workers are running, every figure is one job on them: the same files in
    the same order, each PNG byte for byte the one drawn in this process."""
    from warp_shape.controller.shard import worker_pool

    here = write_figures(small_design, tmp_path / "here")
    with worker_pool(2) as pool:
        pool.start()
        there = write_figures(small_design, tmp_path / "there")
        assert len(pool.job_seconds) == 1 and len(pool.job_seconds[0]) == len(here) // 2
    assert [p.name for p in there] == [p.name for p in here]
    for a, b in zip(here, there):
        if a.suffix == ".png":
            assert a.read_bytes() == b.read_bytes(), a.name


def test_a_runs_fit_figures_share_one_colour_scale_and_the_final_round_is_marked(small_design, tmp_path, monkeypatch):
    """Every fit figure of a run is drawn on one scale, the run's largest |R - r| (an egg's 0.2 mm
    and a pear's 10 mm are then told apart by colour); the PCC-by-round figure marks its last round
    as the finished design under its own controller and its PCC axis reaches 1."""
    import warp_shape.io.figures as figures

    jobs = []
    monkeypatch.setattr(figures, "run_jobs", lambda fn, js: jobs.extend(js) or [j[2] for j in js])
    figures.write_figures(small_design, tmp_path)
    lim = figures.fit_colour_limit(small_design.results)
    fits = [j for j in jobs if j[0] == "fit"]
    assert len(fits) == 2 and all(j[4] == lim for j in fits)
    own = [float(np.abs(figures.signed_radial_error(r)).max()) * 1e3 for r in small_design.results]
    assert lim == pytest.approx(max(own)) and min(own) < lim
    for res in small_design.results:
        fig = figures.build_fit_figure(res, limit=lim)
        bar = next(ax for ax in fig.axes if "signed radial error" in ax.get_ylabel())
        assert bar.get_ylim() == pytest.approx((-lim, lim))
    measures, names = next(j[1] for j in jobs if j[0] == "by_round")
    fig = figures.build_by_round_figure(measures, names, None)
    pcc_ax = next(ax for ax in fig.axes if ax.get_ylabel() == "PCC")
    assert pcc_ax.get_ylim()[1] >= 1.0
    assert pcc_ax.get_xticklabels()[-1].get_text().endswith("final")
    assert any(p.get_gid() == "final" for p in pcc_ax.patches)


def test_ipam_labels_keep_apart_where_the_ipams_cross():
    """Four IPAMs whose a-ends lie within 6 mm of each other: labels 20 % along each (as before) sat
    8.6 mm apart at most; the spots chosen keep every pair of labels far apart, each on its line."""
    from warp_shape.io.figures import label_spots

    turns = np.linspace(0, 2 * np.pi, 5)[:4]
    ends = [(np.array([2.0 * i, 0, 40]), np.array([40 * np.cos(t), 40 * np.sin(t), -40])) for i, t in enumerate(turns)]
    spots = label_spots(ends)
    gaps = [np.linalg.norm(p - q) for k, p in enumerate(spots) for q in spots[:k]]
    assert min(gaps) > 20.0, gaps  # mm (measured 47.9)
    for (a, b), p in zip(ends, spots):  # each on its own line
        assert np.linalg.norm(np.cross(b - a, p - a)) < 1e-9


def test_control_figure_draws_the_chamber_pressure_the_valve_file_gives(small_design):
    """Panel (f) draws the chamber pressure at rest under each row's controls, the valve CSV's, in
    black (never the simulated transient's dip alone), the transient thin grey beside it; and a line
    drawn over an identical one is thinner, so both show."""
    from warp_shape.io.figures import build_control_figure, stacked_widths
    from warp_shape.io.valve import quasi_static_pressure

    res = small_design.results[1]
    fig = build_control_figure(res)
    f = next(ax for ax in fig.axes if ax.get_title().startswith("(f)"))
    lines = {ln.get_label(): ln for ln in f.get_lines()}
    np.testing.assert_allclose(lines["at rest (as the valve CSV)"].get_ydata(), quasi_static_pressure(res)[0] / 1e3)
    np.testing.assert_allclose(lines["simulated transient"].get_ydata(), np.asarray(res.history["pressure_pa"]) / 1e3)
    widths = stacked_widths(4, 1.3)
    assert all(a > b for a, b in zip(widths, widths[1:]))
    c = next(ax for ax in fig.axes if ax.get_title().startswith("(c)"))
    solid = [ln.get_linewidth() for ln in c.get_lines() if ln.get_label().startswith("cell ")]
    assert len(solid) == small_design.design.n_cells and solid == sorted(solid, reverse=True)


def test_calibration_residual_maps_have_mm_axes_equal_scale_one_colour_scale_and_the_sign():
    """Two scans' residual maps of a flattened membrane: axes in mm with the box in the membrane's true
    proportions, one symmetric colour scale across both (the larger scan's largest residual), a face the
    scan lies outside of (+) red, one inside (-) blue, a face no scan point reaches dark grey."""
    from matplotlib.colors import to_rgba

    from warp_shape.calibration import ScanResidual
    from warp_shape.calibration.files import UNSCANNED_COLOR, build_residual_figure, residual_scale_mm

    mesh = ws.icosphere(2, 0.035)
    v = mesh.vertices * np.array([1.0, 1.0, 0.5])  # 70 x 70 x 35 mm
    faces = mesh.faces
    top = v[:, 2] > 0.008
    first = np.where(top, 1.5e-3, -1.0e-3)  # + outside on the top, - inside below
    first[v[:, 0] > 0.03] = np.nan  # a side no scan point reached
    second = np.full(len(v), 2.0e-3)
    scans = [ScanResidual(name, np.zeros((1, 3)), np.zeros(1), np.ones(1), np.eye(4), v, r)
             for name, r in (("a", first), ("b", second))]
    result = SimpleNamespace(residuals=scans)
    lim = residual_scale_mm(result, faces)
    assert lim == pytest.approx(2.0)  # mm: one scale for both, from the larger scan
    fig = build_residual_figure(scans[0], faces, lim)
    ax = fig.axes[0]
    assert all("mm" in label for label in (ax.get_xlabel(), ax.get_ylabel(), ax.get_zlabel()))
    box = np.asarray(ax.get_box_aspect(), dtype=float)
    assert box / box[0] == pytest.approx([1.0, 1.0, 0.5], abs=0.02)  # equal scale: the flattening shows
    surf = ax.collections[0]
    assert surf.get_clim() == pytest.approx((-2.0, 2.0))
    colours = surf.to_rgba(surf.get_array())  # each face's colour from its residual, before any shading
    vr = first[faces]
    seen = np.isfinite(vr)
    face_r = np.where(seen, vr, 0.0).sum(axis=1) / np.maximum(seen.sum(axis=1), 1)
    up, down = np.flatnonzero(seen.all(axis=1) & (face_r > 1.4e-3))[0], np.flatnonzero(face_r < -0.9e-3)[0]
    assert colours[up][0] > colours[up][2] + 0.2 and colours[down][2] > colours[down][0] + 0.1  # red +, blue -
    unseen = np.flatnonzero(~seen.any(axis=1))
    assert unseen.size and to_rgba(UNSCANNED_COLOR)[:3] == pytest.approx(tuple(colours[unseen[0]][:3]), abs=0.02)
