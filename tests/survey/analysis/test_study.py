"""MLS study: density ~ 1/v at a constant pulse rate, line spacing and rolling-shutter
distortion = v x time within the sweep, outputs and errors."""

from __future__ import annotations

import numpy as np
import pytest

from raytrace import Scene
from sensors import Settings, load_sensor
from survey.world.alignment import Alignment, straight
from survey.cli.main import main
from survey.world.profiles import horseshoe
from survey.analysis.study import Study
from survey.errors import StudyError
from survey.world.generator import make_tunnel


@pytest.fixture(scope="module")
def tunnel():
    return make_tunnel(Alignment([straight(24.0)]), horseshoe(5.0), edge_length_m=0.25,
                       roughness_rms_m=0.0)


@pytest.fixture(scope="module")
def study(tunnel):
    return Study(Scene(tunnel.vertices, tunnel.faces), tunnel.alignment,
                 float(tunnel.profile.centroid[1]), load_sensor("velodyne_vlp16"),
                 strip_m=(11.0, 13.0), lead_m=3.0, settings=Settings.ideal(), keep_points=5000)


@pytest.fixture(scope="module")
def rows(study):
    return {v: study.run(v, 10.0, "level") for v in (0.0, 1.0, 2.0)}


def test_density_scales_as_one_over_speed(rows):
    # Same sensor positions, pulses per metre of path ~ 1/v: the count differs only by the
    # rotation phase at which each position is passed (a few per cent at most).
    r1, r2 = rows[1.0], rows[2.0]
    assert r1.density_lining / r2.density_lining == pytest.approx(2.0, rel=0.03)
    assert r1.density_floor / r2.density_floor == pytest.approx(2.0, rel=0.03)
    assert r1.points / r2.points == pytest.approx(2.0, rel=0.03)


def test_distortion_and_line_spacing_are_v_times_sweep_time(rows, study):
    for v in (1.0, 2.0):
        r = rows[v]
        # Straight level motion: displacement = v (t - t_sweep start); a sweep's columns
        # start within [0, 1/f) and a channel fires up to max(firing offset) later.
        late = study.sensor.pattern.firing_offsets_s.max()
        assert r.distortion_max_m == pytest.approx(v / 10.0, rel=0.01)
        assert r.distortion_max_m <= v * (1 / 10.0 + late) + 1e-9
        # Uniform firing in time: the RMS of v t for t uniform on [0, 1/f] is v/(f sqrt 3).
        assert r.distortion_rms_m == pytest.approx(v / 10.0 / np.sqrt(3), rel=0.05)
        assert r.line_spacing_m == pytest.approx(v / 10.0, rel=0.05)
    assert rows[0.0].distortion_max_m < 1e-9


def test_faster_rotation_thins_each_sweep_but_not_the_pass(study, rows):
    r20 = study.run(1.0, 20.0, "level")
    assert r20.density_lining == pytest.approx(rows[1.0].density_lining, rel=0.03)
    assert r20.line_spacing_m == pytest.approx(0.05, rel=0.05)
    assert r20.distortion_max_m == pytest.approx(0.05, rel=0.01)


def test_bad_inputs(tunnel, study):
    scene = study.scene
    with pytest.raises(StudyError, match="moving sensor"):
        Study(scene, tunnel.alignment, 0.0, load_sensor("zf_imager_5016"))
    with pytest.raises(StudyError, match="inside the tunnel"):
        Study(scene, tunnel.alignment, 0.0, load_sensor("velodyne_vlp16"), strip_m=(1, 3))
    with pytest.raises(StudyError, match="speed"):
        study.run(-1.0, 10.0)
    with pytest.raises(StudyError, match="mount"):
        study.run(1.0, 10.0, "sideways")


def test_cli_study_outputs(tmp_path, tunnel, capsys):
    tunnel.write(tmp_path / "t.ply")
    out = tmp_path / "st"
    assert main(["study", "--mesh", str(tmp_path / "t.ply"), "--sensor", "velodyne_vlp16",
                 "--speeds", "0,2", "--rates", "10", "--mounts", "down", "--strip",
                 "11,13", "--lead", "3", "--ideal", "-o", str(out), "--quiet"]) == 0
    rows = (out / "study.csv").read_text().splitlines()
    assert len(rows) == 3 and rows[0].startswith("speed_mps,rate_hz,mount")
    png = (out / "study.png").read_bytes()
    assert png[:4] == b"\x89PNG" and len(png) > 20_000
    assert "| 2.00 | 10 | down |" in (out / "study.md").read_text()
    assert main(["study", "--mesh", str(tmp_path / "t.ply"), "--speeds", "1,x",
                 "-o", str(tmp_path / "s2")]) == 2
    assert "--speeds" in capsys.readouterr().err


def test_with_rate_changes_the_turn_not_the_firing():
    from sensors.errors import SensorSpecError
    from sensors.spec import with_rate

    s = load_sensor("velodyne_vlp16")
    f = with_rate(s, 20.0)
    assert f.pattern.rotation_hz == 20.0
    assert f.pattern.column_period_s == s.pattern.column_period_s
    p = with_rate(load_sensor("zf_profiler_9012"), 50.0)
    assert p.pattern.profile_rate_hz == 50.0
    with pytest.raises(SensorSpecError, match="positive rate"):
        with_rate(s, 0.0)
    with pytest.raises(SensorSpecError, match="spinning lidar or a profiler"):
        with_rate(load_sensor("zf_imager_5016"), 10.0)


def test_study_prints_one_line(study):
    assert repr(study) == (f"Study(velodyne_vlp16, strip 11-13 m, lead 3 m, "
                           f"{len(study.cells.area):,} cells)")
    assert study.strip_m == (11.0, 13.0) and study.lead_m == 3.0
