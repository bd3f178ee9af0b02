"""The simulated point record: ``POINT_DTYPE``, shared by the simulation loop (which
fills it) and the file writers (which store it), and ``FILE_FIELDS``, the one table of
the names those fields carry in files.

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

File names (issue 22): every file format (LAS/LAZ, PLY, NPZ) names a field as LAS does,
``FILE_FIELDS`` below: ``sensor_x, sensor_y, sensor_z`` for ``sx, sy, sz`` and
``gps_time`` for ``time`` (the pulse time in the trajectory's time base, in the slot
LAS calls GPS time); the other names are the same in memory and in files. In LAS, x, y,
z are the scaled coordinates, ``intensity`` is the standard dimension (x 65535, uint16)
and ``gps_time`` the standard one; the rest are extra bytes. PLY and NPZ store every
field as ``POINT_DTYPE`` holds it (float ``intensity`` in [0, 1]). Files written before
this naming hold ``sx, sy, sz, time`` in PLY and NPZ: readers take both
(``point_field``).
"""

from __future__ import annotations

from dataclasses import dataclass

from typing import Final

import numpy as np

__all__ = ["FIELD_NAMES", "FIELD_UNITS", "FILE_DTYPE", "FILE_FIELDS", "FILE_NAMES",
           "FLAG_MIXED", "FLAG_PARTICLE", "FLAG_SURFACE", "LAS_COMPACT",
           "LAS_DESCRIPTIONS", "LAS_EXTRA", "MIXED_SPREAD_M", "POINT_DTYPE",
           "RETURN_FIELDS", "RETURN_POINT_DTYPE", "WAVEFORM_FIELDS",
           "WAVEFORM_POINT_DTYPE", "WAVE_SAMPLES", "XYZ",
           "FileField", "field_offset", "file_records", "las_description", "point_field"]

#: One simulated return (a structured NumPy dtype, native byte order).
POINT_DTYPE = np.dtype([
    ("x", "f8"), ("y", "f8"), ("z", "f8"), ("sx", "f8"), ("sy", "f8"), ("sz", "f8"),
    ("range", "f8"), ("azimuth", "f4"), ("elevation", "f4"), ("time", "f8"),
    ("channel", "i4"), ("column", "i4"), ("frame", "i4"), ("intensity", "f4"),
    ("incidence", "f4"), ("triangle", "i4"), ("flag", "u1")])

#: Values of the ``flag`` field (``sensors.physics`` and ``sensors.waveform`` set them).
FLAG_SURFACE: Final = 1
FLAG_PARTICLE: Final = 2
FLAG_MIXED: Final = 3
#: Sub-returns whose ranges spread more than this are flagged mixed (m).
MIXED_SPREAD_M: Final = 0.01

#: Per-point fields of multiple returns, added to ``POINT_DTYPE`` records where a mode
#: other than the default is simulated (the LAS writer stores return_number and
#: number_of_returns in the point's return bits, the echo's width (sigma, m) and
#: amplitude (relative power) as extra bytes). ``sensors.waveform`` re-exports it.
RETURN_FIELDS: Final = (("return_number", "u1"), ("number_of_returns", "u1"),
                        ("echo_width", "f4"), ("echo_amplitude", "f4"))

#: One return of a multiple-return run (``Settings(returns=...)``): ``POINT_DTYPE``
#: followed by ``sensors.waveform.RETURN_FIELDS``: return_number (1 = nearest
#: reported echo of its pulse), number_of_returns, echo_width (the echo's Gaussian
#: sigma, m) and echo_amplitude (its peak, relative power). The LAS writer stores the
#: first two in the point's return bits and the echo fields as extra bytes.
RETURN_POINT_DTYPE = np.dtype(POINT_DTYPE.descr + list(RETURN_FIELDS))

#: Samples of the waveform window each return of a full-waveform run carries
#: (``Settings(waveform=True)``; 0.25 ns bins: 64 ns, 9.59 m of range).
#: DECISION: a fixed window in the record (not a side table of variable rows), so that
#: waveform chunks flow through everything a chunk flows through (the replay cache,
#: ``Run.chunks``, the writer thread) unchanged; 256 x 2 bytes per return, and the
#: simulation takes smaller chunks in this mode (``sensors.simulate.WAVE_CHUNK_PULSES``)
#: so that memory stays bounded. A pulse whose reported echoes fit in one window shares
#: it (the LAS writer stores it once); otherwise each return's window is centred on its
#: own echo.
WAVE_SAMPLES: Final = 256

