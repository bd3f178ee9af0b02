"""Convergence per cross-section between two epochs, as tunnel monitoring reports it.

- ``chords``: lengths between named points (convergence bolts, prisms: the tunnel
  JSON's ``control_points``) in each epoch, and their change. Convergence is the
  shortening L1 - L2 (positive: the section closes). With a point precision
  ``sigma_m`` (per coordinate, each epoch) a chord's length has variance ~2 sigma^2
  (each end's error projected on the chord), its change 4 sigma^2, so
  LoD95 = 1.96 * 2 sigma.
- ``radial_change``: in the alignment frame, per section (a band of +-``band_m`` about
  a chainage) and per angular bin about the section centre, the radius of each epoch
  at the bin centre and their difference r1 - r2 (positive inward: convergence, the
  sign of ``survey.world.deformation``). Angles are measured from the crown, positive
  to the left (the deformation module's phi).

  DECISION: the radius at the bin centre comes from a least-squares plane
  r = a + b (phi - phi_c) + c (s - s0) through the bin's points, not from their mean:
  the mean radius of a bin depends on where the points fall in it whenever the
  profile is not a circle about the centre (a horseshoe, overbreak) or the section
  changes along the band, and the two epochs are never sampled alike. Its standard
  error gives LoD95 = 1.96 sqrt(se1^2 + se2^2).

Units: metres and radians inside; chainages along the ``Alignment``.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from raytrace.checks import as_points
from survey.errors import CompareError

if TYPE_CHECKING:
    from survey.world.alignment import Alignment

__all__ = ["LOD_Z", "MIN_BIN_POINTS", "Chords", "RadialChange", "chords",
           "control_points", "radial_change", "section_pairs", "sections_every", "summarise"]

Floats = NDArray[np.float64]

#: The 95 % two-sided normal quantile (as M3C2's LoD95).
LOD_Z = 1.96
#: Fewest points in an angular bin for its radius fit (3 parameters + 2 for a spread).
MIN_BIN_POINTS = 5


def control_points(meta: Mapping[str, Any]) -> dict[str, Floats]:
    """{id: xyz (3,)} of a tunnel JSON's ``control_points`` (``read_meta``)."""
    cps = meta.get("control_points")
    if not cps:
        raise CompareError("Expected 'control_points' in the tunnel JSON (a file written "
                           "by 'tunnelsim tunnel' with prisms), got none.")
    return {str(c["id"]): np.asarray(c["xyz"], dtype=np.float64) for c in cps}


@dataclass(repr=False)
class Chords:
    """Chord lengths between named points in two epochs; (k,) arrays in metres.

    Attributes
    ----------
    id_a, id_b : list of str, the chord's two ends
    chainage_m : mean chainage of the two ends (NaN without an alignment)
    length1_m, length2_m : lengths in epoch 1 and 2
    convergence_m : length1_m - length2_m (positive: shortened)
    lod_m : LoD95 of the change (NaN without ``sigma_m``)
    significant : (k,) bool, ``|convergence_m| > lod_m``
    """

    id_a: list[str]
    id_b: list[str]
    chainage_m: Floats
    length1_m: Floats
    length2_m: Floats
    convergence_m: Floats
    lod_m: Floats
    significant: NDArray[np.bool_]

    def __len__(self) -> int:
        return len(self.id_a)

    def __repr__(self) -> str:
        if not len(self):
            return "Chords(0 chords)"
        big = int(np.argmax(np.abs(self.convergence_m)))
        return (f"Chords({len(self)} chords, largest convergence "
                f"{1000 * self.convergence_m[big]:+.2f} mm on {self.id_a[big]}-"
                f"{self.id_b[big]})")

    def rows(self) -> list[dict[str, Any]]:
        """One dict per chord (for CSV and JSON)."""
        return [{"id_a": a, "id_b": b, "chainage_m": float(s), "length1_m": float(l1),
                 "length2_m": float(l2), "convergence_m": float(c), "lod_m": float(d),
                 "significant": bool(g)}
                for a, b, s, l1, l2, c, d, g in zip(
                    self.id_a, self.id_b, self.chainage_m, self.length1_m,
                    self.length2_m, self.convergence_m, self.lod_m, self.significant)]


