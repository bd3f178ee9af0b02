"""The sensor model's data types: the frozen dataclasses a sensor file loads into.

``SensorSpec`` (one device) holds its return physics (``Physics``), its scan pattern
(``TLSPattern``, ``SpinningPattern`` or ``ProfilerPattern``, matching ``kind``) and,
optionally, its ROS 2 driver's conventions (``Driver``). Device facts only: user
settings and runtime state live elsewhere (HELIOS++'s device/setting/state split). SI
units and radians throughout; ``sensors.spec`` reads and validates the TOML files
(datasheet units) into these types and re-exports them.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Final

import numpy as np
from numpy.typing import NDArray

from .errors import SensorSpecError
from .waveform import DEFAULT_RETURNS, ReturnsSpec

__all__ = ["KINDS", "NO_RETURN", "POINT_LAYOUTS", "RING_ORDERS", "SATURATION_RANGE_FLOOR_M",
           "Driver", "Pattern", "Physics", "ProfilerPattern", "SensorSpec",
           "SpinningPattern", "TLSPattern"]


#: Device kinds; each has a pattern table of the same name in its TOML file.
KINDS: Final = ("tls", "spinning", "profiler")

#: Point layouts of ``[driver] point_layout`` (``sensors.bag`` documents and writes them).
POINT_LAYOUTS: Final = ("velodyne", "ouster", "robosense")
#: ``[driver] ring_order``: ring 0 is the lowest beam (ascending), the highest
#: (descending), or the pattern's channel index.
RING_ORDERS: Final = ("elevation_ascending", "elevation_descending", "channel")
#: ``[driver] no_return``: what an organised cloud holds in x, y, z for a cell without a
#: return (``sensors.pointcloud2.organise``).
NO_RETURN: Final = ("zero", "nan")

#: Power of a white target at normal incidence at this range, at the least: the
#: saturation power of the intensity scale for devices with a shorter minimum range.
SATURATION_RANGE_FLOOR_M: Final = 0.1


@dataclass(frozen=True)
class Physics:
    """Return-physics constants of a device (SI units; formulas in ``sensors.physics``).

    Detection threshold: P_min = detection_reflectivity / detection_range_m^2 for
    P = rho cos(theta) / R^2; noise sigma = sqrt(range_sigma_floor_m^2 +
    range_sigma_m^2 P_ref / P) with P_ref = reference_reflectivity /
    reference_range_m^2 (shot-noise-limited ranging: sigma ~ 1/sqrt(SNR)).

    Attributes
    ----------
    range_min_m, range_max_m : float
        Nearest and farthest range the device reports (m).
    detection_range_m, detection_reflectivity : float
        A target of this reflectivity at normal incidence at this range is detected
        half the time.
    detection_softness : float
        Width of the detection edge, in units of ln(power).
    range_sigma_m, reference_range_m, reference_reflectivity : float
        Range noise (1 sigma, m) on a target of the reference reflectivity at the
        reference range.
    range_sigma_floor_m : float
        Range noise that no signal strength removes (m).
    angle_sigma_rad : float
        Angular accuracy per axis (rad).
    beam_divergence_rad : float
        Half angle of the beam (1/e^2 radius of the far field, rad).
    exit_diameter_m : float
        Beam diameter at the exit window (m).
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
    beam_divergence_rad: float
    exit_diameter_m: float

    @property
    def threshold_power(self) -> float:
        """P_min = detection_reflectivity / detection_range_m^2 (relative units)."""
        return self.detection_reflectivity / self.detection_range_m ** 2

    @property
    def reference_power(self) -> float:
        """P_ref = reference_reflectivity / reference_range_m^2 (relative units)."""
        return self.reference_reflectivity / self.reference_range_m ** 2

    @property
    def saturation_power(self) -> float:
        """P_sat: a white target at normal incidence at the minimum range (at least
        ``SATURATION_RANGE_FLOOR_M``), the top of the intensity scale."""
        return 1.0 / max(self.range_min_m, SATURATION_RANGE_FLOOR_M) ** 2

    def __repr__(self) -> str:
        return (f"Physics(range {self.range_min_m:g}-{self.range_max_m:g} m, "
                f"rho {self.detection_reflectivity:g} detected at "
                f"{self.detection_range_m:g} m, sigma {self.range_sigma_m * 1e3:g} mm at "
                f"{self.reference_range_m:g} m)")


