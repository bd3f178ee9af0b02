"""sensors.io.e57: several scans with their poses read in world coordinates; corrupt, cut,
empty files give one line naming the file, not libE57's multi-line dump."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from sensors.io.e57 import read_e57, write_e57_scan
from sensors.io.errors import PointFileError
from tests import iofiles as F


def test_scans_come_back_in_world_coordinates(tmp_path):
    a, b = F.tunnel_points(40, origin=(0, 0, 0)), F.tunnel_points(30, seed=2,
                                                                   origin=(0, 0, 0))
    rot = Rotation.from_euler("z", 30, degrees=True)
    q = rot.as_quat()
    F.e57_file(tmp_path / "s.e57", [a, b],
               poses=[(np.array([1.0, 0, 0, 0]), np.zeros(3)),
                      (np.array([q[3], q[0], q[1], q[2]]), np.array([5.0, 6.0, 7.0]))])
    got = list(read_e57(tmp_path / "s.e57"))
    # pye57 stores coordinates as float32 in its writer: compare at that precision.
    np.testing.assert_allclose(got[0], a, atol=2e-5)
    np.testing.assert_allclose(got[1], rot.apply(b) + [5.0, 6.0, 7.0], atol=2e-5)


def test_write_e57_scan_round_trip_and_refusals(tmp_path):
    xyz = F.tunnel_points(20, origin=(0, 0, 0))
    q = Rotation.from_euler("x", 10, degrees=True).as_quat()
    write_e57_scan(tmp_path / "w.e57", xyz, rotation_xyzw=q, translation=[1.0, 2.0, 3.0],
                   name="t", row=np.arange(20), column=np.zeros(20))
    (got,) = read_e57(tmp_path / "w.e57")
    np.testing.assert_allclose(got, Rotation.from_quat(q).apply(xyz) + [1, 2, 3], atol=2e-5)
    with pytest.raises(PointFileError, match="at least one point"):
        write_e57_scan(tmp_path / "z.e57", np.empty((0, 3)), rotation_xyzw=q,
                       translation=np.zeros(3), name="t")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["w.e57"]


def _flip(p, at):
    b = bytearray(p.read_bytes())
    b[at] ^= 0xFF
    p.write_bytes(bytes(b))


@pytest.mark.parametrize("damage,match", [
    (lambda p: p.write_bytes(b""), r"empty \(0 bytes\)"),
    (lambda p: _flip(p, 2000), "checksum mismatch"),
    (lambda p: F.truncate(p, 0.5), "refuses"),
    (lambda p: p.write_bytes(bytes(48) + p.read_bytes()[48:]), "refuses"),
    (lambda p: p.write_bytes(b"not an e57 file" * 100), "refuses"),
])
def test_damaged_files_give_one_line(tmp_path, damage, match):
    p = tmp_path / "s.e57"
    F.e57_file(p, [F.tunnel_points(40)])
    damage(p)
    with pytest.raises(PointFileError, match=match) as err:
        list(read_e57(p))
    assert "\n" not in str(err.value) and str(p) in str(err.value)


def test_an_empty_scan_is_skipped(tmp_path):
    F.e57_empty_scan(tmp_path / "z.e57")
    assert list(read_e57(tmp_path / "z.e57")) == []