def _named(points: Mapping[str, ArrayLike], name: str) -> dict[str, Floats]:
    out = {}
    for k, v in points.items():
        p = np.asarray(v, dtype=np.float64)
        if p.shape != (3,) or not np.isfinite(p).all():
            raise CompareError(f"Expected point {k!r} of `{name}` as finite (3,) "
                               f"coordinates, got {np.asarray(v).tolist()!r}.")
        out[str(k)] = p
    return out


def section_pairs(points: Mapping[str, ArrayLike], alignment: Alignment, *,
                  section_tol_m: float = 0.5) -> list[tuple[str, str]]:
    """Every pair of named points in one cross-section: chainages (``to_local``)
    within ``section_tol_m`` of each other; in id order."""
    pts = _named(points, "points")
    ids = sorted(pts)
    if not ids:
        return []
    s, _, _ = alignment.to_local(np.stack([pts[i] for i in ids]))
    return [(a, b) for i, a in enumerate(ids) for j, b in enumerate(ids)
            if j > i and abs(s[i] - s[j]) <= section_tol_m]


def chords(points1: Mapping[str, ArrayLike], points2: Mapping[str, ArrayLike],
           pairs: Iterable[tuple[str, str]] | None = None, *,
           alignment: Alignment | None = None, section_tol_m: float = 0.5,
           sigma_m: float | None = None) -> Chords:
    """Chord lengths between named points in two epochs and their convergence.

    Parameters
    ----------
    points1, points2 : mapping of str to (3,) array_like of float
        {id: xyz} in epoch 1 and 2, metres (``control_points`` of the tunnel JSONs).
    pairs : iterable of (str, str), optional
        Chords to measure; by default every pair in one cross-section
        (``section_pairs`` of epoch 1, which needs ``alignment``).
    alignment : Alignment, optional
        Gives each chord's chainage (and the default pairs).
    section_tol_m : float
        Largest chainage difference of two points of one section, m.
    sigma_m : float, optional
        Point precision per coordinate and epoch, m: gives LoD95 = 1.96 * 2 sigma.

    Returns
    -------
    Chords

    Raises
    ------
    CompareError
        A pair names a point missing in an epoch; no pairs and no alignment; bad
        coordinates or sigma.
    """
    p1, p2 = _named(points1, "points1"), _named(points2, "points2")
    if pairs is None:
        if alignment is None:
            raise CompareError("Expected `pairs` or an `alignment` to find the points of "
                               "each section, got neither.")
        pairs = section_pairs({k: v for k, v in p1.items() if k in p2}, alignment,
                              section_tol_m=section_tol_m)
    pairs = [(str(a), str(b)) for a, b in pairs]
    for a, b in pairs:
        for k in (a, b):
            for name, p in (("epoch 1", p1), ("epoch 2", p2)):
                if k not in p:
                    raise CompareError(f"Expected point {k!r} of chord {a}-{b} in {name}, "
                                       f"got ids {sorted(p)[:8]}.")
    if sigma_m is not None and not (np.isfinite(sigma_m) and sigma_m >= 0):
        raise CompareError(f"Expected `sigma_m` >= 0, got {sigma_m!r}.")
    n_ch = len(pairs)
    a1 = np.array([p1[a] for a, _ in pairs]).reshape(n_ch, 3)
    b1 = np.array([p1[b] for _, b in pairs]).reshape(n_ch, 3)
    a2 = np.array([p2[a] for a, _ in pairs]).reshape(n_ch, 3)
    b2 = np.array([p2[b] for _, b in pairs]).reshape(n_ch, 3)
    # Differences first: UTM-sized coordinates cancel exactly before the norm.
    l1 = np.linalg.norm(b1 - a1, axis=1)
    l2 = np.linalg.norm(b2 - a2, axis=1)
    conv = l1 - l2
    if alignment is not None and n_ch:
        s, _, _ = alignment.to_local(np.concatenate([a1, b1]))
        ch = 0.5 * (s[:n_ch] + s[n_ch:])
    else:
        ch = np.full(n_ch, np.nan)
    lod = np.full(n_ch, np.nan if sigma_m is None else LOD_Z * 2.0 * float(sigma_m))
    with np.errstate(invalid="ignore"):
        sig = np.abs(conv) > lod
    return Chords([a for a, _ in pairs], [b for _, b in pairs], ch, l1, l2, conv, lod, sig)