#: Per-point fields of a full-waveform run, after ``RETURN_FIELDS``: ``wave_start_m``
#: the range of the window's first sample (m; sample k lies at wave_start_m + k x bin),
#: ``wave_location_ps`` the return's time from the first sample (ps; LAS "return point
#: waveform location"), ``wave_dx, wave_dy, wave_dz`` the LAS parametric line x(t),
#: y(t), z(t) (m per ps; see ``sensors.waveform.wave_windows`` for its sense),
#: ``wave_gain`` the digitiser gain (relative power per count), ``wave_spacing_ps`` the
#: bin (ps), ``wave`` the window's samples (uint16, little endian: the packet's bytes).
WAVEFORM_FIELDS: Final = (("wave_start_m", "f8"), ("wave_location_ps", "f4"),
                          ("wave_dx", "f4"), ("wave_dy", "f4"), ("wave_dz", "f4"),
                          ("wave_gain", "f8"), ("wave_spacing_ps", "u4"),
                          ("wave", "<u2", (WAVE_SAMPLES,)))

#: One return of a full-waveform run: ``RETURN_POINT_DTYPE`` + ``WAVEFORM_FIELDS``.
#: The LAS writer stores them as point format 9 (.las) or 4 (.laz) wave packets.
WAVEFORM_POINT_DTYPE = np.dtype(RETURN_POINT_DTYPE.descr + list(WAVEFORM_FIELDS))

#: The field names of ``POINT_DTYPE``, in file order.
FIELD_NAMES: tuple[str, ...] = tuple(POINT_DTYPE.names or ())

#: The world-coordinate fields.
XYZ = ("x", "y", "z")


#: Longest description an extra-bytes descriptor holds (LAS 1.4 R15, table 24: 32
#: bytes, NUL-terminated by laspy's writer when shorter).
LAS_DESCRIPTION_BYTES = 32


@dataclass(frozen=True)
class FileField:
    """How one ``POINT_DTYPE`` field is named and stored in files.

    Attributes
    ----------
    field : str
        The ``POINT_DTYPE`` name (in memory).
    name : str
        The name in every file format (LAS dimension, PLY property, NPZ array).
    unit : str
        SI unit ("m", "s", "rad"; "1" for counts, indices and fractions).
    las : str
        How LAS/LAZ stores it: "xyz" (scaled integer coordinates), "standard" (a
        point format 6 dimension of that name) or an extra-bytes type ("f8", "u4", ...).
    old_name : str
        The PLY/NPZ name of files written before this naming (== ``name`` where it
        did not change).
    description : str
        What it is, with its unit in brackets: the description of its LAS extra-bytes
        descriptor (at most 32 bytes).
    """

    field: str
    name: str
    unit: str
    las: str
    old_name: str
    description: str = ""


