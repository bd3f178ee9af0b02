"""Sensor models as data: one TOML file per device, loaded into frozen dataclasses.

Device facts (``SensorSpec``) are kept apart from user settings (the resolution chosen
for a station, the physics switches, the mounting) and from runtime state (poses,
random streams), in the manner of HELIOS++'s device/setting/state split. TOML carries
degrees, microseconds, milliradians and arcseconds, the units of datasheets; the
dataclasses hold SI units and radians.

Every file is validated on load: a missing or malformed field names the file, the
table and the field. ``list_sensors()`` scans ``sensors/specs/``; ``load_sensor`` takes
a registered name or the path of a user's own TOML file.
"""

from __future__ import annotations

import tomllib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .errors import SensorSpecError

SPEC_DIR = Path(__file__).resolve().parent / "specs"
KINDS = ("tls", "spinning", "profiler")


@dataclass(frozen=True)
class Physics:
    """Return-physics constants of a device (SI units).

    Detection threshold: P_min = detection_reflectivity / detection_range_m^2 for
    P = rho cos(theta) / R^2; noise sigma = sqrt(range_sigma_floor_m^2 +
    range_sigma_m^2 P_ref / P) with P_ref = reference_reflectivity /
    reference_range_m^2 (shot-noise-limited ranging: sigma ~ 1/sqrt(SNR)).
    """

    range_min_m: float
    range_max_m: float
    detection_range_m: float
    detection_reflectivity: float
    detection_softness: float
    range_sigma_m: float
    reference_range_m: float
    reference_reflectivity: float
    range_sigma_floor_m: float
    angle_sigma_rad: float
    beam_divergence_rad: float       # half angle (1/e^2 radius of the far field)
    exit_diameter_m: float


@dataclass(frozen=True)
class TLSPattern:
    vertical_fov_rad: float
    head_sweep_rad: float
    measurement_rate_hz: float
    resolutions_rad: dict
    default_resolution: str


@dataclass(frozen=True)
class SpinningPattern:
    rotation_hz: float
    column_period_s: float
    elevations_rad: np.ndarray          # (channels,) in firing order
    azimuth_offsets_rad: np.ndarray     # (channels,)
    firing_offsets_s: np.ndarray        # (channels,) time after the column start
    clockwise: bool


@dataclass(frozen=True)
class ProfilerPattern:
    profile_rate_hz: float
    points_per_profile: int
    blind_sector_rad: tuple             # (start, end) angles in the profile plane


@dataclass(frozen=True)
class SensorSpec:
    name: str
    vendor: str
    model: str
    kind: str
    wavelength_nm: float
    sources: tuple
    physics: Physics
    pattern: object
    path: str

    @property
    def channels(self) -> int:
        if self.kind == "spinning":
            return len(self.pattern.elevations_rad)
        return 1


class _Table:
    """Typed access to one TOML table with errors naming file, table and field."""

    def __init__(self, data, file, table):
        self.data, self.file, self.table = data, file, table

    def _err(self, key, what, got):
        return SensorSpecError(f"Expected `{self.table}.{key}` in {self.file} to be {what}, "
                               f"got {got!r}; fix the sensor file.")

    def has(self, key):
        return key in self.data

    def raw(self, key):
        if key not in self.data:
            raise SensorSpecError(f"Expected a field `{self.table}.{key}` in {self.file}, "
                                  "got none; add it to the sensor file.")
        return self.data[key]

    def num(self, key, lo=None, hi=None, positive=False, default=None):
        if default is not None and key not in self.data:
            return float(default)
        v = self.raw(key)
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not np.isfinite(v):
            raise self._err(key, "a finite number", v)
        if positive and v <= 0:
            raise self._err(key, "positive", v)
        if lo is not None and v < lo or hi is not None and v > hi:
            raise self._err(key, f"within [{lo}, {hi}]", v)
        return float(v)

    def text(self, key):
        v = self.raw(key)
        if not isinstance(v, str) or not v:
            raise self._err(key, "a non-empty string", v)
        return v

    def nums(self, key, n=None):
        v = self.raw(key)
        ok = isinstance(v, list) and all(isinstance(x, (int, float)) and
                                         not isinstance(x, bool) for x in v)
        if not ok or (n is not None and len(v) != n) or not v:
            raise self._err(key, f"a list of {n or 'some'} numbers", v)
        return np.asarray(v, dtype=np.float64)

    def sub(self, key):
        v = self.raw(key)
        if not isinstance(v, dict):
            raise self._err(key, "a table", v)
        return _Table(v, self.file, f"{self.table}.{key}" if self.table else key)


def with_rate(spec: SensorSpec, rate_hz: float) -> SensorSpec:
    """The spec with another rotation (spinning) or profile (profiler) rate; the firing
    rate stays, so points per turn or per profile change as on the device."""
    from dataclasses import replace

    if not (np.isfinite(rate_hz) and rate_hz > 0) or spec.kind not in ("spinning",
                                                                      "profiler"):
        raise SensorSpecError(f"Expected a positive rate for a spinning lidar or a "
                              f"profiler, got {rate_hz:g} Hz for {spec.name} ({spec.kind}).")
    key = "rotation_hz" if spec.kind == "spinning" else "profile_rate_hz"
    return replace(spec, pattern=replace(spec.pattern, **{key: float(rate_hz)}))


