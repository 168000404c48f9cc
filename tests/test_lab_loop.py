"""The loop a lab closes, on the smallest design that shows it: design -> valve files -> drive the
device with them -> scan -> calibrate. The valve file replays to the design's own final frame, and a
calibration on scans of those frames, its manifest on the valve files, finds no change it cannot
stand behind (docs/calibration.md, *What a calibration flags*)."""

from __future__ import annotations

import numpy as np
import pytest

import warp_shape as ws
from warp_shape.calibration import replay_held
from warp_shape.calibration.files import valve_sequence
from warp_shape.cli import main
from warp_shape.io.scene_read import load_actuated_shape

#: the design: 162 vertices, 2 IPAMs by the paper's placement, one target, no co-design (about 20 s)
DESIGN = ["design", "--subdivisions", "2", "--actuators", "2", "--placement", "paper", "--targets", "oval", "heart",
          "--codesign", "off", "--workers", "1"]


@pytest.fixture(scope="module")
def designed(tmp_path_factory):
    out = tmp_path_factory.mktemp("designed") / "out"
    assert main([*DESIGN, "--out", str(out)]) == 0
    return out, ws.load_scene(str(out / "design.usda")).design


def test_a_valve_file_replays_to_the_designs_final_frame(designed):
    """``valve_<target>.csv`` replayed on the design (from its control-step rows, held to rest) lands
    within 0.05 mm of the run's final frame in ``actuation_<target>.usdc`` (measured: 4 um); before the
    control steps were marked and the jams aligned, 0.27-0.51 mm."""
    out, design = designed
    for name in ("oval", "heart"):
        x = replay_held(design, [valve_sequence(out / f"valve_{name}.csv", design)])[0]
        final, _ = load_actuated_shape(out / "design.usda", target=name)
        moved = np.linalg.norm(x - final.vertices, axis=1)
        assert moved.max() < 5e-5, (name, moved.max())
