"""Return physics: what a pulse that reached the mesh turns into, per device.

All vectorised over a chunk, all switchable (``Settings``), all seeded: each random
stream (jitter, particles, detection, noise) comes in fixed blocks of pulses from
``numpy.random.default_rng([seed, stream, block])``, so the output depends on the seed
only: not on the chunk size, not on the thread count. Streams, in this order: 0 angular
jitter (normal, 2 per pulse), 1 particle distance (standard exponential), 2 particle
detection (uniform), 3 surface detection (uniform), 4 range noise (standard normal).

Model (per pulse, R range, rho reflectivity, theta incidence angle):

- Received power from the simple lidar equation for an extended Lambertian target,
  P = rho cos(theta) / R^2 * exp(-2 alpha R) (e.g. Jelalian 1992; two-way Beer-Lambert
  extinction alpha for dust or fog). Relative units; only ratios matter.
- Detection: threshold P_min = rho_det / R_det^2 (the device detects a target of
  reflectivity rho_det at normal incidence half the time at R_det); probability
  1 / (1 + (P / P_min)^(-1 / softness)), a logistic in ln P.
- Range noise: Gaussian with sigma = sqrt(floor^2 + sigma_ref^2 P_ref / P),
  P_ref = rho_ref / R_ref^2: shot-noise-limited ranging, sigma ~ 1 / sqrt(SNR).
- Angular jitter: the beam leaves along the nominal direction tilted by a Gaussian
  angle (sigma per axis = the device's angular accuracy); the instrument reports the
  nominal angles with the range measured along the true beam.
- Intensity: log10(P / P_min) / log10(P_sat / P_min) clipped to [0, 1], P_sat the
  power of a white target at normal incidence at the minimum range (devices compress
  their dynamic range logarithmically).
- Beam divergence: sub-rays in the footprint cone (centre, 6 at half the divergence
  angle, 12 at the full half-angle), Gaussian weights exp(-2 r^2); the return is the
  strongest sub-return or the energy-weighted mean range ("mixed pixels" at edges).
- Airborne particles: a return at range_min + a distance drawn from an exponential
  law with rate ``particle_rate_per_m`` (scattering events per metre; events nearer
  than the minimum range are invisible), from a target of
  ``particle_reflectivity`` at normal incidence; it wins if it is detected before
  the surface.

The four formulas (power, detection probability, range sigma, intensity) are written
once, as scalar Numba functions in ``sensors._kernels.pulses``; the functions here and
the simulation kernels both call them. The constants P_min, P_ref and P_sat are
properties of ``sensors.spec.Physics``.
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Final

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ._checks import as_number
from .errors import SimulationError
from .io.fields import FLAG_MIXED, FLAG_PARTICLE, FLAG_SURFACE, MIXED_SPREAD_M
from .spec import Physics
from .waveform import RETURN_MODES

__all__ = ["SUBRAY_COUNTS",
           "Settings", "detection_probability", "intensity", "intensity_constants",
           "noise_constants", "perpendicular_basis", "power", "range_sigma",
           "subray_offsets"]

# Return flags in the output, and the spread that makes a return mixed (m): defined
# with the point record (sensors.io.fields), re-exported here where they were.

# Sub-ray offsets in units of the divergence half-angle: centre, 6 at 1/2, 12 at 1.
_A6 = 2 * np.pi * np.arange(6) / 6
_A12 = 2 * np.pi * (np.arange(12) + 0.5) / 12
_SUB = {1: np.zeros((1, 2)),
        7: np.concatenate([[[0.0, 0.0]], 0.5 * np.stack([np.cos(_A6), np.sin(_A6)], 1)]),
        19: np.concatenate([[[0.0, 0.0]], 0.5 * np.stack([np.cos(_A6), np.sin(_A6)], 1),
                            np.stack([np.cos(_A12), np.sin(_A12)], 1)])}
#: Sub-rays per pulse that ``Settings.beam_subrays`` accepts.
SUBRAY_COUNTS: Final = tuple(sorted(_SUB))
_MIXED_MODES = ("strongest", "average")
_FRACTION = "a fraction, not a percentage"


@dataclass(frozen=True, kw_only=True)
class Settings:
    """User switches of the return physics (SI units), keyword-only.

    Parameters
    ----------
    range_noise, angle_jitter, detection : bool
        Range noise, angular jitter of the beam, and probabilistic detection; all off
        in ``Settings.ideal()``.
    beam_subrays : {1, 7, 19}
        Sub-rays per pulse for beam divergence (1: off).
    mixed : {"average", "strongest"}
        How sub-returns combine: energy-weighted mean range or the strongest one.
    attenuation_per_m : float >= 0
        Beer-Lambert extinction coefficient alpha (1/m); 0 for clear air.
    particle_rate_per_m : float >= 0
        Rate of particle scattering events along the beam (1/m); 0 for none.
    particle_reflectivity : float in (0, 1]
        Apparent reflectivity of a particle return.
    reflectivity : float in [0, 1]
        Reflectivity used where the mesh has none (and no ``reflectivity`` is given to
        the simulation).
    returns : {"strongest", "last", "first", "dual", "all"} or None
        Multiple returns: the pulse's full waveform (``sensors.waveform``), its echoes
        and those the device reports in this return mode (one of its spec's
        ``returns.modes``; output records ``sensors.io.fields.RETURN_POINT_DTYPE``). None (the
        default): the single blended return per pulse, as before the waveform model.
    waveform : bool
        Full-waveform output (``--waveform``), for devices whose spec has ``[returns]
        waveform = true`` (the survey scanners): every reported return also carries
        its pulse's sampled waveform, a ``sensors.io.fields.WAVE_SAMPLES``-bin window
        around the echoes (records ``sensors.io.fields.WAVEFORM_POINT_DTYPE``), which
        the LAS writer stores as LAS 1.4 wave packets. Runs the multiple-return model:
        with ``returns`` None, in the device's default mode (the first of its
        ``[returns] modes``). False (the default): no waveform is kept.

    Raises
    ------
    SimulationError
        For a value of the wrong type or outside its range.
    """

    range_noise: bool = True
    angle_jitter: bool = True
    detection: bool = True
    beam_subrays: int = 1
    mixed: str = "average"
    attenuation_per_m: float = 0.0
    particle_rate_per_m: float = 0.0
    particle_reflectivity: float = 0.1
    reflectivity: float = 0.5
    returns: str | None = None
    waveform: bool = False

    def __post_init__(self) -> None:
        for name in ("range_noise", "angle_jitter", "detection", "waveform"):
            v = getattr(self, name)
            if not isinstance(v, (bool, np.bool_)):
                raise SimulationError(f"Expected `{name}` to be True or False, got {v!r}.")
        b = self.beam_subrays
        if not isinstance(b, (int, np.integer)) or isinstance(b, bool) or b not in _SUB:
            raise SimulationError(f"Expected `beam_subrays` in {list(SUBRAY_COUNTS)}, got "
                                  f"{b!r}; use 1 to switch beam divergence off.")
        if self.mixed not in _MIXED_MODES:
            raise SimulationError(f"Expected `mixed` to be 'strongest' or 'average', got "
                                  f"{self.mixed!r}.")
        for name in ("attenuation_per_m", "particle_rate_per_m"):
            as_number(getattr(self, name), name, SimulationError, unit="1/m", lo=0)
        as_number(self.particle_reflectivity, "particle_reflectivity", SimulationError,
                  unit=_FRACTION, lo=0, hi=1, lo_open=True)
        as_number(self.reflectivity, "reflectivity", SimulationError, unit=_FRACTION, lo=0,
                  hi=1)
        if self.returns is not None and self.returns not in RETURN_MODES:
            raise SimulationError(f"Expected `returns` (--returns) in {list(RETURN_MODES)} "
                                  f"or None, got {self.returns!r}; pass --returns with one "
                                  "of them.")

    @classmethod
    def ideal(cls) -> Settings:
        """No noise, no jitter, every return within range detected: exact geometry."""
        return cls(range_noise=False, angle_jitter=False, detection=False)

    def __repr__(self) -> str:
        # Only what differs from the defaults: one short line, and eval() gives it back.
        changed = [f"{f.name}={getattr(self, f.name)!r}" for f in fields(self)
                   if getattr(self, f.name) != f.default]
        return f"Settings({', '.join(changed)})"


def subray_offsets(n: int) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Sub-ray offsets (n, 2) in units of the divergence half-angle, and their
    normalised Gaussian weights exp(-2 r^2) (n,); ``n`` in ``SUBRAY_COUNTS``."""
    if n not in _SUB:
        raise SimulationError(f"Expected a sub-ray count in {list(SUBRAY_COUNTS)}, got {n!r}.")
    off = _SUB[n]
    w = np.exp(-2.0 * np.sum(off * off, axis=1))
    return off, w / w.sum()


