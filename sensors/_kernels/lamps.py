"""Illuminance of surface points by one lamp, in one pass (``sensors.shading.luminance``).

The formulas are ``sensors.shading``'s (its module docstring): ``E = I f(alpha)
cos(theta_i) / d^2`` where the point faces the lamp (cos(theta_i) > 0), else 0, with
the spot profile ``f`` linear in the off-axis angle between the beam and cutoff
half-angles (Mitsuba 3's ``spot``). One kernel instead of NumPy's dozen temporaries:
the NumPy version took 0.4 s a lamp for a 1920x1080 frame.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from raytrace.config import CACHE, ERROR_MODEL

#: Spot profile kinds: a point lamp (f = 1 everywhere), a hard-edged beam (f = 1 within
#: the beam half-angle, 0 beyond), a linear ramp between beam and cutoff.
POINT, HARD, RAMP = 0, 1, 2


@njit(cache=CACHE, error_model=ERROR_MODEL, inline="always")
def spot_profile(cos_a, kind, beam, cutoff):
    """f(alpha) in [0, 1] for the cosine of the off-axis angle (``Lamp.profile``)."""
    if kind == POINT:
        return 1.0
    a = np.arccos(min(max(cos_a, -1.0), 1.0))
    if kind == HARD:
        return 1.0 if a <= beam else 0.0
    return min(max((cutoff - a) / (cutoff - beam), 0.0), 1.0)


@njit(parallel=True, cache=CACHE, error_model=ERROR_MODEL)
def lamp_light(p, n, lamp, axis, intensity, kind, beam, cutoff, ell, d, cos_i, cos_a,
               e):  # pragma: no cover (Numba)
    """For points ``p`` (m, 3) with unit normals ``n`` (m, 3) and a lamp at ``lamp``
    (3,) shining along the unit ``axis`` (3,): the unit direction to the lamp ``ell``
    (m, 3), its distance ``d``, cos(theta_i) = n . ell, the cosine of the off-axis
    angle ``cos_a`` = -ell . axis, and the illuminance ``e`` (lux) before shadows."""
    for i in prange(p.shape[0]):
        tx = lamp[0] - p[i, 0]
        ty = lamp[1] - p[i, 1]
        tz = lamp[2] - p[i, 2]
        di = np.sqrt(tx * tx + ty * ty + tz * tz)
        ex = tx / di
        ey = ty / di
        ez = tz / di
        ell[i, 0] = ex
        ell[i, 1] = ey
        ell[i, 2] = ez
        d[i] = di
        ci = n[i, 0] * ex + n[i, 1] * ey + n[i, 2] * ez
        ca = -(ex * axis[0] + ey * axis[1] + ez * axis[2])
        cos_i[i] = ci
        cos_a[i] = ca
        if ci > 0.0:
            e[i] = intensity * spot_profile(ca, kind, beam, cutoff) * ci / (di * di)
        else:
            e[i] = 0.0
