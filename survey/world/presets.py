"""Ready-made tunnels: the embedded default worlds of demos, tests and benchmarks.

``bfo`` mirrors the seed study's tunnel, the ~300 m entrance gallery of the Black Forest
Observatory (BFO, Schiltach): an elongated, slightly curved, narrow gallery with cables
along one wall, niches, a wet floor stretch and open portals. What the study states is
kept (length ~300 m, width 2.5-3 m, a gentle curve, four cables on one wall, niches, a
wet floor, open portals); that it is an old drill-and-blast mine gallery with decimetre
overbreak is from issue 15; everything else is ASSUMED and chosen to be typical of such
galleries:

- alignment: 120 m straight, a left curve of 300 m radius with 20 m clothoid
  transitions turning 0.25 rad (14.3 deg) in all, then straight to 300 m; a 1 % grade
  rising into the hill (drainage runs out of the portal);
- profile: horseshoe of 2.8 m span, springline at 1.4 m, 2.8 m high, 2.05 m wide floor;
- the rock relief of a drill-and-blast gallery (``survey.world.rock.RockRelief()``,
  its defaults; sources and ASSUMED values listed there): decimetre overbreak (Gaussian,
  mean 7 cm, rms 7 cm, 1.2 m correlation, underbreak clipped at 2 cm), a look-out
  sawtooth of ~10 cm per 3 m blasting round (the round length of the rounds measured by
  Dybeł et al. 2021), no overbreak on the levelled floor (0.3 m taper up the walls), and
  a fine texture of 10 mm rms with 0.3 m correlation everywhere. Until issue 15 the
  gallery had only a shotcrete-like roughness of 3 mm rms (0.3 m correlation), on which
  LiDAR odometry (KISS-ICP) lost the motion along the axis; ``relief=None`` gives that
  surface back;
- four cables (12-20 mm radius) on the left wall between 1.50 and 1.74 m height, 3 cm
  clear of the rock (they follow its relief), from chainage 1 to 299 m;
- three niches in the right wall at 75, 150 and 225 m: 1.5 m wide, 0.2-2.0 m high,
  0.8 m deep;
- a drainage channel 25 cm wide, 15 cm deep along the right side of the floor;
- a wet floor stretch from 180 to 230 m;
- rock-bolt plates every 2 m at five angles around the arch between 20 and 280 m;
- monitoring prisms on both walls and at the crown every 25 m (chainage 12.5 to
  287.5 m, 36 in all): the control points;
- the monitoring epoch: 5 mm radial convergence between chainage 120 and 160 m
  (5 m tapers), the example of the generator's issue.

``tbm`` is a bored tunnel: a smooth segmental lining (2 mm roughness), no rock relief.

``junction`` is a mine drift with a 90 deg bend and a T-junction (issue 20: route finding
must handle bends and junctions), built by ``survey.world.junction``. All dimensions are
ASSUMED, typical of a trackless mine's haulage drift (e.g. 4 x 3.5 m, bends of 10-15 m
radius for LHD loaders): a horseshoe of 4 m span, springline at 1.5 m (3.5 m high,
3.4 m flat floor); 30 m straight, a left curve of 12 m radius with 4 m clothoids turning
90 deg, 30 m straight (82.8 m in all); level to chainage 20 m, then a 2 % grade; a 10 m
crosscut leaving to the left at chainage 12 m (so the main gallery's portals are the two
ends farthest apart); 3 mm lining roughness, no rock relief, no features.

Coordinates are local (portal centreline at the origin, heading east) unless an
``origin`` (easting, northing, height) and ``heading_rad`` are given, e.g. UTM.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from numpy.typing import ArrayLike

from survey.errors import TunnelError
from survey.world import features as F
from survey.world.alignment import Alignment, curve, straight
from survey.world.deformation import Convergence, Deformation
from survey.world.generator import make_tunnel
from survey.world.junction import Branch, make_junction_tunnel
from survey.world.mesh import TunnelMesh
from survey.world.profiles import Profile, circle, horseshoe
from survey.world.rock import RockRelief

__all__ = ["BRANCHES", "PRESETS", "RELIEF", "bfo_parts", "junction_parts", "preset",
           "tbm_parts"]

#: (alignment, profile, features, deformations) of a preset world.
Parts = tuple[Alignment, Profile, list[F.Feature], list[Deformation]]


def _origin(origin: ArrayLike) -> tuple[float, float, float]:
    o = np.asarray(origin, dtype=np.float64)
    if o.shape != (3,) or not np.isfinite(o).all():
        raise TunnelError(f"Expected `origin` as finite (easting, northing, height) in m, "
                          f"got shape {o.shape}.")
    return float(o[0]), float(o[1]), float(o[2])


def bfo_parts(origin: ArrayLike = (0.0, 0.0, 0.0), heading_rad: float = 0.0) -> Parts:
    """(alignment, profile, features, deformations) of the BFO-like gallery; ``origin``
    (3,) in m is the portal's centreline point, ``heading_rad`` counter-clockwise from
    east."""
    e0, n0, h0 = _origin(origin)
    elements = [straight(120.0), *curve(0.25, 300.0, 20.0)]
    used = sum(el.length_m for el in elements)
    elements.append(straight(300.0 - used))
    al = Alignment(elements, start_xy=(e0, n0), heading_rad=heading_rad,
                   profile=((0.0, h0), (300.0, h0 + 3.0)))
    prof = horseshoe(2.8, 1.4)
    feats: list[F.Feature] = [
        F.Cable("left", 1.50, radius_m=0.020, start_m=1.0, end_m=299.0),
        F.Cable("left", 1.58, radius_m=0.015, start_m=1.0, end_m=299.0),
        F.Cable("left", 1.66, radius_m=0.015, start_m=1.0, end_m=299.0),
        F.Cable("left", 1.74, radius_m=0.012, start_m=1.0, end_m=299.0),
        *[F.Niche("right", c - 0.75, c + 0.75, 0.2, 2.0, 0.8) for c in (75.0, 150.0, 225.0)],
        F.Drainage(-0.70, 0.25, 0.15),
        F.WetFloor(180.0, 230.0),
        F.Bolts((-0.9, -0.45, 0.0, 0.45, 0.9), spacing_m=2.0, start_m=20.0, end_m=280.0),
        F.Prisms(tuple(np.arange(12.5, 300.0, 25.0)), (1.25, 0.0, -1.25)),
    ]
    deform: list[Deformation] = [Convergence(120.0, 160.0, 0.005, taper_m=5.0)]
    return al, prof, feats, deform


def tbm_parts(origin: ArrayLike = (0.0, 0.0, 0.0), heading_rad: float = 0.0) -> Parts:
    """A straight 100 m bored tunnel, 5 m diameter, with a cable bundle and prisms
    every 20 m: a simple second world (ASSUMED dimensions, typical of a metro TBM)."""
    e0, n0, h0 = _origin(origin)
    al = Alignment([straight(100.0)], start_xy=(e0, n0), heading_rad=heading_rad,
                   profile=((0.0, h0),))
    prof = circle(2.5)
    feats: list[F.Feature] = [F.Cable("left", 3.0, radius_m=0.03),
                              F.Prisms(tuple(np.arange(10.0, 100.0, 20.0)), (1.3, -1.3))]
    deform: list[Deformation] = [Convergence(40.0, 60.0, 0.005, taper_m=5.0)]
    return al, prof, feats, deform


def junction_parts(origin: ArrayLike = (0.0, 0.0, 0.0), heading_rad: float = 0.0) -> Parts:
    """(alignment, profile, features, deformations) of the main gallery of the
    ``junction`` preset (its branch: ``BRANCHES["junction"]``); see the module doc."""
    e0, n0, h0 = _origin(origin)
    elements = [straight(30.0), *curve(np.pi / 2, 12.0, 4.0), straight(30.0)]
    length = sum(el.length_m for el in elements)
    al = Alignment(elements, start_xy=(e0, n0), heading_rad=heading_rad,
                   profile=((0.0, h0), (20.0, h0), (length, h0 + 0.02 * (length - 20.0))))
    return al, horseshoe(4.0, 1.5), [], []


PRESETS: dict[str, Callable[[ArrayLike, float], Parts]] = {"bfo": bfo_parts,
                                                            "tbm": tbm_parts,
                                                            "junction": junction_parts}
#: The branch galleries of presets that have them (``survey.world.junction``).
BRANCHES: dict[str, Branch] = {"junction": Branch(12.0, "left", 10.0)}
#: The surface relief of each preset (None: a smooth lining).
RELIEF: dict[str, RockRelief | None] = {"bfo": RockRelief(), "tbm": None, "junction": None}
#: Lining roughness (m) of each preset without relief (the texture of a relief is its own).
_SMOOTH_ROUGHNESS_M = {"bfo": 0.003, "tbm": 0.002, "junction": 0.003}


def preset(name: str, *, edge_length_m: float = 0.1, seed: int = 0,
           closed_ends: bool = False, roughness_rms_m: float | None = None,
           relief: RockRelief | None | str = "preset",
           origin: ArrayLike = (0.0, 0.0, 0.0), heading_rad: float = 0.0
           ) -> tuple[TunnelMesh, list[Deformation]]:
    """Generate a preset tunnel ("bfo", "tbm" or "junction"); returns (TunnelMesh, its
    default deformations). ``origin`` (3,) in m and ``heading_rad`` place it (e.g. in UTM).

    ``relief``: "preset" (default) for the preset's own (``RELIEF``: rock relief for
    bfo, none for tbm and junction), None for a smooth lining, or a ``RockRelief``.
    ``roughness_rms_m``: the lining roughness, the Gaussian fine texture (standard
    deviation, m), as it has always meant: without relief the same surface as before
    for a seed (0.3 m correlation); with a relief it replaces the relief's texture rms
    (its correlation length kept: 0.3 m for bfo), the overbreak staying. None: the
    relief's texture, or without relief the preset's roughness (bfo 3 mm, tbm 2 mm).
    """
    if name not in PRESETS:
        raise TunnelError(f"Expected a preset in {sorted(PRESETS)}, got {name!r}.")
    if isinstance(relief, str):
        if relief != "preset":
            raise TunnelError(f"Expected `relief` as 'preset', None or a RockRelief, got "
                              f"{relief!r}.")
        relief = RELIEF[name]
    al, prof, feats, deform = PRESETS[name](origin, heading_rad)
    if roughness_rms_m is None and relief is None:
        roughness_rms_m = _SMOOTH_ROUGHNESS_M[name]
    if name in BRANCHES:
        if relief is not None:
            raise TunnelError(f"Expected no rock relief for the {name!r} preset (its "
                              "junction has a lining roughness only), got one; leave "
                              "--relief unset or 'none'.")
        tun = make_junction_tunnel(al, prof, BRANCHES[name], edge_length_m=edge_length_m,
                                   roughness_rms_m=float(roughness_rms_m or 0.0),
                                   closed_ends=closed_ends, seed=seed, name=name)
        return tun, deform
    if closed_ends:  # recesses must stop short of closed ends
        feats = [f for f in feats if not isinstance(f, F.Drainage)] + \
            [F.Drainage(f.offset_m, f.width_m, f.depth_m, al.chainage_range[0] + 0.5,
                        al.chainage_range[1] - 0.5)
             for f in feats if isinstance(f, F.Drainage)]
    tun = make_tunnel(al, prof, edge_length_m=edge_length_m, features=feats, seed=seed,
                      closed_ends=closed_ends, name=name, roughness_rms_m=roughness_rms_m,
                      relief=relief)
    return tun, deform
