"""Camera frames from the mesh with our own BVH: one ray per pixel centre through the
lens model (``sensors.camera``), cast by ``raytrace.Scene``.

A frame holds what every camera kind needs: the geometric hit of each pixel, its
range along the ray, its z-depth (the distance along the optical axis, what a depth
camera reports), the triangle and the surface normal. Shading and thermal radiance are
computed from these (``sensors.shading``); this module knows no light.

Poses: ``world_from_camera`` is the 4x4 pose of the OpenCV optical frame (x right,
y down, z forward) in the world; ``camera_pose`` builds it from a position and the
heading/pitch/roll a user gives (heading: the optical axis's azimuth from +x towards +y,
as the rest of tunnelsim's headings). A rolling-shutter frame takes one pose per image
row, (height, 4, 4): row r's rays leave from row r's optical centre along row r's axes
(``sensors.camera_drive`` interpolates them along a trajectory).

Anti-aliasing: ``pixel_offset=(dx, dy)`` moves every ray from the pixel centre (u, v)
to (u + dx, v + dy) pixels; averaging the shaded frames of several offsets inside the
pixel (-0.5..0.5) supersamples it.

>>> import numpy as np
>>> from raytrace.shapes import tunnel_tube
>>> from raytrace import Hits, Scene
>>> from sensors.camera import load_camera
>>> v, f = tunnel_tube(4_000, length_m=30.0)
>>> cam = load_camera("realsense_d435_depth")
>>> frame = render_depth(Scene(v, f), cam, camera_pose([2.0, 0.0, 1.5], 0.0))
>>> frame.depth_z_m.shape, round(float(frame.depth_z_m[360, 0]), 3)   # left edge: wall
((720, 1280), 1.539)
"""

from __future__ import annotations

import math
from collections import OrderedDict

import numpy as np
from numba import njit, prange
from numpy.typing import ArrayLike, NDArray

from raytrace import Hits, Scene
from raytrace.config import CACHE, ERROR_MODEL

from .camera import CameraSpec, pixel_rays, unproject
from .errors import SimulationError

__all__ = ["Frame", "camera_pose", "render_depth"]


