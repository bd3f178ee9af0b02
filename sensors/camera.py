"""Cameras as data: one TOML file per camera in ``sensors/cameras/`` (``list_cameras``),
loaded through the one spec loader (``sensors.specfile``) into a frozen ``CameraSpec``,
and the lens models that map between pixels and rays.

Frames: the OpenCV optical frame (x right, y down, z forward along the optical axis);
pixel (u, v) = (0, 0) is the *centre* of the top-left pixel, as OpenCV's
``projectPoints`` and ``camera_info`` (ROS ``sensor_msgs/CameraInfo``) state it.

Lens models (the two OpenCV implements, so that a user's calibration drops in):

- ``pinhole``: Brown–Conrady distortion (Brown 1966, "Decentering distortion of
  lenses", Photogramm. Eng. 32(3); Conrady 1919, MNRAS 79), OpenCV's ``k1 k2 p1 p2 k3``::

      x' = X/Z, y' = Y/Z, r2 = x'^2 + y'^2, radial = 1 + k1 r2 + k2 r2^2 + k3 r2^3
      x'' = x' radial + 2 p1 x'y' + p2 (r2 + 2 x'^2)
      y'' = y' radial + p1 (r2 + 2 y'^2) + 2 p2 x'y'
      u = fx x'' + cx,  v = fy y'' + cy

- ``fisheye``: the Kannala–Brandt model (Kannala & Brandt 2006, "A generic camera model
  and calibration method for conventional, wide-angle, and fish-eye lenses", IEEE
  TPAMI 28(8)) as OpenCV's ``cv::fisheye`` writes it, ``k1 k2 k3 k4``::

      theta = atan2(sqrt(X^2 + Y^2), Z)
      theta_d = theta (1 + k1 theta^2 + k2 theta^4 + k3 theta^6 + k4 theta^8)
      u = fx theta_d X / sqrt(X^2 + Y^2) + cx, likewise v

Unprojection (pixel to ray) inverts these by Newton's method on the undistorted
normalised coordinates (pinhole) or on theta (fisheye), to 1e-12; a pixel whose
inversion does not converge (outside the lens's monotonic range) gets a NaN ray.

>>> cam = load_camera("realsense_d435_depth")
>>> cam.width, cam.height, cam.model
(1280, 720, 'pinhole')
>>> uv = project(cam, [[0.0, 0.0, 2.0]])
>>> uv.round(3).tolist() == [[cam.cx, cam.cy]]
True
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Final

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .errors import CameraSpecError
from .specfile import Catalogue, SpecTable, read_toml

__all__ = ["CAMERA_DIR", "KINDS", "MODELS", "TABLE_KEYS", "CameraSpec", "list_cameras",
           "load_camera", "pixel_rays", "project", "unproject"]

CAMERA_DIR: Final = Path(__file__).resolve().parent / "cameras"
#: What a camera records: colour (RGB), depth (z in metres) or thermal (radiance).
KINDS: Final = ("color", "depth", "thermal")
#: Lens models (OpenCV's two).
MODELS: Final = ("pinhole", "fisheye")
#: Number of distortion coefficients per model (OpenCV's order).
N_COEFFS: Final = {"pinhole": 5, "fisheye": 4}

#: Tables and keys of a camera file (``depth`` and ``thermal`` only for those kinds).
TABLE_KEYS: Final = {
    "": ("device", "image", "lens", "sensor", "depth", "thermal"),
    "device": ("name", "vendor", "model", "kind", "sources"),
    "image": ("width", "height", "frame_rate_hz"),
    "lens": ("model", "hfov_deg", "distortion"),
    "sensor": ("exposure_ms", "read_noise_e", "full_well_e", "bit_depth",
               "line_time_us", "shutter", "pixel_um", "f_number", "quantum_efficiency",
               "auto_exposure", "gain_max"),
    "depth": ("min_m", "max_m"),
    "thermal": ("band_um", "netd_mk"),
}


@dataclass(frozen=True)
class CameraSpec:
    """One camera, SI units and radians.

    Attributes
    ----------
    name, vendor, model_name : str
        Registry name and the device's maker and model.
    kind : {"color", "depth", "thermal"}
    width, height : int
        Image size in pixels.
    frame_rate_hz : float
    model : {"pinhole", "fisheye"}
        The lens model.
    fx, fy, cx, cy : float
        Intrinsics in pixels (OpenCV's K = [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]).
    distortion : (5,) or (4,) float64
        ``k1 k2 p1 p2 k3`` (pinhole) or ``k1 k2 k3 k4`` (fisheye).
    exposure_s, read_noise_e, full_well_e : float
        Exposure time, read noise and full-well capacity (electrons). With
        ``auto_exposure`` the longest exposure (the frame's timing uses it).
    pixel_m, f_number, quantum_efficiency : float
        Pixel pitch, the lens's f-number and the sensor's quantum efficiency: the
        exposure's electrons per luminance (``sensors.shading.expose``).
    bit_depth : int
        Bits of the digitised value (8 for the colour PNG, 16 for depth and thermal).
    line_time_s : float
        Rolling shutter: the delay between successive rows (0: global shutter).
    depth_range_m : (float, float) or None
        Valid depth of a depth camera.
    band_m : (float, float) or None
        Spectral band of a thermal camera (metres).
    netd_k : float
        Noise-equivalent temperature difference of a thermal camera (kelvin).
    sources : tuple of str
    path : str
    auto_exposure : bool
        Colour cameras: each frame's exposure time (at most ``exposure_s``) and analog
        gain (1 to ``gain_max``) are chosen from the frame's light
        (``sensors.shading.auto_exposure``); False: ``exposure_s`` at gain 1. Optional
        ``[sensor] auto_exposure`` (default false).
    gain_max : float
        Largest analog gain auto-exposure may take (``[sensor] gain_max``, default 1).
    """

    name: str
    vendor: str
    model_name: str
    kind: str
    width: int
    height: int
    frame_rate_hz: float
    model: str
    fx: float
    fy: float
    cx: float
    cy: float
    distortion: NDArray[np.float64]
    exposure_s: float
    read_noise_e: float
    full_well_e: float
    pixel_m: float
    f_number: float
    quantum_efficiency: float
    bit_depth: int
    line_time_s: float
    depth_range_m: tuple[float, float] | None
    band_m: tuple[float, float] | None
    netd_k: float
    sources: tuple[str, ...]
    path: str = ""
    auto_exposure: bool = False
    gain_max: float = 1.0

    @property
    def K(self) -> NDArray[np.float64]:  # noqa: N802 (the symbol every user knows)
        """(3, 3) float64: the camera matrix."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy],
                         [0.0, 0.0, 1.0]])

    @property
    def global_shutter(self) -> bool:
        """No rolling shutter: every row exposed at once."""
        return self.line_time_s == 0.0

    @property
    def pixel_area_m2(self) -> float:
        """Area of one pixel (square pixels)."""
        return self.pixel_m * self.pixel_m

    def __repr__(self) -> str:
        return (f"CameraSpec({self.name}: {self.vendor} {self.model_name}, {self.kind}, "
                f"{self.width}x{self.height} at {self.frame_rate_hz:g} Hz, {self.model})")


