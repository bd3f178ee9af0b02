"""Tunnel files: a binary PLY mesh plus a JSON sidecar with everything else.

PLY (Turk 1994 format, binary little endian) as CloudCompare, MeshLab, Open3D and
trimesh read it:

- ``vertex``: ``double x, y, z`` (float64: georeferenced coordinates keep their
  precision); for a deformed epoch ``float dx, dy, dz`` (the displacement from the
  first epoch, metres); ``double chainage, profile_t`` (the chainage and profile
  parameter of the lining point the vertex is or is attached to, NaN for cap centres).
  CloudCompare shows all of them as scalar fields.
- ``face``: ``list uchar int vertex_indices``, ``uchar label`` (index into the JSON's
  ``labels``) and ``float reflectivity`` (0-1, from the label table).

The JSON beside it (same name, ``.json``) holds the alignment, profile, features,
parameters, label names, reflectivity table, face counts, control points and the
deformation fields: enough to rebuild the ``TunnelMesh``; with a coordinate reference
system (``TunnelMesh.with_crs``), ``crs`` (WKT2:2019, ``sensors.io.crs.crs_wkt``) and
``crs_name`` (e.g. "EPSG:2056 (CH1903+ / LV95)"), which scans of the tunnel state in
their files. Both files are written atomically.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from numpy.typing import ArrayLike, NDArray

from raytrace.fileio import write_json
from sensors.io.errors import TunnelFileError
from sensors.io.meshes import read_mesh, write_mesh
from survey.errors import TunnelError, TunnelsimError
from survey.world import deformation as _deform
from survey.world.alignment import Alignment
from survey.world.profiles import Profile
from sensors.io.tunnel_json import FORMAT, read_meta, sidecar, tunnel_crs

__all__ = ["LABEL", "LABELS", "REFLECTIVITY", "TunnelMesh", "read_axis",
           "read_tunnel", "write_ply",
           "write_tunnel"]


#: Face labels (uint8 PLY face property ``label``) and their names.
LABELS = ("lining", "floor", "wet_floor", "drainage", "niche", "cable", "bolt", "prism",
          "end_cap")


LABEL = {name: i for i, name in enumerate(LABELS)}


#: Default diffuse reflectivity per label at near-infrared laser wavelengths (0-1).
#: ASSUMED values, typical of published material reflectances near 905-1550 nm:
#: dry concrete/shotcrete 0.3-0.5 (e.g. Kashani et al. 2015, "A review of LiDAR
#: radiometric processing", Sensors 15), wet surfaces markedly darker (water absorbs
#: in the NIR; Kaasalainen et al. 2011 measured strong intensity drops with moisture),
#: black PVC cable sheaths ~0.05-0.1, galvanised steel plates ~0.5. Prisms are
#: retro-reflectors; 0.9 stands in for their very strong return.
REFLECTIVITY = {"lining": 0.4, "floor": 0.3, "wet_floor": 0.1, "drainage": 0.15,
                "niche": 0.4, "cable": 0.06, "bolt": 0.5, "prism": 0.9, "end_cap": 0.3}


@dataclass(repr=False)
class TunnelMesh:
    """A generated tunnel: triangle mesh, per-face labels and the data behind them.

    Attributes
    ----------
    vertices : (n, 3) float64 world coordinates
    faces : (m, 3) int64
    labels : (m,) uint8, indices into ``LABELS``
    vertex_chainage : (n,) float64, chainage of the vertex (lining) or of the lining
        point it is attached to (features)
    vertex_param : (n,) float64, profile parameter t of the same; NaN for end-cap
        centres (which do not deform)
    alignment, profile : the geometry it was built from
    metadata : dict, JSON-ready description (parameters, features, counts, control
        points, deformations; ``crs`` and ``crs_name`` when georeferenced)
    displacement : (n, 3) float64 or None, displacement from the undeformed epoch (m)

    Notes
    -----
    Coordinates, chainages and profile parameters are metres. ``repr`` is one line.
    """

    vertices: NDArray[np.float64]
    faces: NDArray[np.int64]
    labels: NDArray[np.uint8]
    vertex_chainage: NDArray[np.float64]
    vertex_param: NDArray[np.float64]
    alignment: Alignment
    profile: Profile
    metadata: dict[str, Any] = field(default_factory=dict)
    displacement: NDArray[np.float64] | None = None

    def __repr__(self) -> str:
        name = self.metadata.get("name")
        labels = len(np.unique(self.labels))
        return (f"TunnelMesh({name + ': ' if name else ''}{len(self.faces):,} triangles, "
                f"{len(self.vertices):,} vertices, {self.alignment.length_m:.1f} m, "
                f"{self.profile.name}, {labels} label{'s' if labels != 1 else ''}"
                + (", deformed" if self.displacement is not None else "") + ")")

    @property
    def crs(self) -> str | None:
        """The coordinate reference system of the vertices (WKT2), or None (local)."""
        return tunnel_crs(self.metadata)

    def with_crs(self, crs: Any) -> TunnelMesh:
        """The same tunnel stating its coordinates' CRS ``crs`` (EPSG:n, WKT or
        PROJJSON, metre axes; needs pyproj), or none (``crs`` None). The vertices are
        not moved: the CRS says what they already are."""
        from dataclasses import replace

        from sensors.io.crs import crs_label, crs_wkt, parse_crs

        meta = {k: v for k, v in self.metadata.items() if k not in ("crs", "crs_name")}
        if crs is not None:
            c = parse_crs(crs, what="the tunnel's CRS")
            meta.update(crs=crs_wkt(c), crs_name=crs_label(c))
        return replace(self, metadata=meta)

    @property
    def reflectivity(self) -> NDArray[np.float32]:
        """(m,) float32 reflectivity of each face from the metadata's label table."""
        table = self.metadata.get("reflectivity", REFLECTIVITY)
        return np.array([table[n] for n in LABELS], dtype=np.float32)[self.labels]

    def lining_normals(self) -> NDArray[np.float64]:
        """(n, 3) outward (into the rock) unit normal of the lining point each vertex
        belongs or is attached to; zero where it has none."""
        ok = np.isfinite(self.vertex_param)
        out = np.zeros((len(self.vertices), 3))
        if ok.any():
            n2 = self.profile.normals(self.vertex_param[ok])
            th = self.alignment.heading(self.vertex_chainage[ok])
            out[ok, 0] = -n2[:, 0] * np.sin(th)
            out[ok, 1] = n2[:, 0] * np.cos(th)
            out[ok, 2] = n2[:, 1]
        return out

    def deformed(self, deformations: Iterable[_deform.Deformation]) -> TunnelMesh:
        """A second epoch: every vertex moved by the sum of the deformation fields
        along the inward lining normal of its (attachment) point. The displacement is
        kept in ``displacement`` and the fields in ``metadata['deformation']``."""
        deformations = list(deformations)
        for d in deformations:
            if type(d) not in _deform.KINDS.values():
                raise TunnelError(f"Expected Convergence, Ovalisation or Bulge objects, "
                                  f"got {type(d).__name__}.")
        f = _deform.total_field(deformations, self.vertex_chainage, self.vertex_param,
                                self.profile)
        disp = -f[:, None] * self.lining_normals()
        meta = dict(self.metadata)
        meta["deformation"] = [_deform.to_dict(d) for d in deformations]
        meta["displacement_max_m"] = float(np.abs(f).max(initial=0.0))
        meta["control_points"] = _moved_control_points(meta.get("control_points", []),
                                                       deformations, self.profile)
        return TunnelMesh(self.vertices + disp, self.faces, self.labels,
                          self.vertex_chainage, self.vertex_param, self.alignment,
                          self.profile, meta, disp)

    def write(self, path: str | Path) -> tuple[Path, Path]:
        """Write ``path`` (binary PLY with face labels and reflectivity) and the
        metadata beside it (same name, .json); both atomically. Returns the paths."""
        return write_tunnel(self, path)


