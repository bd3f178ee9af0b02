"""load_mesh refuses damaged or face-less PLY meshes with the reason, through the
library and through the commands that take --mesh (one line, exit 2)."""

from __future__ import annotations

import numpy as np
import pytest

from raytrace.errors import SceneFileError
from sensors import load_mesh
from sensors.io.ply import write_ply
from survey.cli.main import main


def _mesh(path):
    v = np.array([[0, 0, 0], [4, 0, 0], [0, 4, 0], [0, 0, 4]], dtype=np.float64)
    f = np.array([[0, 1, 2], [0, 1, 3], [0, 2, 3], [1, 2, 3]], dtype=np.int32)
    vert = np.zeros(4, dtype=[("x", "<f8"), ("y", "<f8"), ("z", "<f8")])
    vert["x"], vert["y"], vert["z"] = v.T
    face = np.zeros(4, dtype=[("vertex_indices", "<i4", (3,))])
    face["vertex_indices"] = f
    write_ply(path, {"vertex": vert, "face": face})
    return v, f


def test_a_whole_mesh_loads(tmp_path):
    v, f = _mesh(tmp_path / "m.ply")
    scene, refl = load_mesh(tmp_path / "m.ply")
    assert scene.n_triangles == 4 and refl is None
    np.testing.assert_array_equal(scene.vertices, v)


def test_a_cut_short_mesh_names_what_was_promised(tmp_path):
    _mesh(tmp_path / "m.ply")
    data = (tmp_path / "m.ply").read_bytes()
    (tmp_path / "cut.ply").write_bytes(data[:-20])
    with pytest.raises(SceneFileError, match=r"promise|record|held|expected"):
        load_mesh(tmp_path / "cut.ply")


def test_a_point_cloud_is_not_a_mesh(tmp_path, capsys):
    vert = np.zeros(30, dtype=[("x", "<f8"), ("y", "<f8"), ("z", "<f8")])
    write_ply(tmp_path / "cloud.ply", {"vertex": vert})
    with pytest.raises(SceneFileError, match="30 vertices and no faces"):
        load_mesh(tmp_path / "cloud.ply")
    rc = main(["scan", "--mesh", str(tmp_path / "cloud.ply"), "--at", "1,1,1", "-o",
               str(tmp_path / "s.laz")])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and "no faces (a point cloud?)" in err[0]
    assert not (tmp_path / "s.laz").exists()


def test_every_point_field_has_a_unit_and_angles_are_radians():
    from sensors.io.fields import FIELD_UNITS, POINT_DTYPE

    assert set(FIELD_UNITS) == set(POINT_DTYPE.names)
    assert {n for n, u in FIELD_UNITS.items() if u == "rad"} == \
        {"azimuth", "elevation", "incidence"}