@dataclass(frozen=True)
class TLSPattern:
    """A terrestrial scanner's mirror and head (see ``sensors.patterns.TLSScan``).

    Attributes
    ----------
    vertical_fov_rad : float
        Field of the mirror sweep, centred on the zenith (rad).
    head_sweep_rad : float
        Turn of the head over a full station (rad).
    measurement_rate_hz : float
        Pulses per second.
    resolutions_rad : dict of str to float
        Angular step (rad) per named resolution preset.
    default_resolution : str
        The preset used when none is named.
    """

    vertical_fov_rad: float
    head_sweep_rad: float
    measurement_rate_hz: float
    resolutions_rad: dict[str, float]
    default_resolution: str

    def __repr__(self) -> str:
        return (f"TLSPattern({np.rad2deg(self.vertical_fov_rad):g} x "
                f"{np.rad2deg(self.head_sweep_rad):g} deg, "
                f"{self.measurement_rate_hz / 1e6:g} MHz, presets "
                f"{', '.join(self.resolutions_rad)}; default {self.default_resolution!r})")


@dataclass(frozen=True)
class SpinningPattern:
    """A spinning multi-beam lidar (see ``sensors.patterns.SpinningScan``).

    Attributes
    ----------
    rotation_hz : float
        Turns per second.
    column_period_s : float
        Time between the starts of two firing columns (s).
    elevations_rad : (channels,) float64
        Beam elevation above the sensor's x-y plane, in firing order (rad).
    azimuth_offsets_rad : (channels,) float64
        Beam azimuth relative to the head's (rad).
    firing_offsets_s : (channels,) float64
        Firing time of each beam after its column's start (s).
    clockwise : bool
        The head turns clockwise seen from +z (negatively about z).
    """

    rotation_hz: float
    column_period_s: float
    elevations_rad: NDArray[np.float64]
    azimuth_offsets_rad: NDArray[np.float64]
    firing_offsets_s: NDArray[np.float64]
    clockwise: bool

    def __eq__(self, other: object) -> bool:
        # The generated __eq__ would compare arrays with ==, whose truth is ambiguous.
        if not isinstance(other, SpinningPattern):
            return NotImplemented
        return (self.rotation_hz, self.column_period_s, self.clockwise) == \
            (other.rotation_hz, other.column_period_s, other.clockwise) and all(
                np.array_equal(a, b) for a, b in
                ((self.elevations_rad, other.elevations_rad),
                 (self.azimuth_offsets_rad, other.azimuth_offsets_rad),
                 (self.firing_offsets_s, other.firing_offsets_s)))

    __hash__ = None  # type: ignore[assignment]  # mutable arrays inside

    def __repr__(self) -> str:
        return (f"SpinningPattern({len(self.elevations_rad)} channels, "
                f"{self.rotation_hz:g} Hz, column {self.column_period_s * 1e6:g} us, "
                f"{'clockwise' if self.clockwise else 'counter-clockwise'})")


@dataclass(frozen=True)
class ProfilerPattern:
    """A 2-D profile scanner (see ``sensors.patterns.ProfileScan``).

    Attributes
    ----------
    profile_rate_hz : float
        Profiles per second.
    points_per_profile : int
        Pulse slots per 360 degree profile (blind ones included).
    blind_sector_rad : (float, float)
        Start and end angle of the blind sector in the profile plane, from the sensor's
        +z towards +y (rad).
    """

    profile_rate_hz: float
    points_per_profile: int
    blind_sector_rad: tuple[float, float]

    def __repr__(self) -> str:
        b0, b1 = np.rad2deg(self.blind_sector_rad)
        return (f"ProfilerPattern({self.profile_rate_hz:g} Hz, {self.points_per_profile} "
                f"points per profile, blind {b0:g}-{b1:g} deg)")


