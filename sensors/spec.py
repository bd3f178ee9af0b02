"""Sensor models as data: one TOML file per device, loaded into frozen dataclasses
(``sensors.spec_types``, re-exported here).

Device facts (``SensorSpec``) are kept apart from user settings (the resolution chosen
for a station, the physics switches, the mounting) and from runtime state (poses,
random streams), in the manner of HELIOS++'s device/setting/state split. TOML carries
degrees, microseconds, milliradians and arcseconds, the units of datasheets; the
dataclasses hold SI units and radians.

Every file is validated on load: a missing or malformed field names the file, the
table and the field, and a key the loader does not know (``rotaton_hz = 20``) is an
error naming the key and the valid ones, as pbrt's ``ParameterDictionary::ReportUnused``
and HELIOS++'s XSD check do: a misspelt key must not become a silent default.
``list_sensors()`` scans ``sensors/specs/``; ``load_sensor`` takes a registered name or
the path of a user's own TOML file.

>>> spec = load_sensor("velodyne_vlp16")
>>> spec
SensorSpec(velodyne_vlp16: Velodyne VLP-16, spinning, 16 channels at 10 Hz, 0.5-100 m)
"""

from __future__ import annotations

import os
import re
from collections.abc import Mapping
from dataclasses import replace
from pathlib import Path
from typing import Any, Final

import numpy as np

from .errors import SensorSpecError
from .specfile import Catalogue, SpecTable, read_toml
# The data types live in ``sensors.spec_types``; they are re-exported here, where
# users have always imported them from.
from .spec_types import (KINDS, NO_RETURN, POINT_LAYOUTS, RING_ORDERS,
                         SATURATION_RANGE_FLOOR_M,
                         Driver, Pattern, Physics, ProfilerPattern, SensorSpec,
                         SpinningPattern, TLSPattern)
from .waveform import DEFAULT_RETURNS, ReturnsSpec

__all__ = ["SPEC_DIR", "TABLE_KEYS", "list_sensors", "load_sensor", "with_rate"]

SPEC_DIR: Final = Path(__file__).resolve().parent / "specs"

#: Keys each table of a sensor file may hold; anything else is refused on load.
#: ``tls.resolutions_deg`` is free-form (preset name -> step) and not listed.
TABLE_KEYS: Final[Mapping[str, tuple[str, ...]]] = {
    "": ("device", "range", "detection", "noise", "beam", "driver", "returns", *KINDS),
    "device": ("name", "vendor", "model", "kind", "wavelength_nm", "sources"),
    "range": ("min_m", "max_m"),
    "detection": ("range_m", "reflectivity", "softness"),
    "noise": ("range_sigma_m", "reference_range_m", "reference_reflectivity",
              "range_sigma_floor_m", "angle_sigma_arcsec"),
    "beam": ("divergence_half_mrad", "exit_diameter_mm"),
    "tls": ("vertical_fov_deg", "head_sweep_deg", "measurement_rate_hz",
            "default_resolution", "resolutions_deg"),
    "spinning": ("rotation_hz", "column_period_us", "elevations_deg",
                 "elevation_uniform_deg", "channels", "azimuth_offset_deg",
                 "firing_offsets_us", "firing_group_size", "firing_group_step_us",
                 "clockwise"),
    "profiler": ("profile_rate_hz", "points_per_profile", "blind_sector_deg"),
    "driver": ("package", "point_layout", "frame_id", "topic", "ring_order",
               "intensity_max", "beam_origin_offset_mm", "organized", "no_return",
               "signal_photons_at_threshold", "dual_topic_suffix"),
    # Optional (sensors.waveform.ReturnsSpec): what the device records per pulse.
    "returns": ("modes", "dual", "max_returns", "pulse_fwhm_ns", "pulse_source", "waveform"),
}


def _table(data: dict[str, Any], file: str) -> SpecTable:
    """The top level of a sensor file, its tables checked against ``TABLE_KEYS``."""
    return SpecTable(data, file, "", SensorSpecError, "sensor", schema=TABLE_KEYS)


def with_rate(spec: SensorSpec, rate_hz: float) -> SensorSpec:
    """The spec with another rotation (spinning) or profile (profiler) rate; the firing
    rate stays, so points per turn or per profile change as on the device.

    Raises
    ------
    SensorSpecError
        For a TLS spec or a rate that is not a positive number.
    """
    ok = isinstance(rate_hz, (int, float, np.floating, np.integer)) and \
        not isinstance(rate_hz, bool) and bool(np.isfinite(rate_hz)) and rate_hz > 0
    p = spec.pattern
    if not ok or isinstance(p, TLSPattern):
        raise SensorSpecError(f"Expected a positive rate for a spinning lidar or a "
                              f"profiler, got {rate_hz!r} Hz for {spec.name} ({spec.kind}).")
    if isinstance(p, SpinningPattern):
        return replace(spec, pattern=replace(p, rotation_hz=float(rate_hz)))
    return replace(spec, pattern=replace(p, profile_rate_hz=float(rate_hz)))


