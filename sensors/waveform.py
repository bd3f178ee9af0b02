"""Full waveform and multiple returns: every echo a pulse's footprint makes, and which of
them a device reports in each return mode.

Model (per pulse; Wagner et al. 2006, "Gaussian decomposition and calibration of a novel
small-footprint full-waveform digitising airborne laser scanner", ISPRS J. 60(2); the
discretisation as HELIOS++ does it, Winiwarter et al. 2022, "Virtual laser scanning
with HELIOS++", Remote Sens. Environ. 269, and its ``FWFSettings``: 0.25 ns bins, a
4 ns pulse, the beam sampled by rings of sub-rays, peaks found in the summed waveform):

- The emitted pulse is a Gaussian in time of full width at half maximum ``pulse_fwhm_s``
  (from the device's datasheet, or ASSUMED where none gives it); in range it is a
  Gaussian of sigma = c fwhm / (2 sqrt(2 ln 2)) / 2 (two-way travel).
- Each contribution (a sub-ray of the footprint at its own range, or an airborne
  particle) adds that shape at its range, scaled by the power ``sensors.physics``
  already computes for it (rho cos(theta) / R^2 exp(-2 alpha R)) times its footprint
  weight. The sum is sampled at bin centres ``k * bin_m`` (bin_m = c bin_s / 2), on a
  grid anchored at range 0, so a waveform does not depend on the chunk it is in.
- Echoes, as a detector finds them: local maxima above a noise threshold, at least a
  minimum separation apart (about the pulse length x c / 2; the strongest wins), each
  refined by a Gaussian decomposition: a three-point Gaussian fit at its peak (Fisher &
  Naidu 1996, "A comparison of algorithms for subpixel peak detection") repeated on the
  waveform minus the other echoes' fitted Gaussians. An echo has a range (sub-bin), an
  amplitude (peak power) and a width (sigma, m); its ``power`` (the energy in units of
  the emitted pulse, amplitude x width / sigma) equals today's single-return,
  footprint-weighted power for a surface that fills the footprint.
- Return modes (``select_returns``): strongest, first, last, dual (``strongest_last``:
  Velodyne, Hesai; ``first_last``; ``strongest_second``: Ouster's two strongest) and
  all (the first N along the beam). Returns of a pulse are numbered along the beam
  (return_number 1 = nearest reported), number_of_returns = how many are reported.

>>> from sensors.waveform import WaveformModel, detect_echoes, select_returns
>>> model = WaveformModel(pulse_fwhm_s=4e-9, threshold_power=1e-6)
>>> e = detect_echoes([[10.0, 10.0, 11.0]], [[5e-4, 5e-4, 4e-4]], model)
>>> int(e.count[0]), e.range_m[0, :2].round(4).tolist()
(2, [10.0, 11.0])
>>> r = select_returns(e, "dual", dual="strongest_last")
>>> r.return_number.tolist(), r.number_of_returns.tolist()
([1, 2], [2, 2])

The simulation loop's entry point is ``chunk_returns`` (per-sub-ray arrays in, one row
per reported return out, with the echo's face, incidence, flag and return numbers);
the default single-return path of the simulation does not run any of this.

Full-waveform output (``Settings(waveform=True)``): ``wave_windows`` samples the summed
waveform each reported return was detected in, a fixed window of
``sensors.io.fields.WAVE_SAMPLES`` bins on the same grid (shared by a pulse's returns
where their echoes fit in it, else centred on each echo), quantised to 16-bit counts
of ``waveform_gain`` (the waveform threshold per count); the LAS writer stores the
windows as LAS 1.4 wave packets (``sensors.writers``).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, replace
from typing import Final, Protocol, TypeVar

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ._checks import as_number, as_whole
from .errors import SensorSpecError, SimulationError
# DECISION: the flags and RETURN_FIELDS come from sensors.io.fields (not sensors.physics),
# so that sensors.spec can import ReturnsSpec from here without an import cycle.
from .io.fields import FLAG_MIXED, FLAG_PARTICLE, FLAG_SURFACE, MIXED_SPREAD_M, RETURN_FIELDS



class Physics(Protocol):
    """What the waveform model reads of a device's ``sensors.spec.Physics``.

    DECISION: a protocol, not an import of sensors.spec (which imports ReturnsSpec
    from here): no import cycle, even one for type checking only."""

    @property
    def threshold_power(self) -> float: ...

    @property
    def detection_softness(self) -> float: ...

__all__ = ["BIN_S", "ChunkReturns", "DEFAULT_PULSE_FWHM_S", "DEFAULT_RETURNS",
           "DUAL_KINDS", "Echoes", "MAX_ECHOES", "RANGE_PER_PS_M", "RETURN_MODES", "Returns", "ReturnsSpec", "SPEED_OF_LIGHT_M_S", "WAVE_BITS",
           "WAVE_PAD_SIGMAS", "WaveWindows", "WaveformModel", "chunk_returns",
           "detect_echoes", "detection_threshold", "pulse_echoes", "renumber_returns",
           "select_returns", "wave_windows", "waveform_gain", "waveforms"]

#: Speed of light in vacuum (m/s); the ~3e-4 relative difference in air is ignored, as
#: the simulator's ranges are geometric.
SPEED_OF_LIGHT_M_S: Final = 299_792_458.0
#: Waveform bin (s): HELIOS++'s default ``binSize_ns`` = 0.25 (Winiwarter et al. 2022).
BIN_S: Final = 0.25e-9
#: Pulse width (FWHM, s) where no datasheet gives one: HELIOS++'s default
#: ``pulseLength_ns`` = 4 (ASSUMED for every device without a published value).
DEFAULT_PULSE_FWHM_S: Final = 4e-9
#: Echoes a waveform keeps at most, by default (the strongest, before mode selection).
MAX_ECHOES: Final = 8
#: Gauss-Seidel rounds of the Gaussian decomposition: each round refits every echo on
#: the waveform less the others; echoes a separation apart converge in 2-3 rounds.
REFINE_ITERATIONS: Final = 8
#: Local maxima a waveform keeps as candidates before the separation rule.
CANDIDATES_MAX: Final = 64
#: Pulses per scratch row of the kernel (fixed: results never depend on threads).
PULSE_BLOCK: Final = 256
#: The waveform's noise threshold sits this many detection softnesses below P_min
#: (``detection_threshold``): detection probability 1 / (1 + e^4) ~ 2 % there.
THRESHOLD_SOFTNESSES: Final = 4.0

RETURN_MODES: Final = ("strongest", "last", "first", "dual", "all")
DUAL_KINDS: Final = ("strongest_last", "first_last", "strongest_second")
_G = TypeVar("_G", bound=np.generic)
_FWHM_TO_SIGMA: Final = 1.0 / (2.0 * math.sqrt(2.0 * math.log(2.0)))


def _range_of_time(t_s: float) -> float:
    """Range (m) of a two-way travel time t_s (s): c t / 2."""
    return SPEED_OF_LIGHT_M_S * t_s / 2.0


@dataclass(frozen=True, kw_only=True)
class WaveformModel:
    """How a device's receiver sees a pulse (SI units), keyword-only.

    Parameters
    ----------
    pulse_fwhm_s : float > 0
        Emitted pulse width, full width at half maximum (s).
    threshold_power : float >= 0
        Noise threshold: a peak must exceed it to be an echo (relative power, the units
        of ``sensors.physics.power``).
    bin_s : float > 0
        Waveform bin (s); ``BIN_S`` (0.25 ns, HELIOS++) by default.
    separation_m : float > 0 or None
        Least range between two echoes; None: the pulse length x c / 2.
    max_echoes : int >= 1
        Echoes kept per pulse (the strongest).
    """

    pulse_fwhm_s: float
    threshold_power: float
    bin_s: float = BIN_S
    separation_m: float | None = None
    max_echoes: int = MAX_ECHOES

    def __post_init__(self) -> None:
        as_number(self.pulse_fwhm_s, "pulse_fwhm_s", SimulationError, unit="s", lo=0,
                  lo_open=True)
        as_number(self.threshold_power, "threshold_power", SimulationError,
                  unit="relative power", lo=0)
        as_number(self.bin_s, "bin_s", SimulationError, unit="s", lo=0, lo_open=True)
        if self.separation_m is not None:
            as_number(self.separation_m, "separation_m", SimulationError, unit="m", lo=0,
                      lo_open=True)
        as_whole(self.max_echoes, "max_echoes", SimulationError, lo=1)
        if self.sigma_m < self.bin_m:
            raise SimulationError(
                f"Expected the pulse ({self.pulse_fwhm_s * 1e9:g} ns FWHM) to span more "
                f"than one bin ({self.bin_s * 1e9:g} ns), got sigma {self.sigma_m:g} m < "
                f"bin {self.bin_m:g} m; use a smaller `bin_s`.")

    @property
    def sigma_m(self) -> float:
        """The pulse's sigma in range (m): c fwhm / (2 sqrt(2 ln 2)) / 2."""
        return _range_of_time(self.pulse_fwhm_s * _FWHM_TO_SIGMA)

    @property
    def bin_m(self) -> float:
        """One bin in range (m): c bin_s / 2."""
        return _range_of_time(self.bin_s)

    @property
    def min_separation_m(self) -> float:
        """Least range between two echoes (m): ``separation_m``, or the pulse length
        (its FWHM) x c / 2."""
        if self.separation_m is not None:
            return float(self.separation_m)
        return _range_of_time(self.pulse_fwhm_s)

    @classmethod
    def for_physics(cls, phys: Physics, pulse_fwhm_s: float = DEFAULT_PULSE_FWHM_S,
                    **kw: object) -> WaveformModel:
        """The model of a device with physics ``phys``: threshold from
        ``detection_threshold(phys)``."""
        return cls(pulse_fwhm_s=pulse_fwhm_s, threshold_power=detection_threshold(phys),
                   **kw)  # type: ignore[arg-type]


