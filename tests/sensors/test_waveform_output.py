"""Full-waveform output (issue 34, ``Settings(waveform=True)``): LAS 1.4 wave packets
read back with laspy and with this file's own parsing of the bytes (``struct``), checked
against the analytic two-plane step (echo ranges, return point locations on their
echoes), the wave packet descriptor the model implies, a brute-force sum of Gaussians,
and the same run without waveform; refusals with messages naming the option."""

from __future__ import annotations

import math
import struct
import tempfile
import warnings
from dataclasses import replace
from pathlib import Path

import laspy
import numpy as np
import pytest
from hypothesis import given, settings as hsettings, strategies as st

from raytrace import Scene
from sensors import Settings, Trajectory, load_sensor, simulate_drive, simulate_station
from sensors import waveform as wf
from sensors.errors import SensorSpecError, SimulationError
from sensors.io.errors import PointFileError
from sensors.io.fields import WAVE_SAMPLES, WAVEFORM_POINT_DTYPE
from sensors.writers import open_writer

NEAR_X, FAR_X = 5.0, 6.0
C = 299_792_458.0
RANGE_PER_PS = C / 2 * 1e-12
BIN_M = C * wf.BIN_S / 2
EVLR = struct.Struct("<H16sHQ32s")             # LAS 1.4 R15 EVLR header, 60 bytes
DESCRIPTOR = struct.Struct("<BBIIdd")          # wave packet descriptor payload, 26 bytes


@pytest.fixture(scope="module")
def step():
    """A step edge seen from the origin: plane x = NEAR_X for y < 0, plane x = FAR_X
    behind everything, both 100 m wide."""
    v = np.array([[NEAR_X, -50, -50], [NEAR_X, 0, -50], [NEAR_X, 0, 50], [NEAR_X, -50, 50],
                  [FAR_X, -50, -50], [FAR_X, 50, -50], [FAR_X, 50, 50], [FAR_X, -50, 50]],
                 dtype=np.float64)
    return Scene(v, np.array([[0, 1, 2], [0, 2, 3], [4, 5, 6], [4, 6, 7]]))


def _survey(modes=("strongest", "all")):
    """The Z+F Imager as a full-waveform recorder with "all" returns (a code-built
    spec: the shipped TOMLs cannot say so yet)."""
    s = load_sensor("zf_imager_5016")
    return replace(s, returns=replace(s.returns, waveform=True, modes=modes,
                                      max_returns=2))


def _station(scene, spec, settings, **kw):
    g = spec.physics.beam_divergence_rad
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")        # the station is outside the mesh's box
        return simulate_station(scene, spec, [0.0, 0.0, 0.0], step_rad=g / 2,
                                window_rad=[-3 * g, 3 * g, -g, g], settings=settings,
                                cache_bytes=0, **kw)


IDEAL_FWF = replace(Settings.ideal(), beam_subrays=19, returns="all", waveform=True)


def _parse(path: Path):
    """This file's own reading of a LAS 1.4 file: global encoding, the start of the
    waveform data record and its header, and the wave packet descriptors."""
    blob = path.read_bytes()
    enc = struct.unpack_from("<H", blob, 6)[0]
    head_size, offset, n_vlrs = struct.unpack_from("<HII", blob, 94)
    start_wf, first_evlr, n_evlrs = struct.unpack_from("<QQI", blob, 227)
    desc, pos = {}, head_size
    for _ in range(n_vlrs):
        _, user, rid, length, _ = struct.unpack_from("<H16sHH32s", blob, pos)
        if user.rstrip(b"\0") == b"LASF_Spec" and 100 <= rid <= 354:
            desc[rid - 99] = DESCRIPTOR.unpack_from(blob, pos + 54)
        pos += 54 + length
    return blob, enc, start_wf, first_evlr, n_evlrs, desc