# ---------------------------------------------------------------------- loading
def _physics(root: SpecTable) -> Physics:
    rng, det, noi, beam = (root.sub(k) for k in ("range", "detection", "noise", "beam"))
    rmin = rng.num("min_m", lo=0.0)
    rmax = rng.num("max_m", positive=True)
    if rmax <= rmin:
        raise SensorSpecError(f"Expected `range.max_m` > `range.min_m` in {root.file}, got "
                              f"{rmax} <= {rmin}; fix the sensor file.")
    return Physics(
        range_min_m=rmin, range_max_m=rmax,
        detection_range_m=det.num("range_m", positive=True),
        detection_reflectivity=det.num("reflectivity", lo=1e-6, hi=1.0),
        detection_softness=det.num("softness", positive=True),
        range_sigma_m=noi.num("range_sigma_m", lo=0.0),
        reference_range_m=noi.num("reference_range_m", positive=True),
        reference_reflectivity=noi.num("reference_reflectivity", lo=1e-6, hi=1.0),
        range_sigma_floor_m=noi.num("range_sigma_floor_m", lo=0.0),
        angle_sigma_rad=float(np.deg2rad(noi.num("angle_sigma_arcsec", lo=0.0) / 3600.0)),
        beam_divergence_rad=beam.num("divergence_half_mrad", lo=0.0) * 1e-3,
        exit_diameter_m=beam.num("exit_diameter_mm", lo=0.0) * 1e-3,
    )


def _tls(p: SpecTable) -> TLSPattern:
    res = p.sub("resolutions_deg")
    resolutions = {k: float(np.deg2rad(res.num(k, positive=True))) for k in res.data}
    if not resolutions:
        raise p.err("resolutions_deg", "a table of at least one preset", res.data)
    default = p.text("default_resolution")
    if default not in resolutions:
        raise SensorSpecError(f"Expected `tls.default_resolution` in {p.file} to be one "
                              f"of {sorted(resolutions)}, got {default!r}.")
    return TLSPattern(float(np.deg2rad(p.num("vertical_fov_deg", lo=1.0, hi=360.0))),
                      float(np.deg2rad(p.num("head_sweep_deg", lo=1.0, hi=360.0))),
                      p.num("measurement_rate_hz", positive=True), resolutions, default)


