"""The ``tunnelsim`` command.

Errors a user can fix (``TunnelsimError`` and bad arguments) print one line on stderr and
exit with status 2; ``--debug`` shows the traceback instead.
"""

from __future__ import annotations

import argparse
import sys
from importlib import metadata

from raytrace.errors import TunnelsimError
from survey.errors import TunnelsimCLIError

EXIT_USAGE = 2


class _Parser(argparse.ArgumentParser):
    """argparse that reports a usage error as one line (and exit 2), like every other
    error of the command."""

    def error(self, message):  # noqa: D401 - argparse API
        raise _UsageError(f"{self.prog}: {message} (see '{self.prog} --help')")


class _UsageError(Exception):
    pass


def _version() -> str:
    try:
        return metadata.version("tunnelsim")
    except metadata.PackageNotFoundError:  # running from a source tree
        return "0+unknown"


def _parse_window(text, what, n):
    """'A:B:C' -> floats, with a one-line error naming the option."""
    parts = text.split(":")
    try:
        vals = [float(v) for v in parts]
    except ValueError:
        vals = []
    if len(vals) != n:
        raise TunnelsimCLIError(f"Expected {what}, got {text!r}.")
    return vals


def _xyz(text, what):
    return _parse_window(text.replace(",", ":"), f"{what} as X,Y,Z in metres", 3)


def _physics_options(p):
    p.add_argument("--ideal", action="store_true",
                   help="exact geometry: no noise, no jitter, every return detected")
    p.add_argument("--no-noise", action="store_true", help="no range noise, no angle jitter")
    p.add_argument("--no-detection", action="store_true",
                   help="keep every return within range (no detection probability)")
    p.add_argument("--beam-subrays", type=int, default=1, choices=[1, 7, 19],
                   help="sub-rays per pulse for beam divergence (default 1: off)")
    p.add_argument("--mixed", default="average", choices=["average", "strongest"],
                   help="how sub-returns combine (default average)")
    p.add_argument("--attenuation", type=float, default=0.0, metavar="PER_M",
                   help="dust/fog extinction coefficient in 1/m (default 0)")
    p.add_argument("--particles", type=float, default=0.0, metavar="PER_M",
                   help="rate of airborne-particle returns per metre (default 0)")
    p.add_argument("--reflectivity", type=float, default=0.5,
                   help="reflectivity where the mesh has none (default 0.5)")
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    p.add_argument("--threads", type=int, help="Numba threads (default: all cores)")
    p.add_argument("--quiet", action="store_true", help="no progress bar or summary")
    p.add_argument("--fields", choices=["compact", "full"],
                   help="LAS/LAZ extra bytes: compact (stations' default) or full (every "
                        "field; moving platforms' default)")
    p.add_argument("-o", "--output", required=True,
                   help="output points: .laz, .las, .ply, .npz (or .e57 for stations)")


def _write_text(path, text):
    from raytrace.fileio import atomic_writer

    from pathlib import Path
    path = Path(path)
    if not path.parent.exists():
        raise TunnelsimCLIError(f"Expected an existing folder for '{path}', got none.")
    with atomic_writer(path, "w") as fh:
        fh.write(text)


