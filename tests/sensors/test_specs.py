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


# ---------------------------------------------------------------- strict keys
# (file, table, a misspelt key in it, the key it should have been)
MISSPELT = [
    ("velodyne_vlp16", "", "rotaton_hz", "rotation_hz"),          # above every table
    ("velodyne_vlp16", "device", "vendr", "vendor"),
    ("velodyne_vlp16", "range", "max_meters", "max_m"),
    ("velodyne_vlp16", "detection", "softnes", "softness"),
    ("velodyne_vlp16", "noise", "range_sigma_floor", "range_sigma_floor_m"),
    ("velodyne_vlp16", "beam", "divergence_half_rad", "divergence_half_mrad"),
    ("velodyne_vlp16", "spinning", "rotaton_hz", "rotation_hz"),
    ("zf_imager_5016", "tls", "head_sweep", "head_sweep_deg"),
    ("zf_profiler_9012", "profiler", "profile_rate", "profile_rate_hz"),
    ("velodyne_vlp16", "driver", "ring_ordr", "ring_order"),
]


def _with_key(text, table, line):
    """``line`` added to ``table`` ("" = the top level, before the first table)."""
    if not table:
        return f"{line}\n{text}"
    head = f"[{table}]\n"
    assert head in text
    return text.replace(head, f"{head}{line}\n", 1)


@pytest.mark.parametrize("name, table, key, meant", MISSPELT)
def test_a_misspelt_key_is_refused_with_the_valid_ones(tmp_path, name, table, key, meant):
    """pbrt's ReportUnused / HELIOS++'s XSD: an unknown key is an error, one line,
    naming the key, the file, the table's valid keys and the likely intended one."""
    from sensors.spec import TABLE_KEYS

    text = (SPEC_DIR / f"{name}.toml").read_text()
    p = tmp_path / "typo.toml"
    p.write_text(_with_key(text, table, f"{key} = 20"))
    with pytest.raises(SensorSpecError, match=rf"unknown key `{key}`") as exc:
        load_sensor(p)
    msg = str(exc.value)
    assert "\n" not in msg and "typo.toml" in msg
    assert f"did you mean `{meant}`" in msg
    assert all(k in msg for k in TABLE_KEYS[table])
    assert (f"table [{table}]" if table else "the top level") in msg


def test_a_misspelt_key_that_replaces_a_real_one_names_the_typo(tmp_path):
    # The typo, not the then-missing `rotation_hz`, is what the user must see.
    text = (SPEC_DIR / "velodyne_vlp16.toml").read_text()
    p = _write(tmp_path, text.replace("rotation_hz = 10.0", "rotaton_hz = 20"))
    with pytest.raises(SensorSpecError, match="`rotaton_hz`.*did you mean `rotation_hz`"):
        load_sensor(p)


def test_free_form_presets_and_conflicting_alternatives(tmp_path):
    zf = (SPEC_DIR / "zf_imager_5016.toml").read_text()
    mine = load_sensor(_write(tmp_path, zf.replace("superhigh = 0.016",
                                                   "superhigh = 0.016\nmine = 0.5")))
    assert mine.pattern.resolutions_rad["mine"] == pytest.approx(np.deg2rad(0.5))
    vlp = (SPEC_DIR / "velodyne_vlp16.toml").read_text()
    both = vlp.replace("azimuth_offset_deg = 0.0", "azimuth_offset_deg = 0.0\nchannels = 16")
    with pytest.raises(SensorSpecError, match="either `spinning.elevations_deg` or"):
        load_sensor(_write(tmp_path, both))
    other = vlp + "\n[profiler]\nprofile_rate_hz = 10.0\n"
    with pytest.raises(SensorSpecError, match=r"only the \[spinning\] pattern table.*"
                                              r"\[profiler\]"):
        load_sensor(_write(tmp_path, other))
    bad = vlp.replace("firing_group_size = 1", "firing_group_size = 1.5")
    with pytest.raises(SensorSpecError, match="firing_group_size.*whole number"):
        load_sensor(_write(tmp_path, bad))


def test_spec_reprs_are_one_short_line():
    for name in list_sensors():
        spec = load_sensor(name)
        for text in (repr(spec), repr(spec.pattern), repr(spec.physics)):
            assert "\n" not in text and len(text) < 160 and "array" not in text
    assert repr(load_sensor("velodyne_vlp16")) == (
        "SensorSpec(velodyne_vlp16: Velodyne VLP-16, spinning, 16 channels at 10 Hz, "
        "0.5-100 m)")
    assert load_sensor("robosense_airy") == load_sensor("robosense_airy")   # arrays inside


def test_module_docstring_examples_run():
    import doctest

    import sensors.spec
    import sensors.trajectory
    for mod in (sensors.spec, sensors.trajectory):
        result = doctest.testmod(mod)
        assert result.attempted >= 2 and result.failed == 0, mod.__name__


def test_the_waveform_recorders_are_the_survey_scanners():
    """[returns] waveform = true (ASSUMED in both files) on exactly the two Z+F
    instruments; every other sensor refuses --waveform."""
    from sensors.spec import list_sensors, load_sensor

    assert {n for n in list_sensors() if load_sensor(n).returns.waveform} == \
        {"zf_imager_5016", "zf_profiler_9012"}