def _moved_control_points(points: Sequence[Mapping[str, Any]],
                          deformations: Sequence[_deform.Deformation], profile: Profile
                          ) -> list[dict[str, Any]]:
    out = []
    for p in points:
        q = dict(p)
        f = _deform.total_field(deformations, np.array([p["chainage_m"]]),
                                np.array([p["profile_t_m"]]), profile)[0]
        n = np.asarray(p["lining_normal"])
        q["xyz"] = (np.asarray(p["xyz"]) - f * n).tolist()
        out.append(q)
    return out


def write_ply(path: str | os.PathLike[str], vertices: ArrayLike, faces: ArrayLike,
              labels: ArrayLike | None = None, reflectivity: ArrayLike | None = None,
              displacement: ArrayLike | None = None,
              vertex_fields: Mapping[str, ArrayLike] | None = None) -> Path:
    """A tunnel's binary little-endian PLY: float64 vertices, optional per-face
    ``label`` (uint8) and ``reflectivity`` (float32), per-vertex displacement
    ``dx dy dz`` (float32) and other per-vertex scalars ``vertex_fields`` {name: (n,)
    float64 array}; written atomically by ``sensors.io.meshes.write_mesh``, read back by
    ``sensors.io.meshes.read_mesh``."""
    v = np.asarray(vertices, dtype=np.float64)
    vf: dict[str, np.ndarray] = {}
    if displacement is not None:
        d = np.asarray(displacement, dtype=np.float64).reshape(-1, 3)
        vf.update(dx=d[:, 0].astype("<f4"), dy=d[:, 1].astype("<f4"),
                  dz=d[:, 2].astype("<f4"))
    for name, arr in (vertex_fields or {}).items():
        vf[name] = np.asarray(arr, dtype="<f8")
    ff: dict[str, np.ndarray] = {}
    if labels is not None:
        ff["label"] = np.asarray(labels).astype("u1")
    if reflectivity is not None:
        ff["reflectivity"] = np.asarray(reflectivity).astype("<f4")
    return write_mesh(path, v, np.asarray(faces), vertex_fields=vf, face_fields=ff,
                      comments=("written by tunnelsim",))


