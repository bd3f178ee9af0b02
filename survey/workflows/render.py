"""``tunnelsim render`` and ``tunnelsim cameras`` as library calls: one camera frame
from a mesh (colour, depth or thermal, lit by a headlamp beside the camera and/or a
platform's lamps, anti-aliased by supersampling) written as image files with their
``camera_info.json``, and the shipped camera models.

The camera and a platform (``platform=``): the camera at ``at`` is the platform's
camera mount, at its platform frame (the mast's top, where its sensor sits), and the
platform stands level facing ``heading_deg``. base_link is where ``sensors.robot``
puts it: a wheeled base's ``body.mast_height_m`` below the mount (on the ground
contact plane), any other platform's at the mount itself. ``world_from_base`` is a
turn by the heading about z and the translation to ``at - (0, 0, that height)``. The
camera's pitch and roll are its own on the mount (the platform does not tilt with
them). The platform's ``[[lamps]]`` are placed with ``sensors.shading.platform_lamps``.

The command line parses its options, calls one of these and prints from the result.
"""

from __future__ import annotations

import math
import os
import time
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["CameraModel", "RenderResult", "camera_models", "label_names", "render_frame"]

PathLike = str | os.PathLike[str]


# ---------------------------------------------------------------------------- cameras
@dataclass(frozen=True)
class CameraModel:
    """One shipped camera model (``tunnelsim cameras``).

    Attributes
    ----------
    name, kind, vendor, model : str
        Registry name, "color" / "depth" / "thermal", maker and model.
    width, height : int
        Pixels.
    frame_rate_hz : float
    hfov_deg, vfov_deg : float
        Horizontal and vertical field of view through the pixel edges, degrees.
    lens : str
        "pinhole" (Brown-Conrady) or "fisheye" (Kannala-Brandt).
    shutter : str
        "global" or "rolling".
    sources : tuple of str
    path : str
        The TOML file.
    """

    name: str
    kind: str
    vendor: str
    model: str
    width: int
    height: int
    frame_rate_hz: float
    hfov_deg: float
    vfov_deg: float
    lens: str
    shutter: str
    sources: tuple[str, ...]
    path: str


def _fov_deg(cam, n: int, f: float) -> float:
    half = n / 2.0 / f
    return math.degrees(2.0 * (math.atan(half) if cam.model == "pinhole" else half))


def camera_models() -> tuple[CameraModel, ...]:
    """The shipped camera models, sorted by name (``sensors.camera.list_cameras``).

    Returns
    -------
    tuple of CameraModel

    Examples
    --------
    >>> [m.name for m in camera_models()][:2]
    ['lwir_640', 'realsense_d435_color']
    >>> round(camera_models()[2].hfov_deg, 3)
    87.0
    """
    from sensors.camera import list_cameras, load_camera

    out = []
    for name in list_cameras():
        c = load_camera(name)
        out.append(CameraModel(c.name, c.kind, c.vendor, c.model_name, c.width, c.height,
                               c.frame_rate_hz, _fov_deg(c, c.width, c.fx),
                               _fov_deg(c, c.height, c.fy), c.model,
                               "global" if c.global_shutter else "rolling", c.sources,
                               c.path))
    return tuple(out)