# ---------------------------------------------------------------------- loading
def _load(path: Path) -> CameraSpec:
    data = read_toml(path, CameraSpecError, "camera")
    root = SpecTable(data, path.name, "", CameraSpecError, "camera", schema=TABLE_KEYS)
    dev, img, lens, sen = (root.sub(k) for k in ("device", "image", "lens", "sensor"))
    kind = dev.text("kind")
    if kind not in KINDS:
        raise dev.err("kind", f"one of {KINDS}", kind)
    for table in ("depth", "thermal"):
        if table in data and table != kind:
            raise CameraSpecError(f"Expected a [{table}] table in {path.name} only for "
                                  f"device.kind = {table!r}, got kind {kind!r}; remove it.")
    model = lens.text("model")
    if model not in MODELS:
        raise lens.err("model", f"one of {MODELS}", model)
    w, h = img.whole("width", 1), img.whole("height", 1)
    hfov = math.radians(lens.num("hfov_deg", lo=1.0, hi=360.0 if model == "fisheye"
                                 else 179.0))
    dist = lens.nums("distortion", N_COEFFS[model])
    # DECISION: square pixels (fy = fx) and the principal point at the image centre
    # (pixel centres at integers: (w - 1) / 2): datasheets give fields of view, not
    # calibrations; a user's calibrated file may differ, ours are nominal.
    if model == "pinhole":
        fx = (w / 2.0) / math.tan(hfov / 2.0)
    else:   # equidistant projection: theta_d = theta at the edge
        fx = (w / 2.0) / (hfov / 2.0)
    shutter = sen.text("shutter")
    if shutter not in ("global", "rolling"):
        raise sen.err("shutter", "'global' or 'rolling'", shutter)
    line = sen.num("line_time_us", lo=0.0) * 1e-6
    if shutter == "global" and line != 0.0:
        raise sen.err("line_time_us", "0 for a global shutter", line * 1e6)
    bits = sen.whole("bit_depth", 1)
    if bits > 16:
        raise sen.err("bit_depth", "at most 16", bits)
    depth = band = None
    netd = 0.0
    if kind == "depth":
        d = root.sub("depth")
        lo, hi = d.num("min_m", lo=0.0), d.num("max_m", positive=True)
        if hi <= lo:
            raise CameraSpecError(f"Expected `depth.max_m` > `depth.min_m` in {path.name}, "
                                  f"got {hi} <= {lo}; fix the camera file.")
        depth = (lo, hi)
    if kind == "thermal":
        t = root.sub("thermal")
        b0, b1 = t.nums("band_um", 2) * 1e-6
        band = (float(b0), float(b1))
        netd = t.num("netd_mk", positive=True) * 1e-3
    auto = sen.flag("auto_exposure") if "auto_exposure" in sen.data else False
    if auto and kind != "color":
        raise sen.err("auto_exposure", "false (auto-exposure is for colour cameras)", auto)
    gain_max = sen.num("gain_max", lo=1.0) if "gain_max" in sen.data else 1.0
    return CameraSpec(dev.text("name"), dev.text("vendor"), dev.text("model"), kind, w, h,
                      img.num("frame_rate_hz", positive=True), model, fx, fx,
                      (w - 1) / 2.0, (h - 1) / 2.0, dist,
                      sen.num("exposure_ms", positive=True) * 1e-3,
                      sen.num("read_noise_e", lo=0.0), sen.num("full_well_e", positive=True),
                      sen.num("pixel_um", positive=True) * 1e-6,
                      sen.num("f_number", positive=True),
                      sen.num("quantum_efficiency", lo=0.0, hi=1.0), bits, line, depth,
                      band, netd, dev.texts("sources"), str(path), auto, gain_max)