class Frame:
    """One rendered frame's geometry, row-major (height, width). Read-only.

    ``render_depth`` makes frames whose surface fields (``normal``, ``points``,
    ``bary_u``, ``bary_v``) are computed on first use and kept, so that a depth frame
    costs only its depth; ``Frame(...)`` with every field given makes one from arrays
    of your own (a depth image from elsewhere, for the frame writers).

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
        The pose of the optical frame; for a rolling-shutter frame, row 0's (the
        first row exposed).
    bary_u, bary_v : (h, w) float64
        Barycentric coordinates of the hit in its triangle: the hit is
        (1 - u - v) p0 + u p1 + v p2 of the face's vertices in their given order
        (``raytrace.Hits``' convention); 0 on a miss. Vertex attributes (colour,
        temperature) are interpolated with them (``sensors.appearance``).
    row_poses : (h, 4, 4) float64 or None
        One pose per image row for a frame rendered with per-row poses (rolling
        shutter); None for a frame rendered from one pose.
    """

    __slots__ = ("hit", "valid", "range_m", "depth_z_m", "triangle", "rays_cam",
                 "world_from_camera", "row_poses", "_surface", "_source")
    hit: NDArray[np.bool_]
    valid: NDArray[np.bool_]
    range_m: NDArray[np.float64]
    depth_z_m: NDArray[np.float64]
    triangle: NDArray[np.int64]
    rays_cam: NDArray[np.float64]
    world_from_camera: NDArray[np.float64]
    row_poses: NDArray[np.float64] | None
    _surface: tuple[NDArray[np.float64], ...] | None
    _source: tuple[Hits, NDArray[np.float64], NDArray[np.float64], int] | None

    def __init__(self, hit: NDArray[np.bool_], valid: NDArray[np.bool_],
                 range_m: NDArray[np.float64], depth_z_m: NDArray[np.float64],
                 triangle: NDArray[np.int64], normal: NDArray[np.float64] | None,
                 points: NDArray[np.float64] | None, rays_cam: NDArray[np.float64],
                 world_from_camera: NDArray[np.float64], bary_u: NDArray[np.float64] | None,
                 bary_v: NDArray[np.float64] | None,
                 row_poses: NDArray[np.float64] | None = None) -> None:
        for name, value in (("hit", hit), ("valid", valid), ("range_m", range_m),
                            ("depth_z_m", depth_z_m), ("triangle", triangle),
                            ("rays_cam", rays_cam), ("world_from_camera", world_from_camera),
                            ("row_poses", row_poses), ("_source", None)):
            object.__setattr__(self, name, value)
        surface = (normal, points, bary_u, bary_v)
        object.__setattr__(self, "_surface",
                           None if any(x is None for x in surface) else surface)

    @classmethod
    def _of_cast(cls, hit: NDArray[np.bool_], valid: NDArray[np.bool_],
                 range_m: NDArray[np.float64], depth_z_m: NDArray[np.float64],
                 triangle: NDArray[np.int64], rays_cam: NDArray[np.float64],
                 world_from_camera: NDArray[np.float64],
                 row_poses: NDArray[np.float64] | None, hits: Hits,
                 dirs: NDArray[np.float64], origins: NDArray[np.float64],
                 block: int) -> Frame:
        """A frame whose surface fields are computed from the cast on first use: its
        ``hits``, the world directions as cast, the origins (ray i leaves from
        ``origins[i // block]``).
        DECISION: lazily (issue 35's depth-frame rate): a depth camera reads none of
        them, and writing them took 3 ms of a 36 ms 640x480 frame."""
        fr = cls(hit, valid, range_m, depth_z_m, triangle, None, None, rays_cam,
                 world_from_camera, None, None, row_poses)
        object.__setattr__(fr, "_source", (hits, dirs, origins, block))
        return fr

    def __setattr__(self, name: str, value: object) -> None:
        raise AttributeError(f"Frame is read-only: cannot set {name!r}.")

    def _surface_fields(self) -> tuple[NDArray[np.float64], ...]:
        surface, source = self._surface, self._source
        if surface is None:
            if source is None:
                raise AttributeError("Expected a frame with normal, points, bary_u and "
                                     "bary_v, got one made without them; pass all four "
                                     "to Frame(...) or render it with render_depth().")
            hits, dirs, origins, block = source
            h, w = self.hit.shape
            n = h * w
            normal, pts = np.empty((n, 3)), np.empty((n, 3))
            bu, bv = np.empty(n), np.empty(n)
            _surface(self.hit.reshape(-1), dirs, origins, block, self.range_m.reshape(-1),
                     hits.u, hits.v, np.asarray(hits.normals, dtype=np.float64), normal,
                     pts, bu, bv)
            surface = (normal.reshape(h, w, 3), pts.reshape(h, w, 3), bu.reshape(h, w),
                       bv.reshape(h, w))
            object.__setattr__(self, "_surface", surface)
            object.__setattr__(self, "_source", None)   # the cast's arrays can go
        return surface

    @property
    def normal(self) -> NDArray[np.float64]:
        """(h, w, 3) float64: unit geometric normals towards the camera; 0 on a miss."""
        return self._surface_fields()[0]

    @property
    def points(self) -> NDArray[np.float64]:
        """(h, w, 3) float64: the hit points, world frame; NaN on a miss."""
        return self._surface_fields()[1]

    @property
    def bary_u(self) -> NDArray[np.float64]:
        """(h, w) float64: the hit's barycentric u; 0 on a miss."""
        return self._surface_fields()[2]

    @property
    def bary_v(self) -> NDArray[np.float64]:
        """(h, w) float64: the hit's barycentric v; 0 on a miss."""
        return self._surface_fields()[3]


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


