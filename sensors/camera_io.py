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
  ``kind``, ``time_s``, the units of the images, and a colour frame's
  ``exposure_s`` and ``gain`` (``sensors.shading.auto_exposure``).

Every file is written to a temporary name and renamed (``raytrace.fileio``).

Frames along a drive (``FrameFolder``, ``sensors.camera_drive``): one folder per
camera, ``<stem>_cameras/<camera name>/`` beside the drive's point file::

    camera_info.json          the intrinsics as above, the mount (base_link ->
                              optical frame), the frame rate and the shutter
    frames.csv                index, stamp_ns, time_s, readout_end_s, the pose of
                              row 0 (x y z qx qy qz qw, the optical frame in the world),
                              exposure_s and gain (the colour image's, auto-exposure)
    rgb/NNNNNN_<stamp_ns>.png      colour cameras (as rgb.png)
    thermal/NNNNNN_<stamp_ns>.png  thermal cameras (as thermal.png)
    depth/NNNNNN_<stamp_ns>.png    every camera: its z-depth (as depth.png)

The stamp is the frame's exposure start (row 0's for a rolling shutter) in ns of the
trajectory's time base. The folder is written under a temporary name and renamed into
place on ``close`` (a folder of the same name is replaced).
"""

from __future__ import annotations

import io
import json
import os
import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Final

import numpy as np
from numpy.typing import NDArray

from scipy.spatial.transform import Rotation

from raytrace.fileio import atomic_writer

from .camera import CameraSpec
from .errors import SimulationError
from .io.stream import Stream
from .render import Frame
from .shading import srgb_encode

__all__ = ["DEPTH_UNIT_M", "DISTORTION_MODELS", "THERMAL_UNIT_K", "FrameFiles",
           "FrameFolder", "camera_info", "depth_counts", "rgb8", "thermal_counts",
           "write_frame"]

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


def rgb8(rgb_linear: NDArray[np.float64]) -> NDArray[np.uint8]:
    """(h, w, 3) uint8 sRGB-encoded image of linear values in [0, 1] (NaN as 0): what
    ``rgb.png`` holds and a ROS ``rgb8`` image carries."""
    rgb = np.nan_to_num(np.asarray(rgb_linear, dtype=np.float64), nan=0.0)
    return np.round(srgb_encode(rgb) * 255.0).astype(np.uint8)


def depth_counts(depth_z_m: NDArray[np.float64]) -> tuple[NDArray[np.uint16], int]:
    """(h, w) uint16 z-depth in ``DEPTH_UNIT_M`` (mm), 0 = no data, and the number of
    valid depths that did not fit (beyond 65.535 m): ``depth.png`` and a ROS ``16UC1``
    depth image (the RealSense driver's)."""
    # DECISION: round the float32 value the .npy holds, so that depth.png is exactly
    # round(depth.npy * 1000) where it has data, whichever file a user reads.
    depth32 = np.asarray(depth_z_m, dtype=np.float64).astype(np.float32)
    return _uint16(depth32.astype(np.float64), DEPTH_UNIT_M)


def thermal_counts(thermal_k: NDArray[np.float64]) -> NDArray[np.uint16]:
    """(h, w) uint16 apparent temperature in ``THERMAL_UNIT_K`` (centikelvin), 0 = no
    data: ``thermal.png`` and a ROS ``mono16`` thermal image."""
    return _uint16(np.asarray(thermal_k, dtype=np.float64), THERMAL_UNIT_K)[0]


def write_frame(folder: str | os.PathLike[str], cam: CameraSpec, frame: Frame, *,
                rgb_linear: NDArray[np.float64] | None = None,
                thermal_k: NDArray[np.float64] | None = None,
                time_s: float = 0.0, exposure_s: float | None = None,
                gain: float = 1.0) -> FrameFiles:
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
    exposure_s, gain : float
        The colour image's exposure time (default the camera's) and analog gain, kept
        in ``camera_info.json``.

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
        rgb_path = out / "rgb.png"
        _png(rgb_path, rgb8(rgb))
    d16, clipped = depth_counts(frame.depth_z_m)
    depth_png, depth_npy = out / "depth.png", out / "depth.npy"
    _png(depth_png, d16)
    with atomic_writer(depth_npy) as fh:
        np.save(fh, np.asarray(frame.depth_z_m, dtype=np.float64).astype(np.float32))
    if thermal_k is not None:
        t = np.asarray(thermal_k, dtype=np.float64)
        if t.shape != (h, w):
            raise SimulationError(f"Expected a thermal image of shape {(h, w)}, got "
                                  f"{t.shape}.")
        thermal_path = out / "thermal.png"
        _png(thermal_path, thermal_counts(t))
    info_path = out / "camera_info.json"
    with atomic_writer(info_path, "w") as fh:
        info = camera_info(cam, frame.world_from_camera, time_s)
        info.update(exposure_s=cam.exposure_s if exposure_s is None else float(exposure_s),
                    gain=float(gain), auto_exposure=cam.auto_exposure)
        json.dump(info, fh, indent=1)
        fh.write("\n")
    return FrameFiles(out, rgb_path, depth_png, depth_npy, thermal_path, info_path,
                      clipped)