def detection_threshold(phys: Physics) -> float:
    """The waveform's noise threshold for a device: P_min exp(-4 softness), where its
    detection probability (``sensors.physics``) has fallen to ~2 %.

    DECISION: echoes are found deterministically above this floor, then each is
    detected with the probability of its power as a single return is today, so a
    pulse with one echo keeps today's statistics (bar the < 2 % tail below the floor).
    """
    return float(phys.threshold_power * math.exp(-THRESHOLD_SOFTNESSES *
                                                 phys.detection_softness))


@dataclass(frozen=True)
class Echoes:
    """Echoes of n pulses, at most e each, sorted by range.

    Attributes
    ----------
    range_m : (n, e) float64
        Echo ranges (m); inf where a pulse has fewer echoes.
    amplitude : (n, e) float64
        Peak of each echo's fitted Gaussian (relative power); 0 where none.
    width_m : (n, e) float64
        Sigma of each echo's fitted Gaussian (m); 0 where none.
    count : (n,) int64
        Echoes per pulse.
    sigma_m : float
        The emitted pulse's sigma (m), for ``power``.
    """

    range_m: NDArray[np.float64]
    amplitude: NDArray[np.float64]
    width_m: NDArray[np.float64]
    count: NDArray[np.int64]
    sigma_m: float

    @property
    def power(self) -> NDArray[np.float64]:
        """(n, e) float64: each echo's energy in units of the emitted pulse (amplitude
        x width / sigma): for a surface filling the footprint, the footprint-weighted
        power of the single-return model."""
        return self.amplitude * self.width_m / self.sigma_m

    def __len__(self) -> int:
        return int(self.count.shape[0])


