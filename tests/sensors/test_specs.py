"""Sensor specs: every shipped file loads, names are unique, sources and assumptions
are stated, and bad files fail with the field named."""

from __future__ import annotations

import numpy as np
import pytest

from sensors import SensorSpecError, list_sensors, load_sensor
from sensors.spec import SPEC_DIR

REQUIRED = {"zf_imager_5016", "robosense_airy", "zf_profiler_9012", "velodyne_vlp16",
            "ouster_os1_64"}


def test_every_file_loads_with_a_unique_name_and_sources():
    names = list_sensors()
    assert REQUIRED <= set(names)
    files = sorted(SPEC_DIR.glob("*.toml"))
    assert len(files) == len(names)                 # one device per file, no duplicates
    for f in files:
        spec = load_sensor(f)
        assert spec.name == f.stem and spec.sources
        assert "assumed" in f.read_text()             # assumptions are marked
        assert spec.physics.range_max_m > spec.physics.range_min_m


def test_seed_superhigh_step_and_airy_timing_are_the_documented_values():
    zf = load_sensor("zf_imager_5016")
    assert np.rad2deg(zf.pattern.resolutions_rad["superhigh"]) == pytest.approx(0.016)
    airy = load_sensor("robosense_airy")
    off = np.unique(airy.pattern.firing_offsets_s)
    assert len(off) == 12 and off[-1] == pytest.approx(97.104e-6, abs=1e-12)
    assert airy.pattern.column_period_s == pytest.approx(111.08e-6)
    vlp = load_sensor("velodyne_vlp16")
    assert sorted(np.rad2deg(vlp.pattern.elevations_rad).round(6)) == list(range(-15, 16, 2))


def _write(tmp_path, text):
    p = tmp_path / "mine.toml"
    p.write_text(text)
    return p


def test_user_file_and_missing_field(tmp_path):
    text = (SPEC_DIR / "velodyne_vlp16.toml").read_text().replace('name = "velodyne_vlp16"',
                                                                   'name = "my_lidar"')
    assert load_sensor(_write(tmp_path, text)).name == "my_lidar"
    bad = text.replace("max_m = 100.0", "")
    with pytest.raises(SensorSpecError, match=r"range\.max_m"):
        load_sensor(_write(tmp_path, bad))
    bad = text.replace("rotation_hz = 10.0", 'rotation_hz = "fast"')
    with pytest.raises(SensorSpecError, match=r"spinning\.rotation_hz.*finite number"):
        load_sensor(_write(tmp_path, bad))
    with pytest.raises(SensorSpecError, match="valid TOML"):
        load_sensor(_write(tmp_path, "[device\nname="))


def test_unknown_name_lists_the_valid_ones():
    with pytest.raises(SensorSpecError, match="zf_imager_5016") as exc:
        load_sensor("leica_rtc360")
    assert "robosense_airy" in str(exc.value)


def test_package_docstring_example_runs():
    import doctest

    import sensors
    result = doctest.testmod(sensors)
    assert result.attempted >= 3 and result.failed == 0
