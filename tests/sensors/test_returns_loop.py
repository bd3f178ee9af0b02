"""Multiple returns in the simulation loop (issue 34): ``Settings(returns=...)`` runs
the waveform model (``sensors.waveform``) per chunk; checked against a plane's
analytic ranges, the default single-return path and the chunk-independence of the
random streams."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings as hsettings, strategies as st

from raytrace import Scene
from sensors import Settings, Trajectory, load_sensor, simulate_drive
from sensors.errors import SensorSpecError, SimulationError
from sensors.io.fields import POINT_DTYPE, RETURN_POINT_DTYPE
from sensors.spec import SPEC_DIR
from sensors.waveform import DEFAULT_RETURNS

WALL_X = 5.0


@pytest.fixture(scope="module")
def wall():
    """A plane x = WALL_X, 100 m x 100 m, facing a sensor at the origin."""
    v = np.array([[WALL_X, -50, -50], [WALL_X, 50, -50], [WALL_X, 50, 50],
                  [WALL_X, -50, 50]], dtype=np.float64)
    return Scene(v, np.array([[0, 1, 2], [0, 2, 3]]))


def _drive(scene, settings, *, chunk_pulses=8192, seed=0, t_end=0.02):
    run = simulate_drive(scene, load_sensor("velodyne_vlp16"), Trajectory.static([0, 0, 0]),
                         settings=settings, seed=seed, t_end=t_end,
                         chunk_pulses=chunk_pulses, cache_bytes=0)
    chunks = list(run)
    return np.concatenate(chunks) if chunks else np.empty(0, RETURN_POINT_DTYPE)


def _plane_range(pts):
    """The analytic range along each point's beam to the plane x = WALL_X."""
    d = np.stack([pts["sx"], pts["sy"], pts["sz"]], 1)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return WALL_X / d[:, 0]


def test_strongest_on_a_plane_gives_the_plane_and_the_default_points(wall):
    ideal = Settings.ideal()
    pts = _drive(wall, Settings(range_noise=False, angle_jitter=False, detection=False,
                                returns="strongest"))
    ref = _drive(wall, ideal)
    assert pts.dtype == RETURN_POINT_DTYPE and ref.dtype == POINT_DTYPE
    assert len(pts) == len(ref) > 1000
    # one echo per pulse on a plane: the range is the plane's, to the Gaussian fit's mm
    np.testing.assert_allclose(pts["range"], _plane_range(pts), atol=1e-3)
    np.testing.assert_allclose(pts["x"], WALL_X, atol=1e-3)
    for f in ("time", "channel", "column", "triangle", "flag"):
        np.testing.assert_array_equal(pts[f], ref[f])
    np.testing.assert_allclose(pts["range"], ref["range"], atol=1e-3)
    assert (pts["return_number"] == 1).all() and (pts["number_of_returns"] == 1).all()
    # a surface filling the footprint: the echo's power is the single return's, so the
    # intensity agrees (float32 of log power)
    np.testing.assert_allclose(pts["intensity"], ref["intensity"], atol=2e-3)


def test_dust_gives_the_particle_first_and_the_wall_second(wall):
    s = Settings(range_noise=False, angle_jitter=False, detection=False,
                 particle_rate_per_m=0.2, returns="dual")
    pts = _drive(wall, s)
    two = pts["number_of_returns"] == 2
    first = pts[two & (pts["return_number"] == 1)]
    second = pts[two & (pts["return_number"] == 2)]
    assert len(first) == len(second) > 200
    # pulse by pulse, in order: the particle (flag 2, no face) then the wall
    np.testing.assert_array_equal(first["time"], second["time"])
    np.testing.assert_array_equal(first["channel"], second["channel"])
    assert (first["flag"] == 2).all() and (first["triangle"] == -1).all()
    assert (second["flag"] == 1).all() and (second["triangle"] >= 0).all()
    # the echoes are at least the pulse's separation apart (4 ns x c / 2 = 0.6 m)
    gap = second["range"] - first["range"]
    assert (gap >= 0.599).all()
    # the wall at its analytic range: to 1 mm where the echoes overlap by less than
    # exp(-0.5 (0.8 / 0.255)^2) ~ 0.7 % (gap > 0.8 m); closer pairs, within one
    # separation and a bit, bias the three-point decomposition by up to ~2 cm (known
    # weakness: 3 of ~3900 pulses here)
    err = np.abs(second["range"] - _plane_range(second))
    assert (err[gap > 0.8] < 1e-3).all() and (err < 0.025).all()
    assert (err < 1e-3).mean() > 0.99
    # without dust the same drive has one return per pulse, the wall
    clear = _drive(wall, Settings(range_noise=False, angle_jitter=False,
                                  detection=False, returns="dual"))
    assert (clear["number_of_returns"] == 1).all() and (clear["flag"] == 1).all()
    assert len(pts) > len(clear)


