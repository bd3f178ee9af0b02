"""The ``tunnelsim`` command.

Errors a user can fix (``TunnelsimError`` and bad arguments) print one line on stderr and
exit with status 2; ``--debug`` shows the traceback instead.
"""

from __future__ import annotations

import argparse
import platform
import sys
from importlib import metadata

import numpy as np

from raytrace.errors import TunnelsimError

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


def _cmd_info(args) -> int:
    from raytrace.config import threading_info

    lines = [f"tunnelsim {_version()}",
             f"python {platform.python_version()} ({platform.machine()}, {platform.system()})"]
    for pkg in ("numpy", "numba", "scipy", "trimesh", "laspy", "lazrs", "pyproj", "pye57",
                "embreex", "open3d"):
        try:
            lines.append(f"{pkg} {metadata.version(pkg)}")
        except metadata.PackageNotFoundError:
            lines.append(f"{pkg} (not installed)")
    info = threading_info()
    lines.append(f"numba threading layer: {info['threading_layer']}")
    lines.append(f"numba threads: {info['threads']} of {info['max_threads']}")
    print("\n".join(lines))
    return 0


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


class TunnelsimCLIError(TunnelsimError, ValueError):
    """A command-line value is malformed."""


def _cmd_tunnel(args) -> int:
    import time
    from pathlib import Path

    from .deformation import Bulge, Convergence
    from .presets import PRESETS, preset
    from .tunnel import edge_length_for

    out = Path(args.output)
    if out.suffix.lower() != ".ply":
        raise TunnelsimCLIError(f"Expected an output file ending in .ply, got '{out}'.")
    if not out.parent.exists():
        raise TunnelsimCLIError(f"Expected an existing output folder, got '{out.parent}'; "
                                "create it first.")
    origin = (0.0, 0.0, 0.0) if args.origin is None else \
        _parse_window(args.origin.replace(",", ":"), "--origin as E,N,H in metres", 3)
    edge = args.edge_length
    if args.triangles is not None:
        al, prof, _, _ = PRESETS[args.preset](origin, 0.0)
        edge = edge_length_for(args.triangles, prof, al.length_m)
    t0 = time.perf_counter()
    tun, default_def = preset(args.preset, edge_length_m=edge, seed=args.seed,
                              closed_ends=args.closed_ends,
                              roughness_rms_m=None if args.roughness_mm is None
                              else args.roughness_mm / 1000.0, origin=origin,
                              heading_rad=np.deg2rad(args.heading_deg))
    deformations = [Convergence(*_parse_window(c, "--convergence START:END:MM", 3)[:2],
                                _parse_window(c, "", 3)[2] / 1000.0)
                    for c in args.convergence]
    deformations += [Bulge(a, np.deg2rad(b), r, mm / 1000.0) for a, b, r, mm in
                     (_parse_window(c, "--bulge CHAINAGE:ANGLE_DEG:RADIUS_M:MM", 4)
                      for c in args.bulge)]
    written = list(tun.write(out))
    if args.epoch2:
        ep2 = Path(args.epoch2)
        epoch = tun.deformed(deformations or default_def)
        written += list(epoch.write(ep2))
    dt = time.perf_counter() - t0
    if not args.quiet:
        counts = ", ".join(f"{k} {v:,}" for k, v in tun.metadata["face_counts"].items())
        print(f"{args.preset}: {len(tun.faces):,} triangles ({counts}), "
              f"{len(tun.vertices):,} vertices, edge length {edge:.4g} m, "
              f"{len(tun.metadata['control_points'])} control points, {dt:.1f} s")
        for p in written:
            print(f"wrote {p}")
    return 0


def build_parser() -> argparse.ArgumentParser:
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
    p.set_defaults(func=_cmd_info)

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
    p.set_defaults(func=_cmd_tunnel)
    return parser


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    debug = "--debug" in argv
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
        if not getattr(args, "func", None):
            parser.print_help()
            return EXIT_USAGE
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
