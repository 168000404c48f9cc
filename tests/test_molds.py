"""Printable molds: millimetre STL files a slicer reads at the right size, closed solids, a shell whose
cavity is the membrane's outer surface, registration keys in both halves, open pour and vent holes."""

from __future__ import annotations

import json
import shutil
import subprocess

import numpy as np
import pytest

pytest.importorskip("manifold3d")
import trimesh  # noqa: E402

from warp_shape.errors import DesignError  # noqa: E402
from warp_shape.io.outputs import write_molds  # noqa: E402
from warp_shape.molds import mold_set, outer_mold, vertical_crossings  # noqa: E402
from warp_shape.scan import surface_distances  # noqa: E402
from warp_shape.scenarios import cube_fig6_design  # noqa: E402

LAYER = 5e-3  # m


@pytest.fixture(scope="module")
def design():
    return cube_fig6_design()


@pytest.fixture(scope="module")
def written(design, tmp_path_factory):
    out = tmp_path_factory.mktemp("molds")
    paths = write_molds(design, out, marker_height=2e-3, layer_thickness=LAYER)
    return out, paths


@pytest.fixture(scope="module")
def molds(design):
    return mold_set(design, layer_thickness=LAYER)


def test_files_are_millimetre_solids(design, written):
    out, paths = written
    names = {p.name for p in paths}
    assert names == {"mold_core_mm.stl", "mold_shell_bottom_mm.stl", "mold_shell_top_mm.stl", "molds_mm.json"}
    info = json.loads((out / "molds_mm.json").read_text())
    assert info["units"] == "mm" and info["scale_from_metres"] == 1000.0
    rest_lo, rest_hi = design.rest.vertices.min(axis=0) * 1e3, design.rest.vertices.max(axis=0) * 1e3
    core = trimesh.load(out / "mold_core_mm.stl")
    assert core.is_watertight and core.is_winding_consistent and core.volume > 0
    # the core holds the rest shape (70 mm across for the 35 mm-radius cube design), bosses stand <= 2 mm proud
    assert np.all(core.bounds[0] <= rest_lo + 1e-3) and np.all(core.bounds[1] >= rest_hi - 1e-3)
    assert np.all(core.bounds[0, :2] >= rest_lo[:2] - 2.0 - 1e-3) and np.all(core.bounds[1] <= rest_hi + 2.0 + 1e-3)
    # below, the seat: 5 mm under the lowest point of the core (bosses included)
    assert core.bounds[0, 2] == pytest.approx(info["core_seat"]["bottom_z"], abs=1e-4)  # STL: float32
    assert rest_lo[2] - 2.0 - 5.0 - 1e-3 <= core.bounds[0, 2] <= rest_lo[2] - 5.0 + 1e-3
    assert 60.0 < core.extents.min() < 80.0
    # the rest shape plus its bosses and the seat's stem below it (about 7 % of a 35 mm sphere)
    assert 1.0 < core.volume / (design.rest.volume() * 1e9) < 1.10
    cavity_hi = outer_mold(design, LAYER).vertices.max(axis=0) * 1e3
    for half in ("bottom", "top"):
        m = trimesh.load(out / f"mold_shell_{half}_mm.stl")
        assert m.is_watertight and m.is_winding_consistent and m.volume > 0
        assert info["parts"][f"mold_shell_{half}"]["extents"] == pytest.approx(m.extents.tolist(), abs=1e-3)
        # block = cavity bounds + 10 mm wall on x and y
        assert m.bounds[1, :2] == pytest.approx(cavity_hi[:2] + 10.0, abs=1e-3)
    assert info["parts"]["mold_core"]["watertight"] is True


def test_other_units_scale_and_are_named(design, tmp_path):
    paths = write_molds(design, tmp_path, marker_height=2e-3, layer_thickness=LAYER, units="cm")
    assert {p.name for p in paths} >= {"mold_core_cm.stl", "molds_cm.json"}
    mm = mold_set(design, layer_thickness=LAYER)
    cm = trimesh.load(tmp_path / "mold_core_cm.stl")
    assert cm.extents == pytest.approx(mm.core.extents / 10.0, rel=1e-6)
    with pytest.raises(DesignError, match="units"):
        mold_set(design, units="furlong")


