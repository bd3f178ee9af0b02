"""Known lining deformations for monitoring studies: ground truth for a second epoch.

Each deformation is a scalar field f(s, t) in metres over chainage s and the profile
parameter t (arc length around the cross-section), applied along the inward lining
normal: positive f moves the surface towards the tunnel axis (convergence, a bulge into
the clear space), negative f away from it. Features fixed to the lining (cables, bolt
plates, prisms) move rigidly with the lining point they are attached to. Fields add up.

- ``Convergence``: uniform radial convergence between two chainages, ramped in and out
  with half-cosine tapers inside the interval (zero outside it, full value between
  ``start_m + taper_m`` and ``end_m - taper_m``).
- ``Ovalisation``: f = a cos(2 (phi - phi0)), phi the polar angle of the profile point
  about the profile centroid measured from the crown (positive to the left); with the
  same chainage window and taper. a > 0 with phi0 = 0 squeezes crown and invert in and
  pushes the walls out (the classic squat ovalisation under vertical load).
- ``Bulge``: a local bump f = A (1 + cos(pi r / R)) / 2 for r < R, where r is the
  distance in the developed lining surface, sqrt((s - s0)^2 + (t - t0)^2).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import asdict, dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from survey.errors import DeformationError
from survey.world.records import from_record

if TYPE_CHECKING:
    from survey.world.profiles import Profile

__all__ = ["KINDS", "Bulge", "Convergence", "Deformation", "Ovalisation", "from_dict",
           "to_dict", "total_field"]

Floats = NDArray[np.float64]


def _taper(s: ArrayLike, start: float, end: float, taper: float) -> Floats:
    """Window: 0 outside [start, end], half-cosine ramps of length ``taper`` inside."""
    s = np.asarray(s, dtype=np.float64)
    w = ((s >= start) & (s <= end)).astype(np.float64)
    if taper > 0:
        up = (s >= start) & (s < start + taper)
        dn = (s > end - taper) & (s <= end)
        w = np.where(up, 0.5 - 0.5 * np.cos(np.pi * (s - start) / taper), w)
        w = np.where(dn, np.minimum(w, 0.5 - 0.5 * np.cos(np.pi * (end - s) / taper)), w)
    return w


def _check_window(start_m: float, end_m: float, taper_m: float) -> None:
    if not (np.isfinite(start_m) and np.isfinite(end_m) and end_m > start_m):
        raise DeformationError(f"Expected a chainage window with end_m > start_m, got "
                               f"[{start_m}, {end_m}].")
    if not (np.isfinite(taper_m) and 0 <= taper_m <= (end_m - start_m) / 2):
        raise DeformationError(f"Expected `taper_m` between 0 and half the window "
                               f"({(end_m - start_m) / 2:g} m), got {taper_m}.")


@dataclass(frozen=True)
class Convergence:
    """Radial convergence ``displacement_m`` (positive inward) between two chainages."""

    start_m: float
    end_m: float
    displacement_m: float
    taper_m: float = 5.0

    def __post_init__(self) -> None:
        _check_window(self.start_m, self.end_m, self.taper_m)

    def field(self, s: ArrayLike, t: ArrayLike, profile: Profile) -> Floats:
        """The field (m, positive inward) at chainages s and profile parameters t."""
        return self.displacement_m * _taper(s, self.start_m, self.end_m, self.taper_m) * \
            np.ones_like(np.asarray(t, dtype=np.float64))


@dataclass(frozen=True)
class Ovalisation:
    """f = amplitude_m cos(2 (phi - axis_rad)) within a chainage window."""

    start_m: float
    end_m: float
    amplitude_m: float
    axis_rad: float = 0.0
    taper_m: float = 5.0

    def __post_init__(self) -> None:
        _check_window(self.start_m, self.end_m, self.taper_m)

    def field(self, s: ArrayLike, t: ArrayLike, profile: Profile) -> Floats:
        """The field (m, positive inward) at chainages s and profile parameters t."""
        p = profile.points(t) - profile.centroid
        phi = np.arctan2(p[..., 0], p[..., 1])  # from the crown, positive to the left
        return self.amplitude_m * np.cos(2.0 * (phi - self.axis_rad)) * \
            _taper(s, self.start_m, self.end_m, self.taper_m)


@dataclass(frozen=True)
class Bulge:
    """Local bump of ``amplitude_m`` (positive inward) centred at ``chainage_m`` and the
    profile point at ``angle_rad`` from the crown, with radius ``radius_m``."""

    chainage_m: float
    angle_rad: float
    radius_m: float
    amplitude_m: float

    def __post_init__(self) -> None:
        if not (np.isfinite(self.radius_m) and self.radius_m > 0):
            raise DeformationError(f"Expected a positive bulge `radius_m`, got "
                                   f"{self.radius_m}.")

    def field(self, s: ArrayLike, t: ArrayLike, profile: Profile) -> Floats:
        """The field (m, positive inward) at chainages s and profile parameters t."""
        t0 = profile.t_at_angle(self.angle_rad)
        per = profile.perimeter_m
        dt = np.mod(np.asarray(t, dtype=np.float64) - t0 + per / 2, per) - per / 2
        r = np.hypot(np.asarray(s, dtype=np.float64) - self.chainage_m, dt)
        return np.where(r < self.radius_m,
                        self.amplitude_m * 0.5 * (1.0 + np.cos(np.pi * r / self.radius_m)),
                        0.0)


#: Any deformation field.
Deformation = Convergence | Ovalisation | Bulge

KINDS: dict[str, type[Any]] = {"convergence": Convergence, "ovalisation": Ovalisation,
                               "bulge": Bulge}


def total_field(deformations: Iterable[Deformation], s: ArrayLike, t: ArrayLike,
                profile: Profile) -> Floats:
    """Sum of the fields (metres, positive inward) at (s, t); NaN t gives 0."""
    s, t = np.broadcast_arrays(np.asarray(s, dtype=np.float64),
                               np.asarray(t, dtype=np.float64))
    ok = np.isfinite(t)
    out = np.zeros(s.shape)
    if not ok.any():
        return out
    for d in deformations:
        out[ok] += d.field(s[ok], t[ok], profile)
    return out


def to_dict(d: Deformation) -> dict[str, Any]:
    """Plain data (JSON-ready) with a ``kind`` key; ``from_dict`` reads it back."""
    name = {v: k for k, v in KINDS.items()}[type(d)]
    return {"kind": name, **asdict(d)}


def from_dict(d: Mapping[str, Any]) -> Deformation:
    """The deformation of a ``to_dict`` dictionary."""
    obj: Deformation = from_record(d, KINDS, DeformationError, "deformation")
    return obj