@dataclass(frozen=True)
class Returns:
    """The returns a device reports, one row per output point, pulse by pulse and
    along the beam within a pulse.

    Attributes
    ----------
    pulse : (p,) int64
        Index of the pulse in the ``Echoes``.
    echo : (p,) int64
        Index of the echo in its pulse's row.
    return_number : (p,) uint8
        1 = nearest reported echo of the pulse.
    number_of_returns : (p,) uint8
        Echoes reported for the pulse.
    """

    pulse: NDArray[np.int64]
    echo: NDArray[np.int64]
    return_number: NDArray[np.uint8]
    number_of_returns: NDArray[np.uint8]

    def take(self, a: NDArray[_G]) -> NDArray[_G]:
        """The (p,) values of an (n, e) per-echo array (e.g. ``Echoes.range_m``)."""
        return a[self.pulse, self.echo]

    def __len__(self) -> int:
        return int(self.pulse.shape[0])


@dataclass(frozen=True, kw_only=True)
class ReturnsSpec:
    """What a device records: the ``[returns]`` table of a sensor TOML.

    Parameters
    ----------
    modes : tuple of str
        Return modes the device supports, from ``RETURN_MODES``; the first is its
        default.
    dual : str
        What ``dual`` means on this device, from ``DUAL_KINDS``.
    max_returns : int >= 1
        Echoes per pulse in ``all`` mode (2 where the device has dual at most).
    pulse_fwhm_ns : float > 0
        Pulse width (FWHM, ns).
    pulse_source : str
        Where the width comes from ("ASSUMED: ..." where no datasheet gives it).
    waveform : bool
        Whether the device records the full waveform (``Settings(waveform=True)``,
        ``--waveform``): the survey scanners.
    """

    modes: tuple[str, ...] = ("strongest",)
    dual: str = "strongest_last"
    max_returns: int = 1
    pulse_fwhm_ns: float = DEFAULT_PULSE_FWHM_S * 1e9
    pulse_source: str = "ASSUMED: HELIOS++ default pulse length"
    waveform: bool = False

    _KEYS = frozenset({"modes", "dual", "max_returns", "pulse_fwhm_ns", "pulse_source",
                       "waveform"})

    def __post_init__(self) -> None:
        err = SensorSpecError
        if not isinstance(self.waveform, (bool, np.bool_)):
            raise err(f"Expected [returns] waveform = true or false, got "
                      f"{self.waveform!r}.")
        if not self.modes or any(m not in RETURN_MODES for m in self.modes) or \
                len(set(self.modes)) != len(self.modes):
            raise err(f"Expected [returns] modes: distinct names from "
                      f"{list(RETURN_MODES)}, got {list(self.modes)!r}.")
        if self.dual not in DUAL_KINDS:
            raise err(f"Expected [returns] dual in {list(DUAL_KINDS)}, got {self.dual!r}.")
        as_whole(self.max_returns, "[returns] max_returns", err, lo=1)
        as_number(self.pulse_fwhm_ns, "[returns] pulse_fwhm_ns", err, unit="ns", lo=0,
                  lo_open=True)
        if ("dual" in self.modes or "all" in self.modes) and self.max_returns < 2:
            raise err(f"Expected [returns] max_returns >= 2 for modes "
                      f"{list(self.modes)}, got {self.max_returns}.")

    @property
    def pulse_fwhm_s(self) -> float:
        """Pulse width (FWHM, s)."""
        return float(self.pulse_fwhm_ns) * 1e-9

    @classmethod
    def from_table(cls, table: Mapping[str, object], where: str = "") -> ReturnsSpec:
        """Validate a TOML ``[returns]`` table (unknown keys rejected) and build the
        spec; ``where`` (a file name) prefixes the error message."""
        unknown = sorted(set(table) - cls._KEYS)
        if unknown:
            raise SensorSpecError(f"{where}{': ' if where else ''}Expected [returns] keys "
                                  f"from {sorted(cls._KEYS)}, got {unknown}.")
        kw = dict(table)
        if "modes" in kw:
            m = kw["modes"]
            if not isinstance(m, (list, tuple)) or not all(isinstance(x, str) for x in m):
                raise SensorSpecError(f"Expected [returns] modes to be a list of names, "
                                      f"got {m!r}.")
            kw["modes"] = tuple(m)
        return cls(**kw)  # type: ignore[arg-type]

    def model(self, phys: Physics, **kw: object) -> WaveformModel:
        """The ``WaveformModel`` of the device (its pulse, threshold from ``phys``)."""
        return WaveformModel.for_physics(phys, self.pulse_fwhm_s, **kw)


