"""``scan_to_file`` and ``scan_campaign`` (survey.workflows.scan) against
``tunnelsim scan``: the library writes the CLI's files byte for byte; ``--waveform``
changes the file.

References: the files the CLI writes (in-process, ``survey.cli.main.main``) in a second
folder; laspy's reading of the points; the tunnel's axis (the 'tbm' preset runs along x
at y = 0, so a station at chainage c stands at x = c, y = 0); the heading a surveyor's
azimuth means (clockwise from north: the unit vector (sin az, cos az)).
"""

from __future__ import annotations

import json
import math

import laspy
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from survey.cli.main import main
from survey.workflows.scan import scan_campaign, scan_to_file, station_heading_deg

#: A coarse step keeps a station at ~16k pulses (a 1-degree grid of the Z+F's field).
STEP_DEG = 2.0


def _files(folder):
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir()) if p.is_file()}


def _dirs(tmp_path):
    a, b = tmp_path / "cli", tmp_path / "lib"
    a.mkdir()
    b.mkdir()
    return a, b


def test_station_is_the_clis_byte_for_byte(tbm_20k, tmp_path, capsys):
    a, b = _dirs(tmp_path)
    assert main(["scan", "--mesh", str(tbm_20k), "--at", "50,0.3,1.5", "--step-deg",
                 str(STEP_DEG), "--heading-deg", "30", "--seed", "4", "--fields", "full",
                 "-o", str(a / "s.laz")]) == 0
    printed = capsys.readouterr().out
    res = scan_to_file(tbm_20k, b / "s.laz", at=(50, 0.3, 1.5),
                       step_rad=math.radians(STEP_DEG), heading_rad=math.radians(30),
                       seed=4, fields="full")
    assert _files(a) == _files(b) and list(_files(b)) == ["s.laz"]
    las = laspy.read(b / "s.laz")
    assert res.output.points == len(las.points) > 1000
    assert res.station_xyz == (50.0, 0.3, 1.5) and res.resolution == "custom step"
    assert printed.startswith(f"{res.label}: {res.output.pulses:,} pulses, "
                              f"{res.output.points:,} points")


def test_station_on_a_chainage_is_the_clis_and_on_the_axis(tbm_20k, tmp_path):
    a, b = _dirs(tmp_path)
    assert main(["scan", "--mesh", str(tbm_20k), "--chainage", "35", "--height", "1.2",
                 "--azimuth-deg", "120", "--step-deg", str(STEP_DEG), "--ideal",
                 "-o", str(a / "s.las"), "--quiet"]) == 0
    from sensors import Settings

    res = scan_to_file(tbm_20k, b / "s.las", chainage_m=35.0, height_m=1.2,
                       heading_rad=math.radians(station_heading_deg(None, 120.0)),
                       step_rad=math.radians(STEP_DEG), settings=Settings.ideal())
    assert _files(a) == _files(b)
    x, y, _z = res.station_xyz
    assert x == pytest.approx(35.0, abs=1e-6) and y == pytest.approx(0.0, abs=1e-6)


def test_campaign_is_the_clis(tbm_20k, tmp_path):
    """Three stations on the axis: the station files are the CLI's byte for byte; the
    manifests differ only in the output folder's name (cli/ and lib/)."""
    a, b = _dirs(tmp_path)
    assert main(["scan", "--mesh", str(tbm_20k), "--chainages", "20:40:10",
                 "--step-deg", str(STEP_DEG), "--seed", "2", "-o", str(a / "c"),
                 "--quiet"]) == 0
    res = scan_campaign(tbm_20k, b / "c", chainages_m=(20, 40, 10),
                        step_rad=math.radians(STEP_DEG), seed=2)
    cli, lib = _files(a / "c"), _files(b / "c")
    assert sorted(cli) == sorted(lib) and len(cli) == 4 and "manifest.json" in lib
    for name in cli:
        if name != "manifest.json":
            assert cli[name] == lib[name], name
    text_a = cli["manifest.json"].decode().replace(str(a), "<out>")
    text_b = lib["manifest.json"].decode().replace(str(b), "<out>")
    assert text_a == text_b
    man = json.loads(text_b)
    assert man["chainages"] == "20:40:10" and res.stations == 3
    assert res.points == sum(len(laspy.read(b / "c" / f"station_{i:03d}.laz").points)
                             for i in range(3))


def test_waveform_changes_the_file(tbm_20k, tmp_path):
    """scan --waveform writes LAS 1.4 point format 9 with its wave packets; the same
    station without it is another file (format 6)."""
    common = ["scan", "--mesh", str(tbm_20k), "--at", "50,0,1.5", "--step-deg", "4",
              "--quiet"]
    assert main([*common, "-o", str(tmp_path / "plain.las")]) == 0
    assert main([*common, "--waveform", "-o", str(tmp_path / "wave.las")]) == 0
    plain, wave = (tmp_path / "plain.las").read_bytes(), (tmp_path / "wave.las").read_bytes()
    assert plain != wave
    las = laspy.read(tmp_path / "wave.las")
    assert las.header.point_format.id == 9
    assert laspy.read(tmp_path / "plain.las").header.point_format.id != 9
    assert int(np.asarray(las.points["wavepacket_size"]).max()) > 0


@given(st.floats(-720.0, 720.0, allow_nan=False))
def test_azimuth_is_clockwise_from_north(az):
    h = math.radians(station_heading_deg(None, az))
    assert math.cos(h) == pytest.approx(math.sin(math.radians(az)), abs=1e-9)
    assert math.sin(h) == pytest.approx(math.cos(math.radians(az)), abs=1e-9)