def test_last_mode_reports_the_wall_behind_the_dust(wall):
    s = Settings(range_noise=False, angle_jitter=False, detection=False,
                 particle_rate_per_m=0.2, returns="last")
    pts = _drive(wall, s)
    hit = pts["sx"] > 0
    assert (pts["flag"][hit] != 2).all()          # never the dust in front
    # the wall's range; where a particle lies within a separation of the wall its
    # echo merges with the wall's and pulls the peak towards it (less than half a
    # separation, 0.3 m). That happens at most as often as a dust event falls in the
    # 0.6 m before the wall: 1 - exp(-0.2 x 0.6) = 11 %.
    err = np.abs(pts["range"][hit] - _plane_range(pts[hit]))
    assert (err < 0.3).all() and (err < 1e-3).mean() > 1 - 0.113


@hsettings(max_examples=6, deadline=None)
@given(chunk=st.sampled_from([257, 1000, 4096]), seed=st.integers(0, 2**16))
def test_returns_do_not_depend_on_the_chunking(wall, chunk, seed):
    """The random streams are keyed by pulse index (and return number), not by chunk:
    noise, detection, dust and the later returns' streams 5 and 6 included."""
    s = Settings(particle_rate_per_m=0.3, beam_subrays=7, returns="dual")
    a = _drive(wall, s, chunk_pulses=chunk, seed=seed, t_end=0.01)
    b = _drive(wall, s, chunk_pulses=100_000, seed=seed, t_end=0.01)
    assert a.tobytes() == b.tobytes()
    two = a["number_of_returns"] == 2
    assert (a["return_number"] <= a["number_of_returns"]).all() and two.any()


def test_a_mode_the_sensor_lacks_is_refused(wall):
    with pytest.raises(SimulationError, match=r"--returns in \['strongest', 'last', "
                                              r"'dual'\] for velodyne_vlp16"):
        _drive(wall, Settings(returns="all"))
    with pytest.raises(SimulationError, match="pass --returns"):
        Settings(returns="second")


def _user_spec(tmp_path, table: str | None):
    text = (SPEC_DIR / "velodyne_vlp16.toml").read_text()
    head = text.index("\n[returns]")
    text = text[:head] + ("" if table is None else "\n[returns]\n" + table)
    p = tmp_path / "user.toml"
    p.write_text(text)
    return p


def test_a_spec_without_returns_records_one(tmp_path, wall):
    spec = load_sensor(_user_spec(tmp_path, None))
    assert spec.returns == DEFAULT_RETURNS and spec.returns.modes == ("strongest",)
    with pytest.raises(SimulationError, match=r"--returns in \['strongest'\]"):
        simulate_drive(wall, spec, Trajectory.static([0, 0, 0]), t_end=0.01,
                       settings=Settings(returns="dual"))


@pytest.mark.parametrize("table, match", [
    ('modes = ["strongest"]\nmax_return = 1\n', r"unknown key `max_return`"),
    ('modes = ["strongest", "second"]\n', r"user.toml: Expected \[returns\] modes"),
    ('modes = ["dual"]\nmax_returns = 1\n', r"user.toml: .*max_returns >= 2"),
])
def test_a_bad_returns_table_is_refused(tmp_path, table, match):
    with pytest.raises(SensorSpecError, match=match):
        load_sensor(_user_spec(tmp_path, table))
