"""Platforms as data: one TOML file per platform in ``sensors/platforms/``
(``list_platforms``), loaded into a frozen ``PlatformSpec`` and validated on load like
the sensor specs: a missing or malformed key names the file, table and key; a key the
platform's motion does not use is refused with the valid ones (pbrt's
``ReportUnused``). TOML carries degrees; the dataclasses hold SI units and radians.
``sensors.platform`` moves a platform along a path.

Lamps (issue 35): an optional ``[[lamps]]`` array of tables, one table per lamp, in
the platform's base_link (x forward, y left, z up) as ``sensors.robot`` places it: a
wheeled base's on the ground contact plane under its centre (the sensor on the mast
``body.mast_height_m`` above it, as ``[mounts]``), any other platform's at the platform
frame itself (the sensor's carrier: a walker's handheld scanner, a trolley's or a
tripod's sensor)::

    [[lamps]]
    kind = "spot"              # or "point"
    xyz_m = [0.16, 0.08, 0.20]
    rpy_deg = [0.0, 5.0, 0.0]  # spot only: the beam is +x of the lamp frame after rpy
    intensity_cd = 1200.0      # luminous intensity on the beam axis
    beam_deg = 20.0            # spot only: full intensity within this half-angle,
    cutoff_deg = 30.0          # falling linearly in angle to 0 at this one (Mitsuba 3's
                               # spot ``beam_width`` / ``cutoff_angle``)

``sensors.shading.platform_lamps`` places them in the world.

>>> load_platform("ground_robot")
PlatformSpec(ground_robot: wheeled, mast 0.5 m, up to 1 m/s, 60 deg/s)
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Final

from .errors import PlatformError
from .specfile import Catalogue, SpecTable, read_toml

__all__ = ["LAMP_KEYS", "LAMP_KINDS", "MOTIONS", "PLATFORM_DIR", "TABLE_KEYS", "Gait",
           "Limits", "PlatformLamp", "PlatformSpec", "Traversability", "list_platforms",
           "load_platform"]

PLATFORM_DIR: Final = Path(__file__).resolve().parent / "platforms"
MOTIONS: Final = ("wheeled", "walking", "rail", "static")
_LIMIT_KEYS = ("max_speed_mps", "max_accel_mps2", "max_jerk_mps3", "max_yaw_rate_dps",
               "max_yaw_accel_dps2")
_GAIT_KEYS = ("step_hz", "bob_m", "sway_m", "roll_deg", "pitch_deg")
_PLATFORM_KEYS = ("name", "description", "motion", "sources")
#: The optional ``[mounts]`` table (issue 30): the IMU on the base (its origin in
#: base_link, on the ground contact plane under the platform's centre, and its roll,
#: pitch, yaw) and, for a wheeled base, the wheel radius. Without it the IMU sits at
#: the platform frame (the mast top, with the sensor), as before.
_MOUNT_KEYS = ("imu_xyz_m", "imu_rpy_deg")
_TRAVERSE_KEYS = ("max_slope_deg", "max_roll_deg", "max_step_m", "ground_clearance_m",
                  "footprint_width_m", "footprint_length_m")
#: Tables and keys of a platform file, by motion: all required, nothing else allowed.
TABLE_KEYS: Final[Mapping[str, Mapping[str, tuple[str, ...]]]] = {
    "wheeled": {"platform": _PLATFORM_KEYS,
                "body": ("mast_height_m", "wheelbase_m", "track_m"),
                "limits": _LIMIT_KEYS, "traversability": _TRAVERSE_KEYS},
    "walking": {"platform": _PLATFORM_KEYS, "body": ("mast_height_m",),
                "limits": _LIMIT_KEYS, "gait": _GAIT_KEYS,
                "traversability": _TRAVERSE_KEYS},
    "rail": {"platform": _PLATFORM_KEYS, "body": ("mast_height_m",),
             "limits": ("max_speed_mps",)},
    "static": {"platform": _PLATFORM_KEYS, "body": ("mast_height_m",)},
}

#: What a ``[[lamps]]`` entry may be: a spot (a beam along the lamp frame's +x) or a
#: point lamp (the same intensity in every direction).
LAMP_KINDS: Final = ("spot", "point")
#: Keys of one ``[[lamps]]`` table, by kind: all required, nothing else allowed (a point
#: lamp has no direction, so no ``rpy_deg`` and no beam).
LAMP_KEYS: Final[Mapping[str, tuple[str, ...]]] = {
    "spot": ("kind", "xyz_m", "rpy_deg", "intensity_cd", "beam_deg", "cutoff_deg"),
    "point": ("kind", "xyz_m", "intensity_cd"),
}


@dataclass(frozen=True)
class PlatformLamp:
    """One lamp on a platform (``[[lamps]]``), in the platform frame, SI units.

    Attributes
    ----------
    kind : {"spot", "point"}
    xyz_m : (float, float, float)
        Position in base_link (x forward, y left, z up; module doc: on the ground for
        a wheeled base, at the platform frame otherwise).
    rpy_rad : (float, float, float)
        Roll, pitch, yaw of the lamp frame in base_link (fixed axes x, y, z, as URDF);
        the beam is the lamp frame's +x. Zero for a point lamp.
    intensity_cd : float
        Luminous intensity on the beam axis (candela; a point lamp's in every
        direction).
    beam_half_angle_rad, cutoff_half_angle_rad : float
        Full intensity within ``beam``, falling linearly in angle to 0 at ``cutoff``
        (``sensors.shading.Lamp``); pi for a point lamp.
    """

    kind: str
    xyz_m: tuple[float, float, float]
    rpy_rad: tuple[float, float, float]
    intensity_cd: float
    beam_half_angle_rad: float = math.pi
    cutoff_half_angle_rad: float = math.pi


@dataclass(frozen=True)
class Limits:
    """What a moving platform can do (SI units); ``inf`` where not limited (rail)."""

    max_speed_mps: float
    max_accel_mps2: float = math.inf
    max_jerk_mps3: float = math.inf
    max_yaw_rate_radps: float = math.inf
    max_yaw_accel_radps2: float = math.inf


@dataclass(frozen=True)
class Traversability:
    """What ground a platform can cross and what room it needs (SI units, radians):
    the steepest floor it climbs along its heading (``max_slope_rad``) and across it
    (``max_roll_rad``, tip-over), the highest step between two points of the floor
    under it (``max_step_m``), the belly's height above the plane of its contacts
    (``ground_clearance_m``) and its footprint (``footprint_width_m`` across,
    ``footprint_length_m`` along: what must fit between the walls)."""

    max_slope_rad: float
    max_roll_rad: float
    max_step_m: float
    ground_clearance_m: float
    footprint_width_m: float
    footprint_length_m: float


@dataclass(frozen=True)
class Gait:
    """A walker's gait: step frequency (Hz), peak-to-peak vertical bob (once a step) and
    lateral sway (once a stride, two steps) of the sensor (m), and the amplitudes of
    its roll (with the sway) and pitch (with the bob) (rad)."""

    step_hz: float
    bob_m: float
    sway_m: float
    roll_rad: float
    pitch_rad: float


@dataclass(frozen=True)
class PlatformSpec:
    """A platform (``load_platform``): body, limits and gait, in SI units.

    Attributes
    ----------
    name, description, motion : str
        ``motion`` is one of ``MOTIONS``.
    sources : tuple of str
    mast_height_m : float
        Height of the platform frame (the sensor mount) above the floor (m).
    wheelbase_m, track_m : float
        Distances between the axles and between the wheels of an axle (m; wheeled, else
        0).
    limits : Limits or None
        None for a static platform.
    gait : Gait or None
        A walker's.
    traversability : Traversability or None
        The ground it crosses and the room it needs (wheeled, walking; else None).
    imu_xyz_m : (float, float, float) or None
        The IMU's origin in base_link (x forward, y left, z up from the ground contact
        under the platform's centre; m); None: at the platform frame (``[mounts]``
        absent).
    imu_rpy_rad : (float, float, float)
        The IMU's roll, pitch, yaw in base_link (fixed axes x, y, z; rad).
    wheel_radius_m : float
        A wheeled base's wheel radius (m; 0 when not given or not wheeled).
    lamps : tuple of PlatformLamp
        The platform's own lights (``[[lamps]]``; empty when the file has none).
    path : str
        The file it was read from.
    """

    name: str
    description: str
    motion: str
    sources: tuple[str, ...]
    mast_height_m: float
    wheelbase_m: float
    track_m: float
    limits: Limits | None
    gait: Gait | None
    path: str
    traversability: Traversability | None = None
    imu_xyz_m: tuple[float, float, float] | None = None
    imu_rpy_rad: tuple[float, float, float] = (0.0, 0.0, 0.0)
    wheel_radius_m: float = 0.0
    lamps: tuple[PlatformLamp, ...] = ()

    def __repr__(self) -> str:
        out = f"PlatformSpec({self.name}: {self.motion}, mast {self.mast_height_m:g} m"
        if self.limits is not None:
            out += f", up to {self.limits.max_speed_mps:g} m/s"
            if math.isfinite(self.limits.max_yaw_rate_radps):
                out += f", {math.degrees(self.limits.max_yaw_rate_radps):.3g} deg/s"
        return out + ")"


# ---------------------------------------------------------------------- loading
def _pos(t: SpecTable, key: str) -> float:
    return t.num(key, positive=True, what="a finite number > 0")


def _nonneg(t: SpecTable, key: str) -> float:
    return t.num(key, lo=0.0, what="a finite number >= 0")


def _lamps(data: object, f: str) -> tuple[PlatformLamp, ...]:
    """The ``[[lamps]]`` array of tables (module doc)."""
    # DECISION: SpecTable reads one table; an array of tables is a TOML list of dicts,
    # each read as its own SpecTable named ``lamps[i]`` (its keys refused like any
    # table's, the valid set picked by the entry's kind).
    if not isinstance(data, list) or not data or not all(isinstance(x, dict) for x in data):
        raise PlatformError(f"Expected `lamps` in {f} to be an array of tables "
                            f"([[lamps]] entries), got {data!r}; fix the platform file.")
    out = []
    for i, entry in enumerate(data):
        name = f"lamps[{i}]"
        kind = entry.get("kind")
        if kind not in LAMP_KINDS:
            raise PlatformError(f"Expected `{name}.kind` in {f} to be one of {LAMP_KINDS}, "
                                f"got {kind!r}; fix the platform file.")
        t = SpecTable(entry, f, name, PlatformError, "platform", valid=LAMP_KEYS[kind],
                      required=True)
        xyz = t.vec3("xyz_m")
        cd = t.num("intensity_cd", lo=0.0, what="a finite number >= 0 (candela)")
        if kind == "point":
            out.append(PlatformLamp(kind, xyz, (0.0, 0.0, 0.0), cd))
            continue
        r, p, y = t.vec3("rpy_deg")
        beam = t.num("beam_deg", positive=True, what="a half-angle in (0, 180) degrees")
        cut = t.num("cutoff_deg", positive=True, what="a half-angle in (0, 180) degrees")
        if not beam <= cut < 180.0:
            raise PlatformError(f"Expected 0 < `{name}.beam_deg` <= `{name}.cutoff_deg` "
                                f"< 180 in {f}, got {beam:g} and {cut:g}; fix the platform "
                                "file.")
        out.append(PlatformLamp(kind, xyz, (math.radians(r), math.radians(p),
                                            math.radians(y)), cd, math.radians(beam),
                                math.radians(cut)))
    return tuple(out)


def _load(path: Path) -> PlatformSpec:
    data = read_toml(path, PlatformError, "platform")
    f = path.name
    head = data.get("platform")
    motion = head.get("motion") if isinstance(head, dict) else None
    if motion not in MOTIONS:
        raise PlatformError(f"Expected `platform.motion` in {f} to be one of {MOTIONS}, "
                            f"got {motion!r}; fix the platform file.")
    keys = dict(TABLE_KEYS[motion])
    mount_keys = _MOUNT_KEYS + (("wheel_radius_m",) if motion == "wheeled" else ())
    # DECISION: [mounts] is optional (a platform file from before issue 30 still loads:
    # its IMU stays at the platform frame); when present, all its keys are required.
    if "mounts" in data:
        keys["mounts"] = mount_keys
    # [[lamps]] is optional too (an array of tables, read by ``_lamps``): unknown
    # tables are refused with it among the valid ones, the others are required.
    SpecTable(data, f, "", PlatformError, "platform", valid=tuple(keys) + ("lamps",))
    SpecTable({k: v for k, v in data.items() if k != "lamps"}, f, "", PlatformError,
              "platform", valid=tuple(keys), required=True)
    lamps = _lamps(data["lamps"], f) if "lamps" in data else ()
    t = {name: SpecTable(data[name], f, name, PlatformError, "platform", valid=valid,
                         required=True, schema=keys) for name, valid in keys.items()}
    src = t["platform"].data["sources"]
    if not isinstance(src, list) or not src or not all(isinstance(s, str) for s in src):
        raise PlatformError(f"Expected `platform.sources` in {f} to be a non-empty list "
                            f"of strings, got {src!r}; fix the platform file.")
    body = t["body"]
    wheeled = motion == "wheeled"
    limits = gait = None
    if "limits" in t:
        lim = t["limits"]
        deg = math.radians
        limits = Limits(_pos(lim, "max_speed_mps")) if motion == "rail" else Limits(
            _pos(lim, "max_speed_mps"), _pos(lim, "max_accel_mps2"),
            _pos(lim, "max_jerk_mps3"), deg(_pos(lim, "max_yaw_rate_dps")),
            deg(_pos(lim, "max_yaw_accel_dps2")))
    if "gait" in t:
        g = t["gait"]
        gait = Gait(_pos(g, "step_hz"), _nonneg(g, "bob_m"),
                    _nonneg(g, "sway_m"),
                    math.radians(_nonneg(g, "roll_deg")),
                    math.radians(_nonneg(g, "pitch_deg")))
    trav = None
    if "traversability" in t:
        tv = t["traversability"]
        slope, roll = (_pos(tv, k) for k in ("max_slope_deg", "max_roll_deg"))
        for key, deg_v in (("max_slope_deg", slope), ("max_roll_deg", roll)):
            if deg_v >= 90.0:
                raise PlatformError(f"Expected `traversability.{key}` in {f} below 90, "
                                    f"got {deg_v:g}; fix the platform file.")
        trav = Traversability(math.radians(slope), math.radians(roll),
                              _pos(tv, "max_step_m"), _pos(tv, "ground_clearance_m"),
                              _pos(tv, "footprint_width_m"), _pos(tv, "footprint_length_m"))
    imu_xyz: tuple[float, float, float] | None = None
    imu_rpy = (0.0, 0.0, 0.0)
    wheel_r = 0.0
    if "mounts" in t:
        m = t["mounts"]
        imu_xyz = m.vec3("imu_xyz_m")
        roll, pitch, yaw = m.vec3("imu_rpy_deg")
        imu_rpy = (math.radians(roll), math.radians(pitch), math.radians(yaw))
        if wheeled:
            wheel_r = _pos(m, "wheel_radius_m")
    return PlatformSpec(t["platform"].text("name"), t["platform"].text("description"),
                        motion, tuple(src), _pos(body, "mast_height_m"),
                        _pos(body, "wheelbase_m") if wheeled else 0.0,
                        _pos(body, "track_m") if wheeled else 0.0, limits, gait, str(path),
                        trav, imu_xyz, imu_rpy, wheel_r, lamps)


#: The shipped platform files (``sensors/platforms/*.toml``) by name.
CATALOGUE: Final = Catalogue(PLATFORM_DIR, _load, PlatformError, "platform")


def list_platforms() -> list[str]:
    """Names of the shipped platforms, sorted."""
    return CATALOGUE.names()


def load_platform(name_or_path: str | os.PathLike[str]) -> PlatformSpec:
    """A shipped platform by name (``list_platforms()``) or a TOML file by path.

    Raises
    ------
    PlatformError
        For an unknown name, a missing file, or a file that is not a valid platform
        (bad TOML, a missing, malformed or unknown key).
    """
    return CATALOGUE.load(name_or_path)


# ---------------------------------------------------------------------- motion
