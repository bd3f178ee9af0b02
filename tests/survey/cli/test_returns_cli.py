"""`drive`/`scan --returns` (issue 34): multiple returns in the LAS file the user gets.

A short VLP-16 drive through the bfo preset with dust (--particles): dual return has
more points than strongest, every second return lies farther along its beam than the
first of its pulse, and return_number / number_of_returns agree with the points each
pulse actually has, read back with laspy."""

from __future__ import annotations

import numpy as np
import pytest

from survey.cli.main import main

DRIVE = ["--sensor", "velodyne_vlp16", "--along", "centreline", "--speed", "2",
         "--duration", "0.2", "--particles", "0.05", "--seed", "3", "--quiet"]


@pytest.fixture(scope="module")
def bfo(tmp_path_factory):
    out = tmp_path_factory.mktemp("bfo") / "bfo.ply"
    assert main(["tunnel", "-o", str(out), "--preset", "bfo", "--edge-length", "0.25",
                 "--quiet"]) == 0
    return out


@pytest.fixture(scope="module")
def drives(bfo, tmp_path_factory):
    """mode -> LAS data of the same drive (None: the default, no --returns)."""
    import laspy

    d = tmp_path_factory.mktemp("drives")
    out = {}
    for mode in (None, "strongest", "dual"):
        path = d / f"{mode}.laz"
        argv = ["drive", "--mesh", str(bfo), *DRIVE, "-o", str(path)]
        assert main(argv + ([] if mode is None else ["--returns", mode])) == 0
        out[mode] = laspy.read(path)
    return out


def _pulses(las):
    """Group index of each point's pulse (gps_time and channel identify a firing)."""
    key = np.stack([np.asarray(las.gps_time), np.asarray(las["channel"], np.float64)], 1)
    _, group = np.unique(key, axis=0, return_inverse=True)
    return group.ravel()


def test_dual_has_more_points_than_strongest(drives):
    n_s, n_d = len(drives["strongest"].points), len(drives["dual"].points)
    assert n_d > n_s > 10_000
    # Dust in front of the lining is where the second echo comes from: some first
    # returns of two-return pulses are particles (classification 7), their second the
    # lining (classification 0).
    d = drives["dual"]
    two = np.asarray(d.number_of_returns) == 2
    first = two & (np.asarray(d.return_number) == 1)
    second = two & (np.asarray(d.return_number) == 2)
    cls = np.asarray(d.classification)
    assert (cls[first] == 7).sum() > 100 and (cls[second] == 0).mean() > 0.9


def test_return_numbers_agree_with_the_points_of_each_pulse(drives):
    for mode in ("strongest", "dual"):
        las = drives[mode]
        rn = np.asarray(las.return_number).astype(np.int64)
        nr = np.asarray(las.number_of_returns).astype(np.int64)
        g = _pulses(las)
        size = np.bincount(g)[g]                        # points each pulse has
        assert (nr == size).all() and (rn >= 1).all() and (rn <= nr).all()
        # within a pulse the numbers are 1..n, each once
        order = np.lexsort((rn, g))
        gs, rs = g[order], rn[order]
        start = np.r_[True, gs[1:] != gs[:-1]]
        rank = np.arange(len(gs)) - np.maximum.accumulate(np.where(start,
                                                                   np.arange(len(gs)), 0))
        assert (rs == rank + 1).all()
        if mode == "strongest":
            assert (nr == 1).all()


def test_each_second_return_is_farther_than_the_first(drives):
    las = drives["dual"]
    rn = np.asarray(las.return_number)
    g = _pulses(las)
    rng = np.asarray(las["range"])
    first = np.full(g.max() + 1, np.nan)
    first[g[rn == 1]] = rng[rn == 1]
    sec = rn == 2
    assert sec.sum() > 500
    # farther by at least the pulse's separation less the range noise (VLP-16: 4 ns ->
    # 0.6 m; noise a few cm): 0.4 m leaves > 5 sigma of margin
    assert (rng[sec] - first[g[sec]] > 0.4).all()
    # the same ray: the world point of the second return lies on the line from the
    # sensor through the first
    xyz = np.stack([las.x, las.y, las.z], 1)
    s = np.stack([las["sensor_x"], las["sensor_y"], las["sensor_z"]], 1)
    u1 = s / np.linalg.norm(s, axis=1, keepdims=True)
    idx1 = np.full(g.max() + 1, -1)
    idx1[g[rn == 1]] = np.flatnonzero(rn == 1)
    j = idx1[g[sec]]
    assert np.allclose(u1[np.flatnonzero(sec)], u1[j], atol=1e-6)
    assert np.all(np.linalg.norm(xyz[np.flatnonzero(sec)] - xyz[j], axis=1) > 0.4)


def test_echo_fields_only_with_returns(drives):
    dims = set(drives["dual"].point_format.dimension_names)
    assert {"echo_width", "echo_amplitude"} <= dims
    w = np.asarray(drives["dual"]["echo_width"])
    # a surface echo is at least as wide as the emitted pulse: sigma = c 4 ns / 2.355 / 2
    assert w.min() >= 0.25 and np.median(w) < 1.0
    default = drives[None]
    assert not {"echo_width", "echo_amplitude"} & set(default.point_format.dimension_names)
    assert (np.asarray(default.return_number) == 1).all()
    assert (np.asarray(default.number_of_returns) == 1).all()


def test_a_mode_the_sensor_lacks_is_refused(bfo, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert main(["drive", "--mesh", str(bfo), *DRIVE, "--returns", "all", "-o",
                 "x.laz"]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1
    assert "--returns" in err and "'strongest', 'last', 'dual'" in err
    assert not list(tmp_path.glob("x.laz*"))


def test_scan_refuses_a_mode_the_phase_scanner_lacks(bfo, tmp_path, capsys, monkeypatch):
    """Z+F is phase-based: one return per measurement, `strongest` only."""
    monkeypatch.chdir(tmp_path)
    assert main(["scan", "--mesh", str(bfo), "--at", "60,0,1.5", "--sensor",
                 "zf_imager_5016", "--resolution", "preview", "--returns", "dual",
                 "--quiet", "-o", "s.laz"]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1
    assert "--returns in ['strongest'] for zf_imager_5016" in err
    assert not list(tmp_path.glob("s.laz*"))


def test_an_unknown_mode_is_a_usage_error(bfo, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert main(["drive", "--mesh", str(bfo), *DRIVE, "--returns", "second", "-o",
                 "x.laz"]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "--returns" in err