@dataclass(frozen=True)
class Driver:
    """How the device's common ROS 2 driver publishes its points (the optional
    ``[driver]`` table): what ``sensors.bag`` follows so that a bag reads like a
    recording. Scan direction and azimuth zero stay the pattern's own
    (``SpinningPattern.clockwise``, ``azimuth_offsets_rad``), set to the driver's where
    the model follows it (each file says).

    Attributes
    ----------
    package : str
        The driver (``velodyne_pointcloud``, ``ouster-ros``, ``rslidar_sdk``).
    point_layout : {"velodyne", "ouster", "robosense"}
        Field layout of its PointCloud2 (``sensors.bag.LAYOUTS``).
    frame_id, topic : str
        The driver's default cloud frame and topic.
    ring_order : {"elevation_ascending", "elevation_descending", "channel"}
        How the driver numbers rings; the simulated ``channel`` stays the firing order.
    intensity_max : float
        The driver's intensity for a return of simulated intensity 1.
    beam_origin_offset_m : float
        Radial distance of the beam origin from the rotation axis in the driver's
        default model (m); documented, not simulated (beams leave the sensor origin).
    organized : bool
        The driver publishes the organised grid of a revolution (rows = rings,
        columns = the revolution's firing columns, a cell for every pulse, returned
        or not; ``is_dense`` false where a cell has no return) rather than the
        returns only. Optional in the file (false).
    no_return : {"zero", "nan"}
        x, y, z of an organised cell without a return. Optional in the file ("zero").
    signal_photons_at_threshold : float
        The ouster layout's ``intensity`` (signal photons) of a return at the
        detection threshold power; signal is proportional to the received power
        (``sensors.pointcloud2``). 0 for the other layouts (optional in the file).
    dual_topic_suffix : str
        Where the driver publishes the second return of a multiple-return drive: on
        its own topic, ``topic + dual_topic_suffix`` (ouster-ros: "/ouster/points2"),
        in the same layout; "" (the default): both returns in the one cloud.
    """

    package: str
    point_layout: str
    frame_id: str
    topic: str
    ring_order: str
    intensity_max: float
    beam_origin_offset_m: float
    organized: bool = False
    no_return: str = "zero"
    signal_photons_at_threshold: float = 0.0
    dual_topic_suffix: str = ""

    def rings(self, elevations_rad: NDArray[np.float64]) -> NDArray[np.uint16]:
        """Ring of each channel (channels, firing order): its rank by elevation, ties
        sharing a ring, as rs_driver's ``genUserChan`` and velodyne_pointcloud's
        calibration sort them; the channel itself for ``"channel"``."""
        el = np.asarray(elevations_rad, dtype=np.float64)
        if self.ring_order == "channel":
            return np.arange(len(el), dtype=np.uint16)
        sign = 1.0 if self.ring_order == "elevation_ascending" else -1.0
        key = sign * el
        return (key[None, :] < key[:, None]).sum(axis=1).astype(np.uint16)


Pattern = TLSPattern | SpinningPattern | ProfilerPattern
_PATTERN_OF_KIND: Final[Mapping[str, type]] = {
    "tls": TLSPattern, "spinning": SpinningPattern, "profiler": ProfilerPattern}


@dataclass(frozen=True)
class SensorSpec:
    """One device, as read from its TOML file (``load_sensor``).

    Attributes
    ----------
    name, vendor, model : str
    kind : {"tls", "spinning", "profiler"}
    wavelength_nm : float
    sources : tuple of str
        Where each value comes from (datasheets, drivers, papers).
    physics : Physics
    pattern : TLSPattern, SpinningPattern or ProfilerPattern
        The one that matches ``kind``.
    path : str
        The file it was read from.
    driver : Driver or None
        The ROS 2 driver's conventions (``[driver]``), if the file gives them.
    returns : ReturnsSpec
        What the device records per pulse (``[returns]``: return modes, what ``dual``
        means, echoes at most, pulse width); ``DEFAULT_RETURNS`` (one return,
        ``strongest``) for a file without the table.
    """

    name: str
    vendor: str
    model: str
    kind: str
    wavelength_nm: float
    sources: tuple[str, ...]
    physics: Physics
    pattern: Pattern
    path: str
    driver: Driver | None = None
    returns: ReturnsSpec = DEFAULT_RETURNS

    def __post_init__(self) -> None:
        want = _PATTERN_OF_KIND.get(self.kind)
        if want is None or not isinstance(self.pattern, want):
            raise SensorSpecError(f"Expected a pattern matching kind {self.kind!r} (one "
                                  f"of {KINDS}), got {type(self.pattern).__name__}.")

    @property
    def channels(self) -> int:
        """Beams fired per column: the elevations of a spinning lidar, else 1."""
        if isinstance(self.pattern, SpinningPattern):
            return len(self.pattern.elevations_rad)
        return 1

    def __repr__(self) -> str:
        p = self.pattern
        if isinstance(p, SpinningPattern):
            what = f"{self.channels} channels at {p.rotation_hz:g} Hz"
        elif isinstance(p, ProfilerPattern):
            what = f"{p.profile_rate_hz:g} profiles/s"
        else:
            what = f"{p.measurement_rate_hz / 1e6:g} MHz"
        return (f"SensorSpec({self.name}: {self.vendor} {self.model}, {self.kind}, {what}, "
                f"{self.physics.range_min_m:g}-{self.physics.range_max_m:g} m)")
