"""Scan patterns: counts from the spec arithmetic, blind zones, unit directions, time
order."""

from __future__ import annotations

import numpy as np
import pytest

from sensors import ProfileScan, SpinningScan, TLSScan, load_sensor
from sensors.patterns import scan_for

ZF = load_sensor("zf_imager_5016")


@pytest.mark.parametrize("name", sorted(ZF.pattern.resolutions_rad))
def test_tls_ray_counts_follow_the_spec(name):
    """Slots per mirror turn n = round(360 / step); slot centres (i + 1/2) 360/n within
    160 deg of the zenith on either side: 2 floor(160 n / 360 + 1/2) per line."""
    n = round(360 / np.rad2deg(ZF.pattern.resolutions_rad[name]))
    scan = TLSScan(ZF, name)
    assert scan.n_slots == n
    assert scan.points_per_line == 2 * int(np.floor(160 * n / 360 + 0.5))
    assert scan.n_lines == round(180 * n / 360)


def test_superhigh_station_is_225_million_rays():
    scan = TLSScan(ZF, "superhigh")
    assert scan.n_pulses == 20_000 * 11_250 == 225_000_000
    # one mirror revolution per line, slots of the blind cone included
    assert scan.duration_s == pytest.approx(11_250 * 22_500 / 1_016_000)


def test_tls_stream_blind_cone_units_and_times():
    scan = TLSScan(ZF, "preview")
    chunks = list(scan.chunks(chunk_pulses=50_000))
    t = np.concatenate([c.time for c in chunks])
    d = np.concatenate([c.direction for c in chunks])
    assert len(t) == scan.n_pulses
    assert np.all(np.diff(t) > 0)                                  # strictly increasing
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0, atol=1e-12)
    nadir = np.degrees(np.arccos(np.clip(-d[:, 2], -1, 1)))
    assert nadir.min() >= 20.0 - 1e-9                              # 40 deg blind cone empty
    assert nadir.min() < 20.0 + np.rad2deg(scan.step_rad)          # and no wider
    row = np.concatenate([c.channel for c in chunks])
    assert row.min() == 0 and row.max() == scan.points_per_line - 1


@pytest.mark.parametrize("name, per_rev", [("robosense_airy", 1 / (10 * 111.08e-6)),
                                           ("velodyne_vlp16", 1 / (10 * 55.296e-6)),
                                           ("ouster_os1_64", 1024.0)])
def test_spinning_counts_per_revolution(name, per_rev):
    spec = load_sensor(name)
    scan = SpinningScan(spec, 0.35)
    chunks = list(scan.chunks(chunk_pulses=20_000))
    frame = np.concatenate([c.frame for c in chunks])
    t = np.concatenate([c.time for c in chunks])
    d = np.concatenate([c.direction for c in chunks])
    ch = np.concatenate([c.channel for c in chunks])
    counts = np.bincount(frame)[:3]                                 # full revolutions
    assert set(counts // spec.channels) <= {int(np.floor(per_rev)), int(np.ceil(per_rev))}
    assert np.all(np.diff(t) >= 0)              # groups of lasers fire together
    for c in range(spec.channels):             # each laser strictly in time
        assert np.all(np.diff(t[ch == c]) > 0)
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0, atol=1e-12)
    np.testing.assert_allclose(np.arcsin(d[:, 2]), spec.pattern.elevations_rad[ch], atol=1e-12)
    # azimuth advances at the rotation rate
    az = np.unwrap(np.arctan2(d[ch == 0, 1], d[ch == 0, 0]))
    rate = np.polyfit(t[ch == 0], az, 1)[0]
    assert abs(rate) == pytest.approx(2 * np.pi * 10.0, rel=1e-9)
    assert np.sign(rate) == (-1 if spec.pattern.clockwise else 1)


def test_airy_groups_fire_every_8_83_us_within_a_block():
    scan = SpinningScan(load_sensor("robosense_airy"), 0.001)
    c = next(iter(scan.chunks()))
    first = c.time[:96]
    groups = np.unique(first)
    assert len(groups) == 12
    np.testing.assert_allclose(np.diff(groups), 97.104e-6 / 11, rtol=1e-9)


def test_profiler_plane_blind_sector_and_times():
    spec = load_sensor("zf_profiler_9012")
    scan = ProfileScan(spec, 0.05)
    chunks = list(scan.chunks(chunk_pulses=3000))
    t = np.concatenate([c.time for c in chunks])
    d = np.concatenate([c.direction for c in chunks])
    assert scan.n_profiles == 10 and len(t) == scan.n_pulses
    assert np.all(np.diff(t) > 0) and np.all(d[:, 0] == 0)
    ang = np.degrees(np.mod(np.arctan2(d[:, 1], d[:, 2]), 2 * np.pi))
    assert not np.any((ang >= 165) & (ang <= 195))
    assert scan.points_per_profile == 5000 - int(np.sum(
        (np.degrees(2 * np.pi * (np.arange(5000) + 0.5) / 5000) >= 165) &
        (np.degrees(2 * np.pi * (np.arange(5000) + 0.5) / 5000) <= 195)))


@pytest.mark.parametrize("name, kw", [("zf_imager_5016", dict(resolution="preview")),
                                      ("robosense_airy", dict(duration_s=0.4))])
def test_chunks_on_the_thread_pool_equal_small_chunks(name, kw):
    """Large chunks are generated on a thread pool in parts, small ones in one thread:
    the pulses must be the same bits however the pattern is cut."""
    scan = scan_for(load_sensor(name), **kw)
    fields = ("time", "direction", "channel", "column", "frame")
    big = [np.concatenate([getattr(p, f) for p in scan.chunks(1 << 20)]) for f in fields]
    small = [np.concatenate([getattr(p, f) for p in scan.chunks(5_000)]) for f in fields]
    assert len(big[0]) > 300_000
    for b, s in zip(big, small):
        assert b.dtype == s.dtype and b.tobytes() == s.tobytes()
