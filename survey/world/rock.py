"""Surface relief of a tunnel lining: fine texture and drill-and-blast overbreak.

Every field here lives on the developed lining: chainage ``s`` along the alignment and
the profile's arc-length parameter ``t`` around it (both metres). A value is an offset
along the profile's outward normal: positive moves the surface away from the tunnel
axis (overbreak), negative into the tunnel (underbreak).

Two layers:

- **Texture** (``texture_field``): a stationary Gaussian random field with Gaussian
  autocorrelation exp(-d^2 / (2 L^2)), made by smoothing white noise on a fixed grid
  (L/4 cells) with a Gaussian kernel of standard deviation L / sqrt(2), interpolated
  bilinearly, scaled to the rms and clipped at ``TEXTURE_CLIP`` standard deviations.
  This is the lining roughness the generator has always had (shotcrete, segments); the
  same seed gives the same surface as before.
- **Rock relief** (``RockRelief``): what a drill-and-blast excavation leaves, on top of
  the texture, tapered to zero on the floor (floors are levelled or ballasted):

  1. overbreak: a second stationary Gaussian field with metre-scale correlation and
     decimetre rms around a positive mean, clipped below at ``-underbreak_max_m``
     (little underbreak is tolerated: protruding rock is scaled or re-blasted) and
     above at ``OVERBREAK_CLIP`` standard deviations;
  2. look-out: contour holes are drilled angled outwards so the next round's drill
     boom has room, so each round ends further outside the design line than it began:
     a sawtooth in chainage, period the round length, height the look-out, each round
     with its own length and height (jitter) so it is not perfectly periodic.

Fields are sampled on fixed grids and interpolated, so the surface does not depend on
the mesh resolution, and every value is bounded (``RockRelief.overbreak_max_m``,
``underbreak_max_m``, ``TEXTURE_CLIP`` x rms), so the generator knows how far the
surface can reach.

Sources. What overbreak looks like, and why it is modelled as a field varying along the
tunnel and around the section: Mandal & Singh 2009, "Evaluating extent and causes of
overbreak in tunnels", Tunnelling and Underground Space Technology 24(1):22-36 (the same
controlled blast pattern gives different overbreak along a tunnel and between the left
wall, right wall and crown). The three measures of contour quality, overbreak depth,
contour roughness and the longitudinal variation of overbreak within a round (Kim &
Bruland's Tunnel Contour Quality Index), measured per 3.0 m blasting round with a
terrestrial laser scanner and with the floor left out of the analysis: Dybeł et al.
2021, "Evaluation of Tunnel Contour Quality Index on the Basis of Terrestrial Laser
Scanning Data", Studia Geotechnica et Mechanica 43(3):255-269, doi:10.2478/sgem-2021-0013.
The look-out distance of the contour holes as a driver of the excavated distance beyond
them: Navarro et al., "Detection of potential overbreak zones in tunnel blasting from
MWD data" (54 blasts, ~1700 contour holes, >4000 scanned sections). Reported overbreak
of 5-10 % for competent, well blasted rock and more than 25 % for fractured or poorly
blasted rock: Schmitz 2003, "Line infrastructure and the role of engineering geology in
analysing overbreak", Ingeokring Newsletter (as summarised where we could read it; for
the 2.8 m bfo gallery, 5-10 % of its 6.7 m^2 section spread over its 7.0 m of wall and
roof is a mean depth of 5-9 cm). The numbers of ``RockRelief``'s defaults were not
found in a source for the BFO gallery and are ASSUMED; each says so.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, fields, replace
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from survey.errors import TunnelError
from survey.world.profiles import Profile

__all__ = ["OVERBREAK_CLIP", "RockRelief", "TEXTURE_CLIP", "floor_weight",
           "surface_relief", "texture_field"]

Floats = NDArray[np.float64]

#: The texture (lining roughness) is clipped at this many standard deviations.
TEXTURE_CLIP = 3.5
#: The Gaussian part of the overbreak is clipped above at this many standard deviations.
OVERBREAK_CLIP = 3.5
#: Grid cells per correlation length of the texture field (kept: same surface as before).
_TEXTURE_CELLS = 4
#: Grid cells per correlation length of the overbreak field: finer than the texture's,
#: so that bilinear interpolation loses < 0.5 % of the variance between grid nodes
#: (1 - (1 + exp(-1/128)) / 2 at a cell centre along one axis).
_OVERBREAK_CELLS = 8
#: scipy.ndimage's default kernel truncation (standard deviations).
_TRUNCATE = 4.0
#: Independent random streams derived from the tunnel's seed (the texture keeps the
#: seed itself, as it always had).
_STREAM_OVERBREAK, _STREAM_ROUNDS = 1, 2


@dataclass(frozen=True)
class RockRelief:
    """Overbreak relief of an unlined or shotcreted drill-and-blast tunnel (metres).

    Defaults describe an old drill-and-blast gallery a few metres wide; all are ASSUMED
    except where noted (see the module's sources).

    Attributes
    ----------
    overbreak_mean_m : float
        Mean of the Gaussian overbreak (before clipping), >= 0. ASSUMED 0.07 m: with the
        look-out's mean of ~5 cm the wall and roof lie ~12 cm outside the design line on
        average, ~13 % of a 2.8 m gallery's section (Schmitz 2003: 5-10 % for
        competent rock, > 25 % when fractured or poorly blasted).
    overbreak_rms_m : float
        Standard deviation of the Gaussian overbreak. ASSUMED 0.07 m (decimetre relief).
    overbreak_corr_m : float
        Correlation length (along the tunnel and around the section) of the overbreak.
        ASSUMED 1.2 m: blocks bounded by joints, a few contour-hole spacings wide.
    underbreak_max_m : float
        Largest underbreak (the overbreak is clipped below at minus this). ASSUMED 0.02 m.
    round_length_m : float
        Advance per blasting round (the look-out's period). 3.0 m as in the rounds
        measured by Dybeł et al. 2021; ASSUMED for BFO.
    round_jitter : float
        Each round's length is ``round_length_m`` x (1 + U(-j, j)), 0 <= j < 1.
        ASSUMED 0.1.
    lookout_m : float
        Look-out at the end of a round: how far outside the start of the round the
        contour holes end. ASSUMED 0.10 m.
    lookout_jitter : float
        Each round's look-out is ``lookout_m`` x (1 + U(-j, j)), 0 <= j < 1.
        ASSUMED 0.3.
    lookout_step_m : float
        Length over which the surface steps back from one round's look-out to the next
        round's start. ASSUMED 0.3 m; a true step would be a vertical wall.
    floor_taper_m : float
        Arc length up the walls over which the overbreak grows from zero on the floor to
        its full value (a smoothstep). ASSUMED 0.3 m.
    texture_rms_m, texture_corr_m : float
        Fine texture on everything, floor included (the generator's roughness field).
        ASSUMED 0.01 m and 0.3 m.
    """

    overbreak_mean_m: float = 0.07
    overbreak_rms_m: float = 0.07
    overbreak_corr_m: float = 1.2
    underbreak_max_m: float = 0.02
    round_length_m: float = 3.0
    round_jitter: float = 0.1
    lookout_m: float = 0.10
    lookout_jitter: float = 0.3
    lookout_step_m: float = 0.3
    floor_taper_m: float = 0.3
    texture_rms_m: float = 0.01
    texture_corr_m: float = 0.3

    def __post_init__(self) -> None:
        for f in fields(self):
            v = getattr(self, f.name)
            if isinstance(v, bool) or not isinstance(v, (int, float, np.floating)) or \
                    not np.isfinite(v) or v < 0:
                raise TunnelError(f"Expected `{f.name}` to be a number >= 0, got {v!r}.")
            object.__setattr__(self, f.name, float(v))
        for name in ("round_jitter", "lookout_jitter"):
            if getattr(self, name) >= 1:
                raise TunnelError(f"Expected `{name}` below 1 (a fraction), got "
                                  f"{getattr(self, name)}.")
        for rms, corr in (("overbreak_rms_m", "overbreak_corr_m"),
                          ("texture_rms_m", "texture_corr_m")):
            if getattr(self, rms) > 0 and getattr(self, corr) <= 0:
                raise TunnelError(f"Expected a positive `{corr}` with `{rms}` > 0, got 0.")
        if self.lookout_m > 0:
            shortest = self.round_length_m * (1 - self.round_jitter)
            if not 0 < self.lookout_step_m < shortest / 2:
                raise TunnelError(f"Expected `lookout_step_m` in (0, {shortest / 2:g}) m "
                                  f"(half the shortest round), got {self.lookout_step_m}; "
                                  "lengthen the rounds or shorten the step.")

    # ------------------------------------------------------------------ bounds
    @property
    def overbreak_max_m(self) -> float:
        """Largest outward offset of the overbreak (texture not included)."""
        return self.overbreak_mean_m + OVERBREAK_CLIP * self.overbreak_rms_m + \
            self.lookout_m * (1 + self.lookout_jitter)

    def scaled(self, factor: float) -> RockRelief:
        """The same relief with the overbreak (mean, rms, underbreak limit and look-out)
        times ``factor`` >= 0; lengths along the surface and the texture kept. 0 leaves
        the texture only."""
        k = float(factor)
        if not (np.isfinite(k) and k >= 0):
            raise TunnelError(f"Expected a relief scale factor >= 0, got {factor}.")
        return replace(self, overbreak_mean_m=k * self.overbreak_mean_m,
                       overbreak_rms_m=k * self.overbreak_rms_m,
                       underbreak_max_m=k * self.underbreak_max_m,
                       lookout_m=k * self.lookout_m)

    def to_dict(self) -> dict[str, float]:
        """Plain data (JSON-ready); ``RockRelief.from_dict`` reads it back."""
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> RockRelief:
        """The relief of a ``to_dict`` dictionary; unknown keys are refused."""
        known = {f.name for f in fields(cls)}
        if not isinstance(d, dict) or set(d) - known:
            got = sorted(set(d) - known) if isinstance(d, dict) else type(d).__name__
            raise TunnelError(f"Expected RockRelief fields {sorted(known)}, got {got}.")
        return cls(**d)

    # ------------------------------------------------------------------ fields
    def rounds(self, c0: float, c1: float, seed: int) -> tuple[Floats, Floats]:
        """Blasting rounds covering chainages [c0, c1]: (starts (n + 1,) float64, the
        chainage where each round began and, last, where the final one ended;
        look-outs (n,) float64). The first round starts up to one round before c0
        (random phase)."""
        # DECISION: the tunnel was driven towards increasing chainage (from the portal
        # at the first chainage), so the look-out grows with chainage inside a round.
        rng = np.random.default_rng([int(seed), _STREAM_ROUNDS])
        length = self.round_length_m
        first = c0 - rng.uniform(0.0, length)
        n = int(np.ceil((c1 - first) / (length * (1 - self.round_jitter)))) + 1
        lengths = length * (1 + self.round_jitter * rng.uniform(-1.0, 1.0, n))
        amps = self.lookout_m * (1 + self.lookout_jitter * rng.uniform(-1.0, 1.0, n))
        starts = first + np.concatenate([[0.0], np.cumsum(lengths)])
        keep = int(np.searchsorted(starts, c1, side="left"))   # rounds starting < c1
        keep = max(keep, 1)
        return starts[:keep + 1], amps[:keep]

    def lookout(self, s: ArrayLike, c0: float, c1: float, seed: int) -> Floats:
        """Look-out sawtooth (len(s),) at chainages s: within round k (start b_k) the
        surface steps down over ``lookout_step_m`` from the previous round's look-out
        to 0, then rises linearly to this round's look-out at its end."""
        s = np.asarray(s, dtype=np.float64)
        if self.lookout_m == 0:
            return np.zeros(s.shape)
        starts, amps = self.rounds(c0, c1, seed)
        prev = np.concatenate([[0.0], amps[:-1]])
        xs = np.stack([starts[:-1], starts[:-1] + self.lookout_step_m], 1).ravel()
        ys = np.stack([prev, np.zeros(len(amps))], 1).ravel()
        xs = np.append(xs, starts[-1])
        ys = np.append(ys, amps[-1])
        return np.asarray(np.interp(s, xs, ys), dtype=np.float64)

    def overbreak(self, profile: Profile, s: ArrayLike, t: ArrayLike, c0: float,
                  c1: float, seed: int) -> Floats:
        """Overbreak (len(s), len(t)) float64 on the grid of chainages s (within
        [c0, c1]) x profile parameters t: clipped Gaussian field plus look-out, times
        the floor taper. Texture not included."""
        s = np.asarray(s, dtype=np.float64)
        t = np.asarray(t, dtype=np.float64)
        per = profile.perimeter_m
        out = np.full((len(s), len(t)), self.overbreak_mean_m)
        if self.overbreak_rms_m > 0:
            rng = np.random.default_rng([int(seed), _STREAM_OVERBREAK])
            g = _gaussian(s, t, c0, c1 - c0, per, self.overbreak_corr_m, rng,
                          _OVERBREAK_CELLS, stationary=True)
            out += self.overbreak_rms_m * g
        out = np.clip(out, -self.underbreak_max_m,
                      self.overbreak_mean_m + OVERBREAK_CLIP * self.overbreak_rms_m)
        out += self.lookout(s, c0, c1, seed)[:, None]
        return out * floor_weight(profile, t, self.floor_taper_m)[None, :]


def _gaussian(s: Floats, t: Floats, s0: float, length: float, perimeter: float,
              corr: float, rng: np.random.Generator, cells: int, stationary: bool
              ) -> Floats:
    """Unit-variance Gaussian field (len(s), len(t)) with autocorrelation
    exp(-d^2 / (2 corr^2)): white noise on a grid of corr/cells cells (periodic in t),
    smoothed by a Gaussian kernel of standard deviation corr / sqrt(2) (the convolution
    of two such kernels has variance corr^2), interpolated bilinearly.

    ``stationary=False`` is the texture's original recipe: the grid spans [s0, s0 +
    length] exactly, 'nearest' at its ends, scaled by the sample standard deviation.
    ``stationary=True`` pads the grid by the kernel's reach at both ends and scales by
    the kernel's exact standard deviation, so the field is stationary up to the ends and
    its sample statistics scatter as a random field's should."""
    from scipy.ndimage import gaussian_filter, gaussian_filter1d, map_coordinates

    g = corr / cells
    ns = int(np.ceil(length / g)) + 1
    nt = max(8, int(np.ceil(perimeter / g)))
    gs, gt = length / (ns - 1), perimeter / nt
    sig = corr / np.sqrt(2.0)
    pad = int(np.ceil(_TRUNCATE * sig / gs)) + 1 if stationary else 0
    noise = rng.standard_normal((ns + 2 * pad, nt))
    fld = gaussian_filter(noise, (sig / gs, sig / gt), mode=("nearest", "wrap"),
                          truncate=_TRUNCATE)
    if stationary:
        fld = fld[pad:pad + ns]
        # Exact variance of the smoothed noise: the squared weights of the discrete
        # kernel (an impulse response), the t kernel wrapped around the perimeter.
        imp_s = np.zeros(2 * pad + 1)
        imp_s[pad] = 1.0
        imp_t = np.zeros(nt)
        imp_t[0] = 1.0
        ks = gaussian_filter1d(imp_s, sig / gs, mode="constant", truncate=_TRUNCATE)
        kt = gaussian_filter1d(imp_t, sig / gt, mode="wrap", truncate=_TRUNCATE)
        fld /= np.sqrt(np.sum(ks ** 2) * np.sum(kt ** 2))
    else:
        fld /= max(fld.std(), 1e-300)
    fld = np.concatenate([fld, fld[:, :1]], axis=1)  # periodic in t
    ii = np.broadcast_to(((s - s0) / gs)[:, None], (len(s), len(t)))
    jj = np.broadcast_to((np.mod(t, perimeter) / gt)[None, :], (len(s), len(t)))
    out = map_coordinates(fld, [ii.ravel(), jj.ravel()], order=1, mode="nearest")
    return np.asarray(out.reshape(len(s), len(t)), dtype=np.float64)


def texture_field(s: ArrayLike, t: ArrayLike, s0: float, length_m: float,
                  perimeter_m: float, rms_m: float, corr_m: float, seed: int) -> Floats:
    """Texture (lining roughness) (len(s), len(t)) float64 at chainages s in [s0, s0 +
    length_m] x profile parameters t: standard deviation ``rms_m``, correlation length
    ``corr_m``, clipped at ``TEXTURE_CLIP`` x rms (see the module doc)."""
    s = np.asarray(s, dtype=np.float64)
    t = np.asarray(t, dtype=np.float64)
    if rms_m == 0:
        return np.zeros((len(s), len(t)))
    # DECISION: the seed itself (not a derived stream) and the sample-std scaling, so a
    # smooth tunnel is the same surface, bit for bit, as before the rock relief existed.
    g = _gaussian(s, t, s0, length_m, perimeter_m, corr_m, np.random.default_rng(seed),
                  _TEXTURE_CELLS, stationary=False)
    return np.clip(g * rms_m, -TEXTURE_CLIP * rms_m, TEXTURE_CLIP * rms_m)


def floor_weight(profile: Profile, t: ArrayLike, taper_m: float) -> Floats:
    """Weight (len(t),) float64 of the overbreak: 0 on the floor (the closure of where
    ``Profile.is_floor``, so floor corners included), rising as a smoothstep 3x^2 - 2x^3
    of x = (arc length from the floor) / taper_m to 1 at ``taper_m`` up the walls. A
    profile without floor gets 1 everywhere."""
    per = profile.perimeter_m
    t = np.mod(np.asarray(t, dtype=np.float64), per)
    td, _ = profile.dense()
    nxt = np.append(td[1:], per)
    fl = profile.is_floor(0.5 * (td + nxt))          # dense segments (~1 mm) on the floor
    a, b = td[fl], nxt[fl]
    if len(a) == 0:
        return np.ones(t.shape)
    i = (np.searchsorted(a, t, side="right") - 1) % len(a)
    inside = np.mod(t - a[i], per) <= b[i] - a[i]
    d = np.minimum(np.mod(t - b[i], per), np.mod(a[(i + 1) % len(a)] - t, per))
    d = np.where(inside, 0.0, d)
    if taper_m == 0:
        return np.where(d > 0, 1.0, 0.0)
    x = np.clip(d / taper_m, 0.0, 1.0)
    return np.asarray(x * x * (3.0 - 2.0 * x), dtype=np.float64)


def surface_relief(profile: Profile, s: ArrayLike, t: ArrayLike, c0: float, c1: float, *,
                   texture_rms_m: float, texture_corr_m: float,
                   relief: RockRelief | None = None, seed: int = 0) -> Floats:
    """Offset (len(s), len(t)) float64 of the lining from the design profile along its
    outward normal, at chainages s in [c0, c1] x profile parameters t: the texture, plus
    the rock relief's overbreak when ``relief`` is given (its own texture fields are
    not read here: the caller decides the texture)."""
    out = texture_field(s, t, c0, c1 - c0, profile.perimeter_m, texture_rms_m,
                        texture_corr_m, seed)
    if relief is not None:
        out = out + relief.overbreak(profile, s, t, c0, c1, seed)
    return out
