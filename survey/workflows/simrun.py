"""A simulated run as ``tunnelsim scan`` and ``tunnelsim drive`` write it: what the scan
workflows (``survey.workflows.scan``) and the drive workflow (``survey.workflows.drive``)
share.

- ``RunOutput``: what writing a run gave (the file, pulses, points, hit ratio, time,
  rate); ``write_run`` writes one through ``Run.write``, ``run_output`` reads it from a
  writer's stats.
- ``check_returned``: the guard against a run that returned no point (or too few).
- ``sensor_spec``, ``physics_settings``, ``output_crs``: a run's sensor, physics and the
  CRS its output states.
- ``xyz_text``, ``box_text``, ``number_text``: positions and numbers in the messages.

DECISION: nothing heavy is imported at module level (NumPy, SciPy, the simulator are
imported where they run): the scan and drive command modules import their workflow
module (and so this one) on every ``tunnelsim`` start, which must not load NumPy.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from sensors.errors import SimulationError

if TYPE_CHECKING:
    from sensors.simulate import Run
    from sensors.spec_types import SensorSpec

#: A callback ``progress(done, total)`` after each chunk (pulses) or task (stations).
ProgressFn = Callable[[int, int], None]


# ---------------------------------------------------------------------------- results
@dataclass(frozen=True)
class RunOutput:
    """What writing a simulated run gave.

    Attributes
    ----------
    path : Path
        The file (or bag folder) written.
    pulses, points : int
        Pulses cast, points written.
    hit_ratio : float
        Share of the pulses that hit a surface (NaN for a drive in time windows).
    seconds : float
        Simulation time (s; NaN for a drive in time windows): casting the pulses and
        writing the points, not a drive's camera frames (``survey.workflows.drive.
        CameraRun.seconds``), even where they are rendered among the points (a bag).
    rays_per_s : float
        Rays cast per second of ``seconds`` (NaN for a drive in time windows).
    """

    path: Path
    pulses: int
    points: int
    hit_ratio: float
    seconds: float
    rays_per_s: float



def output_crs(mesh: str | os.PathLike[str], crs: str | None = None, *,
               tunnel_json: str | os.PathLike[str] | None = None) -> str | None:
    """The CRS a simulation's output states: ``crs`` (``--crs``), else the mesh's (its
    tunnel JSON's ``crs``, or a ``<mesh>.prj`` sidecar), else None.

    Raises
    ------
    sensors.io.crs.CRSError
        For a ``crs`` that pyproj cannot read, or one against the mesh's own.
    """
    from sensors.io.cloudread import cloud_crs_text
    from sensors.io.crs import CRSError, mismatch_message, parse_crs, same_crs
    from sensors.io.tunnel_json import read_meta, tunnel_crs

    where = str(tunnel_json or mesh)
    stated = tunnel_crs(read_meta(Path(tunnel_json))) if tunnel_json else \
        cloud_crs_text(mesh)
    if crs is None:
        return stated
    parsed = parse_crs(crs, what="--crs")
    if stated is not None and not same_crs(parsed, stated):
        raise CRSError(mismatch_message(("--crs", parsed), (where, stated),
                                        what="output and the mesh",
                                        hint="leave --crs out to take the mesh's"))
    return parsed


def box_text(lo: Any, hi: Any) -> str:
    """A box ``lo``-``hi`` (each (3,) float, m) as ``xyz_text`` writes its corners."""
    return f"{xyz_text(lo)}-{xyz_text(hi)}"


def xyz_text(p: Any) -> str:
    """(x, y, z) to the millimetre (a BVH box is padded by ~1e-6 of its size)."""
    return "(" + ", ".join(f"{round(float(c), 3) + 0.0:.10g}" for c in p) + ")"


def number_text(x: float) -> str:
    """``x`` as a user would type it: ``10`` for 10.0, ``0.1`` for 0.1."""
    short = f"{x:g}"
    return short if float(short) == x else repr(float(x))


def run_output(stats: dict[str, Any], path: str | os.PathLike[str]) -> RunOutput:
    """The ``RunOutput`` of a writer's ``stats`` (``Run.write``'s: pulses, points,
    hit_ratio, seconds, rays_per_s) for the file ``path``."""
    return RunOutput(Path(path), int(stats["pulses"]), int(stats["points"]),
                     float(stats["hit_ratio"]), float(stats["seconds"]),
                     float(stats["rays_per_s"]))


def check_returned(label: str, pulses: int, points: int, min_return: float,
                   where: str, *, share: bool = True) -> None:
    """Refuse a run that returned no point, or fewer than ``min_return`` of its pulses
    (``where`` says what the caller knows: the poses, the mesh's box; ``share``: say
    the share returned)."""
    if points == 0 or points < min_return * pulses:
        said = f" ({100 * points / max(pulses, 1):.2g} % returned, below " \
               f"{100 * min_return:g} %)" if points and share else ""
        raise SimulationError(f"Expected the {label} to see the mesh, got {points:,} "
                              f"points from {pulses:,} pulses{said}{where}.")


def write_run(run: Run, output: str | os.PathLike[str], *, fields: str | None,
              crs: Any, progress: ProgressFn | None,
              bag: dict[str, Any] | None = None,
              waveform_data: str | None = None) -> RunOutput:
    """Write ``run`` to ``output`` with ``Run.write`` (which refuses a waveform run into
    a bag); a drive's bag in its robot's frames is ``survey.workflows.robotbag``'s."""
    wave: dict[str, Any] = {} if waveform_data is None else \
        {"waveform_data": waveform_data}
    # A drifted run (slam_drift) states no CRS, and its write takes none.
    stats = run.write(output, progress=progress, fields=fields,
                      **({} if crs is None else {"crs": crs}), **(bag or {}), **wave)
    return run_output(stats, output)


def physics_settings(settings: Any) -> Any:
    """``settings`` (``sensors.Settings``), or the default ``Settings()`` for None."""
    from sensors import Settings

    return Settings() if settings is None else settings


def sensor_spec(sensor: str | os.PathLike[str] | SensorSpec, rate_hz: float | None = None
                ) -> SensorSpec:
    """A sensor's spec from its name, a TOML file or a loaded spec; at the rotation
    (profile) rate ``rate_hz`` instead of its own when given
    (``sensors.spec.with_rate``)."""
    from sensors import load_sensor
    from sensors.spec_types import SensorSpec
    from sensors.spec import with_rate

    spec = sensor if isinstance(sensor, SensorSpec) else load_sensor(sensor)
    return spec if rate_hz is None else with_rate(spec, rate_hz)


__all__ = ["ProgressFn", "RunOutput", "box_text", "check_returned", "number_text",
           "output_crs", "physics_settings", "run_output", "sensor_spec", "write_run",
           "xyz_text"]
