"""A drive split into time windows, simulated on any ``Executor`` and written tiled (one
file per window and a manifest) or merged (one file, the same as the whole drive's).

Windows are ranges of pulse indices: window k holds the whole columns (spinning lidar),
profiles (profiler) or lines (TLS) that start in [t0 + k W, t0 + (k + 1) W), so every
pulse is in exactly one window. Each worker rebuilds the drive (``simulate_drive`` with
the same arguments) and simulates only its range (``Run.chunks(start, stop)``); since
each pulse's random numbers are keyed by its index, the windows' points, concatenated,
are the whole drive's, whatever the window length.
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .campaign import MANIFEST_NAME, sha256_of
from .execution import ClusterError, Executor, SceneRef

__all__ = ["DRIVE_MANIFEST_FORMAT", "Window", "drive_windows", "simulate_windows"]

#: ``format`` of a windowed drive's manifest.
DRIVE_MANIFEST_FORMAT = "tunnelsim-drive-windows/1"
#: Rows handed to the writer at a time when the windows are merged.
MERGE_ROWS = 1 << 20


@dataclass(frozen=True)
class Window:
    """Pulses ``first_pulse`` to ``stop_pulse`` - 1 of a drive: those of the columns
    (profiles, lines) starting in [``start_s``, ``end_s``) (trajectory time, s)."""

    index: int
    start_s: float
    end_s: float
    first_pulse: int
    stop_pulse: int


def _units(run: Any) -> tuple[float, int, int]:
    """(period of a pattern unit in s, units, pulses per unit) of a run's pattern: a
    column of a spinning lidar, a profile, a TLS line."""
    from sensors.patterns import ProfileScan, SpinningScan, TLSScan

    scan = run.scan
    if isinstance(scan, SpinningScan):
        return float(scan.T), int(scan.n_columns), int(scan.spec.channels)
    if isinstance(scan, ProfileScan):
        return 1.0 / float(scan.pattern.profile_rate_hz), int(scan.n_profiles), \
            int(scan.points_per_profile)
    if isinstance(scan, TLSScan) and scan.window is None:
        return scan.n_slots / scan.rate_hz, int(scan.n_lines), int(scan.points_per_line)
    raise ClusterError(f"Expected a spinning lidar, a profiler or a full TLS station to "
                       f"split into windows, got {type(scan).__name__} with a scan window; "
                       "run it without --window-s.")


def drive_windows(run: Any, window_s: float) -> list[Window]:
    """The windows of ``window_s`` seconds of a drive (``sensors.simulate_drive``'s
    Run), in time order; together they hold every pulse once.

    Raises
    ------
    ClusterError
        ``window_s`` not positive and finite, or a pattern that cannot be split.
    """
    if not (isinstance(window_s, (int, float)) and math.isfinite(window_s) and
            window_s > 0):
        raise ClusterError(f"Expected a positive window length in seconds, got "
                           f"{window_s!r}.")
    period, units, per = _units(run)
    count = max(1, math.ceil(run.duration_s / window_s - 1e-9))
    # DECISION: cut at whole columns (profiles, lines): a unit starting before the
    # edge stays whole in the window it starts in, so a sweep is never split across
    # files; the edge's 1e-9 guards k W / T landing a rounding below a whole number.
    cuts = [min(units, math.ceil(k * window_s / period - 1e-9)) for k in range(count)]
    cuts.append(units)
    out: list[Window] = []
    for k in range(count):
        a, b = cuts[k], cuts[k + 1]
        if b > a:
            out.append(Window(len(out), run.t0 + k * window_s,
                              min(run.t0 + (k + 1) * window_s, run.t0 + run.duration_s),
                              a * per, b * per))
    return out


@dataclass(frozen=True)
class _DriveJob:
    """What one worker needs for one window (picklable)."""

    window: Window
    scene: SceneRef
    sensor: Any
    trajectory: Any
    mount: Any
    settings: Any
    seed: int
    reflectivity: float
    t_start: float | None
    t_end: float | None
    path: str
    tiled: bool
    fields: str | None
    crs: Any


def _rebuild(job: _DriveJob) -> Any:
    from sensors import simulate_drive

    scene, refl = job.scene.load()
    return simulate_drive(scene, job.sensor, job.trajectory, job.mount,
                          settings=job.settings, seed=job.seed,
                          reflectivity=refl if refl is not None else job.reflectivity,
                          t_start=job.t_start, t_end=job.t_end)


def drive_window_job(job: _DriveJob) -> dict[str, Any]:
    """Simulate one window (runs on a worker): a point file (tiled) or the raw records
    for the merge; its manifest row."""
    from raytrace.fileio import atomic_writer

    run = _rebuild(job)
    w = job.window
    count = [0]

    def counted() -> Iterator[NDArray[np.void]]:
        for c in run.chunks(w.first_pulse, w.stop_pulse):
            count[0] += len(c)
            yield c

    if job.tiled:
        run.write(job.path, points=counted(), fields=job.fields,
                  **({} if job.crs is None else {"crs": job.crs}))
    else:
        with atomic_writer(job.path) as fh:
            for c in counted():
                fh.write(np.ascontiguousarray(c).data)
    return {"window": w.index, "start_s": w.start_s, "end_s": w.end_s,
            "first_pulse": w.first_pulse, "stop_pulse": w.stop_pulse,
            "file": Path(job.path).name, "points": count[0],
            "sha256": sha256_of(job.path) if job.tiled else None}


def _merged(parts: list[Path]) -> Iterator[NDArray[np.void]]:
    """The windows' raw records, in order, ``MERGE_ROWS`` at a time (memory-mapped)."""
    from sensors.io.fields import POINT_DTYPE

    for p in parts:
        if p.stat().st_size == 0:
            continue
        rec = np.memmap(p, dtype=POINT_DTYPE, mode="r")
        for i in range(0, len(rec), MERGE_ROWS):
            yield np.array(rec[i:i + MERGE_ROWS])
        del rec