def write_tunnel(tunnel: TunnelMesh, path: str | Path) -> tuple[Path, Path]:
    """Write the tunnel's PLY and JSON sidecar (atomically); returns both paths."""
    path = Path(path)
    if path.suffix.lower() != ".ply":
        raise TunnelFileError(f"Expected an output path ending in .ply, got '{path}'.")
    if not path.parent.exists():
        raise TunnelFileError(f"Expected an existing output folder, got '{path.parent}'; "
                              "create it first.")
    write_ply(path, tunnel.vertices, tunnel.faces, tunnel.labels, tunnel.reflectivity,
              tunnel.displacement, {"chainage": tunnel.vertex_chainage,
                                    "profile_t": tunnel.vertex_param})
    meta = dict(tunnel.metadata, format=FORMAT, mesh=path.name)
    write_json(sidecar(path), meta, indent=1)
    return path, sidecar(path)


def _geometry(meta: dict[str, Any], js: Path) -> tuple[Alignment, Profile]:
    """The alignment and profile a tunnel JSON describes."""
    if not isinstance(meta.get("alignment"), dict) or not isinstance(meta.get("profile"), dict):
        raise TunnelFileError(f"Expected 'alignment' and 'profile' objects in '{js}' (a JSON "
                              "written by 'tunnelsim tunnel'), got "
                              f"{sorted(k for k in ('alignment', 'profile') if k in meta)}.")
    try:
        return Alignment.from_dict(meta["alignment"]), Profile.from_dict(meta["profile"])
    except TunnelsimError:
        raise
    except (KeyError, TypeError, ValueError, IndexError) as exc:
        raise TunnelFileError(f"Expected a valid alignment and profile in '{js}', got "
                              f"{type(exc).__name__}: {exc}; rewrite it with 'tunnelsim "
                              "tunnel'.") from None


def read_tunnel(path: str | Path) -> TunnelMesh:
    """Read a tunnel written by ``write_tunnel`` back into a ``TunnelMesh``."""
    path = Path(path)
    js = sidecar(path)
    if not js.is_file():
        raise TunnelFileError(f"Expected the metadata file '{js}' beside '{path}', got "
                              "none; write tunnels with TunnelMesh.write.")
    meta = read_meta(js)
    if meta.get("format") != FORMAT:
        raise TunnelFileError(f"Expected format {FORMAT!r} in '{js}', got "
                              f"{meta.get('format')!r}.")
    mesh = read_mesh(path)
    ply = {**mesh.vertex_fields, **mesh.face_fields}
    missing = [k for k in ("label", "chainage", "profile_t") if k not in ply]
    if missing:
        raise TunnelFileError(f"Expected the tunnel PLY properties label, chainage and "
                              f"profile_t in '{path}', got no {', '.join(missing)}; it is "
                              "not a tunnelsim tunnel (or it is damaged).")
    al, prof = _geometry(meta, js)
    disp = None
    if "dx" in ply:
        disp = np.stack([ply["dx"], ply["dy"], ply["dz"]], 1).astype(np.float64)
    return TunnelMesh(mesh.vertices, mesh.faces, ply["label"].astype(np.uint8),
                      ply["chainage"], ply["profile_t"], al, prof, meta, disp)


def read_axis(json_path: str | Path, option: str = "--tunnel-json"
              ) -> tuple[Alignment, float]:
    """(Alignment, profile-centre height in m) from a tunnel JSON (``tunnelsim tunnel``
    or ``tunnelsim axis``), a LandXML alignment or a chainage,E,N,H CSV
    (``survey.world.alignment_io.load_tunnel``; ``option`` names the option in errors).
    Without a profile (LandXML, CSV) the alignment is the axis: height 0."""
    from survey.world.alignment_io import load_tunnel

    t = load_tunnel(json_path, option=option)
    return t.alignment, float(t.centre[1])