@dataclass(repr=False)
class RadialChange:
    """Radial change by angle in one cross-section; (k,) arrays over angular bins.

    Attributes
    ----------
    chainage_m : float, the section
    angle_rad : bin centres, from the crown, positive to the left
    radius1_m, radius2_m : radius about the section centre at the bin centre (NaN:
        fewer than ``MIN_BIN_POINTS`` points)
    change_m : radius1_m - radius2_m (positive inward: convergence)
    lod_m : LoD95 of the change from the fits' standard errors
    n1, n2 : points in the bin per epoch
    significant : (k,) bool, ``|change_m| > lod_m``
    """

    chainage_m: float
    angle_rad: Floats
    radius1_m: Floats
    radius2_m: Floats
    change_m: Floats
    lod_m: Floats
    n1: NDArray[np.int64]
    n2: NDArray[np.int64]
    significant: NDArray[np.bool_]

    def __repr__(self) -> str:
        ok = np.isfinite(self.change_m)
        if not ok.any():
            return f"RadialChange(chainage {self.chainage_m:g} m, no bin with points)"
        return (f"RadialChange(chainage {self.chainage_m:g} m, {int(ok.sum())} bins, "
                f"median {1000 * np.median(self.change_m[ok]):+.2f} mm, "
                f"{int(self.significant.sum())} significant)")


def _local(points: ArrayLike, alignment: Alignment, centre: Floats, name: str
           ) -> tuple[Floats, Floats, Floats]:
    """(chainage, angle from the crown, radius about centre) of world points."""
    p, _ = as_points(points, name, CompareError)
    s, off, h = alignment.to_local(p) if len(p) else (np.empty(0),) * 3
    x, y = off - centre[0], h - centre[1]
    return s, np.arctan2(x, y), np.hypot(x, y)


def _bin_fit(phi: Floats, s: Floats, r: Floats, phi_c: float, s0: float
             ) -> tuple[float, float]:
    """Radius at (phi_c, s0) and its standard error from r = a + b dphi + c ds."""
    if len(r) < MIN_BIN_POINTS:
        return np.nan, np.nan
    dphi = np.mod(phi - phi_c + np.pi, 2 * np.pi) - np.pi
    x = np.stack([np.ones_like(r), dphi, s - s0], axis=1)
    if np.ptp(s) < 1e-9:        # one ring: no along-axis term
        x = x[:, :2]
    coef, _, rank, _ = np.linalg.lstsq(x, r, rcond=None)
    if rank < x.shape[1]:
        return np.nan, np.nan
    res = r - x @ coef
    dof = len(r) - x.shape[1]
    s2 = float(res @ res) / dof
    cov = s2 * np.linalg.inv(x.T @ x)
    return float(coef[0]), float(np.sqrt(max(cov[0, 0], 0.0)))


