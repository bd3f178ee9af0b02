"""Shading (issue 35) against Mitsuba 3 (Jakob et al. 2022, https://mitsuba.readthedocs.io):
the same tunnel piece, albedo, point lamp and pinhole camera, direct lighting only.

Units, derived rather than fitted. Mitsuba is radiometric and unitless: a ``point``
emitter's ``intensity`` is its radiant intensity I (per steradian), a ``diffuse`` BSDF
of reflectance rho returns radiance rho / pi * I cos(theta_i) / d^2 with a shadow test
(Mitsuba 3 docs, plugins ``point`` and ``diffuse``). ``sensors.shading.luminance`` is
rho / pi * I cos(theta_i) / d^2 in photometric units (cd -> cd/m^2). Both are the same
function of the same number I; the factor 683 lm/W between the unit systems applies to
both sides, so the images compare as they are, with no scale fitted.

Scene choices that make the two renderers compute the same quantity:
- ``face_normals``: Mitsuba shades with the geometric normal, as we do (no vertex
  normal interpolation);
- ``twosided``: a Mitsuba ``diffuse`` BSDF is black from behind; the camera sits inside
  the tube, whose faces may point either way, and ours turns each normal towards the
  camera;
- ``direct`` integrator (direct illumination only: one bounce, i.e. ``path`` with
  ``max_depth`` 2), ``scalar_rgb``, one emitter sample and no BSDF sample per path (a
  point light cannot be hit by a BSDF sample);
- the ``perspective`` sensor's horizontal ``fov`` across the image's edges is ours,
  2 atan(w / 2 / fx), its principal point the image centre (ours (w - 1) / 2 in
  pixel-centre coordinates: the same point).

The residual: ours samples each pixel's centre, Mitsuba's ``box`` filter averages the
pixel's area (256 samples). They differ where the radiance is not linear across a
pixel: creases of the faceted mesh (the face normal, hence the cosine, jumps inside a
pixel: floor/wall corners, the rough lining's facets), the open far portal's rim and
shadow edges; plus Mitsuba's Monte-Carlo noise over the pixel area and its float32
geometry. Measured (2026-11-27, 96x72 pixels, 100 deg across): PSNR 59.1 dB for the
point lamp, 55.0 dB for the headlamp (a spot; its 30-45 deg ramp, linear in angle in
both renderers, crosses the frame) over the whole frame (peak = the reference's
maximum), mean radiance equal to 5e-5 and 2e-4 relative; the largest single-pixel
differences sit on floor/wall creases. A smoothstep ramp instead of Mitsuba's linear
one gives 27 dB for the headlamp: the test tells the two apart.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from raytrace import Scene
from raytrace.shapes import tunnel_tube
from sensors.camera import load_camera
from sensors.render import camera_pose, render_depth
from sensors.shading import Lamp, headlamp, luminance

mi = pytest.importorskip("mitsuba", reason="Mitsuba 3 is the shading reference (pip "
                                           "install mitsuba)")

W, H, SPP = 96, 72, 256


def _mitsuba_lamp(lamp):
    """Our Lamp as a Mitsuba emitter: ``point``, or ``spot`` with the same half-angles
    (Mitsuba's ``cutoff_angle`` and ``beam_width`` are angles from the axis)."""
    if lamp.cutoff_half_angle_rad >= math.pi:
        return {"type": "point", "position": lamp.position.tolist(),
                "intensity": {"type": "rgb", "value": [lamp.intensity_cd] * 3}}
    d = lamp.direction
    up = [0.0, 0.0, 1.0] if abs(d[2]) < 0.9 else [1.0, 0.0, 0.0]
    return {"type": "spot", "cutoff_angle": math.degrees(lamp.cutoff_half_angle_rad),
            "beam_width": math.degrees(lamp.beam_half_angle_rad),
            "intensity": {"type": "rgb", "value": [lamp.intensity_cd] * 3},
            "to_world": mi.ScalarTransform4f().look_at(
                origin=lamp.position.tolist(), target=(lamp.position + d).tolist(), up=up)}


def _mitsuba_image(v, f, obj, T, fx, lamp, rho):
    mi.set_variant("scalar_rgb")
    with open(obj, "w") as fh:
        fh.writelines("v %.17g %.17g %.17g\n" % tuple(p) for p in v)
        fh.writelines("f %d %d %d\n" % tuple(t + 1) for t in f)
    p, down, fwd = T[:3, 3], T[:3, 1], T[:3, 2]
    scene = mi.load_dict({
        "type": "scene",
        "integrator": {"type": "direct", "emitter_samples": 1, "bsdf_samples": 0},
        "sensor": {
            "type": "perspective", "fov_axis": "x",
            "fov": math.degrees(2 * math.atan((W / 2) / fx)),
            # Mitsuba's camera looks along its +z with +y up: up = -(our y, down).
            "to_world": mi.ScalarTransform4f().look_at(origin=p.tolist(),
                                                       target=(p + fwd).tolist(),
                                                       up=(-down).tolist()),
            "film": {"type": "hdrfilm", "width": W, "height": H, "pixel_format": "rgb",
                     "rfilter": {"type": "box"}},
            "sampler": {"type": "independent", "sample_count": SPP}},
        "tube": {"type": "obj", "filename": str(obj), "face_normals": True,
                 "bsdf": {"type": "twosided", "bsdf": {
                     "type": "diffuse",
                     "reflectance": {"type": "rgb", "value": list(rho)}}}},
        "lamp": _mitsuba_lamp(lamp),
    })
    return np.array(mi.render(scene, spp=SPP), dtype=np.float64)[..., :3]


@pytest.mark.parametrize("kind", ["point", "headlamp"])
def test_lambertian_shading_matches_mitsuba_without_fitting(tmp_path, kind):
    """A point lamp off the axis, and the headlamp ``render`` uses (a spot 5 cm above
    the camera, full within 30 deg, falling to 0 at 45 deg off its axis: the
    profile's ramp shows inside the frame)."""
    v, f = tunnel_tube(3_000, length_m=12.0, seed=2)
    fx = (W / 2) / math.tan(math.radians(100.0) / 2)
    cam = replace(load_camera("realsense_d435_color"), width=W, height=H, fx=fx, fy=fx,
                  cx=(W - 1) / 2, cy=(H - 1) / 2, distortion=np.zeros(5))
    T = camera_pose([2.0, 0.2, 1.3], math.radians(5.0), math.radians(-3.0))
    scene = Scene(v, f)
    fr = render_depth(scene, cam, T)
    rho = (0.6, 0.45, 0.3)
    lamp = Lamp([3.0, -0.5, 1.8], [1.0, 0.0, 0.0], 50.0) if kind == "point" else \
        headlamp(T, 50.0)
    ours = luminance(scene, fr, [lamp], np.array(rho))
    ref = _mitsuba_image(v, f, tmp_path / "tube.obj", T, fx, lamp, rho)
    assert ref.shape == ours.shape
    mse = float(((ours - ref) ** 2).mean())
    psnr = 10 * math.log10(ref.max() ** 2 / mse)
    assert psnr >= 30.0, psnr
    # Not a match by scale: the mean radiance agrees to 1 % (no factor fitted), and the
    # channels keep the albedo's ratios.
    assert ours.mean() == pytest.approx(ref.mean(), rel=0.01)
    lit = ref[..., 0] > 0.05 * ref.max()
    np.testing.assert_allclose(ref[..., 1][lit] / ref[..., 0][lit], rho[1] / rho[0],
                               rtol=1e-3)
    # The brightest pixels of both images lie in the same place (a mirrored image
    # fails here), and so do the spot's dark corners.
    assert np.unravel_index(ours[..., 0].argmax(), (H, W)) == pytest.approx(
        np.unravel_index(ref[..., 0].argmax(), (H, W)), abs=2)
    if kind == "headlamp":
        to_p = np.where(fr.hit[..., None], fr.points - lamp.position, 1.0)
        a = np.degrees(np.arccos(np.clip(to_p @ lamp.direction
                                         / np.linalg.norm(to_p, axis=-1), -1, 1)))
        ramp = fr.hit & (a > 31) & (a < 44)
        dark = fr.hit & (a > 46)
        assert ramp.sum() > 200 and dark.sum() > 200
        assert np.all(ours[dark] == 0) and ref[dark].max() < 1e-3 * ref.max()
        # On the ramp (30-45 deg) the two profiles agree pixel by pixel: the median
        # relative difference is Mitsuba's noise; the few pixels beyond 5 % sit on
        # the mesh's creases, as in the whole frame.
        rel = np.abs(ours[ramp][:, 0] - ref[ramp][:, 0]) / np.maximum(ref[ramp][:, 0],
                                                                      1e-3 * ref.max())
        assert np.median(rel) < 0.01 and np.mean(rel > 0.05) < 0.02