def simulate_windows(run: Any, window_s: float, output: str | os.PathLike[str], *,
                     reflectivity: NDArray[np.float64] | float | None = None,
                     executor: Executor | None = None, tiled: bool = False,
                     fmt: str = "laz", fields: str | None = None, crs: Any = None,
                     progress: Callable[[int, int], None] | None = None
                     ) -> dict[str, Any]:
    """Simulate a drive ``run`` (from ``sensors.simulate_drive``) in windows of
    ``window_s`` seconds on ``executor`` and write it.

    Parameters
    ----------
    run : sensors.Run
        The drive as it would run in one piece; its scene, sensor, trajectory, mount,
        settings, seed and time span are what every window rebuilds.
    window_s : float > 0
    output : str or path
        Merged: the point file (any format ``Run.write`` writes), the same bytes as
        ``run.write(output)``. Tiled: a folder (created if missing) that receives
        ``window_000.<fmt>`` ... and ``manifest.json``.
    reflectivity : (n_faces,) float64 or float, optional
        What ``run`` was given as ``reflectivity`` (the workers rebuild it; a per-face
        array ships with the scene).
    executor : Executor, optional
        This process by default.
    tiled : bool
    fmt : str
        The tiles' format (tiled only).
    fields, crs
        As for ``Run.write``.
    progress : callable(done, total), optional
        Called as windows finish.

    Returns
    -------
    dict
        The manifest (tiled: also written as ``manifest.json``): the windows with
        their pulse ranges, points and (tiled) files and SHA-256; merged: the file's
        SHA-256.
    """
    from raytrace.fileio import write_json

    ex = Executor() if executor is None else executor
    wins = drive_windows(run, window_s)
    out = Path(output)
    folder = out if tiled else out.parent
    if tiled:
        folder.mkdir(exist_ok=True)
    if not folder.is_dir():
        raise ClusterError(f"Expected an existing output folder, got '{folder}'; create "
                           "it first.")
    per_face = reflectivity is not None and np.ndim(reflectivity) > 0
    ref = ex.share_scene(run.scene, np.asarray(reflectivity, dtype=np.float64)
                         if per_face else None, folder)
    rho = float(reflectivity) if reflectivity is not None and not per_face else \
        float(run.settings.reflectivity)
    digits = max(3, len(str(len(wins) - 1)))
    names = [f"window_{w.index:0{digits}d}.{fmt}" if tiled else
             f".{out.name}.window{w.index:0{digits}d}.raw" for w in wins]
    span = (run.t0, run.t0 + run.duration_s)
    jobs = [_DriveJob(w, ref, run.sensor, run.trajectory, run.mount, run.settings,
                      run.seed, rho, span[0], span[1],
                      str((folder / n).resolve()), tiled, fields, crs)
            for w, n in zip(wins, names)]
    rows = ex.map(drive_window_job, jobs, progress=progress)
    manifest: dict[str, Any] = {
        "format": DRIVE_MANIFEST_FORMAT, "sensor": run.sensor.name, "seed": run.seed,
        "window_s": float(window_s), "span_s": list(span), "pulses": int(run.n_pulses),
        "points": int(sum(r["points"] for r in rows)), "tiled": tiled, "windows": rows}
    if tiled:
        write_json(folder / MANIFEST_NAME, manifest)
        return manifest
    parts = [folder / n for n in names]
    try:
        run.write(out, points=_merged(parts), fields=fields,
                  **({} if crs is None else {"crs": crs}))
    finally:
        for p in parts:
            p.unlink(missing_ok=True)
    for r in rows:
        r["file"] = None
    manifest.update(file=out.name, sha256=sha256_of(out))
    return manifest