def radial_change(epoch1: ArrayLike, epoch2: ArrayLike, alignment: Alignment,
                  chainages_m: ArrayLike, *, centre: ArrayLike = (0.0, 0.0),
                  band_m: float = 0.25, angle_step_rad: float = np.deg2rad(5.0)
                  ) -> list[RadialChange]:
    """Radial change by angle between two epochs, per cross-section (module doc).

    Parameters
    ----------
    epoch1, epoch2 : (n, 3) array_like of float
        Points of each epoch (world, metres; lining points: clip features first).
    alignment : Alignment
        The tunnel axis; sections are cut perpendicular to it.
    chainages_m : (k,) array_like of float
        Section chainages, within the alignment.
    centre : (2,) array_like of float
        Section centre (left offset, height above the alignment), m: the profile's
        centroid.
    band_m : float
        Half-width of each section along the axis, m.
    angle_step_rad : float
        Angular bin width, rad (bins centred on 0, the crown).

    Returns
    -------
    list of RadialChange
        One per chainage.

    Raises
    ------
    CompareError
        Chainages outside the alignment, a non-positive band or step, an empty
        band in an epoch.
    """
    ch = np.atleast_1d(np.asarray(chainages_m, dtype=np.float64))
    lo, hi = alignment.chainage_range
    bad = ch[~((ch >= lo) & (ch <= hi))]
    if bad.size:
        raise CompareError(f"Expected chainages within the alignment [{lo:g}, {hi:g}] m, "
                           f"got {bad.tolist()[:5]}.")
    if not (np.isfinite(band_m) and band_m > 0):
        raise CompareError(f"Expected a positive `band_m`, got {band_m!r}.")
    nb = int(round(2 * np.pi / angle_step_rad)) if angle_step_rad > 0 else 0
    if nb < 1 or not np.isfinite(angle_step_rad):
        raise CompareError(f"Expected `angle_step_rad` in (0, 2 pi], got "
                           f"{angle_step_rad!r}.")
    step = 2 * np.pi / nb
    c = np.asarray(centre, dtype=np.float64).reshape(2)
    e1 = _local(epoch1, alignment, c, "epoch1")
    e2 = _local(epoch2, alignment, c, "epoch2")
    centres: Floats = ((np.arange(nb) * step + np.pi) % (2 * np.pi) - np.pi).astype(
        np.float64)
    out = []
    for s0 in ch:
        fits = []
        for name, (s, phi, r) in (("epoch 1", e1), ("epoch 2", e2)):
            inb = np.abs(s - s0) <= band_m
            if not inb.any():
                raise CompareError(f"Expected points of {name} within +-{band_m:g} m of "
                                   f"chainage {s0:g} m, got none; widen the band or "
                                   "check the chainage.")
            sb, pb, rb = s[inb], phi[inb], r[inb]
            k = np.round(pb / step).astype(np.int64) % nb
            rad = np.full(nb, np.nan)
            se = np.full(nb, np.nan)
            cnt = np.bincount(k, minlength=nb).astype(np.int64)
            order = np.argsort(k, kind="stable")
            starts = np.concatenate([[0], np.cumsum(cnt)])
            for j in range(nb):
                sel = order[starts[j]:starts[j + 1]]
                rad[j], se[j] = _bin_fit(pb[sel], sb[sel], rb[sel], centres[j], s0)
            fits.append((rad, se, cnt))
        (r1, se1, n1), (r2, se2, n2) = fits
        change = r1 - r2
        lod = LOD_Z * np.sqrt(se1 ** 2 + se2 ** 2)
        with np.errstate(invalid="ignore"):
            sig = np.abs(change) > lod
        out.append(RadialChange(float(s0), centres, r1, r2, change, lod, n1, n2, sig))
    return out


def sections_every(alignment: Alignment, step_m: float, *, margin_m: float = 0.0
                   ) -> Floats:
    """Chainages (k,) float64 at whole multiples of ``step_m`` (0+010, 0+020, ... as
    surveyors number sections, whatever chainage the alignment starts at) lying at
    least ``margin_m`` inside its ends."""
    lo, hi = alignment.chainage_range
    if not (np.isfinite(step_m) and step_m > 0):
        raise CompareError(f"Expected a positive section step, got {step_m!r}.")
    # DECISION: multiples of the step, not lo + k step: a fitted or extended axis
    # starts anywhere, and sections at 9, 19, 29 m are not the 10 m stations asked.
    k0 = int(np.ceil((lo + margin_m) / step_m - 1e-9))
    k1 = int(np.floor((hi - margin_m) / step_m + 1e-9))
    return np.arange(k0, k1 + 1, dtype=np.float64) * step_m


def summarise(changes: Sequence[RadialChange]) -> list[dict[str, Any]]:
    """Per section: chainage, bins with a value, median / min / max change and the
    significant bins (for reports)."""
    rows = []
    for rc in changes:
        ok = np.isfinite(rc.change_m)
        v = rc.change_m[ok]
        rows.append({"chainage_m": rc.chainage_m, "bins": int(ok.sum()),
                     "median_m": float(np.median(v)) if v.size else float("nan"),
                     "min_m": float(v.min()) if v.size else float("nan"),
                     "max_m": float(v.max()) if v.size else float("nan"),
                     "significant": int(rc.significant.sum())})
    return rows
