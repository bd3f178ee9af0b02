"""What a surface looks like to a camera: diffuse albedo (linear RGB), temperature and
thermal emissivity, per vertex or per face of a mesh, and their values at each pixel
of a rendered frame (interpolated with the hit's barycentric coordinates).

Where the values come from, in this order, for each of the three attributes:

1. Vertex properties of the mesh file (``sensors.io.meshes.read_mesh``'s
   ``vertex_fields``): ``red green blue`` (uint8, the PLY convention: sRGB-encoded,
   linearised here by IEC 61966-2-1), ``temperature`` (kelvin) and ``emissivity``
   (0-1), interpolated across each triangle.
2. The face property ``label`` (the tunnel generator's: an index into the label names
   of ``survey.world.mesh.LABELS``, passed in as ``label_names``) and the material
   table ``MATERIALS`` below: one value per face.
3. ``DEFAULT_MATERIAL`` (grey; ASSUMED) for everything else.

Every number of the table is sourced or marked ASSUMED. Visible albedo of a Lambertian
surface (0-1, linear RGB); temperature (K) of a tunnel's surfaces; emissivity in the
8-14 um band of an LWIR camera.

>>> import numpy as np
>>> from sensors.io.meshes import MeshData
>>> m = MeshData(np.zeros((3, 3)), np.array([[0, 1, 2]]),
...              face_fields={"label": np.array([5], dtype=np.uint8)})
>>> app = mesh_appearance(m, label_names=("lining", "floor", "wet_floor", "drainage",
...                                       "niche", "cable"))
>>> app.source["albedo"], app.temperature_k.values.tolist()
('label', [298.15])
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Final

import numpy as np
from numpy.typing import NDArray

from .errors import SimulationError
from .io.meshes import MeshData
from .render import Frame
from .shading import srgb_decode

__all__ = ["DEFAULT_MATERIAL", "MATERIALS", "ROCK_K", "Appearance", "Attribute", "Material",
           "PixelAppearance", "mesh_appearance"]


@dataclass(frozen=True)
class Material:
    """One surface material: what a camera sees of it.

    Attributes
    ----------
    albedo_rgb : (float, float, float)
        Diffuse (Lambertian) albedo per colour channel, linear, 0-1.
    temperature_k : float
        Surface temperature (kelvin).
    emissivity : float
        Emissivity in the long-wave infrared (8-14 um), 0-1.
    retroreflective : bool
        Retro-reflective sheeting on top of the diffuse albedo: the surface returns
        the light of a lamp towards it with ``sensors.shading.RETRO_RA_WHITE``'s
        coefficient of retroreflection (``sensors.shading.luminance``).
    """

    albedo_rgb: tuple[float, float, float]
    temperature_k: float
    emissivity: float
    retroreflective: bool = False

    def __post_init__(self) -> None:
        a = self.albedo_rgb
        if len(a) != 3 or not all(0.0 <= x <= 1.0 for x in a):
            raise SimulationError(f"Expected an albedo of 3 values in [0, 1], got {a}.")
        if not (self.temperature_k > 0 and math.isfinite(self.temperature_k)):
            raise SimulationError(f"Expected a temperature > 0 K, got {self.temperature_k}.")
        if not 0.0 <= self.emissivity <= 1.0:
            raise SimulationError(f"Expected an emissivity in [0, 1], got {self.emissivity}.")
        if not isinstance(self.retroreflective, bool):
            raise SimulationError(f"Expected retroreflective as true or false, got "
                                  f"{self.retroreflective!r}.")


#: Rock temperature of a shallow tunnel: the mean annual surface temperature (about
#: 10 degC in central Europe) plus the continental geothermal gradient (25-30 K/km;
#: e.g. Clauser & Huenges 1995, "Thermal conductivity of rocks and minerals", AGU
#: Reference Shelf 3) over ~100 m of cover: about 13 degC. ASSUMED overburden; a
#: ventilated tunnel's lining is near this in steady state.
ROCK_K: Final = 286.15

#: The material of each face label of ``survey.world.mesh.LABELS``.
#:
#: Albedo (visible, linear RGB): weathered, dusty grey concrete and shotcrete 0.25-0.35
#: (Levinson & Akbari 2002, "Effects of composition and exposure on the solar
#: reflectance of portland cement concrete", Cem. Concr. Res. 32: new concrete
#: 0.41-0.77, soiling and weathering lower it; ASSUMED 0.30 in a dusty tunnel); a
#: wet surface about half as bright as dry (Lekner & Dorf 1988, "Why some things are
#: darker when wet", Appl. Opt. 27(7)); black polymer cable sheaths ~0.05 (carbon
#: black; ASSUMED); galvanised steel bolt plates ~0.5 (ASSUMED, a metal taken as
#: diffuse). Prisms are retro-reflective (``Material.retroreflective``, as a sign's
#: sheeting would be: the light a lamp beside the camera sends back,
#: ``sensors.shading.RETRO_RA_WHITE``, white high-intensity sheeting, ASTM D4956
#: Type III) on a diffuse albedo of 0.27, white
#: sheeting's daytime luminance factor (ASTM D4956's minimum Y for white, 27 %;
#: ASSUMED, not found in a source here). A monitoring prism is glass cube corners in a
#: housing: taken as that sheeting (ASSUMED; a glass prism returns more light in a
#: narrower cone). Floor (ballast, dirt) a little darker and browner than the lining
#: (ASSUMED).
#:
#: Temperature: rock and lining at ``ROCK_K``; wet surfaces 1 K cooler (evaporation;
#: ASSUMED); a niche 2 K warmer (equipment; ASSUMED); power cables' sheaths at 25 degC
#: (ASSUMED: loaded cables run warm, IEC 60502-2 allows 90 degC at the conductor).
#:
#: Emissivity (8-14 um): concrete 0.94, rock 0.93 (Incropera et al., *Fundamentals of
#: Heat and Mass Transfer*, 6th ed., table A.11: concrete 0.88-0.93; the 8-14 um
#: tables of radiometer makers give 0.93-0.95); water 0.96 (ibid.); PVC/PE 0.92
#: (ASSUMED from the same tables' plastics 0.9-0.95); weathered galvanised steel 0.28
#: (ibid.); glass 0.92 (ibid., the prism's face).
MATERIALS: Final[Mapping[str, Material]] = {
    "lining": Material((0.31, 0.30, 0.28), ROCK_K, 0.94),
    "floor": Material((0.24, 0.22, 0.19), ROCK_K, 0.94),
    "wet_floor": Material((0.12, 0.11, 0.10), ROCK_K - 1.0, 0.96),
    "drainage": Material((0.12, 0.12, 0.11), ROCK_K - 1.0, 0.96),
    "niche": Material((0.31, 0.30, 0.28), ROCK_K + 2.0, 0.94),
    "cable": Material((0.05, 0.05, 0.05), 298.15, 0.92),
    "bolt": Material((0.50, 0.50, 0.52), ROCK_K, 0.28),
    "prism": Material((0.27, 0.27, 0.27), ROCK_K, 0.92, retroreflective=True),
    "end_cap": Material((0.31, 0.30, 0.28), ROCK_K, 0.93),
}

#: A surface the file says nothing about: mid grey at 15 degC, emissivity 0.95
#: (ASSUMED; 15 degC is the ICAO standard atmosphere's sea-level temperature).
DEFAULT_MATERIAL: Final = Material((0.3, 0.3, 0.3), 288.15, 0.95)


@dataclass(frozen=True)
class Attribute:
    """One attribute over a mesh: ``values`` (k, ...) per vertex (``per`` = "vertex",
    k = number of vertices, interpolated across each triangle) or per face
    (``per`` = "face", k = number of faces, constant on the face)."""

    values: NDArray[np.float64]
    per: str

    def at(self, frame: Frame, faces: NDArray[np.int64]) -> NDArray[np.float64]:
        """The attribute at each pixel of ``frame`` (h, w, ...) float64; NaN on a miss.

        Vertex values are interpolated with the hit's barycentric coordinates
        (``Frame.bary_u``, ``bary_v``): (1 - u - v) a0 + u a1 + v a2."""
        tri = frame.triangle
        hit = tri >= 0
        tail = self.values.shape[1:]
        out = np.full(tri.shape + tail, np.nan)
        t = tri[hit]
        if self.per == "face":
            out[hit] = self.values[t]
            return out
        f = faces[t]
        u, v = frame.bary_u[hit], frame.bary_v[hit]
        shape = (-1,) + (1,) * len(tail)
        out[hit] = ((1.0 - u - v).reshape(shape) * self.values[f[:, 0]]
                    + u.reshape(shape) * self.values[f[:, 1]]
                    + v.reshape(shape) * self.values[f[:, 2]])
        return out


@dataclass(frozen=True)
class PixelAppearance:
    """The appearance at each pixel of a frame; NaN where the pixel's ray misses.

    Attributes
    ----------
    albedo : (h, w, 3) float64
        Linear RGB albedo.
    temperature_k : (h, w) float64
    emissivity : (h, w) float64
    retroreflective : (h, w) bool or None
        The pixel's surface is retro-reflective (False on a miss); None: no surface
        of the mesh is.
    """

    albedo: NDArray[np.float64]
    temperature_k: NDArray[np.float64]
    emissivity: NDArray[np.float64]
    retroreflective: NDArray[np.bool_] | None = None


@dataclass(frozen=True)
class Appearance:
    """Albedo, temperature and emissivity over a mesh, and where each came from.

    Attributes
    ----------
    albedo : Attribute
        (k, 3) linear RGB in [0, 1].
    temperature_k : Attribute
        (k,) kelvin.
    emissivity : Attribute
        (k,) in [0, 1].
    faces : (m, 3) int64
        The mesh's faces (for the interpolation of vertex values).
    source : dict of str to str
        For "albedo", "temperature" and "emissivity": "vertex" (the file's vertex
        properties), "label" (the face labels and ``MATERIALS``) or "default".
    retroreflective : Attribute or None
        (m,) per face, 1.0 where the face's material is retro-reflective; None when
        no face's is.
    """

    albedo: Attribute
    temperature_k: Attribute
    emissivity: Attribute
    faces: NDArray[np.int64]
    source: dict[str, str] = field(default_factory=dict)
    retroreflective: Attribute | None = None

    def at(self, frame: Frame) -> PixelAppearance:
        """The appearance at each pixel of ``frame`` rendered from this mesh."""
        retro = None
        if self.retroreflective is not None:
            retro = self.retroreflective.at(frame, self.faces) > 0.5   # NaN (miss): False
        return PixelAppearance(self.albedo.at(frame, self.faces),
                               self.temperature_k.at(frame, self.faces),
                               self.emissivity.at(frame, self.faces), retro)


def _vertex_colour(fields: Mapping[str, np.ndarray]) -> NDArray[np.float64] | None:
    if not all(k in fields for k in ("red", "green", "blue")):
        return None
    rgb = np.stack([np.asarray(fields[k]) for k in ("red", "green", "blue")], axis=1)
    # DECISION: integer colours are 0-255 (PLY's uchar convention, 16-bit ones 0-65535);
    # float colours are taken as 0-1. Both sRGB-encoded, as cameras and scanners store them.
    if np.issubdtype(rgb.dtype, np.integer):
        scale = 65535.0 if rgb.max(initial=0) > 255 else 255.0
        rgb = rgb.astype(np.float64) / scale
    return srgb_decode(rgb.astype(np.float64))


def mesh_appearance(mesh: MeshData, label_names: Sequence[str] | None = None,
                    materials: Mapping[str, Material] = MATERIALS,
                    default: Material = DEFAULT_MATERIAL) -> Appearance:
    """The appearance of a mesh read by ``sensors.io.meshes.read_mesh``.

    Parameters
    ----------
    mesh : MeshData
        Vertices, faces and the file's vertex and face properties.
    label_names : sequence of str, optional
        The names of the face property ``label``'s values (index i -> name), e.g.
        ``survey.world.mesh.LABELS``; without it the labels are not used.
    materials : mapping of str to Material
        The material of each label name (default ``MATERIALS``); a name not in it, or
        a label index beyond ``label_names``, gets ``default``.
    default : Material
        For a mesh without vertex properties or labels.

    Returns
    -------
    Appearance

    Raises
    ------
    SimulationError
        For vertex temperatures that are not finite and > 0 K, or emissivities outside
        [0, 1].
    """
    nv, nf = len(mesh.vertices), len(mesh.faces)
    vf, ff = mesh.vertex_fields, mesh.face_fields
    per_face: list[Material] | None = None
    idx = np.zeros(nf, dtype=np.int64)
    if label_names is not None and "label" in ff:
        lab = np.asarray(ff["label"]).astype(np.int64).reshape(-1)
        table = [materials.get(n, default) for n in label_names]
        idx = np.where((lab >= 0) & (lab < len(table)), lab, len(table))
        per_face = [*table, default]
    source: dict[str, str] = {}

    def from_table(what: str) -> Attribute:
        if per_face is None:
            source[what] = "default"
            val = np.asarray(getattr(default, _ATTR[what]), dtype=np.float64)
            return Attribute(np.broadcast_to(val, (nf,) + val.shape).copy(), "face")
        source[what] = "label"
        vals = np.array([getattr(m, _ATTR[what]) for m in per_face], dtype=np.float64)
        return Attribute(vals[idx], "face")

    rgb = _vertex_colour(vf)
    if rgb is not None and len(rgb) == nv:
        source["albedo"] = "vertex"
        albedo = Attribute(rgb, "vertex")
    else:
        albedo = from_table("albedo")
    attrs: dict[str, Attribute] = {}
    for what, lo, hi in (("temperature", 0.0, math.inf), ("emissivity", 0.0, 1.0)):
        if what in vf and len(vf[what]) == nv:
            x = np.asarray(vf[what], dtype=np.float64).reshape(-1)
            bad = ~np.isfinite(x) | (x < lo) | (x > hi) | ((x == 0) & (what == "temperature"))
            if bad.any():
                raise SimulationError(
                    f"Expected vertex {what} values in "
                    f"{'kelvin > 0' if what == 'temperature' else '[0, 1]'}, got "
                    f"{x[bad][0]} at vertex {int(np.flatnonzero(bad)[0])} of "
                    f"'{mesh.path}'; fix the mesh's {what} property.")
            source[what] = "vertex"
            attrs[what] = Attribute(x, "vertex")
        else:
            attrs[what] = from_table(what)
    retro = None
    flags = np.array([float(m.retroreflective) for m in per_face])[idx] \
        if per_face is not None else np.full(nf, float(default.retroreflective))
    if flags.any():
        # DECISION: a face label's material decides, also under vertex colours (a
        # scan's colour is the sheeting's diffuse look; its retro-reflection stays).
        # None when no face is retro-reflective: the shading is then the Lambertian
        # one, bit for bit.
        retro = Attribute(flags, "face")
    return Appearance(albedo, attrs["temperature"], attrs["emissivity"],
                      np.asarray(mesh.faces, dtype=np.int64), source, retro)


_ATTR = {"albedo": "albedo_rgb", "temperature": "temperature_k",
         "emissivity": "emissivity"}
