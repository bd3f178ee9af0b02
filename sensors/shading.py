"""What a camera sees in a tunnel without daylight: Lambertian surfaces lit by the
platform's own lamps (with a shadow ray per lamp), the exposure that turns radiance
into electrons and digital values with shot and read noise, and a thermal camera's
apparent temperature.

Radiometry (photometric units: a lamp's intensity in candela, illuminance in lux,
luminance in cd/m^2; each colour channel scaled by the surface's albedo):

- A lamp of intensity ``I`` (cd) at distance ``d`` lights a surface point with
  illuminance ``E = I f(alpha) cos(theta_i) / d^2`` (inverse-square law, Lambert's
  cosine law), where ``f`` is the spot profile: 1 inside ``beam_half_angle``,
  falling linearly in angle to 0 at ``cutoff_half_angle`` (Mitsuba 3's ``spot``
  emitter: ``beam_width`` and ``cutoff_angle``, the same ramp), 1 everywhere for a
  point lamp; 0 if a shadow ray from the point meets the mesh before the lamp.
- A Lambertian surface of albedo ``rho`` has luminance ``L = rho E / pi``.
- The sensor (Holst & Lomheim, *CMOS/CCD Sensors and Camera Systems*, 2nd ed. 2011,
  ch. 3): image-plane exposure ``H = L t pi / (4 N^2)`` (lux s) for f-number ``N``
  and exposure ``t``; electrons ``e = QE K_v H A_pix`` with ``K_v = 4.1e15`` photons
  per lux s per m^2 at 555 nm; Poisson shot noise and Gaussian read noise; the
  digital value ``e / full_well * (2^bits - 1)``, clipped; the colour PNG is sRGB
  encoded (IEC 61966-2-1).
- Thermal (``apparent_temperature``): the surface's radiance in the camera's band,
  ``eps B(T) + (1 - eps) B(T_ambient)``, inverted to the temperature of a black body
  of that radiance (Planck's law integrated over the band), plus Gaussian noise of
  the camera's NETD.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from raytrace import Scene

from .camera import CameraSpec
from .errors import SimulationError
from .render import Frame

__all__ = ["Lamp", "K_V", "apparent_temperature", "expose", "headlamp", "luminance",
           "srgb_decode", "srgb_encode"]

#: Photons per lux second per square metre at 555 nm (683 lm/W; Holst & Lomheim ch. 2).
K_V = 4.1e15
#: Offset along the normal for shadow rays (metres): above the float64 surface noise.
SHADOW_EPS_M = 1e-6


@dataclass(frozen=True)
class Lamp:
    """A lamp: a point (``cutoff_half_angle_rad`` = pi) or a spot.

    Attributes
    ----------
    position : (3,) float64
        World frame, metres.
    direction : (3,) float64
        The beam axis (unit), world frame; ignored by a point lamp.
    intensity_cd : float
        Luminous intensity on the axis (candela).
    beam_half_angle_rad, cutoff_half_angle_rad : float
        Full intensity within ``beam``, falling linearly in angle to 0 at ``cutoff``.
    """

    position: NDArray[np.float64]
    direction: NDArray[np.float64]
    intensity_cd: float
    beam_half_angle_rad: float = math.pi
    cutoff_half_angle_rad: float = math.pi

    def __post_init__(self) -> None:
        p = np.asarray(self.position, dtype=np.float64).reshape(-1)
        d = np.asarray(self.direction, dtype=np.float64).reshape(-1)
        if p.shape != (3,) or d.shape != (3,) or not np.isfinite(p).all() or \
                not np.isfinite(d).all() or np.linalg.norm(d) == 0:
            raise SimulationError(f"Expected a lamp position and a non-zero direction as "
                                  f"3 finite numbers each, got {p} and {d}.")
        if not (self.intensity_cd >= 0 and math.isfinite(self.intensity_cd)):
            raise SimulationError(f"Expected a lamp intensity >= 0 cd, got "
                                  f"{self.intensity_cd}.")
        if not 0 < self.beam_half_angle_rad <= self.cutoff_half_angle_rad <= math.pi:
            raise SimulationError(f"Expected 0 < beam <= cutoff <= 180 deg for a lamp, got "
                                  f"{math.degrees(self.beam_half_angle_rad):g} and "
                                  f"{math.degrees(self.cutoff_half_angle_rad):g} deg.")
        object.__setattr__(self, "position", p)
        object.__setattr__(self, "direction", d / np.linalg.norm(d))

    def profile(self, cos_alpha: NDArray[np.float64]) -> NDArray[np.float64]:
        """The spot profile f(alpha) in [0, 1] for the cosines of the off-axis angles."""
        if self.cutoff_half_angle_rad >= math.pi:
            return np.ones_like(cos_alpha)
        a = np.arccos(np.clip(cos_alpha, -1.0, 1.0))
        b, c = self.beam_half_angle_rad, self.cutoff_half_angle_rad
        if c == b:
            return (a <= b).astype(np.float64)
        # DECISION: linear in angle, as Mitsuba 3's ``spot`` plugin (the shading's
        # reference, tests/sensors/test_mitsuba_shading.py), not pbrt-v4's smoothstep in
        # cosine: the two renderers then light the same scene alike.
        return np.clip((c - a) / (c - b), 0.0, 1.0)


def headlamp(world_from_camera: ArrayLike, intensity_cd: float = 1000.0,
             beam_half_angle_rad: float = math.radians(30.0),
             cutoff_half_angle_rad: float = math.radians(45.0),
             offset_m: ArrayLike = (0.0, -0.05, 0.0)) -> Lamp:
    """A spot lamp beside the camera (``offset_m`` in the optical frame: 5 cm above it),
    along its axis. DECISION: 1000 cd and a 30/45 deg beam, an LED work light's order
    (ASSUMED), for ``render --at`` without a platform."""
    T = np.asarray(world_from_camera, dtype=np.float64)
    return Lamp(T[:3, 3] + T[:3, :3] @ np.asarray(offset_m, dtype=np.float64), T[:3, 2],
                intensity_cd, beam_half_angle_rad, cutoff_half_angle_rad)


def luminance(scene: Scene, frame: Frame, lamps: Sequence[Lamp],
              albedo: NDArray[np.float64]) -> NDArray[np.float64]:
    """(h, w, c) float64 luminance (cd/m^2) of each pixel's surface point: Lambertian,
    lit by ``lamps`` with a shadow ray each; 0 on a miss.

    ``albedo`` is (h, w, c) (per pixel, e.g. interpolated vertex colours) or (c,)."""
    h, w = frame.hit.shape
    alb = np.broadcast_to(np.asarray(albedo, dtype=np.float64),
                          (h, w, np.asarray(albedo).shape[-1]))
    E = np.zeros((h, w))
    idx = np.flatnonzero(frame.hit.ravel())
    if idx.size == 0 or not lamps:
        return np.zeros(alb.shape)
    p = frame.points.reshape(-1, 3)[idx]
    n = frame.normal.reshape(-1, 3)[idx]
    for lamp in lamps:
        to_lamp = lamp.position - p
        d = np.linalg.norm(to_lamp, axis=1)
        ell = to_lamp / d[:, None]
        cos_i = np.einsum("ij,ij->i", n, ell)
        lit = cos_i > 0
        cos_a = -(ell @ lamp.direction)
        e = np.where(lit, lamp.intensity_cd * lamp.profile(cos_a) * cos_i / (d * d), 0.0)
        # One shadow ray per lit point, from just above the surface towards the lamp.
        check = np.flatnonzero(e > 0)
        if check.size:
            o = p[check] + n[check] * SHADOW_EPS_M
            # Any hit ends the test (``Scene.occluded``: equal to ``cast(...).hit``).
            blocked = scene.occluded(o, ell[check],
                                     t_max=np.maximum(d[check] - 2 * SHADOW_EPS_M, 0.0))
            e[check[blocked]] = 0.0
        E.ravel()[idx] += e
    return alb * (E / math.pi)[:, :, None]


def expose(cam: CameraSpec, lum: NDArray[np.float64], *, seed: int = 0,
           noise: bool = True) -> NDArray[np.float64]:
    """Digital values (h, w, c) float64 in [0, 2^bits - 1] of luminance ``lum``: the
    electrons of the exposure (module docstring), Poisson shot noise and Gaussian read
    noise (seeded), the full well's clip."""
    H = lum * cam.exposure_s * math.pi / (4.0 * cam.f_number ** 2)
    e = cam.quantum_efficiency * K_V * cam.pixel_area_m2 * H
    if noise:
        rng = np.random.default_rng(seed)
        e = rng.poisson(e).astype(np.float64) + rng.normal(0.0, cam.read_noise_e, e.shape)
    dn = np.clip(e / cam.full_well_e, 0.0, 1.0) * (2 ** cam.bit_depth - 1)
    return dn


