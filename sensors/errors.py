"""Errors of the sensors package (all are ``TunnelsimError`` and ``ValueError``)."""

from __future__ import annotations

from raytrace.errors import TunnelsimError

__all__ = ["PointFileError", "SensorSpecError", "SimulationError", "TrajectoryError",
           "TunnelsimError"]


class SensorSpecError(TunnelsimError, ValueError):
    """A sensor specification (TOML) is missing, malformed, inconsistent or holds a key
    the loader does not know."""


class TrajectoryError(TunnelsimError, ValueError):
    """A trajectory or mounting is unusable (times not increasing, bad shapes)."""


class SimulationError(TunnelsimError, ValueError):
    """A simulation request is inconsistent (bad pose, resolution, physics setting)."""


class PointFileError(TunnelsimError, ValueError):
    """A point-cloud file cannot be written or read as asked."""