def _check_rotation(R: NDArray[np.float64]) -> bool:
    """``R`` (..., 3, 3) are all proper rotations (orthonormal, det +1)."""
    RtR = np.einsum("...ki,...kj->...ij", R, R)
    return bool(np.allclose(RtR, np.eye(3), atol=1e-9) and np.all(np.linalg.det(R) > 0))


def _check_pose(world_from_camera: ArrayLike, height: int) -> NDArray[np.float64]:
    """The pose as a float64 (4, 4) or (height, 4, 4) array, checked."""
    T = np.asarray(world_from_camera, dtype=np.float64)
    if T.shape not in ((4, 4), (height, 4, 4)) or not np.isfinite(T).all():
        raise SimulationError(f"Expected world_from_camera as a finite 4x4 matrix or one "
                              f"per image row ({height}, 4, 4), got shape {T.shape}.")
    if not _check_rotation(T[..., :3, :3]):
        raise SimulationError("Expected world_from_camera's rotation to be a proper "
                              "rotation (orthonormal, det +1), got one that is not; build "
                              "it with camera_pose().")
    return T


def _check_offset(pixel_offset: ArrayLike) -> tuple[float, float]:
    off = np.asarray(pixel_offset, dtype=np.float64).reshape(-1)
    if off.shape != (2,) or not np.isfinite(off).all():
        raise SimulationError(f"Expected pixel_offset as 2 finite numbers (dx, dy) in "
                              f"pixels, got {np.asarray(pixel_offset).tolist()}.")
    return float(off[0]), float(off[1])


#: Ray directions of the most recent lenses (``_lens_rays``): inverting the lens model
#: for every pixel costs more than casting the rays (0.7 s for 640x480 by Newton's
#: method, against 0.06 s to cast them), and a sequence of frames reuses one camera.
_RAY_CACHE: OrderedDict[tuple[object, ...], NDArray[np.float64]] = OrderedDict()
# DECISION: 16, room for a supersampling pattern's offsets (each a lens of its own).
_RAY_CACHE_SIZE = 16


def _lens_rays(cam: CameraSpec, offset: tuple[float, float] = (0.0, 0.0)
               ) -> NDArray[np.float64]:
    """``pixel_rays(cam)`` through the pixel centres moved by ``offset`` (pixels), kept
    for the last ``_RAY_CACHE_SIZE`` lenses and offsets (read-only)."""
    key = (cam.model, cam.width, cam.height, cam.fx, cam.fy, cam.cx, cam.cy,
           tuple(float(x) for x in cam.distortion), offset)
    rays = _RAY_CACHE.get(key)
    if rays is None:
        if offset == (0.0, 0.0):
            rays = pixel_rays(cam)
        else:
            v, u = np.mgrid[0:cam.height, 0:cam.width].astype(np.float64)
            uv = np.stack([u.ravel() + offset[0], v.ravel() + offset[1]], 1)
            rays = unproject(cam, uv).reshape(cam.height, cam.width, 3)
        rays.flags.writeable = False
        _RAY_CACHE[key] = rays
        while len(_RAY_CACHE) > _RAY_CACHE_SIZE:
            _RAY_CACHE.popitem(last=False)
    else:
        _RAY_CACHE.move_to_end(key)
    return rays