def _surface_points(mesh, n, seed):
    pts, _ = trimesh.sample.sample_surface(mesh, n, seed=seed)
    return np.asarray(pts)


def test_shell_cavity_is_membrane_outer_surface(design, molds):
    """Both ways within 0.1 mm: the membrane's outer surface lies on the shell halves, and every shell
    surface that is not block, split plane, key or hole lies on the membrane's outer surface."""
    sh = molds.info["shell"]
    cavity = outer_mold(design, LAYER).to_trimesh()
    cavity.apply_scale(1000.0)
    halves = [molds.shell_bottom, molds.shell_top]
    holes = [(np.array(h["center"][:2]), h["radius"]) for h in (sh["pour"], sh["vent"])]

    def near_hole(p):
        return np.any([np.linalg.norm(p[:, :2] - c, axis=1) < r + 0.5 for c, r in holes], axis=0)

    pts = _surface_points(cavity, 4000, 1)
    pts = pts[~near_hole(pts)]
    d = np.min([surface_distances(pts, h) for h in halves], axis=0)
    assert d.max() < 0.1, f"membrane outer surface is {d.max():.3f} mm from the shell cavity"

    z = sh["split_plane_z"]
    keys = np.array(sh["keys"])
    for half in halves:
        p = _surface_points(half, 6000, 2)
        lo, hi = half.bounds
        on_block = np.any(np.abs(p - lo) < 1e-3, axis=1) | np.any(np.abs(p - hi) < 1e-3, axis=1)
        on_split = np.abs(p[:, 2] - z) < 1e-3
        on_key = np.min(np.linalg.norm(p[:, None, :2] - keys[None, :, :2], axis=2), axis=1) < sh["key_radius"] + 0.5
        rest = p[~(on_block | on_split | on_key | near_hole(p))]
        assert len(rest) > 500  # the cavity is a large share of each half's surface
        dev = surface_distances(rest, cavity)
        assert dev.max() < 0.1, f"shell cavity deviates {dev.max():.3f} mm from the membrane's outer surface"


def test_keys_in_both_halves_and_holes_open(molds):
    sh = molds.info["shell"]
    z, h, c = sh["split_plane_z"], sh["key_height"], sh["key_clearance"]
    keys = np.array(sh["keys"])
    assert len(keys) == 3
    bottom = vertical_crossings(molds.shell_bottom, keys[:, :2])
    top = vertical_crossings(molds.shell_top, keys[:, :2])
    # bottom half: a pin standing key_height above the split plane; top half: a hole key_height + clearance deep
    assert np.nanmax(bottom, axis=1) == pytest.approx([z + h] * 3, abs=1e-3)
    assert np.nanmin(top, axis=1) == pytest.approx([z + h + c] * 3, abs=1e-3)
    # the fourth corner has no key: the halves fit together one way only
    lo, hi = molds.shell_bottom.bounds
    free = np.array([[lo[0] + sh["wall"] / 2, hi[1] - sh["wall"] / 2]])
    assert np.nanmax(vertical_crossings(molds.shell_bottom, free)) == pytest.approx(z, abs=1e-3)
    # pour and vent: nothing of the top half on their axes (open from the top into the cavity)
    for hole in (sh["pour"], sh["vent"]):
        axis = np.array([hole["center"][:2]])
        assert np.all(np.isnan(vertical_crossings(molds.shell_top, axis)))
    # the core carries a boss on every IPAM end
    assert len(molds.info["ipam_markers"]) == 2 * 5


def test_bad_mold_sizes_are_clear(design):
    with pytest.raises(DesignError, match="too thin"):
        mold_set(design, wall=4e-3)
    with pytest.raises(DesignError, match="layer_thickness"):
        mold_set(design, layer_thickness=0.0)


