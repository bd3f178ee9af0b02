"""One camera frame as files in a folder, in the conventions the tools people use read
without being told:

- ``rgb.png``: 8-bit sRGB (IEC 61966-2-1) colour image (colour cameras).
- ``depth.png``: 16-bit unsigned z-depth in millimetres, 0 = no data (Intel
  RealSense's ``Z16`` with its default depth unit of 1 mm, and ROS's ``16UC1`` depth
  images); depths beyond 65.535 m are 0 there too.
- ``depth.npy``: float32 z-depth in metres, NaN = no data (NumPy's format; z, not the
  range along the ray, as depth cameras report).
- ``thermal.png``: 16-bit unsigned apparent temperature in centikelvin, 0 = no data
  (the radiometric "TLinear" output of FLIR's Boson/Lepton cores at 0.01 K
  resolution); thermal cameras.
- ``camera_info.json``: ``K`` (3x3), ``D``, ``width``, ``height``, ``model``
  ("pinhole" / "fisheye") and ``distortion_model`` as ROS's ``sensor_msgs/CameraInfo``
  names it ("plumb_bob" / "equidistant"), ``world_from_camera`` (the 4x4 pose of the
  OpenCV optical frame: x right, y down, z forward), the camera's ``name`` and
  ``kind``, ``time_s``, and the units of the images.

Every file is written to a temporary name and renamed (``raytrace.fileio``).
"""

from __future__ import annotations

import io
import json
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Final

import numpy as np
from numpy.typing import NDArray

from raytrace.fileio import atomic_writer

from .camera import CameraSpec
from .errors import SimulationError
from .render import Frame
from .shading import srgb_encode

__all__ = ["DEPTH_UNIT_M", "DISTORTION_MODELS", "THERMAL_UNIT_K", "FrameFiles",
           "camera_info", "write_frame"]

#: Metres per count of ``depth.png`` (RealSense's default depth unit).
DEPTH_UNIT_M: Final = 0.001
#: Kelvin per count of ``thermal.png``.
THERMAL_UNIT_K: Final = 0.01
#: ROS ``sensor_msgs/CameraInfo.distortion_model`` of each lens model
#: (``sensor_msgs/distortion_models.h``).
DISTORTION_MODELS: Final = {"pinhole": "plumb_bob", "fisheye": "equidistant"}


@dataclass(frozen=True)
class FrameFiles:
    """The files of one frame (None: not written for this camera kind).

    Attributes
    ----------
    folder : Path
    rgb, depth_png, depth_npy, thermal, camera_info : Path or None
    depth_clipped : int
        Valid pixels whose depth does not fit ``depth.png`` (beyond 65.535 m): 0 there,
        kept in ``depth.npy``.
    """

    folder: Path
    rgb: Path | None
    depth_png: Path | None
    depth_npy: Path | None
    thermal: Path | None
    camera_info: Path
    depth_clipped: int

    @property
    def paths(self) -> tuple[Path, ...]:
        """Every file written, in the order above."""
        return tuple(p for p in (self.rgb, self.depth_png, self.depth_npy, self.thermal,
                                 self.camera_info) if p is not None)


def camera_info(cam: CameraSpec, world_from_camera: NDArray[np.float64],
                time_s: float = 0.0) -> dict[str, object]:
    """The ``camera_info.json`` object of a frame (module docstring)."""
    return {
        "name": cam.name, "kind": cam.kind, "time_s": float(time_s),
        "width": cam.width, "height": cam.height,
        "model": cam.model, "distortion_model": DISTORTION_MODELS[cam.model],
        "K": cam.K.tolist(), "D": [float(x) for x in cam.distortion],
        "world_from_camera": np.asarray(world_from_camera, dtype=np.float64).tolist(),
        "frame": "OpenCV optical frame: x right, y down, z forward; pixel centres at "
                 "integer (u, v), (0, 0) the top-left pixel's centre",
        "frame_rate_hz": cam.frame_rate_hz,
        "depth_unit_m": DEPTH_UNIT_M, "thermal_unit_k": THERMAL_UNIT_K,
    }


