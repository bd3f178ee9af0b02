"""The one TOML loader of sensors and platforms (``sensors.specfile``): both kinds of file
refuse the same mistakes with messages of one shape, and a catalogue refuses two
files of one name."""

from __future__ import annotations

import pytest

from sensors.errors import PlatformError, SensorSpecError
from sensors.platform_spec import PLATFORM_DIR, load_platform
from sensors.spec import SPEC_DIR, load_sensor
from sensors.specfile import Catalogue, SpecTable


@pytest.mark.parametrize("load, folder, name, error, old, new, match", [
    (load_sensor, SPEC_DIR, "velodyne_vlp16.toml", SensorSpecError, "rotation_hz",
     "rotaton_hz", r"unknown key `rotaton_hz` \(did you mean `rotation_hz`\?\)"),
    (load_platform, PLATFORM_DIR, "ground_robot.toml", PlatformError, "wheelbase_m",
     "wheelbase", r"unknown key `wheelbase` \(did you mean `wheelbase_m`\?\)"),
    # A key under the wrong header is found in the table it belongs to, for both kinds.
    (load_sensor, SPEC_DIR, "velodyne_vlp16.toml", SensorSpecError, "[range]",
     "[range]\nrange_sigma_m = 0.01", r"`range_sigma_m` \(did you mean `range_sigma_m` in "
     r"\[noise\]\?\)"),
    (load_platform, PLATFORM_DIR, "ground_robot.toml", PlatformError, "[body]",
     "[body]\nmax_speed_mps = 1.0", r"`max_speed_mps` \(did you mean `max_speed_mps` in "
     r"\[limits\]\?\)"),
])
def test_both_kinds_refuse_unknown_keys_alike(load, folder, name, error, old, new, match,
                                               tmp_path):
    text = (folder / name).read_text()
    assert old in text
    path = tmp_path / name
    path.write_text(text.replace(old, new, 1))
    with pytest.raises(error, match=match) as info:
        load(path)
    assert name in str(info.value) and "valid keys there" in str(info.value)


def test_catalogue_refuses_two_files_of_one_name(tmp_path):
    for f in ("a.toml", "b.toml"):
        (tmp_path / f).write_text("")

    class Named:
        name = "same"

    cat = Catalogue(tmp_path, lambda p: Named(), SensorSpecError, "sensor")
    with pytest.raises(SensorSpecError, match="unique sensor names, got 'same' in both "
                                               "a.toml and b.toml"):
        cat.names()


@pytest.mark.parametrize("value, kw, match", [
    (float("nan"), {}, "a finite number"), (-1.0, {"positive": True}, "positive"),
    (2.0, {"lo": 0.0, "hi": 1.0}, r"within \[0.0, 1.0\]"), (True, {}, "a finite number"),
])
def test_numbers_are_checked(value, kw, match):
    t = SpecTable({"k": value}, "f.toml", "t", PlatformError, "platform")
    with pytest.raises(PlatformError, match=f"`t.k` in f.toml to be {match}.*fix the "
                                            "platform file"):
        t.num("k", **kw)


def test_required_keys_are_named():
    with pytest.raises(PlatformError, match=r"a key `b` in \[t\] of f.toml"):
        SpecTable({"a": 1}, "f.toml", "t", PlatformError, "platform", valid=("a", "b"),
                  required=True)