def perpendicular_basis(d: NDArray[np.float64]
                        ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Unit vectors u, v (n, 3) with (u, v, d) orthonormal, for unit d (n, 3)."""
    a = np.where(np.abs(d[:, 2:3]) < 0.9, [[0.0, 0.0, 1.0]], [[1.0, 0.0, 0.0]])
    u = np.cross(d, a)
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    return u, np.cross(d, u)


def power(rho: ArrayLike, cos_inc: ArrayLike, r: ArrayLike, alpha: ArrayLike
          ) -> NDArray[np.float64]:
    """Relative received power rho cos(theta) / R^2 exp(-2 alpha R) (see the module
    doc); the arguments broadcast (R = 0 gives inf)."""
    from ._kernels.pulses import received_power_ufunc

    with np.errstate(divide="ignore", invalid="ignore"):
        return received_power_ufunc(rho, cos_inc, r, alpha)


def detection_probability(p: ArrayLike, phys: Physics) -> NDArray[np.float64]:
    """Probability that a return of power ``p`` is detected by a device of physics
    ``phys``: 1 / (1 + (P / P_min)^(-1 / softness))."""
    from ._kernels.pulses import detection_probability_ufunc

    with np.errstate(divide="ignore", over="ignore"):
        return detection_probability_ufunc(p, phys.threshold_power,
                                           1.0 / phys.detection_softness)


def range_sigma(p: ArrayLike, phys: Physics) -> NDArray[np.float64]:
    """Range noise (1 sigma, m) of a return of power ``p``:
    sqrt(floor^2 + sigma_ref^2 P_ref / P)."""
    from ._kernels.pulses import range_sigma_ufunc

    floor2, ref2 = noise_constants(phys)
    with np.errstate(divide="ignore"):
        return range_sigma_ufunc(p, floor2, ref2)


def intensity(p: ArrayLike, phys: Physics) -> NDArray[np.float32]:
    """Intensity in [0, 1] (float32) of a return of power ``p``:
    log10(P / P_min) / log10(P_sat / P_min), clipped."""
    from ._kernels.pulses import intensity_ufunc

    p_min, log_span = intensity_constants(phys)
    with np.errstate(divide="ignore"):
        return intensity_ufunc(p, p_min, log_span).astype(np.float32)


def noise_constants(phys: Physics) -> tuple[float, float]:
    """(floor^2, sigma_ref^2 P_ref): the arguments of the range-sigma formula."""
    return phys.range_sigma_floor_m ** 2, phys.range_sigma_m ** 2 * phys.reference_power


def intensity_constants(phys: Physics) -> tuple[float, float]:
    """(P_min, log10(P_sat / P_min)): the arguments of the intensity formula."""
    p_min = phys.threshold_power
    return p_min, float(np.log10(phys.saturation_power / p_min))