def render_depth(scene: Scene, cam: CameraSpec, world_from_camera: ArrayLike, *,
                 pixel_offset: ArrayLike = (0.0, 0.0)) -> Frame:
    """Cast one ray per pixel of ``cam`` posed at ``world_from_camera``.

    Parameters
    ----------
    scene : raytrace.Scene
        The mesh.
    cam : CameraSpec
        The camera (its lens model maps pixels to rays).
    world_from_camera : (4, 4) or (height, 4, 4) array_like
        Pose of the optical frame in the world (``camera_pose``), or one per image row
        (a rolling shutter: row r's rays leave from row r's pose).
    pixel_offset : (2,) array_like of float, keyword-only
        (dx, dy) in pixels: the rays go through (u + dx, v + dy) instead of the pixel
        centres (u, v), for anti-aliasing. (0, 0) is the pixel centre.

    Returns
    -------
    Frame
        ``world_from_camera`` is the (4, 4) pose (row 0's for per-row poses);
        ``row_poses`` the (height, 4, 4) poses when given per row, else None.

    Raises
    ------
    SimulationError
        A pose that is not a finite (4, 4) / (height, 4, 4) proper rigid transform, or
        an offset that is not 2 finite numbers.
    """
    h, w = cam.height, cam.width
    T = _check_pose(world_from_camera, h)
    rays_cam = _lens_rays(cam, _check_offset(pixel_offset))
    dirs_cam = rays_cam.reshape(-1, 3)
    n = h * w
    per_row = T.ndim == 3
    # Rotation and origin per block of ``block`` consecutive rays: one block (all rays)
    # for one pose, a row of w rays for per-row poses.
    Rs = np.ascontiguousarray(T[..., :3, :3].reshape(-1, 3, 3))
    origins = np.ascontiguousarray(T[..., :3, 3].reshape(-1, 3))
    block = w if per_row else max(n, 1)
    ok_ray, dirs = np.empty(n, np.bool_), np.empty((n, 3))
    _world_rays(dirs_cam, Rs, block, ok_ray, dirs)
    # DECISION: per-row poses cast from per-ray origins (each row's repeated w times):
    # ``Scene.cast`` finds the runs of equal origins itself, and its answer does not
    # depend on the path it takes. ``_world_rays`` makes unit directions, so
    # ``unit=True`` spares the cast its normalised copy (~1.2 ms of CPU a 640x480 frame).
    hits = scene.cast(np.repeat(origins, w, axis=0) if per_row else origins[0], dirs,
                      unit=True)
    lo, hi = cam.depth_range_m if cam.depth_range_m is not None else (-np.inf, np.inf)
    hit, valid, z = np.empty(n, np.bool_), np.empty(n, np.bool_), np.empty(n)
    # DECISION: the range and triangle arrays are the cast's own, masked in place (the
    # cast's arrays are this frame's alone): two fresh 2.5 MB arrays a 640x480 frame
    # fewer.
    rng, tri = hits.t, hits.triangle
    _assemble(dirs_cam, ok_ray, rng, tri, float(lo), float(hi), hit, valid, z)
    return Frame._of_cast(hit.reshape(h, w), valid.reshape(h, w), rng.reshape(h, w),
                          z.reshape(h, w), tri.reshape(h, w), rays_cam,
                          T[0] if per_row else T, T if per_row else None, hits, dirs,
                          origins, block)


@njit(parallel=True, cache=CACHE, error_model=ERROR_MODEL)  # type: ignore[call-overload]
def _world_rays(dirs_cam, Rs, block, ok_ray, dirs):  # pragma: no cover (Numba)
    """Unit world directions of the camera-frame rays: R d, ray i turned by
    ``Rs[i // block]`` (one rotation per image row for a rolling shutter), normalised
    with the arithmetic of ``Scene.cast``'s own normalisation (x / sqrt(x x + y y +
    z z)), so that ``cast(..., unit=True)`` of them casts the rays a plain ``cast`` of
    R d would, bit for bit (a pose's rotation is orthonormal only to 1e-9). A ray the
    lens model could not invert (NaN) is flagged and replaced by the optical axis
    (cast, then masked).
    DECISION: a kernel, not ``dirs_cam @ R.T``: NumPy's BLAS call on (n, 3) x (3, 3)
    took 0.2 s at 640x480 on a loaded 2-core machine (its threads spin), more than the
    cast. DECISION: the rays of a block turned by its rotation, not a rotation looked
    up per ray: the per-ray ``i // block`` (a 64-bit division) was a third of the pass
    (issue 35's depth-frame rate)."""
    n = dirs_cam.shape[0]
    n_blocks = (n + block - 1) // block
    if n_blocks == 1:
        for i in prange(n):
            _world_ray(dirs_cam, Rs, 0, i, ok_ray, dirs)
    else:
        for b in prange(n_blocks):
            for i in range(b * block, min(n, (b + 1) * block)):
                _world_ray(dirs_cam, Rs, b, i, ok_ray, dirs)


