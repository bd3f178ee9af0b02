"""sensors: scanner models as data, timed scan patterns, platform motion, return
physics, the simulation loop and streaming point-cloud writers.

>>> from sensors import list_sensors, load_sensor
>>> "zf_imager_5016" in list_sensors()
True
>>> spec = load_sensor("robosense_airy")
>>> spec.kind, spec.channels
('spinning', 96)
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING

__version__ = "0.2.0"

# Public names are imported on first use: ``import sensors.errors`` (which every
# command-line start does) must not compile or load Numba.
_EXPORTS = {
    "sensors.errors": ("TunnelsimError", "PointFileError", "SensorSpecError", "SimulationError", "TrajectoryError"),
    "sensors.patterns": ("ProfileScan", "Pulses", "SpinningScan", "TLSScan", "scan_for"),
    "sensors.physics": ("Settings",),
    "sensors.simulate": ("POINT_DTYPE", "Run", "simulate_drive", "simulate_station"),
    "sensors.spec": ("SensorSpec", "list_sensors", "load_sensor"),
    "sensors.trajectory": ("Mount", "Trajectory"),
    "sensors.meshes": ("load_mesh",),
}
_WHERE = {name: module for module, names in _EXPORTS.items() for name in names}

__all__ = ["__version__", *_WHERE]

if TYPE_CHECKING:  # the same names, eagerly, for type checkers and IDEs
    from sensors.errors import TunnelsimError, PointFileError, SensorSpecError, SimulationError, TrajectoryError
    from sensors.patterns import ProfileScan, Pulses, SpinningScan, TLSScan, scan_for
    from sensors.physics import Settings
    from sensors.simulate import POINT_DTYPE, Run, simulate_drive, simulate_station
    from sensors.spec import SensorSpec, list_sensors, load_sensor
    from sensors.trajectory import Mount, Trajectory
    from sensors.meshes import load_mesh


def __getattr__(name: str):
    if name not in _WHERE:
        raise AttributeError(f"module 'sensors' has no attribute {name!r}")
    value = getattr(importlib.import_module(_WHERE[name]), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(__all__)