def build_parser() -> argparse.ArgumentParser:
    from survey.cli.commands import adjustment, analysis, clouds, runner, scanning, world

    parser = _Parser(
        prog="tunnelsim",
        description="Tunnel digital twins: meshes from laser scans, simulated scanners.",
        epilog="Example: tunnelsim info",
    )
    parser.add_argument("--version", action="version", version=f"tunnelsim {_version()}")
    parser.add_argument("--debug", action="store_true",
                        help="show tracebacks instead of one-line errors")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    p = sub.add_parser("info", help="versions, Numba threading layer and thread count",
                       description="Print versions of tunnelsim and its dependencies, the "
                                   "Numba threading layer and thread count.",
                       epilog="Example: tunnelsim info")
    p.set_defaults(func=world.cmd_info)

    p = sub.add_parser(
        "tunnel", help="generate a tunnel mesh (PLY + JSON metadata)",
        description="Generate a labelled tunnel mesh from a preset: binary PLY with face "
                    "labels and reflectivity, and a JSON file beside it with the alignment, "
                    "profile, features and control points. Optionally a second, deformed "
                    "epoch with the displacement per vertex.",
        epilog="Example: tunnelsim tunnel -o bfo.ply --preset bfo --edge-length 0.08 "
               "--epoch2 bfo_epoch2.ply --convergence 120:160:5")
    p.add_argument("-o", "--output", required=True, help="output mesh (.ply)")
    p.add_argument("--preset", default="bfo", choices=["bfo", "tbm"],
                   help="which tunnel (default: bfo, the seed study's gallery)")
    g = p.add_mutually_exclusive_group()
    g.add_argument("--edge-length", type=float, default=0.1, metavar="M",
                   help="target edge length of the lining in metres (default 0.1)")
    g.add_argument("--triangles", type=int, metavar="N",
                   help="target number of lining triangles instead of an edge length")
    p.add_argument("--roughness-mm", type=float, metavar="MM",
                   help="lining roughness, standard deviation in mm (preset default)")
    p.add_argument("--closed-ends", action="store_true",
                   help="cap both portals (watertight mesh)")
    p.add_argument("--origin", metavar="E,N,H",
                   help="coordinates of the first portal's centreline point, e.g. UTM")
    p.add_argument("--heading-deg", type=float, default=0.0, metavar="DEG",
                   help="initial direction, degrees counter-clockwise from east")
    p.add_argument("--epoch2", metavar="PATH",
                   help="also write a deformed second epoch (.ply + .json)")
    p.add_argument("--convergence", action="append", default=[], metavar="START:END:MM",
                   help="radial convergence in mm between two chainages (repeatable; "
                        "default for --epoch2: the preset's)")
    p.add_argument("--bulge", action="append", default=[],
                   metavar="CHAINAGE:ANGLE_DEG:RADIUS_M:MM",
                   help="local inward bulge at a chainage and angle from the crown")
    p.add_argument("--seed", type=int, default=0, help="roughness seed (default 0)")
    p.add_argument("--quiet", action="store_true", help="print nothing on success")
    p.set_defaults(func=world.cmd_tunnel)

    p = sub.add_parser(
        "scan", help="simulate a TLS station on a mesh",
        description="Simulate a terrestrial laser scanner station on a mesh and stream the "
                    "points to a file (LAS/LAZ, PLY, NPZ, E57).",
        epilog="Example: tunnelsim scan --mesh bfo.ply --sensor zf_imager_5016 "
               "--resolution superhigh --at 150,2,1.5 -o station.laz")
    p.add_argument("--mesh", required=True, help="mesh file (PLY with reflectivity, OBJ, ...)")
    p.add_argument("--sensor", default="zf_imager_5016",
                   help="sensor name ('tunnelsim sensors' lists them) or a .toml file")
    g = p.add_mutually_exclusive_group(required=True)
    g.add_argument("--at", metavar="X,Y,Z", help="station position (m)")
    g.add_argument("--chainage", type=float, metavar="M",
                   help="station on the tunnel axis at this chainage, --height above the "
                        "floor (axis from --tunnel-json or the mesh's .json)")
    p.add_argument("--height", type=float, default=1.5, metavar="M",
                   help="instrument height above the floor with --chainage (default 1.5)")
    p.add_argument("--tunnel-json", help="axis for --chainage (default: the mesh's .json)")
    p.add_argument("--resolution", help="resolution preset of the sensor (e.g. superhigh)")
    p.add_argument("--step-deg", type=float, metavar="DEG",
                   help="angular step in degrees instead of a preset")
    p.add_argument("--heading-deg", type=float, default=0.0, metavar="DEG",
                   help="station heading, degrees counter-clockwise from +x")
    _physics_options(p)
    p.set_defaults(func=scanning.cmd_scan)

    p = sub.add_parser(
        "drive", help="simulate a moving lidar or profiler along a trajectory",
        description="Simulate a sensor on a moving platform: each pulse is cast from the pose "
                    "at its own time (rolling shutter).",
        epilog="Example: tunnelsim drive --mesh bfo.ply --sensor robosense_airy --along "
               "centreline --speed 1 --mount down --lever 0,0,0.5 -o drive.laz")
    p.add_argument("--mesh", required=True, help="mesh file")
    p.add_argument("--sensor", default="robosense_airy", help="sensor name or a .toml file")
    p.add_argument("--trajectory", help="TUM text (t x y z qx qy qz qw) or CSV trajectory")
    p.add_argument("--along", choices=["centreline"],
                   help="drive along the tunnel centreline (needs the mesh's .json)")
    p.add_argument("--speed", type=float, metavar="M_S", help="speed along the centreline")
    p.add_argument("--height", type=float, default=0.5, metavar="M",
                   help="platform height above the centreline (default 0.5)")
    p.add_argument("--offset", type=float, default=0.0, metavar="M",
                   help="platform offset left of the centreline (default 0)")
    p.add_argument("--margin", type=float, default=1.0, metavar="M",
                   help="distance kept from the portals (default 1)")
    p.add_argument("--mount", choices=["level", "down"], default="level",
                   help="sensor z up (level) or pointing down (default level)")
    p.add_argument("--lever", default="0,0,0", metavar="X,Y,Z",
                   help="lever arm platform -> sensor in metres (default 0,0,0)")
    p.add_argument("--duration", type=float, metavar="S",
                   help="simulate only the first S seconds")
    p.add_argument("--chainage", metavar="START,END",
                   help="with --along: drive only this chainage range in m")
    p.add_argument("--rate", type=float, metavar="HZ",
                   help="rotation (profile) rate in Hz instead of the spec's; the firing "
                        "rate stays, so points per turn (per profile) change")
    p.add_argument("--slam-drift", action="store_true",
                   help="with --along: write the cloud in a drifting SLAM frame, with the "
                        "SLAM and true trajectories (_trajectory.txt, _true_trajectory.txt) "
                        "and the control points (_cp_world.csv, _cp_observed.csv) for "
                        "'tunnelsim correct'")
    _physics_options(p)
    p.set_defaults(func=scanning.cmd_drive)

    p = sub.add_parser(
        "adjust", help="Helmert adjustment between two control-point files",
        description="Least-squares Helmert transformation (PROJ form, position-vector "
                    "convention) between two CSV files of control points (id,x,y,z"
                    "[,sigma|sx,sy,sz]) matched by id, with residuals, sigma0, global "
                    "test and outlier tests.",
        epilog="Example: tunnelsim adjust mls_cp.csv total_station.csv --model 7 "
               "--report adjust.md --json helmert.json")
    p.add_argument("source", help="control points in the source system (CSV)")
    p.add_argument("target", help="control points in the target system (CSV)")
    p.add_argument("--model", choices=["7", "6", "9"], default="7",
                   help="7 similarity (default), 6 rigid, 9 scale per axis")
    p.add_argument("--report", help="write the Markdown report here")
    p.add_argument("--json", help="write the result (parameters and statistics) here")
    p.add_argument("--quiet", action="store_true", help="do not print the report")
    p.set_defaults(func=adjustment.cmd_adjust)

    p = sub.add_parser(
        "transform", help="apply a Helmert transform to a point cloud",
        description="Apply the Helmert transform of 'tunnelsim adjust --json' to a LAS/LAZ "
                    "or binary PLY cloud, chunk by chunk, keeping every other field.",
        epilog="Example: tunnelsim transform --helmert helmert.json mls.laz -o mls_utm.laz")
    p.add_argument("cloud", help="input cloud (.las, .laz, .ply)")
    p.add_argument("--helmert", required=True, help="Helmert JSON from 'tunnelsim adjust'")
    p.add_argument("-o", "--output", required=True, help="output cloud (same kind)")
    p.add_argument("--quiet", action="store_true", help="print nothing on success")
    p.set_defaults(func=adjustment.cmd_transform)

    p = sub.add_parser(
        "correct", help="correct the drift of an MLS run with control points",
        description="Correct a drifting MLS run (trajectory and cloud with GPS time) with "
                    "control points: world coordinates (--control, id,x,y,z[,sigma]) and "
                    "their MLS-frame coordinates with observation time (--observed, "
                    "id,x,y,z,time). Writes the corrected cloud, the corrected trajectory "
                    "(_trajectory.txt), a report (_report.md) and a plot of the correction.",
        epilog="Example: tunnelsim correct --trajectory slam.txt --cloud mls.laz --control "
               "cp.csv --observed cp_mls.csv -o corrected.laz")
    p.add_argument("--trajectory", required=True, help="MLS trajectory (TUM or CSV)")
    p.add_argument("--cloud", required=True, help="MLS cloud with GPS time (.las/.laz/.ply)")
    p.add_argument("--control", required=True, help="control points, world coordinates (CSV)")
    p.add_argument("--observed", required=True,
                   help="the same points in the MLS frame with their time (CSV)")
    p.add_argument("--model", choices=["piecewise", "global"], default="piecewise",
                   help="piecewise rigid per control section (default) or one similarity")
    p.add_argument("-o", "--output", required=True, help="corrected cloud")
    p.add_argument("--json", help="also write the key figures (check-point RMS, largest "
                                  "correction) as JSON")
    p.add_argument("--quiet", action="store_true", help="print nothing on success")
    p.set_defaults(func=adjustment.cmd_correct)

    p = sub.add_parser(
        "preprocess", help="voxel-grid downsampling and outlier removal of a cloud",
        description="Stream a cloud (LAS/LAZ/PLY/XYZ/NPZ/E57) through a voxel grid "
                    "(centroid per voxel, Open3D semantics), then remove statistical and "
                    "radius outliers (Open3D semantics) and write LAS/LAZ with the number "
                    "of points per voxel.",
        epilog="Example: tunnelsim preprocess mls.laz -o clean.laz --voxel 0.02 --sor 8,2.0 "
               "--segment")
    p.add_argument("cloud", help="input cloud")
    p.add_argument("-o", "--output", required=True, help="output cloud (.las/.laz)")
    p.add_argument("--voxel", type=float, metavar="M", help="voxel size in metres")
    p.add_argument("--sor", metavar="K,STD_RATIO",
                   help="statistical outlier removal: K neighbours (the point included), "
                        "threshold mean + STD_RATIO x std")
    p.add_argument("--ror", metavar="N,RADIUS_M",
                   help="radius outlier removal: at least N other points within RADIUS_M")
    p.add_argument("--crop", metavar="START,END",
                   help="keep the chainage range START..END in m (axis from --tunnel-json "
                        "or estimated)")
    p.add_argument("--segment", action="store_true",
                   help="classify lining (64), floor (2), attachments (65), objects (66), "
                        "noise (7) as LAS classification")
    p.add_argument("--tunnel-json", help="alignment for --segment from a generated tunnel's "
                                         "JSON (default: estimated from the cloud)")
    p.add_argument("--quiet", action="store_true", help="print nothing on success")
    p.set_defaults(func=clouds.cmd_preprocess)

    p = sub.add_parser(
        "mesh", help="reconstruct a tunnel mesh from a cleaned cloud",
        description="Tunnel-aware reconstruction: unroll the lining around the centreline "
                    "(estimated, or from a tunnel JSON), take a median radius per cell, "
                    "fill gaps (vertex property support = 0), triangulate; open portals.",
        epilog="Example: tunnelsim mesh clean.laz -o tunnel.ply --cell 0.1,2")
    p.add_argument("cloud", help="input cloud (.las/.laz/.ply/.xyz/.npz/.e57)")
    p.add_argument("-o", "--output", required=True, help="output mesh (.ply)")
    p.add_argument("--cell", default="0.1,2", metavar="M,DEG",
                   help="cell size along the axis (m) and around it (deg), default 0.1,2")
    p.add_argument("--detail", action="store_true",
                   help="add a detail layer: attachments (cables, pipes) as closed tubes "
                        "(vertex support -1)")
    p.add_argument("--method", choices=["tunnel", "poisson"], default="tunnel",
                   help="tunnel-aware mesher (default) or Open3D Poisson (optional extra)")
    p.add_argument("--depth", type=int, default=10,
                   help="Poisson octree depth (default 10)")
    p.add_argument("--triangles", type=int, metavar="N",
                   help="triangle budget: coarsen the cells until the mesh fits")
    p.add_argument("--min-points", type=int, default=3,
                   help="cells with fewer points are interpolated (default 3)")
    p.add_argument("--tunnel-json", help="use the alignment of a generated tunnel's JSON")
    p.add_argument("--json", help="also write the reconstruction quality as JSON")
    p.add_argument("--figure", metavar="PNG",
                   help="also write the unrolled support map (points per cell) as PNG")
    p.add_argument("--quiet", action="store_true", help="print nothing on success")
    p.set_defaults(func=clouds.cmd_mesh)

    p = sub.add_parser(
        "compare", help="cloud-to-cloud or cloud-to-mesh distances, with statistics",
        description="Distances from one or more clouds to a reference, CloudCompare "
                    "semantics: exact nearest neighbour (C2C) or signed distance to a mesh "
                    "(C2M, positive on the side of the triangle normal). The last path is "
                    "the reference (cloud, or a mesh .ply/.obj/.stl). Writes stats.csv, "
                    "stats.md (mean, median, std, 95 %, RMS per scan), histogram.png and "
                    "each cloud as LAZ with the scalar field 'distance'.",
        epilog="Example: tunnelsim compare station_sim.laz station_real.laz --max-dist 0.5 "
               "-o compare/")
    p.add_argument("clouds", nargs="+", metavar="CLOUD",
                   help="compared cloud(s), then the reference")
    p.add_argument("-o", "--output", required=True, help="output folder")
    p.add_argument("--max-dist", type=float, metavar="M",
                   help="clamp distances at M metres (points farther get M)")
    p.add_argument("--split", action="store_true",
                   help="also write the X/Y/Z components (compared - nearest reference)")
    p.add_argument("--model", choices=["plane"],
                   help="local model of the reference: least-squares plane of --k points")
    p.add_argument("--k", type=int, default=6, help="neighbours for --model (default 6)")
    p.add_argument("--threads", type=int, help="Numba threads (default: all cores)")
    p.add_argument("--force", action="store_true", help="write into a non-empty folder")
    p.add_argument("--quiet", action="store_true", help="print nothing on success")
    p.set_defaults(func=analysis.cmd_compare)

    p = sub.add_parser(
        "plan", help="TLS station planning: coverage of spacings, optimised station set",
        description="Quality of every lining cell (coverage, point spacing from the "
                    "preset's angular step and range, incidence, range) for stations on "
                    "the axis at fixed spacings, and optionally the smallest station set "
                    "reaching a target coverage (MILP, greedy bound). Writes plan.csv, "
                    "plan.md and coverage.png (unrolled chainage x angle).",
        epilog="Example: tunnelsim plan --mesh bfo.ply --sensor zf_imager_5016 "
               "--resolution high --spacing 5,10 --optimize --target 0.99 -o plan/")
    p.add_argument("--mesh", required=True, help="tunnel mesh (its .json gives the axis)")
    p.add_argument("--sensor", default="zf_imager_5016", help="TLS sensor name or .toml")
    p.add_argument("--resolution", help="resolution preset (default: the sensor's)")
    p.add_argument("--spacing", default="5,10", metavar="M[,M...]",
                   help="station spacings to compare in metres (default 5,10)")
    p.add_argument("--optimize", action="store_true",
                   help="find the smallest station set for --target")
    p.add_argument("--target", type=float, default=0.99,
                   help="coverage share to reach with --optimize (default 0.99)")
    p.add_argument("--candidate-step", type=float, default=2.5, metavar="M",
                   help="candidate stations every M metres (default 2.5)")
    p.add_argument("--time-limit", type=float, default=60.0, metavar="S",
                   help="MILP time limit in seconds (default 60)")
    p.add_argument("--spacing-mm", type=float, default=5.0,
                   help="point-spacing threshold in mm (default 5)")
    p.add_argument("--incidence-deg", type=float, default=70.0,
                   help="incidence threshold in degrees (default 70)")
    p.add_argument("--range", type=float, default=30.0, metavar="M",
                   help="range threshold in metres (default 30)")
    p.add_argument("--cell", default="0.25,2", metavar="M,DEG",
                   help="lining cell size along (m) and around (deg) (default 0.25,2)")
    p.add_argument("--height", type=float, default=1.5, metavar="M",
                   help="instrument height above the floor (default 1.5)")
    p.add_argument("-o", "--output", required=True, help="output folder")
    p.add_argument("--threads", type=int, help="Numba threads (default: all cores)")
    p.add_argument("--force", action="store_true", help="write into a non-empty folder")
    p.add_argument("--quiet", action="store_true", help="print nothing on success")
    p.set_defaults(func=analysis.cmd_plan)

    p = sub.add_parser(
        "study", help="MLS speed x scan-rate x mounting study",
        description="Drive a spinning lidar (or profiler) through an evaluation strip at "
                    "each speed, rate and mounting: density on lining and floor, empty "
                    "lining share, along-track line spacing, rolling-shutter distortion. "
                    "Writes study.csv, study.md and study.png (floor rings per speed, "
                    "density vs speed).",
        epilog="Example: tunnelsim study --mesh bfo.ply --sensor robosense_airy --speeds "
               "0,1,3 --rates 10,20 --mounts down -o study/")
    p.add_argument("--mesh", required=True, help="tunnel mesh (its .json gives the axis)")
    p.add_argument("--sensor", default="robosense_airy", help="sensor name or .toml")
    p.add_argument("--speeds", default="0,1,3", metavar="V[,V...]",
                   help="speeds in m/s (default 0,1,3)")
    p.add_argument("--rates", default="10", metavar="HZ[,HZ...]",
                   help="rotation (profile) rates in Hz (default 10)")
    p.add_argument("--mounts", default="level,down", metavar="level,down",
                   help="mountings (default level,down)")
    p.add_argument("--strip", metavar="START,END",
                   help="evaluation strip in chainage (default: 5 m mid-tunnel)")
    p.add_argument("--lead", type=float, default=5.0, metavar="M",
                   help="drive this far before and after the strip (default 5)")
    p.add_argument("--height", type=float, default=0.5, metavar="M",
                   help="sensor height above the floor (default 0.5)")
    p.add_argument("--ideal", action="store_true",
                   help="exact geometry: no noise, every return detected")
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    p.add_argument("-o", "--output", required=True, help="output folder")
    p.add_argument("--threads", type=int, help="Numba threads (default: all cores)")
    p.add_argument("--force", action="store_true", help="write into a non-empty folder")
    p.add_argument("--quiet", action="store_true", help="print nothing on success")
    p.set_defaults(func=analysis.cmd_study)

    p = sub.add_parser(
        "gazebo", help="export the tunnel and a lidar robot as a Gazebo world (SDF 1.9)",
        description="Write a Gazebo world folder: world.sdf (underground lighting, the "
                    "tunnel as a static model, a LIMO-sized differential-drive robot "
                    "carrying the lidar as a gpu_lidar sensor), the tunnel model (OBJ "
                    "visual, decimated STL collision) in local coordinates, and a README. "
                    "What SDF cannot express about the sensor is listed.",
        epilog="Example: tunnelsim gazebo --mesh bfo.ply --sensor robosense_airy -o world/")
    p.add_argument("--mesh", required=True, help="tunnel mesh (its .json gives the axis)")
    p.add_argument("--sensor", default="robosense_airy",
                   help="spinning lidar or profiler, name or .toml (default robosense_airy)")
    p.add_argument("--mount", choices=["level", "down"], default="level",
                   help="lidar z up (level) or pointing down (default level)")
    p.add_argument("--chainage", type=float, metavar="M",
                   help="robot start chainage (default: first chainage + 1 m)")
    p.add_argument("-o", "--output", required=True, help="output world folder (new)")
    p.add_argument("--force", action="store_true", help="replace an existing folder")
    p.add_argument("--quiet", action="store_true", help="print nothing on success")
    p.set_defaults(func=world.cmd_gazebo)

    p = sub.add_parser(
        "demo", help="the whole seed workflow on a generated tunnel, with a report",
        description="Run the shipped demo pipeline (print it with --print-config): "
                    "generate the BFO-like tunnel, simulate and correct a drifting MLS "
                    "run, preprocess and reconstruct, compare TLS stations on the "
                    "reconstruction with the truth (Table 1), plan stations (Figure 6), "
                    "study MLS speeds (Figure 7), export to Gazebo; writes report.md.",
        epilog="Example: tunnelsim demo -o tunnelsim-demo")
    p.add_argument("-o", "--output", default="tunnelsim-demo",
                   help="output folder (default ./tunnelsim-demo)")
    p.add_argument("--quick", action="store_true",
                   help="smaller numbers throughout (under a minute; what the tests run)")
    p.add_argument("--print-config", action="store_true",
                   help="print the demo pipeline (TOML for 'tunnelsim run') and exit")
    p.add_argument("--seed", type=int, help="random seed for every step (default: the "
                                            "pipeline's, 0)")
    p.add_argument("--threads", type=int, help="Numba threads (default: all cores)")
    p.add_argument("--force", action="store_true", help="write into a non-empty folder")
    p.add_argument("--quiet", action="store_true", help="no progress lines")
    p.set_defaults(func=runner.cmd_demo)

    p = sub.add_parser(
        "run", help="run a pipeline TOML file (a sequence of tunnelsim steps)",
        description="Run the steps of a pipeline TOML file in order, inside one output "
                    "folder, and write report.md. Each step is a tunnelsim command with "
                    "its options; see 'tunnelsim demo --print-config' for an example.",
        epilog="Example: tunnelsim run demo.toml -o my-demo --quick  (after 'tunnelsim "
               "demo --print-config > demo.toml')")
    p.add_argument("pipeline", help="pipeline TOML file")
    p.add_argument("-o", "--output", required=True, help="output folder")
    p.add_argument("--quick", action="store_true", help="apply the steps' [quick] options")
    p.add_argument("--seed", type=int, help="random seed for every step that takes one")
    p.add_argument("--threads", type=int, help="Numba threads (default: all cores)")
    p.add_argument("--force", action="store_true", help="write into a non-empty folder")
    p.add_argument("--quiet", action="store_true", help="no progress lines")
    p.set_defaults(func=runner.cmd_run)

    p = sub.add_parser("sensors", help="list the sensor models",
                       description="List the shipped sensor models with kind and source "
                                   "file.", epilog="Example: tunnelsim sensors")
    p.set_defaults(func=world.cmd_sensors)
    _coherent(sub)
    return parser