def _png(path: Path, image: NDArray[np.generic]) -> None:
    from PIL import Image      # Pillow: a dependency of matplotlib

    buf = io.BytesIO()
    Image.fromarray(image).save(buf, format="PNG")
    with atomic_writer(path) as fh:
        fh.write(buf.getvalue())


def _uint16(values: NDArray[np.float64], unit: float) -> tuple[NDArray[np.uint16], int]:
    """Counts of ``unit`` (rounded half to even, NumPy's rule); NaN, and values that do
    not fit 1..65535, become 0 (no data). Returns the image and how many valid values
    did not fit."""
    with np.errstate(invalid="ignore"):
        counts = np.round(values / unit)
        fits = np.isfinite(counts) & (counts >= 1) & (counts <= 65535)
    clipped = int((np.isfinite(counts) & ~fits).sum())
    return np.where(fits, counts, 0).astype(np.uint16), clipped


def write_frame(folder: str | os.PathLike[str], cam: CameraSpec, frame: Frame, *,
                rgb_linear: NDArray[np.float64] | None = None,
                thermal_k: NDArray[np.float64] | None = None,
                time_s: float = 0.0) -> FrameFiles:
    """Write one frame's files into ``folder`` (created if missing).

    Parameters
    ----------
    folder : str or path
    cam : CameraSpec
    frame : Frame
        The geometry (``sensors.render.render_depth``); its ``depth_z_m`` becomes
        ``depth.png`` and ``depth.npy``, its pose ``world_from_camera``.
    rgb_linear : (h, w, 3) float64, optional
        Linear colour values in [0, 1] (digital value / full scale); written sRGB-encoded
        as ``rgb.png``.
    thermal_k : (h, w) float64, optional
        Apparent temperature in kelvin, NaN = no data; written as ``thermal.png``.
    time_s : float
        The frame's time stamp, kept in ``camera_info.json``.

    Returns
    -------
    FrameFiles

    Raises
    ------
    SimulationError
        Images whose shape is not the camera's.
    """
    h, w = cam.height, cam.width
    if frame.depth_z_m.shape != (h, w):
        raise SimulationError(f"Expected a frame of {w}x{h} pixels for {cam.name}, got "
                              f"shape {frame.depth_z_m.shape}.")
    out = Path(folder)
    out.mkdir(parents=True, exist_ok=True)
    rgb_path = thermal_path = None
    if rgb_linear is not None:
        rgb = np.asarray(rgb_linear, dtype=np.float64)
        if rgb.shape != (h, w, 3):
            raise SimulationError(f"Expected an RGB image of shape {(h, w, 3)}, got "
                                  f"{rgb.shape}.")
        enc = np.round(srgb_encode(np.nan_to_num(rgb, nan=0.0)) * 255.0).astype(np.uint8)
        rgb_path = out / "rgb.png"
        _png(rgb_path, enc)
    depth = np.asarray(frame.depth_z_m, dtype=np.float64)
    # DECISION: round the float32 value the .npy holds, so that depth.png is exactly
    # round(depth.npy * 1000) where it has data, whichever file a user reads.
    depth32 = depth.astype(np.float32)
    d16, clipped = _uint16(depth32.astype(np.float64), DEPTH_UNIT_M)
    depth_png, depth_npy = out / "depth.png", out / "depth.npy"
    _png(depth_png, d16)
    with atomic_writer(depth_npy) as fh:
        np.save(fh, depth32)
    if thermal_k is not None:
        t = np.asarray(thermal_k, dtype=np.float64)
        if t.shape != (h, w):
            raise SimulationError(f"Expected a thermal image of shape {(h, w)}, got "
                                  f"{t.shape}.")
        thermal_path = out / "thermal.png"
        _png(thermal_path, _uint16(t, THERMAL_UNIT_K)[0])
    info_path = out / "camera_info.json"
    with atomic_writer(info_path, "w") as fh:
        json.dump(camera_info(cam, frame.world_from_camera, time_s), fh, indent=1)
        fh.write("\n")
    return FrameFiles(out, rgb_path, depth_png, depth_npy, thermal_path, info_path,
                      clipped)
