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

from typing import TYPE_CHECKING

from raytrace.lazy import lazy_exports_of

__version__ = "0.2.0"

# Public names are imported on first use: ``import sensors.errors`` (which every
# command-line start does) must not compile or load Numba.
# The one list of public names: type checkers and IDEs import them here; the
# façade reads this block (raytrace.lazy.lazy_exports_of) and imports each on first use.
if TYPE_CHECKING:
    from sensors.errors import (TunnelsimError, CameraSpecError, SensorSpecError, SimulationError, TrajectoryError, PlatformError, RouteError)
    from sensors.io.errors import (FileFormatError, MeshFileError, PointFileError,
        TableFileError, TunnelFileError)
    from sensors.patterns import ProfileScan, Pulses, SpinningScan, TLSScan, scan_for
    from sensors.physics import Settings
    from sensors.io.fields import POINT_DTYPE
    from sensors.simulate import Run, simulate_drive, simulate_station
    from sensors.writers import PointWriter, open_writer
    from sensors.io.copc import CopcWriter
    from sensors.spec_types import SensorSpec
    from sensors.spec import list_sensors, load_sensor
    from sensors.trajectory import Mount, Trajectory
    from sensors.io.meshes import load_mesh
    from sensors.freespace import FreeSpace, free_space
    from sensors.route import Route, find_route, read_waypoints
    from sensors.platform_spec import PlatformSpec, list_platforms, load_platform
    from sensors.platform import platform_trajectory
    from sensors.camera import CameraSpec, list_cameras, load_camera

__getattr__, __dir__, __all__ = lazy_exports_of(__name__, __file__)
