"""What a camera sees in a tunnel without daylight: Lambertian surfaces, and
retro-reflectors, lit by the platform's own lamps (with a shadow ray per lamp), the
exposure that turns radiance into electrons and digital values with shot and read
noise, and a thermal camera's apparent temperature.

Radiometry (photometric units: a lamp's intensity in candela, illuminance in lux,
luminance in cd/m^2; each colour channel scaled by the surface's albedo):

- A lamp of intensity ``I`` (cd) at distance ``d`` lights a surface point with
  illuminance ``E = I f(alpha) cos(theta_i) / d^2`` (inverse-square law, Lambert's
  cosine law), where ``f`` is the spot profile: 1 inside ``beam_half_angle``,
  falling linearly in angle to 0 at ``cutoff_half_angle`` (Mitsuba 3's ``spot``
  emitter: ``beam_width`` and ``cutoff_angle``, the same ramp), 1 everywhere for a
  point lamp; 0 if a shadow ray from the point meets the mesh before the lamp.
- A Lambertian surface of albedo ``rho`` has luminance ``L = rho E / pi``.
- A retro-reflective surface (a ``sensors.appearance.Material`` flagged
  ``retroreflective``: prisms, signs) adds the light it returns towards the lamp:
  ``L_retro = R_A(alpha, beta) E_perp / cos(v)`` in every channel (white sheeting),
  with ``E_perp = I f(alpha_lamp) / d^2`` the illuminance on a plane perpendicular to
  the incident light, ``alpha`` the observation angle (lamp - surface - camera),
  ``beta`` the entrance angle (incident light to the surface normal) and ``v`` the
  viewing angle (camera to the normal). CIE 54.2 (2001) and the CIE ILV (17-24-103,
  17-24-104): ``R_A = R / A`` with ``R = I_r / E_perp`` and ``R_L = L / E_perp``; a
  plane's luminance is its intensity over its projected area, ``L = I_r / (A cos v)``,
  so ``R_L = R_A / cos v`` (``L = R_A E_perp`` facing the camera). ``R_A`` comes from
  ``RETRO_RA_WHITE`` (``retro_coefficient``).
- Lamps: ``headlamp`` (a spot beside the camera) and ``platform_lamps`` (a platform
  file's ``[[lamps]]`` placed with its base_link's pose).
- Anti-aliasing (``radiance_frame``): the luminance of a k x k grid of stratified rays
  through each pixel, averaged (a box filter over the pixel, Mitsuba's ``box``); the
  depth stays the pixel centre's. A thermal camera's pixel (``thermal_frame``) averages
  the band radiance of its rays that meet a surface, then inverts it.
- The sensor (Holst & Lomheim, *CMOS/CCD Sensors and Camera Systems*, 2nd ed. 2011,
  ch. 3): image-plane exposure ``H = L t pi / (4 N^2)`` (lux s) for f-number ``N``
  and exposure ``t``; electrons ``e = QE K_v H A_pix`` with ``K_v = 4.1e15`` photons
  per lux s per m^2 at 555 nm; Poisson shot noise and Gaussian read noise; the
  digital value ``g e / full_well * (2^bits - 1)`` at analog gain ``g`` (read noise
  amplified with the signal), clipped; the colour PNG is sRGB encoded (IEC 61966-2-1).
- Auto-exposure (``auto_exposure``, cameras with ``auto_exposure``): average metering
  of the noiseless frame, aiming its mean linear digital value at 18 % of full scale
  (the photographic mid grey, ISO 12232's 18 % reference reflectance: about 118 of 255
  after sRGB encoding); the exposure time first (between ``AE_MIN_EXPOSURE_S`` and the
  camera's ``exposure_s``), then the gain (up to ``gain_max``) once the time is at its
  longest. DECISION: metered on the frame itself (a converged AE loop), not on the
  previous frame, so that each frame is exposed as a settled camera would expose it;
  the frame's timing (stamps, rolling-shutter rows) keeps the camera's ``exposure_s``.
- Thermal (``apparent_temperature``): the surface's radiance in the camera's band,
  ``eps B(T) + (1 - eps) B(T_ambient)``, inverted to the temperature of a black body
  of that radiance (Planck's law integrated over the band), plus Gaussian noise of
  the camera's NETD.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Final, Protocol

import numpy as np
from numpy.typing import ArrayLike, NDArray

from raytrace import Scene

from ._kernels.lamps import HARD, POINT, RAMP, lamp_light
from ._kernels.noise import shot_and_read
from .camera import CameraSpec
from .errors import SimulationError
from .platform_spec import PlatformSpec
from .render import Frame, render_depth


class _Surfaces(Protocol):
    """What ``radiance_frame`` needs of a mesh's appearance
    (``sensors.appearance.Appearance``, not imported: it imports this module)."""

    def at(self, frame: Frame) -> Any: ...

__all__ = ["AE_MIN_EXPOSURE_S", "AE_TARGET", "Lamp", "K_V", "RETRO_ENTRANCE_DEG",
           "RETRO_ENTRANCE_ZERO_DEG", "RETRO_OBSERVATION_DEG", "RETRO_RA_WHITE",
           "apparent_temperature", "auto_exposure", "expose", "headlamp", "luminance",
           "platform_lamps", "radiance_frame", "retro_coefficient", "srgb_decode",
           "srgb_encode", "stratified_offsets", "thermal_frame"]

#: Photons per lux second per square metre at 555 nm (683 lm/W; Holst & Lomheim ch. 2).
K_V = 4.1e15
#: Auto-exposure's aim: the frame's mean linear digital value, a fraction of full scale
#: (18 %: the photographic mid grey, ISO 12232).
AE_TARGET = 0.18
#: Shortest exposure auto-exposure takes (s). ASSUMED: 20 us, a CMOS sensor's few rows.
AE_MIN_EXPOSURE_S = 20e-6
#: Offset along the normal for shadow rays (metres): above the float64 surface noise.
SHADOW_EPS_M = 1e-6

#: Retro-reflection of white retro-reflective sheeting: the coefficient of
#: retroreflection R_A (cd lx^-1 m^-2; CIE 54.2) at the observation angles
#: ``RETRO_OBSERVATION_DEG`` (rows) and the entrance angles ``RETRO_ENTRANCE_DEG``
#: (columns). Sourced: ASTM D4956 (2001 edition, as tabulated on
#: angelfire.com/trek/cityton/american.htm) Type III (high-intensity) white:
#: 0.1 deg: 300 (-4 deg entrance), 180 (+30 deg); 0.2 deg: 250, 150; 0.5 deg: 95 at -4
#: deg. ASSUMED: 65 at 0.5 deg / +30 deg (the same table's value as usually quoted;
#: the source's excerpt stops before it); 5 and 2.5 at 2 deg (EN 12899-1 class RA2
#: white's 2 deg row, not found in a source here); 0 at 4 deg (the return is a narrow
#: cone; beyond the tables' 2 deg it is taken to vanish linearly). Types I and II white
#: (0.2 deg, -4 deg: 70 and 140) are 3.6 and 1.8 times dimmer.
RETRO_OBSERVATION_DEG: Final = (0.1, 0.2, 0.5, 2.0, 4.0)
RETRO_ENTRANCE_DEG: Final = (4.0, 30.0)
RETRO_RA_WHITE: Final = ((300.0, 180.0), (250.0, 150.0), (95.0, 65.0), (5.0, 2.5),
                         (0.0, 0.0))
#: R_A falls linearly in the entrance angle from the +30 deg column to 0 here (ASSUMED:
#: microprismatic sheeting's entrance angularity ends near 60 deg).
RETRO_ENTRANCE_ZERO_DEG: Final = 60.0


def retro_coefficient(observation_rad: ArrayLike, entrance_rad: ArrayLike
                      ) -> NDArray[np.float64]:
    """The coefficient of retroreflection R_A (cd lx^-1 m^-2) of ``RETRO_RA_WHITE`` at
    observation angles ``observation_rad`` (lamp - surface - camera) and entrance
    angles ``entrance_rad`` (incident light to the surface normal), broadcast.

    Linear in the observation angle between the table's rows (held below 0.1 deg, 0
    from 4 deg), then linear in the entrance angle between the columns (held below 4
    deg), falling linearly to 0 at ``RETRO_ENTRANCE_ZERO_DEG`` beyond 30 deg. The sign
    of the entrance angle is ignored (the table's -4 deg stands for near-normal light).

    >>> import numpy as np
    >>> retro_coefficient(np.radians([0.2, 0.35]), np.radians([4.0, 4.0])).tolist()
    [250.0, 172.5]
    """
    a = np.degrees(np.abs(np.asarray(observation_rad, dtype=np.float64)))
    b = np.degrees(np.abs(np.asarray(entrance_rad, dtype=np.float64)))
    obs = np.asarray(RETRO_OBSERVATION_DEG)
    ra = np.asarray(RETRO_RA_WHITE)
    near = np.interp(a, obs, ra[:, 0], right=0.0)
    far = np.interp(a, obs, ra[:, 1], right=0.0)
    b0, b1 = RETRO_ENTRANCE_DEG
    t = np.clip((b - b0) / (b1 - b0), 0.0, 1.0)
    fade = np.clip((RETRO_ENTRANCE_ZERO_DEG - b) / (RETRO_ENTRANCE_ZERO_DEG - b1), 0.0, 1.0)
    return np.asarray((near + t * (far - near)) * fade, dtype=np.float64)


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


def _rpy_matrix(roll: float, pitch: float, yaw: float) -> NDArray[np.float64]:
    """R = Rz(yaw) Ry(pitch) Rx(roll): roll, pitch, yaw about the fixed x, y, z axes
    (URDF's ``rpy``, REP 103)."""
    cr, sr = math.cos(roll), math.sin(roll)
    cp, sp = math.cos(pitch), math.sin(pitch)
    cy, sy = math.cos(yaw), math.sin(yaw)
    return np.array([[cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
                     [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
                     [-sp, cp * sr, cp * cr]])


def platform_lamps(platform: PlatformSpec, world_from_base: ArrayLike) -> list[Lamp]:
    """The lamps of ``platform`` (its ``[[lamps]]``) in the world, for the platform's
    base_link posed at ``world_from_base``.

    Parameters
    ----------
    platform : PlatformSpec
        ``sensors.platform_spec.load_platform``; its ``lamps`` are in base_link (x
        forward, y left, z up), a spot's beam along its lamp frame's +x after
        ``rpy``.
    world_from_base : (4, 4) array_like of float
        Pose of base_link in the world (a rigid transform).

    Returns
    -------
    list of Lamp
        One per platform lamp, in the file's order (empty for a platform without
        lamps): position ``T p``, beam ``R R_rpy e_x``; a point lamp keeps
        ``cutoff_half_angle_rad`` = pi (its direction, +x of base_link, is unused).

    Raises
    ------
    SimulationError
        ``world_from_base`` not a finite 4x4 rigid transform.

    Examples
    --------
    >>> import numpy as np
    >>> from sensors.platform_spec import load_platform
    >>> lamps = platform_lamps(load_platform("ground_robot"), np.eye(4))
    >>> len(lamps), lamps[0].position.round(3).tolist()
    (2, [0.161, 0.07, 0.2])
    """
    T = np.asarray(world_from_base, dtype=np.float64)
    if T.shape != (4, 4) or not np.isfinite(T).all():
        raise SimulationError(f"Expected world_from_base as a finite 4x4 matrix, got "
                              f"shape {T.shape}.")
    R = T[:3, :3]
    if not np.allclose(R.T @ R, np.eye(3), atol=1e-9) or np.linalg.det(R) < 0 or \
            not np.allclose(T[3], [0.0, 0.0, 0.0, 1.0]):
        raise SimulationError("Expected world_from_base to be a rigid transform (a proper "
                              "rotation, last row 0 0 0 1), got one that is not.")
    out = []
    for lamp in platform.lamps:
        beam = R @ _rpy_matrix(*lamp.rpy_rad)[:, 0]
        out.append(Lamp(R @ np.asarray(lamp.xyz_m, dtype=np.float64) + T[:3, 3], beam,
                        lamp.intensity_cd, lamp.beam_half_angle_rad,
                        lamp.cutoff_half_angle_rad))
    return out


def _profile_kind(lamp: Lamp) -> tuple[int, float, float]:
    """``Lamp.profile`` as the kernel's (kind, beam, cutoff)."""
    b, c = float(lamp.beam_half_angle_rad), float(lamp.cutoff_half_angle_rad)
    kind = POINT if c >= math.pi else (HARD if c == b else RAMP)
    return kind, b, c


def _camera_centres(frame: Frame) -> NDArray[np.float64]:
    """(h, w, 3) optical centre each pixel's ray starts from (its row's pose for a
    rolling shutter)."""
    h, w = frame.hit.shape
    if frame.row_poses is not None:
        return np.broadcast_to(frame.row_poses[:, None, :3, 3], (h, w, 3))
    return np.broadcast_to(frame.world_from_camera[:3, 3], (h, w, 3))


def luminance(scene: Scene, frame: Frame, lamps: Sequence[Lamp],
              albedo: NDArray[np.float64],
              retroreflective: NDArray[np.bool_] | None = None) -> NDArray[np.float64]:
    """(h, w, c) float64 luminance (cd/m^2) of each pixel's surface point: Lambertian,
    lit by ``lamps`` with a shadow ray each, plus the retro-reflected luminance
    ``R_A E_perp / cos v`` (module notes) where ``retroreflective``; 0 on a miss.

    ``albedo`` is (h, w, c) (per pixel, e.g. interpolated vertex colours) or (c,);
    ``retroreflective`` (h, w) bool, or None for none. The retro-reflected light is
    white (added to every channel); it needs the same shadow ray (the light has to
    reach the surface) and returns along the camera's own ray."""
    h, w = frame.hit.shape
    alb = np.broadcast_to(np.asarray(albedo, dtype=np.float64),
                          (h, w, np.asarray(albedo).shape[-1]))
    E = np.zeros((h, w))
    idx = np.flatnonzero(frame.hit.ravel())
    if idx.size == 0 or not lamps:
        return np.zeros(alb.shape)
    p = frame.points.reshape(-1, 3)[idx]
    n = frame.normal.reshape(-1, 3)[idx]
    retro = None
    if retroreflective is not None:
        r = np.flatnonzero(np.asarray(retroreflective, dtype=bool).reshape(-1)[idx])
        if r.size:
            retro = r
            to_cam = _camera_centres(frame).reshape(-1, 3)[idx[r]] - p[r]
            to_cam /= np.linalg.norm(to_cam, axis=1)[:, None]
            cos_v = np.einsum("ij,ij->i", n[r], to_cam)
            L_retro = np.zeros(r.size)
    m = idx.size
    ell, d, cos_i, cos_a, e = np.empty((m, 3)), np.empty(m), np.empty(m), np.empty(m), \
        np.empty(m)
    for lamp in lamps:
        lamp_light(p, n, np.asarray(lamp.position, dtype=np.float64),
                   np.asarray(lamp.direction, dtype=np.float64), float(lamp.intensity_cd),
                   *_profile_kind(lamp), ell, d, cos_i, cos_a, e)
        # One shadow ray per lit point, from just above the surface towards the lamp.
        check = np.flatnonzero(e > 0)
        if check.size:
            o = p[check] + n[check] * SHADOW_EPS_M
            # Any hit ends the test (``Scene.occluded``: equal to ``cast(...).hit``).
            blocked = scene.occluded(o, ell[check],
                                     t_max=np.maximum(d[check] - 2 * SHADOW_EPS_M, 0.0))
            e[check[blocked]] = 0.0
        E.ravel()[idx] += e
        if retro is not None:
            # CIE 54.2: L = R_A(alpha, beta) E_perp / cos v, where the lamp's light
            # reaches the surface (e > 0: in the beam, in front, not shadowed).
            ok = e[retro] > 0
            k = retro[ok]
            e_perp = lamp.intensity_cd * lamp.profile(cos_a[k]) / (d[k] * d[k])
            alpha = np.arccos(np.clip(np.einsum("ij,ij->i", ell[k], to_cam[ok]),
                                      -1.0, 1.0))
            beta = np.arccos(np.clip(cos_i[k], -1.0, 1.0))
            L_retro[ok] += retro_coefficient(alpha, beta) * e_perp / cos_v[ok]
    out = alb * (E / math.pi)[:, :, None]
    if retro is not None:
        extra = np.zeros(h * w)
        extra[idx[retro]] = L_retro
        out = out + extra.reshape(h, w)[:, :, None]
    return out


def stratified_offsets(samples_per_pixel: int) -> NDArray[np.float64]:
    """(n, 2) float64 sub-pixel offsets (dx, dy) in pixels from the pixel centre: the
    centres of a k x k grid of strata over the pixel (-0.5..0.5), n = k^2, row by row.

    One sample is the pixel centre (0, 0). Stratified sampling (Mitchell 1996,
    "Consequences of stratified sampling in graphics", SIGGRAPH; Pharr, Jakob &
    Humphreys, *PBR* 4th ed., 8.5) with each stratum's centre instead of a random
    point: deterministic (frames and tests reproduce), and the average is the
    midpoint rule for the integral over the pixel a box filter takes.

    >>> stratified_offsets(4).tolist()
    [[-0.25, -0.25], [0.25, -0.25], [-0.25, 0.25], [0.25, 0.25]]
    """
    n = samples_per_pixel
    k = math.isqrt(n) if isinstance(n, (int, np.integer)) and n > 0 else 0
    if k * k != n or k == 0:
        raise SimulationError(f"Expected --samples to be a square number of samples per "
                              f"pixel (1, 4, 9, 16, ...), got {n!r}; pass --samples "
                              f"{max(k, 1) ** 2}.")
    c = (np.arange(k) + 0.5) / k - 0.5
    dx, dy = np.meshgrid(c, c)
    return np.column_stack([dx.ravel(), dy.ravel()])


def radiance_frame(scene: Scene, cam: CameraSpec, world_from_camera: ArrayLike,
                   lamps: Sequence[Lamp], appearance: _Surfaces | ArrayLike,
                   samples_per_pixel: int = 1) -> tuple[Frame, NDArray[np.float64]]:
    """The pixel-centre frame and the (h, w, c) luminance of each pixel averaged over
    ``samples_per_pixel`` stratified rays through the pixel (anti-aliasing).

    Parameters
    ----------
    scene : raytrace.Scene
    cam : CameraSpec
    world_from_camera : (4, 4) or (height, 4, 4) array_like
        As ``sensors.render.render_depth`` (per-row poses for a rolling shutter).
    lamps : sequence of Lamp
    appearance : sensors.appearance.Appearance or (c,) array_like of float
        The mesh's appearance (albedo and the retro-reflective flag looked up at every
        sample's hit) or one albedo for the whole mesh (no retro-reflection).
    samples_per_pixel : int
        A square number (``stratified_offsets``); 1: one ray through the pixel centre.

    Returns
    -------
    frame : Frame
        The pixel-centre frame (depth, normals, triangles: a depth camera does not
        average).
    luminance : (h, w, c) float64
        cd/m^2, the mean over the samples of ``luminance`` (linear radiance, averaged
        before the exposure); a sample that misses the mesh adds 0. With one sample it
        is ``luminance(scene, frame, lamps, albedo, retroreflective)`` exactly.

    Raises
    ------
    SimulationError
        ``samples_per_pixel`` not a square number >= 1, or what ``render_depth``
        refuses.
    """
    offsets = stratified_offsets(samples_per_pixel)

    def shade(fr: Frame) -> NDArray[np.float64]:
        if hasattr(appearance, "at"):
            px = appearance.at(fr)
            return luminance(scene, fr, lamps, np.nan_to_num(px.albedo, nan=0.0),
                             getattr(px, "retroreflective", None))
        return luminance(scene, fr, lamps, np.asarray(appearance, dtype=np.float64))

    centre = render_depth(scene, cam, world_from_camera)
    if len(offsets) == 1:
        return centre, shade(centre)
    total: NDArray[np.float64] | None = None
    for dx, dy in offsets:
        # DECISION: each sample is a whole frame through render_depth's offset lens
        # (its ray cache holds 16 offsets), shaded alone and summed: memory stays one
        # frame's whatever the count. An odd k's middle stratum is the centre frame.
        fr = centre if dx == 0.0 and dy == 0.0 else \
            render_depth(scene, cam, world_from_camera, pixel_offset=(dx, dy))
        lum = shade(fr)
        total = lum if total is None else total + lum
    assert total is not None
    return centre, total / len(offsets)


def expose(cam: CameraSpec, lum: NDArray[np.float64], *, seed: int = 0,
           noise: bool = True, exposure_s: float | None = None,
           gain: float = 1.0) -> NDArray[np.float64]:
    """Digital values (h, w, c) float64 in [0, 2^bits - 1] of luminance ``lum``: the
    electrons of the exposure (module docstring), Poisson shot noise and Gaussian read
    noise (seeded), the full well's clip, the analog ``gain``.

    ``exposure_s`` (default the camera's) and ``gain`` (>= 1): as ``auto_exposure``
    chooses them, or fixed."""
    t = cam.exposure_s if exposure_s is None else float(exposure_s)
    if not (math.isfinite(t) and t > 0.0):
        raise SimulationError(f"Expected a positive exposure time (s), got {t}; pass "
                              "the camera's exposure or auto_exposure()'s.")
    if not (math.isfinite(gain) and gain >= 1.0):
        raise SimulationError(f"Expected an analog gain >= 1, got {gain}; pass 1.0 for "
                              "none.")
    H = lum * t * math.pi / (4.0 * cam.f_number ** 2)
    e = cam.quantum_efficiency * K_V * cam.pixel_area_m2 * H
    if noise:
        # One parallel pass, each value from its own stream of the seed's SplitMix64
        # sequence (``_kernels/noise.py``): the same frame for any thread count.
        key = np.random.SeedSequence(seed).generate_state(1, np.uint64)[0]
        flat = np.ascontiguousarray(e, dtype=np.float64).reshape(-1)
        noisy = np.empty_like(flat)
        if shot_and_read(flat, key, float(cam.read_noise_e), noisy):
            raise SimulationError("Expected finite, non-negative luminance to expose, got "
                                  "NaN, inf or negative values; check the lamps and the "
                                  "albedo (0 where nothing is lit).")
        e = noisy.reshape(np.shape(e))
    e = np.minimum(e, cam.full_well_e)     # the pixel saturates before the gain
    dn = np.clip(gain * e / cam.full_well_e, 0.0, 1.0) * (2 ** cam.bit_depth - 1)
    return dn


def auto_exposure(cam: CameraSpec, lum: NDArray[np.float64]) -> tuple[float, float]:
    """(exposure_s, gain) that bring the mean linear digital value of the noiseless
    frame of luminance ``lum`` (h, w, c) to ``AE_TARGET`` of full scale (module
    docstring): the time within [``AE_MIN_EXPOSURE_S``, ``cam.exposure_s``] first,
    then the gain within [1, ``cam.gain_max``]. A frame without light gets the longest
    time and the largest gain."""
    mean = float(np.mean(np.nan_to_num(lum, nan=0.0))) if np.size(lum) else 0.0
    t_max = cam.exposure_s
    e_mean = cam.quantum_efficiency * K_V * cam.pixel_area_m2 * mean * t_max * \
        math.pi / (4.0 * cam.f_number ** 2)
    if not (math.isfinite(e_mean) and e_mean > 0.0):
        return t_max, cam.gain_max
    want = AE_TARGET / (e_mean / cam.full_well_e)      # factor on (t_max, gain 1)
    t = min(t_max, max(min(AE_MIN_EXPOSURE_S, t_max), t_max * want))
    gain = min(cam.gain_max, max(1.0, want * t_max / t))
    return t, gain


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
    return _apparent(cam, _surface_radiance(cam, temperature_k, emissivity, ambient_k),
                     seed, noise)


def _surface_radiance(cam: CameraSpec, temperature_k: ArrayLike,
                      emissivity: ArrayLike | float, ambient_k: float
                      ) -> NDArray[np.float64]:
    """Band radiance (W m^-2 sr^-1) ``eps B(T) + (1 - eps) B(T_ambient)``."""
    T = np.asarray(temperature_k, dtype=np.float64)
    eps = np.broadcast_to(np.asarray(emissivity, dtype=np.float64), T.shape)
    assert cam.band_m is not None
    return eps * _band_radiance(T, cam.band_m) + (1 - eps) * _band_radiance(
        np.full(T.shape, ambient_k), cam.band_m)


def _apparent(cam: CameraSpec, L: NDArray[np.float64], seed: int, noise: bool
              ) -> NDArray[np.float64]:
    """The black body's temperature of band radiances ``L``, plus the NETD's noise."""
    assert cam.band_m is not None
    out = _invert_band_radiance(L, cam.band_m)
    if noise:
        out = out + np.random.default_rng(seed).normal(0.0, cam.netd_k, out.shape)
    return out


def thermal_frame(scene: Scene, cam: CameraSpec, world_from_camera: ArrayLike,
                  appearance: _Surfaces, ambient_k: float, samples_per_pixel: int = 1,
                  *, seed: int = 0, noise: bool = True
                  ) -> tuple[Frame, NDArray[np.float64]]:
    """The pixel-centre frame and the (h, w) apparent temperature (K) of a thermal
    camera, its band radiance averaged over ``samples_per_pixel`` stratified rays.

    Parameters
    ----------
    scene, cam, world_from_camera
        As ``radiance_frame`` (``cam`` a thermal camera).
    appearance : sensors.appearance.Appearance
        Temperature and emissivity at every sample's hit.
    ambient_k : float
        The surroundings each surface reflects (K).
    samples_per_pixel : int
        A square number (``stratified_offsets``).
    seed, noise
        The NETD's noise, as ``apparent_temperature``.

    Returns
    -------
    frame : Frame
    temperature_k : (h, w) float64
        NaN where the pixel centre's ray misses (the depth's mask); elsewhere the
        temperature of the mean band radiance of the pixel's rays that meet a surface.
        DECISION: a ray that misses (an open portal) sees no surface of known
        temperature: it is left out of the mean, not counted as 0 K. With one sample
        it is ``apparent_temperature`` of the centre's surface exactly.

    Raises
    ------
    SimulationError
        Not a thermal camera, or ``samples_per_pixel`` not a square number.
    """
    if cam.band_m is None:
        raise SimulationError(f"Expected a thermal camera for a temperature image, got "
                              f"{cam.name} ({cam.kind}); pass --camera lwir_640.")
    offsets = stratified_offsets(samples_per_pixel)
    centre = render_depth(scene, cam, world_from_camera)
    total = np.zeros(centre.hit.shape)
    count = np.zeros(centre.hit.shape)
    for dx, dy in offsets:
        fr = centre if dx == 0.0 and dy == 0.0 else \
            render_depth(scene, cam, world_from_camera, pixel_offset=(dx, dy))
        px = appearance.at(fr)
        # Evaluated on the hits alone, as ``apparent_temperature`` on the centre's.
        total[fr.hit] += _surface_radiance(cam, px.temperature_k[fr.hit],
                                           px.emissivity[fr.hit], ambient_k)
        count[fr.hit] += 1
    out = np.full(centre.hit.shape, np.nan)
    hit = centre.hit
    if len(offsets) == 1:
        L = total[hit]
    else:
        n = count[hit]
        L = total[hit] / np.maximum(n, 1)
        none = n == 0       # the centre hits a sliver none of the strata's rays meet
        if none.any():
            px = appearance.at(centre)
            L[none] = _surface_radiance(cam, px.temperature_k[hit][none],
                                        px.emissivity[hit][none], ambient_k)
    out[hit] = _apparent(cam, L, seed, noise)
    return centre, out