def _load(path: Path) -> SensorSpec:
    try:
        data = tomllib.loads(path.read_text())
    except tomllib.TOMLDecodeError as exc:
        raise SensorSpecError(f"Expected valid TOML in {path}, got a syntax error: {exc}."
                              ) from exc
    root = _Table(data, path.name, "")
    dev = root.sub("device")
    kind = dev.text("kind")
    if kind not in KINDS:
        raise SensorSpecError(f"Expected `device.kind` in {path.name} to be one of {KINDS}, "
                              f"got {kind!r}.")
    rng, det, noi, beam = (root.sub(k) for k in ("range", "detection", "noise", "beam"))
    rmin = rng.num("min_m", lo=0.0)
    rmax = rng.num("max_m", positive=True)
    if rmax <= rmin:
        raise SensorSpecError(f"Expected `range.max_m` > `range.min_m` in {path.name}, got "
                              f"{rmax} <= {rmin}.")
    phys = Physics(
        range_min_m=rmin, range_max_m=rmax,
        detection_range_m=det.num("range_m", positive=True),
        detection_reflectivity=det.num("reflectivity", lo=1e-6, hi=1.0),
        detection_softness=det.num("softness", positive=True),
        range_sigma_m=noi.num("range_sigma_m", lo=0.0),
        reference_range_m=noi.num("reference_range_m", positive=True),
        reference_reflectivity=noi.num("reference_reflectivity", lo=1e-6, hi=1.0),
        range_sigma_floor_m=noi.num("range_sigma_floor_m", lo=0.0),
        angle_sigma_rad=np.deg2rad(noi.num("angle_sigma_arcsec", lo=0.0) / 3600.0),
        beam_divergence_rad=beam.num("divergence_half_mrad", lo=0.0) * 1e-3,
        exit_diameter_m=beam.num("exit_diameter_mm", lo=0.0) * 1e-3,
    )
    if kind == "tls":
        p = root.sub("tls")
        res = p.sub("resolutions_deg")
        resolutions = {k: np.deg2rad(res.num(k, positive=True)) for k in res.data}
        default = p.text("default_resolution")
        if default not in resolutions:
            raise SensorSpecError(f"Expected `tls.default_resolution` in {path.name} to be "
                                  f"one of {sorted(resolutions)}, got {default!r}.")
        pattern = TLSPattern(np.deg2rad(p.num("vertical_fov_deg", lo=1.0, hi=360.0)),
                             np.deg2rad(p.num("head_sweep_deg", lo=1.0, hi=360.0)),
                             p.num("measurement_rate_hz", positive=True), resolutions,
                             default)
    elif kind == "spinning":
        p = root.sub("spinning")
        if p.has("elevations_deg"):
            el = p.nums("elevations_deg")
        else:
            lo, hi = p.nums("elevation_uniform_deg", 2)
            n = int(p.num("channels", lo=1))
            el = np.linspace(lo, hi, n)
        n = len(el)
        az = p.raw("azimuth_offset_deg")
        az = p.nums("azimuth_offset_deg", n) if isinstance(az, list) else \
            np.full(n, p.num("azimuth_offset_deg"))
        if p.has("firing_offsets_us"):
            off = p.nums("firing_offsets_us", n) * 1e-6
        else:
            size = int(p.num("firing_group_size", lo=1))
            off = (np.arange(n) // size) * p.num("firing_group_step_us", lo=0.0) * 1e-6
        col = p.num("column_period_us", positive=True) * 1e-6
        if off.max() >= col:
            raise SensorSpecError(f"Expected firing offsets within one column period "
                                  f"({col * 1e6:g} us) in {path.name}, got up to "
                                  f"{off.max() * 1e6:g} us.")
        cw = p.raw("clockwise")
        if not isinstance(cw, bool):
            raise p._err("clockwise", "true or false", cw)
        pattern = SpinningPattern(p.num("rotation_hz", positive=True), col,
                                  np.deg2rad(el), np.deg2rad(az), off, cw)
    else:
        p = root.sub("profiler")
        blind = p.nums("blind_sector_deg", 2)
        pattern = ProfilerPattern(p.num("profile_rate_hz", positive=True),
                                  int(p.num("points_per_profile", lo=8)),
                                  tuple(np.deg2rad(blind)))
    sources = dev.raw("sources")
    if not isinstance(sources, list) or not sources:
        raise dev._err("sources", "a non-empty list of strings", sources)
    return SensorSpec(dev.text("name"), dev.text("vendor"), dev.text("model"), kind,
                      dev.num("wavelength_nm", positive=True), tuple(sources), phys,
                      pattern, str(path))


def _registry() -> dict:
    out = {}
    for f in sorted(SPEC_DIR.glob("*.toml")):
        spec = _load(f)
        if spec.name in out:
            raise SensorSpecError(f"Expected unique sensor names, got {spec.name!r} in both "
                                  f"{Path(out[spec.name]).name} and {f.name}.")
        out[spec.name] = str(f)
    return out


def list_sensors() -> list[str]:
    """Names of the shipped sensor models."""
    return sorted(_registry())


def load_sensor(name_or_path) -> SensorSpec:
    """A shipped sensor by name (``list_sensors()``) or a TOML file by path."""
    p = Path(str(name_or_path))
    if p.suffix == ".toml" or p.exists():
        if not p.is_file():
            raise SensorSpecError(f"Expected a sensor TOML file, got '{p}' which does not "
                                  "exist.")
        return _load(p)
    reg = _registry()
    if name_or_path not in reg:
        raise SensorSpecError(f"Expected a sensor name in {sorted(reg)} or a .toml path, "
                              f"got {name_or_path!r}.")
    return _load(Path(reg[name_or_path]))
