"""load_mesh refuses damaged or face-less PLY meshes with the reason, through the
library and through the commands that take --mesh (one line, exit 2)."""

from __future__ import annotations

import numpy as np
import pytest

from sensors.io.errors import MeshFileError
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
    with pytest.raises(MeshFileError, match=r"promise|record|held|expected"):
        load_mesh(tmp_path / "cut.ply")


def test_a_point_cloud_is_not_a_mesh(tmp_path, capsys):
    vert = np.zeros(30, dtype=[("x", "<f8"), ("y", "<f8"), ("z", "<f8")])
    write_ply(tmp_path / "cloud.ply", {"vertex": vert})
    with pytest.raises(MeshFileError, match="30 vertices and no faces"):
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


def test_every_mesh_format_reads_the_same_geometry(tmp_path):
    """PLY (our reader), OBJ, STL, OFF, GLB and Collada (trimesh) give a Scene whose
    hits equal the one built from the arrays; STL/GLB store float32 vertices."""
    trimesh = pytest.importorskip("trimesh")
    from raytrace import Scene
    from sensors.io.meshes import MESH_SUFFIXES, read_mesh
    from raytrace.shapes import tunnel_tube

    v, f = tunnel_tube(2_000, length_m=10.0)
    mesh = trimesh.Trimesh(v, f, process=False)
    o = np.array([5.0, 0.0, 1.5])
    d = np.random.default_rng(1).standard_normal((2000, 3))
    ref = Scene(v, f).cast(o, d)
    exts = [s.lstrip(".") for s in MESH_SUFFIXES if s != ".gltf"]
    try:
        import collada  # noqa: F401
    except ImportError:  # pragma: no cover - the test extra installs it
        exts.remove("dae")
    for ext in exts:
        path = tmp_path / f"t.{ext}"
        mesh.export(path)
        scene, _ = load_mesh(path)
        h = scene.cast(o, d)
        np.testing.assert_array_equal(h.hit, ref.hit)
        np.testing.assert_allclose(h.t[h.hit], ref.t[ref.hit], atol=1e-5)
        assert read_mesh(path).faces.shape == f.shape
    with pytest.raises(MeshFileError, match="does not exist"):
        read_mesh(tmp_path / "nope.ply")
    (tmp_path / "junk.obj").write_text("this is not a mesh")
    with pytest.raises(MeshFileError, match="junk.obj"):
        read_mesh(tmp_path / "junk.obj")


def test_non_finite_vertices_and_quads_are_refused(tmp_path):
    from sensors.io.meshes import read_mesh, write_mesh

    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0.0]])
    write_mesh(tmp_path / "nan.ply", np.vstack([v, [[np.nan, 0, 0]]]), [[0, 1, 2]])
    with pytest.raises(MeshFileError, match="finite vertex coordinates .* vertex 3"):
        read_mesh(tmp_path / "nan.ply")
    vert = np.zeros(4, dtype=[("x", "<f8"), ("y", "<f8"), ("z", "<f8")])
    face = np.zeros(1, dtype=[("vertex_indices", "<i4", (4,))])
    face["vertex_indices"] = [0, 1, 2, 3]
    write_ply(tmp_path / "quad.ply", {"vertex": vert, "face": face})
    with pytest.raises(MeshFileError, match="triangles only"):
        read_mesh(tmp_path / "quad.ply")


from hypothesis import given, settings, strategies as st  # noqa: E402


@settings(max_examples=25, deadline=None)
@given(n=st.integers(3, 40), m=st.integers(1, 30), seed=st.integers(0, 2**31 - 1),
       offset=st.sampled_from([0.0, 2_600_000.0]))
def test_write_then_read_is_exact(tmp_path_factory, n, m, seed, offset):
    """write_mesh -> read_mesh keeps every vertex bit (float64, UTM offsets too), every
    face and every field with its dtype."""
    from sensors.io.meshes import read_mesh, write_mesh

    rng = np.random.default_rng(seed)
    v = rng.normal(size=(n, 3)) * 50 + offset
    f = rng.integers(0, n, size=(m, 3))
    vf = {"chainage": rng.normal(size=n), "dx": rng.normal(size=n).astype(np.float32)}
    ff = {"label": rng.integers(0, 9, m).astype(np.uint8),
          "reflectivity": rng.random(m).astype(np.float32)}
    path = tmp_path_factory.mktemp("rt") / "m.ply"
    write_mesh(path, v, f, vertex_fields=vf, face_fields=ff)
    back = read_mesh(path)
    np.testing.assert_array_equal(back.vertices, v)
    np.testing.assert_array_equal(back.faces, f)
    for got, want in ((back.vertex_fields, vf), (back.face_fields, ff)):
        assert set(got) == set(want)
        for k in want:
            assert got[k].dtype == want[k].dtype
            np.testing.assert_array_equal(got[k], want[k])