def srgb_encode(linear: NDArray[np.float64]) -> NDArray[np.float64]:
    """IEC 61966-2-1 transfer function of linear values in [0, 1]."""
    x = np.clip(linear, 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)


def srgb_decode(encoded: ArrayLike) -> NDArray[np.float64]:
    """Linear values in [0, 1] of sRGB-encoded values in [0, 1]: the inverse of
    ``srgb_encode`` (IEC 61966-2-1), for a mesh's 8-bit vertex colours / 255."""
    x = np.clip(np.asarray(encoded, dtype=np.float64), 0.0, 1.0)
    return np.where(x <= 0.04045, x / 12.92, np.power((x + 0.055) / 1.055, 2.4))


# ---------------------------------------------------------------------- thermal
_H = 6.62607015e-34      # Planck constant (J s), SI 2019 exact
_C = 299_792_458.0       # speed of light (m/s), exact
_KB = 1.380649e-23       # Boltzmann constant (J/K), exact


def _band_radiance(T: NDArray[np.float64], band_m: tuple[float, float],
                   n: int = 64) -> NDArray[np.float64]:
    """Black-body radiance (W m^-2 sr^-1) in ``band_m`` at temperatures ``T`` (K):
    Planck's law integrated by Gauss-Legendre quadrature over wavelength."""
    x, wts = np.polynomial.legendre.leggauss(n)
    lo, hi = band_m
    lam = 0.5 * (hi - lo) * x + 0.5 * (hi + lo)
    Tt = np.asarray(T, dtype=np.float64)[..., None]
    b = 2 * _H * _C ** 2 / lam ** 5 / np.expm1(_H * _C / (lam * _KB * Tt))
    return 0.5 * (hi - lo) * (b * wts).sum(axis=-1)