@njit(cache=CACHE, error_model=ERROR_MODEL, inline="always")  # type: ignore[call-overload]
def _world_ray(dirs_cam, Rs, b, i, ok_ray, dirs):  # pragma: no cover (Numba)
    """Ray i of ``_world_rays``, turned by ``Rs[b]``."""
    x, y, z = dirs_cam[i, 0], dirs_cam[i, 1], dirs_cam[i, 2]
    ok = np.isfinite(x) and np.isfinite(y) and np.isfinite(z)
    ok_ray[i] = ok
    if not ok:
        x, y, z = 0.0, 0.0, 1.0
    wx = Rs[b, 0, 0] * x + Rs[b, 0, 1] * y + Rs[b, 0, 2] * z
    wy = Rs[b, 1, 0] * x + Rs[b, 1, 1] * y + Rs[b, 1, 2] * z
    wz = Rs[b, 2, 0] * x + Rs[b, 2, 1] * y + Rs[b, 2, 2] * z
    length = np.sqrt(wx * wx + wy * wy + wz * wz)
    dirs[i, 0] = wx / length
    dirs[i, 1] = wy / length
    dirs[i, 2] = wz / length


@njit(parallel=True, cache=CACHE, error_model=ERROR_MODEL)  # type: ignore[call-overload]
def _assemble(dirs_cam, ok_ray, t, triangle, lo, hi, hit, valid,
              z):  # pragma: no cover (Numba)
    """The frame's depth arrays from the cast's hits, in one pass (the NumPy version's
    temporaries took longer than the cast): ``t`` becomes the range and ``triangle``
    the frame's triangles, in place (misses: NaN and -1); z is the range times the
    ray's optical-axis cosine, NaN on a miss and outside [lo, hi]."""
    for i in prange(t.shape[0]):
        h_ = ok_ray[i] and triangle[i] >= 0 and np.isfinite(t[i])
        hit[i] = h_
        if h_:
            zi = t[i] * dirs_cam[i, 2]
            ok = zi >= lo and zi <= hi
            valid[i] = ok
            z[i] = zi if ok else np.nan
        else:
            valid[i] = False
            t[i] = np.nan
            z[i] = np.nan
            triangle[i] = -1


@njit(parallel=True, cache=CACHE, error_model=ERROR_MODEL)  # type: ignore[call-overload]
def _surface(hit, dirs, origins, block, rng, u, v, normals, normal, pts, bu,
             bv):  # pragma: no cover (Numba)
    """The frame's surface arrays: the normal turned towards the camera, the hit point
    (ray i leaves from ``origins[i // block]``), the barycentrics. Misses: normal and
    barycentrics 0, points NaN."""
    for i in prange(hit.shape[0]):
        if hit[i]:
            r = rng[i]
            d = normals[i, 0] * dirs[i, 0] + normals[i, 1] * dirs[i, 1] + \
                normals[i, 2] * dirs[i, 2]
            s = -1.0 if d > 0 else 1.0
            o = i // block
            for k in range(3):
                normal[i, k] = s * normals[i, k]
                pts[i, k] = origins[o, k] + dirs[i, k] * r
            bu[i] = u[i]
            bv[i] = v[i]
        else:
            for k in range(3):
                normal[i, k] = 0.0
                pts[i, k] = np.nan
            bu[i] = 0.0
            bv[i] = 0.0