#: Commands that draw random numbers (they take --seed).
SEEDED = {"tunnel", "scan", "drive", "study", "demo", "run"}
#: Commands that only print (no --quiet, no --threads).
PRINTING = {"info", "sensors"}


def _coherent(sub):
    """The options every command shares, added where a command does not define them:
    --debug everywhere; --quiet and --threads wherever work is done; --seed wherever
    random numbers are drawn."""
    for name, p in sub.choices.items():
        have = p._option_string_actions
        if "--debug" not in have:
            p.add_argument("--debug", action="store_true",
                           help="show tracebacks instead of one-line errors")
        if name in PRINTING:
            continue
        if "--quiet" not in have:
            p.add_argument("--quiet", action="store_true", help="print nothing on success")
        if "--threads" not in have:
            p.add_argument("--threads", type=int, metavar="N",
                           help="Numba threads (default: all cores)")
        if name in SEEDED and "--seed" not in have:
            p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    debug = "--debug" in argv
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
        if not getattr(args, "func", None):
            parser.print_help()
            return EXIT_USAGE
        threads = getattr(args, "threads", None)
        if threads is not None:
            from raytrace import set_threads

            try:
                set_threads(threads)
            except ValueError as exc:
                raise TunnelsimCLIError(f"--threads: {exc}") from exc
        return int(args.func(args) or 0)
    except (TunnelsimError, _UsageError) as exc:
        if debug:
            raise
        print(f"tunnelsim: error: {exc}" if isinstance(exc, TunnelsimError) else str(exc),
              file=sys.stderr)
        return EXIT_USAGE
    except KeyboardInterrupt:
        if debug:
            raise
        print("tunnelsim: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
