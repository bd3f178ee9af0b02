"""The known deformations of the detectability study, laid out along a tunnel.

``DetectLayout.build`` places a reference stretch of undeformed lining, a zone of uniform
radial convergence (``Convergence``), more undeformed lining and a ring of bulges
(``Bulge`` at ``BULGE_ANGLES_RAD``) from a start chainage; each ``DetectTarget`` gives
its deformation fields at a magnitude and the mask of its target region (the points
moved by (nearly) the full magnitude). ``survey.analysis.detectability`` scans and
scores the layout (its module notes define the target regions) and re-exports these
names.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from raytrace.checks import positive
from survey.errors import StudyError
from survey.world.deformation import Bulge, Convergence, Deformation

__all__ = ["BULGE_ANGLES_RAD", "BULGE_CORE_FRACTION", "KINDS", "DetectLayout",
           "DetectTarget"]

Floats = NDArray[np.float64]

#: Deformation kinds, in the order of the layout.
KINDS = ("convergence", "bulge")
#: Bulges per magnitude: one ring at these angles from the crown (positive left), rad.
#: ASSUMED: five places around the arch, walls to crown, 45 deg apart.
BULGE_ANGLES_RAD = tuple(float(a) for a in np.deg2rad((-90.0, -45.0, 0.0, 45.0, 90.0)))
#: A bulge's target region: developed distance below this share of its radius
#: (there its displacement is >= (1 + cos(pi / 3)) / 2 = 0.75 of the amplitude).
BULGE_CORE_FRACTION = 1.0 / 3.0


def _pos(value: Any, name: str, zero: bool = False) -> float:
    return positive(value, name, StudyError, zero=zero, what="a number")


@dataclass(frozen=True)
class DetectTarget:
    """One known deformation of the layout, at unit magnitude.

    Attributes
    ----------
    kind : "convergence" or "bulge"
    lo_m, hi_m : chainages (m) outside which it moves nothing
    plateau_m : (start, end) of a convergence zone's full value (m)
    centre_m, radius_m : a bulge ring's chainage and radius (m)
    taper_m : half-cosine ramp at each end of a convergence zone (m)
    """

    kind: str
    lo_m: float
    hi_m: float
    plateau_m: tuple[float, float] = (np.nan, np.nan)
    centre_m: float = np.nan
    radius_m: float = np.nan
    taper_m: float = 0.0

    def deformations(self, magnitude_m: float) -> list[Deformation]:
        """The fields of this target at ``magnitude_m`` (m, inward)."""
        if self.kind == "convergence":
            return [Convergence(self.lo_m, self.hi_m, magnitude_m, taper_m=self.taper_m)]
        return [Bulge(self.centre_m, a, self.radius_m, magnitude_m)
                for a in BULGE_ANGLES_RAD]

    def region(self, s: Floats, t: Floats, perimeter_m: float, t_centres: Floats,
               inset_m: float) -> NDArray[np.bool_]:
        """Target-region mask of points at chainage s and profile parameter t (module
        doc); ``t_centres`` the profile parameters of the bulge angles, ``inset_m``
        the cylinder radius."""
        if self.kind == "convergence":
            return (s >= self.plateau_m[0] + inset_m) & (s <= self.plateau_m[1] - inset_m)
        out = np.zeros(len(s), dtype=bool)
        for t0 in t_centres:
            dt = np.mod(t - t0 + perimeter_m / 2, perimeter_m) - perimeter_m / 2
            out |= np.hypot(s - self.centre_m, dt) <= BULGE_CORE_FRACTION * self.radius_m
        return out

    def to_dict(self) -> dict[str, Any]:
        d: dict[str, Any] = {"kind": self.kind, "lo_m": self.lo_m, "hi_m": self.hi_m}
        if self.kind == "convergence":
            d.update(plateau_m=list(self.plateau_m), taper_m=self.taper_m)
        else:
            d.update(centre_m=self.centre_m, radius_m=self.radius_m,
                     angles_deg=np.rad2deg(BULGE_ANGLES_RAD).tolist())
        return d


@dataclass(frozen=True)
class DetectLayout:
    """The known deformations along a stretch of tunnel, in chainage order: a
    reference stretch of undeformed lining, a convergence zone, ``gap_m`` of undeformed
    lining, a ring of bulges (``BULGE_ANGLES_RAD``); the same places at every
    magnitude (each magnitude is its own epoch 2).

    Use ``DetectLayout.build``; ``start_m``/``end_m`` bound the stretch (m)."""

    targets: tuple[DetectTarget, ...]
    magnitudes_m: tuple[float, ...]
    start_m: float
    end_m: float
    reference_m: tuple[float, float]

    @classmethod
    def build(cls, start_m: float, magnitudes_m: ArrayLike, *, zone_m: float = 5.0,
              taper_m: float = 0.5, gap_m: float = 1.0, bulge_radius_m: float = 0.5,
              reference_m: float = 2.0) -> DetectLayout:
        """Lay out the targets from chainage ``start_m`` (m).

        Parameters
        ----------
        magnitudes_m : (k,) array_like of float > 0
            Deformation magnitudes, m (convergence displacement, bulge amplitude).
        zone_m : float
            Length of the convergence zone's plateau (full value), m. A TLS has a
            station at its start (``Detectability``), so a plateau of half the station
            spacing holds every distance from the nearest station.
        taper_m : float
            Half-cosine ramp at each end of the convergence zone, m.
        gap_m : float
            Undeformed lining between the zone and the bulges, m.
        bulge_radius_m : float
            Radius of every bulge (developed lining distance), m.
        reference_m : float
            Undeformed stretch before the zone, m.
        """
        mags = np.atleast_1d(np.asarray(magnitudes_m, dtype=np.float64)).ravel()
        if mags.size == 0 or not np.all(np.isfinite(mags) & (mags > 0)):
            raise StudyError(f"Expected one or more positive magnitudes (m), got "
                             f"{mags.tolist()!r}.")
        if len(np.unique(mags)) != len(mags):
            raise StudyError(f"Expected distinct magnitudes, got {mags.tolist()!r}.")
        s0 = float(start_m)
        if not np.isfinite(s0):
            raise StudyError(f"Expected a finite start chainage, got {start_m!r}.")
        zone, taper = _pos(zone_m, "zone_m"), _pos(taper_m, "taper_m", zero=True)
        gap, rad = _pos(gap_m, "gap_m", zero=True), _pos(bulge_radius_m, "bulge_radius_m")
        ref = _pos(reference_m, "reference_m")
        a = s0 + ref
        b = a + zone + 2 * taper
        conv = DetectTarget("convergence", a, b, plateau_m=(a + taper, b - taper),
                            taper_m=taper)
        c = b + gap + rad
        bulge = DetectTarget("bulge", c - rad, c + rad, centre_m=c, radius_m=rad)
        return cls((conv, bulge), tuple(float(m) for m in np.sort(mags)), s0, c + rad,
                   (s0, a))

    def deformations(self, magnitude_m: float) -> list[Deformation]:
        """Every field of the layout at ``magnitude_m`` (m)."""
        return [d for t in self.targets for d in t.deformations(magnitude_m)]

    @property
    def length_m(self) -> float:
        return self.end_m - self.start_m

    def to_dict(self) -> dict[str, Any]:
        return {"start_m": self.start_m, "end_m": self.end_m,
                "reference_m": list(self.reference_m),
                "magnitudes_m": list(self.magnitudes_m),
                "targets": [t.to_dict() for t in self.targets]}
