"""Camera frames along a drive (issue 35): the frame schedule on the drive's clock,
each frame's pose (one per image row for a rolling shutter) from the trajectory and
the camera's mount, the platform's lamps, and the shaded image.

Frames: frame i's exposure starts at ``t_i = t_start + i / rate`` (the drive's own
clock, the lidar's time base; ``rate`` the camera's frame rate or a lower one), and a
frame is taken only if its last row's exposure ends within the drive
(``t_i + readout_s(cam) <= t_end``), as a driver publishes a frame once it is read out.
Row r of a rolling-shutter frame starts its exposure at ``t_i + r * line_time_s`` and
is cast from the camera's pose at that instant; a global shutter exposes every row at
``t_i``. Motion blur within the exposure is not modelled (one pose per row).

Mount (REP 103, REP 105): the camera's ``camera_link`` is placed in ``base_link``
(x forward, y left, z up) by a lever arm and roll, pitch, yaw (``camera_mount``);
its optical frame (OpenCV's and ROS's ``*_optical_frame``: z forward, x right, y down)
is ``camera_link`` turned by ``LINK_FROM_OPTICAL``. DECISION: the default mount
(``default_camera_mount``) is ``CAMERA_BELOW_LIDAR_M`` below the lidar's origin,
level, looking along base_link's +x: where a camera sits on a robot's mast under its
lidar, and a pose that sees the tunnel whatever the lidar's boresight.

Light (``drive_lamps``): the platform's ``[[lamps]]`` (``sensors.shading.
platform_lamps``) where it has some, else a headlamp beside the camera
(``sensors.shading.headlamp``, ``DEFAULT_LAMP_CD``); ``lamp_cd`` given adds the
headlamp at that intensity (0: none). DECISION: the lamps are placed at the frame's
start (base_link and row 0's pose at ``t_i``): they move a few centimetres during a
readout, which changes the lighting far less than the row poses change the geometry.
Images are shaded as ``tunnelsim render`` shades one (``frame_image``), with
``samples_per_pixel`` rays per pixel for anti-aliasing (colour and thermal).

>>> import numpy as np
>>> from dataclasses import replace
>>> from sensors.camera import load_camera
>>> cam = replace(load_camera("realsense_d435_color"), width=64, height=48)
>>> t = frame_times(cam, (0.0, 0.1))
>>> len(t), float(t[1])                 # 30 Hz; the 4th frame's readout ends after 0.1 s
(3, 0.03333333333333333)
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Final, NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.transform import Rotation

from raytrace import Scene

from .appearance import Appearance
from .camera import CameraSpec
from .errors import SimulationError
from .render import Frame, render_depth
from .platform_spec import PlatformSpec
from .shading import (Lamp, auto_exposure, expose, headlamp, platform_lamps, radiance_frame,
                      stratified_offsets, thermal_frame)
from .trajectory import Mount, Trajectory

__all__ = ["CAMERA_BELOW_LIDAR_M", "CAMERA_STREAM", "DEFAULT_LAMP_CD",
           "LINK_FROM_OPTICAL", "CameraFrame", "DriveCamera", "LampsFn", "ShadedFrame", "camera_mount",
           "default_camera_mount", "drive_lamps", "frame_seed", "frame_times",
           "frame_image", "image_counts", "optical_mount", "readout_s", "row_times",
           "stamp_ns", "write_frame_folder"]

#: camera_link -> optical frame (REP 103): the columns are the optical axes in
#: camera_link, x_opt = -y_link (right), y_opt = -z_link (down), z_opt = x_link (forward).
LINK_FROM_OPTICAL: Final = np.array([[0.0, 0.0, 1.0],
                                     [-1.0, 0.0, 0.0],
                                     [0.0, -1.0, 0.0]])
#: The default camera sits this far below the lidar's origin (m).
CAMERA_BELOW_LIDAR_M: Final = 0.10
#: The headlamp's intensity without platform lamps (``render``'s default; ASSUMED).
DEFAULT_LAMP_CD: Final = 1000.0
#: Noise stream of the camera frames (``frame_seed``): apart from the lidar's and IMU's.
CAMERA_STREAM: Final = 35

#: ``lamps(world_from_base, world_from_camera)``: the lamps lighting a frame, both
#: poses (4, 4) at the frame's start.
LampsFn = Callable[[NDArray[np.float64], NDArray[np.float64]], Sequence[Lamp]]


# ---------------------------------------------------------------------------- mount
def camera_mount(values: Sequence[float]) -> Mount:
    """base_link -> camera_link from ``X,Y,Z[,ROLL,PITCH,YAW]`` (metres, degrees; fixed
    axes x, y, z as URDF's rpy), the ``--camera-mount`` option.

    Raises
    ------
    SimulationError
        Not 3 or 6 finite numbers.
    """
    vals = [float(v) for v in values]
    if len(vals) not in (3, 6) or not all(map(math.isfinite, vals)):
        raise SimulationError(f"Expected --camera-mount as X,Y,Z[,ROLL,PITCH,YAW] (metres, "
                              f"degrees), got {','.join(f'{v:g}' for v in vals)!r}.")
    rpy = vals[3:] or [0.0, 0.0, 0.0]
    return Mount(tuple(vals[:3]),  # type: ignore[arg-type]
                 Rotation.from_euler("xyz", rpy, degrees=True))


def default_camera_mount(lidar_from_base: Mount) -> Mount:
    """The default camera_link: ``CAMERA_BELOW_LIDAR_M`` below the lidar's origin
    (``lidar_from_base``: base_link -> lidar), level, looking along base_link's +x."""
    x, y, z = lidar_from_base.lever_arm_m
    return Mount((x, y, z - CAMERA_BELOW_LIDAR_M))


def optical_mount(link: Mount) -> Mount:
    """base_link -> optical frame of a camera whose camera_link is ``link``."""
    return Mount(link.lever_arm_m, link.boresight * Rotation.from_matrix(LINK_FROM_OPTICAL))


# ---------------------------------------------------------------------------- schedule
def readout_s(cam: CameraSpec) -> float:
    """From a frame's start to its last row's exposure end (s)."""
    return (cam.height - 1) * cam.line_time_s + cam.exposure_s


def frame_times(cam: CameraSpec, span_s: tuple[float, float],
                rate_hz: float | None = None) -> NDArray[np.float64]:
    """(n,) float64 exposure starts of the frames within ``span_s`` (module notes) at
    ``rate_hz`` (default the camera's frame rate; at most that).

    Raises
    ------
    SimulationError
        A rate that is not in (0, the camera's frame rate].
    """
    rate = cam.frame_rate_hz if rate_hz is None else float(rate_hz)
    if not (math.isfinite(rate) and 0 < rate <= cam.frame_rate_hz * (1 + 1e-12)):
        raise SimulationError(f"Expected --camera-rate-hz in (0, {cam.frame_rate_hz:g}] "
                              f"(the frame rate of {cam.name}), got {rate:g}.")
    a, b = (float(v) for v in span_s)
    last = b - readout_s(cam)
    eps = 1e-9 * max(1.0, abs(b))
    n = int(math.floor((last - a) * rate + eps)) + 1 if last >= a - eps else 0
    return np.asarray(a + np.arange(max(n, 0)) / rate, dtype=np.float64)


def row_times(cam: CameraSpec, t_start: float) -> NDArray[np.float64]:
    """Exposure start of each row, (height,) float64, of a frame starting at
    ``t_start``; (1,) for a global shutter."""
    if cam.global_shutter:
        return np.array([float(t_start)])
    return np.asarray(t_start + np.arange(cam.height) * cam.line_time_s, dtype=np.float64)


def frame_seed(seed: int, camera_index: int, frame_index: int) -> int:
    """The noise seed of one frame: independent of the other frames and cameras and of
    the lidar's streams (``numpy.random.SeedSequence``)."""
    ss = np.random.SeedSequence([int(seed), CAMERA_STREAM, int(camera_index),
                                 int(frame_index)])
    return int(ss.generate_state(1, np.uint64)[0])


# ---------------------------------------------------------------------------- light
def drive_lamps(platform: PlatformSpec | None = None, lamp_cd: float | None = None
                ) -> tuple[LampsFn, str]:
    """The lamps of a drive's frames and what they are (for the summary), as
    ``tunnelsim render --platform`` lights a frame.

    Parameters
    ----------
    platform : sensors.platform_spec.PlatformSpec, optional
        Its ``[[lamps]]``, placed with base_link by ``sensors.shading.platform_lamps``.
    lamp_cd : float, optional
        A headlamp beside the camera (``sensors.shading.headlamp``) at this intensity
        (``--lamp-cd``; 0: none). Default: none when the platform has lamps, else
        ``DEFAULT_LAMP_CD``. DECISION: given with a platform's lamps, both light the
        frame (``render``'s rule: nothing asked for is dropped).

    Raises
    ------
    SimulationError
        A negative or non-finite ``lamp_cd``.
    """
    if lamp_cd is not None and not (math.isfinite(lamp_cd) and lamp_cd >= 0):
        raise SimulationError(f"Expected --lamp-cd >= 0 (candela), got {lamp_cd}; pass "
                              "--lamp-cd 0 for no light.")
    own = tuple(platform.lamps) if platform is not None else ()
    cd = (0.0 if own else DEFAULT_LAMP_CD) if lamp_cd is None else float(lamp_cd)

    def lamps(world_from_base: NDArray[np.float64],
              world_from_camera: NDArray[np.float64]) -> Sequence[Lamp]:
        out = [headlamp(world_from_camera, cd)] if cd > 0 else []
        if own:
            assert platform is not None
            out += platform_lamps(platform, world_from_base)
        return out
    said = [f"headlamp {cd:g} cd"] if cd > 0 else []
    if own:
        assert platform is not None
        said.append(f"{len(own)} lamp{'s' if len(own) > 1 else ''} of the {platform.name}")
    return lamps, " and ".join(said) or "no light"


# ---------------------------------------------------------------------------- shading
class ShadedFrame(NamedTuple):
    """A rendered and shaded frame (``frame_image``).

    Attributes
    ----------
    frame : Frame
        The pixel-centre geometry.
    rgb_linear : (h, w, 3) float64 or None
        Colour: digital value / full scale (linear, [0, 1]).
    thermal_k : (h, w) float64 or None
        Thermal: apparent temperature (K), NaN where the pixel centre's ray misses.
    exposure_s : float
        The exposure time the colour image was taken with (auto-exposure's, or the
        camera's ``exposure_s``; the camera's for depth and thermal frames).
    gain : float
        The analog gain of the colour image (1 without auto-exposure).
    """

    frame: Frame
    rgb_linear: NDArray[np.float64] | None
    thermal_k: NDArray[np.float64] | None
    exposure_s: float
    gain: float


def frame_image(scene: Scene, cam: CameraSpec, world_from_camera: ArrayLike,
                appearance: Appearance, lamps: Sequence[Lamp], *,
                samples_per_pixel: int = 1, seed: int = 0, noise: bool = True,
                ambient_k: float | None = None) -> ShadedFrame:
    """One frame rendered and shaded as ``tunnelsim render`` shades one
    (``survey.workflows.render.render_frame``): colour, the Lambertian luminance under
    ``lamps`` averaged over ``samples_per_pixel`` rays (``sensors.shading.
    radiance_frame``) exposed with the sensor's noise, at the exposure time and gain
    ``sensors.shading.auto_exposure`` chooses for a camera with ``auto_exposure``;
    thermal, the apparent temperature of the averaged band radiance
    (``sensors.shading.thermal_frame``); depth, the frame's z-depth alone.

    Parameters
    ----------
    world_from_camera : (4, 4) or (height, 4, 4) array_like
        As ``sensors.render.render_depth`` (per-row poses: a rolling shutter).
    samples_per_pixel : int
        Colour and thermal cameras: a square number; a depth camera takes 1.

    Returns
    -------
    ShadedFrame
    """
    from .appearance import ROCK_K

    if cam.kind == "color":
        frame, lum = radiance_frame(scene, cam, world_from_camera, lamps, appearance,
                                    samples_per_pixel)
        t, gain = auto_exposure(cam, lum) if cam.auto_exposure else (cam.exposure_s, 1.0)
        rgb = expose(cam, lum, seed=seed, noise=noise, exposure_s=t, gain=gain) / \
            (2.0 ** cam.bit_depth - 1)
        return ShadedFrame(frame, rgb, None, t, gain)
    if cam.kind == "thermal":
        frame, thermal = thermal_frame(scene, cam, world_from_camera, appearance,
                                       ROCK_K if ambient_k is None else float(ambient_k),
                                       samples_per_pixel, seed=seed, noise=noise)
        return ShadedFrame(frame, None, thermal, cam.exposure_s, 1.0)
    return ShadedFrame(render_depth(scene, cam, world_from_camera), None, None,
                       cam.exposure_s, 1.0)


# ---------------------------------------------------------------------------- frames
@dataclass(frozen=True)
class CameraFrame:
    """One frame of a camera along a drive.

    Attributes
    ----------
    index : int
    stamp_s : float
        Exposure start (row 0's), trajectory time base (s).
    readout_end_s : float
        The last row's exposure end: when a driver has the frame.
    frame : Frame
        The geometry; ``world_from_camera`` is row 0's pose, ``row_poses`` every row's
        for a rolling shutter.
    world_from_base : (4, 4) float64
        base_link at ``stamp_s``.
    rgb_linear : (h, w, 3) float64 or None
        Colour cameras (``shade_frame``).
    thermal_k : (h, w) float64 or None
        Thermal cameras.
    exposure_s, gain : float
        The exposure time and analog gain of a colour frame (``ShadedFrame``).
    """

    index: int
    stamp_s: float
    readout_end_s: float
    frame: Frame
    world_from_base: NDArray[np.float64]
    rgb_linear: NDArray[np.float64] | None
    thermal_k: NDArray[np.float64] | None
    exposure_s: float = math.nan
    gain: float = 1.0


def _matrices(pos: NDArray[np.float64], rot: Rotation) -> NDArray[np.float64]:
    out = np.zeros((len(pos), 4, 4))
    out[:, :3, :3] = rot.as_matrix()
    out[:, :3, 3] = pos
    out[:, 3, 3] = 1.0
    return out


class DriveCamera:
    """A camera on a platform along a drive: its frame schedule and its frames.

    Parameters
    ----------
    scene : raytrace.Scene
    cam : CameraSpec
    trajectory : Trajectory
        base_link's poses (``RobotDescription.base_trajectory``; for a trajectory file
        the file's frame).
    mount : Mount
        base_link -> camera_link (``camera_mount``, ``default_camera_mount``).
    appearance : sensors.appearance.Appearance
        Albedo, temperature and emissivity of the scene's faces.
    span_s : (float, float)
        The drive's time window (the frames lie within it).
    rate_hz : float, optional
        Frame rate (default the camera's).
    lamps : LampsFn, optional
        Default: ``drive_lamps()`` (a headlamp).
    seed : int
        Seeds the sensor noise (``frame_seed``).
    noise : bool
    ambient_k : float, optional
        Thermal cameras: the surroundings' temperature (default the rock's).
    index : int
        The camera's place among the drive's cameras (its noise stream).
    samples_per_pixel : int
        Colour and thermal cameras: rays averaged per pixel (a square number;
        anti-aliasing); a depth camera takes 1 (a depth camera does not average).
    """

    def __init__(self, scene: Scene, cam: CameraSpec, trajectory: Trajectory, mount: Mount,
                 appearance: Appearance, *, span_s: tuple[float, float],
                 rate_hz: float | None = None, lamps: LampsFn | None = None, seed: int = 0,
                 noise: bool = True, ambient_k: float | None = None,
                 index: int = 0, samples_per_pixel: int = 1) -> None:
        self.scene, self.cam, self.trajectory = scene, cam, trajectory
        self.link_mount = mount
        self.mount = optical_mount(mount)
        self.appearance = appearance
        self.rate_hz = cam.frame_rate_hz if rate_hz is None else float(rate_hz)
        self.times = frame_times(cam, span_s, self.rate_hz)
        self.lamps = lamps if lamps is not None else drive_lamps()[0]
        self.seed, self.noise, self.ambient_k, self.index = seed, noise, ambient_k, index
        self.samples_per_pixel = int(samples_per_pixel)
        if self.samples_per_pixel != 1 and cam.kind == "depth":
            raise SimulationError(f"Expected --camera-samples 1 for the depth camera "
                                  f"{cam.name} (a depth camera does not average), got "
                                  f"{samples_per_pixel}.")
        stratified_offsets(self.samples_per_pixel)     # a square number, checked now

    def __len__(self) -> int:
        return len(self.times)

    @property
    def rays(self) -> int:
        """Rays cast for the frames' geometry (one per pixel per frame)."""
        return len(self) * self.cam.width * self.cam.height

    @property
    def base_from_optical(self) -> NDArray[np.float64]:
        """(4, 4) float64: the optical frame in base_link."""
        return _matrices(np.asarray([self.mount.lever_arm_m]),
                         Rotation.from_quat([self.mount.boresight.as_quat()]))[0]

    def poses(self, i: int) -> NDArray[np.float64]:
        """world_from_camera of frame ``i``: (4, 4) for a global shutter, (height, 4, 4)
        (row r at ``row_times``) for a rolling one."""
        t = row_times(self.cam, float(self.times[i]))
        pos, rot = self.trajectory.sensor_poses(t, self.mount)
        T = _matrices(pos, rot)
        return T[0] if self.cam.global_shutter else T

    def render(self, i: int) -> CameraFrame:
        """Frame ``i``: geometry, lamps at its start, shaded image."""
        t0 = float(self.times[i])
        T = self.poses(i)
        pos, rot = self.trajectory.interpolate([t0])
        base = _matrices(pos, rot)[0]
        lamps = self.lamps(base, T if T.ndim == 2 else T[0])
        shot = frame_image(self.scene, self.cam, T, self.appearance, lamps,
                           samples_per_pixel=self.samples_per_pixel,
                           seed=frame_seed(self.seed, self.index, i), noise=self.noise,
                           ambient_k=self.ambient_k)
        return CameraFrame(i, t0, t0 + readout_s(self.cam), shot.frame, base,
                           shot.rgb_linear, shot.thermal_k, shot.exposure_s, shot.gain)

    def __iter__(self) -> Iterator[CameraFrame]:
        for i in range(len(self)):
            yield self.render(i)



def image_counts(cam: CameraSpec, frame: CameraFrame) -> NDArray[np.generic]:
    """The digital image of a frame as files and bags carry it (``sensors.camera_io``):
    (h, w, 3) uint8 sRGB for colour, (h, w) uint16 mm for depth, (h, w) uint16
    centikelvin for thermal."""
    from .camera_io import depth_counts, rgb8, thermal_counts

    if cam.kind == "color":
        assert frame.rgb_linear is not None
        return rgb8(frame.rgb_linear)
    if cam.kind == "thermal":
        assert frame.thermal_k is not None
        return thermal_counts(frame.thermal_k)
    return depth_counts(frame.frame.depth_z_m)[0]


def stamp_ns(t_s: float) -> int:
    """A trajectory time (s) as the whole ns of a file name."""
    return int(round(float(t_s) * 1e9))


def write_frame_folder(camera: DriveCamera, folder: str | os.PathLike[str], *,
                       info: dict[str, object] | None = None) -> Path:
    """Render every frame of ``camera`` into ``folder`` (``sensors.camera_io.FrameFolder``:
    ``rgb/`` or ``thermal/``, ``depth/``, ``frames.csv``, ``camera_info.json``).

    Returns
    -------
    Path
        The folder.
    """
    from .camera_io import FrameFolder

    extra = dict(rate_hz=camera.rate_hz, samples_per_pixel=camera.samples_per_pixel,
                 **(info or {}))
    with FrameFolder(folder, camera.cam, camera.base_from_optical, extra) as w:
        for f in camera:
            w.write(f.index, stamp_ns(f.stamp_s), f.frame, readout_end_s=f.readout_end_s,
                    time_s=f.stamp_s, rgb_linear=f.rgb_linear, thermal_k=f.thermal_k,
                    exposure_s=f.exposure_s, gain=f.gain)
    return Path(folder)