def _spinning(p: SpecTable) -> SpinningPattern:
    if p.either("elevations_deg", ("elevation_uniform_deg", "channels")):
        el = p.nums("elevations_deg")
    else:
        lo, hi = p.nums("elevation_uniform_deg", 2)
        el = np.linspace(lo, hi, p.whole("channels", 1))
    n = len(el)
    az_raw = p.raw("azimuth_offset_deg")
    az = p.nums("azimuth_offset_deg", n) if isinstance(az_raw, list) else \
        np.full(n, p.num("azimuth_offset_deg"))
    if p.either("firing_offsets_us", ("firing_group_size", "firing_group_step_us")):
        off = p.nums("firing_offsets_us", n) * 1e-6
    else:
        size = p.whole("firing_group_size", 1)
        off = ((np.arange(n) // size) * p.num("firing_group_step_us", lo=0.0) * 1e-6
               ).astype(np.float64)
    col = p.num("column_period_us", positive=True) * 1e-6
    if off.min() < 0 or off.max() >= col:
        raise SensorSpecError(f"Expected firing offsets within one column period "
                              f"[0, {col * 1e6:g}) us in {p.file}, got "
                              f"{off.min() * 1e6:g} to {off.max() * 1e6:g} us.")
    return SpinningPattern(p.num("rotation_hz", positive=True), col, np.deg2rad(el),
                           np.deg2rad(az), off, p.flag("clockwise"))


def _profiler(p: SpecTable) -> ProfilerPattern:
    b0, b1 = (float(b) for b in np.deg2rad(p.nums("blind_sector_deg", 2)))
    return ProfilerPattern(p.num("profile_rate_hz", positive=True),
                           p.whole("points_per_profile", 8), (b0, b1))


_ROS_NAME = re.compile(r"^/?[A-Za-z_][A-Za-z0-9_]*(/[A-Za-z_][A-Za-z0-9_]*)*$")


def _driver(root: SpecTable) -> Driver | None:
    if "driver" not in root.data:
        return None
    d = root.sub("driver")
    layout, order = d.text("point_layout"), d.text("ring_order")
    for key, got, valid in (("point_layout", layout, POINT_LAYOUTS),
                            ("ring_order", order, RING_ORDERS)):
        if got not in valid:
            raise d.err(key, f"one of {valid}", got)
    frame, topic = d.text("frame_id"), d.text("topic")
    # ROS 2 names (design.ros2.org "Topic and Service names"); tf2 frame ids take no
    # leading slash (tf2 dropped tf's "/" prefix).
    if not _ROS_NAME.match(frame) or frame.startswith("/"):
        raise d.err("frame_id", "a tf2 frame name (letters, digits, _ and /, no "
                    "leading /)", frame)
    if not _ROS_NAME.match(topic):
        raise d.err("topic", "a ROS 2 topic name", topic)
    # The driver-layout keys are optional: a user's file written before them keeps
    # its meaning (returns only, velodyne-like intensity).
    organized = d.flag("organized") if "organized" in d.data else False
    no_return = d.text("no_return") if "no_return" in d.data else "zero"
    if no_return not in NO_RETURN:
        raise d.err("no_return", f"one of {NO_RETURN}", no_return)
    signal = d.num("signal_photons_at_threshold", positive=True) \
        if "signal_photons_at_threshold" in d.data else 0.0
    if layout == "ouster" and signal == 0.0:
        raise SensorSpecError(f"Expected a field `driver.signal_photons_at_threshold` in "
                              f"{d.file} for the ouster layout (its intensity is signal "
                              "photons), got none; add it to the sensor file.")
    # Optional: "" (both returns of a dual drive in the one cloud) where not given.
    suffix = d.text("dual_topic_suffix") if "dual_topic_suffix" in d.data else ""
    if suffix and not _ROS_NAME.match(topic + suffix):
        raise d.err("dual_topic_suffix", "a suffix that keeps the topic a ROS 2 topic "
                    "name (letters, digits, _)", suffix)
    return Driver(d.text("package"), layout, frame, topic, order,
                  d.num("intensity_max", positive=True),
                  d.num("beam_origin_offset_mm", lo=0.0) * 1e-3, organized, no_return,
                  signal, suffix)


def _returns(root: SpecTable, file: str) -> ReturnsSpec:
    """The ``[returns]`` table (keys checked by ``SpecTable``), errors naming the file."""
    table = root.sub("returns")
    try:
        return ReturnsSpec.from_table(table.data, file)
    except SensorSpecError as exc:
        msg = str(exc)
        raise SensorSpecError(msg if file in msg else
                              f"{file}: {msg.rstrip('.')}; fix the sensor file.") from None


def _load(path: Path) -> SensorSpec:
    data = read_toml(path, SensorSpecError, "sensor")
    root = _table(data, path.name)
    dev = root.sub("device")
    kind = dev.text("kind")
    if kind not in KINDS:
        raise SensorSpecError(f"Expected `device.kind` in {path.name} to be one of {KINDS}, "
                              f"got {kind!r}.")
    others = [k for k in KINDS if k != kind and k in data]
    if others:
        raise SensorSpecError(f"Expected only the [{kind}] pattern table in {path.name} "
                              f"(device.kind = {kind!r}), got [{others[0]}] as well; remove "
                              "it or change device.kind.")
    phys = _physics(root)
    pattern: Pattern
    if kind == "tls":
        pattern = _tls(root.sub("tls"))
    elif kind == "spinning":
        pattern = _spinning(root.sub("spinning"))
    else:
        pattern = _profiler(root.sub("profiler"))
    # [returns] is optional: without it a device records one return (today's model).
    returns = _returns(root, path.name) if "returns" in data else DEFAULT_RETURNS
    return SensorSpec(dev.text("name"), dev.text("vendor"), dev.text("model"), kind,
                      dev.num("wavelength_nm", positive=True), dev.texts("sources"), phys,
                      pattern, str(path), _driver(root), returns)


#: The shipped sensor files (``sensors/specs/*.toml``) by name.
CATALOGUE: Final = Catalogue(SPEC_DIR, _load, SensorSpecError, "sensor")


def list_sensors() -> list[str]:
    """Names of the shipped sensor models, sorted."""
    return CATALOGUE.names()


def load_sensor(name_or_path: str | os.PathLike[str]) -> SensorSpec:
    """A shipped sensor by name (``list_sensors()``) or a TOML file by path.

    Raises
    ------
    SensorSpecError
        For an unknown name, a missing file, or a file that is not a valid sensor
        description (bad TOML, a missing, malformed or unknown key).
    """
    return CATALOGUE.load(name_or_path)
