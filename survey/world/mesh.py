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
deformation fields: enough to rebuild the ``TunnelMesh``. Both files are written
atomically.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from raytrace.fileio import atomic_writer
from dataclasses import dataclass, field
from survey.errors import TunnelError, TunnelFileError
from survey.world import deformation as _deform
from survey.world.alignment import Alignment
from survey.world.profiles import Profile

FORMAT = "tunnelsim-tunnel/1"

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


@dataclass
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
        points, deformations)
    displacement : (n, 3) float64 or None, displacement from the undeformed epoch
    """

    vertices: np.ndarray
    faces: np.ndarray
    labels: np.ndarray
    vertex_chainage: np.ndarray
    vertex_param: np.ndarray
    alignment: Alignment
    profile: Profile
    metadata: dict = field(default_factory=dict)
    displacement: np.ndarray | None = None

    @property
    def reflectivity(self) -> np.ndarray:
        """(m,) float32 reflectivity of each face from the metadata's label table."""
        table = self.metadata.get("reflectivity", REFLECTIVITY)
        return np.array([table[n] for n in LABELS], dtype=np.float32)[self.labels]

    def lining_normals(self) -> np.ndarray:
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

    def deformed(self, deformations) -> "TunnelMesh":
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

    def write(self, path):
        """Write ``path`` (binary PLY with face labels and reflectivity) and the
        metadata beside it (same name, .json); both atomically. Returns the paths."""
        from survey.world.mesh import write_tunnel

        return write_tunnel(self, path)


def _moved_control_points(points, deformations, profile):
    out = []
    for p in points:
        q = dict(p)
        f = _deform.total_field(deformations, np.array([p["chainage_m"]]),
                                np.array([p["profile_t_m"]]), profile)[0]
        n = np.asarray(p["lining_normal"])
        q["xyz"] = (np.asarray(p["xyz"]) - f * n).tolist()
        out.append(q)
    return out


def _face_dtype():
    return np.dtype([("n", "u1"), ("v", "<i4", (3,)), ("label", "u1"),
                     ("reflectivity", "<f4")])


def write_ply(path, vertices, faces, labels=None, reflectivity=None, displacement=None,
              vertex_fields=None):
    """Binary little-endian PLY with float64 vertices, optional per-face ``label``
    (uint8) and ``reflectivity`` (float32), per-vertex displacement ``dx dy dz`` and
    other per-vertex scalars ``vertex_fields`` {name: (n,) float64 array}."""
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces)
    if v.ndim != 2 or v.shape[1] != 3 or f.ndim != 2 or f.shape[1] != 3:
        raise TunnelFileError(f"Expected vertices (n, 3) and faces (m, 3), got {v.shape} "
                              f"and {f.shape}.")
    if len(v) >= 2**31:
        raise TunnelFileError(f"Expected fewer than 2**31 vertices for PLY int indices, "
                              f"got {len(v)}.")
    vfields = [("x", "<f8"), ("y", "<f8"), ("z", "<f8")]
    if displacement is not None:
        vfields += [("dx", "<f4"), ("dy", "<f4"), ("dz", "<f4")]
    vertex_fields = vertex_fields or {}
    vfields += [(name, "<f8") for name in vertex_fields]
    vrec = np.empty(len(v), dtype=vfields)
    vrec["x"], vrec["y"], vrec["z"] = v.T
    if displacement is not None:
        d = np.asarray(displacement, dtype=np.float64)
        vrec["dx"], vrec["dy"], vrec["dz"] = d.T
    for name, arr in vertex_fields.items():
        vrec[name] = arr
    ffields = [("n", "u1"), ("v", "<i4", (3,))]
    if labels is not None:
        ffields.append(("label", "u1"))
    if reflectivity is not None:
        ffields.append(("reflectivity", "<f4"))
    frec = np.empty(len(f), dtype=ffields)
    frec["n"] = 3
    frec["v"] = f
    if labels is not None:
        frec["label"] = labels
    if reflectivity is not None:
        frec["reflectivity"] = reflectivity
    names = {"<f8": "double", "<f4": "float", "u1": "uchar"}
    head = ["ply", "format binary_little_endian 1.0", "comment written by tunnelsim",
            f"element vertex {len(v)}"]
    head += [f"property {names[t]} {n}" for n, t in vfields]
    head += [f"element face {len(f)}", "property list uchar int vertex_indices"]
    head += [f"property {names[t]} {n}" for n, t, *_ in ffields[2:]]
    head.append("end_header")
    with atomic_writer(path) as fh:
        fh.write(("\n".join(head) + "\n").encode("ascii"))
        # Chunked writes keep the temporary copies small for multi-million meshes.
        for arr in (vrec, frec):
            step = 1 << 20
            for i in range(0, len(arr), step):
                fh.write(arr[i:i + step].tobytes())
    return Path(path)


