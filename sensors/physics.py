"""Return physics: what a pulse that reached the mesh turns into, per device.

All vectorised over a chunk, all switchable (``Settings``), all seeded: each random
stream (jitter, particles, detection, noise) comes in fixed blocks of pulses from
``numpy.random.default_rng([seed, stream, block])``, so the output depends on the seed
only: not on the chunk size, not on the thread count.

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
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .errors import SimulationError

#: Return flags in the output.
FLAG_SURFACE, FLAG_PARTICLE, FLAG_MIXED = 1, 2, 3
#: Sub-returns whose ranges spread more than this are flagged mixed (m).
MIXED_SPREAD_M = 0.01

# Sub-ray offsets in units of the divergence half-angle: centre, 6 at 1/2, 12 at 1.
_A6 = 2 * np.pi * np.arange(6) / 6
_A12 = 2 * np.pi * (np.arange(12) + 0.5) / 12
_SUB = {1: np.zeros((1, 2)),
        7: np.concatenate([[[0.0, 0.0]], 0.5 * np.stack([np.cos(_A6), np.sin(_A6)], 1)]),
        19: np.concatenate([[[0.0, 0.0]], 0.5 * np.stack([np.cos(_A6), np.sin(_A6)], 1),
                            np.stack([np.cos(_A12), np.sin(_A12)], 1)])}


@dataclass(frozen=True)
class Settings:
    """User switches of the return physics (all SI).

    range_noise, angle_jitter, detection : bool
    beam_subrays : 1 (off), 7 or 19 sub-rays per pulse
    mixed : "strongest" or "average" combination of sub-returns
    attenuation_per_m : Beer-Lambert extinction coefficient alpha (1/m), 0 for clear air
    particle_rate_per_m : rate of particle scattering events along the beam (1/m)
    particle_reflectivity : apparent reflectivity of a particle return
    reflectivity : reflectivity used where the mesh has none
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

    def __post_init__(self):
        if self.beam_subrays not in _SUB:
            raise SimulationError(f"Expected `beam_subrays` in {sorted(_SUB)}, got "
                                  f"{self.beam_subrays}.")
        if self.mixed not in ("strongest", "average"):
            raise SimulationError(f"Expected `mixed` to be 'strongest' or 'average', got "
                                  f"{self.mixed!r}.")
        for name in ("attenuation_per_m", "particle_rate_per_m"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v >= 0):
                raise SimulationError(f"Expected `{name}` >= 0, got {v}.")
        for name in ("particle_reflectivity", "reflectivity"):
            v = getattr(self, name)
            if not (np.isfinite(v) and 0 < v <= 1):
                raise SimulationError(f"Expected `{name}` in (0, 1], got {v}.")

    @classmethod
    def ideal(cls) -> "Settings":
        """No noise, no jitter, every return within range detected: exact geometry."""
        return cls(range_noise=False, angle_jitter=False, detection=False)


def subray_offsets(n: int) -> tuple[np.ndarray, np.ndarray]:
    """Offsets (m, 2) in units of the half-angle and their normalised weights (m,)."""
    off = _SUB[n]
    w = np.exp(-2.0 * np.sum(off * off, axis=1))
    return off, w / w.sum()


def perpendicular_basis(d):
    """Unit vectors u, v (n, 3) with (u, v, d) orthonormal."""
    a = np.where(np.abs(d[:, 2:3]) < 0.9, [[0.0, 0.0, 1.0]], [[1.0, 0.0, 0.0]])
    u = np.cross(d, a)
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    return u, np.cross(d, u)


def tilt(d, angles_xy):
    """Directions d (n, 3) tilted by small angles (n, 2) (radians) about two
    perpendicular axes; unit results."""
    u, v = perpendicular_basis(d)
    out = d + np.tan(angles_xy[:, :1]) * u + np.tan(angles_xy[:, 1:2]) * v
    return out / np.linalg.norm(out, axis=1, keepdims=True)


def power(rho, cos_inc, r, alpha):
    """Relative received power (see module doc)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        return rho * cos_inc / (r * r) * np.exp(-2.0 * alpha * r)


def detection_probability(p, phys):
    p_min = phys.detection_reflectivity / phys.detection_range_m ** 2
    with np.errstate(divide="ignore", over="ignore"):
        return 1.0 / (1.0 + (np.maximum(p, 1e-300) / p_min) ** (-1.0 / phys.detection_softness))


def range_sigma(p, phys):
    p_ref = phys.reference_reflectivity / phys.reference_range_m ** 2
    with np.errstate(divide="ignore"):
        return np.sqrt(phys.range_sigma_floor_m ** 2 +
                       phys.range_sigma_m ** 2 * p_ref / np.maximum(p, 1e-300))


def intensity(p, phys):
    p_min = phys.detection_reflectivity / phys.detection_range_m ** 2
    p_sat = 1.0 / max(phys.range_min_m, 0.1) ** 2
    with np.errstate(divide="ignore"):
        x = np.log10(np.maximum(p, 1e-300) / p_min) / np.log10(p_sat / p_min)
    return np.clip(x, 0.0, 1.0).astype(np.float32)
