"""Reference geometry for tests and benchmarks: closed spheres and tubes, a rough
horseshoe tunnel tube. Vectorised NumPy, deterministic for a given seed.

These are test shapes, not the surveyor's tunnel generator (that lives in ``survey`` and
knows about alignments, features and labels).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["horseshoe_profile", "icosphere", "sweep_profile", "tunnel_tube"]

Mesh = tuple[NDArray[np.float64], NDArray[np.int64]]


def icosphere(subdivisions: int = 3, radius: float = 1.0) -> Mesh:
    """Closed, consistently wound (outward) icosphere centred on the origin.

    Parameters
    ----------
    subdivisions : int
        Times each face is split in four (0: the icosahedron).
    radius : float
        Radius in metres; every vertex lies on the sphere.

    Returns
    -------
    vertices : (n, 3) float64
    faces : (m, 3) int64
        m = 20 * 4**subdivisions.
    """
    t = (1.0 + 5 ** 0.5) / 2.0
    v = np.array([[-1, t, 0], [1, t, 0], [-1, -t, 0], [1, -t, 0],
                  [0, -1, t], [0, 1, t], [0, -1, -t], [0, 1, -t],
                  [t, 0, -1], [t, 0, 1], [-t, 0, -1], [-t, 0, 1]], dtype=np.float64)
    f = np.array([[0, 11, 5], [0, 5, 1], [0, 1, 7], [0, 7, 10], [0, 10, 11],
                  [1, 5, 9], [5, 11, 4], [11, 10, 2], [10, 7, 6], [7, 1, 8],
                  [3, 9, 4], [3, 4, 2], [3, 2, 6], [3, 6, 8], [3, 8, 9],
                  [4, 9, 5], [2, 4, 11], [6, 2, 10], [8, 6, 7], [9, 8, 1]], dtype=np.int64)
    v /= np.linalg.norm(v, axis=1)[:, None]
    for _ in range(subdivisions):
        edges = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
        key = np.sort(edges, axis=1)
        uniq, inv = np.unique(key, axis=0, return_inverse=True)
        mid = v[uniq[:, 0]] + v[uniq[:, 1]]
        mid /= np.linalg.norm(mid, axis=1)[:, None]
        m = f.shape[0]
        inv = inv.ravel()
        a = inv[:m] + v.shape[0]
        b = inv[m:2 * m] + v.shape[0]
        c = inv[2 * m:] + v.shape[0]
        v = np.concatenate([v, mid])
        f = np.concatenate([np.stack([f[:, 0], a, c], 1), np.stack([f[:, 1], b, a], 1),
                            np.stack([f[:, 2], c, b], 1), np.stack([a, b, c], 1)])
    return v * radius, f


def horseshoe_profile(width_m: float = 3.0, wall_height_m: float = 1.2,
                      n: int = 64) -> NDArray[np.float64]:
    """Closed 2-D horseshoe cross-section (y, z), counter-clockwise, floor at z = 0.

    A flat floor of ``width_m``, vertical walls up to ``wall_height_m`` and a
    semicircular roof of radius width/2. Points are spaced evenly by arc length.

    Parameters
    ----------
    width_m, wall_height_m : float
        Floor width and height of the vertical walls, metres.
    n : int
        Number of points.

    Returns
    -------
    (n, 2) float64
        (y, z) in metres.
    """
    r = width_m / 2.0
    # Perimeter pieces: floor, right wall, roof arc, left wall.
    lengths = np.array([width_m, wall_height_m, np.pi * r, wall_height_m])
    s = np.linspace(0.0, lengths.sum(), n, endpoint=False)
    edges = np.cumsum(np.concatenate([[0.0], lengths]))
    y = np.empty(n)
    z = np.empty(n)
    seg = np.searchsorted(edges, s, side="right") - 1
    q = s - edges[seg]
    m0, m1, m2, m3 = (seg == k for k in range(4))
    y[m0], z[m0] = -r + q[m0], 0.0
    y[m1], z[m1] = r, q[m1]
    ang = q[m2] / r
    y[m2], z[m2] = r * np.cos(ang), wall_height_m + r * np.sin(ang)
    y[m3], z[m3] = -r, wall_height_m - q[m3]
    return np.stack([y, z], axis=1)


def sweep_profile(profile_yz: ArrayLike, length_m: float, n_along: int, *,
                  closed_ends: bool = False, roughness_m: float = 0.0,
                  correlation_m: float = 0.3, seed: int = 0) -> Mesh:
    """Sweep a closed 2-D profile along +x into a tube mesh.

    Parameters
    ----------
    profile_yz : (k, 2) float
        Closed cross-section (last point joins the first), counter-clockwise seen from +x.
    length_m : float
        Tube length; x runs from 0 to length_m.
    n_along : int
        Number of rings (>= 2).
    closed_ends : bool
        Add fan caps at both ends (watertight tube) or leave the portals open.
    roughness_m : float
        Standard deviation of a spatially correlated radial displacement (Gaussian-filtered
        white noise, correlation length ``correlation_m``) applied along the profile's
        outward normal.
    seed : int
        Seed of the roughness field.

    Returns
    -------
    vertices : (n, 3) float64
    faces : (m, 3) int64
        Wound so that normals point into the tube (towards a scanner inside).
    """
    prof = np.asarray(profile_yz, dtype=np.float64)
    k = prof.shape[0]
    x = np.linspace(0.0, length_m, n_along)
    yz = np.broadcast_to(prof, (n_along, k, 2)).copy()
    if roughness_m > 0.0:
        from scipy.ndimage import gaussian_filter

        seg = np.linalg.norm(np.roll(prof, -1, axis=0) - prof, axis=1)
        ds_around = seg.mean()
        ds_along = length_m / max(n_along - 1, 1)
        rng = np.random.default_rng(seed)
        noise = rng.standard_normal((n_along, k))
        field = gaussian_filter(noise, (correlation_m / ds_along, correlation_m / ds_around),
                                mode=("nearest", "wrap"))
        field *= roughness_m / max(field.std(), 1e-300)
        tangent = np.roll(prof, -1, axis=0) - np.roll(prof, 1, axis=0)
        normal = np.stack([tangent[:, 1], -tangent[:, 0]], axis=1)  # outward for CCW
        normal /= np.linalg.norm(normal, axis=1)[:, None]
        yz += field[:, :, None] * normal[None, :, :]
    verts = np.concatenate([np.repeat(x, k)[:, None], yz.reshape(-1, 2)], axis=1)
    i = np.arange(n_along - 1)[:, None] * k
    j = np.arange(k)[None, :]
    a = (i + j).ravel()
    b = (i + (j + 1) % k).ravel()
    c = a + k
    d = b + k
    faces = np.concatenate([np.stack([a, c, b], 1), np.stack([b, c, d], 1)])
    if closed_ends:
        n0 = verts.shape[0]
        centres = np.array([[0.0, *prof.mean(axis=0)], [length_m, *prof.mean(axis=0)]])
        verts = np.concatenate([verts, centres])
        jj = np.arange(k)
        cap0 = np.stack([np.full(k, n0), jj, (jj + 1) % k], 1)
        last = (n_along - 1) * k
        cap1 = np.stack([np.full(k, n0 + 1), last + (jj + 1) % k, last + jj], 1)
        faces = np.concatenate([faces, cap0, cap1])
    return verts, faces.astype(np.int64)


def tunnel_tube(n_triangles: int, length_m: float = 300.0, width_m: float = 3.0,
                roughness_m: float = 0.002, seed: int = 0) -> Mesh:
    """A straight horseshoe tunnel of about ``n_triangles`` triangles, open portals,
    with mm-scale correlated roughness: the benchmark and cross-check mesh.

    Parameters
    ----------
    n_triangles : int
        Wanted triangle count (the result is within a ring of it).
    length_m, width_m : float
        Tunnel length along +x and floor width, metres.
    roughness_m : float
        Standard deviation of the correlated lining roughness (0.3 m correlation).
    seed : int
        Seed of the roughness.

    Returns
    -------
    vertices : (n, 3) float64
    faces : (m, 3) int64
    """
    perimeter = width_m + 2 * 1.2 + np.pi * width_m / 2
    cell = np.sqrt(2.0 * perimeter * length_m / n_triangles)
    k = max(8, int(round(perimeter / cell)))
    n_along = max(2, int(round(n_triangles / (2 * k))) + 1)
    prof = horseshoe_profile(width_m, 1.2, k)
    return sweep_profile(prof, length_m, n_along, roughness_m=roughness_m,
                         correlation_m=0.3, seed=seed)
