"""sensors: scanner models as data, timed scan patterns, platform motion, return
physics, the simulation loop and streaming point-cloud writers.

>>> from sensors import list_sensors, load_sensor
>>> "zf_imager_5016" in list_sensors()
True
>>> spec = load_sensor("robosense_airy")
>>> spec.kind, spec.channels
('spinning', 96)
"""

from .errors import PointFileError, SensorSpecError, SimulationError, TrajectoryError
from .patterns import ProfileScan, Pulses, SpinningScan, TLSScan, scan_for
from .physics import Settings
from .simulate import POINT_DTYPE, Run, simulate_drive, simulate_station
from .spec import SensorSpec, list_sensors, load_sensor
from .trajectory import Mount, Trajectory

__all__ = ["list_sensors", "load_sensor", "SensorSpec", "TLSScan", "SpinningScan",
           "ProfileScan", "Pulses", "scan_for", "Settings", "Trajectory", "Mount",
           "simulate_station", "simulate_drive", "Run", "POINT_DTYPE", "SensorSpecError",
           "SimulationError", "TrajectoryError", "PointFileError"]