# DECISION: the LAS names for every format (not the in-memory ones): LAS is the format
# other tools read (CloudCompare, PDAL, laspy users look for gps_time), its standard
# dimensions cannot be renamed, and sensor_x says what sx leaves to guess.
# DECISION (issue 30, compact LAZ for drives): sensor_x/y/z and range are stored as
# float32 extra bytes ("f4"), not float64 as before (LAS_EXTRA_F8 keeps the old types
# for comparison). Precision each needs: they are sensor-frame values, bounded by the
# sensor's range_max (VLP-16 100 m, OS1-64 120 m, the longest TLS, Z+F 5016, 365 m), so
# float32's relative step 2^-23 (IEEE 754; rounding error half of it) is at most
# 2^-23 * 256 m = 31 um below 512 m, and 2^-23 * 128 m = 15 um at the 100-200 m of a
# mobile lidar: below the 0.1 mm LAS coordinate scale (LAS_SCALE) the world x, y, z are
# stored in and one to two orders below any sensor's range noise (mm to cm). Not
# scaled int32 (0.1 mm, LAS 1.4 R15 table 24 scale/offset): measured on 10 s of a
# VLP-16 drive in the bfo preset (2.87M points, these four fields alone in LAZ) it
# compresses further (16.6 bytes/point against 21.1 for float32 and 35.7 for float64)
# but rounds by up to 50 um, and every reader must apply the descriptor's scale (a
# raw-record reader or a tool that ignores it is off by 10^4); float32 is a plain cast
# of the POINT_DTYPE value that every LAS reader takes as it is. azimuth, elevation
# and incidence were float32 already (|angle| < 4 rad: step 2^-22 rad, rounding at most
# 1.2e-7 rad, 12 um of arc at 100 m); channel, column, frame stay uint32, triangle
# int32, flag uint8 (exact integers, unchanged). Drives' 91-byte LAS records ("full")
# become 75 bytes (-16). PLY, NPZ and memory keep float64:
# they are the exact record of the simulation and cost no LAZ context.
FILE_FIELDS: tuple[FileField, ...] = (
    FileField("x", "x", "m", "xyz", "x", "world x [m]"),
    FileField("y", "y", "m", "xyz", "y", "world y [m]"),
    FileField("z", "z", "m", "xyz", "z", "world z [m]"),
    FileField("sx", "sensor_x", "m", "f4", "sx", "x in sensor frame [m]"),
    FileField("sy", "sensor_y", "m", "f4", "sy", "y in sensor frame [m]"),
    FileField("sz", "sensor_z", "m", "f4", "sz", "z in sensor frame [m]"),
    FileField("range", "range", "m", "f4", "range", "measured range [m]"),
    FileField("azimuth", "azimuth", "rad", "f4", "azimuth", "beam azimuth, sensor [rad]"),
    FileField("elevation", "elevation", "rad", "f4", "elevation",
              "beam elevation, sensor [rad]"),
    FileField("time", "gps_time", "s", "standard", "time", "pulse time [s]"),
    FileField("channel", "channel", "1", "u4", "channel", "laser channel [index]"),
    FileField("column", "column", "1", "u4", "column", "firing in sweep [index]"),
    FileField("frame", "frame", "1", "u4", "frame", "sweep number [index]"),
    FileField("intensity", "intensity", "1", "standard", "intensity",
              "intensity [fraction 0-1]"),
    FileField("incidence", "incidence", "rad", "f4", "incidence",
              "incidence angle [rad]"),
    FileField("triangle", "triangle", "1", "i4", "triangle",
              "mesh face hit, -1 none [index]"),
    FileField("flag", "flag", "1", "u1", "flag", "1 surf 2 particle 3 mix [code]"),
)

#: ``POINT_DTYPE`` field -> its name in files.
FILE_NAMES: dict[str, str] = {f.field: f.name for f in FILE_FIELDS}

#: Unit of every ``POINT_DTYPE`` field ("1" for counts, indices and fractions); the
#: module docstring gives each field's meaning. Angles are radians.
FIELD_UNITS: dict[str, str] = {f.field: f.unit for f in FILE_FIELDS}

#: Description, with its unit in brackets, of every extra dimension tunnelsim writes
#: into LAS/LAZ (the simulation's fields, ``compare``'s distances, ``m3c2``'s
#: results, ``preprocess``'s counts): the 32-byte description of its extra-bytes
#: descriptor (LAS 1.4 R15, 2.6 and table 24), which has no unit of its own.
#: ``LasWriter`` and ``output_header`` fill it in (``las_description``).
LAS_DESCRIPTIONS: dict[str, str] = {
    **{f.name: f.description for f in FILE_FIELDS if f.las not in ("xyz", "standard")},
    # compare (C2C unsigned, C2M signed) and m3c2 (signed along the normal)
    "distance": "distance to reference [m]",
    "dx": "x of distance vector [m]",
    "dy": "y of distance vector [m]",
    "dz": "z of distance vector [m]",
    "lod": "M3C2 level of detection 95% [m]",
    "significant": "|distance| > lod [0/1]",
    "spread1": "M3C2 spread, epoch 1 [m]",
    "spread2": "M3C2 spread, epoch 2 [m]",
    "n1": "M3C2 points, epoch 1 [count]",
    "n2": "M3C2 points, epoch 2 [count]",
    "nx": "M3C2 normal x [unit vector]",
    "ny": "M3C2 normal y [unit vector]",
    "nz": "M3C2 normal z [unit vector]",
    "voxel_count": "input points in voxel [count]",
    # multiple returns (RETURN_POINT_DTYPE; sensors.writers.LAS_ECHO_EXTRA)
    "echo_width": "echo Gaussian sigma [m]",
    "echo_amplitude": "echo peak [relative power]",
}


