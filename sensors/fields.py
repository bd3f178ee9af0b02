"""The simulated point record: ``POINT_DTYPE``, shared by the simulation loop (which
fills it) and the file writers (which store it).

Fields (SI, radians):

- ``x, y, z``: the measurement in world coordinates (m).
- ``sx, sy, sz``: the point in the sensor frame as the device reports it (m).
- ``range`` (m), ``azimuth`` and ``elevation`` (rad): the measured range and the nominal
  beam angles in the sensor frame.
- ``time``: pulse time (s, trajectory time base); ``channel``, ``column``, ``frame``: the
  pulse's place in the scan pattern.
- ``intensity`` in [0, 1]; ``incidence`` (rad) at the surface; ``triangle``: input face
  index (-1 for particles); ``flag``: 1 surface, 2 particle, 3 mixed.
"""

from __future__ import annotations

import numpy as np

__all__ = ["FIELDS", "FIELD_NAMES", "POINT_DTYPE", "XYZ"]

#: One simulated return (a structured NumPy dtype, native byte order).
POINT_DTYPE = np.dtype([
    ("x", "f8"), ("y", "f8"), ("z", "f8"), ("sx", "f8"), ("sy", "f8"), ("sz", "f8"),
    ("range", "f8"), ("azimuth", "f4"), ("elevation", "f4"), ("time", "f8"),
    ("channel", "i4"), ("column", "i4"), ("frame", "i4"), ("intensity", "f4"),
    ("incidence", "f4"), ("triangle", "i4"), ("flag", "u1")])

#: The field names of ``POINT_DTYPE``, in file order.
FIELD_NAMES: tuple[str, ...] = tuple(POINT_DTYPE.names or ())

#: The world-coordinate fields.
XYZ = ("x", "y", "z")

#: Unit and meaning of every ``POINT_DTYPE`` field: {name: (unit, meaning)}. Angles are
#: radians; ``help(sensors.fields)`` and the writers' docs point here.
FIELDS: dict[str, tuple[str, str]] = {
    "x": ("m", "world x of the measured point (true pose)"),
    "y": ("m", "world y of the measured point"),
    "z": ("m", "world z of the measured point"),
    "sx": ("m", "x in the sensor frame, as the device reports it (no motion correction)"),
    "sy": ("m", "y in the sensor frame"),
    "sz": ("m", "z in the sensor frame"),
    "range": ("m", "measured range, noise included"),
    "azimuth": ("rad", "nominal beam azimuth in the sensor frame, counter-clockwise "
                       "from +x, in (-pi, pi]"),
    "elevation": ("rad", "nominal beam elevation above the sensor's x-y plane, in "
                         "[-pi/2, pi/2]"),
    "time": ("s", "pulse time in the trajectory's time base"),
    "channel": ("1", "laser channel (firing order of the sensor spec)"),
    "column": ("1", "firing group / column within a sweep or profile"),
    "frame": ("1", "sweep, profile or station index"),
    "intensity": ("1", "relative log received power in [0, 1]"),
    "incidence": ("rad", "angle between beam and surface normal, in [0, pi/2]; 0 for "
                         "particles"),
    "triangle": ("1", "input face index hit; -1 for a particle return"),
    "flag": ("1", "1 surface, 2 particle, 3 mixed pixel"),
}
