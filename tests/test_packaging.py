"""What a built (not editable) install holds: every package of the source tree, the shipped scenes
and targets as listed packages (no setuptools deprecation box about data-only packages)."""

from __future__ import annotations

import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_every_package_and_data_folder_is_listed():
    config = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
    listed = set(config["packages"])
    found = {".".join(p.parent.relative_to(ROOT).parts) for p in (ROOT / "warp_shape").rglob("__init__.py")}
    assert found <= listed, sorted(found - listed)  # e.g. warp_shape.calibration was missing from a wheel
    assert {"warp_shape.scenes", "warp_shape.scenes.targets"} <= listed
    assert config["package-data"]["warp_shape.scenes.targets"] == ["*.ply"]
    assert any((ROOT / "scenes" / "targets").glob("*.ply"))