def las_description(name: str) -> str:
    """The extra-bytes description of a dimension tunnelsim writes (``LAS_DESCRIPTIONS``),
    "" for a name it does not know.

    >>> las_description("lod")
    'M3C2 level of detection 95% [m]'
    """
    return LAS_DESCRIPTIONS.get(name, "")


def field_offset(dtype: np.dtype, name: str) -> int:
    """Byte offset of field ``name`` in the records of the structured ``dtype``."""
    fields = dtype.fields
    if fields is None or name not in fields:
        raise KeyError(f"Expected a field {name!r} in {dtype}, got none.")
    return int(fields[name][1])


#: ``POINT_DTYPE``'s layout under the file names: a chunk viewed with it is written to
#: PLY or NPZ without a copy.
FILE_DTYPE = np.dtype({"names": [FILE_NAMES[n] for n in FIELD_NAMES],
                       "formats": [POINT_DTYPE[n] for n in FIELD_NAMES],
                       "offsets": [field_offset(POINT_DTYPE, n) for n in FIELD_NAMES],
                       "itemsize": POINT_DTYPE.itemsize})

#: LAS extra bytes of the "full" layout, in record order: (file name, POINT_DTYPE
#: field, stored type).
LAS_EXTRA: tuple[tuple[str, str, str], ...] = tuple(
    (f.name, f.field, f.las) for f in FILE_FIELDS if f.las not in ("xyz", "standard"))

#: ``LAS_EXTRA`` with the types of files written before issue 30 (sensor_x, sensor_y,
#: sensor_z and range as float64): readers take both; benchmarks compare the sizes.
LAS_EXTRA_F8: tuple[tuple[str, str, str], ...] = tuple(
    (n, f, "f8" if n in ("sensor_x", "sensor_y", "sensor_z", "range") else t)
    for n, f, t in LAS_EXTRA)

#: Extra bytes of the "compact" LAS layout (the default for TLS stations, whose
#: sensor-frame coordinates, range and angles follow from the world point and the
#: station pose stored in the tunnelsim VLR).
LAS_COMPACT: tuple[str, ...] = ("channel", "column", "triangle", "flag")

_BY_NAME = {**{f.old_name: f.field for f in FILE_FIELDS},
            **{f.name: f.field for f in FILE_FIELDS}}

# Import-time guard: FILE_FIELDS lists every field once, in record order (the order
# of LAS extra bytes, PLY properties and NPZ arrays).
if tuple(FILE_NAMES) != FIELD_NAMES or len(set(FILE_NAMES.values())) != len(FILE_FIELDS):
    raise AssertionError("FILE_FIELDS must name every POINT_DTYPE field once, in order")
if any(len(d.encode()) > LAS_DESCRIPTION_BYTES or "[" not in d
       for d in LAS_DESCRIPTIONS.values()):
    raise AssertionError("LAS_DESCRIPTIONS must fit 32 bytes and name a [unit]")


def point_field(name: str) -> str | None:
    """The ``POINT_DTYPE`` field a file's dimension, property or array ``name`` holds
    (the current file name or the one of earlier versions; case as written), or None
    for a name that is not one of tunnelsim's.

    >>> point_field("sensor_x"), point_field("sx"), point_field("gps_time")
    ('sx', 'sx', 'time')
    """
    return _BY_NAME.get(name)


def file_records(points: np.ndarray) -> np.ndarray:
    """The records ``points`` (n,) with the file names (``FILE_DTYPE``): a view of an
    array of exactly ``POINT_DTYPE``, else a copy of its ``POINT_DTYPE`` fields."""
    pts = np.asarray(points)
    if pts.dtype == POINT_DTYPE:
        return pts.view(FILE_DTYPE)
    out = np.empty(pts.shape, dtype=FILE_DTYPE)
    for n in FIELD_NAMES:
        out[FILE_NAMES[n]] = pts[n]
    return out
