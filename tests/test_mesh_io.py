"""TriMesh.load: every common format through trimesh, validated, centred on request."""

from __future__ import annotations

import numpy as np
import pytest

import warp_shape as ws


@pytest.mark.parametrize("ext", ["stl", "obj", "ply", "glb", "off"])
def test_load_formats_round_trip(tmp_path, ext):
    mesh = ws.icosphere(2, 0.04, center=(0.01, -0.02, 0.005))
    path = tmp_path / f"sphere.{ext}"
    mesh.to_trimesh().export(str(path))
    loaded = ws.TriMesh.load(path)
    assert loaded.n_vertices == mesh.n_vertices and loaded.n_faces == mesh.n_faces
    assert loaded.volume() == pytest.approx(mesh.volume(), rel=1e-5)
    centred = ws.TriMesh.load(path, center=True)
    assert np.allclose(centred.centroid(), 0.0, atol=1e-9)
    assert centred.volume() == pytest.approx(mesh.volume(), rel=1e-5)


def test_load_rejects_bad_files(tmp_path):
    with pytest.raises(ws.MeshError, match="not found"):
        ws.TriMesh.load(tmp_path / "missing.stl")
    junk = tmp_path / "junk.stl"
    junk.write_bytes(b"\x00\x01 this is not a mesh")
    with pytest.raises(ws.MeshError, match="junk.stl"):
        ws.TriMesh.load(junk)
    # a readable but open mesh names the file and the defect
    m = ws.icosphere(1, 0.04).to_trimesh()
    m.update_faces(np.arange(len(m.faces)) != 0)
    path = tmp_path / "open.ply"
    m.export(str(path))
    with pytest.raises(ws.MeshError, match=r"open\.ply: mesh is not closed"):
        ws.TriMesh.load(path)