# ----------------------------------------------------------------------- waveforms
def _contributions(ranges: ArrayLike, powers: ArrayLike
                   ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    r = np.ascontiguousarray(ranges, dtype=np.float64)
    p = np.ascontiguousarray(powers, dtype=np.float64)
    if r.ndim == 1:
        r, p = r[:, None], p[:, None] if p.ndim == 1 else p
    if r.ndim != 2 or p.shape != r.shape:
        raise SimulationError(f"Expected `ranges` and `powers` of one shape (n, m), got "
                              f"{np.shape(ranges)} and {np.shape(powers)}.")
    if np.any(np.isfinite(r) & (r < 0)) or np.any(np.isnan(p)) or np.any(p < 0):
        raise SimulationError("Expected ranges >= 0 (inf for none) and powers >= 0, got "
                              "a negative or NaN value.")
    return r, p


def _rows(r: NDArray[np.float64], p: NDArray[np.float64], model: WaveformModel
          ) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """Each pulse's row of bins: (first bin, bin count), count 0 for no contribution.
    The row reaches REACH_SIGMA sigma beyond the nearest and farthest contribution."""
    from ._kernels.waveform import REACH_SIGMA

    live = np.isfinite(r) & (p > 0)
    big = np.where(live, r, np.inf).min(axis=1) if r.shape[1] else np.full(len(r), np.inf)
    far = np.where(live, r, -np.inf).max(axis=1) if r.shape[1] else big
    reach = REACH_SIGMA * model.sigma_m + 2 * model.bin_m
    has = np.isfinite(big)
    lo = np.floor((np.where(has, big, 0.0) - reach) / model.bin_m).astype(np.int64)
    hi = np.ceil((np.where(has, far, 0.0) + reach) / model.bin_m).astype(np.int64)
    return lo, np.where(has, hi - lo + 1, 0).astype(np.int64)


def waveforms(ranges: ArrayLike, powers: ArrayLike, model: WaveformModel
              ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The sampled received waveform of each pulse.

    Parameters
    ----------
    ranges : (n, m) array_like of float
        Range of each contribution (m); inf (or NaN) for none.
    powers : (n, m) array_like of float
        Its received power, footprint weight included (relative units, >= 0).
    model : WaveformModel

    Returns
    -------
    start_m : (n,) float64
        Range of each row's first sample (m); sample b is at start_m + b model.bin_m.
    samples : (n, w) float64
        The waveforms, zero-padded to the longest row (w = 0 for no contribution).
    """
    from ._kernels.waveform import sample_waveforms

    r, p = _contributions(ranges, powers)
    lo, nb = _rows(r, p, model)
    out = np.zeros((len(r), int(nb.max()) if len(nb) else 0))
    sample_waveforms(r, p, lo, nb, model.bin_m, model.sigma_m, out)
    return (lo * model.bin_m).astype(np.float64), out


def detect_echoes(ranges: ArrayLike, powers: ArrayLike, model: WaveformModel) -> Echoes:
    """Echoes of each pulse's waveform (module doc: threshold, separation, Gaussian
    decomposition).

    Parameters
    ----------
    ranges, powers : (n, m) array_like of float
        As for ``waveforms``.
    model : WaveformModel

    Returns
    -------
    Echoes
        (n, model.max_echoes) arrays, sorted by range.
    """
    from ._kernels.waveform import detect_echoes as kernel

    r, p = _contributions(ranges, powers)
    n, e = len(r), int(model.max_echoes)
    lo, nb = _rows(r, p, model)
    nblk = max(1, -(-n // PULSE_BLOCK))
    width = max(3, int(nb.max()) if n else 3)
    out_r, out_a, out_s = np.empty((n, e)), np.empty((n, e)), np.empty((n, e))
    cnt = np.empty(n, dtype=np.int64)
    kernel(r, p, lo, nb, model.bin_m, model.sigma_m, float(model.threshold_power),
           model.min_separation_m, REFINE_ITERATIONS, np.empty((nblk, width)),
           np.empty((nblk, CANDIDATES_MAX), dtype=np.int64),
           np.empty((nblk, CANDIDATES_MAX)), np.empty((nblk, 4, e)),
           out_r, out_a, out_s, cnt)
    return Echoes(out_r, out_a, out_s, cnt, model.sigma_m)


def pulse_echoes(subray_range_m: ArrayLike, subray_power: ArrayLike, weights: ArrayLike,
                 model: WaveformModel, *, particle_range_m: ArrayLike | None = None,
                 particle_power: ArrayLike | None = None) -> Echoes:
    """Echoes of a chunk of pulses from what the simulation loop has per sub-ray.

    Parameters
    ----------
    subray_range_m : (n, m) array_like of float
        Range of each sub-ray's surface hit (m); inf (or NaN) for a miss or a hit
        nearer than the minimum range.
    subray_power : (n, m) array_like of float
        Each sub-ray's received power, ``sensors.physics.power`` (without weight); 0
        for a miss.
    weights : (m,) array_like of float
        Footprint weights of the sub-rays (``sensors.physics.subray_offsets``).
    model : WaveformModel
    particle_range_m, particle_power : (n,) array_like of float, optional
        An airborne particle's echo per pulse (range inf for none): its range and its
        power (``power(particle_reflectivity, 1, d, alpha)``: the whole beam). The
        caller decides which pulses have one (e.g. nearer than the farthest hit).

    Returns
    -------
    Echoes
    """
    r, p = _stack(subray_range_m, subray_power, weights, particle_range_m, particle_power)
    return detect_echoes(r, p, model)


def _stack(subray_range_m: ArrayLike, subray_power: ArrayLike, weights: ArrayLike,
           particle_range_m: ArrayLike | None, particle_power: ArrayLike | None
           ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """A pulse's contributions (n, m) or (n, m + 1) (the particle last): ranges and
    weighted powers (0 where the range is not finite)."""
    r = np.asarray(subray_range_m, dtype=np.float64)
    w = np.asarray(weights, dtype=np.float64)
    if r.ndim != 2 or w.shape != (r.shape[1],):
        raise SimulationError(f"Expected sub-ray ranges (n, m) and weights (m,), got "
                              f"{r.shape} and {w.shape}.")
    p = np.asarray(subray_power, dtype=np.float64) * w
    if particle_range_m is not None:
        if particle_power is None:
            raise SimulationError("Expected `particle_power` with `particle_range_m`, "
                                  "got None.")
        pr = np.asarray(particle_range_m, dtype=np.float64).reshape(-1, 1)
        pp = np.broadcast_to(np.asarray(particle_power, dtype=np.float64).reshape(-1, 1),
                             pr.shape)
        r = np.concatenate([r, pr], axis=1)
        p = np.concatenate([p, pp], axis=1)
    return r, np.where(np.isfinite(r), p, 0.0)


# ------------------------------------------------------------------- return modes
def select_returns(echoes: Echoes, mode: str, *, dual: str = "strongest_last",
                   max_returns: int = 2) -> Returns:
    """The echoes a device reports in return mode ``mode``.

    Parameters
    ----------
    echoes : Echoes
    mode : {"strongest", "last", "first", "dual", "all"}
    dual : {"strongest_last", "first_last", "strongest_second"}
        What ``dual`` means on the device: the strongest and the last (if the strongest
        is the last, the second strongest and the last: Velodyne VLP-16 manual, Hesai
        PandarXT manual 3.1.2.3), the first and the last, or the two strongest (Ouster
        firmware 3.1 "Return Order").
    max_returns : int >= 1
        ``all``: the first ``max_returns`` echoes along the beam.

    Returns
    -------
    Returns
        Rows grouped by pulse, in range order within a pulse. "Strongest" compares
        ``Echoes.power``.
    """
    if mode not in RETURN_MODES:
        raise SimulationError(f"Expected a return mode in {list(RETURN_MODES)}, got "
                              f"{mode!r}; pass --returns with one of them.")
    if dual not in DUAL_KINDS:
        raise SimulationError(f"Expected `dual` in {list(DUAL_KINDS)}, got {dual!r}.")
    k = as_whole(max_returns, "max_returns", SimulationError, lo=1)
    cnt = echoes.count
    n, e = echoes.range_m.shape
    live = np.arange(e)[None, :] < cnt[:, None]
    strength = np.where(live, echoes.power, -np.inf)
    order = np.argsort(-strength, axis=1, kind="stable")   # strongest first
    last = np.maximum(cnt - 1, 0)
    pick = np.zeros((n, e), dtype=np.bool_)
    rows = np.arange(n)
    has = cnt > 0
    if mode == "strongest":
        pick[rows[has], order[has, 0]] = True
    elif mode == "first":
        pick[rows[has], 0] = True
    elif mode == "last":
        pick[rows[has], last[has]] = True
    elif mode == "all":
        pick = live & (np.arange(e)[None, :] < k)
    elif dual == "first_last":
        pick[rows[has], 0] = True
        pick[rows[has], last[has]] = True
    elif dual == "strongest_second":
        pick[rows[has], order[has, 0]] = True
        two = cnt > 1
        pick[rows[two], order[two, 1]] = True
    else:  # strongest_last; the second strongest where the strongest is the last
        pick[rows[has], last[has]] = True
        s0 = order[:, 0]
        alt = np.where(s0 == last, order[:, 1] if e > 1 else s0, s0)
        two = cnt > 1
        pick[rows[two], alt[two]] = True
    pulse, echo = np.nonzero(pick)                         # row-major: by pulse, by range
    per = pick.sum(axis=1)
    first_of = np.concatenate([[0], np.cumsum(per)[:-1]]) if n else np.zeros(0, np.int64)
    number = np.arange(len(pulse)) - first_of[pulse] + 1
    return Returns(pulse.astype(np.int64), echo.astype(np.int64),
                   number.astype(np.uint8), per[pulse].astype(np.uint8))


# The default of a spec that has no [returns] table: today's single return.
DEFAULT_RETURNS: Final = ReturnsSpec()


# ------------------------------------------------------- the simulation loop's entry
@dataclass(frozen=True)
class ChunkReturns:
    """The reported returns of a chunk of pulses, one row each, grouped by pulse and in
    range order within a pulse: what ``sensors.simulate`` needs to detect, add noise to
    and write them (``Returns`` plus the per-return physics).

    Attributes
    ----------
    pulse : (p,) int64
        The pulse (row of the chunk) of each return.
    range_m, power : (p,) float64
        Echo range (m, noise-free) and power (``Echoes.power``: the single-return
        model's footprint-weighted power for a surface filling the footprint).
    cos : (p,) float64
        Cosine of incidence of the echo's strongest contribution (1 for a particle).
    flag : (p,) uint8
        ``sensors.physics`` flags: surface, particle, or mixed (the echo's sub-rays
        spread over more than ``MIXED_SPREAD_M`` or it holds only part of the beam).
    triangle : (p,) int32
        Face of the echo's strongest sub-ray (-1 for a particle).
    return_number, number_of_returns : (p,) uint8
    amplitude, width_m : (p,) float64
        The echo's fitted Gaussian: peak (relative power) and sigma (m).
    contrib_range_m, contrib_power : (n, m) or (n, m + 1) float64
        The chunk's contributions as the waveform summed them (sub-rays, weighted, and
        the particle last): what ``wave_windows`` samples.
    """

    pulse: NDArray[np.int64]
    range_m: NDArray[np.float64]
    power: NDArray[np.float64]
    cos: NDArray[np.float64]
    flag: NDArray[np.uint8]
    triangle: NDArray[np.int32]
    return_number: NDArray[np.uint8]
    number_of_returns: NDArray[np.uint8]
    amplitude: NDArray[np.float64]
    width_m: NDArray[np.float64]
    contrib_range_m: NDArray[np.float64] | None = None
    contrib_power: NDArray[np.float64] | None = None

    def __len__(self) -> int:
        return int(self.pulse.shape[0])


def chunk_returns(subray_range_m: ArrayLike, subray_power: ArrayLike,
                  subray_cos: ArrayLike, subray_triangle: ArrayLike, weights: ArrayLike,
                  model: WaveformModel, mode: str, *, dual: str = "strongest_last",
                  max_returns: int = 2, particle_range_m: ArrayLike | None = None,
                  particle_power: ArrayLike | None = None) -> ChunkReturns:
    """Waveform, echoes and the returns of mode ``mode`` for a chunk, from the arrays
    the simulation's beam-divergence step has per sub-ray.

    Parameters
    ----------
    subray_range_m, subray_power : (n, m) array_like of float
        As for ``pulse_echoes`` (inf / 0 for a miss).
    subray_cos : (n, m) array_like of float
        Cosine of incidence of each sub-ray's hit.
    subray_triangle : (n, m) array_like of int
        Face of each sub-ray's hit (-1 for a miss).
    weights : (m,) array_like of float
    model : WaveformModel
    mode, dual, max_returns
        As for ``select_returns``.
    particle_range_m, particle_power : (n,) array_like of float, optional
        As for ``pulse_echoes``.

    Returns
    -------
    ChunkReturns
    """
    from ._kernels.waveform import attribute_returns

    r = np.asarray(subray_range_m, dtype=np.float64)
    cos = np.asarray(subray_cos, dtype=np.float64)
    tri = np.asarray(subray_triangle, dtype=np.int32)
    if cos.shape != r.shape or tri.shape != r.shape:
        raise SimulationError(f"Expected sub-ray ranges, cosines and triangles of one "
                              f"shape (n, m), got {r.shape}, {cos.shape}, {tri.shape}.")
    if mode == "all" and isinstance(max_returns, (int, np.integer)) and \
            max_returns > model.max_echoes:   # the waveform must keep as many echoes
        model = replace(model, max_echoes=int(max_returns))
    rr, pw = _stack(r, subray_power, weights, particle_range_m, particle_power)
    echoes = detect_echoes(rr, pw, model)
    ret = select_returns(echoes, mode, dual=dual, max_returns=max_returns)
    m = r.shape[1]
    x = ret.take(echoes.range_m)
    # DECISION: an echo is made of the contributions within half the separation of its
    # range; its triangle and incidence are those of the strongest of them.
    j = np.empty(len(ret), dtype=np.int64)
    mixed = np.empty(len(ret), dtype=np.bool_)
    attribute_returns(ret.pulse, x, rr, pw, m, 0.5 * model.min_separation_m,
                      MIXED_SPREAD_M, j, mixed)
    particle = j == m
    js = np.minimum(j, m - 1)
    rows = ret.pulse
    flag = np.where(particle, FLAG_PARTICLE, np.where(mixed, FLAG_MIXED, FLAG_SURFACE))
    return ChunkReturns(
        pulse=ret.pulse, range_m=x, power=ret.take(echoes.power),
        cos=np.where(particle, 1.0, cos[rows, js]), flag=flag.astype(np.uint8),
        triangle=np.where(particle, -1, tri[rows, js]).astype(np.int32),
        return_number=ret.return_number, number_of_returns=ret.number_of_returns,
        amplitude=ret.take(echoes.amplitude), width_m=ret.take(echoes.width_m),
        contrib_range_m=rr, contrib_power=pw)


def renumber_returns(pulse: ArrayLike, keep: ArrayLike
                     ) -> tuple[NDArray[np.uint8], NDArray[np.uint8]]:
    """Return numbers among the kept returns (e.g. those detected after
    ``chunk_returns``): 1 = nearest kept return of its pulse.

    Parameters
    ----------
    pulse : (p,) array_like of int
        Pulse of each return, grouped (non-decreasing) and in range order within a
        pulse, as ``ChunkReturns.pulse``.
    keep : (p,) array_like of bool

    Returns
    -------
    return_number, number_of_returns : (k,) uint8
        For the k kept returns, in their order.
    """
    pu = np.asarray(pulse, dtype=np.int64)[np.asarray(keep, dtype=np.bool_)]
    if not len(pu):
        return np.zeros(0, np.uint8), np.zeros(0, np.uint8)
    start = np.flatnonzero(np.concatenate([[True], pu[1:] != pu[:-1]]))
    size = np.diff(np.append(start, len(pu)))
    group = np.repeat(np.arange(len(start)), size)
    number = np.arange(len(pu)) - start[group] + 1
    return number.astype(np.uint8), size[group].astype(np.uint8)



# ------------------------------------------------------- full-waveform windows
#: Metres of range per picosecond of two-way travel time (c / 2 x 1e-12): the length of
#: the LAS parametric line x(t), y(t), z(t).
RANGE_PER_PS_M: Final = SPEED_OF_LIGHT_M_S / 2.0 * 1e-12
#: Bits per stored sample: unsigned 16-bit, linear (relative power = gain x sample).
WAVE_BITS: Final = 16
#: A window is shared by a pulse's returns where their echoes, padded by this many
#: pulse sigmas either side (the echo has fallen to 3e-4 of its peak there), fit in it.
WAVE_PAD_SIGMAS: Final = 4.0


@dataclass(frozen=True)
class WaveWindows:
    """The sampled waveform windows of a chunk's returns (``wave_windows``).

    Attributes
    ----------
    start_m : (p,) float64
        Range of each return's first sample (m); sample k at start_m + k bin_m.
    samples : (p, w) uint16
        The window's samples, relative power / ``gain``, rounded, clipped at 65535.
    shared : (p,) bool
        Whether the return's window is its pulse's shared one (all its reported echoes
        fit) rather than one centred on its own echo.
    gain : float
        Relative power per count (the LAS descriptor's digitizer gain).
    spacing_ps : int
        Time between samples (ps): the model's bin.
    """

    start_m: NDArray[np.float64]
    samples: NDArray[np.uint16]
    shared: NDArray[np.bool_]
    gain: float
    spacing_ps: int

    def __len__(self) -> int:
        return int(self.start_m.shape[0])


def waveform_gain(phys: Physics) -> float:
    """The digitiser gain (relative power per count) of a device's stored waveforms:
    one count is its waveform noise threshold (``detection_threshold``).

    DECISION: the least significant bit at the noise floor, as a digitiser's range is
    set: every echo the detector finds is at least one count, and the 16-bit full
    scale is 65535 thresholds (Z+F Imager: a 0.5 reflectivity wall at normal incidence
    clips nearer than ~1.4 m; no device's 1e6 dynamic range fits 16 linear bits, and
    LAS 1.4 has no logarithmic sample type). A clipped sample is 65535."""
    return detection_threshold(phys)


def wave_windows(ranges: ArrayLike, powers: ArrayLike, model: WaveformModel, *,
                 return_pulse: ArrayLike, echo_range_m: ArrayLike, gain: float,
                 samples: int | None = None, out: NDArray[np.uint16] | None = None
                 ) -> WaveWindows:
    """Waveform windows of the returns of a chunk, on the model's bin grid (anchored
    at range 0, as ``waveforms``), quantised to ``WAVE_BITS`` bits.

    A pulse's returns share one window, centred between its nearest and farthest
    reported echo, where those echoes padded by ``WAVE_PAD_SIGMAS`` sigmas fit in it;
    otherwise each return gets the window centred on its own echo (a dust echo far
    before the wall). Windows start at range >= 0.

    Parameters
    ----------
    ranges, powers : (n, m) array_like of float
        The chunk's contributions, the particle included (``pulse_echoes``'s stacking:
        the summed waveform the echoes were detected in).
    model : WaveformModel
    return_pulse : (p,) array_like of int
        Pulse (row of ``ranges``) of each return, grouped by pulse
        (``ChunkReturns.pulse``).
    echo_range_m : (p,) array_like of float
        Each return's echo range (m; noise-free, as detected).
    gain : float > 0
        Relative power per count (``waveform_gain``).
    samples : int >= 3, optional
        Window length; ``sensors.io.fields.WAVE_SAMPLES`` by default.
    out : (p, samples) uint16 array, optional
        Where to put the samples (rows may be strided, e.g. a record array's field);
        a new array by default.

    Returns
    -------
    WaveWindows
    """
    from ._kernels.waveform import sample_quantised
    from .io.fields import WAVE_SAMPLES

    w = WAVE_SAMPLES if samples is None else as_whole(samples, "samples", SimulationError,
                                                        lo=3)
    g = as_number(gain, "gain", SimulationError, unit="relative power per count", lo=0,
                  lo_open=True)
    r, p = _contributions(ranges, powers)
    pulse = np.asarray(return_pulse, dtype=np.int64).reshape(-1)
    x = np.asarray(echo_range_m, dtype=np.float64).reshape(-1)
    if x.shape != pulse.shape or (len(pulse) and (pulse.min() < 0 or
                                                   pulse.max() >= len(r))):
        raise SimulationError(f"Expected `return_pulse` (p,) of rows of `ranges` "
                              f"({len(r)}) and `echo_range_m` of its length, got "
                              f"{pulse.shape} and {x.shape}.")
    if not np.isfinite(x).all():
        raise SimulationError("Expected finite `echo_range_m`, got inf or NaN.")
    bm = model.bin_m
    if len(pulse):
        first = np.flatnonzero(np.concatenate([[True], pulse[1:] != pulse[:-1]]))
        lo = np.minimum.reduceat(x, first)
        hi = np.maximum.reduceat(x, first)
        group = np.repeat(np.arange(len(first)), np.diff(np.append(first, len(pulse))))
    else:
        lo = hi = np.zeros(0)
        group = np.zeros(0, dtype=np.int64)
    pad = WAVE_PAD_SIGMAS * model.sigma_m
    fits = (hi - lo + 2.0 * pad) / bm <= w - 1
    shared = fits[group]
    centre = np.where(shared, 0.5 * (lo + hi)[group], x)
    start = np.maximum(np.round(centre / bm).astype(np.int64) - w // 2, 0)
    q = np.zeros((len(pulse), w), dtype="<u2") if out is None else out
    if q.shape != (len(pulse), w) or q.dtype != np.dtype("<u2"):
        raise SimulationError(f"Expected `out` of shape ({len(pulse)}, {w}) uint16, got "
                              f"{q.shape} {q.dtype}.")
    # DECISION: each return's row is computed from its pulse's contributions straight
    # into ``out`` (e.g. the records' ``wave`` field): a window shared by a dual pair
    # is built twice, which costs less than building it once and copying rows.
    if len(pulse):
        sample_quantised(r, p, pulse, start, bm, model.sigma_m, 1.0 / g,
                         float(2 ** WAVE_BITS - 1),
                         np.empty((max(1, -(-len(pulse) // PULSE_BLOCK)), w)), q)
    return WaveWindows(start_m=start * bm, samples=q, shared=shared,
                       gain=g, spacing_ps=int(round(model.bin_s * 1e12)))
