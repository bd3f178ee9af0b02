"""Errors of the sensors package (all are ``TunnelsimError`` and ``ValueError``)."""

from __future__ import annotations

from raytrace.errors import TunnelsimError

__all__ = ["CameraSpecError", "PlatformError", "RouteError", "SensorSpecError",
           "SimulationError", "TrajectoryError", "TunnelsimError"]


class SensorSpecError(TunnelsimError, ValueError):
    """A sensor specification (TOML) is missing, malformed, inconsistent or holds a key
    the loader does not know."""


class TrajectoryError(TunnelsimError, ValueError):
    """A trajectory or mounting is unusable (times not increasing, bad shapes)."""


class RouteError(TrajectoryError):
    """No route can be found in a mesh as asked: no enclosed free space or floor, a
    waypoint outside it or not connected, a passage too narrow or low. A
    ``TrajectoryError``, as it was before it had its own class."""


class PlatformError(TunnelsimError, ValueError):
    """A platform specification (TOML) is missing, malformed or holds a key the loader
    does not know, or a platform cannot follow the path asked (a speed above its
    limit, a floor it cannot find)."""


class CameraSpecError(TunnelsimError, ValueError):
    """A camera description (TOML) is missing, malformed or holds a key the loader does
    not read; or camera-frame input has the wrong shape."""


class SimulationError(TunnelsimError, ValueError):
    """A simulation request is inconsistent (bad pose, resolution, physics setting)."""