#: The shipped camera files by name.
CATALOGUE: Final = Catalogue(CAMERA_DIR, _load, CameraSpecError, "camera")


def list_cameras() -> list[str]:
    """Names of the shipped camera models, sorted."""
    return CATALOGUE.names()


def load_camera(name_or_path: str | os.PathLike[str]) -> CameraSpec:
    """A shipped camera by name (``list_cameras()``) or a TOML file by path.

    Raises
    ------
    CameraSpecError
        For an unknown name, a missing file, or a file that is not a valid camera
        description (bad TOML, a missing, malformed or unknown key).
    """
    return CATALOGUE.load(name_or_path)


# ---------------------------------------------------------------------- lens models
def _points(points: ArrayLike) -> NDArray[np.float64]:
    p = np.asarray(points, dtype=np.float64)
    if p.ndim == 1:
        p = p[None, :]
    if p.ndim != 2 or p.shape[1] != 3:
        raise CameraSpecError(f"Expected camera-frame points as (n, 3), got shape {p.shape}.")
    return p


def _distort_pinhole(x: NDArray[np.float64], y: NDArray[np.float64],
                     d: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    k1, k2, p1, p2, k3 = d
    r2 = x * x + y * y
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
    yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
    return xd, yd


def _theta_d(theta: NDArray[np.float64], d: NDArray[np.float64]) -> NDArray[np.float64]:
    t2 = theta * theta
    return theta * (1.0 + t2 * (d[0] + t2 * (d[1] + t2 * (d[2] + t2 * d[3]))))


def project(cam: CameraSpec, points: ArrayLike) -> NDArray[np.float64]:
    """Pixel coordinates (n, 2) float64 of camera-frame points (n, 3) (OpenCV optical
    frame). Points behind a pinhole camera (Z <= 0) get NaN; a fisheye projects any
    direction but straight back."""
    p = _points(points)
    X, Y, Z = p.T
    d = cam.distortion
    with np.errstate(divide="ignore", invalid="ignore"):
        if cam.model == "pinhole":
            x, y = X / Z, Y / Z
            xd, yd = _distort_pinhole(x, y, d)
            xd = np.where(Z > 0, xd, np.nan)
            yd = np.where(Z > 0, yd, np.nan)
        else:
            rho = np.hypot(X, Y)
            td = _theta_d(np.arctan2(rho, Z), d)
            # On the axis (rho = 0) the point images at the centre, or nowhere when it
            # lies straight behind.
            xd = np.where(rho > 0, td * X / rho, np.where(Z > 0, 0.0, np.nan))
            yd = np.where(rho > 0, td * Y / rho, np.where(Z > 0, 0.0, np.nan))
    return np.stack([cam.fx * xd + cam.cx, cam.fy * yd + cam.cy], axis=1)


def unproject(cam: CameraSpec, uv: ArrayLike, *, iterations: int = 30
              ) -> NDArray[np.float64]:
    """Unit ray directions (n, 3) float64 in the camera frame through pixels (n, 2).

    Newton's method inverts the lens model (pinhole: on the undistorted normalised
    coordinates, starting from the distorted ones; fisheye: on theta); a pixel whose
    inversion does not reach 1e-12 of the pixel's normalised coordinate gets NaN.
    """
    q = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
    xd = (q[:, 0] - cam.cx) / cam.fx
    yd = (q[:, 1] - cam.cy) / cam.fy
    d = cam.distortion
    if cam.model == "pinhole":
        x, y = xd.copy(), yd.copy()
        k1, k2, p1, p2, k3 = d
        for _ in range(iterations):
            fx_, fy_ = _distort_pinhole(x, y, d)
            ex, ey = fx_ - xd, fy_ - yd
            r2 = x * x + y * y
            radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
            dr = 2.0 * (k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2))   # d radial / d r2 * 2
            j11 = radial + x * dr * x + 2.0 * p1 * y + 6.0 * p2 * x
            j12 = x * dr * y + 2.0 * p1 * x + 2.0 * p2 * y
            j21 = y * dr * x + 2.0 * p1 * x + 2.0 * p2 * y
            j22 = radial + y * dr * y + 6.0 * p1 * y + 2.0 * p2 * x
            det = j11 * j22 - j12 * j21
            with np.errstate(divide="ignore", invalid="ignore"):
                x_new = x - (j22 * ex - j12 * ey) / det
                y_new = y - (-j21 * ex + j11 * ey) / det
            # A fixed point stays one: stopping there gives the same bits as iterating on
            # (a lens without distortion is one after the first step: 12 s saved per
            # 1080p ray set).
            done = np.array_equal(x_new, x, equal_nan=True) and \
                np.array_equal(y_new, y, equal_nan=True)
            x, y = x_new, y_new
            if done:
                break
        fx_, fy_ = _distort_pinhole(x, y, d)
        ok = (np.abs(fx_ - xd) < 1e-12) & (np.abs(fy_ - yd) < 1e-12)
        ray = np.stack([x, y, np.ones_like(x)], axis=1)
    else:
        rd = np.hypot(xd, yd)
        theta = rd.copy()
        for _ in range(iterations):
            t2 = theta * theta
            f = _theta_d(theta, d) - rd
            df = 1.0 + t2 * (3 * d[0] + t2 * (5 * d[1] + t2 * (7 * d[2] + t2 * 9 * d[3])))
            with np.errstate(divide="ignore", invalid="ignore"):
                theta_new = theta - f / df
            done = np.array_equal(theta_new, theta, equal_nan=True)
            theta = theta_new
            if done:
                break
        ok = (np.abs(_theta_d(theta, d) - rd) < 1e-12) & (theta >= 0) & (theta < np.pi)
        with np.errstate(divide="ignore", invalid="ignore"):
            cx_, cy_ = np.where(rd > 0, xd / rd, 0.0), np.where(rd > 0, yd / rd, 0.0)
        s = np.sin(theta)
        ray = np.stack([s * cx_, s * cy_, np.cos(theta)], axis=1)
    ray /= np.linalg.norm(ray, axis=1, keepdims=True)
    ray[~ok] = np.nan
    return ray


def pixel_rays(cam: CameraSpec) -> NDArray[np.float64]:
    """(height, width, 3) float64 unit ray directions (camera frame) through every pixel
    centre, row-major (v, u)."""
    v, u = np.mgrid[0:cam.height, 0:cam.width].astype(np.float64)
    return unproject(cam, np.stack([u.ravel(), v.ravel()], 1)).reshape(cam.height,
                                                                        cam.width, 3)
