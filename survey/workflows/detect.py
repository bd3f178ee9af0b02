"""The detectability study (issue 17) as one library call: ``detect_study`` lays known
deformations on a tunnel, scans it as built and deformed with each sensor at each
station spacing (TLS) or speed (MLS) and noise factor, runs M3C2, and writes what
``tunnelsim detect`` writes (detect.json, detect.csv, targets.csv, detect.md and .html,
detect.png); it returns the rows and the paths.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from raytrace.fileio import write_json
from sensors import SensorSpec, load_sensor
from survey.analysis.detectability import Detectability, DetectRow
from survey.analysis.detect_layout import DetectLayout
from survey.analysis.m3c2 import M3C2Params
from survey.errors import StudyError
from survey.report.detectability import (
    detect_csv,
    detect_markdown,
    detect_summary,
    plot_detectability,
    targets_csv,
)
from survey.report.header import write_headed_report
from survey.world.mesh import read_tunnel
from survey.world.presets import preset as make_preset
from survey.workflows.files import output_folder, write_text_file

__all__ = ["DETECT_FILES", "FULL", "QUICK", "DetectResult", "detect_study"]

PathLike = str | Path

#: Defaults of the full study and of ``quick=True`` (a value given wins). Magnitudes
#: in mm (converted as the command line converts ``--magnitudes``), the rest SI.
#: DECISION: quick is a tbm-like tube of coarse edges (0.2 m), a compact layout and
#: TLS preview scans: 2 noise factors x 4 epochs of 3 preview stations take about a
#: minute on 2 shared cores, enough for the tests and the demo.
FULL: dict[str, Any] = {
    "preset": "tbm", "edge_length_m": 0.1, "resolution": "middle", "zone_m": 5.0,
    "taper_m": 0.5, "gap_m": 1.0, "bulge_radius_m": 0.5, "reference_m": 2.0,
    "core_spacing_m": 0.1, "magnitudes_mm": (1.0, 2.0, 5.0, 10.0),
    "spacings_m": (10.0, 20.0), "speeds_mps": (1.0, 3.0), "noises": (0.5, 1.0, 2.0)}
QUICK: dict[str, Any] = {
    "preset": "tbm", "edge_length_m": 0.2, "resolution": "preview", "zone_m": 2.0,
    "taper_m": 0.25, "gap_m": 0.5, "bulge_radius_m": 0.4, "reference_m": 1.5,
    "core_spacing_m": 0.15, "magnitudes_mm": (2.0, 5.0, 10.0), "spacings_m": (10.0,),
    "speeds_mps": (3.0,), "noises": (1.0, 30.0)}
#: The files ``detect_study`` writes into its folder (and detect.html beside detect.md).
DETECT_FILES = ("detect.json", "detect.csv", "targets.csv", "detect.md", "detect.png")


@dataclass(frozen=True)
class DetectResult:
    """What ``detect_study`` computed and wrote.

    Attributes
    ----------
    study : Detectability, the tunnel, layout, M3C2 parameters and seed
    rows : tuple of DetectRow, one per configuration (sensor x speed/spacing x noise)
    markdown : str
        The report's Markdown without its header block (what ``tunnelsim detect``
        prints).
    folder : Path, the output folder
    json_path, csv_path, targets_path, report_path, plot_path : Path
        detect.json, detect.csv, targets.csv, detect.md (its HTML beside it),
        detect.png in ``folder``.
    """

    study: Detectability
    rows: tuple[DetectRow, ...]
    markdown: str
    folder: Path
    json_path: Path
    csv_path: Path
    targets_path: Path
    report_path: Path
    plot_path: Path


def _sensors(sensors: str | Sequence[str | SensorSpec]
             ) -> tuple[list[SensorSpec], str]:
    """The sensor specs and how the header names them."""
    if isinstance(sensors, str):
        names: list[Any] = [n.strip() for n in sensors.split(",") if n.strip()]
        words = sensors
    else:
        names = list(sensors)
        words = ",".join(s.name if isinstance(s, SensorSpec) else str(s) for s in names)
    if not names:
        raise StudyError(f"Expected --sensor NAME[,NAME...], got {sensors!r}.")
    return [s if isinstance(s, SensorSpec) else load_sensor(s) for s in names], words


def detect_study(output: PathLike, *, mesh: PathLike | None = None,
                 preset: str | None = None, edge_length_m: float | None = None,
                 sensors: str | Sequence[str | SensorSpec] = "zf_imager_5016",
                 spacings_m: Sequence[float] | None = None,
                 speeds_mps: Sequence[float] | None = None,
                 noises: Sequence[float] | None = None,
                 magnitudes_m: Sequence[float] | None = None, start_m: float | None = None,
                 zone_m: float | None = None, taper_m: float | None = None,
                 gap_m: float | None = None, bulge_radius_m: float | None = None,
                 reference_m: float | None = None, resolution: str | None = None,
                 rate_hz: float | None = None, height_m: float | None = None,
                 core_spacing_m: float | None = None, cyl_radius_m: float = 0.1,
                 max_depth_m: float = 0.1, normal_radii_m: Sequence[float] = (0.25,),
                 reg_error_m: float = 0.0, quick: bool = False, force: bool = False,
                 seed: int = 0, project: str | None = None, instrument: str | None = None,
                 progress: Callable[[int, int], None] | None = None) -> DetectResult:
    """Detectability study: the smallest deformation a survey detects, and its false
    alarms (``tunnelsim detect``).

    A radial convergence zone and a ring of bulges at each magnitude are laid beside
    undeformed lining; each configuration scans the tunnel as built and deformed, runs
    M3C2 (normals towards the axis) and reports the smallest magnitude detected at
    >= 95 % of the deformed region's core points (``|d|`` > LoD95, d > 0), its a-hat vs a
    estimate (MIL-HDBK-1823A) and the false-alarm rate on undeformed lining.

    Parameters
    ----------
    output : path-like
        The output folder (created; a non-empty one only with ``force``).
    mesh : path-like, optional
        A generated tunnel (.ply with its .json); else the tunnel ``preset``.
    preset : {"bfo", "tbm"}, optional
        The preset to generate (default tbm).
    edge_length_m : float, optional
        With a preset: its lining edge length (m; default 0.1, quick 0.2).
    sensors : str or sequence of str or SensorSpec
        Sensor names or .toml files, as a sequence or comma-separated.
    spacings_m : sequence of float, optional
        TLS station spacings (m; default 10, 20; quick 10). Used when a sensor is a TLS.
    speeds_mps : sequence of float, optional
        Speeds of moving sensors (m/s; default 1, 3; quick 3).
    noises : sequence of float, optional
        Factors on each sensor's range and angle noise (default 0.5, 1, 2; quick 1, 30).
    magnitudes_m : sequence of float, optional
        Deformation magnitudes (m; default 1, 2, 5, 10 mm; quick 2, 5, 10 mm).
    start_m : float, optional
        Chainage where the layout starts (default: centred in the tunnel, to 1 cm).
    zone_m, taper_m, gap_m, bulge_radius_m, reference_m : float, optional
        The layout (``DetectLayout.build``; defaults ``FULL``, or ``QUICK``).
    resolution : str, optional
        TLS resolution preset (default middle; quick preview).
    rate_hz : float, optional
        Rotation / profile rate of moving sensors (default: the sensor's).
    height_m : float, optional
        Sensor height above the floor (default 1.5 TLS, 1.0 moving).
    core_spacing_m : float, optional
        Core points: one per cube of this size (m) of epoch 1 (default 0.1; quick 0.15).
    cyl_radius_m, max_depth_m, normal_radii_m, reg_error_m : float
        M3C2 cylinder radius, half-length, normal radii and registration error (m).
    quick : bool
        Take the defaults of the small study (``QUICK``, about a minute).
    force : bool
        Write into a non-empty folder (its files are replaced one by one).
    seed : int
        Seed of the preset's roughness and of the scans' noise.
    project, instrument : str, optional
        The user's words the report header states.
    progress : callable, optional
        Called with (configurations done, total) after each configuration.

    Returns
    -------
    DetectResult

    Raises
    ------
    StudyError
        Bad values, a layout outside the tunnel, a mesh that is no generated tunnel,
        an output that is a file or a non-empty folder without ``force``.
    sensors.SensorSpecError
        An unknown sensor.

    Examples
    --------
    >>> res = detect_study("det", quick=True)              # doctest: +SKIP
    >>> sorted(p.name for p in res.folder.iterdir())       # doctest: +SKIP
    ['detect.csv', 'detect.html', 'detect.json', 'detect.md', 'detect.png', 'targets.csv']
    """
    dflt = QUICK if quick else FULL

    def get(name: str, value: Any) -> Any:
        return dflt[name] if value is None else value

    specs, words = _sensors(sensors)
    mags = [float(m) for m in magnitudes_m] if magnitudes_m is not None else \
        [m / 1000.0 for m in dflt["magnitudes_mm"]]
    noise = [float(k) for k in get("noises", noises)]
    spacings = [float(s) for s in get("spacings_m", spacings_m)] \
        if any(s.kind == "tls" for s in specs) else []
    speeds = [float(v) for v in get("speeds_mps", speeds_mps)] \
        if any(s.kind != "tls" for s in specs) else []
    name = preset or dflt["preset"]
    if mesh is not None:
        if edge_length_m is not None or preset is not None:
            raise StudyError("Expected edge_length_m and preset only without mesh (a "
                             "mesh has its own edges), got them with mesh.")
        tunnel = read_tunnel(mesh)
    else:
        tunnel, _ = make_preset(name, edge_length_m=get("edge_length_m", edge_length_m),
                                seed=seed)
    kw = dict(zone_m=get("zone_m", zone_m), taper_m=get("taper_m", taper_m),
              gap_m=get("gap_m", gap_m), bulge_radius_m=get("bulge_radius_m",
                                                            bulge_radius_m),
              reference_m=get("reference_m", reference_m))
    start = start_m
    if start is None:
        probe = DetectLayout.build(0.0, mags, **kw)
        c0, c1 = tunnel.alignment.chainage_range
        start = round(0.5 * (c0 + c1) - 0.5 * probe.length_m, 2)
    layout = DetectLayout.build(start, mags, **kw)
    prm = M3C2Params(cyl_radius_m, max_depth_m, tuple(float(r) for r in normal_radii_m),
                     reg_error_m)
    study = Detectability(tunnel, layout, params=prm,
                          core_spacing_m=get("core_spacing_m", core_spacing_m), seed=seed)
    out = output_folder(output, force=force, error=StudyError)
    res = get("resolution", resolution)
    rows = study.grid(specs, speeds_mps=speeds, spacings_m=spacings, noises=noise,
                      progress=progress, resolution=res, rate_hz=rate_hz,
                      height_m=height_m)
    paths = [out / f for f in DETECT_FILES]
    write_json(paths[0], detect_summary(study, rows, extra={
        "quick": bool(quick), "resolution": res, "rate_hz": rate_hz}))
    write_text_file(paths[1], detect_csv(rows))
    write_text_file(paths[2], targets_csv(rows))
    md = detect_markdown(study, rows)
    plot_detectability(rows, paths[4])
    write_headed_report(paths[3], md, inputs=[("mesh", mesh, "")] if mesh else [],
                        crs_from=[mesh] if mesh else [],
                        settings=[("sensors", words),
                                  ("tunnel", "the mesh" if mesh else f"preset {name}")],
                        project=project, instrument=instrument)
    return DetectResult(study, tuple(rows), md, out, *paths)