def test_core_stands_on_a_flat_seat_clear_of_the_ipam_ends(design, molds):
    """The core's lowest layer is a flat disk (the seat, where the air tubes leave the device): under
    the centroid, 25 mm in radius at most (30 % of the core's width), unless IPAM ends lie there;
    the Fig. 6 device has one at the bottom pole, so its seat moves beside it and keeps the bosses
    clear. The sidecar names the boss tips and face centroids apart and says how each part prints."""
    core, info = molds.core, molds.info
    seat = info["core_seat"]
    bottom = core.bounds[0, 2]
    flat = (core.face_normals[:, 2] < -0.999) & (np.abs(core.triangles_center[:, 2] - bottom) < 1e-4)
    area = float(core.area_faces[flat].sum())
    assert area == pytest.approx(np.pi * seat["radius"] ** 2, rel=0.01)  # a 64-sided disk
    assert 8.0 <= seat["radius"] <= min(25.0, 0.3 * 70.0)
    ends = np.array([m["face_centroid"] for m in info["ipam_markers"]])
    low = ends[ends[:, 2] < 0]
    gap = np.linalg.norm(low[:, :2] - np.array(seat["center"][:2]), axis=1).min()
    assert gap >= seat["radius"] + info["marker_radius"]  # no boss under the seat
    assert "air tubes" in seat["note"] and seat["covers_ipam_ends"] == []
    m = info["ipam_markers"][0]
    tip, face = np.array(m["position"]), np.array(m["face_centroid"])
    assert np.linalg.norm(tip - face) == pytest.approx(info["marker_height"], abs=1e-6)  # 2 mm proud
    assert "report.md" in info["ipam_markers_note"]
    assert "pins stick up" in info["printing"]["shell_bottom"]


def test_seat_goes_under_the_centroid_when_nothing_is_there(design):
    from warp_shape.molds import seat_place

    body = design.rest.to_trimesh()
    centre, radius = seat_place(body, np.zeros((0, 3)))
    assert centre == pytest.approx(body.centroid[:2], abs=1e-12) and radius == pytest.approx(0.3 * 0.07, rel=0.02)


def _designs_with(n_ipams: int):
    """A design of the shipped problems' shape with ``n_ipams`` IPAMs: the rest shape the designer
    starts from (heart alone for 1, oval and heart for 4, the four targets for 20), each IPAM joining
    the faces nearest to a pair of opposite directions spread over the sphere (no design run)."""
    import warp_shape as ws
    from warp_shape.display import Design
    from warp_shape.designer.initialize import initial_rest_shape

    names = {1: ["heart"], 4: ["oval", "heart"], 20: ["oval", "pear", "heart", "cube"]}[n_ipams]
    rest = initial_rest_shape(ws.load_scene("four_targets_20").design.rest, [ws.target(t) for t in names])
    d = Design(rest)
    c = rest.face_centroids()
    u = c / np.linalg.norm(c, axis=1, keepdims=True)
    taken: set = set()
    for k in range(n_ipams):  # a Fibonacci spiral of directions; the first is the top-bottom axis
        z = 1.0 - (k + 0.5) / n_ipams if n_ipams > 1 else 1.0
        r, a = np.sqrt(1.0 - z * z), k * np.pi * (3.0 - np.sqrt(5.0))
        ends = []
        for sign in (1.0, -1.0):
            f = next(int(f) for f in np.argsort(-sign * (u @ [r * np.cos(a), r * np.sin(a), z])) if int(f) not in taken)
            taken.add(f)
            ends.append(f)
        d.add_ipam(*ends)
    return d


@pytest.mark.slow
@pytest.mark.skipif(shutil.which("prusa-slicer") is None,
                    reason="PrusaSlicer is not installed here (apt-get install prusa-slicer): the slicing check is skipped")
@pytest.mark.parametrize("n_ipams", [1, 4, 20])
def test_prusa_slicer_slices_every_mold_part(n_ipams, tmp_path):
    """PrusaSlicer with its default settings (no supports) slices every part into G-code; before the
    seat, the core of the one- and four-IPAM designs stood on a point ("There is an object with no
    extrusions in the first layer")."""
    write_molds(_designs_with(n_ipams), tmp_path, marker_height=2e-3, layer_thickness=LAYER)
    for part in ("mold_core", "mold_shell_bottom", "mold_shell_top"):
        stl, gcode = tmp_path / f"{part}_mm.stl", tmp_path / f"{part}.gcode"
        run = subprocess.run(["prusa-slicer", "--export-gcode", str(stl), "--output", str(gcode)],
                             capture_output=True, text=True, timeout=300)
        assert run.returncode == 0 and gcode.exists(), (n_ipams, part, run.stdout[-500:], run.stderr[-500:])
        text = gcode.read_text()
        assert text.count(";LAYER_CHANGE") > 100, (n_ipams, part)  # ~90 mm at 0.3 mm layers
        assert "; support_material = 0" in text
