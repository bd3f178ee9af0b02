"""Camera frames from the mesh with our own BVH: one ray per pixel centre through the
lens model (``sensors.camera``), cast by ``raytrace.Scene``.

A frame holds what every camera kind needs: the geometric hit of each pixel, its
range along the ray, its z-depth (the distance along the optical axis, what a depth
camera reports), the triangle and the surface normal. Shading and thermal radiance are
computed from these (``sensors.shading``); this module knows no light.

Poses: ``world_from_camera`` is the 4x4 pose of the OpenCV optical frame (x right,
y down, z forward) in the world; ``camera_pose`` builds it from a position and the
heading/pitch/roll a user gives (heading: the optical axis's azimuth from +x towards +y,
as the rest of tunnelsim's headings).

>>> import numpy as np
>>> from raytrace.shapes import tunnel_tube
>>> from raytrace import Scene
>>> from sensors.camera import load_camera
>>> v, f = tunnel_tube(4_000, length_m=30.0)
>>> cam = load_camera("realsense_d435_depth")
>>> frame = render_depth(Scene(v, f), cam, camera_pose([2.0, 0.0, 1.5], 0.0))
>>> frame.depth_z_m.shape, round(float(frame.depth_z_m[360, 0]), 3)   # left edge: wall
((720, 1280), 1.539)
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from raytrace import Scene

from .camera import CameraSpec, pixel_rays
from .errors import SimulationError

__all__ = ["Frame", "camera_pose", "render_depth"]


@dataclass(frozen=True)
class Frame:
    """One rendered frame's geometry, row-major (height, width).

    Attributes
    ----------
    hit : (h, w) bool
        The pixel's ray meets the mesh.
    valid : (h, w) bool
        Hit and, for a depth camera, within its depth range.
    range_m : (h, w) float64
        Distance from the optical centre to the hit along the ray; NaN on a miss.
    depth_z_m : (h, w) float64
        The hit's z in the optical frame (what depth cameras report); NaN where not
        ``valid``.
    triangle : (h, w) int64
        Row of the hit face in the scene's faces; -1 on a miss.
    normal : (h, w, 3) float64
        Unit geometric normal of the hit face, world frame, turned towards the camera;
        zero on a miss.
    points : (h, w, 3) float64
        The hit points, world frame; NaN on a miss.
    rays_cam : (h, w, 3) float64
        Unit ray directions in the optical frame.
    world_from_camera : (4, 4) float64
    """

    hit: NDArray[np.bool_]
    valid: NDArray[np.bool_]
    range_m: NDArray[np.float64]
    depth_z_m: NDArray[np.float64]
    triangle: NDArray[np.int64]
    normal: NDArray[np.float64]
    points: NDArray[np.float64]
    rays_cam: NDArray[np.float64]
    world_from_camera: NDArray[np.float64]


def camera_pose(position: ArrayLike, heading_rad: float, pitch_rad: float = 0.0,
                roll_rad: float = 0.0) -> NDArray[np.float64]:
    """(4, 4) world_from_camera of an OpenCV optical frame at ``position`` whose axis
    points along ``heading_rad`` (azimuth from +x towards +y), tilted up by
    ``pitch_rad`` and rolled clockwise (seen from behind) by ``roll_rad``."""
    p = np.asarray(position, dtype=np.float64).reshape(-1)
    if p.shape != (3,) or not np.isfinite(p).all():
        raise SimulationError(f"Expected a camera position as 3 finite numbers, got {p}.")
    for name, a in (("heading", heading_rad), ("pitch", pitch_rad), ("roll", roll_rad)):
        if not math.isfinite(a):
            raise SimulationError(f"Expected a finite camera {name}, got {a}.")
    ch, sh = math.cos(heading_rad), math.sin(heading_rad)
    cp, sp = math.cos(pitch_rad), math.sin(pitch_rad)
    fwd = np.array([ch * cp, sh * cp, sp])
    right0 = np.array([sh, -ch, 0.0])                  # fwd x up, level
    down0 = np.cross(fwd, right0)                      # z x x = y: down
    cr, sr = math.cos(roll_rad), math.sin(roll_rad)
    right = cr * right0 + sr * down0
    down = np.cross(fwd, right)
    out = np.eye(4)
    out[:3, 0], out[:3, 1], out[:3, 2], out[:3, 3] = right, down, fwd, p
    return out


def _check_pose(world_from_camera: ArrayLike) -> NDArray[np.float64]:
    T = np.asarray(world_from_camera, dtype=np.float64)
    if T.shape != (4, 4) or not np.isfinite(T).all():
        raise SimulationError(f"Expected world_from_camera as a finite 4x4 matrix, got "
                              f"shape {T.shape}.")
    R = T[:3, :3]
    if not np.allclose(R.T @ R, np.eye(3), atol=1e-9) or np.linalg.det(R) < 0:
        raise SimulationError("Expected world_from_camera's rotation to be a proper "
                              "rotation (orthonormal, det +1), got one that is not; build "
                              "it with camera_pose().")
    return T


def render_depth(scene: Scene, cam: CameraSpec, world_from_camera: ArrayLike) -> Frame:
    """Cast one ray per pixel centre of ``cam`` posed at ``world_from_camera``.

    Parameters
    ----------
    scene : raytrace.Scene
        The mesh.
    cam : CameraSpec
        The camera (its lens model maps pixels to rays).
    world_from_camera : (4, 4) array_like
        Pose of the optical frame in the world (``camera_pose``).

    Returns
    -------
    Frame
    """
    T = _check_pose(world_from_camera)
    rays_cam = pixel_rays(cam)
    h, w = cam.height, cam.width
    dirs_cam = rays_cam.reshape(-1, 3)
    ok_ray = np.isfinite(dirs_cam).all(axis=1)
    dirs = dirs_cam @ T[:3, :3].T
    dirs[~ok_ray] = T[:3, 2]          # cast something; the pixel is masked below
    hits = scene.cast(T[:3, 3], dirs)
    hit = hits.hit & ok_ray
    rng = np.where(hit, hits.t, np.nan)
    z = rng * dirs_cam[:, 2]
    valid = hit.copy()
    if cam.depth_range_m is not None:
        lo, hi = cam.depth_range_m
        with np.errstate(invalid="ignore"):
            valid &= (z >= lo) & (z <= hi)
    normal = np.zeros((h * w, 3))
    if hit.any():
        n = np.asarray(hits.normals, dtype=np.float64)[hit]
        flip = np.einsum("ij,ij->i", n, dirs[hit]) > 0
        n[flip] *= -1.0
        normal[hit] = n
    pts = np.where(hit[:, None], T[:3, 3] + dirs * np.where(hit, hits.t, 0.0)[:, None],
                   np.nan)
    return Frame(hit.reshape(h, w), valid.reshape(h, w), rng.reshape(h, w),
                 np.where(valid, z, np.nan).reshape(h, w),
                 np.where(hit, hits.triangle, -1).reshape(h, w), normal.reshape(h, w, 3),
                 pts.reshape(h, w, 3), rays_cam, T)