# ---------------------------------------------------------------------------- render
@dataclass(frozen=True)
class RenderResult:
    """What ``render_frame`` wrote and saw.

    Attributes
    ----------
    files : tuple of Path
        Every file written (``rgb.png`` / ``thermal.png`` as the camera's kind has
        them, ``depth.png``, ``depth.npy``, ``camera_info.json``).
    folder : Path
    camera, kind : str
        The camera's name and kind.
    width, height : int
    world_from_camera : (4, 4) float64
        Pose of the OpenCV optical frame.
    hit_fraction : float
        Pixels whose ray meets the mesh.
    valid_fraction : float
        Pixels with a depth (hit, and within a depth camera's range).
    depth_min_m, depth_median_m, depth_max_m : float
        Of the valid pixels' z-depth (NaN when none).
    depth_clipped : int
        Valid pixels beyond ``depth.png``'s 65.535 m (0 there, kept in ``depth.npy``).
    lamp_cd : float
        The headlamp's intensity (0: no headlamp).
    mean_value : float
        Colour: the mean linear value of the RGB image (0-1, of full scale);
        thermal: the mean apparent temperature (K); depth: NaN.
    saturated_fraction : float
        Colour: pixel channels at full well (raise the exposure's light less, or pass
        a weaker --lamp-cd); otherwise 0.
    appearance : dict of str to str
        Where albedo, temperature and emissivity came from ("vertex", "label",
        "default").
    seconds : float
    platform : str or None
        The platform whose lamps lit the frame (``platform=``).
    lamps : int
        Lamps that lit the frame (the headlamp and the platform's).
    samples_per_pixel : int
        Rays averaged per pixel (``samples=``).
    exposure_s, gain : float
        The colour image's exposure time and analog gain (auto-exposure's for a camera
        with ``auto_exposure``; else the camera's exposure at gain 1).
    """

    files: tuple[Path, ...]
    folder: Path
    camera: str
    kind: str
    width: int
    height: int
    world_from_camera: NDArray[np.float64]
    hit_fraction: float
    valid_fraction: float
    depth_min_m: float
    depth_median_m: float
    depth_max_m: float
    depth_clipped: int
    lamp_cd: float
    mean_value: float
    saturated_fraction: float
    appearance: dict[str, str]
    seconds: float
    platform: str | None = None
    lamps: int = 0
    samples_per_pixel: int = 1
    exposure_s: float = math.nan
    gain: float = 1.0


def label_names(mesh_path: PathLike) -> tuple[str, ...]:
    """Names of a mesh's face labels, index by index, as ``render_frame`` reads them
    (``sensors.appearance.mesh_appearance``'s ``label_names``).

    Parameters
    ----------
    mesh_path : str or path
        The mesh; its tunnel JSON (``sensors.io.tunnel_json.sidecar``) is read if there.

    Returns
    -------
    tuple of str
        The JSON's ``labels`` (``""`` for an index it skips), else the generator's
        ``survey.world.mesh.LABELS``.
    """
    from sensors.io.errors import TunnelFileError
    from sensors.io.tunnel_json import read_meta, sidecar
    from survey.world.mesh import LABELS

    js = sidecar(Path(mesh_path))
    if js.is_file():
        try:
            labels = read_meta(js).get("labels")
        except TunnelFileError:    # a JSON that is not a tunnel's: the labels stay default
            labels = None
        if isinstance(labels, dict) and labels:
            try:
                n = max(int(k) for k in labels) + 1
                return tuple(str(labels.get(str(i), "")) for i in range(n))
            except ValueError:
                pass
    return tuple(LABELS)