def _fit_peaks(y, peaks):
    """Sub-sample centres (samples) of the echoes of waveform y: a least-squares fit of
    one Gaussian per peak (scipy ``curve_fit``; Wagner et al. 2006's Gaussian
    decomposition, done here independently of ``sensors.waveform``)."""
    from scipy.optimize import curve_fit

    def model(x, *a):
        return sum(a[3 * j] * np.exp(-0.5 * ((x - a[3 * j + 1]) / a[3 * j + 2]) ** 2)
                   for j in range(len(a) // 3))

    x = np.arange(len(y), dtype=np.float64)
    p0 = [v for k in peaks for v in (y[k], float(k), 5.0)]
    a, _ = curve_fit(model, x, y, p0=p0)
    return np.asarray(a[1::3])


def _peaks(y, floor):
    k = np.flatnonzero((y[1:-1] > y[:-2]) & (y[1:-1] >= y[2:]) & (y[1:-1] > floor)) + 1
    return k


def test_two_planes_in_the_las_waveform(tmp_path, step):
    """Pulses straddling the step: each packet (laspy's EVLR bytes and this file's
    struct parsing agree) peaks at both planes' ranges (+-1 bin, placed with the
    point's return point location and x(t), y(t), z(t)); the location is the echo's
    peak in its own samples (+-1 mm) and the point is on its plane (+-1 mm); the
    descriptor is the model's."""
    spec = _survey()
    run = _station(step, spec, IDEAL_FWF)
    path = tmp_path / "fwf.las"
    run.write(path)
    las = laspy.read(path)
    assert las.header.point_format.id == 9
    blob, enc, start_wf, first_evlr, n_evlrs, desc = _parse(path)
    assert enc & 0b110 == 0b010                       # waveform internal, not external
    assert n_evlrs == 1 and first_evlr == start_wf
    _, user, rid, length, _ = EVLR.unpack_from(blob, start_wf)
    assert (user.rstrip(b"\0"), rid) == (b"LASF_Spec", 65535)
    assert start_wf + 60 + length == len(blob)
    gain = wf.waveform_gain(spec.physics)
    assert desc == {1: (16, 0, WAVE_SAMPLES, 250, pytest.approx(gain, rel=1e-12), 0.0)}
    evlr = [v for v in las.header.evlrs if v.record_id == 65535]
    assert len(evlr) == 1 and len(evlr[0].record_data) == length
    two = np.asarray(las.number_of_returns) == 2
    assert two.sum() >= 8
    xyz = np.stack([las.x, las.y, las.z], 1)
    xt = np.stack([las.x_t, las.y_t, las.z_t], 1).astype(np.float64)
    ps = 250.0
    for q in range(len(las.points)):
        off, size = int(las.wavepacket_offset[q]), int(las.wavepacket_size[q])
        assert int(las.wavepacket_index[q]) == 1 and size == 2 * WAVE_SAMPLES
        mine = np.frombuffer(blob, "<u2", WAVE_SAMPLES, start_wf + off)
        theirs = np.frombuffer(bytes(evlr[0].record_data), "<u2", WAVE_SAMPLES, off - 60)
        np.testing.assert_array_equal(mine, theirs)
        y = mine * gain
        loc = float(las.return_point_wave_location[q])
        # Sample k lies at point + (loc - k spacing) x(t) (LASlib, CloudCompare).
        at = xyz[q] + (loc - np.arange(WAVE_SAMPLES)[:, None] * ps) * xt[q]
        peaks = _peaks(y, 20 * gain)
        want = [NEAR_X, FAR_X] if two[q] else [round(float(xyz[q, 0]))]
        assert len(peaks) == len(want)
        np.testing.assert_allclose(at[peaks, 0], want, atol=1.0001 * BIN_M)
        # The point on its plane, and its location at its echo's peak in the samples.
        plane = NEAR_X if abs(xyz[q, 0] - NEAR_X) < 0.5 else FAR_X
        assert abs(xyz[q, 0] - plane) <= 1e-3
        centres = _fit_peaks(y, peaks)
        mine_k = centres[np.argmin(np.abs(at[peaks, 0] - plane))]
        assert abs(mine_k * ps - loc) * RANGE_PER_PS <= 1e-3
        np.testing.assert_allclose(np.linalg.norm(xt[q]), RANGE_PER_PS, rtol=1e-6)
    # Both returns of a pulse share one packet (their echoes fit in one window).
    rn = np.asarray(las.return_number)
    firsts = np.flatnonzero(two & (rn == 1))
    np.testing.assert_array_equal(las.wavepacket_offset[firsts],
                                  las.wavepacket_offset[firsts + 1])


def test_laz_keeps_the_packets_in_a_wdp_beside_it(tmp_path, step):
    """A .laz: point format 4, global encoding "external", NAME.wdp starting with the
    record header; its packets and every point's wave packet fields equal the .las
    of the same run's."""
    run = _station(step, _survey(), IDEAL_FWF)
    run.write(tmp_path / "a.las")
    run.write(tmp_path / "a.laz")
    a, z = laspy.read(tmp_path / "a.las"), laspy.read(tmp_path / "a.laz")
    assert z.header.point_format.id == 4
    assert z.header.global_encoding.waveform_data_packets_external
    assert not z.header.global_encoding.waveform_data_packets_internal
    assert not z.header.evlrs
    wdp = (tmp_path / "a.wdp").read_bytes()
    _, user, rid, length, _ = EVLR.unpack_from(wdp, 0)
    assert (user.rstrip(b"\0"), rid, length) == (b"LASF_Spec", 65535, len(wdp) - 60)
    las_packets = bytes(a.header.evlrs[0].record_data)
    assert wdp[60:] == las_packets
    for f in ("wavepacket_index", "wavepacket_offset", "wavepacket_size",
              "return_point_wave_location", "x_t", "y_t", "z_t", "return_number",
              "number_of_returns", "gps_time", "X", "Y", "Z"):
        np.testing.assert_array_equal(np.asarray(z[f]), np.asarray(a[f]), err_msg=f)


def test_waveform_adds_packets_and_changes_no_point(tmp_path, step):
    """The same run without --waveform: point format 6, no waveform record; the
    points (coordinates, return numbers, echo fields) are the same."""
    spec = _survey()
    plain = replace(IDEAL_FWF, waveform=False)
    _station(step, spec, plain).write(tmp_path / "p.las")
    _station(step, spec, IDEAL_FWF).write(tmp_path / "w.las")
    p, w = laspy.read(tmp_path / "p.las"), laspy.read(tmp_path / "w.las")
    assert (p.header.point_format.id, w.header.point_format.id) == (6, 9)
    assert not p.header.evlrs and w.header.evlrs
    assert (tmp_path / "p.las").read_bytes() != (tmp_path / "w.las").read_bytes()
    for f in ("X", "Y", "Z", "return_number", "number_of_returns", "gps_time",
              "echo_width", "echo_amplitude", "intensity"):
        np.testing.assert_array_equal(np.asarray(p[f]), np.asarray(w[f]), err_msg=f)


def test_default_mode_and_chunking(step):
    """Without --returns a waveform run simulates the device's default mode; its
    records do not depend on the chunking (pulse-keyed random streams)."""
    spec = _survey(modes=("strongest", "all"))
    s = replace(Settings(beam_subrays=7), waveform=True)
    a = np.concatenate(list(_station(step, spec, s)))
    b = np.concatenate(list(_station(step, spec, s, chunk_pulses=5)))
    assert a.dtype == WAVEFORM_POINT_DTYPE
    assert (a["number_of_returns"] == 1).all()       # "strongest", the first mode
    assert a.tobytes() == b.tobytes()


def test_a_drive_points_its_packets_along_each_beam():
    """On a moving, turning platform (a VLP-16 made a waveform recorder), x(t), y(t),
    z(t) point from each point back to the sensor's position at its pulse time (from
    the trajectory), and the anchor (sample 0) lies wave_start_m from the sensor."""
    from sensors import Mount

    # A plane x = 5 as a 10 x 10 grid (200 faces): with 2 faces raytrace's "auto"
    # builds a cube map per pulse origin of a moving platform (minutes, not seconds).
    g = np.linspace(-50, 50, 11)
    yy, zz = np.meshgrid(g, g, indexing="ij")
    v = np.stack([np.full(yy.size, 5.0), yy.ravel(), zz.ravel()], 1)
    k = (np.arange(10)[:, None] * 11 + np.arange(10)[None, :]).ravel()
    faces = np.concatenate([np.stack([k, k + 11, k + 12], 1),
                            np.stack([k, k + 12, k + 1], 1)])
    wall = Scene(v, faces)
    spec = load_sensor("velodyne_vlp16")
    spec = replace(spec, returns=replace(spec.returns, waveform=True))
    traj = Trajectory.along_polyline([[0, -2, 0], [1, 0, 0.2], [0, 2, 0]], 2.0,
                                     rate_hz=50)
    mount = Mount(lever_arm_m=(0.1, 0.0, 0.3))
    run = simulate_drive(wall, spec, traj, mount, t_end=traj.start_s + 0.05,
                         settings=replace(Settings(), waveform=True), cache_bytes=0)
    pts = np.concatenate(list(run))
    assert len(pts) > 500
    pos, _ = traj.sensor_matrices(pts["time"], mount)
    p = np.stack([pts["x"], pts["y"], pts["z"]], 1)
    back = np.stack([pts["wave_dx"], pts["wave_dy"], pts["wave_dz"]], 1).astype(float)
    u = (pos - p) / np.linalg.norm(pos - p, axis=1, keepdims=True)
    np.testing.assert_allclose(back / RANGE_PER_PS, u, atol=1e-6)
    anchor = p + pts["wave_location_ps"][:, None].astype(float) * back
    np.testing.assert_allclose(np.linalg.norm(anchor - pos, axis=1), pts["wave_start_m"],
                               atol=1e-5)


def test_windows_equal_a_brute_force_sum_of_gaussians():
    """``wave_windows``: the samples are the sum of the contributions' Gaussians at the
    bins (to half a count); two echoes 1.5 m apart share a window, a dust echo 20 m
    before the wall gets its own window, each centred on its echo."""
    model = wf.WaveformModel(pulse_fwhm_s=4e-9, threshold_power=1e-6)
    r = np.array([[5.0, 6.5, np.inf], [30.0, 30.0, 10.0]])
    p = np.array([[2e-3, 1e-3, 0.0], [5e-4, 5e-4, 1e-3]])
    gain = 1e-7
    w = wf.wave_windows(r, p, model, return_pulse=[0, 0, 1, 1],
                        echo_range_m=[5.0, 6.5, 10.0, 30.0], gain=gain)
    assert w.shared.tolist() == [True, True, False, False]
    assert w.start_m[0] == w.start_m[1]
    for q, (i, x) in enumerate([(0, 5.75), (0, 5.75), (1, 10.0), (1, 30.0)]):
        grid = w.start_m[q] + np.arange(WAVE_SAMPLES) * model.bin_m
        assert abs(grid[WAVE_SAMPLES // 2] - x) <= model.bin_m
        s = model.sigma_m
        ok = np.isfinite(r[i])
        brute = (p[i, ok][None] * np.exp(-0.5 * ((grid[:, None] - r[i, ok][None]) / s) ** 2)
                 ).sum(1)
        np.testing.assert_allclose(w.samples[q] * gain, np.minimum(brute, 65535 * gain),
                                   atol=gain / 2 * (1 + 1e-9))


# ------------------------------------------------------------------------ refusals
def test_a_sensor_without_waveform_is_refused(step):
    with pytest.raises(SimulationError, match="--waveform"):
        simulate_drive(step, "velodyne_vlp16", Trajectory.static([0, 0, 0]), t_end=0.01,
                       settings=Settings(waveform=True))


@pytest.mark.parametrize("name", ["w.ply", "w.npz", "w.e57", "w.copc.laz", "w.mcap"])
def test_formats_without_wave_packets_are_refused_before_simulating(tmp_path, step, name):
    run = _station(step, _survey(), IDEAL_FWF)
    with pytest.raises(PointFileError, match=r"Expected a \.las or \.laz output for "
                                             r"--waveform"):
        run.write(tmp_path / name)
    assert not run.stats and not list(tmp_path.iterdir())


def test_where_the_packets_go_is_checked(tmp_path, step):
    run = _station(step, _survey(), IDEAL_FWF)
    with pytest.raises(PointFileError, match="--waveform internal"):
        run.write(tmp_path / "w.laz", waveform_data="internal")
    with pytest.raises(PointFileError, match="--waveform internal or external"):
        run.write(tmp_path / "w.las", waveform_data="inside")
    plain = _station(step, _survey(), replace(IDEAL_FWF, waveform=False))
    with pytest.raises(PointFileError, match="only for a full-waveform run"):
        plain.write(tmp_path / "w.las", waveform_data="external")
    # "external" on a .las: the packets beside it, none inside.
    run.write(tmp_path / "x.las", waveform_data="external")
    las = laspy.read(tmp_path / "x.las")
    assert las.header.global_encoding.waveform_data_packets_external
    assert las.header.point_format.id == 9 and not las.header.evlrs
    assert (tmp_path / "x.wdp").stat().st_size == 60 + 2 * WAVE_SAMPLES * len(
        np.unique(np.asarray(las.wavepacket_offset)))


def test_a_bad_waveform_key_is_refused():
    with pytest.raises(SensorSpecError, match=r"\[returns\] waveform = true or false"):
        wf.ReturnsSpec(waveform="yes")
    with pytest.raises(SimulationError, match="waveform"):
        Settings(waveform=1)


# ------------------------------------------------------------------------ property
@hsettings(max_examples=25, deadline=None)
@given(gain=st.floats(1e-9, 10.0), spacing=st.integers(1, 10_000),
       n=st.integers(1, 6), seed=st.integers(0, 2**16), laz=st.booleans())
def test_descriptor_and_packets_round_trip(gain, spacing, n, seed, laz):
    """Any gain and spacing the records carry come back in the descriptor (laspy's
    parsed VLR and struct), and every point's packet holds its record's samples."""
    rng = np.random.default_rng(seed)
    rec = np.zeros(n, dtype=WAVEFORM_POINT_DTYPE)
    rec["x"] = rng.uniform(-10, 10, n)
    rec["time"] = np.sort(rng.uniform(0, 1, n))
    rec["return_number"] = rec["number_of_returns"] = 1
    rec["wave_gain"], rec["wave_spacing_ps"] = gain, spacing
    rec["wave_start_m"] = rng.uniform(0, 100, n)
    rec["wave_location_ps"] = rng.uniform(0, 60_000, n)
    rec["wave_dx"] = -RANGE_PER_PS
    rec["wave"] = rng.integers(0, 65536, (n, WAVE_SAMPLES))
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / ("r.laz" if laz else "r.las")
        with open_writer(path, sensor="zf_imager_5016", waveform=True) as w:
            w.write_points(rec)
        las = laspy.read(path)
        _, _, _, _, _, desc = _parse(path) if not laz else (None,) * 5 + (None,)
        parsed = [v.parsed_record for v in las.header.vlrs
                  if type(v).__name__ == "WaveformPacketVlr"]
        data = (path.with_suffix(".wdp").read_bytes()[60:] if laz else
                bytes(las.header.evlrs[0].record_data))
    assert len(parsed) == 1
    got = (parsed[0].bits_per_sample, parsed[0].waveform_compression_type,
           parsed[0].number_of_samples, parsed[0].temporal_sample_spacing,
           parsed[0].digitizer_gain, parsed[0].digitizer_offset)
    assert got == (16, 0, WAVE_SAMPLES, spacing, gain, 0.0)
    if desc is not None:
        assert desc == {1: got}
    for q in range(n):
        off = int(las.wavepacket_offset[q]) - 60
        np.testing.assert_array_equal(np.frombuffer(data, "<u2", WAVE_SAMPLES, off),
                                      rec["wave"][q])
    np.testing.assert_array_equal(np.asarray(las.return_point_wave_location),
                                  rec["wave_location_ps"])
    assert math.isclose(float(np.asarray(las.x_t)[0]), -RANGE_PER_PS, rel_tol=1e-6)

