"""Reading trajectories (issue 21): CSV columns by their header names in any order,
the headerless rule, unknown names refused, TUM as it was, and time stamps that cannot
be seconds (nanoseconds, microseconds, milliseconds) refused with the unit and the fix;
and the trapezoidal start and stop of ``along_polyline(accel_mps2=...)``."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from sensors import Trajectory
from sensors.errors import TrajectoryError
from sensors.trajectory import CSV_COLUMNS, csv_column_order, looks_like_time_unit

FIELDS = ("t", "x", "y", "z", "qx", "qy", "qz", "qw")


def _poses(n=50, t0=0.0):
    """(n, 8) rows t x y z qx qy qz qw: a path with a tilted, turning attitude (no
    component of the quaternions is zero, so a swapped column always shows)."""
    t = t0 + 0.01 * np.arange(n)
    q = Rotation.from_euler("zyx", np.c_[0.3 + 0.02 * np.arange(n), np.full(n, 0.4),
                                         np.full(n, -0.7)]).as_quat(canonical=True)
    pos = np.c_[10 + np.arange(n) * 0.1, -3 + 0.05 * np.arange(n), 1.5 + 0 * t]
    return np.c_[t, pos, q]


def _write_csv(path, rows, header):
    with open(path, "w") as fh:
        if header is not None:
            fh.write(",".join(header) + "\n")
        np.savetxt(fh, rows, delimiter=",", fmt="%.17g")   # exact round trip
    return path


def _same(a: Trajectory, rows, atol=1e-12):
    """The trajectory holds the rows (``atol``: 1e-12, or the writer's 9 decimals)."""
    np.testing.assert_allclose(a.times, rows[:, 0], rtol=0, atol=atol)
    np.testing.assert_allclose(a.positions, rows[:, 1:4], rtol=0, atol=atol)
    np.testing.assert_allclose(a.rotations.as_quat(canonical=True), rows[:, 4:8], rtol=0,
                               atol=atol)


# ---------------------------------------------------------------------------- CSV
def test_issue_header_is_read_by_name(tmp_path):
    """The file of the issue: qw before qx. The spin axis (body z in the world) comes
    out as the rows say, not horizontal."""
    rows = _poses()
    order = [0, 1, 2, 3, 7, 4, 5, 6]                 # t, px, py, pz, qw, qx, qy, qz
    path = _write_csv(tmp_path / "a.csv", rows[:, order],
                      ["timestamp", "px", "py", "pz", "qw", "qx", "qy", "qz"])
    got = Trajectory.read(path)
    _same(got, rows)
    z_axis = got.rotations.apply([0.0, 0.0, 1.0])
    np.testing.assert_allclose(z_axis, Rotation.from_quat(rows[:, 4:8]).apply([0, 0, 1]),
                               atol=1e-12)
    # What reading by position gave: a quaternion (w, x, y, z) taken as (x, y, z, w).
    wrong = Rotation.from_quat(rows[:, order][:, 4:8]).apply([0.0, 0.0, 1.0])
    assert np.abs(wrong - z_axis).max() > 0.1


@settings(max_examples=60, deadline=None)
@given(perm=st.permutations(range(8)),
       alias=st.lists(st.integers(0, 2), min_size=8, max_size=8),
       upper=st.booleans(), spaces=st.booleans())
def test_any_column_order_reads_the_same_trajectory(tmp_path_factory, perm, alias, upper,
                                                     spaces):
    """Property: the 8 named columns in any order, under any of their names (any case,
    spaces around), read back the trajectory of the canonical file."""
    d = tmp_path_factory.mktemp("perm")
    rows = _poses(20)
    canon = Trajectory.read(_write_csv(d / "canon.csv", rows, list(FIELDS)))
    names = [CSV_COLUMNS[f][alias[i] % len(CSV_COLUMNS[f])] for i, f in enumerate(FIELDS)]
    names = [n.upper() if upper else n for n in names]
    header = [f" {names[j]} " if spaces else names[j] for j in perm]
    got = Trajectory.read(_write_csv(d / "p.csv", rows[:, list(perm)], header))
    np.testing.assert_array_equal(got.times, canon.times)
    np.testing.assert_array_equal(got.positions, canon.positions)
    np.testing.assert_array_equal(got.rotations.as_quat(), canon.rotations.as_quat())


def test_written_csv_reads_back(tmp_path):
    rows = _poses()
    tr = Trajectory(rows[:, 0], rows[:, 1:4], rows[:, 4:8])
    _same(Trajectory.read(tr.write(tmp_path / "w.csv")), rows, atol=1e-9)
    _same(Trajectory.read(tr.write(tmp_path / "w.txt")), rows, atol=1e-9)


def test_headerless_csv_keeps_its_first_pose(tmp_path):
    """The headerless rule: a first line of 8 numbers is a pose, TUM order."""
    rows = _poses(7)
    got = Trajectory.read(_write_csv(tmp_path / "h.csv", rows, None))
    assert len(got) == 7
    _same(got, rows)


def test_euroc_style_hash_header_and_comments(tmp_path):
    rows = _poses(5)
    path = tmp_path / "e.csv"
    with open(path, "w") as fh:
        fh.write("# exported by a tool\n\n#timestamp,tx,ty,tz,qx,qy,qz,qw\n")
        for i, r in enumerate(rows):
            fh.write(",".join(f"{v:.17g}" for v in r) + "\n")
            if i == 2:
                fh.write("# a comment between poses\n")
    _same(Trajectory.read(path), rows)


@pytest.mark.parametrize("header, match", [
    (["#timestamp", "p_RS_R_x", "py", "pz", "qw", "qx", "qy", "qz"], "unknown 'p_RS_R_x'"),
    (["t", "x", "y", "z", "qx", "qy", "qz", "qw", "vx", "vy"], "unknown 'vx', 'vy'"),
    (["t", "x", "px", "z", "qx", "qy", "qz", "qw"], r"one column for x in .*got 'x' and 'px'"),
    (["t", "x", "y", "z", "qx", "qy", "qz"], "a column for qw"),
])
def test_bad_header_is_refused_naming_the_columns(tmp_path, header, match):
    rows = np.zeros((3, len(header)))
    rows[:, 0] = [0, 1, 2]
    path = _write_csv(tmp_path / "b.csv", rows, header)
    with pytest.raises(TrajectoryError, match=match):
        Trajectory.read(path)


def test_csv_column_order_is_the_inverse_permutation():
    header = ["qz", "TIME", "ty", "qw", "X", "pz", "qx", "qy"]
    order = csv_column_order(header)
    assert [header[i].lower() for i in order] == ["time", "x", "ty", "pz", "qx", "qy",
                                                  "qz", "qw"]


@pytest.mark.parametrize("text, match", [
    ("1,2,3,4,5,6,7\n", "8 columns .* headerless .* got 7"),
    ("t,x,y,z,qx,qy,qz,qw\n", "poses .* below its header, got none"),
    ("\n# nothing\n", "got none"),
    ("t,x,y,z,qx,qy,qz,qw\n0,0,0,0,0,0,0,1\n1,0,0,0,0,0\n",
     "same number of fields on every line"),
])
def test_csv_without_poses_or_with_short_rows(tmp_path, text, match):
    path = tmp_path / "s.csv"
    path.write_text(text)
    with pytest.raises(TrajectoryError, match=match):
        Trajectory.read(path)


def test_tum_is_read_as_before(tmp_path):
    rows = _poses(6)
    path = tmp_path / "a.txt"
    with open(path, "w") as fh:
        fh.write("# t x y z qx qy qz qw\n")
        np.savetxt(fh, rows, fmt="%.17g")
        fh.write("# end\n")
    _same(Trajectory.read(path), rows)
    path.write_text("0 1 2 3 0 0 0 1\n1 1 2 3 0 0 0\n")
    with pytest.raises(TrajectoryError, match="8 numbers"):
        Trajectory.read(path)


# ---------------------------------------------------------------------------- time units
@pytest.mark.parametrize("scale, t0, unit, factor", [
    (1e9, 1.7e18, "nanoseconds", "1e9"),         # ROS stamps since 1970
    (1e9, 0.0, "nanoseconds", "1e9"),
    (1e6, 0.0, "microseconds", "1e6"),
    (1e6, 1.7e15, "microseconds", "1e6"),
    (1e3, 0.0, "milliseconds", "1e3"),
])
def test_stamps_that_are_not_seconds_are_refused(tmp_path, scale, t0, unit, factor):
    """A 99 s drive at 100 Hz, its stamps in another unit: refused on reading (the ns
    file of the issue ran until killed), naming the unit, the rate and the factor."""
    t = np.arange(9900) * 0.01
    rows = np.c_[t * scale + t0, np.c_[t, 0 * t, 0 * t], np.tile([0, 0, 0, 1.0], (len(t), 1))]
    path = tmp_path / "ns.txt"
    np.savetxt(path, rows, fmt="%.12g")
    with pytest.raises(TrajectoryError, match=rf"look like {unit} \(a pose every 10 ms\); "
                                              rf"convert .*\(divide it by {factor}\)"):
        Trajectory.read(path)
    _write_csv(tmp_path / "ns.csv", rows, list(FIELDS))
    with pytest.raises(TrajectoryError, match=unit):
        Trajectory.read(tmp_path / "ns.csv")


def test_epoch_seconds_and_sparse_handmade_poses_are_seconds(tmp_path):
    t = 1.7e9 + np.arange(500) * 0.005                  # GNSS/INS at 200 Hz, Unix time
    rows = np.c_[t, np.zeros((500, 3)), np.tile([0, 0, 0, 1.0], (500, 1))]
    np.savetxt(tmp_path / "e.txt", rows, fmt="%.9f")
    assert Trajectory.read(tmp_path / "e.txt").start_s == pytest.approx(1.7e9)
    # Two poses 20 minutes apart: a straight line drawn by hand.
    np.savetxt(tmp_path / "h.txt", [[0, 0, 0, 0, 0, 0, 0, 1], [1200, 1200, 0, 0, 0, 0, 0, 1]])
    assert Trajectory.read(tmp_path / "h.txt").duration_s == 1200


@settings(max_examples=200, deadline=None)
@given(rate=st.floats(1.5, 700), duration=st.floats(1.0, 3600.0),
       epoch=st.one_of(st.just(0.0), st.floats(1e9, 2e9)))
def test_time_unit_rule(rate, duration, epoch):
    """Property: a drive of 1 s to 1 h at 1.5-700 Hz is taken as seconds, whether its
    stamps count from 0 or from 1970; the same stamps in ns or us are refused as that
    unit."""
    t = epoch + np.arange(int(duration * rate) + 1) / rate
    assert looks_like_time_unit(t) is None
    assert looks_like_time_unit(t * 1e9) == ("nanoseconds", 1e-9)
    assert looks_like_time_unit(t * 1e6) == ("microseconds", 1e-6)


def test_epoch_against_relative_times_says_so():
    """Where two time bases meet (a cloud's times looked up on a trajectory), epoch
    seconds against seconds from 0 are named, with the offset; a plain miss is not."""
    rows = _poses(100, t0=1.7e9)
    epoch = Trajectory(rows[:, 0], rows[:, 1:4], rows[:, 4:8])
    with pytest.raises(TrajectoryError, match=r"the trajectory's look like epoch seconds "
                                              r"\(from 1700000000\) and the others like "
                                              r"seconds from a start \(from 0\).*subtract "
                                              r"1700000000 s"):
        epoch.interpolate([0.0, 0.5])
    rel = Trajectory(rows[:, 0] - 1.7e9, rows[:, 1:4], rows[:, 4:8])
    with pytest.raises(TrajectoryError, match="the others look like epoch seconds"):
        rel.interpolate([1.7e9 + 0.1])
    with pytest.raises(TrajectoryError) as exc:
        rel.interpolate([5.0])
    assert "epoch" not in str(exc.value)


@settings(max_examples=40, deadline=None)
@given(length=st.floats(0.5, 200.0), speed=st.floats(0.2, 5.0), accel=st.floats(0.1, 3.0))
def test_along_polyline_accelerates_from_rest_to_rest(length, speed, accel):
    """With accel_mps2 the trip is a trapezoid (or triangle) speed profile: it starts
    and ends at rest, never exceeds the speed or the acceleration (to the sampling),
    covers the path, and lasts the analytic time."""
    tr = Trajectory.along_polyline([[0.0, 0, 0], [length, 0, 0]], speed, accel_mps2=accel,
                                   rate_hz=200.0)
    x, t = tr.positions[:, 0], tr.times
    v = np.diff(x) / np.diff(t)
    peak = min(speed, math.sqrt(accel * length))
    want = 2 * peak / accel + (length - peak ** 2 / accel) / peak
    assert t[-1] == pytest.approx(want, rel=1e-9)
    assert x[0] == 0.0 and x[-1] == pytest.approx(length, abs=1e-9)
    assert (np.diff(x) >= 0).all() and v.max() <= peak * (1 + 1e-9)
    # Mean speed over the first and last sample steps: a body starting from rest.
    assert v[0] <= accel * np.diff(t)[0] + 1e-9 and v[-1] <= accel * np.diff(t)[-1] + 1e-9


@pytest.mark.parametrize("delim, decimal", [(";", ","), ("\t", "."), ("\t", ","), (" ", ".")])
def test_csv_in_other_dialects_reads_the_same_poses(tmp_path, delim, decimal):
    # Trajectory tables are sniffed like control points (sensors.io.tables): semicolons
    # or tabs, decimal commas, Latin-1; the poses equal the comma file's exactly.
    rows = _poses(6)
    plain = tmp_path / "plain.csv"
    _write_csv(plain, rows, ["t", "x", "y", "z", "qx", "qy", "qz", "qw"])
    other = tmp_path / "other.csv"
    lines = [delim.join(["t", "x", "y", "z", "qx", "qy", "qz", "qw"])]
    for r in rows:
        lines.append(delim.join(repr(float(v)).replace(".", decimal) for v in r))
    other.write_bytes(("\n".join(lines) + "\n").encode("latin-1"))
    a, b = Trajectory.read(plain), Trajectory.read(other)
    np.testing.assert_array_equal(a.times, b.times)
    np.testing.assert_array_equal(a.positions, b.positions)
    np.testing.assert_array_equal(a.rotations.as_quat(), b.rotations.as_quat())
