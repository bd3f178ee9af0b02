"""Colour and temperature carried from coloured clouds onto a mesh's vertices (issue 35).

The clouds stream through a voxel grid with their points (``AppearanceGrid``, the grid
of ``survey.clouds.preprocess.VoxelGrid``): per voxel the sums of its points' colour in
*linear* light (sRGB decoded, IEC 61966-2-1) and of their temperatures (kelvin), with
the number of points that had each: 48 bytes a voxel more than the grid's own 40 while
the clouds stream, 24 bytes a voxel kept after (``AppearanceCloud``, float32).

Each mesh vertex then takes (``transfer_appearance``) the mean of the points of the
(at most ``NEIGHBOURS``) voxels nearest to it whose centroid lies within ``radius_m``,
every voxel weighted by its number of points with a value (so the mean is the points'
mean, whatever the grid), colour averaged in linear light and encoded back to sRGB
(a mean of encoded values is darker than the mean light: the averaging of colours
in a linear space, e.g. Poynton, *Digital Video and HD*, 2nd ed., ch. 27). A vertex
with no such voxel takes the nearest voxel's value (the fallback; counted).

Written as ``red green blue`` uint8 (sRGB, the PLY convention that
``sensors.appearance.mesh_appearance`` reads) and ``temperature`` float32 (K).
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial import cKDTree

from survey.errors import ReconstructionError

__all__ = ["NEIGHBOURS", "VERTEX_QUERY_CHUNK", "AppearanceCloud", "AppearanceGrid",
           "VertexAppearance", "appearance_fields", "appearance_radius",
           "cloud_appearances", "describe", "transfer_appearance"]

PathLike = str | os.PathLike[str]
Floats = NDArray[np.float64]

#: Most voxels (or points) averaged into one vertex: bounds the query's memory
#: (``VERTEX_QUERY_CHUNK`` x this x 16 bytes) and its time.
NEIGHBOURS = 32
#: Mesh vertices queried at once.
VERTEX_QUERY_CHUNK = 1 << 17
#: The per-point fields the grid carries: linear colour x its weight, the weight (1: the
#: point has a colour), temperature x its weight, the weight.
FIELDS = ("rgb", "rgb_n", "t", "t_n")


def _srgb_decode(x: Floats) -> Floats:
    from sensors.shading import srgb_decode

    return srgb_decode(x)


def appearance_fields(rgb: Floats | None, temperature: Floats | None, n: int,
                      colour: bool, thermal: bool) -> dict[str, Floats]:
    """The grid's per-point fields of one chunk of ``n`` points: colour (n, 3) sRGB in
    [0, 1] or None, temperature (n,) K or None; NaN is no value. Only the fields of
    ``colour`` / ``thermal`` (what any cloud of the run carries)."""
    out: dict[str, Floats] = {}
    if colour:
        if rgb is None:
            out["rgb"], out["rgb_n"] = np.zeros((n, 3)), np.zeros(n)
        else:
            ok: NDArray[np.bool_] = np.asarray(np.isfinite(rgb).all(axis=1))
            out["rgb"] = np.where(ok[:, None], _srgb_decode(np.nan_to_num(rgb)), 0.0)
            out["rgb_n"] = ok.astype(np.float64)
    if thermal:
        if temperature is None:
            out["t"], out["t_n"] = np.zeros(n), np.zeros(n)
        else:
            okt: NDArray[np.bool_] = np.asarray(np.isfinite(temperature))
            out["t"] = np.where(okt, temperature, 0.0)
            out["t_n"] = okt.astype(np.float64)
    return out


@dataclass(frozen=True)
class AppearanceCloud:
    """Reduced points with the mean colour and temperature of their points.

    DECISION: the means and counts are float32 (24 bytes a voxel with both
    attributes, held while the mesher runs): 6e-8 relative, 2e-5 K at 300 K, below the
    8-bit colour step and any thermal camera's NETD; counts are exact to 2**24 points
    a voxel. The averaging itself runs in float64.

    Attributes
    ----------
    points : (m, 3) float64, voxel centroids (or the points themselves), metres
    rgb : (m, 3) float32 or None, the mean linear colour of each one's points with one
    rgb_n : (m,) float32 or None, how many of its points had a colour (0: none)
    t : (m,) float32 or None, the mean temperature (K) of its points with one
    t_n : (m,) float32 or None, how many had a temperature
    sources : dict, per attribute ("colour", "temperature") the files and how each
        stores it, e.g. {"colour": ["a.laz: LAS RGB, 16-bit"]}
    """

    points: Floats
    rgb: NDArray[np.float32] | None
    rgb_n: NDArray[np.float32] | None
    t: NDArray[np.float32] | None
    t_n: NDArray[np.float32] | None
    sources: dict[str, list[str]] = field(default_factory=dict)

    @classmethod
    def from_means(cls, points: Floats, fields: Mapping[str, Floats],
                   counts: NDArray[np.int64] | None,
                   sources: dict[str, list[str]]) -> AppearanceCloud:
        """From ``VoxelGrid.fields()`` (per-voxel means over all points of ``FIELDS``:
        value x weight, weight) and the counts (None: one point each)."""
        c = np.ones(len(points)) if counts is None else counts.astype(np.float64)
        out: dict[str, Any] = {}
        for k in ("rgb", "t"):
            if k not in fields:
                out[k] = out[k + "_n"] = None
                continue
            v = np.asarray(fields[k], dtype=np.float64)
            w = np.asarray(fields[k + "_n"], dtype=np.float64)
            wb = w.reshape((-1,) + (1,) * (v.ndim - 1))
            out[k] = np.divide(v, wb, out=np.zeros_like(v), where=wb > 0).astype(
                np.float32)
            out[k + "_n"] = (w * c).astype(np.float32)
        return cls(np.asarray(points, dtype=np.float64), out["rgb"], out["rgb_n"],
                   out["t"], out["t_n"], sources)


def cloud_appearances(clouds: Sequence[PathLike], *, colour: bool = True,
                      temperature: bool = True) -> tuple[list[Any], dict[str, list[str]]]:
    """(``sensors.io.cloudfields.CloudAppearance`` per cloud, the sources: per
    attribute the files that carry it and how) of the clouds; ``colour`` /
    ``temperature`` False: that attribute is not looked for."""
    from sensors.io.cloudfields import CloudAppearance, cloud_appearance

    apps = []
    sources: dict[str, list[str]] = {}
    for c in clouds:
        a = cloud_appearance(c, colour=colour) if (colour or temperature) else \
            CloudAppearance(Path(c), None, None)
        a = CloudAppearance(a.path, a.colour if colour else None,
                            a.temperature if temperature else None)
        apps.append(a)
        if a.colour is not None:
            sources.setdefault("colour", []).append(f"{a.path.name}: {a.colour.how}")
        if a.temperature is not None:
            sources.setdefault("temperature", []).append(
                f"{a.path.name}: field {a.temperature!r} (K)")
    return apps, sources


class AppearanceGrid:
    """A voxel grid of points with their colour and temperature sums
    (``survey.clouds.preprocess.VoxelGrid``, Open3D's anchoring), fed by
    ``add(xyz, rgb, temperature)``; ``result()`` -> ``AppearanceCloud``."""

    def __init__(self, voxel_size_m: float, min_bound: ArrayLike, *, colour: bool,
                 temperature: bool, sources: dict[str, list[str]]) -> None:
        from survey.clouds.preprocess import VoxelGrid

        self._grid = VoxelGrid(voxel_size_m, min_bound)
        self._colour, self._thermal = colour, temperature
        self._sources = sources
        self.n_points = 0

    def add(self, xyz: Floats, rgb: Floats | None, temperature: Floats | None) -> None:
        """Accumulate a chunk: points (n, 3), colour (n, 3) sRGB [0, 1] or None,
        temperature (n,) K or None."""
        self._grid.add(xyz, appearance_fields(rgb, temperature, len(xyz), self._colour,
                                              self._thermal))
        self.n_points += len(xyz)

    def result(self) -> tuple[Floats, NDArray[np.int64], AppearanceCloud]:
        """(centroids (m, 3), counts (m,), the ``AppearanceCloud`` of the voxels); the
        grid is emptied (its sums are not kept beside the result)."""
        pts, counts = self._grid.result()
        fields = self._grid.fields()
        self._grid = None         # type: ignore[assignment]
        return pts, counts, AppearanceCloud.from_means(pts, fields, counts,
                                                        self._sources)


@dataclass(frozen=True)
class VertexAppearance:
    """Per-vertex colour and temperature of a mesh (``transfer_appearance``).

    Attributes
    ----------
    rgb : (n, 3) uint8 or None, sRGB
    temperature_k : (n,) float32 or None
    radius_m : float, the radius of the neighbourhood averaged
    neighbours : int, the most voxels (or points) averaged
    fallback : dict, per attribute the number of vertices that had no point within
        ``radius_m`` and took the nearest point's value
    """

    rgb: NDArray[np.uint8] | None
    temperature_k: NDArray[np.float32] | None
    radius_m: float
    neighbours: int
    fallback: dict[str, int]

    def vertex_fields(self) -> dict[str, np.ndarray]:
        """{"red", "green", "blue": uint8, "temperature": float32} for the PLY."""
        out: dict[str, np.ndarray] = {}
        if self.rgb is not None:
            out.update(red=self.rgb[:, 0], green=self.rgb[:, 1], blue=self.rgb[:, 2])
        if self.temperature_k is not None:
            out["temperature"] = self.temperature_k
        return out


def appearance_radius(vertices: ArrayLike, faces: ArrayLike, voxel_m: float) -> float:
    """The neighbourhood (m) a vertex's colour is averaged over: half the mesh's median
    edge length (the reach of a vertex's share of the surface), at least ``voxel_m``
    (the grid's spacing, so that a voxel is always within reach on a surface).

    DECISION: tied to the mesh's own cell (the tunnel mesher's cells, the Poisson cell,
    the decimated triangles), so that a coarser mesh averages over its larger cells
    rather than sampling the colour at one point of each."""
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    if len(f) == 0:
        return float(voxel_m) if voxel_m > 0 else 0.0
    e = np.concatenate([v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 1]],
                        v[f[:, 0]] - v[f[:, 2]]])
    return max(0.5 * float(np.median(np.linalg.norm(e, axis=1))), float(voxel_m))


def _mean_near(tree: cKDTree, means: NDArray[Any], weights: NDArray[Any], q: Floats,
               radius_m: float, k: int) -> tuple[Floats, int]:
    """Mean of ``means`` weighted by ``weights`` (points) over the (at most k) nearest
    of the tree's points within ``radius_m`` of each query; the nearest one's value
    where none is within. Returns (values (n, ...) float64, number of fallbacks)."""
    tail = means.shape[1:]
    out = np.empty((len(q),) + tail)
    fallback = 0
    kk = min(k, tree.n)
    for a in range(0, len(q), VERTEX_QUERY_CHUNK):
        qc = q[a:a + VERTEX_QUERY_CHUNK]
        d, i = tree.query(qc, k=kk, distance_upper_bound=radius_m)
        d, i = d.reshape(len(qc), kk), i.reshape(len(qc), kk)
        hit = np.isfinite(d)
        ii = np.where(hit, i, 0)
        w = np.where(hit, weights[ii].astype(np.float64), 0.0)
        wsum = w.sum(axis=1)
        num = (means[ii].astype(np.float64) * w.reshape(w.shape + (1,) * len(tail))
               ).sum(axis=1)
        ok = wsum > 0
        res = np.empty((len(qc),) + tail)
        res[ok] = num[ok] / wsum[ok].reshape((-1,) + (1,) * len(tail))
        if not ok.all():
            _, j = tree.query(qc[~ok], k=1)
            res[~ok] = means[j]
            fallback += int((~ok).sum())
        out[a:a + len(qc)] = res
    return out, fallback


def transfer_appearance(cloud: AppearanceCloud, vertices: ArrayLike, radius_m: float,
                        *, neighbours: int = NEIGHBOURS) -> VertexAppearance:
    """Colour and temperature of each mesh vertex from a reduced cloud (module doc).

    Parameters
    ----------
    cloud : AppearanceCloud
    vertices : (n, 3) float64
        Mesh vertices (m), in the cloud's coordinates (UTM-sized ones too: the search
        runs about a local origin).
    radius_m : float
        Points within this of a vertex are averaged (``appearance_radius``).
    neighbours : int
        At most this many nearest voxels (points) are averaged.

    Returns
    -------
    VertexAppearance
        None for an attribute no point of the cloud has.
    """
    v = np.asarray(vertices, dtype=np.float64).reshape(-1, 3)
    if not (np.isfinite(radius_m) and radius_m > 0):
        raise ReconstructionError(f"Expected a positive radius for the colour transfer, "
                                  f"got {radius_m!r}.")
    origin = np.round(cloud.points.mean(axis=0)) if len(cloud.points) else np.zeros(3)
    fallback: dict[str, int] = {}
    results: dict[str, Floats | None] = {"colour": None, "temperature": None}
    tree, tree_has = None, None
    for what, means, n in (("colour", cloud.rgb, cloud.rgb_n),
                           ("temperature", cloud.t, cloud.t_n)):
        if means is None or n is None:
            continue
        has = n > 0
        if not has.any():
            continue
        every = bool(has.all())
        if tree is None or tree_has is None or not np.array_equal(has, tree_has):
            # one tree for both attributes when the same points carry them
            tree = None
            tree = cKDTree(cloud.points - origin if every else cloud.points[has] - origin)
            tree_has = has
        vals, fb = _mean_near(tree, means if every else means[has],
                              n if every else n[has], v - origin, radius_m,
                              int(neighbours))
        results[what] = vals
        fallback[what] = fb
    rgb = None
    if results["colour"] is not None:
        from sensors.shading import srgb_encode

        rgb = np.rint(srgb_encode(results["colour"]) * 255.0).astype(np.uint8)
    t = results["temperature"]
    return VertexAppearance(rgb, None if t is None else t.astype(np.float32),
                            float(radius_m), int(neighbours), fallback)


def describe(app: VertexAppearance | None, sources: Mapping[str, Iterable[str]],
             left_out: Mapping[str, bool]) -> dict[str, Any]:
    """The "appearance" block of the mesh's report: per attribute where it came from
    (the files and how they store it), how many vertices fell back to the nearest
    point, or why the mesh has none."""
    block: dict[str, Any] = {}
    for what, opt in (("colour", "--no-colour"), ("temperature", "--no-temperature")):
        have = app is not None and (app.rgb if what == "colour" else
                                    app.temperature_k) is not None
        if left_out.get(what):
            block[what] = {"written": False, "why": f"left out by {opt}"}
        elif not have:
            block[what] = {"written": False, "why": "the clouds carry none"}
        else:
            assert app is not None
            block[what] = {"written": True, "sources": list(sources.get(what, [])),
                           "fallback_vertices": int(app.fallback.get(what, 0))}
    if app is not None:
        block.update(radius_m=app.radius_m, neighbours=app.neighbours)
    return block
