"""sensors.io.ply: written files read by trimesh (an independent reader), other writers'
files read back exactly, damaged files refused with what was promised and held."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from sensors.io.errors import PointFileError
from sensors.io.ply import PlyWriter, ply_element, read_ply, read_ply_header, write_ply
from tests import iofiles as F


def test_streamed_cloud_of_unknown_length_reads_in_trimesh(tmp_path):
    dt = np.dtype([("x", "f8"), ("y", "f8"), ("z", "f8"), ("channel", "i4"),
                   ("flag", "u1")])
    rec = np.zeros(1000, dtype=dt)
    rec["x"], rec["y"], rec["z"] = F.tunnel_points(1000).T
    rec["channel"] = np.arange(1000)
    with PlyWriter(tmp_path / "c.ply", [("vertex", dt, None)], comments=["a test"]) as w:
        for i in range(0, 1000, 300):
            w.write("vertex", rec[i:i + 300])
    cloud = trimesh.load(tmp_path / "c.ply")
    np.testing.assert_array_equal(cloud.vertices, F.tunnel_points(1000))
    back = read_ply(tmp_path / "c.ply")["vertex"]
    np.testing.assert_array_equal(back, rec)
    assert "comment a test" in read_ply_header(tmp_path / "c.ply").comments


def test_mesh_with_face_properties_reads_in_trimesh(tmp_path):
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], dtype=np.float64)
    f = np.array([[0, 1, 2], [0, 1, 3], [0, 2, 3]])
    vert = np.zeros(4, dtype=[("x", "f8"), ("y", "f8"), ("z", "f8")])
    vert["x"], vert["y"], vert["z"] = v.T
    face = np.zeros(3, dtype=[("vertex_indices", "i4", (3,)), ("label", "u1")])
    face["vertex_indices"], face["label"] = f, [1, 2, 3]
    write_ply(tmp_path / "m.ply", {"vertex": vert, "face": face})
    m = trimesh.load(tmp_path / "m.ply", process=False)
    np.testing.assert_array_equal(m.faces, f)
    np.testing.assert_array_equal(m.vertices, v)
    back = read_ply(tmp_path / "m.ply")
    np.testing.assert_array_equal(back["face"]["vertex_indices"], f)
    np.testing.assert_array_equal(back["face"]["label"], [1, 2, 3])


def test_big_endian_files_read_exactly(tmp_path):
    xyz = F.tunnel_points(50)
    F.ply_cloud(tmp_path / "b.ply", xyz, big_endian=True, extra={"i": np.arange(50.0)})
    v = ply_element(tmp_path / "b.ply")
    np.testing.assert_array_equal(np.stack([v["x"], v["y"], v["z"]], 1), xyz)
    np.testing.assert_array_equal(read_ply(tmp_path / "b.ply")["vertex"]["i"], np.arange(50))


def _header_with(lines):
    return ("\n".join(["ply", "format binary_little_endian 1.0", *lines, "end_header"])
            + "\n").encode()


@pytest.mark.parametrize("data,match", [
    (b"", r"empty \(0 bytes\)"),
    (b"solid cube\n", "without the 'ply' magic"),
    (b"ply\nformat binary_little_endian 1.0\nelement vertex 3\n", "no 'end_header'"),
    (b"ply\nformat ascii 1.0\nelement vertex 0\nproperty float x\nend_header\n",
     "got format 'ascii'"),
    (_header_with(["element vertex many", "property float x"]), "malformed line"),
    (_header_with(["element vertex 1", "property float128 x"]), "malformed line"),
    (_header_with(["property float x"]), "malformed line"),
    (_header_with(["element vertex 1"]) + bytes(4), "has no properties"),
    (_header_with(["element vertex 2", "property float x", "property float x"]) + bytes(8),
     "names a property twice"),
    (_header_with(["element vertex 1", "property float x", "fancy stuff"]),
     "unknown header line"),
])
def test_broken_headers_give_one_clear_error(tmp_path, data, match):
    (tmp_path / "b.ply").write_bytes(data)
    with pytest.raises(PointFileError, match=match):
        read_ply(tmp_path / "b.ply")


def test_cut_short_and_overcounted_files_say_what_they_promised(tmp_path):
    p = tmp_path / "c.ply"
    F.ply_cloud(p, F.tunnel_points(600))
    F.truncate(p, 0.5)
    with pytest.raises(PointFileError, match=r"Expected 600 vertex records .* got \d+ "
                                             r"whole ones: the file is cut short"):
        ply_element(p)
    F.ply_cloud(p, F.tunnel_points(600))
    F.set_ply_count(p, 695_000)
    with pytest.raises(PointFileError, match=r"Expected 695,000 vertex records .* got 600"):
        ply_element(p)


def test_undercounted_file_warns_about_the_bytes_it_leaves(tmp_path):
    p = tmp_path / "c.ply"
    F.ply_cloud(p, F.tunnel_points(600))
    F.set_ply_count(p, 500)
    with pytest.warns(UserWarning, match="2,400 bytes after the records"):
        assert len(ply_element(p)) == 500


def test_ragged_faces_are_refused(tmp_path):
    head = _header_with(["element vertex 4", "property float x", "property float y",
                         "property float z", "element face 2",
                         "property list uchar int vertex_indices"])
    faces = bytes([3]) + np.array([0, 1, 2], "<i4").tobytes() + bytes([4]) + \
        np.array([0, 1, 2], "<i4").tobytes()
    (tmp_path / "q.ply").write_bytes(head + bytes(48) + faces)
    with pytest.raises(PointFileError, match="lists of one length"):
        read_ply(tmp_path / "q.ply")


def test_writer_leaves_nothing_on_error_and_checks_counts(tmp_path):
    dt = np.dtype([("x", "f8")])
    with pytest.raises(KeyboardInterrupt), \
            PlyWriter(tmp_path / "a.ply", [("vertex", dt, None)]) as w:
        w.write("vertex", np.zeros(3, dt))
        raise KeyboardInterrupt
    with pytest.raises(PointFileError, match="Expected 5 vertex records"), \
            PlyWriter(tmp_path / "b.ply", [("vertex", dt, 5)]) as w:
        w.write("vertex", np.zeros(3, dt))
    with pytest.raises(PointFileError, match="PLY property types"):
        PlyWriter(tmp_path / "c.ply", [("vertex", np.dtype([("x", "i8")]), None)])
    assert not list(tmp_path.iterdir())