#: Temperatures (K) of the table that inverts the band radiance: 150-1000 K by 0.01 K.
_T_TABLE = np.linspace(150.0, 1000.0, 85_001)
_L_TABLES: dict[tuple[float, float], NDArray[np.float64]] = {}


def _invert_band_radiance(L: NDArray[np.float64],
                          band_m: tuple[float, float]) -> NDArray[np.float64]:
    """The black-body temperature (K, 150-1000) of band radiances ``L``.

    DECISION: a table of the band radiance every 0.01 K, inverted by linear
    interpolation (the radiance rises monotonically with T), instead of bisection on
    every pixel: 64 quadrature nodes x 50 steps per pixel took seconds per frame. The
    interpolation's error is below 1e-6 K (the radiance is smooth on 0.01 K), far
    under any camera's NETD."""
    key = (float(band_m[0]), float(band_m[1]))
    table = _L_TABLES.get(key)
    if table is None:
        table = _L_TABLES[key] = _band_radiance(_T_TABLE, key)
    return np.interp(L, table, _T_TABLE)


def apparent_temperature(cam: CameraSpec, temperature_k: NDArray[np.float64],
                         emissivity: NDArray[np.float64] | float = 0.95,
                         ambient_k: float = 288.15, *, seed: int = 0,
                         noise: bool = True) -> NDArray[np.float64]:
    """The temperature (K) a radiometric camera reports for surfaces at
    ``temperature_k`` of ``emissivity`` reflecting surroundings at ``ambient_k``
    (module docstring), with Gaussian noise of the camera's NETD."""
    if cam.band_m is None:
        raise SimulationError(f"Expected a thermal camera for a temperature image, got "
                              f"{cam.name} ({cam.kind}); pass --camera lwir_640.")
    T = np.asarray(temperature_k, dtype=np.float64)
    eps = np.broadcast_to(np.asarray(emissivity, dtype=np.float64), T.shape)
    L = eps * _band_radiance(T, cam.band_m) + (1 - eps) * _band_radiance(
        np.full(T.shape, ambient_k), cam.band_m)
    out = _invert_band_radiance(L, cam.band_m)
    if noise:
        out = out + np.random.default_rng(seed).normal(0.0, cam.netd_k, out.shape)
    return out