def render_frame(mesh: PathLike, camera: str | PathLike, at: ArrayLike, output: PathLike,
                 *, heading_deg: float, pitch_deg: float = 0.0, roll_deg: float = 0.0,
                 lamp_cd: float | None = None, seed: int = 0, noise: bool = True,
                 ambient_k: float | None = None, time_s: float = 0.0,
                 platform: str | os.PathLike[str] | None = None,
                 samples: int = 1) -> RenderResult:
    """Render one frame of ``camera`` at ``at`` in ``mesh`` and write its files.

    Shaded as a drive's camera frames are (``sensors.camera_drive.frame_image``, the
    one shading path). The frame's light: a spot lamp 5 cm above the camera along its
    axis (``sensors.shading.headlamp``: a 30/45 degree beam, ASSUMED) of ``lamp_cd``,
    and, with ``platform``, the platform's lamps (module doc: the camera is its
    camera mount). Colour cameras get Lambertian shading (plus the retro-reflection
    of retro-reflective materials, ``sensors.shading.luminance``) with a shadow ray
    per lamp, averaged over ``samples`` rays per pixel
    (``sensors.shading.radiance_frame``), the exposure's shot and read noise and the
    sRGB PNG; thermal cameras the apparent temperature of each surface's temperature
    and emissivity, its band radiance averaged over ``samples`` rays
    (``sensors.shading.thermal_frame``); every camera the z-depth of the pixel
    centre. Albedo, temperature and emissivity come from the mesh's vertex
    properties, else its face labels, else grey (``sensors.appearance``).

    Parameters
    ----------
    mesh : str or path
        A mesh file (``sensors.io.meshes.read_mesh``).
    camera : str or path
        A shipped camera's name (``camera_models``) or a camera TOML file.
    at : (3,) array_like
        The camera's optical centre, metres, in the mesh's coordinates.
    output : str or path
        The folder for the files (created; files of the same names are replaced).
    heading_deg, pitch_deg, roll_deg : float
        The optical axis's azimuth from +x towards +y, its tilt up, and the roll
        clockwise seen from behind (degrees).
    lamp_cd : float, optional
        The headlamp's luminous intensity on its axis (candela); 0 for none. Default:
        1000 cd without ``platform``, none with it (its lamps light the frame).
        DECISION: given with ``platform``, the headlamp lights the frame too (both
        count; nothing the caller asked for is dropped).
    seed : int
        Seed of the exposure's (or thermal camera's) noise.
    noise : bool
        Add the sensor's noise (shot and read noise, or NETD).
    ambient_k : float, optional
        Temperature of the surroundings a thermal surface reflects (default:
        ``sensors.appearance.ROCK_K``, the tunnel's own rock).
    time_s : float
        Time stamp written into ``camera_info.json``.
    platform : str or path, optional
        A platform name (``sensors.platform_spec.list_platforms``) or TOML file whose
        ``[[lamps]]`` light the frame, the camera at ``at`` being its camera mount
        (module doc). Colour cameras only: no lamp changes a depth or thermal frame.
    samples : int
        Rays per pixel, a square number (1, 4, 9, 16 ...): a k x k grid of strata
        (``sensors.shading.stratified_offsets``), their linear radiance (colour) or
        band radiance (thermal) averaged (anti-aliasing); 1 is the pixel centre. Not
        for a depth camera (its depth is the pixel centre's).

    Returns
    -------
    RenderResult

    Raises
    ------
    sensors.errors.CameraSpecError
        An unknown camera or a bad camera file.
    sensors.io.errors.MeshFileError
        A mesh that cannot be read (a point cloud without faces ...).
    sensors.errors.SimulationError
        A pose that is not finite, a negative lamp intensity, a camera from which no
        pixel's ray meets the mesh (outside it, or looking out of it), ``samples`` not
        a square number, ``samples`` > 1 for a depth camera, or ``platform`` for a
        depth or thermal camera.
    sensors.errors.PlatformError
        An unknown platform or a bad platform file.

    Examples
    --------
    >>> import tempfile, pathlib
    >>> from survey.workflows.world import tunnel_files
    >>> d = pathlib.Path(tempfile.mkdtemp())
    >>> _ = tunnel_files(d / "t.ply", preset="tbm", edge_length_m=0.5)
    >>> r = render_frame(d / "t.ply", "lwir_640", [5.0, 0.0, 1.5], d / "frame",
    ...                  heading_deg=0.0)
    >>> [p.name for p in r.files], r.hit_fraction > 0.9
    (['depth.png', 'depth.npy', 'thermal.png', 'camera_info.json'], True)
    """
    from sensors.appearance import mesh_appearance
    from sensors.camera import load_camera
    from sensors.camera_drive import frame_image
    from sensors.camera_io import write_frame
    from sensors.errors import CameraSpecError, SimulationError
    from sensors.io.errors import MeshFileError
    from sensors.io.meshes import read_mesh
    from sensors.errors import PlatformError
    from sensors.platform_spec import load_platform
    from sensors.render import camera_pose
    from sensors.robot import RobotDescription
    from sensors.shading import headlamp, platform_lamps, stratified_offsets

    from raytrace import Scene

    t0 = time.perf_counter()
    try:
        cam = load_camera(camera)
    except CameraSpecError as exc:
        raise CameraSpecError(f"--camera: {exc} 'tunnelsim cameras' lists the names."
                              ) from None
    if lamp_cd is not None and not (math.isfinite(lamp_cd) and lamp_cd >= 0):
        raise SimulationError(f"Expected --lamp-cd >= 0 (candela), got {lamp_cd}; pass "
                              "--lamp-cd 0 for no light.")
    n_samples = len(stratified_offsets(samples))
    if (cam.kind == "depth" and n_samples > 1) or (cam.kind != "color" and
                                                   platform is not None):
        what = (f"--samples 1, got {samples}" if platform is None else
                f"no --platform, got {str(platform)!r}")
        why = ("a depth camera reports the pixel centre's depth, it does not average"
               if platform is None else "the platform's lamps light only a colour frame")
        raise SimulationError(f"Expected {what} for the {cam.kind} camera {cam.name} "
                              f"({why}); pass a colour --camera or leave it out.")
    spec = None
    if platform is not None:
        try:
            spec = load_platform(platform)
        except PlatformError as exc:
            raise PlatformError(f"--platform: {exc}") from None
    head_cd = (0.0 if spec is not None else 1000.0) if lamp_cd is None else float(lamp_cd)
    p = np.asarray(at, dtype=np.float64).reshape(-1)
    if p.shape != (3,) or not np.isfinite(p).all():
        raise SimulationError(f"Expected --at as 3 finite numbers X,Y,Z in metres, got "
                              f"{p.tolist()}.")
    for name, a in (("--heading-deg", heading_deg), ("--pitch-deg", pitch_deg),
                    ("--roll-deg", roll_deg)):
        if not math.isfinite(a):
            raise SimulationError(f"Expected a finite {name}, got {a}.")
    try:
        m = read_mesh(mesh)
    except MeshFileError as exc:
        raise MeshFileError(f"--mesh: {exc}") from None
    lo, hi = m.vertices.min(axis=0), m.vertices.max(axis=0)
    if np.any(p < lo) or np.any(p > hi):
        warnings.warn(f"--at {','.join(f'{x:g}' for x in p)} lies outside the mesh's "
                      f"bounding box ({', '.join(f'{a:.2f}..{b:.2f}' for a, b in zip(lo, hi))}"
                      "); the camera sees the mesh from outside.", stacklevel=2)
    T = camera_pose(p, math.radians(heading_deg), math.radians(pitch_deg),
                    math.radians(roll_deg))
    scene = Scene(m.vertices, m.faces)
    app = mesh_appearance(m, label_names(mesh) if "label" in m.face_fields
                          else None)
    lamps = [headlamp(T, head_cd)] if head_cd > 0 else []
    if spec is not None:
        mast = RobotDescription.from_platform(spec, "camera").mast_height_m
        lamps += platform_lamps(spec, _world_from_base(p, heading_deg, mast))
    # One shading path: the frame a drive's camera takes (sensors.camera_drive).
    shot = frame_image(scene, cam, T, app, lamps, samples_per_pixel=n_samples, seed=seed,
                       noise=noise, ambient_k=ambient_k)
    frame, rgb, thermal = shot.frame, shot.rgb_linear, shot.thermal_k
    if not frame.hit.any():
        raise SimulationError(
            f"Expected the camera at --at {','.join(f'{x:g}' for x in p)} to see the "
            f"mesh, got no pixel whose ray meets it (outside the tunnel, or looking out "
            "of an open end); pass --at inside the mesh or another --heading-deg.")
    mean_value, saturated = math.nan, 0.0
    if rgb is not None:
        mean_value, saturated = float(rgb.mean()), float((rgb >= 1.0).mean())
    elif thermal is not None:
        mean_value = float(np.nanmean(thermal))
    files = write_frame(output, cam, frame, rgb_linear=rgb, thermal_k=thermal,
                        time_s=time_s, exposure_s=shot.exposure_s, gain=shot.gain)
    z = frame.depth_z_m[frame.valid]
    stats = (float(z.min()), float(np.median(z)), float(z.max())) if z.size else \
        (math.nan,) * 3
    return RenderResult(files.paths, files.folder, cam.name, cam.kind, cam.width,
                        cam.height, T, float(frame.hit.mean()), float(frame.valid.mean()),
                        *stats, files.depth_clipped, head_cd, mean_value, saturated,
                        dict(app.source), time.perf_counter() - t0,
                        None if spec is None else spec.name, len(lamps), n_samples,
                        shot.exposure_s, shot.gain)


def _world_from_base(camera_at: NDArray[np.float64], heading_deg: float,
                     mast_height_m: float) -> NDArray[np.float64]:
    """(4, 4) pose of a level platform's base_link whose camera mount (its platform
    frame, ``mast_height_m`` above base_link) is at ``camera_at``, facing
    ``heading_deg`` (module doc)."""
    h = math.radians(heading_deg)
    T = np.eye(4)
    T[:2, :2] = [[math.cos(h), -math.sin(h)], [math.sin(h), math.cos(h)]]
    T[:3, 3] = camera_at - np.array([0.0, 0.0, mast_height_m])
    return T
