"""Report figures: PNGs from a small design run (Fig. 6 panels per target, PCC by round)."""

from __future__ import annotations

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
                     target_names=["oval", "heart"])


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
    assert names == ["control_heart.png", "control_oval.png", "pcc_by_round.png"]
    for p in paths:
        assert p.parent == tmp_path
        _check_png(p)
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
    assert [p.name for p in paths] == ["control_cube.png"]
    _check_png(paths[0])
