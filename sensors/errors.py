"""Errors of the sensors package (all are ``TunnelsimError`` and ``ValueError``)."""

from raytrace.errors import TunnelsimError


class SensorSpecError(TunnelsimError, ValueError):
    """A sensor specification (TOML) is missing, malformed or inconsistent."""


class TrajectoryError(TunnelsimError, ValueError):
    """A trajectory or mounting is unusable (times not increasing, bad shapes)."""


class SimulationError(TunnelsimError, ValueError):
    """A simulation request is inconsistent (bad pose, resolution, physics setting)."""


class PointFileError(TunnelsimError, ValueError):
    """A point-cloud file cannot be written or read as asked."""