_PLY_TYPES = {"char": "i1", "uchar": "u1", "short": "<i2", "ushort": "<u2", "int": "<i4",
              "uint": "<u4", "float": "<f4", "double": "<f8", "int8": "i1", "uint8": "u1",
              "int16": "<i2", "uint16": "<u2", "int32": "<i4", "uint32": "<u4",
              "float32": "<f4", "float64": "<f8"}


def read_ply(path):
    """Read a binary little-endian triangle PLY (as written by ``write_ply``).

    Returns a dict with ``vertices`` (n, 3) float64, ``faces`` (m, 3) int64 and any
    extra vertex/face properties by name. Other PLY files: use trimesh.
    """
    path = Path(path)
    if not path.is_file():
        raise TunnelFileError(f"Expected a PLY file, got '{path}' which does not exist.")
    with open(path, "rb") as fh:
        if fh.readline().strip() != b"ply":
            raise TunnelFileError(f"Expected a PLY file, got '{path}' without the 'ply' "
                                  "magic line.")
        elements, props = [], {}
        fmt = None
        while True:
            line = fh.readline()
            if not line:
                raise TunnelFileError(f"Expected 'end_header' in '{path}', got end of file.")
            words = line.decode("ascii", "replace").split()
            if not words or words[0] in ("comment", "obj_info"):
                continue
            if words[0] == "format":
                fmt = words[1]
            elif words[0] == "element":
                elements.append((words[1], int(words[2])))
                props[words[1]] = []
            elif words[0] == "property":
                props[elements[-1][0]].append(words[1:])
            elif words[0] == "end_header":
                break
        if fmt != "binary_little_endian":
            raise TunnelFileError(f"Expected a binary little-endian PLY, got format {fmt} "
                                  f"in '{path}'; read it with trimesh.")
        out = {}
        for name, count in elements:
            fields = []
            for p in props[name]:
                if p[0] == "list":
                    if _PLY_TYPES[p[1]] != "u1":
                        raise TunnelFileError("Expected face lists with uchar counts.")
                    fields += [("_n", "u1"), ("_v", _PLY_TYPES[p[2]], (3,))]
                else:
                    fields.append((p[1], _PLY_TYPES[p[0]]))
            rec = np.frombuffer(fh.read(np.dtype(fields).itemsize * count),
                                dtype=fields, count=count)
            if name == "face":
                if (rec["_n"] != 3).any():
                    raise TunnelFileError(f"Expected triangles only in '{path}'.")
                out["faces"] = rec["_v"].astype(np.int64)
            if name == "vertex":
                out["vertices"] = np.stack([rec["x"], rec["y"], rec["z"]], 1).astype(float)
            for fname in rec.dtype.names:
                if not fname.startswith("_") and fname not in ("x", "y", "z"):
                    out[fname] = rec[fname].copy()
    return out


def sidecar(path) -> Path:
    return Path(path).with_suffix(".json")


def write_tunnel(tunnel, path):
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
    with atomic_writer(sidecar(path), "w") as fh:
        json.dump(meta, fh, indent=1)
    return path, sidecar(path)


def read_tunnel(path):
    """Read a tunnel written by ``write_tunnel`` back into a ``TunnelMesh``."""
    from survey.world.alignment import Alignment
    from survey.world.profiles import Profile
    from survey.world.mesh import TunnelMesh

    path = Path(path)
    js = sidecar(path)
    if not js.is_file():
        raise TunnelFileError(f"Expected the metadata file '{js}' beside '{path}', got "
                              "none; write tunnels with TunnelMesh.write.")
    meta = json.loads(js.read_text())
    if meta.get("format") != FORMAT:
        raise TunnelFileError(f"Expected format {FORMAT!r} in '{js}', got "
                              f"{meta.get('format')!r}.")
    ply = read_ply(path)
    al = Alignment.from_dict(meta["alignment"])
    prof = Profile.from_dict(meta["profile"])
    disp = None
    if "dx" in ply:
        disp = np.stack([ply["dx"], ply["dy"], ply["dz"]], 1).astype(np.float64)
    return TunnelMesh(ply["vertices"], ply["faces"], ply["label"].astype(np.uint8),
                      ply["chainage"], ply["profile_t"], al, prof, meta, disp)


def read_axis(json_path):
    """(Alignment, profile-centre height) from a generated tunnel's JSON."""
    from survey.world.alignment import Alignment
    from survey.world.profiles import Profile

    js = Path(json_path)
    if not js.is_file():
        raise TunnelFileError(f"Expected a tunnel JSON, got '{js}' which does not exist.")
    meta = json.loads(js.read_text())
    if "alignment" not in meta or "profile" not in meta:
        raise TunnelFileError(f"Expected 'alignment' and 'profile' in '{js}' (a JSON "
                              "written by 'tunnelsim tunnel'), got neither.")
    return (Alignment.from_dict(meta["alignment"]),
            float(Profile.from_dict(meta["profile"]).centroid[1]))


