"""Ready-made tunnels: the embedded default worlds of demos, tests and benchmarks.

``bfo`` mirrors the seed study's tunnel, the ~300 m entrance gallery of the Black Forest
Observatory (BFO, Schiltach): an elongated, slightly curved, narrow gallery with cables
along one wall, niches, a wet floor stretch and open portals. What the study states is
kept (length ~300 m, width 2.5-3 m, a gentle curve, four cables on one wall, niches, a
wet floor, open portals); everything else is ASSUMED and chosen to be typical of such
galleries:

- alignment: 120 m straight, a left curve of 300 m radius with 20 m clothoid
  transitions turning 0.25 rad (14.3 deg) in all, then straight to 300 m; a 1 % grade
  rising into the hill (drainage runs out of the portal);
- profile: horseshoe of 2.8 m span, springline at 1.4 m, 2.8 m high, 2.05 m wide floor;
- shotcrete roughness 3 mm rms with 0.3 m correlation length;
- four cables (12-20 mm radius) on the left wall between 1.50 and 1.74 m height, 3 cm
  clear of the wall, from chainage 1 to 299 m;
- three niches in the right wall at 75, 150 and 225 m: 1.5 m wide, 0.2-2.0 m high,
  0.8 m deep;
- a drainage channel 25 cm wide, 15 cm deep along the right side of the floor;
- a wet floor stretch from 180 to 230 m;
- rock-bolt plates every 2 m at five angles around the arch between 20 and 280 m;
- monitoring prisms on both walls and at the crown every 25 m (chainage 12.5 to
  287.5 m, 36 in all): the control points;
- the monitoring epoch: 5 mm radial convergence between chainage 120 and 160 m
  (5 m tapers), the example of the generator's issue.

Coordinates are local (portal centreline at the origin, heading east) unless an
``origin`` (easting, northing, height) and ``heading_rad`` are given, e.g. UTM.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from survey.errors import TunnelError
from survey.world import features as F
from survey.world.alignment import Alignment, curve, straight
from survey.world.deformation import Convergence, Deformation
from survey.world.generator import make_tunnel
from survey.world.mesh import TunnelMesh
from survey.world.profiles import Profile, circle, horseshoe

__all__ = ["PRESETS", "bfo_parts", "preset", "tbm_parts"]

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


PRESETS: dict[str, Callable[[ArrayLike, float], Parts]] = {"bfo": bfo_parts,
                                                            "tbm": tbm_parts}


def preset(name: str, *, edge_length_m: float = 0.1, seed: int = 0,
           closed_ends: bool = False, roughness_rms_m: float | None = None,
           origin: ArrayLike = (0.0, 0.0, 0.0), heading_rad: float = 0.0
           ) -> tuple[TunnelMesh, list[Deformation]]:
    """Generate a preset tunnel ("bfo" or "tbm"); returns (TunnelMesh, its default
    deformations). ``origin`` (3,) in m and ``heading_rad`` place it (e.g. in UTM)."""
    if name not in PRESETS:
        raise TunnelError(f"Expected a preset in {sorted(PRESETS)}, got {name!r}.")
    al, prof, feats, deform = PRESETS[name](origin, heading_rad)
    kw: dict[str, Any] = {} if roughness_rms_m is None else {"roughness_rms_m": roughness_rms_m}
    if name == "bfo" and roughness_rms_m is None:
        kw["roughness_rms_m"] = 0.003
    if closed_ends:  # recesses must stop short of closed ends
        feats = [f for f in feats if not isinstance(f, F.Drainage)] + \
            [F.Drainage(f.offset_m, f.width_m, f.depth_m, al.chainage_range[0] + 0.5,
                        al.chainage_range[1] - 0.5)
             for f in feats if isinstance(f, F.Drainage)]
    tun = make_tunnel(al, prof, edge_length_m=edge_length_m, features=feats, seed=seed,
                      closed_ends=closed_ends, name=name, **kw)
    return tun, deform
