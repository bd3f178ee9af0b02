"""The simulated point record: ``POINT_DTYPE``, shared by the simulation loop (which
fills it) and the file writers (which store it).

Fields (SI, radians):

- ``x, y, z``: the measurement in world coordinates (m).
- ``sx, sy, sz``: the point in the sensor frame as the device reports it (m).
- ``range`` (m), ``azimuth`` and ``elevation`` (rad): the measured range and the nominal
  beam angles in the sensor frame: azimuth counter-clockwise from +x in (-pi, pi],
  elevation above the sensor's x-y plane in [-pi/2, pi/2].
- ``time``: pulse time (s, trajectory time base); ``channel``, ``column``, ``frame``: the
  pulse's place in the scan pattern.
- ``intensity`` in [0, 1]; ``incidence`` (rad) between beam and surface normal, in
  [0, pi/2] (0 for particles); ``triangle``: input face index (-1 for particles);
  ``flag``: 1 surface, 2 particle, 3 mixed.
"""

from __future__ import annotations

import numpy as np

__all__ = ["FIELD_NAMES", "FIELD_UNITS", "POINT_DTYPE", "XYZ"]

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

#: Unit of every ``POINT_DTYPE`` field ("1" for counts, indices and fractions); the
#: module docstring gives each field's meaning. Angles are radians.
FIELD_UNITS: dict[str, str] = {
    **dict.fromkeys(("x", "y", "z", "sx", "sy", "sz", "range"), "m"),
    **dict.fromkeys(("azimuth", "elevation", "incidence"), "rad"), "time": "s",
    **dict.fromkeys(("channel", "column", "frame", "intensity", "triangle", "flag"), "1"),
}
