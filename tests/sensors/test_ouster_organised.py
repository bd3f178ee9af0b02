"""The OS1's clouds as ouster-ros publishes them (issue 30): organised 64 x 1024 (row =
ring, column = the revolution's column), ouster_ros::Point's offsets, the cells without
a return zero (or NaN), each cell with a return the simulated point of that beam and
column; signal photons and calibrated reflectivity against the lidar equation."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from raytrace import Scene
from raytrace.shapes import tunnel_tube
from sensors import PointFileError, Trajectory, load_sensor, simulate_drive
from sensors.physics import Settings
from sensors.bag import RosbagStream
from sensors.spec import SPEC_DIR, with_rate
from sensors.writers import open_writer

pytest.importorskip("rosbags", reason="rosbags is in the test extra")
from rosbags.highlevel import AnyReader  # noqa: E402

T0 = 50.0
TOPIC = "/ouster/points"


def _c_struct(members):
    """Offsets of a C struct (each member aligned to its size) and its size rounded up
    to 16 bytes (EIGEN_ALIGN16): ouster_ros::Point of include/ouster_ros/os_point.h,
    PCL_ADD_POINT4D being x, y, z and a pad float."""
    out, off = [], 0
    for n, t, size in members:
        off = -(-off // size) * size
        if n != "pad":
            out.append((n, off, t))
        off += size
    return out, -(-off // 16) * 16


OUSTER, STEP = _c_struct([("x", "f4", 4), ("y", "f4", 4), ("z", "f4", 4), ("pad", "f4", 4),
                          ("intensity", "f4", 4), ("t", "u4", 4),
                          ("reflectivity", "u2", 2), ("ring", "u2", 2),
                          ("ambient", "u2", 2), ("range", "u4", 4)])
ROS_TYPE = {"u2": 4, "u4": 6, "f4": 7}


@pytest.fixture(scope="module")
def scene():
    # a short tube: the beams along its axis leave through the portal (no return)
    v, f = tunnel_tube(6_000, length_m=20.0, seed=5)
    return Scene(v, f)


@pytest.fixture(scope="module")
def traj():
    return Trajectory.along_polyline([[4.0, 0.0, 1.4], [10.0, 0.0, 1.4]], 1.0, rate_hz=50,
                                     start_time=T0)


def _bag(run, traj, path, spec=None):
    with open_writer(path, sensor=spec or run.sensor, seed=run.seed, mount=run.mount,
                     trajectory=traj, span_s=(run.t0, run.t0 + run.duration_s)) as w:
        for chunk in run:
            w.write_points(chunk)
    with AnyReader([Path(path)]) as r:
        conns = [c for c in r.connections if c.topic == TOPIC]
        return [r.deserialize(raw, c.msgtype)
                for c, _t, raw in r.messages(connections=conns)]


def _grid(msg):
    dt = np.dtype({"names": [n for n, _o, _t in OUSTER],
                   "formats": ["<" + t for _n, _o, t in OUSTER],
                   "offsets": [o for _n, o, _t in OUSTER], "itemsize": STEP})
    g = np.frombuffer(np.asarray(msg.data, dtype=np.uint8).tobytes(), dtype=dt)
    return g.reshape(msg.height, msg.width)


def _rows(spec):
    """Row of each channel: ouster-ros's ring u counts the beams from the top
    (beam_altitude_angles are listed top down): the rank by descending elevation."""
    el = spec.pattern.elevations_rad
    return np.argsort(np.argsort(-el, kind="stable"), kind="stable")


@pytest.fixture(scope="module")
def drive(scene, traj, tmp_path_factory):
    run = simulate_drive(scene, "ouster_os1_64", traj, seed=3, t_end=T0 + 0.2)
    msgs = _bag(run, traj, tmp_path_factory.mktemp("os1") / "os1.mcap")
    return run, np.concatenate(list(run)), msgs


def test_the_cloud_is_the_organised_grid_of_the_simulation(drive):
    run, pts, msgs = drive
    spec = run.sensor
    T = spec.pattern.column_period_s
    rows = _rows(spec)
    assert len(msgs) == 2
    for k, msg in enumerate(msgs):
        assert (msg.height, msg.width) == (64, 1024)
        assert [(f.name, f.offset, f.datatype, f.count) for f in msg.fields] == \
            [(n, o, ROS_TYPE[t], 1) for n, o, t in OUSTER]
        assert msg.point_step == STEP == 48 and msg.row_step == 48 * 1024
        g = _grid(msg)
        sweep = pts[pts["frame"] == k]
        r, c = rows[sweep["channel"]], sweep["column"]
        hit = np.zeros((64, 1024), dtype=bool)
        hit[r, c] = True
        assert hit.sum() == len(sweep)                # one return per beam and column
        assert 0 < len(sweep) < 64 * 1024 and not msg.is_dense
        # zeros exactly where the simulation had no return
        empty = g[~hit]
        for f in ("x", "y", "z", "intensity", "reflectivity", "ambient", "range"):
            assert not empty[f].any(), f
        assert np.all(g[hit]["range"] > 0)
        # every cell: ring = its row; t = its column's time after the stamp (ns)
        np.testing.assert_array_equal(g["ring"], np.repeat(np.arange(64), 1024)
                                      .reshape(64, 1024))
        col = np.tile(np.arange(1024), (64, 1))
        np.testing.assert_array_equal(g["t"][~hit], np.round(col[~hit] * T * 1e9))
        # a cell with a return is the simulation's point of that beam and column
        cell = g[r, c]
        stamp = T0 + k * 0.1
        for a, b in (("x", "sx"), ("y", "sy"), ("z", "sz")):
            np.testing.assert_array_equal(cell[a], sweep[b].astype(np.float32))
        np.testing.assert_array_equal(cell["range"], np.round(sweep["range"] * 1e3))
        np.testing.assert_array_equal(cell["t"], np.round((sweep["time"] - stamp) * 1e9))
        assert np.all(cell["intensity"] > 0) and not cell["ambient"].any()


def test_no_return_nan_follows_ouster_ros_mainline(scene, traj, tmp_path):
    text = (SPEC_DIR / "ouster_os1_64.toml").read_text()
    assert 'no_return = "zero"' in text
    p = tmp_path / "os1_nan.toml"
    p.write_text(text.replace('no_return = "zero"', 'no_return = "nan"'))
    spec = load_sensor(p)
    run = simulate_drive(scene, spec, traj, seed=3, t_end=T0 + 0.1)
    msg = _bag(run, traj, tmp_path / "nan.mcap", spec)[0]
    g = _grid(msg)
    pts = np.concatenate(list(run))
    pts = pts[pts["frame"] == 0]          # the points of the one whole sweep
    hit = np.zeros((64, 1024), dtype=bool)
    hit[_rows(spec)[pts["channel"]], pts["column"]] = True
    assert not msg.is_dense and (~hit).any()
    for a in ("x", "y", "z"):
        assert np.all(np.isnan(g[a][~hit])) and np.all(np.isfinite(g[a][hit]))
    assert not g["range"][~hit].any() and not g["intensity"][~hit].any()


def test_signal_and_reflectivity_follow_the_lidar_equation(scene, traj, tmp_path):
    """Ideal geometry, one reflectivity rho: P = rho cos(theta) / R^2 from the simulated
    range and incidence; signal = 10 photons x P / P_min (capped at 65535); calibrated
    reflectivity = round(100 rho cos(theta)) (Ouster: corrected for range only)."""
    rho = 0.6
    run = simulate_drive(scene, "ouster_os1_64", traj, seed=3, t_end=T0 + 0.1,
                         settings=Settings.ideal(), reflectivity=rho)
    msg = _bag(run, traj, tmp_path / "ideal.mcap")[0]
    pts = np.concatenate(list(run))
    pts = pts[pts["frame"] == 0]
    cell = _grid(msg)[_rows(run.sensor)[pts["channel"]], pts["column"]]
    phys = run.sensor.physics
    cos = np.cos(pts["incidence"].astype(np.float64))
    p = rho * cos / pts["range"] ** 2
    seen = p >= phys.threshold_power          # below it the intensity is clipped to 0
    assert seen.mean() > 0.9
    np.testing.assert_allclose(cell["intensity"][seen], np.minimum(
        10.0 * p[seen] / phys.threshold_power, 65535.0), rtol=2e-5)
    want = np.round(100 * rho * cos[seen])
    got = cell["reflectivity"][seen].astype(float)
    # float32 intensity and incidence: a value on a .5 boundary may round either way
    assert np.abs(got - want).max() <= 1 and np.mean(got == want) > 0.99
    assert got.max() <= 60


def test_organised_clouds_need_whole_columns_per_revolution(tmp_path):
    spec = with_rate(load_sensor("ouster_os1_64"), 7.0)     # 1462.86 columns a turn
    with pytest.raises(PointFileError, match="whole number of columns"):
        RosbagStream(tmp_path / "x.mcap", spec, single_file=True)
    assert not list(tmp_path.iterdir())


def test_driver_layout_keys_are_strict(tmp_path):
    from sensors import SensorSpecError

    text = (SPEC_DIR / "ouster_os1_64.toml").read_text()
    p = tmp_path / "mine.toml"
    for old, new, match in [
            ('no_return = "zero"', 'no_return = "none"', "no_return"),
            ("organized = true", 'organized = "yes"', "organized"),
            ("signal_photons_at_threshold = 10.0", "signal_photons_at_threshold = -1.0",
             "signal_photons_at_threshold"),
            ("signal_photons_at_threshold = 10.0", "", "signal_photons_at_threshold"),
            ("organized = true", "organised = true", "organized")]:   # a misspelt key
        p.write_text(text.replace(old, new))
        with pytest.raises(SensorSpecError, match=match):
            load_sensor(p)


@settings(max_examples=40, deadline=None)
@given(st.integers(1, 8), st.integers(1, 16), st.integers(0, 2 ** 32 - 1),
       st.sampled_from(["zero", "nan"]))
def test_organise_puts_each_return_in_its_cell(height, width, seed, no_return):
    """Any set of (beam, column) returns, beams in any ring order: the grid holds each
    return at (ring, column) and the empty-cell pattern elsewhere (reference: a
    brute-force loop over the cells)."""
    from sensors.io.fields import POINT_DTYPE
    from sensors.pointcloud2 import LAYOUTS, organise

    g = np.random.default_rng(seed)
    rings = g.permutation(height).astype(np.uint16)       # ring of each channel
    hit = g.random((height, width)) < 0.6                  # by (channel, column)
    ch, col = np.nonzero(hit)
    sweep = np.zeros(len(ch), dtype=POINT_DTYPE)
    sweep["channel"], sweep["column"] = ch, col
    layout = LAYOUTS["ouster"]
    pts = np.zeros(len(ch), dtype=layout.dtype)
    pts["x"] = g.uniform(1, 2, len(ch))
    pts["range"] = g.integers(500, 10_000, len(ch))
    pts["ring"] = rings[ch]
    offsets = g.uniform(0, 1e-5, height)
    grid, dense = organise(layout, pts, sweep, rings, width, 1e-4, offsets, no_return)
    assert grid.shape == (height * width,) and dense == bool(hit.all())
    for c in range(height):
        for v in range(width):
            cell = grid[int(rings[c]) * width + v]
            assert cell["ring"] == rings[c]
            assert cell["t"] == round((v * 1e-4 + offsets[c]) * 1e9) or hit[c, v]
            if hit[c, v]:
                j = np.flatnonzero((ch == c) & (col == v))[0]
                assert cell["x"] == pts["x"][j] and cell["range"] == pts["range"][j]
            else:
                assert cell["range"] == 0 and cell["intensity"] == 0
                assert (np.isnan(cell["x"]) if no_return == "nan" else cell["x"] == 0)


def test_the_drive_reader_drops_the_cells_without_a_return(drive, tmp_path, traj):
    # `tunnelsim slam` reads bags through survey.clouds.drives: an organised OS1 frame
    # gives the simulation's points of that sweep, no (0, 0, 0) cell.
    from survey.clouds.drives import iter_frames, open_drive

    run, pts, _ = drive
    path = tmp_path / "os1.mcap"
    _bag(run, traj, path)
    frames = list(iter_frames(open_drive(path)))
    assert len(frames) == 2
    for k, fr in enumerate(frames):
        sweep = pts[pts["frame"] == k]
        got = np.asarray(fr.points)
        assert len(got) == len(sweep)
        assert np.all(np.abs(got).sum(axis=1) > 0)