def _pose_row(T: NDArray[np.float64]) -> list[float]:
    """x y z qx qy qz qw of a (4, 4) pose (scalar-last quaternion, w >= 0)."""
    q = Rotation.from_matrix(T[:3, :3]).as_quat(canonical=True)
    return [*(float(v) for v in T[:3, 3]), *(float(v) for v in q)]


class FrameFolder(Stream):
    """The frames of one camera along a drive, into a folder (module notes), frame by
    frame; ``close`` writes ``frames.csv`` and ``camera_info.json`` and moves the folder
    into place, ``abort`` (or an exception in a ``with`` block) leaves nothing.

    Parameters
    ----------
    folder : path-like
        The camera's folder (``<stem>_cameras/<name>``); its parent is created.
    cam : CameraSpec
    base_from_optical : (4, 4) array_like
        The optical frame in base_link (the mount), stated in ``camera_info.json``.
    info : dict, optional
        JSON-ready extras for ``camera_info.json`` (the rate, the lamps ...).
    """

    def __init__(self, folder: str | os.PathLike[str], cam: CameraSpec,
                 base_from_optical: NDArray[np.float64],
                 info: dict[str, object] | None = None) -> None:
        self.path = Path(folder)
        self.cam = cam
        self._base = np.asarray(base_from_optical, dtype=np.float64)
        self._info = dict(info or {})
        self._made_parent = not self.path.parent.exists()
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._tmp = Path(tempfile.mkdtemp(prefix="." + self.path.name + ".",
                                          suffix=".part", dir=self.path.parent))
        self._rows: list[str] = []
        self.depth_clipped = 0
        self.files = 0

    def write(self, index: int, stamp_ns: int, frame: Frame, *,
              readout_end_s: float, time_s: float,
              rgb_linear: NDArray[np.float64] | None = None,
              thermal_k: NDArray[np.float64] | None = None,
              exposure_s: float | None = None, gain: float = 1.0) -> None:
        """Write frame ``index`` (stamped ``stamp_ns``, trajectory time ``time_s``): its
        depth, and its colour or thermal image taken with ``exposure_s`` (default the
        camera's) at ``gain``."""
        h, w = self.cam.height, self.cam.width
        if frame.depth_z_m.shape != (h, w):
            raise SimulationError(f"Expected a frame of {w}x{h} pixels for "
                                  f"{self.cam.name}, got shape {frame.depth_z_m.shape}.")
        name = f"{index:06d}_{stamp_ns}.png"
        images: list[tuple[str, NDArray[np.generic]]] = []
        if rgb_linear is not None:
            images.append(("rgb", rgb8(rgb_linear)))
        if thermal_k is not None:
            images.append(("thermal", thermal_counts(thermal_k)))
        d16, clipped = depth_counts(frame.depth_z_m)
        images.append(("depth", d16))
        self.depth_clipped += clipped
        for sub, img in images:
            (self._tmp / sub).mkdir(exist_ok=True)
            _png(self._tmp / sub / name, img)
            self.files += 1
        pose = " ".join(f"{v:.9f}" for v in _pose_row(frame.world_from_camera))
        t_exp = self.cam.exposure_s if exposure_s is None else float(exposure_s)
        self._rows.append(f"{index},{stamp_ns},{time_s:.9f},{readout_end_s:.9f},"
                          + pose.replace(" ", ",") + f",{t_exp:.9g},{gain:.6g}")

    def _finish(self) -> None:
        with atomic_writer(self._tmp / "frames.csv", "w") as fh:
            fh.write("index,stamp_ns,time_s,readout_end_s,x,y,z,qx,qy,qz,qw,exposure_s,"
                     "gain\n")
            fh.write("".join(r + "\n" for r in self._rows))
        info = camera_info(self.cam, np.eye(4))
        del info["world_from_camera"], info["time_s"]
        info.update(self._info, frames=len(self._rows),
                    base_from_optical=self._base.tolist(),
                    shutter="global" if self.cam.global_shutter else "rolling",
                    line_time_s=self.cam.line_time_s, exposure_s=self.cam.exposure_s,
                    auto_exposure=self.cam.auto_exposure, gain_max=self.cam.gain_max,
                    stamp="exposure start of row 0, ns of the trajectory's time base",
                    pose="frames.csv: the optical frame of row 0 in the world; row r "
                         "is exposed line_time_s * r later")
        with atomic_writer(self._tmp / "camera_info.json", "w") as fh:
            json.dump(info, fh, indent=1)
            fh.write("\n")
        try:
            if self.path.exists():
                shutil.rmtree(self.path)
            os.rename(self._tmp, self.path)
        except OSError as exc:
            raise SimulationError(f"Expected to move the camera frames to "
                                  f"'{self.path}', got {type(exc).__name__}: {exc}.") from exc
        finally:
            shutil.rmtree(self._tmp, ignore_errors=True)

    def _discard(self, exc: BaseException) -> None:
        shutil.rmtree(self._tmp, ignore_errors=True)
        if self._made_parent:               # the <stem>_cameras folder this made, if empty
            try:
                self.path.parent.rmdir()
            except OSError:
                pass
