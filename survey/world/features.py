"""Tunnel features as data: what the generator adds to the swept lining.

Recesses (``Niche``, ``Drainage``) are cut into the lining grid itself, so the mesh stays
one manifold surface; ``WetFloor`` only relabels floor faces; cables, bolt plates and
prisms are separate closed solids fixed to a lining point (they move with it when the
lining deforms). Positions on the profile are given the way a surveyor states them: a
side and a height for wall items, an offset for floor items, an angle from the crown
(positive to the left, about the profile centroid) for items around the arch.

All lengths in metres, angles in radians, chainages in the alignment's chainage.
``None`` for a chainage range means the whole tunnel.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from survey.errors import FeatureError
from survey.world.records import from_record

__all__ = ["KINDS", "Bolts", "Cable", "Drainage", "Feature", "Niche", "Prisms", "WetFloor",
           "from_dict", "to_dict"]


def _pos(name: str, v: float, allow_zero: bool = False) -> None:
    v = float(v)
    if not np.isfinite(v) or v < 0 or (v == 0 and not allow_zero):
        raise FeatureError(f"Expected `{name}` to be a {'non-negative' if allow_zero else 'positive'} "
                           f"number, got {v}.")


def _side(v: str) -> None:
    if v not in ("left", "right"):
        raise FeatureError(f"Expected side 'left' or 'right', got {v!r}.")


def _range(a: float | None, b: float | None) -> None:
    if a is not None and b is not None and not b > a:
        raise FeatureError(f"Expected end_m > start_m, got [{a}, {b}].")


@dataclass(frozen=True)
class Cable:
    """A cable or pipe along a wall: a closed polygonal tube of ``radius_m`` whose
    surface stays ``gap_m`` clear of the design lining at ``height_m`` on ``side``."""

    side: str
    height_m: float
    radius_m: float = 0.015
    gap_m: float = 0.03
    start_m: float | None = None
    end_m: float | None = None
    sides: int = 8

    def __post_init__(self) -> None:
        _side(self.side)
        _pos("radius_m", self.radius_m)
        _pos("gap_m", self.gap_m, allow_zero=True)
        _range(self.start_m, self.end_m)
        if int(self.sides) < 3:
            raise FeatureError(f"Expected a cable with at least 3 sides, got {self.sides}.")


@dataclass(frozen=True)
class Niche:
    """A rectangular recess in a wall, ``depth_m`` deep, between two chainages and
    two heights."""

    side: str
    start_m: float
    end_m: float
    bottom_m: float
    top_m: float
    depth_m: float = 0.6

    def __post_init__(self) -> None:
        _side(self.side)
        _range(self.start_m, self.end_m)
        if not self.top_m > self.bottom_m:
            raise FeatureError(f"Expected top_m > bottom_m, got {self.bottom_m}, "
                               f"{self.top_m}.")
        _pos("depth_m", self.depth_m)


@dataclass(frozen=True)
class Drainage:
    """A drainage channel cut into the floor, centred at ``offset_m`` (left positive)."""

    offset_m: float
    width_m: float = 0.3
    depth_m: float = 0.2
    start_m: float | None = None
    end_m: float | None = None

    def __post_init__(self) -> None:
        _pos("width_m", self.width_m)
        _pos("depth_m", self.depth_m)
        _range(self.start_m, self.end_m)


@dataclass(frozen=True)
class WetFloor:
    """A stretch of wet floor (standing water film): relabels the floor faces, which
    gives them the low reflectivity of the 'wet_floor' label."""

    start_m: float
    end_m: float

    def __post_init__(self) -> None:
        _range(self.start_m, self.end_m)


@dataclass(frozen=True)
class Bolts:
    """Rock-bolt bearing plates (square, ``plate_m`` wide, ``thickness_m`` proud of the
    lining) every ``spacing_m`` along the tunnel at each angle from the crown."""

    angles_rad: tuple[float, ...]
    spacing_m: float = 1.5
    start_m: float | None = None
    end_m: float | None = None
    plate_m: float = 0.15
    thickness_m: float = 0.02

    def __post_init__(self) -> None:
        object.__setattr__(self, "angles_rad", tuple(float(a) for a in self.angles_rad))
        _pos("spacing_m", self.spacing_m)
        _pos("plate_m", self.plate_m)
        _pos("thickness_m", self.thickness_m)
        _range(self.start_m, self.end_m)


@dataclass(frozen=True)
class Prisms:
    """Monitoring prisms (control points): a sphere of ``radius_m`` on a stalk,
    its centre ``standoff_m`` from the design lining, in cross-sections at
    ``chainages_m`` and at each angle from the crown. Their centres are the control
    points written in the tunnel's metadata."""

    chainages_m: tuple[float, ...]
    angles_rad: tuple[float, ...]
    radius_m: float = 0.03
    standoff_m: float = 0.1

    def __post_init__(self) -> None:
        object.__setattr__(self, "chainages_m", tuple(float(c) for c in self.chainages_m))
        object.__setattr__(self, "angles_rad", tuple(float(a) for a in self.angles_rad))
        _pos("radius_m", self.radius_m)
        if not self.standoff_m > self.radius_m:
            raise FeatureError(f"Expected `standoff_m` larger than the prism radius "
                               f"({self.radius_m} m), got {self.standoff_m}.")


#: Any feature the generator takes.
Feature = Cable | Niche | Drainage | WetFloor | Bolts | Prisms

KINDS: dict[str, type[Any]] = {"cable": Cable, "niche": Niche, "drainage": Drainage, "wet_floor": WetFloor,
         "bolts": Bolts, "prisms": Prisms}


def to_dict(f: Feature) -> dict[str, Any]:
    """Plain data (JSON-ready) with a ``kind`` key; ``from_dict`` reads it back."""
    name = {v: k for k, v in KINDS.items()}[type(f)]
    d = asdict(f)
    return {"kind": name, **{k: (list(v) if isinstance(v, tuple) else v)
                             for k, v in d.items()}}


def from_dict(d: Mapping[str, Any]) -> Feature:
    """The feature of a ``to_dict`` dictionary."""
    obj: Feature = from_record(d, KINDS, FeatureError, "feature")
    return obj
